//! Grid rendering, id labels (checked on pixels), JPEG encoding, instance annotation.

use grounder::stitch::{
    annotate_instances, decode_image, encode_jpeg, plan, render_grid_with_placements, stitch_all,
    AnnotateOptions, GridSpec, StitchOptions,
};
use image::{Rgb, RgbImage};

fn is_red(p: &Rgb<u8>) -> bool {
    p.0[0] > 180 && p.0[1] < 90 && p.0[2] < 90
}

fn small_opts(max_side: u32) -> StitchOptions {
    StitchOptions {
        max_side,
        ..StitchOptions::default()
    }
}

#[test]
fn grid_size_keeps_tile_aspect_and_fits_limit() {
    let tile = RgbImage::from_pixel(200, 100, Rgb([10, 200, 30]));
    let tiles: Vec<(String, &RgbImage)> = (0..3).map(|i| (format!("{i:05}"), &tile)).collect();
    let spec = GridSpec {
        rows: 4,
        cols: 1,
        frames: 3,
    };
    let (img, places) = render_grid_with_placements(&tiles, &spec, &small_opts(256)).unwrap();
    // Full grid 200 x 400 -> longer side 256 -> 128 x 256; tiles 128 x 64.
    assert_eq!(img.dimensions(), (128, 256));
    for (i, p) in places.iter().enumerate() {
        assert_eq!((p.x, p.y, p.w, p.h), (0, 64 * i as u32, 128, 64));
    }
    // The unused fourth cell is background.
    assert_eq!(*img.get_pixel(64, 230), Rgb([0, 0, 0]));
    // Tile content survives away from the label.
    let p = img.get_pixel(100, 64 + 50);
    assert!(p.0[1] > 180 && p.0[0] < 40, "{p:?}");
}

#[test]
fn small_grids_are_scaled_up_unless_disabled() {
    let tile = RgbImage::from_pixel(100, 50, Rgb([90, 90, 90]));
    let tiles = vec![("00001".to_string(), &tile)];
    let spec = GridSpec {
        rows: 2,
        cols: 4,
        frames: 1,
    };
    let (img, _) = render_grid_with_placements(&tiles, &spec, &small_opts(800)).unwrap();
    assert_eq!(img.dimensions(), (800, 200));
    let opts = StitchOptions {
        upscale: false,
        ..small_opts(800)
    };
    let (img, _) = render_grid_with_placements(&tiles, &spec, &opts).unwrap();
    assert_eq!(img.dimensions(), (400, 100));
}

#[test]
fn ids_are_drawn_in_red_at_each_tiles_top_left_only() {
    // Gray tiles of different shades, one with a different aspect ratio.
    let imgs: Vec<RgbImage> = (0..6)
        .map(|i| {
            let (w, h) = if i == 2 { (150, 240) } else { (320, 240) };
            RgbImage::from_pixel(w, h, Rgb([40 + 30 * i as u8; 3]))
        })
        .collect();
    let tiles: Vec<(String, &RgbImage)> = imgs
        .iter()
        .enumerate()
        .map(|(i, im)| (format!("{:05}", 100 + i), im))
        .collect();
    let spec = GridSpec {
        rows: 2,
        cols: 4,
        frames: 6,
    };
    let (img, places) = render_grid_with_placements(&tiles, &spec, &small_opts(1024)).unwrap();
    assert_eq!(img.dimensions(), (1024, 384));
    let mut red_in_label_zone = vec![0usize; places.len()];
    for (x, y, p) in img.enumerate_pixels() {
        if !is_red(p) {
            continue;
        }
        // Every red pixel must lie in the top-left label zone of some tile:
        // within the top 20 % of its height and the left 60 % of a full-width tile.
        let owner = places
            .iter()
            .position(|t| x >= t.x && x < t.x + 154 && y >= t.y && y < t.y + t.h / 5);
        match owner {
            Some(i) => red_in_label_zone[i] += 1,
            None => panic!("red pixel outside any label zone at ({x}, {y})"),
        }
    }
    for (i, n) in red_in_label_zone.iter().enumerate() {
        assert!(*n > 20, "tile {i} has only {n} red label pixels");
    }
    // Text height about 10 % of the tile height (192 px tiles -> about 19 px of ink).
    let t = &places[0];
    let rows: Vec<u32> = (t.y..t.y + t.h)
        .filter(|&y| (t.x..t.x + t.w).any(|x| is_red(img.get_pixel(x, y))))
        .collect();
    let ink = rows.last().unwrap() - rows.first().unwrap() + 1;
    assert!((16..=22).contains(&ink), "ink height {ink}");
    // The label box behind the text is white-ish, and the tile's lower part keeps its shade.
    let below = img.get_pixel(t.x + t.w / 2, t.y + t.h - 5);
    assert_eq!(below.0[0], 40);
    // Cells 7 and 8 are empty.
    assert_eq!(*img.get_pixel(1024 - 10, 300), Rgb([0, 0, 0]));
}

