//! 2D boxes answered by a VLM (`detector = "vlm"`): the coordinate conventions the main
//! model families use, and a tolerant reader that turns a reply into a box in pixels or
//! says exactly why it cannot be used.
//!
//! Conventions ([`BoxFormat`]): `pixels` — [x1, y1, x2, y2] in the frame's pixels (Qwen2.5-VL
//! and later); `norm1000` — [x1, y1, x2, y2] scaled to 0–1000 (Qwen-VL, many fine-tunes);
//! `yxyx1000` — [ymin, xmin, ymax, xmax] scaled to 0–1000 (Gemini). Replies are read from
//! the `bbox_2d` key (also `bbox`, `box`, `box_2d`), as numbers, numeric strings, or one
//! nested list; `null` means "not in this frame".

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::json::extract_json;

/// How the VLM writes a box.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BoxFormat {
    /// [x1, y1, x2, y2] in pixels of the frame.
    #[default]
    Pixels,
    /// [x1, y1, x2, y2], each coordinate scaled to 0–1000 of the frame's size.
    Norm1000,
    /// [ymin, xmin, ymax, xmax], each scaled to 0–1000.
    Yxyx1000,
}

impl BoxFormat {
    /// The name used in settings and prompts.
    pub fn name(self) -> &'static str {
        match self {
            BoxFormat::Pixels => "pixels",
            BoxFormat::Norm1000 => "norm1000",
            BoxFormat::Yxyx1000 => "yxyx1000",
        }
    }

    /// Read a name (as in settings).
    pub fn parse(name: &str) -> Option<Self> {
        match name.trim().to_ascii_lowercase().as_str() {
            "pixels" | "pixel" | "absolute" => Some(BoxFormat::Pixels),
            "norm1000" | "normalized" | "normalised" => Some(BoxFormat::Norm1000),
            "yxyx1000" | "gemini" => Some(BoxFormat::Yxyx1000),
            _ => None,
        }
    }

    /// One sentence saying what the four numbers are, for a frame of `w` x `h` pixels.
    pub fn help(self, w: u32, h: u32) -> String {
        match self {
            BoxFormat::Pixels => {
                format!("[left, top, right, bottom] in pixels, x from 0 to {w} and y from 0 to {h}")
            }
            BoxFormat::Norm1000 => "[left, top, right, bottom], each scaled so that the frame's \
                width and height both run from 0 to 1000"
                .to_string(),
            BoxFormat::Yxyx1000 => "[top, left, bottom, right], each scaled so that the frame's \
                width and height both run from 0 to 1000"
                .to_string(),
        }
    }

    /// The box in this format for a pixel box (what a correct answer holds).
    pub fn encode(self, b: [f32; 4], (w, h): (u32, u32)) -> [f32; 4] {
        let (sx, sy) = (1000.0 / w.max(1) as f32, 1000.0 / h.max(1) as f32);
        match self {
            BoxFormat::Pixels => b,
            BoxFormat::Norm1000 => [b[0] * sx, b[1] * sy, b[2] * sx, b[3] * sy],
            BoxFormat::Yxyx1000 => [b[1] * sy, b[0] * sx, b[3] * sy, b[2] * sx],
        }
    }

    /// The pixel box for four numbers in this format.
    pub fn decode(self, n: [f64; 4], (w, h): (u32, u32)) -> [f64; 4] {
        let (sx, sy) = (f64::from(w) / 1000.0, f64::from(h) / 1000.0);
        match self {
            BoxFormat::Pixels => n,
            BoxFormat::Norm1000 => [n[0] * sx, n[1] * sy, n[2] * sx, n[3] * sy],
            BoxFormat::Yxyx1000 => [n[1] * sx, n[0] * sy, n[3] * sx, n[2] * sy],
        }
    }
}

/// Why a box reply cannot be used (the text goes into the feedback).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BoxError {
    #[error("no JSON object with a \"bbox_2d\" key was found")]
    Unparsable,
    #[error("\"bbox_2d\" must hold four numbers, found {0}")]
    NotFourNumbers(String),
    #[error("the box {0:?} lies outside the {1} x {2} frame")]
    Outside([f64; 4], u32, u32),
    #[error("the box {0:?} has no area (right must exceed left and bottom must exceed top)")]
    Degenerate([f64; 4]),
}

/// A VLM's box answer.
#[derive(Debug, Clone, PartialEq)]
pub struct BoxAnswer {
    pub reasoning: String,
    /// The box in pixels, clipped to the frame; `None` when the model says the object is
    /// not in the frame.
    pub bbox: Option<[f32; 4]>,
    /// The four numbers as the model wrote them.
    pub raw: Option<[f64; 4]>,
}

fn number(v: &Value) -> Option<f64> {
    match v {
        Value::Number(n) => n.as_f64(),
        Value::String(s) => s.trim().parse().ok(),
        _ => None,
    }
}

fn four(v: &Value) -> Result<[f64; 4], BoxError> {
    let wrong = || BoxError::NotFourNumbers(v.to_string());
    let a = match v {
        Value::Array(a) if a.len() == 1 && a[0].is_array() => return four(&a[0]),
        Value::Array(a) => a,
        _ => return Err(wrong()),
    };
    if a.len() != 4 {
        return Err(wrong());
    }
    let mut out = [0.0; 4];
    for (o, x) in out.iter_mut().zip(a) {
        *o = number(x).filter(|f| f.is_finite()).ok_or_else(wrong)?;
    }
    Ok(out)
}

