//! Object models of the props family, built from cylinders, cones, ellipsoids and thin
//! boxes in a local frame: origin at the centre of the footprint on the floor, z up, the
//! object's back towards +y (its front faces -y).

use super::prim::Shape;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// What a part is made of; decides its albedo at render time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Mat {
    /// The object's named colour.
    Main,
    /// A darker shade of the named colour (door panels, trim).
    Trim,
    /// Brushed metal (poles, handles, lamp bases).
    Metal,
    /// Dark glossy screen.
    Screen,
    /// Foliage.
    Leaf,
    /// Pale window glass.
    Glass,
    /// Dark wood (picture frames, furniture feet).
    Wood,
}

/// A flat area other objects may stand on, in the model's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Surface {
    /// Rectangle of half-size `half` centred at (`c`, `z`), turned by `yaw`.
    Rect {
        c: [f64; 2],
        half: [f64; 2],
        yaw: f64,
        z: f64,
    },
    /// Disk of radius `r` centred at (`c`, `z`).
    Disk { c: [f64; 2], r: f64, z: f64 },
}

impl Surface {
    /// Height of the surface.
    pub fn z(&self) -> f64 {
        match *self {
            Surface::Rect { z, .. } | Surface::Disk { z, .. } => z,
        }
    }

    /// The surface turned by `yaw` about the vertical through the origin, then moved by `t`.
    pub fn placed(&self, yaw: f64, t: [f64; 3]) -> Surface {
        let (s, co) = yaw.sin_cos();
        let mv = |c: [f64; 2]| [co * c[0] - s * c[1] + t[0], s * c[0] + co * c[1] + t[1]];
        match *self {
            Surface::Rect {
                c,
                half,
                yaw: y0,
                z,
            } => Surface::Rect {
                c: mv(c),
                half,
                yaw: y0 + yaw,
                z: z + t[2],
            },
            Surface::Disk { c, r, z } => Surface::Disk {
                c: mv(c),
                r,
                z: z + t[2],
            },
        }
    }

    /// A random point at least `margin` inside the surface, or None when it is too small.
    pub fn sample(&self, margin: f64, rng: &mut ChaCha8Rng) -> Option<[f64; 2]> {
        match *self {
            Surface::Rect { c, half, yaw, .. } => {
                let (hx, hy) = (half[0] - margin, half[1] - margin);
                if hx <= 0.0 || hy <= 0.0 {
                    return None;
                }
                let (a, b) = (rng.gen_range(-hx..hx), rng.gen_range(-hy..hy));
                let (s, co) = yaw.sin_cos();
                Some([c[0] + co * a - s * b, c[1] + s * a + co * b])
            }
            Surface::Disk { c, r, .. } => {
                let rr = r - margin;
                if rr <= 0.0 {
                    return None;
                }
                let (rho, phi) = (
                    rr * rng.gen_range(0.0f64..1.0).sqrt(),
                    rng.gen_range(0.0..std::f64::consts::TAU),
                );
                Some([c[0] + rho * phi.cos(), c[1] + rho * phi.sin()])
            }
        }
    }
}

/// An object model: its parts and where things can be put on it.
#[derive(Debug, Clone, Default)]
pub(crate) struct Model {
    pub parts: Vec<(Shape, Mat)>,
    pub surfaces: Vec<Surface>,
}

impl Model {
    fn push(&mut self, s: Shape, m: Mat) {
        self.parts.push((s, m));
    }

    /// Footprint radius: the largest horizontal distance of any part's bounds from the origin.
    pub fn radius(&self) -> f64 {
        self.parts
            .iter()
            .map(|(s, _)| {
                let b = s.aabb();
                let x = b.min[0].abs().max(b.max[0].abs());
                let y = b.min[1].abs().max(b.max[1].abs());
                x.hypot(y)
            })
            .fold(0.0, f64::max)
    }
}

