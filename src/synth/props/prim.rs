//! Ray intersection with the primitives the props family is built from: boxes turned about
//! the vertical, vertical frustums (cylinders and cones are special cases) and ellipsoids
//! turned about the vertical. Every primitive is closed (frustums carry their caps), and
//! every hit reports the ray parameter and the outward unit normal.

use crate::geometry::Aabb;

/// A solid in the aligned frame (z up).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Shape {
    /// Box with half-extents `half` (along its own x, y, z) centred at `c`, turned by `yaw`
    /// radians about the vertical.
    Cuboid {
        c: [f64; 3],
        half: [f64; 3],
        yaw: f64,
    },
    /// Vertical frustum with its axis at (`x`, `y`): radius `r0` at height `z0`, `r1` at
    /// `z1` (> `z0`). Equal radii make a cylinder, a zero radius a cone. Both caps closed.
    Frustum {
        x: f64,
        y: f64,
        z0: f64,
        z1: f64,
        r0: f64,
        r1: f64,
    },
    /// Ellipsoid with semi-axes `r` (along its own x, y, z) centred at `c`, turned by `yaw`.
    Ellipsoid { c: [f64; 3], r: [f64; 3], yaw: f64 },
}

/// A ray hit: parameter along the ray and outward unit normal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Hit {
    pub t: f64,
    pub n: [f64; 3],
}

/// Hits closer than this (in ray-parameter units) are ignored.
const EPS: f64 = 1e-7;

