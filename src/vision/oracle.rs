//! Oracle detector: boxes from the scene's ground-truth instance masks (FORMATS §1a
//! `instance/<frame>.png` + `instance/labels.json`). For evaluation and ablations only, with
//! an optional miss rate and box jitter.

use std::collections::BTreeMap;

use anyhow::{anyhow, bail, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::common::clamp_box;
use super::{DetectInput, Detection, Detector};

/// Instances smaller than this many mask pixels are ignored (label noise, slivers).
pub const MIN_PIXELS: usize = 16;

/// The oracle detector.
#[derive(Debug, Clone, PartialEq)]
pub struct OracleDetector {
    /// Probability of dropping each instance.
    pub miss: f64,
    /// Each box edge moves by up to this fraction of the box size.
    pub jitter: f64,
    /// Random seed (combined with the frame key).
    pub seed: u64,
    /// Sleep this long per frame (tests: indexing slow enough to be interrupted).
    pub delay_ms: u64,
}

impl OracleDetector {
    /// Parse "miss=0.1,jitter=0.05,seed=1,delay_ms=0" (all optional; empty = perfect
    /// boxes, no delay).
    pub fn from_spec(spec: &str) -> Result<Self> {
        let mut o = Self {
            miss: 0.0,
            jitter: 0.0,
            seed: 0,
            delay_ms: 0,
        };
        for part in spec.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let (k, v) = part
                .split_once('=')
                .ok_or_else(|| anyhow!("oracle option `{part}` is not key=value"))?;
            let num = |v: &str| {
                v.trim()
                    .parse::<f64>()
                    .map_err(|_| anyhow!("oracle option `{part}` needs a number"))
            };
            match k.trim() {
                "miss" => o.miss = num(v)?,
                "jitter" => o.jitter = num(v)?,
                "seed" => {
                    o.seed = v
                        .trim()
                        .parse()
                        .map_err(|_| anyhow!("oracle seed `{v}` is not an integer"))?
                }
                "delay_ms" => {
                    o.delay_ms = v
                        .trim()
                        .parse()
                        .map_err(|_| anyhow!("oracle delay_ms `{v}` is not an integer"))?
                }
                other => {
                    bail!("unknown oracle option `{other}` (expected miss, jitter, seed, delay_ms)")
                }
            }
        }
        if !(0.0..=1.0).contains(&o.miss) || !(0.0..=1.0).contains(&o.jitter) {
            bail!("oracle miss and jitter must be between 0 and 1");
        }
        Ok(o)
    }
}

impl Detector for OracleDetector {
    fn name(&self) -> String {
        format!(
            "oracle:miss={},jitter={},seed={}",
            self.miss, self.jitter, self.seed
        )
    }

    /// Open: the scene's labels decide.
    fn vocabulary(&self) -> Vec<String> {
        Vec::new()
    }

    /// Any label may exist in a scene; compare with detections after
    /// [`super::synonyms::normalize`].
    fn can_see(&self, label: &str) -> Option<String> {
        let n = super::synonyms::normalize(label);
        (!n.is_empty()).then_some(n)
    }

    fn needs_instances(&self) -> bool {
        true
    }

