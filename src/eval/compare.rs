//! `grounder compare`: two evaluation reports of the same queries, query by query. The
//! accuracies of each, their difference with its 95 % interval (a bootstrap over target
//! objects, paired by query: [`super::interval`]), and the objects whose queries changed.

use super::interval::{bootstrap, cluster_key_of, clusters, hit, Interval, RESAMPLES};
use super::metrics::QueryRecord;
use anyhow::{Context, Result};
use std::collections::{BTreeMap, HashMap, HashSet};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// `grounder compare`.
#[derive(Debug, clap::Args)]
pub struct CompareArgs {
    /// The reference report: a `grounder eval --out` folder or its results.jsonl.
    pub base: PathBuf,
    /// The report compared with it, over the queries both hold.
    pub run: PathBuf,
    /// Dataset folder (queries.jsonl) naming the targets of records that do not carry
    /// theirs (reports written before records named them). Without it a pair takes the
    /// target the run's record names, and a pair neither names is resampled alone.
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Print the comparison as one JSON object (shares, not percentages) instead of text.
    #[arg(long)]
    pub json: bool,
}

/// One threshold's figures over the matched queries.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Delta {
    pub threshold: f64,
    pub base: f64,
    pub run: f64,
    /// `run - base`, as a share of the queries.
    pub difference: f64,
    pub interval: Option<Interval>,
    /// Per object (cluster key) whose hits changed: the net change and its query count.
    pub changed: Vec<Changed>,
}

/// An object whose queries' hits changed.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Changed {
    /// `scene#target` (or `query ID` for a record without its target).
    pub object: String,
    /// Queries gained less queries lost.
    pub net: i64,
    pub queries: usize,
}

/// The comparison of two reports.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Comparison {
    pub matched: usize,
    pub only_base: usize,
    pub only_run: usize,
    pub objects: usize,
    pub deltas: Vec<Delta>,
}

/// Compare `run` with `base` over the queries (by id) both hold. A pair is resampled with
/// its target object, named by the base record or else by the run's.
pub fn compare(base: &[QueryRecord], run: &[QueryRecord]) -> Comparison {
    let by_id: HashMap<&str, &QueryRecord> = run.iter().map(|r| (r.query_id.as_str(), r)).collect();
    // Each pair with its cluster, named by the base record's target or else by the run's.
    let pairs: Vec<(&QueryRecord, &QueryRecord, String)> = base
        .iter()
        .filter_map(|b| {
            let r = *by_id.get(b.query_id.as_str())?;
            Some((b, r, cluster_key_of(b, b.target_id.or(r.target_id))))
        })
        .collect();
    let matched = pairs.len();
    let in_base: HashSet<&str> = base.iter().map(|r| r.query_id.as_str()).collect();
    let mut objects = 0;
    let deltas = [0.25, 0.5]
        .into_iter()
        .map(|t| {
            let d = |b: &QueryRecord, r: &QueryRecord| {
                f64::from(u8::from(hit(r, t))) - f64::from(u8::from(hit(b, t)))
            };
            let c = clusters(pairs.iter().map(|(b, r, k)| (k.clone(), d(b, r))));
            objects = c.len();
            let sums: Vec<(f64, usize)> = c.iter().map(|(_, s, n)| (*s, *n)).collect();
            let share = |f: &dyn Fn(&QueryRecord, &QueryRecord) -> bool| {
                let k = pairs.iter().filter(|(b, r, _)| f(b, r)).count();
                k as f64 / matched.max(1) as f64
            };
            let (base, run) = (share(&|b, _| hit(b, t)), share(&|_, r| hit(r, t)));
            Delta {
                threshold: t,
                base,
                run,
                difference: run - base,
                interval: bootstrap(&sums, RESAMPLES),
                changed: c
                    .into_iter()
                    .filter(|(_, s, _)| *s != 0.0)
                    .map(|(object, s, queries)| Changed {
                        object,
                        net: s as i64,
                        queries,
                    })
                    .collect(),
            }
        })
        .collect();
    Comparison {
        matched,
        only_base: base.len() - matched,
        only_run: run
            .iter()
            .filter(|r| !in_base.contains(r.query_id.as_str()))
            .count(),
        objects,
        deltas,
    }
}

/// The comparison as text (percentages; the difference in points).
pub fn render(c: &Comparison) -> String {
    let mut o = String::new();
    let _ = writeln!(
        o,
        "{} queries in both reports ({} only in the base, {} only in the run), {} target objects",
        c.matched, c.only_base, c.only_run, c.objects
    );
    for d in &c.deltas {
        let iv = d.interval.map_or_else(
            || "no interval".to_string(),
            |i| format!("95 % interval {:+.1} to {:+.1}", 100.0 * i.lo, 100.0 * i.hi),
        );
        let _ = writeln!(
            o,
            "Acc@{}: base {:.1} %, run {:.1} %, difference {:+.1} points ({iv}, objects resampled)",
            d.threshold,
            100.0 * d.base,
            100.0 * d.run,
            100.0 * d.difference
        );
    }
    for d in &c.deltas {
        if d.changed.is_empty() {
            continue;
        }
        let _ = writeln!(o, "objects whose queries changed at {}:", d.threshold);
        let mut changed = d.changed.clone();
        changed.sort_by(|a, b| {
            (a.net.abs().cmp(&b.net.abs()).reverse()).then(a.object.cmp(&b.object))
        });
        for c in changed {
            let _ = writeln!(o, "  {}: {:+} of {} queries", c.object, c.net, c.queries);
        }
    }
    o
}

