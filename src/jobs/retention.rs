//! Retention of finished jobs: jobs that ended (succeeded, failed, canceled) longer ago
//! than `job_retention_days` are deleted with their trace, events and artifacts by a
//! periodic sweep. Rows go first, then the artifact folders: a crash in between leaves
//! folders without a job, which the start-up sweep removes.

use std::time::Duration;

use super::JobSystem;

/// How often the sweep runs for a retention of `keep`: a tenth of it, between 200 ms and
/// an hour.
pub fn period(keep: Duration) -> Duration {
    (keep / 10).clamp(Duration::from_millis(200), Duration::from_secs(3600))
}

/// Sweep every [`period`] until shutdown.
pub async fn run(jobs: JobSystem, keep: Duration) {
    loop {
        tokio::select! {
            _ = jobs.shutdown_signal() => break,
            _ = tokio::time::sleep(period(keep)) => {}
        }
        match sweep(&jobs, keep).await {
            Ok(0) => {}
            Ok(n) => tracing::info!(jobs = n, "retention: finished jobs past their time deleted"),
            Err(e) => tracing::warn!("retention sweep failed (tried again later): {e:#}"),
        }
    }
}

/// Delete the jobs finished more than `keep` ago and their artifacts; returns how many.
pub async fn sweep(jobs: &JobSystem, keep: Duration) -> anyhow::Result<usize> {
    let cutoff = time::OffsetDateTime::now_utc()
        - time::Duration::try_from(keep).unwrap_or(time::Duration::MAX);
    let cutoff = cutoff
        .format(&time::format_description::well_known::Rfc3339)
        .unwrap_or_default();
    let ids = jobs.store().delete_finished_before(&cutoff).await?;
    for id in &ids {
        super::sweep::remove_dir(&jobs.artifact_dir(id)).await?;
        // With a bucket, the job's artifacts there go too (a no-op without one).
        jobs.storage().remove_remote(None, Some(id)).await?;
    }
    Ok(ids.len())
}