#[test]
fn labels_are_readable_on_red_and_white_tiles() {
    // The white box keeps red text visible on a red tile; the text is visible on white.
    for shade in [[255u8, 0, 0], [255, 255, 255]] {
        let tile = RgbImage::from_pixel(400, 300, Rgb(shade));
        let tiles = vec![("00042".to_string(), &tile)];
        let spec = GridSpec {
            rows: 1,
            cols: 1,
            frames: 1,
        };
        let (img, _) = render_grid_with_placements(&tiles, &spec, &small_opts(400)).unwrap();
        let label = (0..60u32).flat_map(|y| (0..150u32).map(move |x| (x, y)));
        let (mut white, mut red) = (0, 0);
        for (x, y) in label {
            let p = img.get_pixel(x, y);
            white += usize::from(p.0 == [255, 255, 255]);
            red += usize::from(p.0 == [255, 0, 0]);
        }
        assert!(
            white > 100 && red > 100,
            "shade {shade:?}: white {white} red {red}"
        );
    }
}

#[test]
fn bad_input_is_an_error() {
    let tile = RgbImage::new(10, 10);
    let tiles: Vec<(String, &RgbImage)> = (0..5).map(|i| (i.to_string(), &tile)).collect();
    let spec = GridSpec {
        rows: 4,
        cols: 1,
        frames: 5,
    };
    assert!(render_grid_with_placements(&tiles, &spec, &small_opts(64)).is_err());
    assert!(render_grid_with_placements(&[], &spec, &small_opts(64)).is_err());
}

#[test]
fn jpeg_round_trip() {
    let mut img = RgbImage::from_pixel(120, 80, Rgb([200, 30, 30]));
    for x in 60..120 {
        for y in 0..80 {
            img.put_pixel(x, y, Rgb([20, 20, 220]));
        }
    }
    let jpeg = encode_jpeg(&img, 90).unwrap();
    assert_eq!(&jpeg[..2], &[0xFF, 0xD8]);
    let back = decode_image(&jpeg).unwrap();
    assert_eq!(back.dimensions(), (120, 80));
    let p = back.get_pixel(20, 40);
    assert!(p.0[0] > 170 && p.0[2] < 70, "{p:?}");
    let p = back.get_pixel(100, 40);
    assert!(p.0[2] > 190 && p.0[0] < 60, "{p:?}");
}

#[test]
fn stitch_all_follows_the_plan_and_keeps_order() {
    let imgs: Vec<RgbImage> = (0..40)
        .map(|i| RgbImage::from_pixel(64, 48, Rgb([i as u8 * 5, 80, 80])))
        .collect();
    let frames: Vec<(String, &RgbImage)> = imgs
        .iter()
        .enumerate()
        .map(|(i, im)| (format!("{i:05}"), im))
        .collect();
    let out = stitch_all(&frames, 6, &small_opts(256)).unwrap();
    let specs = plan(40, 6);
    assert_eq!(out.len(), specs.len());
    let ids: Vec<String> = out.iter().flat_map(|s| s.image_ids.clone()).collect();
    let want: Vec<String> = (0..40).map(|i| format!("{i:05}")).collect();
    assert_eq!(ids, want);
    for (s, spec) in out.iter().zip(&specs) {
        assert_eq!(s.spec, *spec);
        assert_eq!(s.width.max(s.height), 256);
        let back = decode_image(&s.jpeg).unwrap();
        assert_eq!(back.dimensions(), (s.width, s.height));
        assert!(s.data_url().starts_with("data:image/jpeg;base64,/9j/"));
    }
}

