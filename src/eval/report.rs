//! The report folder: `results.jsonl` (append-only, resumable), `summary.json`,
//! `summary.md` and `iou_hist.png`.

use super::metrics::{summarize, AccBlock, QueryRecord, Rate, Summary};
use super::plot;
use anyhow::{Context, Result};
use std::collections::HashSet;
use std::fmt::Write as _;
use std::io::Write;
use std::path::{Path, PathBuf};

/// File name of the per-query results.
pub const RESULTS: &str = "results.jsonl";
/// File name of the plot.
pub const PLOT: &str = "iou_hist.png";

/// Read `results.jsonl`; a malformed last line (interrupted write) is ignored, a malformed
/// line elsewhere is an error. A missing file gives no records.
pub fn read_results(path: &Path) -> Result<Vec<QueryRecord>> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
    };
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    let mut out = Vec::with_capacity(lines.len());
    for (i, line) in lines.iter().enumerate() {
        match serde_json::from_str::<QueryRecord>(line) {
            Ok(r) => out.push(r),
            Err(_) if i + 1 == lines.len() && !text.ends_with('\n') => break,
            Err(e) => {
                return Err(e).with_context(|| {
                    format!("{}: line {} is not a result record", path.display(), i + 1)
                })
            }
        }
    }
    Ok(out)
}

/// Append-only writer of `results.jsonl`, flushed after each line.
pub struct ResultsLog {
    file: std::fs::File,
    done: HashSet<String>,
    records: Vec<QueryRecord>,
}

impl ResultsLog {
    /// Open (or create) `out_dir/results.jsonl`, loading the records already there.
    /// A torn last line from an interrupted run is cut off first.
    pub fn open(out_dir: &Path) -> Result<Self> {
        std::fs::create_dir_all(out_dir)
            .with_context(|| format!("cannot create {}", out_dir.display()))?;
        let path = out_dir.join(RESULTS);
        let records = read_results(&path)?;
        // Rewrite when the file does not end cleanly, so appends start on a fresh line.
        if let Ok(text) = std::fs::read_to_string(&path) {
            if !text.is_empty() && !text.ends_with('\n') {
                let mut clean = String::new();
                for r in &records {
                    clean.push_str(&serde_json::to_string(r)?);
                    clean.push('\n');
                }
                std::fs::write(&path, clean)
                    .with_context(|| format!("cannot rewrite {}", path.display()))?;
            }
        }
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .with_context(|| format!("cannot open {}", path.display()))?;
        let done = records.iter().map(|r| r.query_id.clone()).collect();
        Ok(Self {
            file,
            done,
            records,
        })
    }

    /// Whether this query already has a record.
    pub fn contains(&self, query_id: &str) -> bool {
        self.done.contains(query_id)
    }

    /// Append one record and flush it to disk.
    pub fn append(&mut self, rec: QueryRecord) -> Result<()> {
        let mut line = serde_json::to_string(&rec)?;
        line.push('\n');
        self.file
            .write_all(line.as_bytes())
            .context("cannot append to results.jsonl")?;
        self.file.flush().context("cannot flush results.jsonl")?;
        self.done.insert(rec.query_id.clone());
        self.records.push(rec);
        Ok(())
    }

    /// All records (loaded and appended).
    pub fn records(&self) -> &[QueryRecord] {
        &self.records
    }
}

/// Paths of the written summary files.
#[derive(Debug, Clone)]
pub struct SummaryFiles {
    pub json: PathBuf,
    pub markdown: PathBuf,
    pub plot: PathBuf,
}

/// Summarise `records` and write `summary.json`, `summary.md` and the plot into `out_dir`.
pub fn write_summary(out_dir: &Path, records: &[QueryRecord]) -> Result<(Summary, SummaryFiles)> {
    let summary = summarize(records);
    let files = SummaryFiles {
        json: out_dir.join("summary.json"),
        markdown: out_dir.join("summary.md"),
        plot: out_dir.join(PLOT),
    };
    std::fs::write(&files.json, serde_json::to_string_pretty(&summary)?)
        .with_context(|| format!("cannot write {}", files.json.display()))?;
    plot::render_iou_histogram(records, &files.plot)?;
    std::fs::write(&files.markdown, render_markdown(&summary, plot::has_font()))
        .with_context(|| format!("cannot write {}", files.markdown.display()))?;
    Ok((summary, files))
}

/// Most classes in the markdown's per-class table (all are in summary.json).
const CLASS_ROWS: usize = 20;

fn pct(x: f64) -> String {
    format!("{:.1} %", 100.0 * x)
}

fn rate_cell(r: &Rate) -> String {
    if r.n == 0 {
        "n/a".to_string()
    } else {
        format!("{} ({}/{})", pct(r.rate), r.k, r.n)
    }
}

fn acc_row(out: &mut String, name: &str, a: &AccBlock) {
    let _ = writeln!(
        out,
        "| {name} | {} | {} | {} |",
        a.n,
        pct(a.acc_025),
        pct(a.acc_05)
    );
}

