//! ScanRefer JSON (a list of {scene_id, object_id, object_name, ann_id, description, ...}).

use super::ObjectsSource;
use crate::eval::dataset::Query;
use anyhow::{Context, Result};
use serde::Deserialize;
use std::path::Path;

/// ScanRefer writes ids as strings; accept numbers too.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum IdField {
    S(String),
    N(u64),
}

impl IdField {
    fn text(&self) -> String {
        match self {
            IdField::S(s) => s.trim().to_string(),
            IdField::N(n) => n.to_string(),
        }
    }
}

#[derive(Debug, Deserialize)]
struct Entry {
    scene_id: String,
    object_id: IdField,
    #[serde(default)]
    object_name: Option<String>,
    ann_id: IdField,
    description: String,
}

/// Convert a ScanRefer file; returns the queries and how many entries were skipped
/// because their scene or object is not in the objects folder.
pub fn convert(input: &Path, objects: &ObjectsSource) -> Result<(Vec<Query>, usize)> {
    let text = std::fs::read_to_string(input)
        .with_context(|| format!("cannot read {}", input.display()))?;
    let entries: Vec<Entry> = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a ScanRefer JSON list", input.display()))?;
    let mut out = Vec::new();
    let mut skipped = 0;
    for (i, e) in entries.iter().enumerate() {
        let oid = e.object_id.text();
        let target_id: u32 = oid.parse().with_context(|| {
            format!(
                "{}: entry {i}: object_id {oid:?} is not a number",
                input.display()
            )
        })?;
        let Some(scene) = objects.get(&e.scene_id)? else {
            skipped += 1;
            continue;
        };
        let Some(target) = scene.get(target_id) else {
            skipped += 1;
            continue;
        };
        let mut extra = serde_json::Map::new();
        extra.insert("ann_id".into(), e.ann_id.text().into());
        if let Some(n) = &e.object_name {
            extra.insert("object_name".into(), n.clone().into());
        }
        out.push(Query {
            scene_id: e.scene_id.clone(),
            query_id: format!("{}_{}_{}", e.scene_id, oid, e.ann_id.text()),
            text: e.description.trim().to_string(),
            target_id,
            target_label: target.label.clone(),
            subset: scene.subset_of(&target.label),
            extra,
        });
    }
    Ok((out, skipped))
}
