//! The generator and the projection conventions agree: instance pixels back-projected through
//! the written depth, intrinsics, pose and axis alignment land in the object's ground-truth
//! box. Everything is read back from disk with independent parsing.

use grounder::geometry::Aabb;
use grounder::synth::{generate_family, Family, Layout, SynthParams};
use image::{ImageBuffer, Luma};
use nalgebra::{Matrix4, Point3, Vector4};
use std::collections::BTreeMap;
use std::path::Path;

fn read_matrix(path: &Path) -> Matrix4<f64> {
    let text = std::fs::read_to_string(path).unwrap();
    let v: Vec<f64> = text
        .split_whitespace()
        .map(|t| t.parse().unwrap())
        .collect();
    assert_eq!(v.len(), 16, "{}", path.display());
    Matrix4::from_row_slice(&v)
}

fn read_u16(path: &Path) -> ImageBuffer<Luma<u16>, Vec<u16>> {
    image::open(path).unwrap().to_luma16()
}

/// Back-project every interior instance pixel of every frame; returns per-object
/// (points tested, points outside the box by more than 2 cm, AABB of the points).
pub(crate) fn check_scene(
    dir: &Path,
    layout: Layout,
    objects: &BTreeMap<u32, Aabb>,
) -> BTreeMap<u32, (usize, usize, Option<Aabb>)> {
    let (k, color_dir, depth_dir, pose_dir) = match layout {
        Layout::Scannet => (
            read_matrix(&dir.join("intrinsic/intrinsic_color.txt")),
            dir.join("color"),
            dir.join("depth"),
            dir.join("pose"),
        ),
        Layout::PosedImages => (
            read_matrix(&dir.join("intrinsic.txt")),
            dir.to_path_buf(),
            dir.to_path_buf(),
            dir.to_path_buf(),
        ),
    };
    let align = read_matrix(&dir.join("axis_align_matrix.txt"));
    let (fx, fy, cx, cy) = (k[(0, 0)], k[(1, 1)], k[(0, 2)], k[(1, 2)]);
    let mut stats: BTreeMap<u32, (usize, usize, Option<Aabb>)> = BTreeMap::new();
    let mut names: Vec<String> = std::fs::read_dir(dir.join("instance"))
        .unwrap()
        .filter_map(|e| {
            e.unwrap()
                .file_name()
                .to_str()
                .unwrap()
                .strip_suffix(".png")
                .map(str::to_string)
        })
        .collect();
    names.sort();
    assert!(!names.is_empty());
    for name in names {
        assert!(color_dir.join(format!("{name}.jpg")).exists());
        let inst = read_u16(&dir.join("instance").join(format!("{name}.png")));
        let depth = read_u16(&depth_dir.join(format!("{name}.png")));
        let pose = read_matrix(&pose_dir.join(format!("{name}.txt")));
        let to_out = align * pose;
        let (wc, hc) = inst.dimensions();
        let (wd, hd) = depth.dimensions();
        for v in 2..hc - 2 {
            for u in 2..wc - 2 {
                let id = inst.get_pixel(u, v)[0];
                if id == 0 {
                    continue;
                }
                // Interior pixels only: the depth lookup may move by up to a colour pixel or two.
                if (v - 2..=v + 2).any(|y| (u - 2..=u + 2).any(|x| inst.get_pixel(x, y)[0] != id)) {
                    continue;
                }
                let dx = ((u as f64 * wd as f64 / wc as f64).round() as u32).min(wd - 1);
                let dy = ((v as f64 * hd as f64 / hc as f64).round() as u32).min(hd - 1);
                let z = depth.get_pixel(dx, dy)[0] as f64 / 1000.0;
                assert!(z > 0.0, "noise-free depth must have no holes");
                let cam = Vector4::new((u as f64 - cx) * z / fx, (v as f64 - cy) * z / fy, z, 1.0);
                let w = to_out * cam;
                let p = Point3::new(w.x, w.y, w.z);
                let gt = objects
                    .get(&(id as u32))
                    .unwrap_or_else(|| panic!("instance id {id} not in the ground truth"));
                let e = stats.entry(id as u32).or_insert((0, 0, None));
                e.0 += 1;
                if !gt.contains(&p, 0.02) {
                    e.1 += 1;
                }
                e.2 = Some(match e.2 {
                    None => Aabb::new([p.x, p.y, p.z], [p.x, p.y, p.z]),
                    Some(b) => Aabb::new(
                        [0, 1, 2].map(|i| b.min[i].min(p[i])),
                        [0, 1, 2].map(|i| b.max[i].max(p[i])),
                    ),
                });
            }
        }
    }
    stats
}

fn run(params: SynthParams) {
    run_family(Family::Rooms, params, 0.5);
}

/// Generate a scene of `family` and check that every instance pixel back-projects into its
/// object's box and that the points span the boxes (mean IoU of the point boxes above
/// `min_mean_iou` over objects seen by more than 200 pixels).
pub(crate) fn run_family(family: Family, params: SynthParams, min_mean_iou: f64) {
    let tmp = tempfile::tempdir().unwrap();
    let scene = generate_family(family, &params, tmp.path(), false).unwrap();
    let objects: BTreeMap<u32, Aabb> = scene.objects.iter().map(|o| (o.id, o.aabb)).collect();
    let labels: BTreeMap<String, String> = serde_json::from_str(
        &std::fs::read_to_string(scene.dir.join("instance/labels.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(labels.len(), objects.len());
    for o in &scene.objects {
        assert_eq!(labels[&o.id.to_string()], o.label);
    }
    let stats = check_scene(&scene.dir, params.layout, &objects);
    let mut total = 0;
    let mut ious = Vec::new();
    for (id, (n, outside, pts)) in &stats {
        total += n;
        assert_eq!(*outside, 0, "object {id}: {outside} of {n} back-projected pixels are more than 2 cm outside its box");
        if *n > 200 {
            ious.push(pts.unwrap().iou(&objects[id]));
        }
    }
    assert!(
        stats.len() * 2 >= objects.len(),
        "only {} of {} objects seen",
        stats.len(),
        objects.len()
    );
    assert!(total > 1000, "too few instance pixels: {total}");
    // The ground-truth box is tight: the points seen span most of it.
    let mean_iou = ious.iter().sum::<f64>() / ious.len() as f64;
    eprintln!(
        "{} objects seen of {}, {total} points, mean IoU of point boxes {mean_iou:.3}",
        stats.len(),
        objects.len()
    );
    assert!(
        mean_iou > min_mean_iou,
        "back-projected points span too little of the boxes: mean IoU {mean_iou:.2}"
    );
}

#[test]
fn instance_pixels_back_project_into_their_boxes_scannet_layout() {
    for seed in [3, 11] {
        run(SynthParams::small(seed));
    }
}

#[test]
fn instance_pixels_back_project_into_their_boxes_posed_images_layout() {
    run(SynthParams {
        layout: Layout::PosedImages,
        color_size: (324, 242),
        depth_size: (160, 120),
        ..SynthParams::small(5)
    });
}
