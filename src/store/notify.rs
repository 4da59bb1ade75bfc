//! PostgreSQL change notifications: every replica LISTENs on `grounder_jobs` (sent by the
//! triggers of migrations/postgres/0100_leases.sql) and feeds what it hears into its own
//! [`super::events::Hub`] and poll cache, so waiters on a job (long polls, event streams,
//! the worker running it) wake whichever replica wrote the change.

use std::sync::{Arc, Weak};
use std::time::Duration;

use sqlx::postgres::PgListener;

use super::cache::JobCache;
use super::events::Hub;

/// The channel the triggers notify on.
pub const CHANNEL: &str = "grounder_jobs";

/// Start listening (the first connection is made before this returns, so a change made
/// after it is never missed). The task ends once the store's hub is dropped.
pub async fn start(url: &str, hub: &Arc<Hub>, cache: &Arc<JobCache>) -> anyhow::Result<()> {
    let mut listener = PgListener::connect(url)
        .await
        .map_err(|e| anyhow::anyhow!("cannot LISTEN for job changes: {e}"))?;
    listener
        .listen(CHANNEL)
        .await
        .map_err(|e| anyhow::anyhow!("cannot LISTEN for job changes: {e}"))?;
    let (hub, cache) = (Arc::downgrade(hub), Arc::downgrade(cache));
    tokio::spawn(run(listener, hub, cache));
    Ok(())
}

async fn run(mut listener: PgListener, hub: Weak<Hub>, cache: Weak<JobCache>) {
    loop {
        let got = tokio::time::timeout(Duration::from_secs(2), listener.try_recv()).await;
        let (Some(hub), Some(cache)) = (hub.upgrade(), cache.upgrade()) else {
            return;
        };
        match got {
            // Nothing for a while: check the store is still alive, listen again.
            Err(_) => {}
            Ok(Ok(Some(n))) => {
                cache.invalidate();
                hub.changed(n.payload());
                hub.remote.notify_waiters();
            }
            // The connection was lost (and is reopened by the next call): whatever changed
            // meanwhile was not heard, so everyone looks again.
            Ok(Ok(None)) => {
                cache.invalidate();
                hub.changed_all();
                hub.remote.notify_waiters();
            }
            Ok(Err(e)) => {
                tracing::warn!("job change notifications: {e}; listening again");
                cache.invalidate();
                hub.changed_all();
                tokio::time::sleep(Duration::from_millis(500)).await;
            }
        }
    }
}
