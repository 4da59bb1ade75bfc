//! Job leases on PostgreSQL (see `store::queue`): the worker running a job renews its lease
//! and stops the job once it is no longer its own; every replica sweeps for leases that ran
//! out (their replica died) and puts those jobs back in the queue.

use std::sync::Arc;
use std::time::Duration;
use tokio::sync::Notify;
use tokio_util::sync::CancellationToken;

use crate::store::Store;

/// How often a lease is renewed and expired leases are looked for: a third of the lease.
fn period(store: &Store) -> Duration {
    Duration::from_millis((store.lease_ms() / 3).max(100) as u64)
}

/// Keep this replica's lease on a running job: renew it every third of the lease and on
/// every change of the job (a cancel through another replica arrives as a notification).
/// When the job is no longer ours (canceled, or requeued after the lease ran out), `token`
/// is cancelled so the pipeline stops. None on SQLite (no leases).
pub fn keep(
    store: Store,
    job_id: String,
    token: CancellationToken,
) -> Option<tokio::task::JoinHandle<()>> {
    if !store.pg() {
        return None;
    }
    let every = period(&store);
    let mut changes = store.events.subscribe(&job_id);
    Some(tokio::spawn(async move {
        loop {
            tokio::select! {
                _ = token.cancelled() => return,
                _ = tokio::time::sleep(every) => {}
                r = changes.changed() => if r.is_err() { return },
            }
            match store.renew_lease(&job_id).await {
                Ok(true) => {}
                Ok(false) => {
                    tracing::info!(job = %job_id, "the job is no longer this replica's (canceled or requeued); stopping it");
                    token.cancel();
                    return;
                }
                Err(e) => tracing::warn!(job = %job_id, "cannot renew the job's lease: {e}"),
            }
        }
    }))
}

/// Until `stop`: every third of the lease, requeue (or fail, past `max_attempts`) the
/// running jobs whose lease ran out, and wake this replica's workers when any came back.
pub async fn sweep(store: Store, max_attempts: i64, wake: Arc<Notify>, stop: CancellationToken) {
    let every = period(&store);
    loop {
        tokio::select! {
            _ = stop.cancelled() => return,
            _ = tokio::time::sleep(every) => {}
        }
        match store.expire_leases(max_attempts).await {
            Ok((0, 0)) => {}
            Ok((requeued, failed)) => {
                tracing::info!(
                    requeued,
                    failed,
                    "jobs whose lease ran out (their replica stopped renewing)"
                );
                wake.notify_waiters();
            }
            Err(e) => tracing::warn!("cannot sweep expired job leases: {e}"),
        }
    }
}
