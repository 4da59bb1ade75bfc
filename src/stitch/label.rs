//! Text labels drawn with the vendored DejaVu Sans Bold font (no system font lookup).

use ab_glyph::{point, Font, FontRef, PxScale, ScaleFont};
use image::{Rgb, RgbImage};
use std::sync::OnceLock;

/// DejaVu Sans Bold, vendored in `assets/fonts/` with its licence.
pub(crate) static FONT_BYTES: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans-Bold.ttf");

/// The embedded label font.
pub fn font() -> &'static FontRef<'static> {
    static FONT: OnceLock<FontRef<'static>> = OnceLock::new();
    FONT.get_or_init(|| {
        // The bytes are compiled into the binary; a unit test checks they parse.
        FontRef::try_from_slice(FONT_BYTES).expect("embedded DejaVu Sans Bold is a valid font")
    })
}

/// Pixel rectangle: left, top, width, height.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PixelRect {
    /// Left edge (inclusive).
    pub x: i32,
    /// Top edge (inclusive).
    pub y: i32,
    /// Width in pixels.
    pub w: u32,
    /// Height in pixels.
    pub h: u32,
}

/// How a label looks.
#[derive(Debug, Clone, Copy)]
pub struct LabelStyle {
    /// Text colour.
    pub text: [u8; 3],
    /// Colour of the box behind the text; `None` draws no box.
    pub background: Option<[u8; 3]>,
    /// Height of the inked text (cap/digit height) in pixels.
    pub ink_height: f32,
}

/// Font scale at which digits and capitals are `ink_height` pixels tall.
fn scale_for_ink_height(ink_height: f32) -> PxScale {
    static INK_PER_PX: OnceLock<f32> = OnceLock::new();
    let ratio = *INK_PER_PX.get_or_init(|| {
        let (_, _, _, h) = ink_bounds(PxScale::from(100.0), "0123456789ID");
        (h / 100.0).max(0.1)
    });
    PxScale::from((ink_height / ratio).max(1.0))
}

/// Ink bounds (min_x, min_y, width, height) of `text` laid out on one line at `scale`,
/// relative to the line origin (top of the ascender at y = 0).
fn ink_bounds(scale: PxScale, text: &str) -> (f32, f32, f32, f32) {
    let mut min = (f32::MAX, f32::MAX);
    let mut max = (f32::MIN, f32::MIN);
    for_each_glyph(scale, text, |g| {
        let b = g.px_bounds();
        min = (min.0.min(b.min.x), min.1.min(b.min.y));
        max = (max.0.max(b.max.x), max.1.max(b.max.y));
    });
    if min.0 > max.0 {
        return (0.0, 0.0, 0.0, 0.0);
    }
    (min.0, min.1, max.0 - min.0, max.1 - min.1)
}

fn for_each_glyph(scale: PxScale, text: &str, mut f: impl FnMut(&ab_glyph::OutlinedGlyph)) {
    let font = font().as_scaled(scale);
    let mut x = 0.0f32;
    let mut last = None;
    for c in text.chars() {
        let id = font.glyph_id(c);
        if let Some(prev) = last {
            x += font.kern(prev, id);
        }
        let glyph = id.with_scale_and_position(scale, point(x, font.ascent()));
        x += font.h_advance(id);
        last = Some(id);
        if let Some(g) = font.outline_glyph(glyph) {
            f(&g);
        }
    }
}

/// Size of the box a label of `text` occupies with `style` (text plus padding).
pub fn label_size(text: &str, style: &LabelStyle) -> (u32, u32) {
    let scale = scale_for_ink_height(style.ink_height);
    let (_, _, w, h) = ink_bounds(scale, text);
    let pad = padding(style.ink_height);
    ((w.ceil() as u32) + 2 * pad, (h.ceil() as u32) + 2 * pad)
}

fn padding(ink_height: f32) -> u32 {
    ((ink_height * 0.15).round() as u32).max(1)
}

