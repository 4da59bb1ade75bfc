//! The summary of a run's records (FORMATS §3): ScanRefer accuracies per subset, Nr3D
//! accuracy, per-stage success rates, VLM use and latency percentiles.

use super::dataset::Subset;
use super::metrics::{QueryRecord, StageOutcome, MASK_SUCCESS_IOU};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// ScanRefer accuracies over a group of queries.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct AccBlock {
    pub n: usize,
    pub acc_025: f64,
    pub acc_05: f64,
}

/// A success rate: `k` of `n` (rate 0 when n = 0).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Rate {
    pub n: usize,
    pub k: usize,
    pub rate: f64,
}

impl Rate {
    fn of<I: IntoIterator<Item = bool>>(it: I) -> Self {
        let (mut n, mut k) = (0, 0);
        for b in it {
            n += 1;
            k += b as usize;
        }
        Rate {
            n,
            k,
            rate: if n == 0 { 0.0 } else { k as f64 / n as f64 },
        }
    }
}

/// ScanRefer metrics.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ScanReferSummary {
    pub overall: AccBlock,
    pub unique: AccBlock,
    pub multiple: AccBlock,
    /// 95 % intervals of the overall accuracies, resampling target objects
    /// ([`super::interval`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub overall_interval: Option<super::interval::AccIntervals>,
}

/// Nr3D metrics; the split rates are present only when some query carries the flag.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Nr3dSummary {
    pub overall: Rate,
    pub easy: Option<Rate>,
    pub hard: Option<Rate>,
    pub view_dependent: Option<Rate>,
    pub view_independent: Option<Rate>,
}

/// Per-stage success rates over the queries where the stage outcome is known.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct StageRates {
    pub preselection_contains_target: Rate,
    pub image_choice_correct: Rate,
    pub detection_present: Rate,
    pub instance_choice_correct: Rate,
    /// Masks with IoU >= 0.5.
    pub mask_iou_ge_05: Rate,
    /// Mean mask IoU over known values.
    pub mask_iou_mean: Option<f64>,
    pub box_iou_ge_05: Rate,
}

/// Latency percentiles (nearest-rank) in milliseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Latency {
    pub p50: f64,
    pub p90: f64,
    pub p99: f64,
    pub mean: f64,
}

/// ScanRefer accuracies of the queries whose target is of one class.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ClassAcc {
    pub label: String,
    pub n: usize,
    pub acc_025: f64,
    pub acc_05: f64,
    /// Mean 3D IoU (0 for a query without a box).
    pub mean_iou: f64,
}

/// Per target class, the classes that lose the most queries first (at 0.25, then at 0.5,
/// then by name). Records without a label (older results) are left out.
pub fn by_class(records: &[QueryRecord]) -> Vec<ClassAcc> {
    let mut of: BTreeMap<&str, Vec<&QueryRecord>> = BTreeMap::new();
    for r in records {
        if let Some(l) = &r.target_label {
            of.entry(l.as_str()).or_default().push(r);
        }
    }
    let mut out: Vec<ClassAcc> = of
        .into_iter()
        .map(|(label, rs)| {
            let a = acc(&rs);
            ClassAcc {
                label: label.to_string(),
                n: a.n,
                acc_025: a.acc_025,
                acc_05: a.acc_05,
                mean_iou: rs.iter().map(|r| r.iou).sum::<f64>() / rs.len().max(1) as f64,
            }
        })
        .collect();
    let lost = |c: &ClassAcc, a: f64| ((1.0 - a) * c.n as f64).round() as usize;
    out.sort_by(|a, b| {
        (lost(b, b.acc_025), lost(b, b.acc_05))
            .cmp(&(lost(a, a.acc_025), lost(a, a.acc_05)))
            .then_with(|| a.label.cmp(&b.label))
    });
    out
}

/// Everything written to `summary.json`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    pub n_queries: usize,
    pub n_with_prediction: usize,
    pub scanrefer: ScanReferSummary,
    pub nr3d: Nr3dSummary,
    pub stages: StageRates,
    pub mean_vlm_calls: f64,
    pub mean_tokens: f64,
    pub latency_ms: Latency,
    /// How many queries failed first at each stage.
    pub failure_stages: BTreeMap<String, usize>,
    /// Accuracies per target class ([`by_class`]; empty for results without labels).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub by_class: Vec<ClassAcc>,
}

