//! Templated grounding queries whose target is unique by construction, and the FORMATS §2
//! annotation writer.
//!
//! Every template is a predicate over the ground-truth objects; a query is written only when
//! exactly one object satisfies it (with a safety margin for distances and sizes).

use super::{SynthObject, SynthQuery, SynthScene};
use anyhow::{Context, Result};
use serde_json::json;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

/// Distances must differ by this much (m) for "closest"/"farthest" to be unambiguous.
const DIST_MARGIN: f64 = 0.3;
/// Volumes must differ by this factor for "largest"/"smallest".
const VOLUME_RATIO: f64 = 1.2;
/// Heights must differ by this much (m) for "tallest".
const HEIGHT_MARGIN: f64 = 0.1;

/// True when `a` rests on top of `b` (bottom within 1 cm of one of b's part tops, footprints overlapping).
pub(crate) fn rests_on(a: &SynthObject, b: &SynthObject) -> bool {
    b.parts.iter().any(|p| {
        (a.aabb.min[2] - p.max[2]).abs() < 0.01
            && (0..2).all(|i| a.aabb.min[i] < p.max[i] && p.min[i] < a.aabb.max[i])
    })
}

struct Acc<'a> {
    scene: &'a str,
    counts: BTreeMap<&'a str, usize>,
    out: Vec<SynthQuery>,
}

impl Acc<'_> {
    fn push(&mut self, text: String, target: &SynthObject, kind: &str) {
        let subset = if self.counts.get(target.label.as_str()).copied().unwrap_or(0) == 1 {
            "unique"
        } else {
            "multiple"
        };
        let query_id = format!("{}_q{:03}", self.scene, self.out.len());
        self.out.push(SynthQuery {
            scene_id: self.scene.to_string(),
            query_id,
            text,
            target_id: target.id,
            target_label: target.label.clone(),
            subset: subset.to_string(),
            kind: kind.to_string(),
        });
    }
}

/// All unambiguous templated queries for one scene's objects.
pub(crate) fn make_queries(scene_id: &str, objects: &[SynthObject]) -> Vec<SynthQuery> {
    let mut by_label: BTreeMap<&str, Vec<&SynthObject>> = BTreeMap::new();
    for o in objects {
        by_label.entry(o.label.as_str()).or_default().push(o);
    }
    let counts = by_label.iter().map(|(k, v)| (*k, v.len())).collect();
    let mut acc = Acc {
        scene: scene_id,
        counts,
        out: Vec::new(),
    };
    let unique_anchors: Vec<&SynthObject> = by_label
        .values()
        .filter(|v| v.len() == 1)
        .map(|v| v[0])
        .collect();

    // Attribute: "the red chair" when exactly one object of that label has that colour.
    for group in by_label.values() {
        for o in group {
            if group.iter().filter(|x| x.color == o.color).count() == 1 {
                acc.push(format!("the {} {}", o.color, o.label), o, "attribute");
            }
        }
    }
    // Relation: closest to / farthest from an anchor whose label is unique.
    for (label, group) in &by_label {
        if group.len() < 2 {
            continue;
        }
        for anchor in unique_anchors.iter().filter(|a| a.label != *label).take(4) {
            let mut d: Vec<(f64, &SynthObject)> = group
                .iter()
                .map(|o| (o.aabb.center_distance(&anchor.aabb), *o))
                .collect();
            d.sort_by(|a, b| a.0.total_cmp(&b.0));
            if d[1].0 - d[0].0 > DIST_MARGIN {
                acc.push(
                    format!("the {} closest to the {}", label, anchor.label),
                    d[0].1,
                    "relation",
                );
            }
            let n = d.len();
            if d[n - 1].0 - d[n - 2].0 > DIST_MARGIN {
                acc.push(
                    format!("the {} farthest from the {}", label, anchor.label),
                    d[n - 1].1,
                    "relation",
                );
            }
        }
    }
    // Support: "the pillow on the bed" when exactly one object of that label rests on the anchor.
    for anchor in &unique_anchors {
        for (label, group) in &by_label {
            let on: Vec<&&SynthObject> = group.iter().filter(|o| rests_on(o, anchor)).collect();
            if on.len() == 1 {
                acc.push(
                    format!("the {} on the {}", label, anchor.label),
                    on[0],
                    "support",
                );
            }
        }
    }
    // Extremes: largest / smallest by volume, tallest by top height.
    for (label, group) in &by_label {
        if group.len() < 2 {
            continue;
        }
        let mut v: Vec<(f64, &SynthObject)> = group.iter().map(|o| (o.aabb.volume(), *o)).collect();
        v.sort_by(|a, b| b.0.total_cmp(&a.0));
        if v[0].0 > VOLUME_RATIO * v[1].0 {
            acc.push(format!("the largest {label}"), v[0].1, "extreme");
        }
        let n = v.len();
        if v[n - 2].0 > VOLUME_RATIO * v[n - 1].0 {
            acc.push(format!("the smallest {label}"), v[n - 1].1, "extreme");
        }
        let mut t: Vec<(f64, &SynthObject)> = group.iter().map(|o| (o.aabb.max[2], *o)).collect();
        t.sort_by(|a, b| b.0.total_cmp(&a.0));
        if t[0].0 > t[1].0 + HEIGHT_MARGIN {
            acc.push(format!("the tallest {label}"), t[0].1, "extreme");
        }
    }
    acc.out
}

/// Write `objects/<scene_id>.json` for every scene and one `queries.jsonl` holding all
/// scenes' queries (FORMATS §2). Objects carry an extra `color` key.
pub fn write_dataset(scenes: &[SynthScene], dataset_dir: &Path) -> Result<()> {
    let objects_dir = dataset_dir.join("objects");
    std::fs::create_dir_all(&objects_dir)
        .with_context(|| format!("synth: cannot create {}", objects_dir.display()))?;
    let mut lines = Vec::new();
    for s in scenes {
        let objs: Vec<serde_json::Value> = s.objects.iter().map(|o| json!({"id": o.id, "label": o.label, "color": o.color, "aabb": {"min": o.aabb.min, "max": o.aabb.max}})).collect();
        let doc = json!({"scene_id": s.scene_id, "objects": objs});
        let path = objects_dir.join(format!("{}.json", s.scene_id));
        std::fs::write(&path, serde_json::to_string_pretty(&doc)?)
            .with_context(|| format!("synth: cannot write {}", path.display()))?;
        for q in &s.queries {
            writeln!(lines, "{}", serde_json::to_string(q)?)?;
        }
    }
    let path = dataset_dir.join("queries.jsonl");
    std::fs::write(&path, lines).with_context(|| format!("synth: cannot write {}", path.display()))
}
