//! Stitching speed: plan + render + JPEG-encode 48 decoded 1296x968 frames into 6 grids
//! (target < 150 ms on 2 cores), and the same including JPEG decode from disk.

use criterion::{criterion_group, criterion_main, Criterion};
use grounder::stitch::{
    decode_image, encode_jpeg, load_frames, make_preview, plan, render_grid, stitch_all,
    stitch_with_specs, tile_scales, use_previews, ResizeFilter, StitchOptions,
};
use image::{Rgb, RgbImage};
use rand::{Rng, SeedableRng};

/// A frame with smooth gradients, blocks and noise, so JPEG and resizing do real work.
fn synthetic_frame(seed: u64) -> RgbImage {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let (w, h) = (1296u32, 968u32);
    let mut img = RgbImage::from_fn(w, h, |x, y| {
        Rgb([
            (x * 255 / w) as u8,
            (y * 255 / h) as u8,
            ((x + y + seed as u32 * 37) % 256) as u8,
        ])
    });
    for _ in 0..12 {
        let (x0, y0) = (rng.gen_range(0..w - 200), rng.gen_range(0..h - 200));
        let c = Rgb([rng.gen(), rng.gen(), rng.gen()]);
        for y in y0..y0 + rng.gen_range(50..200) {
            for x in x0..x0 + rng.gen_range(50..200) {
                img.put_pixel(x, y, c);
            }
        }
    }
    for p in img.pixels_mut() {
        let n: i16 = rng.gen_range(-6..=6);
        p.0[0] = (i16::from(p.0[0]) + n).clamp(0, 255) as u8;
    }
    img
}

fn bench(c: &mut Criterion) {
    let frames: Vec<RgbImage> = (0..48).map(synthetic_frame).collect();
    let tiles: Vec<(String, &RgbImage)> = frames
        .iter()
        .enumerate()
        .map(|(i, f)| (format!("{:05}", i * 7), f))
        .collect();
    let opts = StitchOptions::default();
    assert_eq!(plan(48, 6).len(), 6);

    let mut g = c.benchmark_group("stitch");
    g.sample_size(20);
    g.bench_function("48_decoded_frames_to_6_jpeg_grids", |b| {
        b.iter(|| stitch_all(&tiles, 6, &opts).map(|v| v.len()).unwrap_or(0))
    });

    let fast = StitchOptions {
        resize_filter: ResizeFilter::Bilinear,
        ..opts.clone()
    };
    g.bench_function("48_decoded_frames_to_6_jpeg_grids_bilinear", |b| {
        b.iter(|| stitch_all(&tiles, 6, &fast).map(|v| v.len()).unwrap_or(0))
    });
    // Parts, for the breakdown: one (2, 4) grid rendered, and its JPEG encoding.
    let spec = plan(48, 6)[0];
    g.bench_function("render_one_2x4_grid", |b| {
        b.iter(|| {
            render_grid(&tiles[..8], &spec, &opts)
                .map(|i| i.width())
                .unwrap_or(0)
        })
    });
    let grid = render_grid(&tiles[..8], &spec, &opts).expect("render");
    g.bench_function("encode_one_grid_jpeg", |b| {
        b.iter(|| {
            encode_jpeg(&grid, opts.jpeg_quality)
                .map(|v| v.len())
                .unwrap_or(0)
        })
    });
    g.bench_function("decode_one_frame_jpeg", |b| {
        let jpeg = encode_jpeg(&frames[0], 90).expect("encode");
        b.iter(|| decode_image(&jpeg).map(|i| i.width()).unwrap_or(0))
    });
    g.bench_function("make_one_preview", |b| {
        b.iter(|| make_preview(&frames[0]).map(|v| v.len()).unwrap_or(0))
    });
    let dir = tempfile::tempdir().expect("temp dir");
    let paths: Vec<std::path::PathBuf> = frames
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let p = dir.path().join(format!("{i:05}.jpg"));
            std::fs::write(&p, encode_jpeg(f, 90).expect("encode")).expect("write");
            p
        })
        .collect();
    let ids: Vec<String> = (0..48).map(|i| format!("{:05}", i * 7)).collect();
    g.bench_function("48_jpeg_files_decode_and_stitch", |b| {
        b.iter(|| {
            let decoded = load_frames(&paths).expect("decode");
            let tiles: Vec<(String, &RgbImage)> = ids.iter().cloned().zip(decoded.iter()).collect();
            stitch_all(&tiles, 6, &opts).map(|v| v.len()).unwrap_or(0)
        })
    });
    // What the agent does: frames whose grid shows them at half size or less are read
    // from the previews indexing stored.
    let specs = plan(48, 6);
    let scales = tile_scales(&[(1296, 968); 48], &specs, &opts);
    let from_preview = use_previews(&scales, &specs, &[true; 48]);
    let sources: Vec<std::path::PathBuf> = paths
        .iter()
        .zip(&frames)
        .zip(&from_preview)
        .map(|((p, f), &pre)| {
            if !pre {
                return p.clone();
            }
            let q = p.with_extension("preview.jpg");
            std::fs::write(&q, make_preview(f).expect("preview")).expect("write");
            q
        })
        .collect();
    g.bench_function("48_jpeg_previews_decode_and_stitch", |b| {
        b.iter(|| {
            let decoded = load_frames(&sources).expect("decode");
            let tiles: Vec<(String, &RgbImage)> = ids.iter().cloned().zip(decoded.iter()).collect();
            stitch_with_specs(&tiles, &specs, &opts)
                .map(|v| v.len())
                .unwrap_or(0)
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
