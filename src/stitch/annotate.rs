//! Instance annotation for the object-selection question: each candidate box's id drawn at
//! the box centre, white on black, optionally with the box outline.

use super::label::{draw_label, label_size, stroke_rect, LabelStyle, PixelRect};
use super::render::{resize_to_limit, scale_to_limit};
use anyhow::Result;
use image::RgbImage;
use serde::{Deserialize, Serialize};

/// Settings for [`annotate_instances`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AnnotateOptions {
    /// Resize so the longer side is this many pixels (`None`: keep the frame's size).
    pub max_side: Option<u32>,
    /// Scale small frames up to `max_side` as well.
    pub upscale: bool,
    /// Text put before each id (the reference shows "ID:i").
    pub prefix: String,
    /// Text height as a fraction of the output image height.
    pub label_height_frac: f32,
    /// Text colour.
    pub text_color: [u8; 3],
    /// Box colour behind the text.
    pub label_background: [u8; 3],
    /// Draw each candidate box's outline.
    pub draw_boxes: bool,
    /// Outline colour.
    pub box_color: [u8; 3],
    /// Outline thickness as a fraction of the output image height (at least 1 px).
    pub box_thickness_frac: f32,
}

impl Default for AnnotateOptions {
    fn default() -> Self {
        Self {
            max_side: Some(2048),
            upscale: true,
            prefix: "ID:".to_string(),
            label_height_frac: 0.03,
            text_color: [255, 255, 255],
            label_background: [0, 0, 0],
            draw_boxes: false,
            box_color: [0, 255, 0],
            box_thickness_frac: 0.003,
        }
    }
}

/// Draw each `(id, [x0, y0, x1, y1])` box (pixel coordinates of `img`) as a label centred
/// on the box centre, after resizing per `opts`. Boxes may lie partly outside the image.
pub fn annotate_instances(
    img: &RgbImage,
    boxes: &[(String, [f32; 4])],
    opts: &AnnotateOptions,
) -> Result<RgbImage> {
    let (mut out, s) = match opts.max_side {
        Some(side) => {
            let s = scale_to_limit(img.width(), img.height(), side, opts.upscale) as f32;
            (resize_to_limit(img, side, opts.upscale)?, s)
        }
        None => (img.clone(), 1.0),
    };
    let h = out.height() as f32;
    if opts.draw_boxes {
        let t = ((opts.box_thickness_frac * h).round() as u32).max(1);
        for (_, b) in boxes {
            let (x0, y0) = (b[0].min(b[2]) * s, b[1].min(b[3]) * s);
            let (x1, y1) = (b[0].max(b[2]) * s, b[1].max(b[3]) * s);
            let r = PixelRect {
                x: x0.round() as i32,
                y: y0.round() as i32,
                w: ((x1 - x0).round() as u32).max(1),
                h: ((y1 - y0).round() as u32).max(1),
            };
            stroke_rect(&mut out, r, t, opts.box_color);
        }
    }
    let style = LabelStyle {
        text: opts.text_color,
        background: Some(opts.label_background),
        ink_height: (opts.label_height_frac * h).max(6.0),
    };
    for (id, b) in boxes {
        let text = format!("{}{}", opts.prefix, id);
        let (lw, lh) = label_size(&text, &style);
        let cx = (b[0] + b[2]) * 0.5 * s;
        let cy = (b[1] + b[3]) * 0.5 * s;
        let x = (cx - lw as f32 * 0.5).round() as i32;
        let y = (cy - lh as f32 * 0.5).round() as i32;
        draw_label(&mut out, &text, x, y, &style);
    }
    Ok(out)
}