    fn detect(&self, input: &DetectInput<'_>) -> Result<Vec<Detection>> {
        let (Some(inst), Some(labels)) = (input.instances, input.labels) else {
            bail!("the oracle detector needs the scene's instance masks and labels.json");
        };
        if self.delay_ms > 0 {
            std::thread::sleep(std::time::Duration::from_millis(self.delay_ms));
        }
        if inst.data.len() != inst.width as usize * inst.height as usize {
            bail!(
                "instance mask buffer does not match its {}x{} size",
                inst.width,
                inst.height
            );
        }
        // id -> (min x, min y, max x, max y, count)
        let mut boxes: BTreeMap<u16, (u32, u32, u32, u32, usize)> = BTreeMap::new();
        for (i, &id) in inst.data.iter().enumerate() {
            if id == 0 {
                continue;
            }
            let (x, y) = (i as u32 % inst.width, i as u32 / inst.width);
            let e = boxes.entry(id).or_insert((x, y, x, y, 0));
            e.0 = e.0.min(x);
            e.1 = e.1.min(y);
            e.2 = e.2.max(x);
            e.3 = e.3.max(y);
            e.4 += 1;
        }
        let (cw, ch) = input.color.dimensions();
        let sx = cw as f32 / inst.width as f32;
        let sy = ch as f32 / inst.height as f32;
        let mut rng = ChaCha8Rng::seed_from_u64(
            self.seed ^ input.frame_key.wrapping_mul(0x9E37_79B9_7F4A_7C15),
        );
        let mut out = Vec::new();
        for (id, (x0, y0, x1, y1, n)) in boxes {
            let Some(label) = labels.get(&(id as u32)) else {
                continue;
            };
            if n < MIN_PIXELS {
                continue;
            }
            let mut b = [
                x0 as f32 * sx,
                y0 as f32 * sy,
                (x1 + 1) as f32 * sx,
                (y1 + 1) as f32 * sy,
            ];
            if self.miss > 0.0 && rng.gen_bool(self.miss) {
                continue;
            }
            if self.jitter > 0.0 {
                let (bw, bh) = (b[2] - b[0], b[3] - b[1]);
                let j = self.jitter as f32;
                for (k, v) in b.iter_mut().enumerate() {
                    let size = if k % 2 == 0 { bw } else { bh };
                    *v += rng.gen_range(-j..=j) * size;
                }
            }
            if let Some(bbox) = clamp_box(b, cw, ch) {
                out.push(Detection {
                    label: label.clone(),
                    score: 1.0,
                    bbox,
                });
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::InstanceMask;
    use std::collections::HashMap;

    fn scene() -> (image::RgbImage, InstanceMask, HashMap<u32, String>) {
        // depth-sized mask 20x10, colour 40x20
        let mut data = vec![0u16; 200];
        for y in 2..6 {
            for x in 3..9 {
                data[y * 20 + x] = 7;
            }
        }
        for y in 0..10 {
            for x in 15..20 {
                data[y * 20 + x] = 9;
            }
        }
        data[0] = 11; // one pixel: ignored
        let labels = HashMap::from([
            (7, "chair".to_string()),
            (9, "door".to_string()),
            (11, "cup".to_string()),
        ]);
        (
            image::RgbImage::new(40, 20),
            InstanceMask {
                width: 20,
                height: 10,
                data,
            },
            labels,
        )
    }

    #[test]
    fn boxes_from_depth_sized_masks_in_colour_pixels() {
        let (img, inst, labels) = scene();
        let o = OracleDetector::from_spec("").unwrap();
        let input = DetectInput {
            color: &img,
            instances: Some(&inst),
            labels: Some(&labels),
            frame_key: 3,
        };
        let d = o.detect(&input).unwrap();
        assert_eq!(d.len(), 2);
        assert_eq!(
            (d[0].label.as_str(), d[0].bbox),
            ("chair", [6.0, 4.0, 18.0, 12.0])
        );
        assert_eq!(
            (d[1].label.as_str(), d[1].bbox),
            ("door", [30.0, 0.0, 40.0, 20.0])
        );
        assert!(o.detect(&DetectInput::image(&img)).is_err());
    }

    #[test]
    fn miss_and_jitter_are_seeded() {
        let (img, inst, labels) = scene();
        let input = DetectInput {
            color: &img,
            instances: Some(&inst),
            labels: Some(&labels),
            frame_key: 5,
        };
        let all_missed = OracleDetector::from_spec("miss=1")
            .unwrap()
            .detect(&input)
            .unwrap();
        assert!(all_missed.is_empty());
        let j = OracleDetector::from_spec("jitter=0.2,seed=4").unwrap();
        let a = j.detect(&input).unwrap();
        assert_eq!(a, j.detect(&input).unwrap());
        assert_ne!(a[0].bbox, [6.0, 4.0, 18.0, 12.0]);
        assert!(OracleDetector::from_spec("miss=2").is_err());
        assert!(OracleDetector::from_spec("foo=1").is_err());
    }
}