fn rot_z(v: [f64; 3], yaw: f64) -> [f64; 3] {
    let (s, c) = yaw.sin_cos();
    [c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn normalize(v: [f64; 3]) -> [f64; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if l > 0.0 {
        [v[0] / l, v[1] / l, v[2] / l]
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// Roots of a t² + b t + c = 0 in increasing order (one root when a is ~0).
fn quadratic(a: f64, b: f64, c: f64) -> Option<(f64, f64)> {
    if a.abs() < 1e-14 {
        if b.abs() < 1e-14 {
            return None;
        }
        let t = -c / b;
        return Some((t, t));
    }
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    // Numerically stable form.
    let q = -0.5 * (b + b.signum() * s);
    let (t0, t1) = if q.abs() < 1e-300 {
        let t = -b / (2.0 * a);
        (t, t)
    } else {
        (q / a, c / q)
    };
    Some((t0.min(t1), t0.max(t1)))
}

impl Shape {
    /// Exact axis-aligned bounds of the solid.
    pub fn aabb(&self) -> Aabb {
        match *self {
            Shape::Cuboid { c, half, yaw } => {
                let (s, co) = yaw.sin_cos();
                let ex = co.abs() * half[0] + s.abs() * half[1];
                let ey = s.abs() * half[0] + co.abs() * half[1];
                Aabb::new(
                    [c[0] - ex, c[1] - ey, c[2] - half[2]],
                    [c[0] + ex, c[1] + ey, c[2] + half[2]],
                )
            }
            Shape::Frustum {
                x,
                y,
                z0,
                z1,
                r0,
                r1,
            } => {
                let r = r0.max(r1);
                Aabb::new([x - r, y - r, z0], [x + r, y + r, z1])
            }
            Shape::Ellipsoid { c, r, yaw } => {
                let (s, co) = yaw.sin_cos();
                let ex = ((r[0] * co).powi(2) + (r[1] * s).powi(2)).sqrt();
                let ey = ((r[0] * s).powi(2) + (r[1] * co).powi(2)).sqrt();
                Aabb::new(
                    [c[0] - ex, c[1] - ey, c[2] - r[2]],
                    [c[0] + ex, c[1] + ey, c[2] + r[2]],
                )
            }
        }
    }

    /// The same solid turned by `yaw` about the vertical through the origin, then moved by `t`.
    pub fn placed(&self, yaw: f64, t: [f64; 3]) -> Shape {
        let mv = |p: [f64; 3]| {
            let q = rot_z(p, yaw);
            [q[0] + t[0], q[1] + t[1], q[2] + t[2]]
        };
        match *self {
            Shape::Cuboid { c, half, yaw: y0 } => Shape::Cuboid {
                c: mv(c),
                half,
                yaw: y0 + yaw,
            },
            Shape::Frustum {
                x,
                y,
                z0,
                z1,
                r0,
                r1,
            } => {
                let p = mv([x, y, 0.0]);
                Shape::Frustum {
                    x: p[0],
                    y: p[1],
                    z0: z0 + t[2],
                    z1: z1 + t[2],
                    r0,
                    r1,
                }
            }
            Shape::Ellipsoid { c, r, yaw: y0 } => Shape::Ellipsoid {
                c: mv(c),
                r,
                yaw: y0 + yaw,
            },
        }
    }

    /// First hit of the ray `o + t d` (t > 0) from outside the solid; `d` need not be unit.
    pub fn intersect(&self, o: [f64; 3], d: [f64; 3]) -> Option<Hit> {
        match *self {
            Shape::Cuboid { c, half, yaw } => cuboid_hit(c, half, yaw, o, d),
            Shape::Frustum {
                x,
                y,
                z0,
                z1,
                r0,
                r1,
            } => frustum_hit([x, y, z0], z1 - z0, r0, r1, o, d),
            Shape::Ellipsoid { c, r, yaw } => ellipsoid_hit(c, r, yaw, o, d),
        }
    }
}

fn cuboid_hit(c: [f64; 3], half: [f64; 3], yaw: f64, o: [f64; 3], d: [f64; 3]) -> Option<Hit> {
    let p = rot_z(sub(o, c), -yaw);
    let q = rot_z(d, -yaw);
    let (mut tmin, mut tmax, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0);
    for a in 0..3 {
        if q[a].abs() < 1e-300 {
            if p[a].abs() > half[a] {
                return None;
            }
            continue;
        }
        let (t0, t1) = ((-half[a] - p[a]) / q[a], (half[a] - p[a]) / q[a]);
        let (n, f) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
        if n > tmin {
            tmin = n;
            axis = a;
        }
        tmax = tmax.min(f);
    }
    if tmax < tmin || tmin <= EPS {
        return None;
    }
    let mut n = [0.0; 3];
    n[axis] = if q[axis] > 0.0 { -1.0 } else { 1.0 };
    Some(Hit {
        t: tmin,
        n: rot_z(n, yaw),
    })
}

fn frustum_hit(base: [f64; 3], h: f64, r0: f64, r1: f64, o: [f64; 3], d: [f64; 3]) -> Option<Hit> {
    let p = sub(o, base);
    let s = (r1 - r0) / h;
    let mut best: Option<Hit> = None;
    let mut take = |t: f64, n: [f64; 3]| {
        if t > EPS && best.is_none_or(|b| t < b.t) {
            best = Some(Hit { t, n });
        }
    };
    // Side: x² + y² = (r0 + s z)², 0 <= z <= h, r0 + s z >= 0.
    let rp = r0 + s * p[2];
    let a = d[0] * d[0] + d[1] * d[1] - s * s * d[2] * d[2];
    let b = 2.0 * (p[0] * d[0] + p[1] * d[1] - s * rp * d[2]);
    let cc = p[0] * p[0] + p[1] * p[1] - rp * rp;
    if let Some((t0, t1)) = quadratic(a, b, cc) {
        for t in [t0, t1] {
            let z = p[2] + t * d[2];
            let r = r0 + s * z;
            if (0.0..=h).contains(&z) && r >= 0.0 {
                let (x, y) = (p[0] + t * d[0], p[1] + t * d[1]);
                take(t, normalize([x, y, -s * r]));
            }
        }
    }
    // Caps.
    if d[2].abs() > 1e-300 {
        for (z, r, nz) in [(0.0, r0, -1.0), (h, r1, 1.0)] {
            let t = (z - p[2]) / d[2];
            let (x, y) = (p[0] + t * d[0], p[1] + t * d[1]);
            if r > 0.0 && x * x + y * y <= r * r {
                take(t, [0.0, 0.0, nz]);
            }
        }
    }
    best
}

fn ellipsoid_hit(c: [f64; 3], r: [f64; 3], yaw: f64, o: [f64; 3], d: [f64; 3]) -> Option<Hit> {
    let p = rot_z(sub(o, c), -yaw);
    let q = rot_z(d, -yaw);
    let ps = [p[0] / r[0], p[1] / r[1], p[2] / r[2]];
    let qs = [q[0] / r[0], q[1] / r[1], q[2] / r[2]];
    let a = qs[0] * qs[0] + qs[1] * qs[1] + qs[2] * qs[2];
    let b = 2.0 * (ps[0] * qs[0] + ps[1] * qs[1] + ps[2] * qs[2]);
    let cc = ps[0] * ps[0] + ps[1] * ps[1] + ps[2] * ps[2] - 1.0;
    let (t0, _) = quadratic(a, b, cc)?;
    if t0 <= EPS {
        return None;
    }
    let h = [p[0] + t0 * q[0], p[1] + t0 * q[1], p[2] + t0 * q[2]];
    let n = normalize([
        h[0] / (r[0] * r[0]),
        h[1] / (r[1] * r[1]),
        h[2] / (r[2] * r[2]),
    ]);
    Some(Hit {
        t: t0,
        n: rot_z(n, yaw),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_4, SQRT_2};

    fn close(a: [f64; 3], b: [f64; 3]) -> bool {
        (0..3).all(|i| (a[i] - b[i]).abs() < 1e-9)
    }

    fn hit(s: &Shape, o: [f64; 3], d: [f64; 3]) -> Hit {
        s.intersect(o, d)
            .unwrap_or_else(|| panic!("{s:?} missed from {o:?} along {d:?}"))
    }

    const CYL: Shape = Shape::Frustum {
        x: 1.0,
        y: 2.0,
        z0: 0.0,
        z1: 1.0,
        r0: 0.5,
        r1: 0.5,
    };

    #[test]
    fn cylinder_side_and_cap() {
        // Horizontal ray towards the axis: hits the side at distance 3 - 0.5.
        let h = hit(&CYL, [1.0, -1.0, 0.5], [0.0, 1.0, 0.0]);
        assert!((h.t - 2.5).abs() < 1e-9, "{h:?}");
        assert!(close(h.n, [0.0, -1.0, 0.0]), "{h:?}");
        // Oblique ray, non-unit direction: the hit lies on the side and the normal is radial.
        let (o, d) = ([-2.0, 0.0, 0.3], [2.0, 1.5, 0.1]);
        let h = hit(&CYL, o, d);
        let p = [o[0] + h.t * d[0], o[1] + h.t * d[1], o[2] + h.t * d[2]];
        let r = ((p[0] - 1.0).powi(2) + (p[1] - 2.0).powi(2)).sqrt();
        assert!((r - 0.5).abs() < 1e-9, "{p:?}");
        assert!(close(h.n, [(p[0] - 1.0) / 0.5, (p[1] - 2.0) / 0.5, 0.0]));
        // From above: the top cap.
        let h = hit(&CYL, [1.2, 2.1, 3.0], [0.0, 0.0, -2.0]);
        assert!(
            (h.t - 1.0).abs() < 1e-9 && close(h.n, [0.0, 0.0, 1.0]),
            "{h:?}"
        );
        // From below the floor plane: the bottom cap.
        let h = hit(&CYL, [1.0, 2.0, -1.0], [0.0, 0.0, 1.0]);
        assert!(
            (h.t - 1.0).abs() < 1e-9 && close(h.n, [0.0, 0.0, -1.0]),
            "{h:?}"
        );
        // Misses: passes beside, passes above, points away.
        assert!(CYL.intersect([1.6, -1.0, 0.5], [0.0, 1.0, 0.0]).is_none());
        assert!(CYL.intersect([1.0, -1.0, 1.2], [0.0, 1.0, 0.0]).is_none());
        assert!(CYL.intersect([1.0, -1.0, 0.5], [0.0, -1.0, 0.0]).is_none());
    }

    #[test]
    fn cone_side_hit_and_normal() {
        // Cone of radius 1 at z = 0 narrowing to its apex at z = 1: at z = 0.5 the radius is 0.5
        // and the outward normal leans 45° upwards.
        let cone = Shape::Frustum {
            x: 0.0,
            y: 0.0,
            z0: 0.0,
            z1: 1.0,
            r0: 1.0,
            r1: 0.0,
        };
        let h = hit(&cone, [-5.0, 0.0, 0.5], [1.0, 0.0, 0.0]);
        assert!((h.t - 4.5).abs() < 1e-9, "{h:?}");
        assert!(close(h.n, [-1.0 / SQRT_2, 0.0, 1.0 / SQRT_2]), "{h:?}");
        // Above the apex nothing (the mirrored cone of the quadric is excluded).
        assert!(cone.intersect([-5.0, 0.0, 1.5], [1.0, 0.0, 0.0]).is_none());
        // A lamp shade: wider at the bottom (r 0.3 at z 1.2, r 0.15 at z 1.5); a ray straight
        // down the axis hits the top cap, one from below the bottom cap.
        let shade = Shape::Frustum {
            x: 0.0,
            y: 0.0,
            z0: 1.2,
            z1: 1.5,
            r0: 0.3,
            r1: 0.15,
        };
        let h = hit(&shade, [0.0, 0.0, 2.0], [0.0, 0.0, -1.0]);
        assert!((h.t - 0.5).abs() < 1e-9 && close(h.n, [0.0, 0.0, 1.0]));
        let h = hit(&shade, [0.25, 0.0, 0.0], [0.0, 0.0, 1.0]);
        assert!((h.t - 1.2).abs() < 1e-9 && close(h.n, [0.0, 0.0, -1.0]));
        // Horizontal ray at z = 1.35: radius 0.225, slope -0.5 -> normal ∝ (-1, 0, 0.5).
        let h = hit(&shade, [-2.0, 0.0, 1.35], [1.0, 0.0, 0.0]);
        assert!((h.t - (2.0 - 0.225)).abs() < 1e-9, "{h:?}");
        let k = 1.0 / 1.25f64.sqrt();
        assert!(close(h.n, [-k, 0.0, 0.5 * k]), "{h:?}");
    }

    #[test]
    fn sphere_and_ellipsoid() {
        let s = Shape::Ellipsoid {
            c: [1.0, 1.0, 1.0],
            r: [0.5; 3],
            yaw: 0.3,
        };
        let h = hit(&s, [1.0, 1.0, 5.0], [0.0, 0.0, -2.0]);
        assert!(
            (h.t - 1.75).abs() < 1e-9 && close(h.n, [0.0, 0.0, 1.0]),
            "{h:?}"
        );
        // Oblique: the normal of a sphere is the radial direction.
        let (o, d) = ([-1.0, 0.8, 1.1], [1.0, 0.05, 0.0]);
        let h = hit(&s, o, d);
        let p = [o[0] + h.t * d[0], o[1] + h.t * d[1], o[2] + h.t * d[2]];
        assert!(close(
            h.n,
            [(p[0] - 1.0) / 0.5, (p[1] - 1.0) / 0.5, (p[2] - 1.0) / 0.5]
        ));
        assert!(s.intersect([1.0, 1.6, 5.0], [0.0, 0.0, -1.0]).is_none());
        // Ellipsoid turned by 90°: its long semi-axis (0.8 along its own x) now lies along y.
        let e = Shape::Ellipsoid {
            c: [0.0, 0.0, 0.0],
            r: [0.8, 0.2, 0.4],
            yaw: std::f64::consts::FRAC_PI_2,
        };
        let h = hit(&e, [0.0, -3.0, 0.0], [0.0, 1.0, 0.0]);
        assert!(
            (h.t - 2.2).abs() < 1e-9 && close(h.n, [0.0, -1.0, 0.0]),
            "{h:?}"
        );
        let h = hit(&e, [-3.0, 0.0, 0.0], [1.0, 0.0, 0.0]);
        assert!(
            (h.t - 2.8).abs() < 1e-9 && close(h.n, [-1.0, 0.0, 0.0]),
            "{h:?}"
        );
        let b = e.aabb();
        assert!(close(b.min, [-0.2, -0.8, -0.4]) && close(b.max, [0.2, 0.8, 0.4]));
    }

    #[test]
    fn turned_cuboid_hit_normal_and_bounds() {
        // A unit cube turned by 45°: its corner points at -x, sqrt(2)/2 from the centre.
        let c = Shape::Cuboid {
            c: [0.0, 0.0, 0.5],
            half: [0.5; 3],
            yaw: FRAC_PI_4,
        };
        let h = hit(&c, [-3.0, 0.1, 0.5], [1.0, 0.0, 0.0]);
        // The face x' = -0.5 (or y' = ±0.5) of the turned cube: x + y = -sqrt(2)/2 for y > 0.
        assert!((h.t - (3.0 - SQRT_2 / 2.0 + 0.1)).abs() < 1e-9, "{h:?}");
        assert!(close(h.n, [-1.0 / SQRT_2, 1.0 / SQRT_2, 0.0]), "{h:?}");
        let b = c.aabb();
        assert!(close(b.max, [SQRT_2 / 2.0, SQRT_2 / 2.0, 1.0]), "{b:?}");
        // Placement composes: a box at (1, 0) turned by 90° lands at (0, 1).
        let p = Shape::Cuboid {
            c: [1.0, 0.0, 0.0],
            half: [0.2, 0.1, 0.1],
            yaw: 0.0,
        }
        .placed(std::f64::consts::FRAC_PI_2, [0.0, 0.0, 1.0]);
        let b = p.aabb();
        assert!(
            close(b.min, [-0.1, 0.8, 0.9]) && close(b.max, [0.1, 1.2, 1.1]),
            "{b:?}"
        );
    }
}
