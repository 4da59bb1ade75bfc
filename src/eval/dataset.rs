//! Loading and validating a grounder annotation dataset (FORMATS §2).

use crate::geometry::Aabb;
use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashSet};
use std::path::Path;

/// One annotated object of a scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneObject {
    /// Instance id (as in the scene's instance masks).
    pub id: u32,
    /// Class label.
    pub label: String,
    /// Ground-truth box in the service's output frame.
    pub aabb: Aabb,
}

/// `objects/<scene_id>.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneObjects {
    /// Scene id (must match the file name).
    pub scene_id: String,
    /// All annotated objects of the scene.
    pub objects: Vec<SceneObject>,
}

impl SceneObjects {
    /// The object with this id.
    pub fn get(&self, id: u32) -> Option<&SceneObject> {
        self.objects.iter().find(|o| o.id == id)
    }

    /// Number of objects carrying this label.
    pub fn label_count(&self, label: &str) -> usize {
        self.objects.iter().filter(|o| o.label == label).count()
    }

    /// "unique" when exactly one object has this label, else "multiple" (ScanRefer).
    pub fn subset_of(&self, label: &str) -> Subset {
        if self.label_count(label) == 1 {
            Subset::Unique
        } else {
            Subset::Multiple
        }
    }
}

/// ScanRefer subset of a query.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Subset {
    /// The scene has exactly one object of the target's class.
    Unique,
    /// The scene has several objects of the target's class.
    Multiple,
}

/// One line of `queries.jsonl`; unknown keys are kept in `extra`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Query {
    /// Scene the query refers to.
    pub scene_id: String,
    /// Unique id of the query within the dataset.
    pub query_id: String,
    /// The referring sentence.
    pub text: String,
    /// Id of the target object in `objects/<scene_id>.json`.
    pub target_id: u32,
    /// Label of the target object.
    pub target_label: String,
    /// unique / multiple.
    pub subset: Subset,
    /// Any other keys (e.g. "hard", "view_dependent").
    #[serde(flatten)]
    pub extra: serde_json::Map<String, serde_json::Value>,
}

impl Query {
    /// A boolean flag among the extra keys ("hard", "view_dependent"), if present.
    pub fn flag(&self, key: &str) -> Option<bool> {
        self.extra.get(key).and_then(|v| v.as_bool())
    }
}

/// A whole dataset: objects per scene and the queries, in file order.
#[derive(Debug, Clone, Default)]
pub struct Dataset {
    /// Objects keyed by scene id.
    pub scenes: BTreeMap<String, SceneObjects>,
    /// Queries in the order of `queries.jsonl`.
    pub queries: Vec<Query>,
}

impl Dataset {
    /// Load `dir/objects/*.json` and `dir/queries.jsonl`, then [`Dataset::validate`].
    pub fn load(dir: &Path) -> Result<Self> {
        let obj_dir = dir.join("objects");
        let entries = std::fs::read_dir(&obj_dir)
            .with_context(|| format!("cannot read {}", obj_dir.display()))?;
        let mut scenes = BTreeMap::new();
        for entry in entries {
            let path = entry
                .with_context(|| format!("cannot list {}", obj_dir.display()))?
                .path();
            if path.extension().and_then(|e| e.to_str()) != Some("json") {
                continue;
            }
            let text = std::fs::read_to_string(&path)
                .with_context(|| format!("cannot read {}", path.display()))?;
            let so: SceneObjects = serde_json::from_str(&text)
                .with_context(|| format!("{} is not a valid objects file", path.display()))?;
            let stem = path
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or_default();
            if stem != so.scene_id {
                bail!(
                    "{}: scene_id {:?} does not match the file name",
                    path.display(),
                    so.scene_id
                );
            }
            scenes.insert(so.scene_id.clone(), so);
        }
        let qpath = dir.join("queries.jsonl");
        let text = std::fs::read_to_string(&qpath)
            .with_context(|| format!("cannot read {}", qpath.display()))?;
        let queries = parse_queries(&text).with_context(|| format!("in {}", qpath.display()))?;
        let ds = Dataset { scenes, queries };
        ds.validate()?;
        Ok(ds)
    }

    /// Check ids, references and labels; the first problem is returned as an error.
    pub fn validate(&self) -> Result<()> {
        for so in self.scenes.values() {
            let mut ids = HashSet::new();
            for o in &so.objects {
                if !ids.insert(o.id) {
                    bail!("scene {}: object id {} appears twice", so.scene_id, o.id);
                }
                if (0..3).any(|i| {
                    !o.aabb.min[i].is_finite()
                        || !o.aabb.max[i].is_finite()
                        || o.aabb.min[i] > o.aabb.max[i]
                }) {
                    bail!(
                        "scene {}: object {} has an invalid box (min > max or not finite)",
                        so.scene_id,
                        o.id
                    );
                }
            }
        }
        let mut qids = HashSet::new();
        for q in &self.queries {
            if !qids.insert(q.query_id.as_str()) {
                bail!("query_id {:?} appears twice", q.query_id);
            }
            let so = self
                .scenes
                .get(&q.scene_id)
                .with_context(|| format!("query {}: no objects/{}.json", q.query_id, q.scene_id))?;
            let target = so.get(q.target_id).with_context(|| {
                format!(
                    "query {}: target_id {} is not an object of scene {}",
                    q.query_id, q.target_id, q.scene_id
                )
            })?;
            if target.label != q.target_label {
                bail!(
                    "query {}: target_label {:?} differs from the object's label {:?}",
                    q.query_id,
                    q.target_label,
                    target.label
                );
            }
        }
        Ok(())
    }