fn results_of(path: &Path) -> Result<Vec<QueryRecord>> {
    let file = if path.is_dir() {
        path.join(super::report::RESULTS)
    } else {
        path.to_path_buf()
    };
    if !file.is_file() {
        anyhow::bail!("{}: no results.jsonl there", path.display());
    }
    super::report::read_results(&file)
}

/// Run `grounder compare`.
pub fn run(args: CompareArgs) -> Result<()> {
    let mut base = results_of(&args.base)?;
    let mut run = results_of(&args.run)?;
    if let Some(ds) = &args.dataset {
        let path = ds.join("queries.jsonl");
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        let targets: BTreeMap<String, u32> = super::dataset::parse_queries(&text)?
            .into_iter()
            .map(|q| (q.query_id, q.target_id))
            .collect();
        for r in base.iter_mut().chain(run.iter_mut()) {
            if r.target_id.is_none() {
                r.target_id = targets.get(&r.query_id).copied();
            }
        }
    }
    let c = compare(&base, &run);
    if c.matched == 0 {
        anyhow::bail!("the two reports share no query id");
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&c)?);
    } else {
        print!("{}", render(&c));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::dataset::Subset;

    fn rec(q: &str, target: u32, iou: f64) -> QueryRecord {
        crate::eval::metrics::test_record(q, "s", Some(target), iou, Subset::Multiple)
    }

    #[test]
    fn paired_difference_by_object_with_the_objects_that_changed() {
        // 10 objects of 3 queries; the run loses object 0 (all 3 queries) and gains one
        // query of object 1 at 0.25 only. Query "x" is in the base alone.
        let mut base: Vec<QueryRecord> = (0..30)
            .map(|i| rec(&format!("q{i}"), i / 3, if i < 3 { 0.8 } else { 0.6 }))
            .collect();
        base[3].iou = 0.1;
        base.push(rec("x", 99, 0.9));
        let mut run: Vec<QueryRecord> = base[..30].to_vec();
        for r in &mut run[..3] {
            r.iou = 0.0;
        }
        run[3].iou = 0.3;
        let c = compare(&base, &run);
        assert_eq!(
            (c.matched, c.only_base, c.only_run, c.objects),
            (30, 1, 0, 10)
        );
        let d25 = &c.deltas[0];
        assert!((d25.base - 29.0 / 30.0).abs() < 1e-12);
        assert!((d25.difference - (-2.0 / 30.0)).abs() < 1e-12);
        let ch = |object: &str, net, queries| Changed {
            object: object.into(),
            net,
            queries,
        };
        assert_eq!(d25.changed, vec![ch("s#0", -3, 3), ch("s#1", 1, 3)]);
        let iv = d25.interval.expect("clusters");
        assert!(iv.lo < d25.difference && d25.difference < iv.hi, "{iv:?}");
        assert!(iv.hi <= 0.1 && iv.lo >= -0.45, "{iv:?}");
        // At 0.5 only the lost object changes (object 1's gain is an IoU of 0.3).
        assert_eq!(c.deltas[1].changed, vec![ch("s#0", -3, 3)]);
        let text = render(&c);
        assert!(text.contains("Acc@0.25: base 96.7 %, run 90.0 %, difference -6.7 points"));
        assert!(text.contains("  s#0: -3 of 3 queries"), "{text}");
    }

    #[test]
    fn the_run_names_the_targets_an_older_base_does_not() {
        // 4 objects of 2 queries; the base's records predate target ids.
        let run: Vec<QueryRecord> = (0..8)
            .map(|i| rec(&format!("q{i}"), i / 2, if i < 2 { 0.0 } else { 0.6 }))
            .collect();
        let base: Vec<QueryRecord> = run
            .iter()
            .map(|r| QueryRecord {
                target_id: None,
                iou: 0.6,
                ..r.clone()
            })
            .collect();
        let c = compare(&base, &run);
        assert_eq!((c.matched, c.objects), (8, 4));
        let lost = Changed {
            object: "s#0".into(),
            net: -2,
            queries: 2,
        };
        assert_eq!(c.deltas[0].changed, vec![lost]);
    }

    #[test]
    fn a_folder_without_results_is_a_clear_error() {
        let dir = tempfile::tempdir().expect("tempdir");
        let err = results_of(dir.path()).expect_err("no results");
        assert!(err.to_string().contains("no results.jsonl there"), "{err}");
    }
}
