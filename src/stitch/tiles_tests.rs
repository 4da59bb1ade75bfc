//! Tests of [`super`]: grids from files equal the decoded stitch, with and without the
//! cache, and the cache's bounds.

use super::*;
use crate::stitch::{decode_image, plan, stitch_with_specs};

fn picture(w: u32, h: u32, seed: u32) -> RgbImage {
    RgbImage::from_fn(w, h, |x, y| {
        let v = (x * 7 + y * 13 + seed * 31) ^ (x * y + seed);
        image::Rgb([
            (v % 251) as u8,
            ((v / 3) % 241) as u8,
            ((x + seed) % 256) as u8,
        ])
    })
}

/// JPEG files of mixed sizes, and the images decoded from them.
fn files(dir: &Path, n: usize) -> (Vec<PathBuf>, Vec<RgbImage>) {
    let mut paths = Vec::new();
    let mut decoded = Vec::new();
    for i in 0..n {
        let (w, h) = if i % 3 == 0 { (160, 120) } else { (121, 97) };
        let jpeg = encode_jpeg(&picture(w, h, i as u32), 90).unwrap();
        let p = dir.join(format!("{i}.jpg"));
        std::fs::write(&p, &jpeg).unwrap();
        decoded.push(decode_image(&jpeg).unwrap());
        paths.push(p);
    }
    (paths, decoded)
}

fn reference(
    decoded: &[RgbImage],
    ids: &[String],
    specs: &[GridSpec],
    o: &StitchOptions,
) -> Vec<Vec<u8>> {
    let refs: Vec<(String, &RgbImage)> = ids.iter().cloned().zip(decoded).collect();
    stitch_with_specs(&refs, specs, o)
        .unwrap()
        .into_iter()
        .map(|g| g.jpeg)
        .collect()
}

#[test]
fn grids_from_files_equal_the_decoded_stitch_with_and_without_cached_tiles() {
    let dir = tempfile::tempdir().unwrap();
    let (paths, decoded) = files(dir.path(), 11);
    let ids: Vec<String> = (0..11).map(|i| format!("{i:05}")).collect();
    for o in [
        StitchOptions::default(),
        StitchOptions {
            max_side: 300,
            upscale: false,
            resize_filter: ResizeFilter::Bilinear,
            ..StitchOptions::default()
        },
    ] {
        let specs = plan(paths.len(), 4);
        let want = reference(&decoded, &ids, &specs, &o);
        let cache = TileCache::default();
        let (first, s1) = stitch_files(&paths, &ids, &specs, &o, &cache).unwrap();
        assert_eq!(
            (s1.tiles_cached, s1.frames_cached, s1.grids_cached),
            (0, 0, 0)
        );
        // Each file's tile and decoded frame, and the grids.
        assert_eq!(cache.len(), 11 + 11 + specs.len());
        // The same grids again: taken whole.
        let (second, s2) = stitch_files(&paths, &ids, &specs, &o, &cache).unwrap();
        assert_eq!((s2.tiles_cached, s2.grids_cached), (0, specs.len()));
        // Other labels: the grids are drawn again from the cached tiles.
        let relabelled = StitchOptions {
            label_color: [0, 0, 255],
            ..o.clone()
        };
        let (third, s3) = stitch_files(&paths, &ids, &specs, &relabelled, &cache).unwrap();
        assert_eq!((s3.tiles_cached, s3.grids_cached), (11, 0));
        let want3 = reference(&decoded, &ids, &specs, &relabelled);
        for (k, w) in want.iter().enumerate() {
            assert!(first[k].jpeg == *w, "grid {k} differs (uncached)");
            assert!(second[k].jpeg == *w, "grid {k} differs (cached grid)");
            assert!(third[k].jpeg == want3[k], "grid {k} differs (cached tiles)");
            assert_ne!(want3[k], *w);
        }
        assert_eq!(first[0].image_ids, ids[..specs[0].frames as usize].to_vec());
        // Another plan of the same files: other tile sizes, resized from the decoded
        // frames kept, and the same grids as without a cache (these tiles are small
        // enough for a reduced DCT scale under the smaller `max_side`, so not the
        // full decode's grids there).
        let specs = plan(5, 1);
        let (want, _) =
            stitch_files(&paths[..5], &ids[..5], &specs, &o, &TileCache::new(0)).unwrap();
        let want: Vec<Vec<u8>> = want.into_iter().map(|g| g.jpeg).collect();
        let (g, s) = stitch_files(&paths[..5], &ids[..5], &specs, &o, &cache).unwrap();
        // Under the default options every tile is decoded at full scale, in both
        // layouts; under the smaller `max_side` the two layouts' tiles take other DCT
        // scales, so no decoded frame fits.
        let hits = if o == StitchOptions::default() { 5 } else { 0 };
        assert_eq!(
            (s.tiles_cached, s.frames_cached, s.grids_cached),
            (0, hits, 0)
        );
        assert!(g.iter().zip(&want).all(|(g, w)| g.jpeg == *w));
    }
}

