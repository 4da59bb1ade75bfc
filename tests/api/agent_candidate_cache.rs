//! Candidates cached by another version of the service, or with other settings, are never
//! read as this one's: the frames a job needs get theirs found again, and cached.

use crate::agent_fixture::*;
use grounder::vision::Detection;

/// The boxes of a trace's candidate list.
fn boxes(listed: &serde_json::Value) -> Vec<Vec<f32>> {
    listed
        .as_array()
        .cloned()
        .unwrap_or_default()
        .iter()
        .map(|c| serde_json::from_value(c["box"].clone()).unwrap())
        .collect()
}

#[tokio::test]
async fn candidates_cached_under_an_older_key_are_found_again_not_read() {
    let f = Fixture::start_with_config(5_000, "centernet", |c| {
        c.agent.candidates.enabled = true;
        c.agent.candidates.in_views = true;
        c.agent.candidates.in_views_partial_only = false;
    })
    .await;
    let (id, key) = (&f.scene_id, &f.candidates_key);
    let indexed = f.store.scene_candidates(id, key).await.unwrap();
    assert!(indexed.values().any(|c| !c.is_empty()), "{indexed:?}");
    // An older release's index: one tiny box per frame under the unversioned key.
    let stale = Detection {
        label: "object".into(),
        score: 1.0,
        bbox: [0.0, 0.0, 7.0, 5.0],
    };
    for idx in indexed.keys() {
        let one = std::slice::from_ref(&stale);
        f.store
            .put_candidates(id, "candidates", *idx, one)
            .await
            .unwrap();
    }
    assert!(f.store.scene_candidates(id, key).await.unwrap().is_empty());

    let job = f.run_whiteboard_mark_0().await;
    let out = &steps(&job, "candidates")[0]["outputs"];
    assert_eq!(out["from"], "computed", "{out:#}");
    let want: Vec<Vec<f32>> = indexed[&0].iter().map(|d| d.bbox.to_vec()).collect();
    assert_eq!(boxes(&out["candidates"]), want, "what indexing found");
    let proj = &steps(&job, "projection")[0]["outputs"];
    let computed: Vec<String> =
        serde_json::from_value(proj["view_candidates_computed"].clone()).unwrap_or_default();
    assert!(!computed.is_empty(), "{proj:#}");
    for v in computed.iter().chain(std::iter::once(&"00000".to_string())) {
        let idx: usize = v.parse().unwrap();
        let now = f.store.frame_candidates(id, key, idx).await.unwrap();
        assert_eq!(now.as_ref(), indexed.get(&idx), "frame {idx} cached again");
        let old = f
            .store
            .frame_candidates(id, "candidates", idx)
            .await
            .unwrap();
        assert_eq!(old, None, "frame {idx}: the stale rows are replaced");
    }

    // The next job reads what the first one cached.
    let job = f.run_whiteboard_mark_0().await;
    assert_eq!(steps(&job, "candidates")[0]["outputs"]["from"], "index");
    let proj = &steps(&job, "projection")[0]["outputs"];
    assert_eq!(proj["view_candidates_computed"], serde_json::json!([]));
}
