//! The visual-retrieval benchmark (paper Sec. 4.4, supplementary B): images stamped with
//! an id and a coloured block are stitched with a chosen layout; the VLM lists every id and
//! block colour; recall over the ground-truth (id, colour) pairs is the accuracy.

use super::plan::GridSpec;
use super::render::{stitch_with_specs, StitchOptions, StitchedImage};
use anyhow::{bail, Context, Result};
use image::{Rgb, RgbImage};
use rand::seq::index::sample;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::time::Duration;

/// The six block colours of the benchmark.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BlockColor {
    /// Pure red.
    Red,
    /// Pure green.
    Green,
    /// Pure blue.
    Blue,
    /// Yellow.
    Yellow,
    /// White.
    White,
    /// Black.
    Black,
}

impl BlockColor {
    /// All six colours.
    pub const ALL: [BlockColor; 6] = [
        BlockColor::Red,
        BlockColor::Green,
        BlockColor::Blue,
        BlockColor::Yellow,
        BlockColor::White,
        BlockColor::Black,
    ];

    /// RGB value drawn.
    pub fn rgb(self) -> [u8; 3] {
        match self {
            BlockColor::Red => [255, 0, 0],
            BlockColor::Green => [0, 255, 0],
            BlockColor::Blue => [0, 0, 255],
            BlockColor::Yellow => [255, 255, 0],
            BlockColor::White => [255, 255, 255],
            BlockColor::Black => [0, 0, 0],
        }
    }

    /// Lower-case English name.
    pub fn name(self) -> &'static str {
        match self {
            BlockColor::Red => "red",
            BlockColor::Green => "green",
            BlockColor::Blue => "blue",
            BlockColor::Yellow => "yellow",
            BlockColor::White => "white",
            BlockColor::Black => "black",
        }
    }
}

/// One ground-truth image of a case: its id and its block colour.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct RetrievalItem {
    /// Five-digit id drawn on the image.
    pub id: String,
    /// Colour of the block stamped on it.
    pub color: BlockColor,
}

/// Settings of the generator.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GeneratorOptions {
    /// Block side as a fraction of the image's shorter side.
    pub block_frac: f32,
    /// Stitching and encoding settings (id labels are drawn by the stitcher).
    pub stitch: StitchOptions,
}

impl Default for GeneratorOptions {
    fn default() -> Self {
        Self {
            block_frac: 0.15,
            stitch: StitchOptions::default(),
        }
    }
}

/// One benchmark request: the stitched images and the truth in reading order.
#[derive(Debug, Clone)]
pub struct RetrievalCase {
    /// Layout used, (rows, cols).
    pub layout: (u32, u32),
    /// Stitched images, in order.
    pub images: Vec<StitchedImage>,
    /// Ground truth, one item per stamped image.
    pub truth: Vec<RetrievalItem>,
}

/// Copy of `img` with a `color` square of side `block_frac * min(w, h)` at a random
/// position, kept clear of the top-left corner where the id label goes.
pub fn stamp_block(
    img: &RgbImage,
    color: BlockColor,
    block_frac: f32,
    rng: &mut impl Rng,
) -> RgbImage {
    let mut out = img.clone();
    let (w, h) = img.dimensions();
    let side = ((w.min(h) as f32 * block_frac).round() as u32).clamp(1, w.min(h));
    let (label_w, label_h) = (w / 2, h / 5);
    let mut pos = (w - side, h - side);
    for _ in 0..32 {
        let x = rng.gen_range(0..=w - side);
        let y = rng.gen_range(0..=h - side);
        if x >= label_w || y >= label_h {
            pos = (x, y);
            break;
        }
    }
    for y in pos.1..pos.1 + side {
        for x in pos.0..pos.0 + side {
            out.put_pixel(x, y, Rgb(color.rgb()));
        }
    }
    out
}