#[test]
fn paste_writes_what_replace_writes() {
    let tile = picture(7, 5, 3);
    for (x, y) in [(0, 0), (2, 3), (9, 6), (13, 1), (20, 20)] {
        let mut a = picture(15, 9, 1);
        let mut b = a.clone();
        paste(&mut a, &tile, x, y);
        image::imageops::replace(&mut b, &tile, i64::from(x), i64::from(y));
        assert!(a == b, "at {x},{y}");
    }
}

#[test]
fn the_cache_stays_within_its_bytes_and_never_serves_a_rewritten_file() {
    let dir = tempfile::tempdir().unwrap();
    let (paths, _) = files(dir.path(), 6);
    let ids: Vec<String> = (0..6).map(|i| format!("{i:05}")).collect();
    let o = StitchOptions {
        max_side: 200,
        ..StitchOptions::default()
    };
    let specs = plan(6, 6);
    // Everything one stitch keeps, then half of that as the bound.
    let all = TileCache::default();
    stitch_files(&paths, &ids, &specs, &o, &all).unwrap();
    let half = all.bytes() / 2;
    let cache = TileCache::new(half);
    stitch_files(&paths, &ids, &specs, &o, &cache).unwrap();
    assert!(cache.bytes() <= half, "{} > {half}", cache.bytes());
    assert!(
        !cache.is_empty() && cache.len() < all.len(),
        "{}",
        cache.len()
    );
    // Nothing is kept under a bound of 0.
    let none = TileCache::new(0);
    let (_, s) = stitch_files(&paths, &ids, &specs, &o, &none).unwrap();
    assert_eq!((s.tiles_cached, none.len()), (0, 0));

    // A file rewritten with other content (and size) is decoded again.
    let cache = TileCache::default();
    stitch_files(&paths, &ids, &specs, &o, &cache).unwrap();
    let jpeg = encode_jpeg(&picture(160, 120, 99), 70).unwrap();
    std::fs::write(&paths[0], &jpeg).unwrap();
    let (g, s) = stitch_files(&paths, &ids, &specs, &o, &cache).unwrap();
    // Its grid is drawn again from the other cached tiles; the other grids come whole.
    let first = specs[0].frames as usize;
    assert_eq!(
        (s.tiles_cached, s.grids_cached),
        (first - 1, specs.len() - 1)
    );
    // Its grid is the one an empty cache draws. These tiles are a third of their
    // frames or less, so they are decoded at half scale (`decode_at_least`) and the grid
    // is no longer the full-size decode's to the byte: it looks the same.
    let (fresh, _) = stitch_files(&paths, &ids, &specs, &o, &TileCache::new(0)).unwrap();
    assert!(g[0].jpeg == fresh[0].jpeg);
    let decoded: Vec<RgbImage> = paths
        .iter()
        .map(|p| decode_image(&std::fs::read(p).unwrap()).unwrap())
        .collect();
    let full = decode_image(&reference(&decoded, &ids, &specs, &o)[0]).unwrap();
    let ours = decode_image(&g[0].jpeg).unwrap();
    assert_eq!(full.dimensions(), ours.dimensions());
    let diff = full
        .as_raw()
        .iter()
        .zip(ours.as_raw())
        .map(|(&a, &b)| f64::from(a.abs_diff(b)))
        .sum::<f64>()
        / full.as_raw().len() as f64;
    // The test pictures are close to noise, where two ways of scaling down differ most
    // (two unrelated such pictures differ by about 85 a channel).
    assert!(diff < 12.0, "mean difference {diff}");
    // A missing file is an error naming it.
    let gone = vec![dir.path().join("nope.jpg")];
    let e = stitch_files(&gone, &ids[..1], &plan(1, 6), &o, &cache).unwrap_err();
    assert!(format!("{e:#}").contains("nope.jpg"), "{e:#}");
    assert!(e.downcast_ref::<UnreadableFile>().is_some(), "{e:#}");
}
