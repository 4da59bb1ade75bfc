//! Per-query records and the summary metrics of FORMATS §3 (ScanRefer, Nr3D, stage rates).

use super::dataset::{Query, SceneObjects, Subset};
use crate::geometry::Aabb;
use serde::{Deserialize, Serialize};

/// Success of each pipeline stage for one query (the paper's Table 10 criteria).
/// `None` means "not known" (stage not reached or the trace does not say).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct StageOutcome {
    /// The pre-selected views contain the target.
    pub preselection_contains_target: Option<bool>,
    /// The image the VLM chose shows the target.
    pub image_choice_correct: Option<bool>,
    /// The detector found the target (a box with 2D IoU >= 0.5) in the chosen image.
    pub detection_present: Option<bool>,
    /// The VLM chose the target's detection.
    pub instance_choice_correct: Option<bool>,
    /// 2D IoU of the segmenter's mask with the target's instance mask.
    pub mask_iou: Option<f64>,
    /// 3D IoU of the final box with the target's box is >= 0.5.
    pub box_iou_ge_05: Option<bool>,
}

/// Mask IoU at or above which segmentation counts as a success.
pub const MASK_SUCCESS_IOU: f64 = 0.5;

impl StageOutcome {
    /// Name of the first stage known to have failed, in pipeline order.
    pub fn first_failure(&self) -> Option<&'static str> {
        let checks = [
            ("preselection", self.preselection_contains_target),
            ("image_choice", self.image_choice_correct),
            ("detection", self.detection_present),
            ("instance_choice", self.instance_choice_correct),
            ("segmentation", self.mask_iou.map(|m| m >= MASK_SUCCESS_IOU)),
            ("projection", self.box_iou_ge_05),
        ];
        checks
            .iter()
            .find(|(_, ok)| *ok == Some(false))
            .map(|(n, _)| *n)
    }
}

/// One line of `results.jsonl`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct QueryRecord {
    pub query_id: String,
    pub scene_id: String,
    /// The query's target object (absent in results written before records carried it);
    /// queries about one object are resampled together for the report's intervals.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_id: Option<u32>,
    /// The target's class (`target_label` of the query; absent in older results).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_label: Option<String>,
    pub subset: Subset,
    /// Predicted box, `null` when the job produced none.
    pub predicted: Option<Aabb>,
    /// 3D IoU with the target's box (0 without prediction).
    pub iou: f64,
    /// Nr3D criterion: the nearest ground-truth centre is the target's.
    pub nr3d_correct: bool,
    /// First failed stage ("job_failed" / "no_prediction" when nothing finer is known).
    pub failure_stage: Option<String>,
    pub vlm_calls: u32,
    pub tokens: u64,
    pub latency_ms: f64,
    pub stages: StageOutcome,
    /// Nr3D difficulty flag copied from the query, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hard: Option<bool>,
    /// Nr3D view-dependence flag copied from the query, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view_dependent: Option<bool>,
    /// Final job status (succeeded / failed / canceled / error).
    #[serde(default)]
    pub status: String,
    /// Error message of a failed job, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// What the runner observed for one query, before scoring.
#[derive(Debug, Clone, Default)]
pub struct Observation {
    pub predicted: Option<Aabb>,
    pub stages: StageOutcome,
    pub vlm_calls: u32,
    pub tokens: u64,
    pub latency_ms: f64,
    pub status: String,
    pub error: Option<String>,
}

/// Nr3D rule: is the object whose centre is nearest the predicted centre the target?
pub fn nr3d_correct(pred: &Aabb, objects: &SceneObjects, target_id: u32) -> bool {
    let nearest = objects
        .objects
        .iter()
        .map(|o| (o.id, pred.center_distance(&o.aabb)))
        .min_by(|a, b| a.1.total_cmp(&b.1));
    matches!(nearest, Some((id, _)) if id == target_id)
}

/// Score one observation against the ground truth into a record.
pub fn score(query: &Query, objects: &SceneObjects, obs: Observation) -> QueryRecord {
    let target = objects.get(query.target_id);
    let iou = match (&obs.predicted, target) {
        (Some(p), Some(t)) => p.iou(&t.aabb),
        _ => 0.0,
    };
    let nr3d = obs
        .predicted
        .as_ref()
        .is_some_and(|p| nr3d_correct(p, objects, query.target_id));
    let mut stages = obs.stages;
    if obs.predicted.is_some() {
        stages.box_iou_ge_05 = Some(iou >= 0.5);
    }
    let failure_stage = stages.first_failure().map(str::to_string).or_else(|| {
        if obs.status != "succeeded" {
            Some("job_failed".to_string())
        } else if obs.predicted.is_none() {
            Some("no_prediction".to_string())
        } else {
            None
        }
    });
    QueryRecord {
        query_id: query.query_id.clone(),
        scene_id: query.scene_id.clone(),
        target_id: Some(query.target_id),
        target_label: Some(query.target_label.clone()),
        subset: query.subset,
        predicted: obs.predicted,
        iou,
        nr3d_correct: nr3d,
        failure_stage,
        vlm_calls: obs.vlm_calls,
        tokens: obs.tokens,
        latency_ms: obs.latency_ms,
        stages,
        hard: query.flag("hard"),
        view_dependent: query.flag("view_dependent"),
        status: obs.status,
        error: obs.error,
    }
}

