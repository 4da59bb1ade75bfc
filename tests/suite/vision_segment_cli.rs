//! `grounder segment`: one box in one frame of a scene directory, end to end through the
//! binary, on a small synthetic room.

use std::path::Path;
use std::process::{Command, Output};

fn grounder(args: &[&str], extra: &[&Path]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_grounder"))
        .args(args)
        .args(extra)
        .output()
        .expect("the binary runs")
}

/// The bounding box [x0, y0, x1, y1) and the pixel count of the largest object instance
/// (id > 0) of an instance PNG.
fn largest_instance(path: &Path) -> ([u32; 4], u16, usize) {
    let img = image::open(path).expect("instance png").to_luma16();
    let mut count = std::collections::HashMap::<u16, usize>::new();
    for p in img.pixels() {
        if p.0[0] > 0 {
            *count.entry(p.0[0]).or_default() += 1;
        }
    }
    let (&id, &n) = count.iter().max_by_key(|(_, n)| **n).expect("an object");
    let (mut b, mut any) = ([u32::MAX, u32::MAX, 0, 0], false);
    for (x, y, p) in img.enumerate_pixels() {
        if p.0[0] == id {
            any = true;
            b = [b[0].min(x), b[1].min(y), b[2].max(x + 1), b[3].max(y + 1)];
        }
    }
    assert!(any);
    (b, id, n)
}

#[test]
fn a_box_in_a_frame_is_segmented_drawn_and_described_and_a_bad_box_is_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("synth");
    let o = grounder(
        &[
            "synth",
            "--seed",
            "7",
            "--frames",
            "8",
            "--color-size",
            "320x240",
            "--depth-size",
            "160x120",
            "--out",
        ],
        &[&out],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let scene = std::fs::read_dir(&out)
        .expect("the scene folder")
        .filter_map(Result::ok)
        .map(|e| e.path())
        .next()
        .expect("one scene");
    let (b, _, n) = largest_instance(&scene.join("instance").join("0.png"));
    let bx = format!("{},{},{},{}", b[0], b[1], b[2], b[3]);
    let png = dir.path().join("mask.png");
    let o = grounder(
        &["segment", "--frame", "0", "--box", &bx, "--out"],
        &[&png, &scene],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let line: serde_json::Value =
        serde_json::from_slice(&o.stdout).expect("one JSON line on stdout");
    let pixels = line["pixels"].as_u64().expect("pixels") as usize;
    // The object's mask: most of its pixels, not the whole box's background.
    assert!(pixels as f64 > 0.5 * n as f64, "{line}");
    assert!(pixels as f64 <= 1.5 * n as f64, "{line}");
    let mb: Vec<u64> = serde_json::from_value(line["mask_box"].clone()).expect("mask box");
    assert!(
        mb[0] >= u64::from(b[0]) && mb[2] <= u64::from(b[2]),
        "{line}"
    );
    assert_eq!(
        line["hidden_sides"].as_array().map(Vec::len),
        Some(4),
        "{line}"
    );
    assert!(line["partial"]["partial"].is_boolean(), "{line}");
    let drawn = image::open(&png).expect("the overlay").to_rgb8();
    assert_eq!(drawn.dimensions(), (320, 240));
    // The box's outline is drawn in green.
    assert_eq!(drawn.get_pixel(b[0], (b[1] + b[3]) / 2).0, [0, 255, 0]);

    // The frame's missing depth in the box is completed from the other frames first, as
    // the service does for the chosen view; `--depth-fill off` leaves it missing.
    assert!(line["depth_fill"]["missing"].is_u64(), "{line}");
    let depth_png = scene.join("depth").join("0.png");
    let mut depth = image::open(&depth_png).expect("depth png").to_luma16();
    let (dw, cw) = (depth.width(), 320);
    let to_depth = |v: u32| v * dw / cw;
    // The box's central half (a quarter of its area) loses its readings.
    let (qx, qy) = ((b[2] - b[0]) / 4, (b[3] - b[1]) / 4);
    for y in to_depth(b[1] + qy)..to_depth(b[3] - qy) {
        for x in to_depth(b[0] + qx)..to_depth(b[2] - qx) {
            depth.put_pixel(x, y, image::Luma([0]));
        }
    }
    depth.save(&depth_png).expect("depth written");
    let filled = |fill: &[&str]| {
        let mut args = vec!["segment", "--frame", "0", "--box", &bx];
        args.extend_from_slice(fill);
        args.push("--out");
        let o = grounder(&args, &[&png, &scene]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let line: serde_json::Value = serde_json::from_slice(&o.stdout).expect("a JSON line");
        line["depth_fill"].clone()
    };
    let on = filled(&[]);
    assert!(on["missing"].as_u64().is_some_and(|m| m >= 16), "{on}");
    assert!(on["filled"].as_u64().is_some_and(|f| f > 0), "{on}");
    assert!(filled(&["--depth-fill", "off"]).is_null());

    // A box with no area, a frame the scene lacks: one line on stderr, no image written.
    let none = dir.path().join("none.png");
    for (frame, bad) in [("0", "10,10,10,40"), ("nope", "1,1,9,9")] {
        let o = grounder(
            &["segment", "--frame", frame, "--box", bad, "--out"],
            &[&none, &scene],
        );
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(err.starts_with("error: "), "{err}");
        assert!(!none.exists());
    }
}
