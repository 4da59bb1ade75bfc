//! Templated queries single out exactly one object, and the FORMATS §2 files are written.

use grounder::synth::{generate, write_dataset, SynthObject, SynthParams};
use std::collections::BTreeMap;

fn params(seed: u64) -> SynthParams {
    SynthParams {
        frames: 1,
        color_size: (32, 24),
        depth_size: (16, 12),
        ..SynthParams::small(seed)
    }
}

/// Independent re-evaluation of each template against the objects.
fn matches(text: &str, objects: &[SynthObject]) -> Vec<u32> {
    let by = |label: &str| {
        objects
            .iter()
            .filter(|o| o.label == label)
            .collect::<Vec<_>>()
    };
    let rest = text
        .strip_prefix("the ")
        .expect("queries start with 'the '");
    if let Some((label, anchor)) = rest.split_once(" closest to the ") {
        let a = by(anchor);
        assert_eq!(a.len(), 1, "anchor {anchor} must be unique");
        let mut d: Vec<_> = by(label)
            .into_iter()
            .map(|o| (o.aabb.center_distance(&a[0].aabb), o.id))
            .collect();
        d.sort_by(|x, y| x.0.total_cmp(&y.0));
        return if d.len() >= 2 && d[1].0 - d[0].0 > 0.1 {
            vec![d[0].1]
        } else {
            d.iter().map(|x| x.1).collect()
        };
    }
    if let Some((label, anchor)) = rest.split_once(" farthest from the ") {
        let a = by(anchor);
        assert_eq!(a.len(), 1);
        let mut d: Vec<_> = by(label)
            .into_iter()
            .map(|o| (o.aabb.center_distance(&a[0].aabb), o.id))
            .collect();
        d.sort_by(|x, y| y.0.total_cmp(&x.0));
        return if d.len() >= 2 && d[0].0 - d[1].0 > 0.1 {
            vec![d[0].1]
        } else {
            d.iter().map(|x| x.1).collect()
        };
    }
    if let Some((label, anchor)) = rest.split_once(" on the ") {
        let a = by(anchor);
        assert_eq!(a.len(), 1);
        let top = a[0].aabb;
        return by(label)
            .into_iter()
            .filter(|o| {
                o.aabb.min[2] > top.min[2] + 0.05
                    && (0..2).all(|i| o.aabb.min[i] < top.max[i] && top.min[i] < o.aabb.max[i])
            })
            .map(|o| o.id)
            .collect();
    }
    // Extremes: every object within a looser tolerance of the best counts as a match.
    if let Some(label) = rest.strip_prefix("largest ") {
        let g = by(label);
        let best = g.iter().map(|o| o.aabb.volume()).fold(0.0, f64::max);
        return g
            .iter()
            .filter(|o| o.aabb.volume() * 1.1 >= best)
            .map(|o| o.id)
            .collect();
    }
    if let Some(label) = rest.strip_prefix("smallest ") {
        let g = by(label);
        let best = g.iter().map(|o| o.aabb.volume()).fold(f64::MAX, f64::min);
        return g
            .iter()
            .filter(|o| o.aabb.volume() <= best * 1.1)
            .map(|o| o.id)
            .collect();
    }
    if let Some(label) = rest.strip_prefix("tallest ") {
        let g = by(label);
        let best = g.iter().map(|o| o.aabb.max[2]).fold(f64::MIN, f64::max);
        return g
            .iter()
            .filter(|o| o.aabb.max[2] >= best - 0.05)
            .map(|o| o.id)
            .collect();
    }
    // Attribute: "<colour> <label>".
    let (colour, label) = rest.split_once(' ').expect("attribute query");
    objects
        .iter()
        .filter(|o| o.color == colour && o.label == label)
        .map(|o| o.id)
        .collect()
}

#[test]
fn every_query_has_exactly_one_matching_object() {
    let t = tempfile::tempdir().unwrap();
    let mut kinds = BTreeMap::new();
    let mut multiple = 0;
    for seed in 0..12 {
        let s = generate(&params(seed), t.path()).unwrap();
        let mut counts: BTreeMap<&str, usize> = BTreeMap::new();
        for o in &s.objects {
            *counts.entry(o.label.as_str()).or_default() += 1;
        }
        assert!(
            counts.values().any(|&c| c >= 2),
            "seed {seed}: no repeated label"
        );
        let mut ids = std::collections::BTreeSet::new();
        for q in &s.queries {
            assert!(ids.insert(q.query_id.clone()), "duplicate query id");
            let m = matches(&q.text, &s.objects);
            assert_eq!(
                m,
                vec![q.target_id],
                "seed {seed}: {:?} matches {:?}",
                q.text,
                m
            );
            let target = s.objects.iter().find(|o| o.id == q.target_id).unwrap();
            assert_eq!(target.label, q.target_label);
            let expected = if counts[target.label.as_str()] == 1 {
                "unique"
            } else {
                "multiple"
            };
            assert_eq!(q.subset, expected, "{}", q.text);
            multiple += (q.subset == "multiple") as usize;
            *kinds.entry(q.kind.clone()).or_insert(0) += 1;
        }
    }
    for k in ["attribute", "relation", "support", "extreme"] {
        assert!(
            kinds.get(k).copied().unwrap_or(0) > 0,
            "no {k} queries: {kinds:?}"
        );
    }
    assert!(multiple > 10, "too few 'multiple' queries: {multiple}");
}

#[test]
fn dataset_files_follow_formats_section_2() {
    let t = tempfile::tempdir().unwrap();
    let scenes: Vec<_> = (0..2)
        .map(|s| generate(&params(s), &t.path().join("scenes")).unwrap())
        .collect();
    let ds = t.path().join("ds");
    write_dataset(&scenes, &ds).unwrap();
    for s in &scenes {
        let v: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(ds.join(format!("objects/{}.json", s.scene_id))).unwrap(),
        )
        .unwrap();
        assert_eq!(v["scene_id"], s.scene_id.as_str());
        let objs = v["objects"].as_array().unwrap();
        assert_eq!(objs.len(), s.objects.len());
        for (j, o) in objs.iter().zip(&s.objects) {
            assert_eq!(j["id"].as_u64().unwrap(), o.id as u64);
            assert_eq!(j["label"], o.label.as_str());
            let min: Vec<f64> = serde_json::from_value(j["aabb"]["min"].clone()).unwrap();
            assert_eq!(min, o.aabb.min.to_vec());
        }
    }
    let text = std::fs::read_to_string(ds.join("queries.jsonl")).unwrap();
    let lines: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(
        lines.len(),
        scenes.iter().map(|s| s.queries.len()).sum::<usize>()
    );
    for l in &lines {
        for key in ["scene_id", "query_id", "text", "target_label", "subset"] {
            assert!(l[key].is_string(), "{key} missing in {l}");
        }
        assert!(l["target_id"].is_u64());
    }
}