/// Build one case: `count` stitched images of layout (`rows`, `cols`), every cell filled
/// with a random image from `pool`, a unique random five-digit id and a random block colour.
pub fn generate_case(
    pool: &[RgbImage],
    layout: (u32, u32),
    count: usize,
    rng: &mut impl Rng,
    opts: &GeneratorOptions,
) -> Result<RetrievalCase> {
    if pool.is_empty() {
        bail!("the benchmark needs at least one source image");
    }
    if count == 0 || layout.0 == 0 || layout.1 == 0 {
        bail!("layout and image count must be positive");
    }
    let per = (layout.0 * layout.1) as usize;
    let n = per * count;
    if n > 100_000 {
        bail!("{n} images exceed the five-digit id space");
    }
    let ids = sample(rng, 100_000, n).into_vec();
    let mut truth = Vec::with_capacity(n);
    let mut stamped = Vec::with_capacity(n);
    for id in ids {
        let color = BlockColor::ALL[rng.gen_range(0..BlockColor::ALL.len())];
        let src = &pool[rng.gen_range(0..pool.len())];
        stamped.push(stamp_block(src, color, opts.block_frac, rng));
        truth.push(RetrievalItem {
            id: format!("{id:05}"),
            color,
        });
    }
    let tiles: Vec<(String, &RgbImage)> = truth
        .iter()
        .map(|t| t.id.clone())
        .zip(stamped.iter())
        .collect();
    let specs = vec![
        GridSpec {
            rows: layout.0,
            cols: layout.1,
            frames: per as u32
        };
        count
    ];
    let images = stitch_with_specs(&tiles, &specs, &opts.stitch)?;
    Ok(RetrievalCase {
        layout,
        images,
        truth,
    })
}

/// Random generator for case `trial` of layout number `layout_index` (independent streams,
/// so a case can be rebuilt on its own).
pub fn case_rng(seed: u64, layout_index: usize, trial: usize) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(((layout_index as u64) << 32) | trial as u64);
    rng
}

/// Simple varied images (gradients and shapes) for running the benchmark without a dataset.
pub fn synthetic_pool(n: usize, width: u32, height: u32, seed: u64) -> Vec<RgbImage> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let a: [u8; 3] = rng.gen();
            let b: [u8; 3] = rng.gen();
            let mut img = RgbImage::from_fn(width, height, |x, y| {
                let t = (x + y) as f32 / (width + height).max(1) as f32;
                Rgb(std::array::from_fn(|c| {
                    (f32::from(a[c]) * (1.0 - t) + f32::from(b[c]) * t) as u8
                }))
            });
            for _ in 0..4 {
                let c: [u8; 3] = rng.gen();
                let (cx, cy) = (
                    rng.gen_range(0..width) as i64,
                    rng.gen_range(0..height) as i64,
                );
                let r = rng.gen_range(5..(width.min(height) / 4).max(6)) as i64;
                for y in (cy - r).max(0)..(cy + r).min(i64::from(height)) {
                    for x in (cx - r).max(0)..(cx + r).min(i64::from(width)) {
                        if (x - cx).pow(2) + (y - cy).pow(2) <= r * r {
                            img.put_pixel(x as u32, y as u32, Rgb(c));
                        }
                    }
                }
            }
            img
        })
        .collect()
}

/// The instruction sent with a case's images.
pub fn prompt(case: &RetrievalCase) -> String {
    format!(
        "The {} picture(s) attached are grids of smaller photos. Every photo has a five-digit \
         number printed in red at its top-left corner and one solid square of colour somewhere \
         in it; the colour is one of red, green, blue, yellow, white or black. Go through every \
         photo of every picture in order and write down its number and the colour of its \
         square. Reply with JSON only, in this form: \
         {{\"ids\": [\"01234\", \"00077\"], \"colors\": [\"blue\", \"white\"]}} \
         where the two lists have the same length and the same order.",
        case.images.len()
    )
}

/// A VLM's reply: ids and colours, position by position.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct RetrievalAnswer {
    /// Ids as read.
    pub ids: Vec<String>,
    /// Colours as read.
    pub colors: Vec<String>,
}

