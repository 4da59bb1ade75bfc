//! Room layout of the props family: a furnished room in the aligned frame (x in [0, W],
//! y in [0, D], z up from the floor) whose objects are turned freely about the vertical,
//! pushed under tables, stood on shelves and tables, hung on walls.

use super::models::{model, Mat, Surface};
use super::place::Builder;
use super::prim::Shape;
use crate::geometry::Aabb;
use crate::synth::build::alignment;
use crate::synth::SynthObject;
use nalgebra::{Matrix4, Vector3};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// One placed object.
#[derive(Debug, Clone)]
pub(crate) struct PropObject {
    pub id: u32,
    pub label: String,
    pub colour: String,
    /// Linear RGB of the named colour (after a small per-object variation).
    pub rgb: [f64; 3],
    pub shapes: Vec<(Shape, Mat)>,
    pub surfaces: Vec<Surface>,
    /// Bounds of each shape (same order as `shapes`).
    pub parts: Vec<Aabb>,
    /// Union of `parts`, rounded outwards to micrometres.
    pub aabb: Aabb,
}

/// The generated room in the aligned frame plus the axis alignment written to disk.
pub(crate) struct PropWorld {
    /// (W, D, H) in metres.
    pub size: (f64, f64, f64),
    pub objects: Vec<PropObject>,
    /// Linear RGB of the walls and of the floor's base tone.
    pub wall_rgb: [f64; 3],
    pub floor_rgb: [f64; 3],
    /// Floor pattern: true = square tiles, false = planks.
    pub tiles: bool,
    /// World -> aligned.
    pub align: Matrix4<f64>,
    /// Aligned -> world.
    pub align_inv: Matrix4<f64>,
}

impl PropWorld {
    /// Ground truth in the shared form (parts are the shapes' bounds).
    pub fn output_objects(&self) -> Vec<SynthObject> {
        self.objects
            .iter()
            .map(|o| SynthObject {
                id: o.id,
                label: o.label.clone(),
                color: o.colour.clone(),
                aabb: o.aabb,
                parts: o.parts.clone(),
                rgb: o.rgb,
            })
            .collect()
    }

    /// Is `p` inside (or within `margin` of) any object's box or outside the room?
    pub fn blocked(&self, p: [f64; 3], margin: f64) -> bool {
        let (w, d, h) = self.size;
        if p[0] < margin || p[1] < margin || p[0] > w - margin || p[1] > d - margin || p[2] > h {
            return true;
        }
        self.objects
            .iter()
            .any(|o| (0..3).all(|i| p[i] > o.aabb.min[i] - margin && p[i] < o.aabb.max[i] + margin))
    }
}

/// Yaw of a placed object (its first turned shape, else 0).
fn yaw_of(o: &PropObject) -> f64 {
    o.shapes
        .iter()
        .find_map(|(s, _)| match s {
            Shape::Cuboid { yaw, .. } => Some(*yaw),
            _ => None,
        })
        .unwrap_or(0.0)
}

