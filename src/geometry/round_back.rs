//! The hidden back of a round object seen from one side (ours, not the paper's).
//!
//! A cup, a bottle or a plant pot seen from one side shows the half of its round body that
//! faces the camera: the box of those points is as wide as the object but only about half
//! as deep. A round body is as deep as it is wide, so when the points' near surface follows
//! a circular arc, the box is widened away from the camera to the square that holds that
//! circle. A box-like object seen at its corner also shows a near surface bulging towards
//! the camera, but two straight faces meeting at a right angle: the best circle through
//! them misses them by about 4.6 % of their width (5 % and more when the corner is off
//! centre), against the one or two percent of a round body's depth noise. Its box needs no
//! completion anyway: both visible faces span the object's whole extent along the room's
//! axes.

use nalgebra::{Point3, Vector2};
use serde::{Deserialize, Serialize};

use super::support_layer::percentile;
use super::Aabb;

/// Settings of [`round_back`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RoundBackParams {
    /// Off: the box is what the views measured.
    pub enabled: bool,
    /// Seen from one side: the points' depth along the line of sight is less than this
    /// share of their width across it (a half circle's is 0.5).
    pub max_depth_ratio: f64,
    /// The near surface bulges towards the camera: the nearest points of the outer sixths
    /// of the width lie at least this share of the width behind those of the middle third
    /// (about 0.15 for a half circle, 0 or less for a flat face).
    pub min_bulge: f64,
    /// The near surface is an arc: root-mean-square distance of its profile from the best
    /// circle, as a share of the width (a right-angled corner: 0.046).
    pub max_arc_rms: f64,
    /// Fewer fused points than this: no completion.
    pub min_points: usize,
}

impl Default for RoundBackParams {
    fn default() -> Self {
        Self {
            enabled: true,
            max_depth_ratio: 0.8,
            min_bulge: 0.07,
            max_arc_rms: 0.03,
            min_points: 20,
        }
    }
}

/// What [`round_back`] measured and decided (for the trace).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct RoundBack {
    /// The box was widened.
    pub applied: bool,
    /// Why not, when it was not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub skipped: Option<&'static str>,
    /// Width across the line of sight (m).
    pub width: f64,
    /// Depth along the line of sight over the width.
    pub depth_ratio: f64,
    /// Bulge towards the camera over the width.
    pub bulge: f64,
    /// The arc fit's root-mean-square error over the width.
    pub arc_rms: f64,
}

/// Percentiles `qs` (fractions, 0–1) of `v` (not empty), sorting it once.
fn sorted_percentiles<const N: usize>(mut v: Vec<f64>, qs: [f64; N]) -> [f64; N] {
    v.sort_by(f64::total_cmp);
    qs.map(|q| percentile(&v, q))
}

/// Algebraic least-squares circle through 2D points `(a, b)`: `(centre_a, centre_b, r)`.
fn fit_circle(pts: &[(f64, f64)]) -> Option<(f64, f64, f64)> {
    // x² + y² + D x + E y + F = 0, solved in the normal equations.
    let mut m = nalgebra::Matrix3::<f64>::zeros();
    let mut rhs = nalgebra::Vector3::<f64>::zeros();
    for &(a, b) in pts {
        let row = nalgebra::Vector3::new(a, b, 1.0);
        m += row * row.transpose();
        rhs += row * -(a * a + b * b);
    }
    let s = m.lu().solve(&rhs)?;
    let (ca, cb) = (-s[0] / 2.0, -s[1] / 2.0);
    let r2 = ca * ca + cb * cb - s[2];
    (r2 > 0.0 && r2.is_finite()).then(|| (ca, cb, r2.sqrt()))
}

