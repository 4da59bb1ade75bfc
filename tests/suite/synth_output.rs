//! Output properties of `synth::generate`: byte-identical for a seed, realistic noise does
//! what it says, files follow FORMATS §1.

use grounder::synth::{generate, generate_with, Noise, SynthParams};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Every file under `dir` with its bytes, by relative path.
pub(crate) fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(
                    p.strip_prefix(dir).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    out
}

fn tiny(seed: u64, noise: Noise) -> SynthParams {
    SynthParams {
        frames: 6,
        noise,
        color_size: (160, 120),
        depth_size: (80, 60),
        ..SynthParams::small(seed)
    }
}

#[test]
fn same_seed_gives_identical_bytes_and_other_seeds_differ() {
    let (a, b, c) = (
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
    );
    let p = tiny(42, Noise::Realistic);
    let sa = generate_with(&p, a.path(), true).unwrap();
    let sb = generate_with(&p, b.path(), true).unwrap();
    let (fa, fb) = (snapshot(a.path()), snapshot(b.path()));
    assert_eq!(fa.keys().collect::<Vec<_>>(), fb.keys().collect::<Vec<_>>());
    for (k, v) in &fa {
        assert!(v == &fb[k], "{} differs between two runs", k.display());
    }
    assert!(
        fa.len() > 6 * 4,
        "expected colour, depth, pose and instance files, got {}",
        fa.len()
    );
    assert_eq!(sa.objects, sb.objects);
    assert_eq!(sa.queries, sb.queries);
    // The tar holds the scene under a single top-level folder.
    let mut ar = tar::Archive::new(std::fs::File::open(sa.tar.unwrap()).unwrap());
    let names: Vec<PathBuf> = ar
        .entries()
        .unwrap()
        .map(|e| e.unwrap().path().unwrap().into_owned())
        .collect();
    assert!(names.iter().all(|n| n.starts_with("scene_synth_0042")));
    assert!(names.contains(&PathBuf::from("scene_synth_0042/depth/20.png")));

    let sc = generate(&tiny(43, Noise::Realistic), c.path()).unwrap();
    assert_eq!(sc.scene_id, "scene_synth_0043");
    let fc = snapshot(&sc.dir);
    let rel = PathBuf::from("color/0.jpg");
    assert_ne!(fc[&rel], fa[&PathBuf::from("scene_synth_0042").join(&rel)]);
}

#[test]
fn scannet_layout_files_and_frame_names() {
    let t = tempfile::tempdir().unwrap();
    let s = generate(&tiny(1, Noise::None), t.path()).unwrap();
    let names: Vec<&str> = s.frames.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names, ["0", "20", "40", "60", "80", "100"]);
    for f in [
        "intrinsic/intrinsic_color.txt",
        "intrinsic/intrinsic_depth.txt",
        "axis_align_matrix.txt",
        "instance/labels.json",
        "color/100.jpg",
        "depth/100.png",
        "pose/100.txt",
        "instance/100.png",
    ] {
        assert!(s.dir.join(f).is_file(), "missing {f}");
    }
    let color = image::open(s.dir.join("color/0.jpg")).unwrap();
    assert_eq!((color.width(), color.height()), (160, 120));
    let depth = image::open(s.dir.join("depth/0.png")).unwrap();
    assert_eq!(depth.color(), image::ColorType::L16);
    assert_eq!((depth.width(), depth.height()), (80, 60));
    // The axis alignment really rotates and offsets.
    let a = s.axis_align;
    assert!(a[(0, 1)].abs() > 0.1 && a[(0, 3)].abs() + a[(1, 3)].abs() > 0.0);
    // Colour is shaded and textured, not flat: many distinct colours.
    let rgb = color.to_rgb8();
    let distinct: std::collections::BTreeSet<[u8; 3]> = rgb.pixels().map(|p| p.0).collect();
    assert!(
        distinct.len() > 500,
        "only {} distinct colours",
        distinct.len()
    );
}

#[test]
fn realistic_noise_adds_holes_noise_cutoff_and_inf_poses() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let frames = 30;
    let clean = generate(
        &SynthParams {
            frames,
            ..tiny(9, Noise::None)
        },
        a.path(),
    )
    .unwrap();
    let noisy = generate(
        &SynthParams {
            frames,
            ..tiny(9, Noise::Realistic)
        },
        b.path(),
    )
    .unwrap();
    let invalid: Vec<&str> = noisy
        .frames
        .iter()
        .filter(|f| !f.pose_valid)
        .map(|f| f.name.as_str())
        .collect();
    assert!(
        !invalid.is_empty() && invalid.len() < frames / 4,
        "inf-pose frames: {invalid:?}"
    );
    for f in &noisy.frames {
        let text = std::fs::read_to_string(noisy.dir.join(format!("pose/{}.txt", f.name))).unwrap();
        let v: Vec<f64> = text
            .split_whitespace()
            .map(|t| t.parse().unwrap())
            .collect();
        assert_eq!(v.len(), 16);
        assert_eq!(
            v.iter().all(|x| x.is_finite()),
            f.pose_valid,
            "frame {}",
            f.name
        );
    }
    let (mut holes, mut changed, mut total, mut max_mm, mut clean_zero) =
        (0usize, 0usize, 0usize, 0u16, 0usize);
    for f in &clean.frames {
        let dc = image::open(clean.dir.join(format!("depth/{}.png", f.name)))
            .unwrap()
            .to_luma16();
        let dn = image::open(noisy.dir.join(format!("depth/{}.png", f.name)))
            .unwrap()
            .to_luma16();
        for (c, n) in dc.pixels().zip(dn.pixels()) {
            total += 1;
            clean_zero += (c[0] == 0) as usize;
            holes += (n[0] == 0) as usize;
            changed += (n[0] != 0 && n[0] != c[0]) as usize;
            max_mm = max_mm.max(n[0]);
        }
    }
    assert_eq!(clean_zero, 0, "noise-free depth has holes");
    assert!(holes > total / 100, "too few holes: {holes} of {total}");
    assert!(
        changed > total / 2,
        "noise changed only {changed} of {total} readings"
    );
    assert!(max_mm <= 5000, "reading beyond the cut-off: {max_mm} mm");
    // Pose jitter: the valid noisy poses are close to, but not exactly, the clean ones.
    let p = |s: &grounder::synth::SynthScene, n: &str| {
        std::fs::read_to_string(s.dir.join(format!("pose/{n}.txt"))).unwrap()
    };
    assert_ne!(p(&clean, "0"), p(&noisy, "0"));
}