/// Generate a furnished room for `seed`.
pub(crate) fn build(seed: u64) -> PropWorld {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0070_e5f1_a9b3);
    let (w, d, h) = (
        rng.gen_range(4.5..7.5),
        rng.gen_range(4.0..6.5),
        rng.gen_range(2.5..3.0),
    );
    let mut b = Builder {
        rng,
        w,
        d,
        h,
        objects: Vec::new(),
        zones: Vec::new(),
    };

    // Door, with a keep-clear zone in front.
    let c = b.colour("door");
    let m = model("door", false, &mut b.rng);
    if let Some((i, _)) = b.at_wall("door", &c, &m, None, 0.0, 0.0, 0.0, None) {
        let a = b.objects[i].aabb;
        b.zones.push(Aabb::new(
            [a.min[0] - 0.5, a.min[1] - 0.5, 0.0],
            [a.max[0] + 0.5, a.max[1] + 0.5, 2.2],
        ));
    }
    // Windows with curtains beside them.
    for _ in 0..b.rng.gen_range(1..=2) {
        let c = b.colour("window");
        let m = model("window", false, &mut b.rng);
        let z = b.r(0.8, 1.0);
        let Some((i, k)) = b.at_wall("window", &c, &m, None, 0.0, z, 0.0, None) else {
            continue;
        };
        if b.rng.gen_bool(0.75) {
            let a = b.objects[i].aabb;
            let cc = b.colour("curtain");
            for side in [-1.0, 1.0] {
                let cm = model("curtain", false, &mut b.rng);
                let half = cm.radius().min(0.6);
                let (lo, hi) = if k < 2 {
                    (a.min[0], a.max[0])
                } else {
                    (a.min[1], a.max[1])
                };
                let along = if side < 0.0 {
                    lo - 0.03 - half * 0.9
                } else {
                    hi + 0.03 + half * 0.9
                };
                b.at_wall("curtain", &cc, &cm, Some(k), 0.0, 0.0, 0.01, Some(along));
            }
        }
    }
    // Pictures.
    for _ in 0..b.rng.gen_range(1..=3) {
        let c = b.colour("picture");
        let m = model("picture", false, &mut b.rng);
        let z = b.r(1.3, 1.7);
        b.at_wall("picture", &c, &m, None, 0.0, z, 0.0, None);
    }
    // Round table with chairs around it, some pushed under, some pulled out and turned.
    let tm = model("table", false, &mut b.rng);
    let rad = tm.radius();
    let tc = b.colour("table");
    let mut table = None;
    for _ in 0..40 {
        let x = b.r(1.3 + rad, (w - 1.3 - rad).max(1.3 + rad + 1e-3));
        let y = b.r(1.3 + rad, (d - 1.3 - rad).max(1.3 + rad + 1e-3));
        let yaw = b.r(0.0, TAU);
        table = b.put("table", &tc, &tm, yaw, [x, y, 0.0], None);
        if table.is_some() {
            break;
        }
    }
    let n_chairs = b.rng.gen_range(2..=4usize);
    let chair_colour = b.colour("chair");
    if let Some(t) = table {
        let ctr = b.objects[t].aabb.center();
        let phi0 = b.r(0.0, TAU);
        for k in 0..n_chairs {
            let c = if b.rng.gen_bool(0.3) {
                b.colour("chair")
            } else {
                chair_colour.clone()
            };
            let m = model("chair", false, &mut b.rng);
            let half_d = m
                .parts
                .iter()
                .map(|(s, _)| s.aabb().max[1])
                .fold(0.0, f64::max);
            let phi = phi0 + k as f64 * TAU / n_chairs as f64 + b.r(-0.25, 0.25);
            let pushed = b.rng.gen_bool(0.5);
            let (rho, jit) = if pushed {
                (rad + half_d - b.r(0.15, 0.25), b.r(-0.1, 0.1))
            } else {
                (rad + half_d + b.r(0.1, 0.4), b.r(-0.5, 0.5))
            };
            let pos = [ctr[0] + rho * phi.cos(), ctr[1] + rho * phi.sin(), 0.0];
            if b.put("chair", &c, &m, phi - FRAC_PI_2 + jit, pos, None)
                .is_none()
                && pushed
            {
                let pos = [
                    ctr[0] + (rho + 0.3) * phi.cos(),
                    ctr[1] + (rho + 0.3) * phi.sin(),
                    0.0,
                ];
                b.put("chair", &c, &m, phi - FRAC_PI_2 + jit, pos, None);
            }
        }
        let n = b.rng.gen_range(1..=3);
        b.clutter_on(t, n);
    }
    // Desk against a wall: monitor, maybe a table lamp, clutter, a chair pushed under.
    let c = b.colour("desk");
    let m = model("desk", false, &mut b.rng);
    if let Some((desk, _)) = b.at_wall("desk", &c, &m, None, 0.05, 0.0, 0.02, None) {
        let yd = yaw_of(&b.objects[desk]);
        let dc = b.objects[desk].aabb.center();
        let c = b.colour("monitor");
        let mm = model("monitor", false, &mut b.rng);
        let back = [-yd.sin(), yd.cos()];
        let along = [yd.cos(), yd.sin()];
        let half_d = m.parts[0].0.aabb().size()[1].min(m.parts[0].0.aabb().size()[0]) / 2.0;
        for _ in 0..20 {
            let s = b.r(-0.3, 0.3);
            let off = half_d - 0.16;
            let p = [
                dc[0] + back[0] * off + along[0] * s,
                dc[1] + back[1] * off + along[1] * s,
            ];
            let top = b.objects[desk].surfaces[0].z();
            let yaw = yd + b.r(-0.3, 0.3);
            if b.put("monitor", &c, &mm, yaw, [p[0], p[1], top], Some(desk))
                .is_some()
            {
                break;
            }
        }
        if b.rng.gen_bool(0.5) {
            let c = b.colour("lamp");
            let lm = model("lamp", false, &mut b.rng);
            b.on("lamp", &c, &lm, desk, None, None);
        }
        let n = b.rng.gen_range(0..=2);
        b.clutter_on(desk, n);
        let c = if b.rng.gen_bool(0.5) {
            chair_colour.clone()
        } else {
            b.colour("chair")
        };
        let cm = model("chair", false, &mut b.rng);
        let push = if b.rng.gen_bool(0.6) {
            b.r(0.15, 0.3)
        } else {
            -b.r(0.1, 0.4)
        };
        let half_c = cm
            .parts
            .iter()
            .map(|(s, _)| s.aabb().max[1])
            .fold(0.0, f64::max);
        let dist = half_d + half_c - push;
        let pos = [dc[0] - back[0] * dist, dc[1] - back[1] * dist, 0.0];
        let jit = if push > 0.0 {
            b.r(-0.08, 0.08)
        } else {
            b.r(-0.5, 0.5)
        };
        b.put("chair", &c, &cm, yd + PI + jit, pos, None);
    }
    // Bookshelf with things on its shelves.
    if b.rng.gen_bool(0.85) {
        let c = b.colour("bookshelf");
        let m = model("bookshelf", false, &mut b.rng);
        if let Some((s, _)) = b.at_wall("bookshelf", &c, &m, None, 0.06, 0.0, 0.03, None) {
            let n = b.rng.gen_range(2..=5);
            b.clutter_on(s, n);
        }
    }
    // Sofa (against a wall or free-standing, turned) with pillows.
    if b.rng.gen_bool(0.75) {
        let c = b.colour("sofa");
        let m = model("sofa", false, &mut b.rng);
        let sofa = if b.rng.gen_bool(0.6) {
            b.at_wall("sofa", &c, &m, None, 0.1, 0.0, 0.05, None)
                .map(|x| x.0)
        } else {
            b.free("sofa", &c, &m)
        };
        if let Some(s) = sofa {
            let ys = yaw_of(&b.objects[s]);
            for _ in 0..b.rng.gen_range(1..=3) {
                let c = b.colour("pillow");
                let pm = model("pillow", false, &mut b.rng);
                let yaw = ys + b.r(-0.2, 0.2);
                b.on("pillow", &c, &pm, s, Some(yaw), Some(0.0));
            }
        }
    }
    // Along the walls and in the corners.
    let mut extras = vec![
        "lamp",
        "plant",
        "trash can",
        "cabinet",
        "plant",
        "lamp",
        "trash can",
        "cabinet",
        "chair",
    ];
    extras.shuffle(&mut b.rng);
    let n_extra = b.rng.gen_range(4..=extras.len());
    for label in extras.into_iter().take(n_extra) {
        let c = b.colour(label);
        let m = model(label, true, &mut b.rng);
        let placed = match label {
            "cabinet" => b
                .at_wall(label, &c, &m, None, 0.05, 0.0, 0.02, None)
                .map(|x| x.0),
            "chair" => b.free(label, &c, &m),
            _ => {
                let gap = b.r(0.05, 0.4);
                b.at_wall(label, &c, &m, None, PI, 0.0, gap, None)
                    .map(|x| x.0)
            }
        };
        if let (Some(i), "cabinet") = (placed, label) {
            if b.rng.gen_bool(0.5) {
                let c = b.colour("lamp");
                let lm = model("lamp", false, &mut b.rng);
                if b.on("lamp", &c, &lm, i, None, None).is_none() {
                    b.clutter_on(i, 1);
                }
            }
        }
    }

    // Axis alignment: rotation about z and an offset.
    let theta = (b.r(5.0, 85.0) + 90.0 * b.rng.gen_range(0..4) as f64).to_radians();
    let t = Vector3::new(b.r(-4.0, 4.0), b.r(-4.0, 4.0), b.r(-0.1, 0.3));
    let (align, align_inv) = alignment(theta, t);
    let wall_rgb = [b.r(0.5, 0.7), b.r(0.5, 0.7), b.r(0.45, 0.65)];
    let tiles = b.rng.gen_bool(0.5);
    let floor_rgb = if tiles {
        [0.45, 0.44, 0.42].map(|c| c * b.r(0.8, 1.2))
    } else {
        [0.3, 0.18, 0.09]
    };
    PropWorld {
        size: (w, d, h),
        objects: b.objects,
        wall_rgb,
        floor_rgb,
        tiles,
        align,
        align_inv,
    }
}

