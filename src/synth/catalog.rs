//! Furniture catalogue: labels, colour names, realistic sizes and the boxes each piece is
//! built from (in a local frame: x in [0, w], y in [0, d] with the back at y = d, z up).

use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// Colour names and their linear-RGB albedo.
pub(crate) const PALETTE: &[(&str, [f64; 3])] = &[
    ("red", [0.55, 0.06, 0.05]),
    ("blue", [0.06, 0.14, 0.50]),
    ("green", [0.08, 0.35, 0.09]),
    ("yellow", [0.70, 0.55, 0.06]),
    ("white", [0.78, 0.78, 0.75]),
    ("black", [0.03, 0.03, 0.035]),
    ("brown", [0.25, 0.12, 0.05]),
    ("grey", [0.28, 0.28, 0.29]),
    ("orange", [0.75, 0.25, 0.03]),
    ("purple", [0.25, 0.07, 0.35]),
    ("pink", [0.80, 0.35, 0.45]),
    ("beige", [0.60, 0.50, 0.35]),
];

pub(crate) fn palette(name: &str) -> [f64; 3] {
    PALETTE
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, c)| *c)
        .unwrap_or([0.5, 0.5, 0.5])
}

/// Plausible colour names per label.
pub(crate) fn colours_for(label: &str) -> &'static [&'static str] {
    match label {
        "chair" => &["brown", "black", "red", "blue", "white", "green", "grey"],
        "table" | "desk" => &["brown", "white", "black"],
        "cabinet" | "bookshelf" => &["white", "brown", "grey", "black"],
        "bed" => &["white", "blue", "grey", "beige"],
        "sofa" => &["grey", "blue", "green", "red", "beige"],
        "trash can" => &["black", "grey", "blue", "green"],
        "monitor" => &["black", "white", "grey"],
        "nightstand" => &["brown", "white"],
        "lamp" => &["white", "black", "yellow"],
        "pillow" => &["white", "red", "blue", "yellow", "green", "orange", "pink"],
        "door" => &["brown", "white"],
        "window" => &["white", "black", "brown"],
        "picture" => &["red", "blue", "green", "yellow", "orange", "purple"],
        "box" => &["brown", "white", "orange"],
        _ => &["grey"],
    }
}

/// A part in the object's local frame: x in [0, w], y in [0, d] (back at y = d), z up.
pub(crate) type Part = ([f64; 3], [f64; 3]);

fn bx(x0: f64, y0: f64, z0: f64, x1: f64, y1: f64, z1: f64) -> Part {
    ([x0, y0, z0], [x1, y1, z1])
}