/// Box from its min and max corner (not turned).
fn cub(lo: [f64; 3], hi: [f64; 3]) -> Shape {
    Shape::Cuboid {
        c: [0, 1, 2].map(|i| (lo[i] + hi[i]) / 2.0),
        half: [0, 1, 2].map(|i| (hi[i] - lo[i]) / 2.0),
        yaw: 0.0,
    }
}

fn cyl(x: f64, y: f64, z0: f64, z1: f64, r0: f64, r1: f64) -> Shape {
    Shape::Frustum {
        x,
        y,
        z0,
        z1,
        r0,
        r1,
    }
}

/// Labels whose model is small enough to stand on a table or a shelf.
pub(crate) const CLUTTER: &[&str] = &["cup", "bottle", "vase", "book", "box"];

/// Plausible colour names per label (all in the shared palette).
pub(crate) fn colours(label: &str) -> &'static [&'static str] {
    match label {
        "chair" => &[
            "brown", "black", "red", "blue", "white", "green", "grey", "orange",
        ],
        "table" | "desk" => &["brown", "white", "black", "beige"],
        "cabinet" | "bookshelf" => &["white", "brown", "grey", "black", "beige"],
        "sofa" => &["grey", "blue", "green", "red", "beige", "brown"],
        "pillow" => &["white", "red", "blue", "yellow", "green", "orange", "pink"],
        "lamp" => &["white", "black", "red", "yellow", "beige", "green"],
        "plant" => &["white", "brown", "grey", "blue", "red", "black"],
        "curtain" => &["beige", "blue", "red", "grey", "white", "purple", "green"],
        "trash can" => &["black", "grey", "blue", "green", "white"],
        "monitor" => &["black", "white", "grey"],
        "picture" => &["red", "blue", "green", "yellow", "orange", "purple"],
        "window" => &["white", "black", "brown"],
        "door" => &["brown", "white", "grey"],
        "cup" => &["white", "red", "blue", "yellow", "black"],
        "bottle" => &["green", "blue", "white", "brown"],
        "vase" => &["blue", "white", "red", "yellow", "purple"],
        "book" => &["red", "blue", "green", "yellow", "black", "orange"],
        "box" => &["brown", "white", "orange", "red"],
        _ => &["grey"],
    }
}