#[cfg(test)]
mod tests {
    use super::super::place::clash;
    use super::*;

    #[test]
    fn rooms_are_furnished_without_collisions() {
        let mut labels = std::collections::BTreeSet::new();
        for seed in 0..20 {
            let wd = build(seed);
            assert!(
                wd.objects.len() >= 10,
                "seed {seed}: {} objects",
                wd.objects.len()
            );
            for (i, a) in wd.objects.iter().enumerate() {
                labels.insert(a.label.clone());
                for k in 0..3 {
                    assert!(a.aabb.min[k] <= a.aabb.max[k]);
                }
                assert!(
                    a.aabb.min[0] >= -1e-6 && a.aabb.max[0] <= wd.size.0 + 1e-6,
                    "seed {seed}: {}",
                    a.label
                );
                assert!(
                    a.aabb.min[1] >= -1e-6 && a.aabb.max[1] <= wd.size.1 + 1e-6,
                    "seed {seed}: {}",
                    a.label
                );
                for o in &wd.objects[i + 1..] {
                    for (sa, _) in &a.shapes {
                        for (sb, _) in &o.shapes {
                            assert!(
                                !clash(sa, sb, -1e-6),
                                "seed {seed}: {} and {} intersect",
                                a.label,
                                o.label
                            );
                        }
                    }
                }
            }
        }
        for l in [
            "lamp",
            "chair",
            "table",
            "bookshelf",
            "plant",
            "curtain",
            "trash can",
            "cabinet",
            "pillow",
            "sofa",
            "monitor",
            "desk",
            "picture",
            "window",
            "door",
        ] {
            assert!(labels.contains(l), "no {l} in 20 rooms: {labels:?}");
        }
    }

    #[test]
    fn some_objects_are_turned_off_the_axes() {
        let wd = build(3);
        let turned = wd
            .objects
            .iter()
            .filter(|o| {
                let y = yaw_of(o).rem_euclid(FRAC_PI_2);
                y > 0.05 && y < FRAC_PI_2 - 0.05
            })
            .count();
        assert!(turned >= 2, "only {turned} objects turned off the axes");
    }
}
