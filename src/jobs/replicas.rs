//! What replicas on one PostgreSQL database do for each other, every third of the lease
//! and whatever their role: write this replica's heartbeat; release the idempotency keys
//! dead replicas left in flight; finish the imports and deletes they left half done; and
//! take over indexing whose lease ran out (see `store::replicas`).

use std::sync::Arc;
use std::time::Duration;
use tokio_util::sync::CancellationToken;

use super::indexing::{resume, Indexer};
use super::sweep::{finish_hidden, Mode};
use crate::storage::Storage;
use crate::store::{Claim, Store};

/// One round of the work above; what it did is logged.
pub async fn tick(
    store: &Store,
    storage: &Storage,
    indexer: &Arc<Indexer>,
    max_index_attempts: i64,
) -> anyhow::Result<()> {
    store.heartbeat().await?;
    let released = store.idempotency_release_dead().await?;
    if released > 0 {
        tracing::info!(
            released,
            "released idempotency keys left in flight by stopped replicas"
        );
    }
    let mode = Mode::Shared {
        grace: Duration::ZERO,
    };
    let (imports, deletes) = finish_hidden(store, storage, mode).await?;
    if imports + deletes > 0 {
        tracing::info!(
            imports,
            deletes,
            "undid imports and finished deletes left by stopped replicas"
        );
    }
    resume(indexer, max_index_attempts, Claim::TakeOver).await?;
    store.forget_dead_replicas().await?;
    Ok(())
}

/// Until `stop`: [`tick`] every third of the lease; then this replica leaves (what it
/// still holds becomes the others' to release).
pub async fn run(
    store: Store,
    storage: Arc<Storage>,
    indexer: Arc<Indexer>,
    max_index_attempts: i64,
    stop: CancellationToken,
) {
    let every = Duration::from_millis((store.lease_ms() / 3).max(100) as u64);
    loop {
        tokio::select! {
            _ = stop.cancelled() => break,
            _ = tokio::time::sleep(every) => {}
        }
        if let Err(e) = tick(&store, &storage, &indexer, max_index_attempts).await {
            tracing::warn!("replica housekeeping failed (tried again shortly): {e:#}");
        }
    }
    if let Err(e) = store.leave().await {
        tracing::warn!("cannot remove this replica's heartbeat: {e}");
    }
}