/// The markdown report (tables for ScanRefer, Nr3D, stages, cost and latency).
pub fn render_markdown(s: &Summary, plot_has_text: bool) -> String {
    let mut o = String::new();
    let _ = writeln!(o, "# Evaluation summary\n");
    let _ = writeln!(
        o,
        "{} queries, {} with a predicted box.\n",
        s.n_queries, s.n_with_prediction
    );
    let _ = writeln!(
        o,
        "## ScanRefer\n\n| subset | n | Acc@0.25 | Acc@0.5 |\n|---|---|---|---|"
    );
    acc_row(&mut o, "overall", &s.scanrefer.overall);
    acc_row(&mut o, "unique", &s.scanrefer.unique);
    acc_row(&mut o, "multiple", &s.scanrefer.multiple);
    if let Some(iv) = &s.scanrefer.overall_interval {
        let _ = writeln!(
            o,
            "\n95 % intervals (bootstrap over the {} target objects, each with all its queries; \
             {} resamples): Acc@0.25 {}–{}, Acc@0.5 {}–{}.",
            iv.objects,
            iv.resamples,
            pct(iv.acc_025.lo),
            pct(iv.acc_025.hi),
            pct(iv.acc_05.lo),
            pct(iv.acc_05.hi)
        );
    }
    if !s.by_class.is_empty() {
        let _ = writeln!(
            o,
            "\n## Per target class (most queries lost first)\n\n\
             | class | n | Acc@0.25 | Acc@0.5 | mean IoU |\n|---|---|---|---|---|"
        );
        for c in s.by_class.iter().take(CLASS_ROWS) {
            let _ = writeln!(
                o,
                "| {} | {} | {} | {} | {:.2} |",
                c.label.replace('|', "\\|"),
                c.n,
                pct(c.acc_025),
                pct(c.acc_05),
                c.mean_iou
            );
        }
        if s.by_class.len() > CLASS_ROWS {
            let _ = writeln!(
                o,
                "\n{} more classes in summary.json (`by_class`).",
                s.by_class.len() - CLASS_ROWS
            );
        }
    }
    let _ = writeln!(
        o,
        "\n## Nr3D (nearest ground-truth centre is the target)\n\n| split | accuracy |\n|---|---|"
    );
    let _ = writeln!(o, "| overall | {} |", rate_cell(&s.nr3d.overall));
    for (name, r) in [
        ("easy", &s.nr3d.easy),
        ("hard", &s.nr3d.hard),
        ("view-dependent", &s.nr3d.view_dependent),
        ("view-independent", &s.nr3d.view_independent),
    ] {
        if let Some(r) = r {
            let _ = writeln!(o, "| {name} | {} |", rate_cell(r));
        }
    }
    let st = &s.stages;
    let _ = writeln!(
        o,
        "\n## Stage success rates (over queries where the stage is known)\n"
    );
    let _ = writeln!(o, "| stage | success |\n|---|---|");
    let _ = writeln!(
        o,
        "| view pre-selection contains the target | {} |",
        rate_cell(&st.preselection_contains_target)
    );
    let _ = writeln!(
        o,
        "| VLM image choice shows the target | {} |",
        rate_cell(&st.image_choice_correct)
    );
    let _ = writeln!(
        o,
        "| detection of the target present | {} |",
        rate_cell(&st.detection_present)
    );
    let _ = writeln!(
        o,
        "| VLM instance choice correct | {} |",
        rate_cell(&st.instance_choice_correct)
    );
    let mean = st
        .mask_iou_mean
        .map(|m| format!(", mean IoU {m:.3}"))
        .unwrap_or_default();
    let _ = writeln!(
        o,
        "| mask IoU >= 0.5 | {}{mean} |",
        rate_cell(&st.mask_iou_ge_05)
    );
    let _ = writeln!(o, "| box IoU >= 0.5 | {} |", rate_cell(&st.box_iou_ge_05));
    if !s.failure_stages.is_empty() {
        let _ = writeln!(
            o,
            "\n## First failing stage\n\n| stage | queries |\n|---|---|"
        );
        for (k, v) in &s.failure_stages {
            let _ = writeln!(o, "| {k} | {v} |");
        }
    }
    let l = &s.latency_ms;
    let _ = writeln!(o, "\n## Cost and latency\n\n| measure | value |\n|---|---|");
    let _ = writeln!(o, "| mean VLM calls per query | {:.2} |", s.mean_vlm_calls);
    let _ = writeln!(o, "| mean tokens per query | {:.0} |", s.mean_tokens);
    let _ = writeln!(
        o,
        "| latency p50 / p90 / p99 | {:.0} / {:.0} / {:.0} ms |",
        l.p50, l.p90, l.p99
    );
    let _ = writeln!(o, "| latency mean | {:.0} ms |", l.mean);
    let _ = writeln!(o, "\n## IoU distribution\n\n![IoU histogram]({})\n", PLOT);
    if !plot_has_text {
        let _ = writeln!(
            o,
            "Left panel (blue): unique subset; right panel (orange): multiple subset. Ten bins of \
             width 0.1 from IoU 0 to 1 (no prediction counts as 0); dashed lines at 0.25 and 0.5."
        );
    }
    o
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::dataset::Subset;

    fn rec(id: &str, iou: f64, subset: Subset) -> QueryRecord {
        crate::eval::metrics::test_record(id, "s", None, iou, subset)
    }

    #[test]
    fn log_appends_resumes_and_drops_torn_line() {
        let dir = tempfile::tempdir().unwrap();
        {
            let mut log = ResultsLog::open(dir.path()).unwrap();
            log.append(rec("a", 0.9, Subset::Unique)).unwrap();
            log.append(rec("b", 0.1, Subset::Multiple)).unwrap();
        }
        let path = dir.path().join(RESULTS);
        let mut text = std::fs::read_to_string(&path).unwrap();
        text.push_str("{\"query_id\":\"c\",\"sce");
        std::fs::write(&path, text).unwrap();
        let mut log = ResultsLog::open(dir.path()).unwrap();
        assert!(log.contains("a") && log.contains("b") && !log.contains("c"));
        log.append(rec("c", 0.5, Subset::Multiple)).unwrap();
        let back = read_results(&path).unwrap();
        assert_eq!(
            back.iter().map(|r| r.query_id.as_str()).collect::<Vec<_>>(),
            ["a", "b", "c"]
        );
        // A broken line in the middle is an error, not silently skipped.
        std::fs::write(&path, "garbage\n{}\n").unwrap();
        assert!(read_results(&path).is_err());
    }

    #[test]
    fn per_class_accuracies_lose_the_most_queries_first() {
        let labelled = |id: &str, label: &str, iou: f64| QueryRecord {
            target_label: Some(label.into()),
            ..rec(id, iou, Subset::Multiple)
        };
        let recs = vec![
            labelled("c1", "chair", 0.9),
            labelled("c2", "chair", 0.3),
            labelled("c3", "chair", 0.0),
            labelled("l1", "lamp", 0.0),
            labelled("l2", "lamp", 0.1),
            labelled("t1", "table", 0.6),
            labelled("p1", "tv|stand", 0.9),
            rec("old", 0.0, Subset::Unique),
        ];
        let s = crate::eval::metrics::summarize(&recs);
        let order: Vec<&str> = s.by_class.iter().map(|c| c.label.as_str()).collect();
        assert_eq!(order, ["lamp", "chair", "table", "tv|stand"]);
        let chair = &s.by_class[1];
        assert_eq!(chair.n, 3);
        assert!((chair.acc_025 - 2.0 / 3.0).abs() < 1e-12);
        assert!((chair.acc_05 - 1.0 / 3.0).abs() < 1e-12);
        assert!((chair.mean_iou - 0.4).abs() < 1e-12);
        let md = render_markdown(&s, true);
        assert!(md.contains("| lamp | 2 | 0.0 % | 0.0 % | 0.05 |"), "{md}");
        assert!(
            md.contains("| chair | 3 | 66.7 % | 33.3 % | 0.40 |"),
            "{md}"
        );
        // A label's `|` is escaped, so the row keeps its five cells.
        assert!(md.contains("| tv\\|stand | 1 | 100.0 % |"), "{md}");
        // Records without labels (older results) give no per-class section.
        let unlabelled = crate::eval::metrics::summarize(&recs[7..]);
        assert!(unlabelled.by_class.is_empty());
        assert!(!render_markdown(&unlabelled, true).contains("Per target class"));
    }

    #[test]
    fn summary_files_and_markdown_tables() {
        let dir = tempfile::tempdir().unwrap();
        let recs = vec![
            rec("a", 0.9, Subset::Unique),
            rec("b", 0.3, Subset::Multiple),
            rec("c", 0.05, Subset::Multiple),
        ];
        let (s, files) = write_summary(dir.path(), &recs).unwrap();
        assert_eq!(s.scanrefer.overall.n, 3);
        let md = std::fs::read_to_string(&files.markdown).unwrap();
        assert!(md.contains("| overall | 3 | 66.7 % | 33.3 % |"), "{md}");
        assert!(md.contains("| multiple | 2 | 50.0 % | 0.0 % |"), "{md}");
        // Three queries, each its own cluster (no target ids): the interval spans 0-100 %
        // at 0.25 ("a" and "b" hit, "c" misses) and ends at 0 % below 0.5.
        let iv = s.scanrefer.overall_interval.expect("records");
        assert_eq!(iv.objects, 3);
        assert!(iv.acc_025.lo < 0.67 && iv.acc_025.hi > 0.67, "{iv:?}");
        assert!(
            md.contains("95 % intervals (bootstrap over the 3 target objects"),
            "{md}"
        );
        let json: Summary =
            serde_json::from_str(&std::fs::read_to_string(&files.json).unwrap()).unwrap();
        assert_eq!(json, s);
        let img = image::open(&files.plot).unwrap();
        assert_eq!((img.width(), img.height()), (960, 420));
        assert_eq!(
            plot::histogram(&recs, Subset::Multiple),
            [1, 0, 0, 1, 0, 0, 0, 0, 0, 0]
        );
    }
}
