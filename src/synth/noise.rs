//! `--noise realistic`: the imperfections of a consumer RGB-D sensor and its tracking.
//! Every random draw is a hash of (seed, frame, pixel), so frames render in any order and
//! the output stays byte-identical.

use super::render::{hash, hash_u64, DepthFrame};
use super::{Noise, SynthParams};
use nalgebra::{Matrix4, Rotation3, Vector3};
use rand::seq::index::sample;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Depth readings beyond this distance are dropped (sensor range).
pub(crate) const DEPTH_CUTOFF_M: f64 = 5.0;

/// Frames whose pose file is written as inf (about 1 in 25, at least one; never frame 0).
pub(crate) fn invalid_pose_frames(params: &SynthParams) -> Vec<usize> {
    if params.noise != Noise::Realistic || params.frames < 4 {
        return Vec::new();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(params.seed ^ 0x001f_b05e);
    let n = (params.frames / 25).max(1);
    let mut v: Vec<usize> = sample(&mut rng, params.frames - 1, n)
        .into_iter()
        .map(|i| i + 1)
        .collect();
    v.sort_unstable();
    v
}

/// Approximately standard normal draw from one hash: the sum of four 16-bit uniforms
/// (Irwin–Hall), rescaled to unit variance. Cheap enough for every colour channel.
fn gauss(seed: u64, a: i64, b: i64) -> f64 {
    let h = hash_u64(a, b, 11, seed);
    let s: u64 = (0..4).map(|k| (h >> (16 * k)) & 0xFFFF).sum();
    (s as f64 / 65535.0 - 2.0) * 3f64.sqrt()
}

/// Distance-dependent noise, flying pixels at depth edges, holes (grazing angles, random
/// blobs) and a range cut-off, applied in place.
pub(crate) fn depth_noise(d: &mut DepthFrame, seed: u64, frame: usize) {
    let (w, h) = (d.width as usize, d.height as usize);
    let seed = seed.wrapping_mul(31).wrapping_add(frame as u64 * 7919 + 1);
    let z: Vec<f64> = d.mm.iter().map(|&m| m as f64 / 1000.0).collect();
    let blobs: Vec<(f64, f64, f64)> = (0..(2 + (hash(0, 0, 1, seed) * 4.0) as i64))
        .map(|k| {
            (
                hash(k, 1, 2, seed) * w as f64,
                hash(k, 2, 2, seed) * h as f64,
                (0.01 + 0.03 * hash(k, 3, 2, seed)) * w as f64,
            )
        })
        .collect();
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let mut zi = z[i];
            if zi <= 0.0 {
                continue;
            }
            // Flying pixel: a mix of the two sides of a depth edge.
            for j in [
                if x + 1 < w { Some(i + 1) } else { None },
                if y + 1 < h { Some(i + w) } else { None },
            ]
            .into_iter()
            .flatten()
            {
                if (z[j] - z[i]).abs() > 0.1 && hash(x as i64, y as i64, 3, seed) < 0.5 {
                    zi = z[i] + (z[j] - z[i]) * (0.2 + 0.6 * hash(x as i64, y as i64, 4, seed));
                    break;
                }
            }
            let sigma = 0.0012 + 0.0019 * (zi - 0.4).powi(2);
            zi += sigma * gauss(seed, x as i64, y as i64);
            let in_blob = blobs
                .iter()
                .any(|&(bx, by, r)| (x as f64 - bx).powi(2) + (y as f64 - by).powi(2) < r * r);
            let grazing = d.cos[i] < 0.12;
            d.mm[i] = if in_blob || grazing || zi > DEPTH_CUTOFF_M || zi <= 0.0 {
                0
            } else {
                (zi * 1000.0).round().min(65535.0) as u16
            };
        }
    }
}

/// Sensor noise on the 8-bit colour image (about 2 grey levels).
pub(crate) fn color_noise(rgb: &mut [u8], seed: u64, frame: usize) {
    let seed = seed
        .wrapping_mul(131)
        .wrapping_add(frame as u64 * 104_729 + 3);
    for (i, c) in rgb.iter_mut().enumerate() {
        let n = 2.0 * gauss(seed, i as i64, 0);
        *c = (*c as f64 + n).round().clamp(0.0, 255.0) as u8;
    }
}

/// Small tracking error: about 0.3 degrees of rotation and 4 mm of translation.
pub(crate) fn jitter_pose(pose: &Matrix4<f64>, seed: u64, frame: usize) -> Matrix4<f64> {
    let s = seed.wrapping_mul(7).wrapping_add(frame as u64 * 613 + 5);
    let g = |k: i64| gauss(s, k, 9);
    let axis_angle = Vector3::new(g(0), g(1), g(2)) * 0.3f64.to_radians() / 3f64.sqrt();
    let rot = Rotation3::new(axis_angle);
    let mut delta = Matrix4::identity();
    delta.fixed_view_mut::<3, 3>(0, 0).copy_from(rot.matrix());
    delta
        .fixed_view_mut::<3, 1>(0, 3)
        .copy_from(&(Vector3::new(g(3), g(4), g(5)) * 0.004));
    pose * delta
}
