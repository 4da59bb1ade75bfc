//! Nr3D CSV (scan_id, target_id, utterance, instance_type, stimulus_id, flags...).

use super::ObjectsSource;
use crate::eval::dataset::Query;
use anyhow::{bail, Context, Result};
use std::collections::{HashMap, HashSet};
use std::path::Path;

/// Words that make an utterance view-dependent (the ReferIt3D criterion).
pub const VIEW_WORDS: [&str; 10] = [
    "front",
    "behind",
    "back",
    "left",
    "right",
    "facing",
    "leftmost",
    "rightmost",
    "looking",
    "across",
];

/// Whether the utterance uses a viewpoint word.
pub fn is_view_dependent(utterance: &str) -> bool {
    utterance
        .to_lowercase()
        .split(|c: char| !c.is_ascii_alphabetic())
        .any(|w| VIEW_WORDS.contains(&w))
}

/// Number of same-class objects (target included) encoded in a stimulus id
/// `<scan>-<class>-<count>-<target>-<distractors...>` (class names contain no '-').
pub fn stimulus_count(stimulus_id: &str) -> Option<usize> {
    stimulus_id.split('-').nth(2)?.parse().ok()
}

const FLAG_COLUMNS: [&str; 6] = [
    "mentions_target_class",
    "uses_object_lang",
    "uses_spatial_lang",
    "uses_color_lang",
    "uses_shape_lang",
    "correct_guess",
];

fn parse_bool(s: &str) -> Option<bool> {
    match s.trim().to_ascii_lowercase().as_str() {
        "true" | "1" => Some(true),
        "false" | "0" => Some(false),
        _ => None,
    }
}

/// Convert an Nr3D CSV. "hard" = more than two objects of the target's class in the scene
/// (i.e. at least two distractors; from stimulus_id when present, else from the objects);
/// "view_dependent" from the utterance's words. Rows whose scene or object is missing
/// from the objects folder are skipped and counted.
pub fn convert(input: &Path, objects: &ObjectsSource) -> Result<(Vec<Query>, usize)> {
    let mut rdr = csv::Reader::from_path(input)
        .with_context(|| format!("cannot read {}", input.display()))?;
    let headers = rdr
        .headers()
        .with_context(|| format!("{}: no CSV header", input.display()))?
        .clone();
    let col: HashMap<&str, usize> = headers
        .iter()
        .enumerate()
        .map(|(i, h)| (h.trim(), i))
        .collect();
    for need in ["scan_id", "target_id", "utterance", "instance_type"] {
        if !col.contains_key(need) {
            bail!("{}: missing column {need:?}", input.display());
        }
    }
    let mut out = Vec::new();
    let mut ids = HashSet::new();
    let mut skipped = 0;
    for (row, rec) in rdr.records().enumerate() {
        let rec = rec.with_context(|| format!("{}: bad CSV row {}", input.display(), row + 2))?;
        let get = |k: &str| col.get(k).and_then(|&i| rec.get(i)).unwrap_or("").trim();
        let scene_id = get("scan_id").to_string();
        let target_id: u32 = get("target_id").parse().with_context(|| {
            format!(
                "{}: row {}: target_id {:?} is not a number",
                input.display(),
                row + 2,
                get("target_id")
            )
        })?;
        let Some(scene) = objects.get(&scene_id)? else {
            skipped += 1;
            continue;
        };
        let Some(target) = scene.get(target_id) else {
            skipped += 1;
            continue;
        };
        let count =
            stimulus_count(get("stimulus_id")).unwrap_or_else(|| scene.label_count(&target.label));
        let utterance = get("utterance").to_string();
        let mut extra = serde_json::Map::new();
        extra.insert("hard".into(), (count > 2).into());
        extra.insert(
            "view_dependent".into(),
            is_view_dependent(&utterance).into(),
        );
        extra.insert("instance_type".into(), get("instance_type").into());
        for k in FLAG_COLUMNS {
            if let Some(b) = parse_bool(get(k)) {
                extra.insert(k.into(), b.into());
            }
        }
        let base = match get("assignmentid") {
            "" => format!("nr3d_{row}"),
            a => format!("nr3d_{a}"),
        };
        let query_id = if ids.contains(&base) {
            format!("{base}_{row}")
        } else {
            base
        };
        ids.insert(query_id.clone());
        out.push(Query {
            scene_id,
            query_id,
            text: utterance,
            target_id,
            target_label: target.label.clone(),
            subset: scene.subset_of(&target.label),
            extra,
        });
    }
    Ok((out, skipped))
}
