//! Converters on hand-written samples of the original formats (tests/fixtures/convert/).

use grounder::eval::convert::{nr3d, scannet, scanrefer, ObjectsSource};
use grounder::eval::dataset::{Dataset, Subset};
use std::path::{Path, PathBuf};
use std::process::Command;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/convert")
}

fn assert_box(got: &grounder::geometry::Aabb, min: [f64; 3], max: [f64; 3]) {
    for i in 0..3 {
        assert!(
            (got.min[i] - min[i]).abs() < 1e-6 && (got.max[i] - max[i]).abs() < 1e-6,
            "{got:?} vs {min:?} {max:?}"
        );
    }
}

#[test]
fn scannet_boxes_are_aligned_vertex_aabbs() {
    let so =
        scannet::scene_objects(&fixtures().join("scans/scene0000_00"), "scene0000_00").unwrap();
    assert_eq!(so.objects.len(), 3);
    // Alignment: x' = -y + 10, y' = x + 20, z' = z (hand-computed).
    assert_eq!(so.objects[0].label, "chair");
    assert_box(&so.objects[0].aabb, [9.0, 20.0, 0.0], [10.0, 21.0, 1.0]);
    assert_box(&so.objects[1].aabb, [7.0, 22.0, 0.0], [8.0, 23.0, 0.5]);
    assert_eq!(so.objects[2].label, "table");
    assert_box(&so.objects[2].aabb, [11.0, 19.0, 0.0], [12.0, 19.5, 0.8]);
}

#[test]
fn ply_ascii_and_errors() {
    let ascii = b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nend_header\n1 2 3 255\n-1 0.5 4 0\n";
    assert_eq!(
        scannet::read_ply_vertices(ascii).unwrap(),
        vec![[1.0, 2.0, 3.0], [-1.0, 0.5, 4.0]]
    );
    let truncated = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n\0\0\0\0";
    assert!(scannet::read_ply_vertices(truncated)
        .unwrap_err()
        .to_string()
        .contains("truncated"));
    assert!(scannet::read_ply_vertices(b"hello").is_err());
    assert!(scannet::parse_axis_alignment("axisAlignment = 1 2 3\n").is_err());
    assert_eq!(
        scannet::parse_axis_alignment("sceneType = x\n").unwrap(),
        nalgebra::Matrix4::identity()
    );
}

fn objects_dir() -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    scannet::convert_scans(&fixtures().join("scans"), &[], d.path()).unwrap();
    d
}

#[test]
fn scanrefer_queries_with_subsets_and_skips() {
    let objs = objects_dir();
    let (q, skipped) = scanrefer::convert(
        &fixtures().join("scanrefer.json"),
        &ObjectsSource::new(objs.path()),
    )
    .unwrap();
    assert_eq!(skipped, 2);
    assert_eq!(q.len(), 2);
    assert_eq!(q[0].query_id, "scene0000_00_0_0");
    assert_eq!(
        (q[0].target_id, q[0].target_label.as_str(), q[0].subset),
        (0, "chair", Subset::Multiple)
    );
    assert_eq!(
        (q[1].target_id, q[1].target_label.as_str(), q[1].subset),
        (2, "table", Subset::Unique)
    );
    assert_eq!(q[1].extra["ann_id"], "3");
    assert_eq!(q[1].text, "the only table in the room, between the chairs.");
}

#[test]
fn nr3d_flags() {
    let objs = objects_dir();
    let (q, skipped) = nr3d::convert(
        &fixtures().join("nr3d.csv"),
        &ObjectsSource::new(objs.path()),
    )
    .unwrap();
    assert_eq!(skipped, 1);
    assert_eq!(q.len(), 3);
    assert_eq!(q[0].query_id, "nr3d_41");
    assert_eq!(q[0].text, "Facing the table, the chair on the left");
    assert_eq!(
        (q[0].flag("hard"), q[0].flag("view_dependent")),
        (Some(false), Some(true))
    );
    assert_eq!(
        (q[1].flag("hard"), q[1].flag("view_dependent")),
        (Some(false), Some(false))
    );
    assert_eq!(q[1].subset, Subset::Unique);
    // Stimulus says four chairs -> hard.
    assert_eq!(
        (q[2].flag("hard"), q[2].flag("view_dependent")),
        (Some(true), Some(false))
    );
    assert_eq!(q[2].flag("correct_guess"), Some(false));
    assert!(nr3d::is_view_dependent("the one on the RIGHT."));
    assert!(!nr3d::is_view_dependent("the bright lamp"));
}

#[test]
fn cli_pipeline_produces_a_loadable_dataset() {
    let exe = env!("CARGO_BIN_EXE_grounder");
    let out = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        let o = Command::new(exe).args(args).output().unwrap();
        assert!(
            o.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    };
    let f = fixtures();
    let gt = out.path().join("gt");
    let sr = out.path().join("scanrefer");
    run(&[
        "convert",
        "scannet-gt",
        "--scans",
        f.join("scans").to_str().unwrap(),
        "--out",
        gt.to_str().unwrap(),
    ]);
    run(&[
        "convert",
        "scanrefer",
        "--input",
        f.join("scanrefer.json").to_str().unwrap(),
        "--objects",
        gt.to_str().unwrap(),
        "--out",
        sr.to_str().unwrap(),
    ]);
    let ds = Dataset::load(&sr).unwrap();
    assert_eq!(ds.queries.len(), 2);
    assert_eq!(ds.scenes["scene0000_00"].objects.len(), 3);
    // A missing input is a one-line error, not a panic.
    let o = Command::new(exe)
        .args([
            "convert",
            "nr3d",
            "--input",
            "/nonexistent.csv",
            "--objects",
            gt.to_str().unwrap(),
            "--out",
            sr.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.starts_with("error: cannot read /nonexistent.csv"),
        "{err}"
    );
}
