//! How sure a benchmark figure is: 95 % intervals from a bootstrap over target objects.
//!
//! Queries about one object mostly succeed or fail together (five sentences about one chair
//! share its segmentation), so resampling single queries would claim more certainty than
//! the data hold. The objects are resampled instead, each with all of its queries (a
//! cluster bootstrap), with a fixed seed so that a report is reproducible. A difference
//! between two runs of the same queries is resampled the same way, paired by query.

use super::metrics::QueryRecord;
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Resamples drawn for an interval.
pub const RESAMPLES: usize = 2000;
/// The bootstrap's seed (fixed: the same records give the same interval).
const SEED: u64 = 20_261_128;

/// A central 95 % interval.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Interval {
    pub lo: f64,
    pub hi: f64,
}

/// Intervals of the overall ScanRefer accuracies.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AccIntervals {
    /// Clusters resampled: target objects (a record without its target is its own).
    pub objects: usize,
    pub resamples: usize,
    pub acc_025: Interval,
    pub acc_05: Interval,
}

/// The cluster a record belongs to: its scene and target object, or the query alone when
/// the record does not name its target (results written before records carried it).
pub fn cluster_key(r: &QueryRecord) -> String {
    cluster_key_of(r, r.target_id)
}

/// [`cluster_key`] with the target named elsewhere (a paired record's, when `r` lacks it).
pub fn cluster_key_of(r: &QueryRecord, target: Option<u32>) -> String {
    match target {
        Some(t) => format!("{}#{t}", r.scene_id),
        None => format!("query {}", r.query_id),
    }
}

/// Per cluster (in key order): the sum of `value` over its records and their count.
pub fn clusters(records: impl IntoIterator<Item = (String, f64)>) -> Vec<(String, f64, usize)> {
    let mut by: BTreeMap<String, (f64, usize)> = BTreeMap::new();
    for (key, v) in records {
        let e = by.entry(key).or_insert((0.0, 0));
        e.0 += v;
        e.1 += 1;
    }
    by.into_iter().map(|(k, (s, n))| (k, s, n)).collect()
}

/// The 95 % interval of the mean of all values (sum over counts) when whole clusters are
/// drawn with replacement; `None` without clusters.
pub fn bootstrap(clusters: &[(f64, usize)], resamples: usize) -> Option<Interval> {
    if clusters.is_empty() || resamples == 0 {
        return None;
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(SEED);
    let mut means: Vec<f64> = (0..resamples)
        .map(|_| {
            let (mut s, mut n) = (0.0, 0usize);
            for _ in 0..clusters.len() {
                let c = clusters[rng.gen_range(0..clusters.len())];
                s += c.0;
                n += c.1;
            }
            if n == 0 {
                0.0
            } else {
                s / n as f64
            }
        })
        .collect();
    means.sort_by(f64::total_cmp);
    Some(Interval {
        lo: super::summary::percentile(&means, 2.5),
        hi: super::summary::percentile(&means, 97.5),
    })
}

/// Whether a record counts at `threshold` (ScanRefer: a box with IoU at or above it).
pub fn hit(r: &QueryRecord, threshold: f64) -> bool {
    r.predicted.is_some() && r.iou >= threshold
}

/// The intervals of a run's overall Acc@0.25 and Acc@0.5; `None` without records.
pub fn acc_intervals(records: &[QueryRecord]) -> Option<AccIntervals> {
    let at = |t: f64| {
        let c = clusters(
            records
                .iter()
                .map(|r| (cluster_key(r), f64::from(u8::from(hit(r, t))))),
        );
        let sums: Vec<(f64, usize)> = c.iter().map(|(_, s, n)| (*s, *n)).collect();
        (c.len(), bootstrap(&sums, RESAMPLES))
    };
    let ((objects, a25), (_, a50)) = (at(0.25), at(0.5));
    Some(AccIntervals {
        objects,
        resamples: RESAMPLES,
        acc_025: a25?,
        acc_05: a50?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::dataset::Subset;

    fn rec(scene: &str, target: Option<u32>, q: usize, iou: f64) -> QueryRecord {
        let id = format!("{scene}_q{q}");
        crate::eval::metrics::test_record(&id, scene, target, iou, Subset::Unique)
    }

    #[test]
    fn one_value_everywhere_has_no_spread_and_the_interval_holds_the_mean() {
        assert_eq!(bootstrap(&[], 100), None);
        let same = [(3.0, 3), (2.0, 2), (1.0, 1)];
        assert_eq!(bootstrap(&same, 500), Some(Interval { lo: 1.0, hi: 1.0 }));
        let mixed: Vec<(f64, usize)> = (0..40).map(|i| (f64::from(i % 2), 1)).collect();
        let iv = bootstrap(&mixed, RESAMPLES).expect("clusters");
        assert!(iv.lo < 0.5 && 0.5 < iv.hi, "{iv:?}");
        assert!(
            iv.lo > 0.25 && iv.hi < 0.75,
            "40 halves: about ±0.16, got {iv:?}"
        );
        // Seeded: the same clusters give the same interval.
        assert_eq!(bootstrap(&mixed, RESAMPLES), Some(iv));
    }

    #[test]
    fn queries_about_one_object_are_resampled_together() {
        // 20 objects, half found and half missed, 5 queries each: as uncertain as 20
        // queries, not as 100.
        let records: Vec<QueryRecord> = (0..20u32)
            .flat_map(|o| {
                let iou = if o % 2 == 0 { 0.9 } else { 0.0 };
                (0..5).map(move |q| rec("s", Some(o), q + 5 * o as usize, iou))
            })
            .collect();
        let by_object = acc_intervals(&records).expect("records");
        assert_eq!(by_object.objects, 20);
        let loose: Vec<QueryRecord> = records
            .iter()
            .cloned()
            .map(|mut r| {
                r.target_id = None;
                r
            })
            .collect();
        let by_query = acc_intervals(&loose).expect("records");
        assert_eq!(by_query.objects, 100);
        let width = |i: Interval| i.hi - i.lo;
        assert!(
            width(by_object.acc_025) > 1.8 * width(by_query.acc_025),
            "{by_object:?} against {by_query:?}"
        );
        // At 0.5 the found half still counts (IoU 0.9).
        assert!(by_object.acc_05.lo < 0.5 && by_object.acc_05.hi > 0.5);
    }
}
