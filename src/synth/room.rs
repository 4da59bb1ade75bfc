//! Room layout: furniture of realistic sizes, labels and colour names, placed without
//! overlap in the aligned (output) frame. x in [0, W], y in [0, D], z up from the floor.

use super::build::{alignment, overlaps, union};
use super::catalog::{colours_for, palette, parts_of, size_of, Part};
use super::SynthObject;
use crate::geometry::Aabb;
use nalgebra::{Matrix4, Vector3};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The generated room in the aligned frame plus the axis alignment written to disk.
pub(crate) struct World {
    /// (W, D, H) in metres.
    pub size: (f64, f64, f64),
    pub objects: Vec<SynthObject>,
    /// World -> aligned.
    pub align: Matrix4<f64>,
    /// Aligned -> world.
    pub align_inv: Matrix4<f64>,
}

impl World {
    pub fn output_objects(&self) -> Vec<SynthObject> {
        self.objects.clone()
    }
}

/// Which way the object's back points (local +y is its back).
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Facing {
    /// back towards +y
    N,
    /// back towards -y
    S,
    /// back towards +x
    E,
    /// back towards -x
    W,
}

/// Map local parts to aligned-frame boxes with the footprint's min corner at (x0, y0, z0).
fn orient(parts: &[Part], w: f64, d: f64, facing: Facing, origin: [f64; 3]) -> Vec<Aabb> {
    parts
        .iter()
        .map(|(lo, hi)| {
            let map = |x: f64, y: f64| -> (f64, f64) {
                match facing {
                    Facing::N => (x, y),
                    Facing::S => (w - x, d - y),
                    Facing::E => (y, w - x),
                    Facing::W => (d - y, x),
                }
            };
            let (ax, ay) = map(lo[0], lo[1]);
            let (bx_, by) = map(hi[0], hi[1]);
            Aabb::new(
                [
                    ax.min(bx_) + origin[0],
                    ay.min(by) + origin[1],
                    lo[2] + origin[2],
                ],
                [
                    ax.max(bx_) + origin[0],
                    ay.max(by) + origin[1],
                    hi[2] + origin[2],
                ],
            )
        })
        .collect()
}

struct Builder {
    rng: ChaCha8Rng,
    w: f64,
    d: f64,
    h: f64,
    objects: Vec<SynthObject>,
    /// Keep-clear zones (in front of the door) that new objects must not intersect.
    zones: Vec<Aabb>,
}

impl Builder {
    fn free(&self, b: &Aabb) -> bool {
        b.min[0] >= -1e-9
            && b.min[1] >= -1e-9
            && b.max[0] <= self.w + 1e-9
            && b.max[1] <= self.d + 1e-9
            && b.max[2] <= self.h - 0.05
            && !self
                .objects
                .iter()
                .map(|o| &o.aabb)
                .chain(self.zones.iter())
                .any(|o| overlaps(o, b, 0.03))
    }

    fn add(&mut self, label: &str, colour: &str, mut parts: Vec<Aabb>) -> usize {
        // Micrometre coordinates: short decimals that survive a JSON round trip exactly.
        let um = |x: f64| (x * 1e6).round() / 1e6;
        for p in parts.iter_mut() {
            p.min = p.min.map(um);
            p.max = p.max.map(um);
        }
        let aabb = union(&parts);
        let mut rgb = palette(colour);
        for c in rgb.iter_mut() {
            *c = (*c * self.rng.gen_range(0.9..1.1)).clamp(0.0, 1.0);
        }
        let id = self.objects.len() as u32 + 1;
        let display = if label == "table lamp" { "lamp" } else { label };
        self.objects.push(SynthObject {
            id,
            label: display.to_string(),
            color: colour.to_string(),
            aabb,
            parts,
            rgb,
        });
        self.objects.len() - 1
    }

    fn pick_colour(&mut self, label: &str) -> String {
        let c = colours_for(label);
        c[self.rng.gen_range(0..c.len())].to_string()
    }

    /// Try to put an object with its back against a random wall, at height z0.
    fn against_wall(&mut self, label: &str, z0: f64, colour: &str) -> Option<usize> {
        let (w, d, h) = size_of(label, &mut self.rng);
        let parts = parts_of(label, w, d, h);
        for _ in 0..60 {
            let facing = *[Facing::N, Facing::S, Facing::E, Facing::W].choose(&mut self.rng)?;
            let (fw, fd) = if matches!(facing, Facing::N | Facing::S) {
                (w, d)
            } else {
                (d, w)
            };
            let origin = match facing {
                Facing::N => [
                    self.rng.gen_range(0.0..(self.w - fw).max(0.01)),
                    self.d - fd,
                    z0,
                ],
                Facing::S => [self.rng.gen_range(0.0..(self.w - fw).max(0.01)), 0.0, z0],
                Facing::E => [
                    self.w - fw,
                    self.rng.gen_range(0.0..(self.d - fd).max(0.01)),
                    z0,
                ],
                Facing::W => [0.0, self.rng.gen_range(0.0..(self.d - fd).max(0.01)), z0],
            };
            let boxes = orient(&parts, w, d, facing, origin);
            if self.free(&union(&boxes)) {
                return Some(self.add(label, colour, boxes));
            }
        }
        None
    }