/// Build the model of `label` (sizes drawn from `rng`). `floor` lamps stand on the floor,
/// otherwise "lamp" is a table lamp.
pub(crate) fn model(label: &str, floor_lamp: bool, rng: &mut ChaCha8Rng) -> Model {
    let mut m = Model::default();
    let mut r = |a: f64, b: f64| rng.gen_range(a..b);
    match label {
        "chair" => {
            let (w, d, seat, top) = (r(0.42, 0.5), r(0.42, 0.5), r(0.44, 0.48), r(0.82, 0.95));
            let (hw, hd, leg, th) = (w / 2.0, d / 2.0, r(0.03, 0.04), r(0.03, 0.05));
            for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
                let (x, y) = (sx * (hw - leg / 2.0), sy * (hd - leg / 2.0));
                m.push(
                    cub(
                        [x - leg / 2.0, y - leg / 2.0, 0.0],
                        [x + leg / 2.0, y + leg / 2.0, seat - th],
                    ),
                    Mat::Main,
                );
            }
            m.push(cub([-hw, -hd, seat - th], [hw, hd, seat]), Mat::Main);
            // Open back: two posts, a top rail and a lower rail or slats, with gaps between.
            for sx in [-1.0, 1.0] {
                let x = sx * (hw - leg / 2.0);
                m.push(
                    cub(
                        [x - leg / 2.0, hd - leg, seat],
                        [x + leg / 2.0, hd, top - 0.06],
                    ),
                    Mat::Main,
                );
            }
            m.push(cub([-hw, hd - 0.025, top - 0.06], [hw, hd, top]), Mat::Main);
            let slats = r(0.0, 1.0) < 0.5;
            if slats {
                for k in [-1.0, 0.0, 1.0] {
                    let x = k * w / 4.0;
                    m.push(
                        cub([x - 0.02, hd - 0.02, seat], [x + 0.02, hd, top - 0.06]),
                        Mat::Main,
                    );
                }
            } else {
                let z = seat + (top - seat) * 0.4;
                m.push(cub([-hw, hd - 0.02, z], [hw, hd, z + 0.04]), Mat::Main);
            }
        }
        "table" => {
            let (rad, h, th) = (r(0.45, 0.65), r(0.72, 0.76), 0.035);
            m.push(cyl(0.0, 0.0, h - th, h, rad, rad), Mat::Main);
            if r(0.0, 1.0) < 0.5 {
                m.push(cyl(0.0, 0.0, 0.0, 0.04, 0.3, 0.26), Mat::Main);
                let c = r(0.045, 0.07);
                m.push(cyl(0.0, 0.0, 0.04, h - th, c, c), Mat::Main);
            } else {
                for k in 0..4 {
                    let a = std::f64::consts::FRAC_PI_4 + k as f64 * std::f64::consts::FRAC_PI_2;
                    let (x, y) = (0.62 * rad * a.cos(), 0.62 * rad * a.sin());
                    m.push(cyl(x, y, 0.0, h - th, 0.02, 0.028), Mat::Main);
                }
            }
            m.surfaces.push(Surface::Disk {
                c: [0.0, 0.0],
                r: rad - 0.05,
                z: h,
            });
        }
        "desk" => {
            let (w, d, h) = (r(1.1, 1.5), r(0.6, 0.75), r(0.72, 0.76));
            let (hw, hd) = (w / 2.0, d / 2.0);
            m.push(cub([-hw, -hd, h - 0.035], [hw, hd, h]), Mat::Main);
            for sx in [-1.0, 1.0] {
                let x = sx * (hw - 0.02);
                m.push(
                    cub([x - 0.02, -hd + 0.04, 0.0], [x + 0.02, hd, h - 0.035]),
                    Mat::Main,
                );
            }
            m.push(
                cub([-hw + 0.04, hd - 0.02, 0.35], [hw - 0.04, hd, h - 0.035]),
                Mat::Trim,
            );
            m.surfaces.push(Surface::Rect {
                c: [0.0, 0.0],
                half: [hw - 0.03, hd - 0.03],
                yaw: 0.0,
                z: h,
            });
        }
        "monitor" => {
            let (w, h) = (r(0.5, 0.65), r(0.42, 0.5));
            m.push(cyl(0.0, 0.02, 0.0, 0.015, 0.11, 0.095), Mat::Main);
            m.push(cub([-0.025, 0.01, 0.015], [0.025, 0.04, 0.14]), Mat::Main);
            m.push(cub([-w / 2.0, -0.02, 0.1], [w / 2.0, 0.01, h]), Mat::Main);
            m.push(
                cub(
                    [-w / 2.0 + 0.015, -0.025, 0.115],
                    [w / 2.0 - 0.015, -0.02, h - 0.015],
                ),
                Mat::Screen,
            );
        }
        "lamp" if floor_lamp => {
            let h = r(1.45, 1.75);
            let (r0, sh) = (r(0.18, 0.25), r(0.22, 0.32));
            let r1 = r0 * r(0.6, 0.85);
            let pole = r(0.012, 0.018);
            m.push(cyl(0.0, 0.0, 0.0, 0.03, r(0.13, 0.16), 0.12), Mat::Metal);
            m.push(cyl(0.0, 0.0, 0.03, h - sh + 0.05, pole, pole), Mat::Metal);
            m.push(cyl(0.0, 0.0, h - sh, h, r0, r1), Mat::Main);
        }
        "lamp" => {
            let (body, sh) = (r(0.15, 0.25), r(0.14, 0.18));
            let r0 = r(0.12, 0.16);
            m.push(cyl(0.0, 0.0, 0.0, 0.02, r(0.07, 0.09), 0.07), Mat::Metal);
            let br = r(0.04, 0.06);
            m.push(cyl(0.0, 0.0, 0.02, 0.02 + body, br, br * 0.7), Mat::Trim);
            m.push(
                cyl(
                    0.0,
                    0.0,
                    0.02 + body,
                    0.02 + body + sh,
                    r0,
                    r0 * r(0.6, 0.8),
                ),
                Mat::Main,
            );
        }
        "bookshelf" => {
            let (w, d, h, t) = (r(0.7, 1.0), r(0.28, 0.36), r(1.6, 2.0), 0.02);
            let (hw, hd) = (w / 2.0, d / 2.0);
            m.push(cub([-hw, hd - t, 0.0], [hw, hd, h]), Mat::Trim);
            for sx in [-1.0, 1.0] {
                let x = sx * (hw - t / 2.0);
                m.push(
                    cub([x - t / 2.0, -hd, 0.0], [x + t / 2.0, hd - t, h]),
                    Mat::Main,
                );
            }
            let n = rng.gen_range(4..=5usize);
            for k in 0..=n {
                let z = 0.06 + k as f64 * (h - 0.06 - t) / n as f64;
                m.push(cub([-hw + t, -hd, z], [hw - t, hd - t, z + t]), Mat::Main);
                m.surfaces.push(Surface::Rect {
                    c: [0.0, -t / 2.0],
                    half: [hw - t - 0.01, hd - t / 2.0 - 0.01],
                    yaw: 0.0,
                    z: z + t,
                });
            }
        }
        "plant" => {
            let r0 = r(0.1, 0.15);
            let (r1, ph) = (r0 * r(1.2, 1.35), r(0.2, 0.35));
            m.push(cyl(0.0, 0.0, 0.0, ph, r0, r1), Mat::Main);
            let top = ph + r(0.35, 0.8);
            m.push(cyl(0.0, 0.0, ph, top, 0.012, 0.012), Mat::Wood);
            let n = rng.gen_range(1..=3usize);
            for k in 0..n {
                let (rx, ry, rz) = (
                    rng.gen_range(0.16..0.3),
                    rng.gen_range(0.16..0.3),
                    rng.gen_range(0.18..0.32),
                );
                let z = top - k as f64 * 0.15 + rng.gen_range(-0.05..0.05);
                let (dx, dy) = (rng.gen_range(-0.08..0.08), rng.gen_range(-0.08..0.08));
                m.push(
                    Shape::Ellipsoid {
                        c: [dx, dy, z.max(ph + rz)],
                        r: [rx, ry, rz],
                        yaw: rng.gen_range(0.0..3.1),
                    },
                    Mat::Leaf,
                );
            }
        }
        "trash can" => {
            let h = r(0.3, 0.5);
            if r(0.0, 1.0) < 0.7 {
                let r0 = r(0.12, 0.17);
                let r1 = r0 * r(1.05, 1.25);
                m.push(cyl(0.0, 0.0, 0.0, h, r0, r1), Mat::Main);
                m.push(cyl(0.0, 0.0, h, h + 0.02, r1 + 0.01, r1 + 0.01), Mat::Trim);
            } else {
                let (w, d) = (r(0.24, 0.32), r(0.22, 0.3));
                m.push(
                    cub([-w / 2.0, -d / 2.0, 0.0], [w / 2.0, d / 2.0, h]),
                    Mat::Main,
                );
            }
        }
        "cabinet" => {
            let (w, d) = (r(0.5, 1.2), r(0.4, 0.55));
            let h = if r(0.0, 1.0) < 0.3 {
                r(1.6, 1.9)
            } else {
                r(0.7, 1.1)
            };
            let (hw, hd) = (w / 2.0, d / 2.0);
            m.push(cub([-hw, -hd + 0.02, 0.0], [hw, hd, h]), Mat::Main);
            let doors = if w > 0.8 { 2 } else { 1 };
            let dw = (w - 0.02) / doors as f64;
            for k in 0..doors {
                let x0 = -hw + 0.01 + k as f64 * dw;
                m.push(
                    cub(
                        [x0 + 0.005, -hd, 0.06],
                        [x0 + dw - 0.005, -hd + 0.02, h - 0.02],
                    ),
                    Mat::Trim,
                );
                let hx = if k == 0 && doors == 2 {
                    x0 + dw - 0.05
                } else {
                    x0 + 0.05
                };
                m.push(
                    cyl(hx, -hd - 0.02, h * 0.55, h * 0.55 + 0.12, 0.008, 0.008),
                    Mat::Metal,
                );
            }
            m.surfaces.push(Surface::Rect {
                c: [0.0, 0.0],
                half: [hw - 0.03, hd - 0.03],
                yaw: 0.0,
                z: h,
            });
        }
        "sofa" => {
            let (w, d, arm) = (r(1.6, 2.2), r(0.8, 0.95), r(0.15, 0.2));
            let (hw, hd, seat) = (w / 2.0, d / 2.0, r(0.4, 0.45));
            let back = r(0.18, 0.22);
            for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
                let (x, y) = (sx * (hw - 0.06), sy * (hd - 0.06));
                m.push(cyl(x, y, 0.0, 0.08, 0.025, 0.02), Mat::Wood);
            }
            m.push(
                cub([-hw + arm, -hd, 0.08], [hw - arm, hd - back, seat]),
                Mat::Main,
            );
            m.push(
                cub([-hw, hd - back, 0.08], [hw, hd, r(0.8, 0.9)]),
                Mat::Main,
            );
            let arm_top = r(0.58, 0.66);
            for sx in [-1.0, 1.0] {
                let x = sx * (hw - arm / 2.0);
                m.push(
                    cub(
                        [x - arm / 2.0, -hd, 0.08],
                        [x + arm / 2.0, hd - back, arm_top],
                    ),
                    Mat::Main,
                );
            }
            m.surfaces.push(Surface::Rect {
                c: [0.0, hd - back - 0.1],
                half: [hw - arm - 0.25, 0.05],
                yaw: 0.0,
                z: seat,
            });
        }
        "pillow" => {
            // Upright, leaning on a sofa back: flat along its own y.
            let (rx, ry, rz) = (r(0.19, 0.25), r(0.06, 0.08), r(0.15, 0.19));
            m.push(
                Shape::Ellipsoid {
                    c: [0.0, 0.0, rz],
                    r: [rx, ry, rz],
                    yaw: 0.0,
                },
                Mat::Main,
            );
        }
        "curtain" => {
            // Pleats: a zig-zag row of thin slabs, hanging from a rod.
            let (w, h) = (r(0.55, 0.95), r(2.0, 2.3));
            let pitch = 0.08;
            let n = (w / pitch).round().max(3.0) as usize;
            let a = r(0.5, 0.7);
            let len = pitch / a.cos();
            for k in 0..n {
                let x = -w / 2.0 + (k as f64 + 0.5) * pitch;
                let yaw = if k % 2 == 0 { a } else { -a };
                m.push(
                    Shape::Cuboid {
                        c: [x, 0.0, 0.02 + (h - 0.02) / 2.0 - 0.03],
                        half: [len / 2.0, 0.006, (h - 0.02) / 2.0 - 0.03],
                        yaw,
                    },
                    Mat::Main,
                );
            }
            let depth = pitch * a.tan() / 2.0 + 0.01;
            m.push(
                cub(
                    [-w / 2.0 - 0.05, depth, h - 0.04],
                    [w / 2.0 + 0.05, depth + 0.025, h],
                ),
                Mat::Metal,
            );
        }
        "picture" => {
            let (w, h) = (r(0.35, 0.8), r(0.3, 0.6));
            let (hw, hh) = (w / 2.0, h / 2.0);
            m.push(cub([-hw, -0.01, -hh], [hw, 0.015, hh]), Mat::Wood);
            m.push(
                cub(
                    [-hw + 0.03, -0.015, -hh + 0.03],
                    [hw - 0.03, -0.01, hh - 0.03],
                ),
                Mat::Main,
            );
        }
        "window" => {
            let (w, h, d) = (r(0.9, 1.5), r(1.0, 1.4), r(0.05, 0.08));
            let (hw, f) = (w / 2.0, 0.05);
            m.push(cub([-hw, -d / 2.0, 0.0], [hw, d / 2.0, f]), Mat::Main);
            m.push(cub([-hw, -d / 2.0, h - f], [hw, d / 2.0, h]), Mat::Main);
            m.push(
                cub([-hw, -d / 2.0, f], [-hw + f, d / 2.0, h - f]),
                Mat::Main,
            );
            m.push(cub([hw - f, -d / 2.0, f], [hw, d / 2.0, h - f]), Mat::Main);
            m.push(cub([-0.02, -d / 2.0, f], [0.02, d / 2.0, h - f]), Mat::Main);
            m.push(
                cub([-hw + f, d / 2.0 - 0.01, f], [hw - f, d / 2.0, h - f]),
                Mat::Glass,
            );
        }
        "door" => {
            let (w, h) = (r(0.8, 0.95), r(2.0, 2.1));
            let hw = w / 2.0;
            m.push(cub([-hw, -0.02, 0.0], [hw, 0.02, h]), Mat::Main);
            m.push(
                cub([-hw + 0.1, -0.03, 1.1], [hw - 0.1, -0.02, h - 0.15]),
                Mat::Trim,
            );
            m.push(
                cub([-hw + 0.1, -0.03, 0.15], [hw - 0.1, -0.02, 0.9]),
                Mat::Trim,
            );
            m.push(
                cub([hw - 0.2, -0.07, 0.98], [hw - 0.07, -0.045, 1.0]),
                Mat::Metal,
            );
            m.push(cyl(hw - 0.09, -0.035, 0.96, 1.02, 0.02, 0.02), Mat::Metal);
        }
        "cup" => {
            let h = r(0.08, 0.11);
            let r0 = r(0.03, 0.04);
            m.push(cyl(0.0, 0.0, 0.0, h, r0, r0 * 1.25), Mat::Main);
        }
        "bottle" => {
            let (h, rad) = (r(0.16, 0.22), r(0.03, 0.04));
            m.push(cyl(0.0, 0.0, 0.0, h, rad, rad), Mat::Main);
            m.push(cyl(0.0, 0.0, h, h + 0.06, rad, 0.013), Mat::Main);
            m.push(cyl(0.0, 0.0, h + 0.06, h + 0.08, 0.014, 0.014), Mat::Trim);
        }
        "vase" => {
            let (h, rb) = (r(0.2, 0.35), r(0.05, 0.07));
            let belly = rb * r(1.3, 1.7);
            m.push(cyl(0.0, 0.0, 0.0, h * 0.45, rb, belly), Mat::Main);
            m.push(cyl(0.0, 0.0, h * 0.45, h, belly, rb * 0.6), Mat::Main);
        }
        "book" => {
            let (w, d, t) = (r(0.15, 0.22), r(0.2, 0.28), r(0.025, 0.05));
            m.push(
                cub([-w / 2.0, -d / 2.0, 0.0], [w / 2.0, d / 2.0, t]),
                Mat::Main,
            );
        }
        _ => {
            // "box" and anything unknown.
            let (w, d, h) = (r(0.15, 0.35), r(0.15, 0.3), r(0.1, 0.3));
            m.push(
                cub([-w / 2.0, -d / 2.0, 0.0], [w / 2.0, d / 2.0, h]),
                Mat::Main,
            );
        }
    }
    m
}
