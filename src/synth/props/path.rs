//! Camera path of the props family: a walk around the room whose eye height and pitch
//! vary, interrupted by close-ups where the camera stops 0.6–1.5 m from an object and
//! looks at it from a random side.

use super::layout::PropWorld;
use crate::geometry::camera::look_at_pose;
use crate::synth::build::look_along;
use nalgebra::{Matrix4, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::TAU;

/// Every how many frames a close-up pair starts (frames k, k+1 of each block of this size).
const BLOCK: usize = 5;

/// Camera-to-aligned-world poses (OpenCV axes) of `frames` views.
pub(crate) fn camera_path(world: &PropWorld, frames: usize, seed: u64) -> Vec<Matrix4<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0c10_5e0f);
    let (w, d, _) = world.size;
    let (cx, cy) = (w / 2.0, d / 2.0);
    let phase = rng.gen_range(0.0..TAU);
    let dir = if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
    // Close-up targets: objects in a random order, walls' flat things included.
    let mut order: Vec<usize> = (0..world.objects.len()).collect();
    for i in (1..order.len()).rev() {
        order.swap(i, rng.gen_range(0..=i));
    }
    let mut next_target = 0usize;
    let mut out = Vec::with_capacity(frames);
    for i in 0..frames {
        let s = i as f64 / frames as f64;
        let close = i % BLOCK >= BLOCK - 2 && !order.is_empty() && frames >= BLOCK;
        if close {
            if let Some(p) = close_up(world, &order, &mut next_target, &mut rng) {
                out.push(p);
                continue;
            }
        }
        out.push(loop_pose(world, cx, cy, phase + dir * TAU * s, s, &mut rng));
    }
    out
}

/// A view from the loop: eye on an ellipse inside the room, looking across it.
fn loop_pose(
    world: &PropWorld,
    cx: f64,
    cy: f64,
    phi: f64,
    s: f64,
    rng: &mut ChaCha8Rng,
) -> Matrix4<f64> {
    let (w, d, _) = world.size;
    let (rx, ry) = ((w / 2.0 - 0.9).max(0.3), (d / 2.0 - 0.9).max(0.3));
    let height = rng.gen_range(1.3..1.75);
    let mut eye = Point3::new(cx + rx * phi.cos(), cy + ry * phi.sin(), height);
    // Step towards the centre until the eye is clear of furniture.
    for _ in 0..20 {
        if !world.blocked([eye.x, eye.y, eye.z], 0.25) {
            break;
        }
        eye.x += (cx - eye.x) * 0.15;
        eye.y += (cy - eye.y) * 0.15;
    }
    let yaw = phi + std::f64::consts::PI + rng.gen_range(-0.7..0.7) + 0.3 * (2.0 * TAU * s).sin();
    let pitch: f64 = rng.gen_range(-0.65..-0.15);
    look_along(eye, yaw, pitch)
}

/// A view 0.6–1.5 m from the next target that can be reached with a free eye.
fn close_up(
    world: &PropWorld,
    order: &[usize],
    next: &mut usize,
    rng: &mut ChaCha8Rng,
) -> Option<Matrix4<f64>> {
    for _ in 0..order.len() {
        let o = &world.objects[order[*next % order.len()]];
        *next += 1;
        let c = o.aabb.center();
        for _ in 0..25 {
            let dist = rng.gen_range(0.6..1.5);
            let az = rng.gen_range(0.0..TAU);
            let height = (c[2] + rng.gen_range(0.3..0.9)).clamp(0.9, 1.8);
            let horiz = (dist * dist - (height - c[2]).powi(2)).max(0.09).sqrt();
            let eye = Point3::new(c[0] + horiz * az.cos(), c[1] + horiz * az.sin(), height);
            if world.blocked([eye.x, eye.y, eye.z], 0.2) {
                continue;
            }
            // Look at the object, a little off-centre.
            let target = Point3::new(
                c[0] + rng.gen_range(-0.1..0.1),
                c[1] + rng.gen_range(-0.1..0.1),
                c[2] + rng.gen_range(-0.1..0.1),
            );
            let dir = target - eye;
            if dir.xy().norm() < 0.1 {
                continue;
            }
            return Some(look_at_pose(eye, target, Vector3::z()));
        }
    }
    None
}
