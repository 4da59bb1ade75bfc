//! Stitching from image files through a cache of resized tiles and encoded grids. A robot
//! asks many questions about one room, and the frames a query shows often came up before
//! (every query about chairs pre-selects the same frames): decoding a frame and resizing it
//! to its tile, or drawing and encoding the same grid, is then work done already.
//! [`TileCache`] keeps both, bounded in bytes, least recently used dropped first. A tile is
//! keyed by its file (path, size and modification time, so a rewritten file is never served
//! from an old tile), its size and the filter; a grid by its tiles, ids, layout and
//! options. [`stitch_files`] draws the same grids as [`super::stitch_with_specs`] on the
//! decoded files, to the byte.

use super::plan::{grid_starts, GridSpec};
use super::render::{
    check_grid, draw_labels, encode_jpeg, grid_layout, ResizeFilter, StitchOptions, StitchedImage,
    TilePlacement,
};
use anyhow::{Context, Result};
use image::RgbImage;
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Instant, SystemTime};

/// Default bound of the tile cache (`tile_cache_mb`).
pub const DEFAULT_TILE_CACHE_MB: u64 = 32;

/// What identifies a resized tile.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
struct TileKey {
    path: PathBuf,
    len: u64,
    modified: Option<SystemTime>,
    w: u32,
    h: u32,
    filter: ResizeFilter,
}

/// What identifies an encoded grid: its tiles, ids, layout and options.
#[derive(Debug, Clone, PartialEq)]
struct GridKey {
    tiles: Vec<TileKey>,
    ids: Vec<String>,
    spec: GridSpec,
    opts: StitchOptions,
}

#[derive(Debug, Clone, PartialEq)]
enum Key {
    Tile(TileKey),
    Grid(GridKey),
}

#[derive(Clone)]
enum Kept {
    Tile(Arc<RgbImage>),
    Grid(Arc<StitchedImage>),
}

impl Kept {
    fn bytes(&self) -> u64 {
        match self {
            Kept::Tile(t) => t.as_raw().len() as u64,
            Kept::Grid(g) => g.jpeg.len() as u64,
        }
    }
}

#[derive(Default)]
struct Inner {
    /// Least recently used first.
    kept: Vec<(Key, Kept)>,
    bytes: u64,
}

/// Resized tiles and encoded grids, bounded in bytes (see the module documentation).
/// 0 keeps nothing.
pub struct TileCache {
    max_bytes: u64,
    inner: Mutex<Inner>,
}

impl Default for TileCache {
    fn default() -> Self {
        Self::new(DEFAULT_TILE_CACHE_MB << 20)
    }
}