    /// Try to put an object on top of another one (pillow on bed, monitor on desk, ...).
    fn on_top(&mut self, label: &str, base: usize, near_back: bool, colour: &str) -> Option<usize> {
        let (w, d, h) = size_of(label, &mut self.rng);
        let parts = parts_of(label, w, d, h);
        let b = self.objects[base].aabb;
        // The supporting surface is the top of the base's largest-footprint part.
        let top = self.objects[base]
            .parts
            .iter()
            .filter(|p| {
                (p.max[0] - p.min[0]) * (p.max[1] - p.min[1])
                    > 0.2 * (b.max[0] - b.min[0]) * (b.max[1] - b.min[1])
            })
            .map(|p| p.max[2])
            .fold(f64::MIN, f64::max);
        let top = if top == f64::MIN { b.max[2] } else { top };
        for _ in 0..40 {
            let facing = *[Facing::N, Facing::S, Facing::E, Facing::W].choose(&mut self.rng)?;
            let (fw, fd) = if matches!(facing, Facing::N | Facing::S) {
                (w, d)
            } else {
                (d, w)
            };
            if fw > b.max[0] - b.min[0] - 0.1 || fd > b.max[1] - b.min[1] - 0.1 {
                continue;
            }
            let x = self
                .rng
                .gen_range(b.min[0] + 0.05..b.max[0] - fw - 0.05 + 1e-6);
            let y = self
                .rng
                .gen_range(b.min[1] + 0.05..b.max[1] - fd - 0.05 + 1e-6);
            let boxes = orient(&parts, w, d, facing, [x, y, top]);
            let u = union(&boxes);
            let others_ok = !self
                .objects
                .iter()
                .enumerate()
                .any(|(i, o)| i != base && overlaps(&o.aabb, &u, 0.02));
            let inside_base = self.objects[base]
                .parts
                .iter()
                .all(|p| !overlaps(p, &u, -1e-6));
            if others_ok && inside_base && (!near_back || self.rng.gen_bool(0.7)) {
                return Some(self.add(label, colour, boxes));
            }
        }
        None
    }
}

/// Colours for `n` objects of one label: mostly one colour, some different, so both
/// unique-colour and repeated-colour instances occur.
fn group_colours(b: &mut Builder, label: &str, n: usize) -> Vec<String> {
    let base = b.pick_colour(label);
    let mut out = vec![base.clone(); n];
    for c in out.iter_mut() {
        if b.rng.gen_bool(0.4) {
            *c = b.pick_colour(label);
        }
    }
    out
}