/// Local parts of a label with footprint w x d and height h.
pub(crate) fn parts_of(label: &str, w: f64, d: f64, h: f64) -> Vec<Part> {
    let leg = 0.045;
    let legs = |top: f64| {
        vec![
            bx(0.0, 0.0, 0.0, leg, leg, top),
            bx(w - leg, 0.0, 0.0, w, leg, top),
            bx(0.0, d - leg, 0.0, leg, d, top),
            bx(w - leg, d - leg, 0.0, w, d, top),
        ]
    };
    match label {
        "chair" => {
            let seat = 0.45;
            let mut p = legs(seat - 0.05);
            p.push(bx(0.0, 0.0, seat - 0.05, w, d, seat));
            p.push(bx(0.0, d - 0.06, seat, w, d, h));
            p
        }
        "table" => {
            let mut p = legs(h - 0.04);
            p.push(bx(0.0, 0.0, h - 0.04, w, d, h));
            p
        }
        "desk" => vec![
            bx(0.0, 0.0, h - 0.04, w, d, h),
            bx(0.0, 0.05, 0.0, 0.04, d, h - 0.04),
            bx(w - 0.04, 0.05, 0.0, w, d, h - 0.04),
        ],
        "bed" => vec![
            bx(0.0, 0.0, 0.0, w, d - 0.06, 0.5),
            bx(0.0, d - 0.06, 0.0, w, d, h),
        ],
        "sofa" => vec![
            bx(0.0, 0.0, 0.0, w, d - 0.2, 0.42),
            bx(0.0, d - 0.2, 0.0, w, d, h),
            bx(0.0, 0.0, 0.42, 0.18, d - 0.2, 0.62),
            bx(w - 0.18, 0.0, 0.42, w, d - 0.2, 0.62),
        ],
        "bookshelf" => {
            let t = 0.03;
            let mut p = vec![
                bx(0.0, d - t, 0.0, w, d, h),
                bx(0.0, 0.0, 0.0, t, d - t, h),
                bx(w - t, 0.0, 0.0, w, d - t, h),
            ];
            for k in 0..5 {
                let z = k as f64 * (h - t) / 4.0;
                p.push(bx(t, 0.0, z, w - t, d - t, z + t));
            }
            p
        }
        "monitor" => vec![
            bx(w * 0.4, d * 0.3, 0.0, w * 0.6, d * 0.7, 0.02),
            bx(w * 0.45, d * 0.45, 0.02, w * 0.55, d * 0.6, 0.12),
            bx(0.0, d * 0.6, 0.12, w, d, h),
        ],
        "lamp" => {
            let pole = 0.035;
            let (cx, cy) = (w / 2.0, d / 2.0);
            vec![
                bx(cx - 0.1, cy - 0.1, 0.0, cx + 0.1, cy + 0.1, 0.03),
                bx(
                    cx - pole / 2.0,
                    cy - pole / 2.0,
                    0.03,
                    cx + pole / 2.0,
                    cy + pole / 2.0,
                    h - 0.22,
                ),
                bx(0.0, 0.0, h - 0.22, w, d, h),
            ]
        }
        _ => vec![bx(0.0, 0.0, 0.0, w, d, h)],
    }
}

/// Size ranges (w, d, h) per label.
pub(crate) fn size_of(label: &str, rng: &mut ChaCha8Rng) -> (f64, f64, f64) {
    let mut r = |a: f64, b: f64| rng.gen_range(a..b);
    match label {
        "chair" => (r(0.42, 0.5), r(0.42, 0.5), r(0.85, 1.0)),
        "table" => (r(1.2, 1.6), r(0.8, 1.0), r(0.72, 0.78)),
        "desk" => (r(1.1, 1.5), r(0.6, 0.75), r(0.72, 0.76)),
        "cabinet" => (r(0.6, 1.2), r(0.4, 0.6), r(0.8, 1.9)),
        "bed" => (r(1.4, 1.8), r(1.95, 2.1), r(0.9, 1.1)),
        "sofa" => (r(1.7, 2.2), r(0.85, 0.95), r(0.8, 0.9)),
        "bookshelf" => (r(0.7, 1.0), r(0.3, 0.38), r(1.7, 2.0)),
        "trash can" => (r(0.25, 0.35), r(0.25, 0.35), r(0.35, 0.5)),
        "monitor" => (r(0.5, 0.65), r(0.18, 0.22), r(0.42, 0.5)),
        "nightstand" => (r(0.4, 0.5), r(0.38, 0.45), r(0.5, 0.6)),
        "lamp" => (r(0.25, 0.35), r(0.25, 0.35), r(1.4, 1.7)),
        "table lamp" => (r(0.22, 0.3), r(0.22, 0.3), r(0.4, 0.5)),
        "pillow" => (r(0.5, 0.65), r(0.35, 0.42), r(0.12, 0.18)),
        "door" => (r(0.85, 0.95), 0.05, r(2.0, 2.1)),
        "window" => (r(1.0, 1.5), 0.06, r(1.0, 1.3)),
        "picture" => (r(0.4, 0.8), 0.03, r(0.35, 0.6)),
        "box" => (r(0.3, 0.6), r(0.3, 0.5), r(0.25, 0.5)),
        _ => (0.5, 0.5, 0.5),
    }
}