impl TileCache {
    pub fn new(max_bytes: u64) -> Self {
        Self {
            max_bytes,
            inner: Mutex::new(Inner::default()),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        // Every update leaves the list and its byte count consistent: a poisoned lock is
        // used as is.
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn get(&self, key: &Key) -> Option<Kept> {
        let mut g = self.lock();
        let pos = g.kept.iter().position(|(k, _)| k == key)?;
        let e = g.kept.remove(pos);
        let v = e.1.clone();
        g.kept.push(e);
        Some(v)
    }

    fn put(&self, key: Key, v: Kept) {
        let bytes = v.bytes();
        if bytes > self.max_bytes {
            return;
        }
        let mut g = self.lock();
        if let Some(pos) = g.kept.iter().position(|(k, _)| *k == key) {
            let (_, old) = g.kept.remove(pos);
            g.bytes -= old.bytes();
        }
        g.kept.push((key, v));
        g.bytes += bytes;
        while g.bytes > self.max_bytes && !g.kept.is_empty() {
            let (_, old) = g.kept.remove(0);
            g.bytes -= old.bytes();
        }
    }

    fn tile(&self, key: &TileKey) -> Option<Arc<RgbImage>> {
        match self.get(&Key::Tile(key.clone()))? {
            Kept::Tile(t) => Some(t),
            Kept::Grid(_) => None,
        }
    }

    fn grid(&self, key: &GridKey) -> Option<Arc<StitchedImage>> {
        match self.get(&Key::Grid(key.clone()))? {
            Kept::Grid(g) => Some(g),
            Kept::Tile(_) => None,
        }
    }

    /// Bytes kept (tiles' pixels and grids' JPEGs).
    pub fn bytes(&self) -> u64 {
        self.lock().bytes
    }

    /// Tiles and grids kept.
    pub fn len(&self) -> usize {
        self.lock().kept.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// What [`stitch_files`] did, for the trace.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StitchStats {
    /// Reading the files' headers, decoding and resizing the tiles not cached, ms.
    pub decode_ms: f64,
    /// Composing the grids, drawing the labels and encoding them, ms.
    pub render_ms: f64,
    /// Tiles taken from the cache (for grids not taken whole from it).
    pub tiles_cached: usize,
    /// Grids taken whole from the cache (same tiles, ids, layout and options).
    pub grids_cached: usize,
}

/// Milliseconds since `t`.
fn ms(t: Instant) -> f64 {
    (t.elapsed().as_secs_f64() * 1e6).round() / 1e3
}

/// The context of an error reading or decoding one of [`stitch_files`]'s files (callers
/// tell a stored frame that cannot be read from a stitching failure by it).
#[derive(Debug, thiserror::Error)]
#[error("cannot read or decode the image file {0}")]
pub struct UnreadableFile(pub PathBuf);

/// A file's cache identity and its image's size (from the header, not decoded).
fn probe(path: &Path) -> Result<(u64, Option<SystemTime>, (u32, u32))> {
    let meta =
        std::fs::metadata(path).with_context(|| format!("cannot read {}", path.display()))?;
    let dims = image::ImageReader::open(path)
        .and_then(|r| r.with_guessed_format())
        .with_context(|| format!("cannot read {}", path.display()))?
        .into_dimensions()
        .with_context(|| format!("cannot decode image in {}", path.display()))?;
    Ok((meta.len(), meta.modified().ok(), dims))
}

/// Decode `path` and resize it to `w` x `h` as [`super::render_grid`] draws a tile. A
/// JPEG is decoded at the smallest DCT scale still at least `w` x `h`
/// ([`super::decode::decode_at_least`]), so the tile depends on the file and its size only,
/// as its cache key says.
fn make_tile(path: &Path, w: u32, h: u32, filter: ResizeFilter) -> Result<RgbImage> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let img = super::decode::decode_at_least(&bytes, (w, h))
        .with_context(|| format!("in {}", path.display()))?;
    let mut tile = RgbImage::new(w, h);
    fast_image_resize::Resizer::new()
        .resize(&img, &mut tile, &filter.options())
        .context("cannot resize a tile")?;
    Ok(tile)
}

/// Copy `tile` into `out` with its top-left corner at (`x`, `y`), clipped to `out`: the
/// pixels `image::imageops::replace` writes, a row slice at a time rather than a pixel.
fn paste(out: &mut RgbImage, tile: &RgbImage, x: u32, y: u32) {
    let (ow, oh) = (out.width() as usize, out.height() as usize);
    let (x, y) = (x as usize, y as usize);
    let tw = tile.width() as usize;
    let w = tw.min(ow.saturating_sub(x));
    let h = (tile.height() as usize).min(oh.saturating_sub(y));
    if w == 0 {
        return;
    }
    let (dst, src) = (&mut **out, tile.as_raw());
    for r in 0..h {
        let d = ((y + r) * ow + x) * 3;
        let s = r * tw * 3;
        dst[d..d + w * 3].copy_from_slice(&src[s..s + w * 3]);
    }
}

/// Render and encode the image files `paths` (ids `ids`) into the grids `specs` (in order,
/// in parallel), taking resized tiles from `cache` and keeping the new ones there. The
/// grids equal [`super::stitch_with_specs`] over the decoded files.
pub fn stitch_files(
    paths: &[PathBuf],
    ids: &[String],
    specs: &[GridSpec],
    opts: &StitchOptions,
    cache: &TileCache,
) -> Result<(Vec<StitchedImage>, StitchStats)> {
    let t = Instant::now();
    let needed: usize = specs.iter().map(|s| s.frames as usize).sum();
    if needed != paths.len() || ids.len() != paths.len() {
        anyhow::bail!(
            "the plan holds {needed} frames but {} were given",
            paths.len()
        );
    }
    let probes: Vec<_> = paths
        .par_iter()
        .map(|p| probe(p).context(UnreadableFile(p.clone())))
        .collect::<Result<_>>()?;
    let dims: Vec<(u32, u32)> = probes.iter().map(|p| p.2).collect();
    // Each grid's size and each frame's place in it.
    let mut grids = Vec::with_capacity(specs.len());
    let mut rects = Vec::with_capacity(paths.len());
    for (spec, start) in specs.iter().zip(grid_starts(specs)) {
        let d = &dims[start..start + spec.frames as usize];
        check_grid(d, spec)?;
        let (w, h, r) = grid_layout(d, spec, opts);
        grids.push((w, h, start));
        rects.extend(r);
    }
    let keys: Vec<TileKey> = paths
        .iter()
        .zip(&probes)
        .zip(&rects)
        .map(|((p, pr), r)| TileKey {
            path: p.clone(),
            len: pr.0,
            modified: pr.1,
            w: r[2],
            h: r[3],
            filter: opts.resize_filter,
        })
        .collect();
    // Grids shown before (same tiles, ids, layout, options) come back whole.
    let grid_keys: Vec<GridKey> = specs
        .iter()
        .zip(&grids)
        .map(|(spec, &(_, _, start))| {
            let end = start + spec.frames as usize;
            GridKey {
                tiles: keys[start..end].to_vec(),
                ids: ids[start..end].to_vec(),
                spec: *spec,
                opts: opts.clone(),
            }
        })
        .collect();
    let whole: Vec<Option<Arc<StitchedImage>>> = grid_keys.iter().map(|k| cache.grid(k)).collect();
    // The tiles of the other grids: from the cache, else decoded and resized.
    let mut wanted = vec![false; keys.len()];
    for ((spec, &(_, _, start)), w) in specs.iter().zip(&grids).zip(&whole) {
        if w.is_none() {
            wanted[start..start + spec.frames as usize].fill(true);
        }
    }
    let cached: Vec<Option<Arc<RgbImage>>> = keys
        .iter()
        .zip(&wanted)
        .map(|(k, &w)| if w { cache.tile(k) } else { None })
        .collect();
    let tiles_cached = cached.iter().filter(|c| c.is_some()).count();
    let tiles: Vec<Option<Arc<RgbImage>>> = keys
        .par_iter()
        .zip(cached)
        .zip(&wanted)
        .map(|((k, c), &w)| match c {
            Some(t) => Ok(Some(t)),
            None if !w => Ok(None),
            None => {
                let t = make_tile(&k.path, k.w, k.h, k.filter)
                    .context(UnreadableFile(k.path.clone()))?;
                let t = Arc::new(t);
                cache.put(Key::Tile(k.clone()), Kept::Tile(t.clone()));
                Ok(Some(t))
            }
        })
        .collect::<Result<_>>()?;
    let decode_ms = ms(t);
    let t = Instant::now();
    let grids_cached = whole.iter().filter(|w| w.is_some()).count();
    let images = specs
        .par_iter()
        .zip(grids)
        .zip(whole)
        .zip(grid_keys)
        .map(|(((spec, (w, h, start)), whole), key)| {
            if let Some(g) = whole {
                return Ok(g.as_ref().clone());
            }
            let end = start + spec.frames as usize;
            let mut out = RgbImage::from_pixel(w, h, image::Rgb(opts.background));
            let mut placements = Vec::with_capacity(end - start);
            for ((&[x, y, tw, th], tile), id) in rects[start..end]
                .iter()
                .zip(&tiles[start..end])
                .zip(&ids[start..end])
            {
                let tile = tile
                    .as_ref()
                    .context("a tile of a grid to draw was not made")?;
                paste(&mut out, tile, x, y);
                placements.push(TilePlacement {
                    image_id: id.clone(),
                    x,
                    y,
                    w: tw,
                    h: th,
                });
            }
            draw_labels(&mut out, &placements, opts);
            let jpeg = encode_jpeg(&out, opts.jpeg_quality)?;
            let img = StitchedImage {
                jpeg,
                width: w,
                height: h,
                image_ids: ids[start..end].to_vec(),
                spec: *spec,
            };
            cache.put(Key::Grid(key), Kept::Grid(Arc::new(img.clone())));
            Ok(img)
        })
        .collect::<Result<Vec<_>>>()?;
    let stats = StitchStats {
        decode_ms,
        render_ms: ms(t),
        tiles_cached,
        grids_cached,
    };
    Ok((images, stats))
}

#[cfg(test)]
mod tests {
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
            assert_eq!((s1.tiles_cached, s1.grids_cached), (0, 0));
            assert_eq!(cache.len(), 11 + specs.len());
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
            // Another plan of the same files reuses nothing it should not.
            let specs = plan(5, 6);
            let want = reference(&decoded[..5], &ids[..5], &specs, &o);
            let (g, _) = stitch_files(&paths[..5], &ids[..5], &specs, &o, &cache).unwrap();
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
}