/// Fill a rectangle, clipped to the image.
pub fn fill_rect(img: &mut RgbImage, r: PixelRect, colour: [u8; 3]) {
    let (iw, ih) = (img.width() as i64, img.height() as i64);
    let x0 = i64::from(r.x).clamp(0, iw);
    let y0 = i64::from(r.y).clamp(0, ih);
    let x1 = (i64::from(r.x) + i64::from(r.w)).clamp(0, iw);
    let y1 = (i64::from(r.y) + i64::from(r.h)).clamp(0, ih);
    for y in y0..y1 {
        for x in x0..x1 {
            img.put_pixel(x as u32, y as u32, Rgb(colour));
        }
    }
}

/// Draw a rectangle outline `thickness` pixels wide, clipped to the image.
pub fn stroke_rect(img: &mut RgbImage, r: PixelRect, thickness: u32, colour: [u8; 3]) {
    let t = thickness.max(1).min(r.w.max(1)).min(r.h.max(1));
    let edges = [
        PixelRect {
            x: r.x,
            y: r.y,
            w: r.w,
            h: t,
        },
        PixelRect {
            x: r.x,
            y: r.y + r.h as i32 - t as i32,
            w: r.w,
            h: t,
        },
        PixelRect {
            x: r.x,
            y: r.y,
            w: t,
            h: r.h,
        },
        PixelRect {
            x: r.x + r.w as i32 - t as i32,
            y: r.y,
            w: t,
            h: r.h,
        },
    ];
    for e in edges {
        fill_rect(img, e, colour);
    }
}

/// Draw `text` with its box's top-left corner at (`x`, `y`); returns the box drawn
/// (before clipping to the image).
pub fn draw_label(img: &mut RgbImage, text: &str, x: i32, y: i32, style: &LabelStyle) -> PixelRect {
    let scale = scale_for_ink_height(style.ink_height);
    let (min_x, min_y, w, h) = ink_bounds(scale, text);
    let pad = padding(style.ink_height) as i32;
    let rect = PixelRect {
        x,
        y,
        w: (w.ceil() as u32) + 2 * pad as u32,
        h: (h.ceil() as u32) + 2 * pad as u32,
    };
    if let Some(bg) = style.background {
        fill_rect(img, rect, bg);
    }
    // Shift so the ink's top-left lands at (x + pad, y + pad).
    let ox = x + pad - min_x.floor() as i32;
    let oy = y + pad - min_y.floor() as i32;
    let (iw, ih) = (img.width() as i32, img.height() as i32);
    let fg = style.text;
    for_each_glyph(scale, text, |g| {
        let b = g.px_bounds();
        g.draw(|gx, gy, cov| {
            let px = ox + b.min.x.floor() as i32 + gx as i32;
            let py = oy + b.min.y.floor() as i32 + gy as i32;
            if px < 0 || py < 0 || px >= iw || py >= ih {
                return;
            }
            let a = cov.clamp(0.0, 1.0);
            let p = img.get_pixel_mut(px as u32, py as u32);
            for (ch, f) in p.0.iter_mut().zip(fg) {
                *ch = (f32::from(*ch) * (1.0 - a) + f32::from(f) * a).round() as u8;
            }
        });
    });
    rect
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_font_parses_and_has_digits() {
        let f = font();
        assert_ne!(f.glyph_id('0').0, 0);
        assert_ne!(f.glyph_id('9').0, 0);
    }

    #[test]
    fn ink_height_is_respected() {
        let style = LabelStyle {
            text: [255, 0, 0],
            background: None,
            ink_height: 40.0,
        };
        let mut img = RgbImage::new(400, 100);
        draw_label(&mut img, "00042", 0, 0, &style);
        let rows: Vec<u32> = (0..100)
            .filter(|&y| (0..400).any(|x| img.get_pixel(x, y).0[0] > 128))
            .collect();
        let inked = rows.last().unwrap_or(&0) - rows.first().unwrap_or(&0) + 1;
        assert!((37..=43).contains(&inked), "ink height {inked}");
    }
}
