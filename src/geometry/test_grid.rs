//! Test helpers: points on a regular grid and a noisy fixed-seed cloud (shared by the
//! geometry modules' tests).

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

/// Noisy points on three touching planes plus strays, from a fixed-seed generator;
/// coordinates on a millimetre grid so that equal distances (ties) occur.
pub(crate) fn noisy_planes(n: usize, seed: u64) -> Vec<Point3<f64>> {
    let mut x = seed;
    let mut r = move || {
        x = x
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (x >> 33) as f64 / (1u64 << 31) as f64
    };
    (0..n)
        .map(|i| {
            let (a, b, c) = (r(), r(), 0.01 * r());
            let p = match i % 4 {
                0 => [a, b, c],
                1 => [a, c, b],
                2 => [c, a, b],
                _ => [3.0 * a - 1.0, 3.0 * b - 1.0, 3.0 * r() - 1.0],
            };
            Point3::new(
                (p[0] * 1000.0).round() / 1000.0,
                (p[1] * 1000.0).round() / 1000.0,
                (p[2] * 1000.0).round() / 1000.0,
            )
        })
        .collect()
}
