//! A scene row's hidden states around its files: `importing` is written before the files
//! are moved in and `deleting` before they are removed, so that the start-up sweep can
//! tell a half-done import or delete from a scene and finish it (see `jobs::sweep`).

use std::collections::HashSet;

use super::{now_rfc3339, Store, StoreError};

/// Error of a queued job whose scene was deleted before it ran.
const SCENE_DELETED: &str =
    r#"{"code":"scene_deleted","detail":"the scene was deleted before the job ran"}"#;

impl Store {
    /// Make an imported scene visible: `importing` turns `status`. False when the row is
    /// no longer `importing` (it was swept). A scene turning `indexing` gets an ownerless
    /// indexing lease: its indexer takes it at once; should this replica die first, any
    /// replica takes the indexing over once it runs out (see `store::replicas`).
    pub async fn publish_scene(&self, id: &str, status: &str) -> Result<bool, StoreError> {
        let r = sqlx::query(&self.sql(format!(
            "UPDATE scenes SET status = ?, index_owner = NULL, \
             index_until = CASE WHEN ? = 'indexing' THEN {} + ? ELSE NULL END \
             WHERE id = ? AND status = 'importing'",
            super::replicas::clock_ms(self.backend)
        )))
        .bind(status)
        .bind(status)
        .bind(self.lease_ms())
        .bind(id)
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected() == 1)
    }

    /// Remove the row of a scene being imported or deleted (its frames and detections go
    /// with it); jobs still queued on it are canceled. A visible scene is never touched.
    pub async fn remove_hidden_scene(&self, id: &str) -> Result<(), StoreError> {
        let mut tx = self.begin_write().await?;
        sqlx::query(
            &self.sql("DELETE FROM scenes WHERE id = ? AND status IN ('importing', 'deleting')"),
        )
        .bind(id)
        .execute(&mut *tx)
        .await?;
        sqlx::query(&self.sql(
            "UPDATE jobs SET status = 'canceled', finished_at = ?, error = ? \
             WHERE scene_id = ? AND status = 'queued' \
             AND NOT EXISTS (SELECT 1 FROM scenes WHERE id = ?3)",
        ))
        .bind(now_rfc3339())
        .bind(SCENE_DELETED)
        .bind(id)
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        self.job_cache.invalidate();
        self.events.changed_all();
        Ok(())
    }

    /// Scenes left `importing` or `deleting` (by a crash): (id, status).
    pub async fn hidden_scenes(&self) -> Result<Vec<(String, String)>, StoreError> {
        Ok(sqlx::query_as(&self.sql(
            "SELECT id, status FROM scenes WHERE status IN ('importing', 'deleting') ORDER BY id",
        ))
        .fetch_all(&self.pool)
        .await?)
    }

    /// Every scene row's id, whatever its state.
    pub async fn scene_ids(&self) -> Result<HashSet<String>, StoreError> {
        let ids: Vec<String> = sqlx::query_scalar(&self.sql("SELECT id FROM scenes"))
            .fetch_all(&self.pool)
            .await?;
        Ok(ids.into_iter().collect())
    }

    /// The file stems of a scene's frames (under `color/` and `instance/`).
    pub async fn frame_files(&self, scene_id: &str) -> Result<HashSet<String>, StoreError> {
        let stems: Vec<String> = sqlx::query_scalar(
            &self.sql("SELECT COALESCE(file, CAST(idx AS TEXT)) FROM frames WHERE scene_id = ?"),
        )
        .bind(scene_id)
        .fetch_all(&self.pool)
        .await?;
        Ok(stems.into_iter().collect())
    }

    /// The ids of every job ever run on a scene (their artifacts go with it).
    pub async fn job_ids_of_scene(&self, scene_id: &str) -> Result<Vec<String>, StoreError> {
        Ok(
            sqlx::query_scalar(&self.sql("SELECT id FROM jobs WHERE scene_id = ? ORDER BY seq"))
                .bind(scene_id)
                .fetch_all(&self.pool)
                .await?,
        )
    }

    /// Delete the jobs that finished before `cutoff` (RFC 3339) with their trace, events
    /// and webhook rows; returns their ids (their artifacts are the caller's to remove).
    pub async fn delete_finished_before(&self, cutoff: &str) -> Result<Vec<String>, StoreError> {
        let older = if self.pg() {
            "finished_at::timestamptz < (?)::timestamptz"
        } else {
            "julianday(finished_at) < julianday(?)"
        };
        let ids: Vec<String> = sqlx::query_scalar(&self.sql(format!(
            "DELETE FROM jobs WHERE status IN ('succeeded', 'failed', 'canceled') \
             AND finished_at IS NOT NULL AND {older} RETURNING id"
        )))
        .bind(cutoff)
        .fetch_all(&self.pool)
        .await?;
        if !ids.is_empty() {
            self.job_cache.invalidate();
            self.events.changed_all();
        }
        Ok(ids)
    }

    /// Does a job row exist?
    pub async fn job_exists(&self, id: &str) -> Result<bool, StoreError> {
        let n: Option<i64> = sqlx::query_scalar(&self.sql("SELECT 1 FROM jobs WHERE id = ?"))
            .bind(id)
            .fetch_optional(&self.pool)
            .await?;
        Ok(n.is_some())
    }

    /// Cancel queued jobs whose scene row is gone (a job created while its scene was being
    /// deleted); returns how many.
    pub async fn cancel_jobs_without_scene(&self) -> Result<u64, StoreError> {
        let r = sqlx::query(&self.sql("UPDATE jobs SET status = 'canceled', finished_at = ?, error = ? \
             WHERE status = 'queued' AND NOT EXISTS (SELECT 1 FROM scenes s WHERE s.id = jobs.scene_id)"))
        .bind(now_rfc3339())
        .bind(SCENE_DELETED)
        .execute(&self.pool)
        .await?;
        if r.rows_affected() > 0 {
            self.job_cache.invalidate();
            self.events.changed_all();
        }
        Ok(r.rows_affected())
    }

    /// Count the start of an indexing attempt of a scene; returns the attempts so far.
    pub async fn begin_index_attempt(&self, id: &str) -> Result<i64, StoreError> {
        let n: Option<i64> = sqlx::query_scalar(&self.sql("UPDATE scenes SET index_attempts = index_attempts + 1 WHERE id = ? RETURNING index_attempts"))
        .bind(id)
        .fetch_optional(&self.pool)
        .await?;
        Ok(n.unwrap_or(0))
    }

    /// Indexing ended (either way): the next indexing starts counting afresh.
    pub async fn end_index_attempts(&self, id: &str) -> Result<(), StoreError> {
        sqlx::query(&self.sql("UPDATE scenes SET index_attempts = 0 WHERE id = ?"))
            .bind(id)
            .execute(&self.pool)
            .await?;
        Ok(())
    }

    /// Scenes left `indexing` by a previous process, with their attempts so far.
    pub async fn interrupted_indexing(&self) -> Result<Vec<(String, i64)>, StoreError> {
        Ok(sqlx::query_as(
            &self
                .sql("SELECT id, index_attempts FROM scenes WHERE status = 'indexing' ORDER BY id"),
        )
        .fetch_all(&self.pool)
        .await?)
    }
}
