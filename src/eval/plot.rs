//! PNG plot of the IoU distribution per ScanRefer subset (plotters, bitmap backend).

use super::dataset::Subset;
use super::metrics::QueryRecord;
use anyhow::{anyhow, Context, Result};
use plotters::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// Number of histogram bins over IoU in [0, 1].
pub const BINS: usize = 10;
const FONT_NAME: &str = "grounder-eval";
static FONT_OK: OnceLock<bool> = OnceLock::new();

/// Counts per IoU bin (bin i holds [i/10, (i+1)/10), IoU 1 goes into the last bin;
/// queries without prediction count as IoU 0).
pub fn histogram(records: &[QueryRecord], subset: Subset) -> [usize; BINS] {
    let mut h = [0usize; BINS];
    for r in records.iter().filter(|r| r.subset == subset) {
        let iou = if r.predicted.is_some() {
            r.iou.clamp(0.0, 1.0)
        } else {
            0.0
        };
        h[((iou * BINS as f64) as usize).min(BINS - 1)] += 1;
    }
    h
}

/// Default font locations tried when no font is given: `assets/fonts/DejaVuSans-Bold.ttf`
/// under the working directory, then under the crate's source directory.
pub fn default_font_paths() -> Vec<PathBuf> {
    let rel = Path::new("assets/fonts/DejaVuSans-Bold.ttf");
    vec![
        rel.to_path_buf(),
        Path::new(env!("CARGO_MANIFEST_DIR")).join(rel),
    ]
}

/// Register font bytes for plot text (first call wins). Returns whether text can be drawn.
pub fn register_font(bytes: Vec<u8>) -> bool {
    *FONT_OK.get_or_init(|| {
        let leaked: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        plotters::style::register_font(FONT_NAME, FontStyle::Normal, leaked).is_ok()
    })
}

/// Load the first readable font among `paths` and register it; false when none works.
pub fn register_font_from(paths: &[PathBuf]) -> bool {
    if let Some(ok) = FONT_OK.get() {
        return *ok;
    }
    // The font embedded in the binary when no path holds one.
    let bytes = paths
        .iter()
        .find_map(|p| std::fs::read(p).ok())
        .unwrap_or_else(|| crate::stitch::label::FONT_BYTES.to_vec());
    register_font(bytes)
}

/// Whether a font has been registered successfully.
pub fn has_font() -> bool {
    FONT_OK.get().copied().unwrap_or(false)
}

/// Draw side-by-side histograms (left: unique, blue; right: multiple, orange) of IoU in
/// ten bins from 0 to 1, with a dashed line at 0.25 and 0.5. Text (titles, axis labels) is
/// drawn only when a font is registered; the bars and reference lines always are.
pub fn render_iou_histogram(records: &[QueryRecord], path: &Path) -> Result<()> {
    let text = has_font();
    let root = BitMapBackend::new(path, (960, 420)).into_drawing_area();
    let err = |e: &dyn std::fmt::Display| anyhow!("cannot draw {}: {e}", path.display());
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let panels = root.split_evenly((1, 2));
    for (panel, (subset, color, name)) in panels.iter().zip([
        (Subset::Unique, BLUE, "unique"),
        (Subset::Multiple, RGBColor(230, 120, 20), "multiple"),
    ]) {
        let h = histogram(records, subset);
        let top = (*h.iter().max().unwrap_or(&0)).max(1);
        let ymax = top as f64 + 1.0;
        let mut builder = ChartBuilder::on(panel);
        builder.margin(15);
        if text {
            let n: usize = h.iter().sum();
            builder
                .caption(format!("IoU, {name} (n = {n})"), (FONT_NAME, 22))
                .x_label_area_size(35)
                .y_label_area_size(45);
        }
        let mut chart = builder
            .build_cartesian_2d(0.0f64..1.0f64, 0.0f64..ymax)
            .map_err(|e| err(&e))?;
        if text {
            chart
                .configure_mesh()
                .label_style((FONT_NAME, 14))
                .y_labels((top + 2).min(11))
                .y_label_formatter(&|v| format!("{v:.0}"))
                .x_desc("3D IoU with the target box")
                .y_desc("queries")
                .axis_desc_style((FONT_NAME, 15))
                .draw()
                .map_err(|e| err(&e))?;
        } else {
            chart
                .draw_series([
                    PathElement::new(vec![(0.0, 0.0), (1.0, 0.0)], BLACK),
                    PathElement::new(vec![(0.0, 0.0), (0.0, ymax)], BLACK),
                ])
                .map_err(|e| err(&e))?;
        }
        let w = 1.0 / BINS as f64;
        chart
            .draw_series(h.iter().enumerate().map(|(i, &c)| {
                Rectangle::new(
                    [
                        (i as f64 * w + 0.005, 0.0),
                        ((i + 1) as f64 * w - 0.005, c as f64),
                    ],
                    color.filled(),
                )
            }))
            .map_err(|e| err(&e))?;
        for x in [0.25, 0.5] {
            chart
                .draw_series(DashedLineSeries::new(
                    vec![(x, 0.0), (x, ymax)],
                    6,
                    4,
                    BLACK.stroke_width(1),
                ))
                .map_err(|e| err(&e))?;
        }
    }
    root.present()
        .map_err(|e| err(&e))
        .with_context(|| "plot")?;
    Ok(())
}