/// Widen `bbox` horizontally to hold the round body whose near side `points` are, as seen
/// from `eye` (the chosen view's camera centre); z is the up axis. `side_placed`: support
/// completion already moved a side face (onto a wall behind), which then stays. Returns
/// the box (the same when no completion applies) and what was measured.
pub fn round_back(
    bbox: &Aabb,
    points: &[Point3<f64>],
    eye: Point3<f64>,
    side_placed: bool,
    params: &RoundBackParams,
) -> (Aabb, RoundBack) {
    let mut rec = RoundBack::default();
    let skip = |mut rec: RoundBack, why: &'static str| {
        rec.skipped = Some(why);
        (*bbox, rec)
    };
    if !params.enabled {
        return skip(rec, "off");
    }
    if side_placed {
        return skip(rec, "side placed by support");
    }
    if points.len() < params.min_points.max(3) {
        return skip(rec, "few points");
    }
    // Line of sight (horizontal) to the points' median, and across it.
    let [cx] = sorted_percentiles(points.iter().map(|p| p.x).collect(), [0.5]);
    let [cy] = sorted_percentiles(points.iter().map(|p| p.y).collect(), [0.5]);
    let centre = Vector2::new(cx, cy);
    let e = Vector2::new(eye.x, eye.y);
    let Some(d) = (centre - e).try_normalize(1e-9) else {
        return skip(rec, "above the camera");
    };
    let n = Vector2::new(-d.y, d.x);
    let uv: Vec<(f64, f64)> = points
        .iter()
        .map(|p| {
            let q = Vector2::new(p.x, p.y) - e;
            (q.dot(&d), q.dot(&n))
        })
        .collect();
    let [u0, u1] = sorted_percentiles(uv.iter().map(|p| p.0).collect(), [0.02, 0.98]);
    let [v0, v1] = sorted_percentiles(uv.iter().map(|p| p.1).collect(), [0.02, 0.98]);
    let w = v1 - v0;
    if w <= 1e-6 {
        return skip(rec, "no width");
    }
    rec.width = w;
    rec.depth_ratio = (u1 - u0) / w;
    if rec.depth_ratio >= params.max_depth_ratio {
        return skip(rec, "seen in depth");
    }
    // Bulge: nearest points (10th percentile of depth) of the outer sixths against the
    // middle third.
    let t = |v: f64| (v - v0) / w;
    let mid: Vec<f64> = uv
        .iter()
        .filter(|p| (1.0 / 3.0..2.0 / 3.0).contains(&t(p.1)))
        .map(|p| p.0)
        .collect();
    let out: Vec<f64> = uv
        .iter()
        .filter(|p| t(p.1) < 1.0 / 6.0 || t(p.1) > 5.0 / 6.0)
        .map(|p| p.0)
        .collect();
    if mid.len() < 5 || out.len() < 5 {
        return skip(rec, "few points across");
    }
    let ([out_near], [mid_near]) = (
        sorted_percentiles(out, [0.1]),
        sorted_percentiles(mid, [0.1]),
    );
    rec.bulge = (out_near - mid_near) / w;
    if rec.bulge < params.min_bulge {
        return skip(rec, "no bulge");
    }
    // The near surface's profile: the nearest point of each of up to 24 strips (1 cm or
    // wider) across the width, and the circle that best fits it.
    let bins = ((w / 0.01) as usize).clamp(6, 24);
    let mut profile: Vec<Option<(f64, Vec<f64>)>> = vec![None; bins];
    for &(u, v) in &uv {
        // Points outside the 2nd..98th percentiles join the outer strips.
        let k = ((t(v) * bins as f64) as usize).min(bins - 1);
        let strip = profile[k].get_or_insert((f64::INFINITY, Vec::new()));
        strip.0 = strip.0.min(u);
        strip.1.push(v);
    }
    let env: Vec<(f64, f64)> = profile
        .into_iter()
        .flatten()
        .map(|(u, v)| {
            let [median] = sorted_percentiles(v, [0.5]);
            (u, median)
        })
        .collect();
    let Some((cu, cv, r)) = fit_circle(&env) else {
        return skip(rec, "no arc");
    };
    let rms = (env
        .iter()
        .map(|&(u, v)| ((u - cu).hypot(v - cv) - r).powi(2))
        .sum::<f64>()
        / env.len() as f64)
        .sqrt();
    rec.arc_rms = rms / w;
    let nearest = env.iter().map(|p| p.0).fold(f64::INFINITY, f64::min);
    if rec.arc_rms > params.max_arc_rms || r > w || cu <= nearest {
        return skip(rec, "not an arc");
    }
    // The body: a disc as wide as the points, its front where the points' front is.
    let c = e + d * (u0 + w / 2.0) + n * ((v0 + v1) / 2.0);
    let half = w / 2.0;
    let mut out_box = *bbox;
    for (a, c) in [c.x, c.y].into_iter().enumerate() {
        out_box.min[a] = out_box.min[a].min(c - half);
        out_box.max[a] = out_box.max[a].max(c + half);
    }
    rec.applied = true;
    (out_box, rec)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points of the side of a vertical surface given by its horizontal profile over
    /// `t` in 0..=1, 12 cm high.
    fn wall_of(profile: impl Fn(f64) -> (f64, f64), steps: usize) -> Vec<Point3<f64>> {
        let mut pts = Vec::new();
        for i in 0..=steps {
            let (x, y) = profile(i as f64 / steps as f64);
            for k in 0..12 {
                pts.push(Point3::new(x, y, 1.0 + 0.01 * k as f64));
            }
        }
        pts
    }

    /// The points' box, and [`round_back`] of it seen from the origin with the defaults.
    fn complete(pts: &[Point3<f64>]) -> (Aabb, Aabb, RoundBack) {
        let b = Aabb::from_points(pts).expect("points");
        let (out, rec) = round_back(
            &b,
            pts,
            Point3::origin(),
            false,
            &RoundBackParams::default(),
        );
        (b, out, rec)
    }

    #[test]
    fn a_cylinder_seen_from_one_side_gets_its_back() {
        // A 4 cm radius cup at (2, 0), seen from the origin: the half facing the camera
        // (angles 100..260 degrees around its axis, the silhouette's edges unmeasured).
        let (cx, r) = (2.0, 0.04);
        let pts = wall_of(
            |t| {
                let a = (100.0 + 160.0 * t).to_radians();
                (cx + r * a.cos(), r * a.sin())
            },
            40,
        );
        let (b, out, rec) = complete(&pts);
        assert!(b.max[0] - b.min[0] < 0.5 * 2.0 * r, "one-sided: {b:?}");
        assert!(rec.applied, "{rec:?}");
        let depth = out.max[0] - out.min[0];
        assert!((depth - 2.0 * r).abs() < 0.012, "depth {depth} ({rec:?})");
        // Behind the front, not in front of it; z untouched.
        assert!((out.min[0] - b.min[0]).abs() < 1e-9 && out.max[0] > b.max[0]);
        assert_eq!((out.min[2], out.max[2]), (b.min[2], b.max[2]));
        // Off: the box stays.
        let off = RoundBackParams {
            enabled: false,
            ..RoundBackParams::default()
        };
        assert_eq!(round_back(&b, &pts, Point3::origin(), false, &off).0, b);
        // Support placed a side face: it stays.
        let on = RoundBackParams::default();
        let (kept, rec) = round_back(&b, &pts, Point3::origin(), true, &on);
        assert_eq!((kept, rec.skipped), (b, Some("side placed by support")));
    }

    #[test]
    fn a_box_corner_and_a_flat_face_keep_their_box() {
        // A 40 cm cabinet's corner towards the camera: two faces at right angles.
        let k = std::f64::consts::FRAC_1_SQRT_2;
        let corner = wall_of(
            |t| {
                let s = 0.4 * (2.0 * t - 1.0);
                (2.0 + s.abs() * k, s * k)
            },
            40,
        );
        let (b, out, rec) = complete(&corner);
        assert!(!rec.applied && out == b, "{rec:?}");
        assert_eq!(rec.skipped, Some("not an arc"), "{rec:?}");
        // A picture's flat face, head on.
        let (b, out, rec) = complete(&wall_of(|t| (2.0, 0.3 * t - 0.15), 30));
        assert!(!rec.applied && out == b, "{rec:?}");
        // A cylinder seen all round: deep enough already.
        let full = wall_of(
            |t| {
                let a = (360.0 * t).to_radians();
                (2.0 + 0.05 * a.cos(), 0.05 * a.sin())
            },
            60,
        );
        let (_, _, rec) = complete(&full);
        assert_eq!(rec.skipped, Some("seen in depth"), "{rec:?}");
    }
}