fn value_to_string(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// Parse a reply holding a JSON object with `ids` and `colors` (or `colours`) lists; text
/// or code fences around the object are ignored.
pub fn parse_answer(text: &str) -> Result<RetrievalAnswer> {
    let start = text.find('{').context("the reply holds no JSON object")?;
    let end = text.rfind('}').context("the reply holds no JSON object")?;
    if end < start {
        bail!("the reply holds no JSON object");
    }
    let v: Value =
        serde_json::from_str(&text[start..=end]).context("the reply is not valid JSON")?;
    let list = |key: &str| -> Vec<String> {
        v.get(key)
            .and_then(Value::as_array)
            .map(|a| a.iter().map(value_to_string).collect())
            .unwrap_or_default()
    };
    let ids = list("ids");
    let mut colors = list("colors");
    if colors.is_empty() {
        colors = list("colours");
    }
    if v.get("ids").is_none() {
        bail!("the reply has no \"ids\" list");
    }
    Ok(RetrievalAnswer { ids, colors })
}

/// Normalise an id as read: digits only compared as a number ("3" == "00003").
fn norm_id(s: &str) -> String {
    let t = s.trim().trim_start_matches("ID:").trim();
    match t.parse::<u64>() {
        Ok(n) => n.to_string(),
        Err(_) => t.to_lowercase(),
    }
}

/// Result of scoring one answer.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Score {
    /// Ground-truth images retrieved with the right colour.
    pub correct: usize,
    /// Ground-truth images.
    pub total: usize,
    /// `correct / total` (0 when `total` is 0).
    pub recall: f64,
}

/// Recall as the paper defines it: a ground-truth (id, colour) counts as retrieved when at
/// least one (id, colour) pair of the answer matches it; conflicting duplicate pairs for
/// one id do not count against it. Pairs are formed position by position; unpaired
/// trailing entries of the longer list are ignored.
pub fn score(truth: &[RetrievalItem], answer: &RetrievalAnswer) -> Score {
    let pairs: std::collections::HashSet<(String, String)> = answer
        .ids
        .iter()
        .zip(&answer.colors)
        .map(|(i, c)| (norm_id(i), c.trim().to_lowercase()))
        .collect();
    let correct = truth
        .iter()
        .filter(|t| pairs.contains(&(norm_id(&t.id), t.color.name().to_string())))
        .count();
    let total = truth.len();
    let recall = if total == 0 {
        0.0
    } else {
        correct as f64 / total as f64
    };
    Score {
        correct,
        total,
        recall,
    }
}

// ---------------------------------------------------------------------------------------
// TEMPORARY VLM CALL — to be replaced by the shared client in `crate::vlm` once it exists.
// A minimal OpenAI-compatible chat-completions request: one user message with the prompt
// and the JPEG images as base64 data URLs; returns the assistant's text.
// ---------------------------------------------------------------------------------------

/// Ask an OpenAI-compatible endpoint (`{base_url}/chat/completions`) about `images_jpeg`.
/// TEMPORARY: swap for the shared `crate::vlm` client.
pub async fn ask(
    base_url: &str,
    model: &str,
    api_key: Option<&str>,
    prompt: &str,
    images_jpeg: &[Vec<u8>],
    timeout: Duration,
) -> Result<String> {
    let mut content = vec![serde_json::json!({"type": "text", "text": prompt})];
    for jpeg in images_jpeg {
        content.push(serde_json::json!({
            "type": "image_url",
            "image_url": {"url": super::render::jpeg_data_url(jpeg), "detail": "high"}
        }));
    }
    let body = serde_json::json!({
        "model": model,
        "messages": [{"role": "user", "content": content}],
        "temperature": 0.1,
        "top_p": 0.3,
        "max_tokens": 4095,
    });
    let client = reqwest::Client::builder()
        .timeout(timeout)
        .build()
        .context("cannot build the HTTP client")?;
    let url = format!("{}/chat/completions", base_url.trim_end_matches('/'));
    let mut req = client.post(&url).json(&body);
    if let Some(key) = api_key.filter(|k| !k.is_empty()) {
        req = req.bearer_auth(key);
    }
    let resp = req
        .send()
        .await
        .with_context(|| format!("VLM request to {url} failed"))?;
    let status = resp.status();
    let text = resp.text().await.context("cannot read the VLM response")?;
    if !status.is_success() {
        let snippet: String = text.chars().take(200).collect();
        bail!("VLM answered HTTP {status}: {snippet}");
    }
    let v: Value = serde_json::from_str(&text).context("the VLM response is not JSON")?;
    v.pointer("/choices/0/message/content")
        .and_then(Value::as_str)
        .map(str::to_string)
        .context("the VLM response has no choices[0].message.content")
}