fn acc(records: &[&QueryRecord]) -> AccBlock {
    let n = records.len();
    if n == 0 {
        return AccBlock::default();
    }
    let c25 = records
        .iter()
        .filter(|r| r.predicted.is_some() && r.iou >= 0.25)
        .count();
    let c50 = records
        .iter()
        .filter(|r| r.predicted.is_some() && r.iou >= 0.5)
        .count();
    AccBlock {
        n,
        acc_025: c25 as f64 / n as f64,
        acc_05: c50 as f64 / n as f64,
    }
}

/// Nearest-rank percentile of a sorted slice (`p` in 0..=100); 0 for an empty slice.
pub fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let rank = ((p / 100.0) * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

fn flagged_rate(
    records: &[QueryRecord],
    pick: impl Fn(&QueryRecord) -> Option<bool>,
    want: bool,
) -> Option<Rate> {
    let any = records.iter().any(|r| pick(r).is_some());
    any.then(|| {
        Rate::of(
            records
                .iter()
                .filter(|r| pick(r) == Some(want))
                .map(|r| r.nr3d_correct),
        )
    })
}

/// Summarise all records.
pub fn summarize(records: &[QueryRecord]) -> Summary {
    let all: Vec<&QueryRecord> = records.iter().collect();
    let uniq: Vec<&QueryRecord> = records
        .iter()
        .filter(|r| r.subset == Subset::Unique)
        .collect();
    let mult: Vec<&QueryRecord> = records
        .iter()
        .filter(|r| r.subset == Subset::Multiple)
        .collect();
    let n = records.len();
    let mean = |f: &dyn Fn(&QueryRecord) -> f64| {
        if n == 0 {
            0.0
        } else {
            records.iter().map(f).sum::<f64>() / n as f64
        }
    };
    let mut lat: Vec<f64> = records.iter().map(|r| r.latency_ms).collect();
    lat.sort_by(f64::total_cmp);
    let masks: Vec<f64> = records.iter().filter_map(|r| r.stages.mask_iou).collect();
    let mut failure_stages = BTreeMap::new();
    for r in records {
        if let Some(f) = &r.failure_stage {
            *failure_stages.entry(f.clone()).or_insert(0) += 1;
        }
    }
    let st = |f: fn(&StageOutcome) -> Option<bool>| {
        Rate::of(records.iter().filter_map(|r| f(&r.stages)))
    };
    Summary {
        n_queries: n,
        n_with_prediction: records.iter().filter(|r| r.predicted.is_some()).count(),
        scanrefer: ScanReferSummary {
            overall: acc(&all),
            unique: acc(&uniq),
            multiple: acc(&mult),
            overall_interval: super::interval::acc_intervals(records),
        },
        nr3d: Nr3dSummary {
            overall: Rate::of(records.iter().map(|r| r.nr3d_correct)),
            easy: flagged_rate(records, |r| r.hard, false),
            hard: flagged_rate(records, |r| r.hard, true),
            view_dependent: flagged_rate(records, |r| r.view_dependent, true),
            view_independent: flagged_rate(records, |r| r.view_dependent, false),
        },
        stages: StageRates {
            preselection_contains_target: st(|s| s.preselection_contains_target),
            image_choice_correct: st(|s| s.image_choice_correct),
            detection_present: st(|s| s.detection_present),
            instance_choice_correct: st(|s| s.instance_choice_correct),
            mask_iou_ge_05: Rate::of(masks.iter().map(|m| *m >= MASK_SUCCESS_IOU)),
            mask_iou_mean: (!masks.is_empty())
                .then(|| masks.iter().sum::<f64>() / masks.len() as f64),
            box_iou_ge_05: st(|s| s.box_iou_ge_05),
        },
        mean_vlm_calls: mean(&|r| r.vlm_calls as f64),
        mean_tokens: mean(&|r| r.tokens as f64),
        latency_ms: Latency {
            p50: percentile(&lat, 50.0),
            p90: percentile(&lat, 90.0),
            p99: percentile(&lat, 99.0),
            mean: mean(&|r| r.latency_ms),
        },
        failure_stages,
        by_class: by_class(records),
    }
}
