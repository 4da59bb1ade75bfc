//! Camera path: a loop at head height that looks across the room from every side, so
//! each object is seen from several views.

use super::build::look_along;
use super::room::World;
use nalgebra::{Matrix4, Point3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::TAU;

/// Camera-to-aligned-world poses (OpenCV axes) of `frames` views.
pub(crate) fn camera_path(world: &World, frames: usize, seed: u64) -> Vec<Matrix4<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x00ca_3e7a);
    let (w, d, _) = world.size;
    let (cx, cy) = (w / 2.0, d / 2.0);
    let (rx, ry) = ((w / 2.0 - 1.0).max(0.3), (d / 2.0 - 1.0).max(0.3));
    let phase = rng.gen_range(0.0..TAU);
    let height = rng.gen_range(1.45..1.6);
    let sway = rng.gen_range(0.35..0.7);
    (0..frames)
        .map(|i| {
            let s = i as f64 / frames as f64;
            let phi = phase + TAU * s;
            let eye = Point3::new(
                cx + rx * phi.cos(),
                cy + ry * phi.sin(),
                height + 0.04 * (3.0 * phi).sin(),
            );
            // Look across the room, swinging left and right of the centre.
            let yaw = phi + std::f64::consts::PI + sway * (2.0 * TAU * s + 0.7).sin();
            let pitch = -0.35 + 0.12 * (3.0 * TAU * s).cos();
            look_along(eye, yaw, pitch)
        })
        .collect()
}