pub use super::summary::*;

/// A scored record for unit tests: a unit box predicted, one VLM call, 10 tokens, 5 ms.
#[cfg(test)]
pub(crate) fn test_record(
    query_id: &str,
    scene_id: &str,
    target_id: Option<u32>,
    iou: f64,
    subset: Subset,
) -> QueryRecord {
    QueryRecord {
        query_id: query_id.into(),
        scene_id: scene_id.into(),
        target_id,
        target_label: None,
        subset,
        predicted: Some(Aabb::new([0.0; 3], [1.0; 3])),
        iou,
        nr3d_correct: iou > 0.3,
        failure_stage: None,
        vlm_calls: 1,
        tokens: 10,
        latency_ms: 5.0,
        stages: StageOutcome::default(),
        hard: None,
        view_dependent: None,
        status: "succeeded".into(),
        error: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::dataset::SceneObject;

    fn scene() -> SceneObjects {
        let o = |id, label: &str, min: [f64; 3], max: [f64; 3]| SceneObject {
            id,
            label: label.into(),
            aabb: Aabb::new(min, max),
        };
        SceneObjects {
            scene_id: "s".into(),
            objects: vec![
                o(1, "chair", [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]),
                o(2, "chair", [3.0, 0.0, 0.0], [4.0, 1.0, 1.0]),
                o(3, "table", [0.0, 3.0, 0.0], [2.0, 5.0, 1.0]),
            ],
        }
    }

    fn query(id: &str, target: u32, subset: Subset, extra: serde_json::Value) -> Query {
        Query {
            scene_id: "s".into(),
            query_id: id.into(),
            text: "t".into(),
            target_id: target,
            target_label: if target == 3 {
                "table".into()
            } else {
                "chair".into()
            },
            subset,
            extra: extra.as_object().cloned().unwrap_or_default(),
        }
    }

    fn obs(pred: Option<Aabb>, latency: f64) -> Observation {
        Observation {
            predicted: pred,
            latency_ms: latency,
            status: "succeeded".into(),
            vlm_calls: 2,
            tokens: 100,
            ..Default::default()
        }
    }

    #[test]
    fn nr3d_uses_nearest_centre_of_all_objects() {
        let s = scene();
        // Tiny box near chair 2's centre (3.5, 0.5, 0.5): IoU with chair 2 is small but Nr3D is right.
        let p = Aabb::new([3.4, 0.4, 0.4], [3.6, 0.6, 0.6]);
        assert!(nr3d_correct(&p, &s, 2));
        assert!(!nr3d_correct(&p, &s, 1));
        let r = score(
            &query("q", 2, Subset::Multiple, serde_json::json!({})),
            &s,
            obs(Some(p), 1.0),
        );
        assert!(r.nr3d_correct);
        assert_eq!(
            r.target_label.as_deref(),
            Some("chair"),
            "the query's class"
        );
        // 0.008 / 1.0
        assert!((r.iou - 0.008).abs() < 1e-9, "{}", r.iou);
        assert_eq!(r.failure_stage.as_deref(), Some("projection"));
    }

    #[test]
    fn hand_computed_summary() {
        let s = scene();
        let e = serde_json::json!({});
        // q1: exact chair 1 (IoU 1). q2: chair 2 shifted by 0.5 in x: inter 0.5, union 1.5 -> 1/3.
        // q3: table, box [0,3,0]-[2,4,1]: inter 2, union 4 -> 0.5. q4: no prediction.
        let recs = vec![
            score(
                &query(
                    "q1",
                    1,
                    Subset::Multiple,
                    serde_json::json!({"hard": false, "view_dependent": true}),
                ),
                &s,
                obs(Some(Aabb::new([0.0; 3], [1.0; 3])), 10.0),
            ),
            score(
                &query("q2", 2, Subset::Multiple, serde_json::json!({"hard": true})),
                &s,
                obs(Some(Aabb::new([3.5, 0.0, 0.0], [4.5, 1.0, 1.0])), 20.0),
            ),
            score(
                &query("q3", 3, Subset::Unique, e.clone()),
                &s,
                obs(Some(Aabb::new([0.0, 3.0, 0.0], [2.0, 4.0, 1.0])), 30.0),
            ),
            score(
                &query("q4", 3, Subset::Unique, e),
                &s,
                Observation {
                    status: "failed".into(),
                    latency_ms: 40.0,
                    ..Default::default()
                },
            ),
        ];
        assert!((recs[1].iou - 1.0 / 3.0).abs() < 1e-12);
        assert!((recs[2].iou - 0.5).abs() < 1e-12);
        assert_eq!(recs[3].failure_stage.as_deref(), Some("job_failed"));
        let sm = summarize(&recs);
        assert_eq!(sm.n_queries, 4);
        assert_eq!(sm.n_with_prediction, 3);
        assert_eq!(
            sm.scanrefer.overall,
            AccBlock {
                n: 4,
                acc_025: 0.75,
                acc_05: 0.5
            }
        );
        assert_eq!(
            sm.scanrefer.unique,
            AccBlock {
                n: 2,
                acc_025: 0.5,
                acc_05: 0.5
            }
        );
        assert_eq!(
            sm.scanrefer.multiple,
            AccBlock {
                n: 2,
                acc_025: 1.0,
                acc_05: 0.5
            }
        );
        // Nr3D: q1, q2 (centre 4,.5,.5 nearest chair 2), q3 (centre 1,3.5,.5 nearest table) right; q4 wrong.
        assert_eq!(
            sm.nr3d.overall,
            Rate {
                n: 4,
                k: 3,
                rate: 0.75
            }
        );
        assert_eq!(
            sm.nr3d.easy,
            Some(Rate {
                n: 1,
                k: 1,
                rate: 1.0
            })
        );
        assert_eq!(
            sm.nr3d.hard,
            Some(Rate {
                n: 1,
                k: 1,
                rate: 1.0
            })
        );
        assert_eq!(
            sm.nr3d.view_dependent,
            Some(Rate {
                n: 1,
                k: 1,
                rate: 1.0
            })
        );
        assert_eq!(
            sm.nr3d.view_independent,
            Some(Rate {
                n: 0,
                k: 0,
                rate: 0.0
            })
        );
        assert_eq!(
            sm.stages.box_iou_ge_05,
            Rate {
                n: 3,
                k: 2,
                rate: 2.0 / 3.0
            }
        );
        assert_eq!(sm.mean_vlm_calls, 1.5);
        assert_eq!(sm.mean_tokens, 75.0);
        assert_eq!(sm.latency_ms.p50, 20.0);
        assert_eq!(sm.latency_ms.p90, 40.0);
        assert_eq!(sm.latency_ms.mean, 25.0);
        assert_eq!(sm.failure_stages.get("projection"), Some(&1));
        assert_eq!(sm.failure_stages.get("job_failed"), Some(&1));
    }

    #[test]
    fn stage_rates_and_first_failure() {
        let st = StageOutcome {
            preselection_contains_target: Some(true),
            image_choice_correct: Some(true),
            detection_present: None,
            instance_choice_correct: Some(false),
            mask_iou: Some(0.4),
            box_iou_ge_05: Some(false),
        };
        assert_eq!(st.first_failure(), Some("instance_choice"));
        let s = scene();
        let mut o = obs(Some(Aabb::new([0.0; 3], [1.0; 3])), 5.0);
        o.stages = st;
        let r = score(
            &query("q", 1, Subset::Multiple, serde_json::json!({})),
            &s,
            o,
        );
        // The record's own box IoU overrides the trace: exact box.
        assert_eq!(r.stages.box_iou_ge_05, Some(true));
        let mut o2 = obs(None, 5.0);
        o2.stages.mask_iou = Some(0.8);
        o2.stages.detection_present = Some(true);
        let r2 = score(
            &query("q2", 1, Subset::Multiple, serde_json::json!({})),
            &s,
            o2,
        );
        assert_eq!(r2.failure_stage.as_deref(), Some("no_prediction"));
        let sm = summarize(&[r, r2]);
        assert_eq!(
            sm.stages.mask_iou_ge_05,
            Rate {
                n: 2,
                k: 1,
                rate: 0.5
            }
        );
        assert!((sm.stages.mask_iou_mean.unwrap() - 0.6).abs() < 1e-12);
        assert_eq!(
            sm.stages.detection_present,
            Rate {
                n: 1,
                k: 1,
                rate: 1.0
            }
        );
        assert_eq!(
            sm.stages.preselection_contains_target,
            Rate {
                n: 1,
                k: 1,
                rate: 1.0
            }
        );
    }

    #[test]
    fn percentile_nearest_rank() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(percentile(&v, 50.0), 50.0);
        assert_eq!(percentile(&v, 99.0), 99.0);
        assert_eq!(percentile(&[7.0], 90.0), 7.0);
        assert_eq!(percentile(&[], 50.0), 0.0);
    }
}
