//! Placement rules of the props layout: where a model may go (inside the room, clear of
//! other objects' parts and of keep-clear zones) and the ways of putting it there (against
//! a wall, anywhere on the floor, on another object's surface).

use super::layout::PropObject;
use super::models::{colours, model, Mat, Model, Surface, CLUTTER};
use super::prim::Shape;
use crate::geometry::Aabb;
use crate::synth::build::{overlaps, union};
use crate::synth::catalog::palette;
use rand::seq::SliceRandom;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// Horizontal distance from (x, y) to a box's footprint.
fn dist_xy(x: f64, y: f64, b: &Aabb) -> f64 {
    let dx = (b.min[0] - x).max(0.0).max(x - b.max[0]);
    let dy = (b.min[1] - y).max(0.0).max(y - b.max[1]);
    dx.hypot(dy)
}

/// Could two shapes touch (closer than `margin`)? Boxes of the shapes, refined for
/// frustums by their round footprint, so chairs can go under round tables.
pub(super) fn clash(a: &Shape, b: &Shape, margin: f64) -> bool {
    let (ba, bb) = (a.aabb(), b.aabb());
    if !overlaps(&ba, &bb, margin) {
        return false;
    }
    for (s, other) in [(a, &bb), (b, &ba)] {
        if let Shape::Frustum { x, y, r0, r1, .. } = *s {
            if dist_xy(x, y, other) >= r0.max(r1) + margin {
                return false;
            }
        }
    }
    true
}

pub(super) struct Builder {
    pub rng: ChaCha8Rng,
    pub w: f64,
    pub d: f64,
    pub h: f64,
    pub objects: Vec<PropObject>,
    /// Keep-clear zones (in front of the door).
    pub zones: Vec<Aabb>,
}

/// Wall yaw: the yaw that turns a model's back (+y) towards wall `k` (0: y = D, 1: y = 0,
/// 2: x = W, 3: x = 0).
fn wall_yaw(k: usize) -> f64 {
    [0.0, PI, -FRAC_PI_2, FRAC_PI_2][k]
}

impl Builder {
    pub(super) fn r(&mut self, a: f64, b: f64) -> f64 {
        self.rng.gen_range(a..b)
    }

    pub(super) fn colour(&mut self, label: &str) -> String {
        colours(label)
            .choose(&mut self.rng)
            .map_or("grey", |c| c)
            .to_string()
    }

    /// Can the placed shapes go in? Strict contact is allowed with `base` (the supporter).
    pub(super) fn fits(&self, shapes: &[(Shape, Mat)], base: Option<usize>) -> bool {
        let parts: Vec<Aabb> = shapes.iter().map(|(s, _)| s.aabb()).collect();
        let u = union(&parts);
        let inside = u.min[0] >= 0.0
            && u.min[1] >= 0.0
            && u.max[0] <= self.w
            && u.max[1] <= self.d
            && u.min[2] >= -1e-9
            && u.max[2] <= self.h - 0.05;
        if !inside || self.zones.iter().any(|z| overlaps(z, &u, 0.0)) {
            return false;
        }
        self.objects.iter().enumerate().all(|(i, o)| {
            let margin = if Some(i) == base { -1e-6 } else { 0.02 };
            !overlaps(&o.aabb, &u, margin)
                || !o
                    .shapes
                    .iter()
                    .any(|(a, _)| shapes.iter().any(|(b, _)| clash(a, b, margin)))
        })
    }

    pub(super) fn add(
        &mut self,
        label: &str,
        colour: &str,
        shapes: Vec<(Shape, Mat)>,
        surfaces: Vec<Surface>,
    ) -> usize {
        let parts: Vec<Aabb> = shapes.iter().map(|(s, _)| s.aabb()).collect();
        let u = union(&parts);
        // Micrometre coordinates, rounded outwards: short decimals that survive JSON.
        let aabb = Aabb::new(
            u.min.map(|x| (x * 1e6).floor() / 1e6),
            u.max.map(|x| (x * 1e6).ceil() / 1e6),
        );
        let mut rgb = palette(colour);
        for c in rgb.iter_mut() {
            *c = (*c * self.rng.gen_range(0.9..1.1)).clamp(0.0, 1.0);
        }
        self.objects.push(PropObject {
            id: self.objects.len() as u32 + 1,
            label: label.to_string(),
            colour: colour.to_string(),
            rgb,
            shapes,
            surfaces,
            parts,
            aabb,
        });
        self.objects.len() - 1
    }