#[test]
fn instance_ids_are_white_on_black_at_box_centres() {
    let img = RgbImage::from_pixel(400, 300, Rgb([0, 120, 200]));
    let boxes = vec![
        ("0".to_string(), [20.0, 20.0, 120.0, 100.0]),
        ("1".to_string(), [250.0, 150.0, 390.0, 290.0]),
    ];
    let opts = AnnotateOptions {
        max_side: None,
        label_height_frac: 0.06,
        ..Default::default()
    };
    let out = annotate_instances(&img, &boxes, &opts).unwrap();
    assert_eq!(out.dimensions(), (400, 300));
    for (_, b) in &boxes {
        let (cx, cy) = (((b[0] + b[2]) / 2.0) as u32, ((b[1] + b[3]) / 2.0) as u32);
        let (mut white, mut black) = (0, 0);
        for y in cy - 12..cy + 12 {
            for x in cx - 30..cx + 30 {
                let p = img_px(&out, x, y);
                white += usize::from(p == [255, 255, 255]);
                black += usize::from(p == [0, 0, 0]);
            }
        }
        assert!(
            white > 20 && black > 50,
            "box {b:?}: white {white} black {black}"
        );
        // Box corners are untouched without outlines.
        assert_eq!(
            img_px(&out, b[0] as u32 + 1, b[1] as u32 + 1),
            [0, 120, 200]
        );
    }
    // Far from any box: untouched.
    assert_eq!(img_px(&out, 200, 10), [0, 120, 200]);
    // With outlines and resizing to 800 px.
    let opts = AnnotateOptions {
        max_side: Some(800),
        draw_boxes: true,
        ..Default::default()
    };
    let out = annotate_instances(&img, &boxes, &opts).unwrap();
    assert_eq!(out.dimensions(), (800, 600));
    assert_eq!(img_px(&out, 40, 100), [0, 255, 0]);
    assert_eq!(img_px(&out, 500, 400), [0, 255, 0]);
}

fn img_px(img: &RgbImage, x: u32, y: u32) -> [u8; 3] {
    img.get_pixel(x, y).0
}

/// Writes `docs/stitch-example.png` (all stitched images of 40 synthetic frames, L = 6) for
/// a look by eye. Run with `GROUNDER_WRITE_DOCS=1 cargo test --test suite stitch_render -- --ignored`.
#[test]
#[ignore]
fn write_contact_sheet() {
    if std::env::var("GROUNDER_WRITE_DOCS").is_err() {
        return;
    }
    let frames = grounder::stitch::retrieval::synthetic_pool(40, 648, 484, 7);
    let tiles: Vec<(String, &RgbImage)> = frames
        .iter()
        .enumerate()
        .map(|(i, f)| (format!("{:05}", i * 13), f))
        .collect();
    let opts = StitchOptions {
        max_side: 480,
        jpeg_quality: 85,
        ..StitchOptions::default()
    };
    let out = stitch_all(&tiles, 6, &opts).unwrap();
    let imgs: Vec<RgbImage> = out.iter().map(|s| decode_image(&s.jpeg).unwrap()).collect();
    // Flow layout, 10 px gaps, rows at most 1100 px wide.
    let (gap, max_w) = (10u32, 1100u32);
    let mut rows: Vec<Vec<&RgbImage>> = vec![vec![]];
    let mut w = gap;
    for im in &imgs {
        if w + im.width() + gap > max_w && !rows.last().unwrap().is_empty() {
            rows.push(vec![]);
            w = gap;
        }
        rows.last_mut().unwrap().push(im);
        w += im.width() + gap;
    }
    let height: u32 = rows
        .iter()
        .map(|r| r.iter().map(|i| i.height()).max().unwrap() + gap)
        .sum();
    let mut sheet = RgbImage::from_pixel(max_w, height + gap, Rgb([64, 64, 64]));
    let mut y = gap;
    for r in &rows {
        let mut x = gap;
        for im in r {
            image::imageops::replace(&mut sheet, *im, x as i64, y as i64);
            x += im.width() + gap;
        }
        y += r.iter().map(|i| i.height()).max().unwrap() + gap;
    }
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/stitch-example.png");
    sheet.save(&path).unwrap();
}
