//! Depth segmenter quality on a small rendered room: boxes on the floor, one stacked on a
//! table, walls behind; Kinect-like depth noise growing with distance, dropouts and flying
//! pixels at depth edges. Mask IoU against the rendered instance masks is measured for every
//! object whose visible box is at least 40x40 px (run with --nocapture to see the figures).

use grounder::geometry::camera::{look_at_pose, DepthMap, FrameCamera, Intrinsics};
use grounder::geometry::mask::Mask;
use grounder::vision::{build_segmenter, SegmentInput, Segmenter, VisionConfig};
use image::{Rgb, RgbImage};
use nalgebra::{Matrix4, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const W: u32 = 320;
const H: u32 = 240;

struct Obj {
    min: [f64; 3],
    max: [f64; 3],
    id: u16,
    rgb: [u8; 3],
}

fn room() -> Vec<Obj> {
    let o = |min: [f64; 3], max: [f64; 3], id, rgb| Obj { min, max, id, rgb };
    vec![
        o([0.3, 0.3, 0.0], [1.1, 0.8, 0.9], 1, [150, 100, 60]), // cabinet in a corner
        o([2.0, 1.5, 0.0], [3.2, 2.3, 0.75], 2, [120, 80, 40]), // table block
        o([2.4, 1.7, 0.75], [2.8, 2.05, 1.0], 3, [40, 90, 200]), // box on the table
        o([1.4, 2.6, 0.0], [1.9, 3.1, 0.5], 4, [200, 60, 60]),  // low stool
        o([4.2, 0.4, 0.0], [4.7, 1.0, 1.8], 5, [220, 220, 210]), // tall cupboard
        o([3.5, 3.0, 0.0], [4.2, 3.6, 0.6], 6, [60, 160, 80]),  // crate
    ]
}

/// Entry distance of a ray into an AABB (slab method).
fn hit(o: &Point3<f64>, d: &Vector3<f64>, min: [f64; 3], max: [f64; 3]) -> Option<f64> {
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for a in 0..3 {
        if d[a].abs() < 1e-12 {
            if o[a] < min[a] || o[a] > max[a] {
                return None;
            }
            continue;
        }
        let (mut ta, mut tb) = ((min[a] - o[a]) / d[a], (max[a] - o[a]) / d[a]);
        if ta > tb {
            std::mem::swap(&mut ta, &mut tb);
        }
        t0 = t0.max(ta);
        t1 = t1.min(tb);
    }
    (t0 <= t1 && t0 > 1e-6).then_some(t0)
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    let (u1, u2): (f64, f64) = (rng.gen_range(1e-12..1.0), rng.gen());
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

struct View {
    color: RgbImage,
    depth: DepthMap,
    ids: Vec<u16>,
    cam: FrameCamera,
}

fn render(eye: [f64; 3], target: [f64; 3], seed: u64) -> View {
    let k = Intrinsics {
        fx: 288.0,
        fy: 288.0,
        cx: 160.0,
        cy: 120.0,
        width: W,
        height: H,
    };
    let pose = look_at_pose(Point3::from(eye), Point3::from(target), Vector3::z());
    let objs = room();
    let o = Point3::from(eye);
    let r = pose.fixed_view::<3, 3>(0, 0).into_owned();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = (W * H) as usize;
    let (mut z, mut ids, mut rgb) = (vec![0.0f64; n], vec![0u16; n], vec![[0u8; 3]; n]);
    for v in 0..H {
        for u in 0..W {
            let dc = Vector3::new(
                (u as f64 + 0.5 - k.cx) / k.fx,
                (v as f64 + 0.5 - k.cy) / k.fy,
                1.0,
            );
            let d = r * dc;
            // room interior: exit of the room box, colour by the surface hit
            let mut best = f64::INFINITY;
            let mut colour = [180u8, 170, 150];
            for a in 0..3 {
                let (lo, hi) = ([0.0, 0.0, 0.0][a], [5.0, 4.0, 2.6][a]);
                if d[a].abs() > 1e-12 {
                    let t = if d[a] > 0.0 {
                        (hi - o[a]) / d[a]
                    } else {
                        (lo - o[a]) / d[a]
                    };
                    if t > 0.0 && t < best {
                        best = t;
                        colour = if a == 2 && d[a] < 0.0 {
                            [110, 105, 100]
                        } else {
                            [185, 180, 170 - 20 * a as u8]
                        };
                    }
                }
            }
            let mut id = 0;
            for ob in &objs {
                if let Some(t) = hit(&o, &d, ob.min, ob.max) {
                    if t < best {
                        best = t;
                        id = ob.id;
                        colour = ob.rgb;
                    }
                }
            }
            let i = (v * W + u) as usize;
            z[i] = best; // t along dc (z = 1) is the camera depth
            ids[i] = id;
            rgb[i] = colour;
        }
    }
    // sensor: noise grows with distance, flying pixels at edges, dropouts
    let mut data = vec![0u16; n];
    for v in 0..H as usize {
        for u in 0..W as usize {
            let i = v * W as usize + u;
            let mut zz = z[i];
            if u + 1 < W as usize && (z[i + 1] - zz).abs() > 0.1 && rng.gen_bool(0.5) {
                zz += rng.gen::<f64>() * (z[i + 1] - zz); // flying pixel between the two surfaces
            }
            let sigma = 0.0012 + 0.0019 * (zz - 0.4).powi(2);
            zz += sigma * gauss(&mut rng);
            let dropout = rng.gen_bool(0.02) || zz > 6.0;
            data[i] = if dropout {
                0
            } else {
                (zz * 1000.0).round().clamp(0.0, 65535.0) as u16
            };
        }
    }
    for _ in 0..15 {
        // clustered holes (specular/dark patches)
        let (cx, cy, rr) = (
            rng.gen_range(0..W) as i64,
            rng.gen_range(0..H) as i64,
            rng.gen_range(2..6) as i64,
        );
        for y in (cy - rr).max(0)..(cy + rr).min(H as i64) {
            for x in (cx - rr).max(0)..(cx + rr).min(W as i64) {
                if (x - cx).pow(2) + (y - cy).pow(2) <= rr * rr {
                    data[(y * W as i64 + x) as usize] = 0;
                }
            }
        }
    }
    let color = RgbImage::from_fn(W, H, |x, y| {
        let c = rgb[(y * W + x) as usize];
        let mut jit = |v: u8| (v as i32 + rng.gen_range(-8..=8)).clamp(0, 255) as u8;
        Rgb([jit(c[0]), jit(c[1]), jit(c[2])])
    });
    let cam = FrameCamera {
        color: k,
        depth: None,
        depth_size: (W, H),
        pose,
        align: Matrix4::identity(),
    };
    View {
        color,
        depth: DepthMap::new(W, H, data),
        ids,
        cam,
    }
}

/// (IoU of the segmenter, IoU of the plain box) per object seen with a box >= 40x40 px.
fn measure(seg: &dyn Segmenter) -> Vec<(u16, f64, f64)> {
    let views = [
        ([4.6, 3.7, 1.5], [2.0, 1.5, 0.5], 1),
        ([0.3, 3.7, 1.6], [2.8, 1.2, 0.5], 2),
        ([2.5, 0.2, 1.4], [2.5, 2.5, 0.4], 3),
        ([4.7, 2.0, 1.7], [1.5, 1.8, 0.4], 4),
    ];
    let mut out = Vec::new();
    for (eye, target, seed) in views {
        let v = render(eye, target, seed);
        for id in 1..=6u16 {
            let mut gt = Mask::new(W, H);
            let (mut x0, mut y0, mut x1, mut y1) = (W, H, 0, 0);
            for (i, &g) in v.ids.iter().enumerate() {
                if g == id {
                    let (x, y) = (i as u32 % W, i as u32 / W);
                    gt.set(x, y, true);
                    (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
                }
            }
            if gt.count() == 0 || x1 + 1 - x0 < 40 || y1 + 1 - y0 < 40 {
                continue;
            }
            let bbox = [x0 as f32, y0 as f32, (x1 + 1) as f32, (y1 + 1) as f32];
            let m = seg
                .segment(
                    &SegmentInput {
                        color: &v.color,
                        depth: &v.depth,
                        camera: &v.cam,
                    },
                    bbox,
                )
                .expect("segment");
            out.push((id, m.iou(&gt), Mask::from_box(W, H, bbox).iou(&gt)));
        }
    }
    out
}

#[test]
fn depth_segmenter_masks_match_ground_truth() {
    let seg = build_segmenter("depth", &VisionConfig::default()).expect("depth segmenter");
    let r = measure(seg.as_ref());
    assert!(r.len() >= 10, "too few measurable objects: {}", r.len());
    let mean = r.iter().map(|x| x.1).sum::<f64>() / r.len() as f64;
    let base = r.iter().map(|x| x.2).sum::<f64>() / r.len() as f64;
    let worst = r.iter().map(|x| x.1).fold(1.0, f64::min);
    for (id, iou, b) in &r {
        eprintln!("object {id}: depth-mask IoU {iou:.3} (box {b:.3})");
    }
    eprintln!("depth segmenter: mean mask IoU {mean:.3} over {} objects >= 40x40 px (box baseline {base:.3}, worst {worst:.3})", r.len());
    assert!(mean >= 0.75, "mean IoU {mean:.3} below 0.75");
    assert!(worst >= 0.5, "one object failed badly: IoU {worst:.3}");
    assert!(
        mean > base + 0.05,
        "depth masks ({mean:.3}) should beat the box ({base:.3})"
    );
}

#[test]
fn box_segmenter_is_the_box() {
    let seg = build_segmenter("box", &VisionConfig::default()).expect("box");
    let v = render([4.6, 3.7, 1.5], [2.0, 1.5, 0.5], 1);
    let m = seg
        .segment(
            &SegmentInput {
                color: &v.color,
                depth: &v.depth,
                camera: &v.cam,
            },
            [10.0, 20.0, 50.0, 40.0],
        )
        .expect("seg");
    assert_eq!(m, Mask::from_box(W, H, [10.0, 20.0, 50.0, 40.0]));
    assert_eq!(m.count(), 40 * 20);
}