/// Generate a furnished room for `seed`.
pub(crate) fn build(seed: u64) -> World {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_0f60);
    let (w, d, h) = (
        rng.gen_range(5.0..7.0),
        rng.gen_range(4.5..6.5),
        rng.gen_range(2.6..2.9),
    );
    let mut b = Builder {
        rng,
        w,
        d,
        h,
        objects: Vec::new(),
        zones: Vec::new(),
    };
    let target = b.rng.gen_range(8..=20usize);

    // Door with a keep-clear zone in front of it.
    let c = b.pick_colour("door");
    if let Some(i) = b.against_wall("door", 0.0, &c) {
        let a = b.objects[i].aabb;
        let zone = Aabb::new(
            [a.min[0] - 0.5, a.min[1] - 0.5, 0.0],
            [a.max[0] + 0.5, a.max[1] + 0.5, 2.2],
        );
        b.zones.push(zone);
    }
    let n_windows = b.rng.gen_range(1..=2);
    for c in group_colours(&mut b, "window", n_windows) {
        let z = b.rng.gen_range(0.85..1.0);
        b.against_wall("window", z, &c);
    }
    // Bed with pillows, nightstand and a table lamp.
    if b.rng.gen_bool(0.8) {
        let c = b.pick_colour("bed");
        if let Some(bed) = b.against_wall("bed", 0.0, &c) {
            let n = b.rng.gen_range(1..=3);
            for c in group_colours(&mut b, "pillow", n) {
                b.on_top("pillow", bed, true, &c);
            }
            if b.rng.gen_bool(0.7) {
                let c = b.pick_colour("nightstand");
                if let Some(ns) = b.against_wall("nightstand", 0.0, &c) {
                    if b.rng.gen_bool(0.7) {
                        let c = b.pick_colour("lamp");
                        b.on_top("table lamp", ns, false, &c);
                    }
                }
            }
        }
    }
    // Table in the middle with chairs around it.
    let (tw, td, th) = size_of("table", &mut b.rng);
    let tx = b.w / 2.0 - tw / 2.0 + b.rng.gen_range(-0.3..0.3);
    let ty = b.d / 2.0 - td / 2.0 + b.rng.gen_range(-0.3..0.3);
    let table_boxes = orient(
        &parts_of("table", tw, td, th),
        tw,
        td,
        Facing::N,
        [tx, ty, 0.0],
    );
    if b.free(&union(&table_boxes)) {
        let c = b.pick_colour("table");
        let t = b.add("table", &c, table_boxes);
        let ta = b.objects[t].aabb;
        let n = b.rng.gen_range(2..=4usize);
        let colours = group_colours(&mut b, "chair", n);
        let sides = [Facing::N, Facing::S, Facing::E, Facing::W];
        for (k, c) in colours.iter().enumerate() {
            let (cw, cd, ch) = size_of("chair", &mut b.rng);
            let facing = sides[k];
            let gap = 0.12;
            let origin = match facing {
                Facing::N => [
                    ta.min[0] + 0.1 + b.rng.gen_range(0.0..(tw - cw - 0.2).max(0.01)),
                    ta.max[1] + gap,
                    0.0,
                ],
                Facing::S => [
                    ta.min[0] + 0.1 + b.rng.gen_range(0.0..(tw - cw - 0.2).max(0.01)),
                    ta.min[1] - gap - cd,
                    0.0,
                ],
                Facing::E => [ta.max[0] + gap, ta.min[1] + (td - cw) / 2.0, 0.0],
                Facing::W => [ta.min[0] - gap - cd, ta.min[1] + (td - cw) / 2.0, 0.0],
            };
            let boxes = orient(&parts_of("chair", cw, cd, ch), cw, cd, facing, origin);
            if b.free(&union(&boxes)) {
                b.add("chair", c, boxes);
            }
        }
    }
    // Extras along the walls until the target count is reached.
    let mut extras = vec![
        "sofa",
        "desk",
        "bookshelf",
        "cabinet",
        "cabinet",
        "trash can",
        "picture",
        "picture",
        "box",
        "box",
        "box",
        "lamp",
        "picture",
        "trash can",
        "cabinet",
        "chair",
    ];
    extras.shuffle(&mut b.rng);
    let box_colours = group_colours(&mut b, "box", 3);
    let pic_colours = group_colours(&mut b, "picture", 3);
    let mut nbox = 0;
    let mut npic = 0;
    for label in extras {
        if b.objects.len() >= target {
            break;
        }
        let colour = match label {
            "box" => {
                nbox += 1;
                box_colours[(nbox - 1) % 3].clone()
            }
            "picture" => {
                npic += 1;
                pic_colours[(npic - 1) % 3].clone()
            }
            _ => b.pick_colour(label),
        };
        let z = if label == "picture" {
            b.rng.gen_range(1.3..1.6)
        } else {
            0.0
        };
        let placed = b.against_wall(label, z, &colour);
        if label == "desk" {
            if let Some(desk) = placed {
                let c = b.pick_colour("monitor");
                b.on_top("monitor", desk, false, &c);
            }
        }
    }
    // Axis alignment: rotation about z (not a multiple of 90 degrees) and an offset.
    let theta = (b.rng.gen_range(15.0..75.0f64) + 90.0 * b.rng.gen_range(0..4) as f64).to_radians();
    let t = Vector3::new(
        b.rng.gen_range(-3.0..3.0),
        b.rng.gen_range(-3.0..3.0),
        b.rng.gen_range(-0.2..0.2),
    );
    let (align, align_inv) = alignment(theta, t);
    World {
        size: (w, d, h),
        objects: b.objects,
        align,
        align_inv,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rooms_have_8_to_20_non_overlapping_objects() {
        for seed in 0..30 {
            let w = build(seed);
            assert!(
                (8..=20).contains(&w.objects.len()),
                "seed {seed}: {} objects",
                w.objects.len()
            );
            for (i, a) in w.objects.iter().enumerate() {
                for p in &a.parts {
                    assert!(
                        p.min[0] >= -1e-6
                            && p.max[0] <= w.size.0 + 1e-6
                            && p.min[1] >= -1e-6
                            && p.max[1] <= w.size.1 + 1e-6,
                        "seed {seed}: {} part {p:?} outside the room {:?}",
                        a.label,
                        w.size
                    );
                }
                for bo in &w.objects[i + 1..] {
                    for pa in &a.parts {
                        for pb in &bo.parts {
                            assert!(
                                !overlaps(pa, pb, -1e-6),
                                "seed {seed}: {} and {} intersect",
                                a.label,
                                bo.label
                            );
                        }
                    }
                }
            }
            let inv = w.align_inv * w.align;
            assert!((inv - Matrix4::identity()).abs().max() < 1e-12);
        }
    }
}