/// Read a box reply for a frame of `size` pixels written in `format`. A box that pokes out
/// of the frame by up to 2 % of its size is clipped; one further out, or with no area, is an
/// error.
pub fn parse_box(text: &str, format: BoxFormat, size: (u32, u32)) -> Result<BoxAnswer, BoxError> {
    let v = extract_json(text).map_err(|_| BoxError::Unparsable)?;
    let reasoning = match v.get("reasoning") {
        Some(Value::String(s)) => s.clone(),
        _ => String::new(),
    };
    let field = ["bbox_2d", "bbox", "box_2d", "box"]
        .iter()
        .find_map(|k| v.get(*k))
        .ok_or(BoxError::Unparsable)?;
    if field.is_null() {
        return Ok(BoxAnswer {
            reasoning,
            bbox: None,
            raw: None,
        });
    }
    let raw = four(field)?;
    let b = format.decode(raw, size);
    let (w, h) = (f64::from(size.0), f64::from(size.1));
    let (tx, ty) = (0.02 * w, 0.02 * h);
    if b[0] < -tx || b[1] < -ty || b[2] > w + tx || b[3] > h + ty {
        return Err(BoxError::Outside(b, size.0, size.1));
    }
    let c = [
        b[0].clamp(0.0, w),
        b[1].clamp(0.0, h),
        b[2].clamp(0.0, w),
        b[3].clamp(0.0, h),
    ];
    if c[2] - c[0] < 2.0 || c[3] - c[1] < 2.0 {
        return Err(BoxError::Degenerate(b));
    }
    Ok(BoxAnswer {
        reasoning,
        bbox: Some(c.map(|x| x as f32)),
        raw: Some(raw),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const SIZE: (u32, u32) = (640, 480);

    #[test]
    fn each_convention_round_trips() {
        let b = [64.0f32, 48.0, 320.0, 240.0];
        for f in [BoxFormat::Pixels, BoxFormat::Norm1000, BoxFormat::Yxyx1000] {
            let e = f.encode(b, SIZE);
            let text = format!(
                "{{\"reasoning\": \"x\", \"bbox_2d\": [{}, {}, {}, {}]}}",
                e[0], e[1], e[2], e[3]
            );
            let got = parse_box(&text, f, SIZE).unwrap().bbox.unwrap();
            for k in 0..4 {
                assert!((got[k] - b[k]).abs() < 0.01, "{f:?}: {got:?}");
            }
        }
        // The norm1000 box read as pixels is a different box.
        let e = BoxFormat::Yxyx1000.encode(b, SIZE);
        assert_ne!(
            BoxFormat::Pixels.decode(e.map(f64::from), SIZE),
            [64.0, 48.0, 320.0, 240.0]
        );
    }

    #[test]
    fn tolerant_reading() {
        let cases = [
            "```json\n{\"bbox_2d\": [\"10\", \"20\", \"110\", \"220\"]}\n```",
            "[{\"bbox_2d\": [10, 20, 110, 220], \"label\": \"lamp\"}]",
            "{'bbox': [[10, 20, 110, 220]], 'reasoning': 'left'}",
            "The box is {\"box_2d\": [10, 20, 110, 220],}",
        ];
        for c in cases {
            let a = parse_box(c, BoxFormat::Pixels, SIZE).unwrap_or_else(|e| panic!("{c}: {e}"));
            assert_eq!(a.bbox, Some([10.0, 20.0, 110.0, 220.0]), "{c}");
        }
        let none = parse_box(
            "{\"reasoning\": \"not here\", \"bbox_2d\": null}",
            BoxFormat::Pixels,
            SIZE,
        );
        assert_eq!(none.unwrap().bbox, None);
    }

    #[test]
    fn bad_boxes_are_refused_with_a_reason() {
        let p = |t: &str| parse_box(t, BoxFormat::Pixels, SIZE);
        assert!(matches!(p("no json here"), Err(BoxError::Unparsable)));
        assert!(matches!(
            p("{\"bbox_2d\": [1, 2, 3]}"),
            Err(BoxError::NotFourNumbers(_))
        ));
        assert!(matches!(
            p("{\"bbox_2d\": [1, 2, \"a\", 4]}"),
            Err(BoxError::NotFourNumbers(_))
        ));
        assert!(matches!(
            p("{\"bbox_2d\": [10, 10, 900, 100]}"),
            Err(BoxError::Outside(..))
        ));
        assert!(matches!(
            p("{\"bbox_2d\": [-50, 10, 100, 100]}"),
            Err(BoxError::Outside(..))
        ));
        assert!(matches!(
            p("{\"bbox_2d\": [100, 10, 50, 100]}"),
            Err(BoxError::Degenerate(_))
        ));
        assert!(matches!(
            p("{\"bbox_2d\": [100, 10, 100, 100]}"),
            Err(BoxError::Degenerate(_))
        ));
        // Slightly past the border: clipped.
        let a = p("{\"bbox_2d\": [-3, 0, 645, 480]}").unwrap();
        assert_eq!(a.bbox, Some([0.0, 0.0, 640.0, 480.0]));
        // A 0-1000 answer read as pixels in a 640-wide frame is outside it.
        assert!(matches!(
            p("{\"bbox_2d\": [100, 100, 900, 900]}"),
            Err(BoxError::Outside(..))
        ));
    }
}