    /// Scene ids referenced by the queries, in first-use order.
    pub fn query_scenes(&self) -> Vec<String> {
        let mut seen = HashSet::new();
        self.queries
            .iter()
            .filter(|q| seen.insert(q.scene_id.clone()))
            .map(|q| q.scene_id.clone())
            .collect()
    }
}

/// Parse `queries.jsonl` text (blank lines skipped); errors name the line.
pub fn parse_queries(text: &str) -> Result<Vec<Query>> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let q: Query = serde_json::from_str(line)
            .with_context(|| format!("line {}: not a valid query", i + 1))?;
        out.push(q);
    }
    Ok(out)
}

/// Write a dataset in FORMATS §2 layout (used by the converters).
pub fn write_dataset(dir: &Path, scenes: &[SceneObjects], queries: &[Query]) -> Result<()> {
    let obj_dir = dir.join("objects");
    std::fs::create_dir_all(&obj_dir)
        .with_context(|| format!("cannot create {}", obj_dir.display()))?;
    for so in scenes {
        let path = obj_dir.join(format!("{}.json", so.scene_id));
        let text = serde_json::to_string_pretty(so)?;
        std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))?;
    }
    if !queries.is_empty() {
        let mut text = String::new();
        for q in queries {
            text.push_str(&serde_json::to_string(q)?);
            text.push('\n');
        }
        let path = dir.join("queries.jsonl");
        std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}

/// Load only `dir/objects/<scene>.json` for the given scene.
pub fn load_scene_objects(objects_dir: &Path, scene_id: &str) -> Result<SceneObjects> {
    let path = objects_dir.join(format!("{scene_id}.json"));
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_str(&text)
        .with_context(|| format!("{} is not a valid objects file", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obj(id: u32, label: &str) -> SceneObject {
        SceneObject {
            id,
            label: label.into(),
            aabb: Aabb::new([0.0; 3], [1.0; 3]),
        }
    }

    #[test]
    fn query_keeps_extra_keys_and_flags() {
        let q = parse_queries(
            "{\"scene_id\":\"s\",\"query_id\":\"q\",\"text\":\"t\",\"target_id\":1,\"target_label\":\"chair\",\"subset\":\"unique\",\"hard\":true,\"note\":\"x\"}\n\n",
        )
        .unwrap();
        assert_eq!(q.len(), 1);
        assert_eq!(q[0].flag("hard"), Some(true));
        assert_eq!(q[0].flag("view_dependent"), None);
        let back = serde_json::to_value(&q[0]).unwrap();
        assert_eq!(back["note"], "x");
        assert_eq!(back["subset"], "unique");
    }

    #[test]
    fn bad_line_names_line_number() {
        let err = parse_queries("\n{oops}\n").unwrap_err();
        assert!(format!("{err:#}").contains("line 2"), "{err:#}");
    }

    #[test]
    fn validation_catches_wrong_label_and_missing_target() {
        let so = SceneObjects {
            scene_id: "s".into(),
            objects: vec![obj(1, "chair"), obj(2, "chair"), obj(3, "table")],
        };
        assert_eq!(so.subset_of("chair"), Subset::Multiple);
        assert_eq!(so.subset_of("table"), Subset::Unique);
        let mk = |id: u32, label: &str| Query {
            scene_id: "s".into(),
            query_id: format!("q{id}{label}"),
            text: "t".into(),
            target_id: id,
            target_label: label.into(),
            subset: Subset::Unique,
            extra: Default::default(),
        };
        let mut ds = Dataset {
            scenes: [("s".to_string(), so)].into_iter().collect(),
            queries: vec![mk(3, "table")],
        };
        assert!(ds.validate().is_ok());
        ds.queries.push(mk(3, "chair"));
        assert!(ds.validate().unwrap_err().to_string().contains("differs"));
        ds.queries.pop();
        ds.queries.push(mk(9, "table"));
        assert!(ds
            .validate()
            .unwrap_err()
            .to_string()
            .contains("not an object"));
    }

    #[test]
    fn load_round_trip_and_missing_scene() {
        let dir = tempfile::tempdir().unwrap();
        let so = SceneObjects {
            scene_id: "a".into(),
            objects: vec![obj(4, "lamp")],
        };
        let q = Query {
            scene_id: "a".into(),
            query_id: "a_0".into(),
            text: "the lamp".into(),
            target_id: 4,
            target_label: "lamp".into(),
            subset: Subset::Unique,
            extra: Default::default(),
        };
        write_dataset(
            dir.path(),
            std::slice::from_ref(&so),
            std::slice::from_ref(&q),
        )
        .unwrap();
        let ds = Dataset::load(dir.path()).unwrap();
        assert_eq!(ds.scenes["a"], so);
        assert_eq!(ds.queries, vec![q]);
        std::fs::remove_file(dir.path().join("objects/a.json")).unwrap();
        let err = Dataset::load(dir.path()).unwrap_err();
        assert!(err.to_string().contains("no objects/a.json"), "{err}");
    }
}