    /// Place `m` turned by `yaw` and moved by `t` when it fits.
    pub(super) fn put(
        &mut self,
        label: &str,
        colour: &str,
        m: &Model,
        yaw: f64,
        t: [f64; 3],
        base: Option<usize>,
    ) -> Option<usize> {
        let shapes: Vec<(Shape, Mat)> = m
            .parts
            .iter()
            .map(|(s, k)| (s.placed(yaw, t), *k))
            .collect();
        if !self.fits(&shapes, base) {
            return None;
        }
        let surfaces = m.surfaces.iter().map(|s| s.placed(yaw, t)).collect();
        Some(self.add(label, colour, shapes, surfaces))
    }

    /// Against wall `wall` (random when None), back `gap` from it, turned by up to `jitter`
    /// off the wall, at height `z`; `along` fixes the centre's coordinate along the wall.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn at_wall(
        &mut self,
        label: &str,
        colour: &str,
        m: &Model,
        wall: Option<usize>,
        jitter: f64,
        z: f64,
        gap: f64,
        along: Option<f64>,
    ) -> Option<(usize, usize)> {
        for _ in 0..60 {
            let k = wall.unwrap_or_else(|| self.rng.gen_range(0..4));
            let yaw = wall_yaw(k)
                + if jitter > 0.0 {
                    self.r(-jitter, jitter)
                } else {
                    0.0
                };
            let b = union(
                &m.parts
                    .iter()
                    .map(|(s, _)| s.placed(yaw, [0.0; 3]).aabb())
                    .collect::<Vec<_>>(),
            );
            let (len, lo, hi) = if k < 2 {
                (self.w, b.min[0], b.max[0])
            } else {
                (self.d, b.min[1], b.max[1])
            };
            if hi - lo > len {
                return None;
            }
            let s = along.unwrap_or_else(|| self.rng.gen_range(-lo..(len - hi).max(-lo + 1e-6)));
            let t = match k {
                0 => [s, self.d - gap - b.max[1], z],
                1 => [s, gap - b.min[1], z],
                2 => [self.w - gap - b.max[0], s, z],
                _ => [gap - b.min[0], s, z],
            };
            if let Some(i) = self.put(label, colour, m, yaw, t, None) {
                return Some((i, k));
            }
            if along.is_some() {
                return None;
            }
        }
        None
    }

    /// Anywhere on the floor, any yaw.
    pub(super) fn free(&mut self, label: &str, colour: &str, m: &Model) -> Option<usize> {
        let rad = m.radius();
        for _ in 0..60 {
            let x = self.r(rad, (self.w - rad).max(rad + 1e-6));
            let y = self.r(rad, (self.d - rad).max(rad + 1e-6));
            let yaw = self.r(0.0, TAU);
            if let Some(i) = self.put(label, colour, m, yaw, [x, y, 0.0], None) {
                return Some(i);
            }
        }
        None
    }

    /// On one of `base`'s surfaces at a random point (at least the model's footprint radius
    /// inside, or `margin` when given), turned by `yaw` (random when None).
    pub(super) fn on(
        &mut self,
        label: &str,
        colour: &str,
        m: &Model,
        base: usize,
        yaw: Option<f64>,
        margin: Option<f64>,
    ) -> Option<usize> {
        let surfaces = self.objects[base].surfaces.clone();
        if surfaces.is_empty() {
            return None;
        }
        let rad = margin.unwrap_or_else(|| m.radius());
        for _ in 0..30 {
            let s = surfaces[self.rng.gen_range(0..surfaces.len())];
            let Some(p) = s.sample(rad, &mut self.rng) else {
                continue;
            };
            let yaw = yaw.unwrap_or_else(|| self.rng.gen_range(0.0..TAU));
            if let Some(i) = self.put(label, colour, m, yaw, [p[0], p[1], s.z()], Some(base)) {
                return Some(i);
            }
        }
        None
    }

    pub(super) fn clutter_on(&mut self, base: usize, n: usize) {
        for _ in 0..n {
            let label = *CLUTTER.choose(&mut self.rng).unwrap_or(&"box");
            let c = self.colour(label);
            let m = model(label, false, &mut self.rng);
            self.on(label, &c, &m, base, None, None);
        }
    }
}
