//! Test helper: points on a regular grid (shared by the geometry modules' tests).

use nalgebra::Point3;

/// Points on a grid: `f(a, b)` for a, b stepping by `step` over the two closed ranges.
pub(crate) fn grid(
    a: (f64, f64),
    b: (f64, f64),
    step: f64,
    f: impl Fn(f64, f64) -> Point3<f64>,
) -> Vec<Point3<f64>> {
    let mut out = Vec::new();
    let mut x = a.0;
    while x <= a.1 + 1e-9 {
        let mut y = b.0;
        while y <= b.1 + 1e-9 {
            out.push(f(x, y));
            y += step;
        }
        x += step;
    }
    out
}
