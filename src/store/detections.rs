//! Cached detections and class-agnostic candidates, per scene, detector and frame.

use sqlx::Row;
use std::collections::BTreeMap;

use super::scenes::HIDDEN_STATES;
use super::{Store, StoreError};
use crate::vision::Detection;

/// Detector keys under which class-agnostic candidates are cached: the unversioned key of
/// old indexes, and each version's (`vision::candidates::CandidateParams::cache_key`).
const ANY_CANDIDATES: &str = "(detector = 'candidates' OR detector LIKE 'candidates/%')";
/// Label of the row that marks a frame indexed with candidates where none were found.
pub(crate) const CANDIDATES_NONE: &str = "(none)";

/// Replace one frame's cached rows of `detector` with `rows`, inside `tx`.
async fn replace_frame_rows(
    tx: &mut sqlx::Transaction<'_, sqlx::Any>,
    backend: super::Backend,
    scene_id: &str,
    detector: &str,
    frame_idx: usize,
    rows: &[Detection],
) -> Result<(), StoreError> {
    sqlx::query(
        &backend
            .sql("DELETE FROM detections WHERE scene_id = ? AND detector = ? AND frame_idx = ?"),
    )
    .bind(scene_id)
    .bind(detector)
    .bind(frame_idx as i64)
    .execute(&mut **tx)
    .await?;
    insert_frame_rows(tx, backend, scene_id, detector, frame_idx, rows).await
}

/// Add `rows` to one frame's cached rows of `detector`, inside `tx`.
async fn insert_frame_rows(
    tx: &mut sqlx::Transaction<'_, sqlx::Any>,
    backend: super::Backend,
    scene_id: &str,
    detector: &str,
    frame_idx: usize,
    rows: &[Detection],
) -> Result<(), StoreError> {
    for d in rows {
        sqlx::query(&backend.sql("INSERT INTO detections (scene_id, detector, frame_idx, label, score, x1, y1, x2, y2) VALUES (?,?,?,?,?,?,?,?,?)"))
            .bind(scene_id)
            .bind(detector)
            .bind(frame_idx as i64)
            .bind(&d.label)
            .bind(d.score as f64)
            .bind(d.bbox[0] as f64)
            .bind(d.bbox[1] as f64)
            .bind(d.bbox[2] as f64)
            .bind(d.bbox[3] as f64)
            .execute(&mut **tx)
            .await?;
    }
    Ok(())
}

impl Store {
    /// Replace a frame's cached detections and bump the scene's indexing progress.
    pub async fn put_detections(
        &self,
        scene_id: &str,
        detector: &str,
        frame_idx: usize,
        dets: &[Detection],
    ) -> Result<(), StoreError> {
        let mut tx = self.pool.begin().await?;
        replace_frame_rows(&mut tx, self.backend, scene_id, detector, frame_idx, dets).await?;
        sqlx::query(&self.sql("UPDATE scenes SET index_done = index_done + 1 WHERE id = ?"))
            .bind(scene_id)
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(())
    }

    /// Store one frame's class-agnostic candidates under `key` (cached like detections;
    /// indexing progress is counted by [`Self::put_detections`]), replacing what the frame
    /// had cached under any other candidates key.
    pub async fn put_candidates(
        &self,
        scene_id: &str,
        key: &str,
        frame_idx: usize,
        cands: &[Detection],
    ) -> Result<(), StoreError> {
        let none = [Detection {
            label: CANDIDATES_NONE.into(),
            score: 0.0,
            bbox: [0.0; 4],
        }];
        let rows = if cands.is_empty() { &none[..] } else { cands };
        let mut tx = self.pool.begin().await?;
        sqlx::query(&self.sql(format!(
            "DELETE FROM detections WHERE scene_id = ? AND frame_idx = ? AND {ANY_CANDIDATES}"
        )))
        .bind(scene_id)
        .bind(frame_idx as i64)
        .execute(&mut *tx)
        .await?;
        insert_frame_rows(&mut tx, self.backend, scene_id, key, frame_idx, rows).await?;
        tx.commit().await?;
        Ok(())
    }

    /// One frame's candidates cached under `key`, largest first; `None` when none were
    /// (indexed without candidates, or with another version or settings).
    pub async fn frame_candidates(
        &self,
        scene_id: &str,
        key: &str,
        frame_idx: usize,
    ) -> Result<Option<Vec<Detection>>, StoreError> {
        let rows = sqlx::query(&self.sql("SELECT label, score, x1, y1, x2, y2 FROM detections WHERE scene_id = ? AND detector = ? AND frame_idx = ? ORDER BY rowid"))
            .bind(scene_id)
            .bind(key)
            .bind(frame_idx as i64)
            .fetch_all(&self.pool)
            .await?;
        let mut out = Vec::with_capacity(rows.len());
        for r in rows {
            let f = |k: &str| r.try_get::<f64, _>(k).map(|v| v as f32);
            let label: String = r.try_get("label")?;
            if label == CANDIDATES_NONE {
                continue;
            }
            out.push(Detection {
                label,
                score: f("score")?,
                bbox: [f("x1")?, f("y1")?, f("x2")?, f("y2")?],
            });
        }
        if out.is_empty() {
            // A frame indexed with candidates and none found holds one marker row.
            let marked: Option<i64> = sqlx::query_scalar(&self.sql("SELECT 1 FROM detections WHERE scene_id = ? AND detector = ? AND frame_idx = ? AND label = ? LIMIT 1"))
                .bind(scene_id)
                .bind(key)
                .bind(frame_idx as i64)
                .bind(CANDIDATES_NONE)
                .fetch_optional(&self.pool)
                .await?;
            return Ok(marked.map(|_| Vec::new()));
        }
        Ok(Some(out))
    }

    /// Every frame's candidates cached under `key`, in one query, each frame's largest
    /// first (as [`Self::frame_candidates`]); frames indexed with candidates and none found
    /// map to an empty list, frames without them under `key` are absent.
    pub async fn scene_candidates(
        &self,
        scene_id: &str,
        key: &str,
    ) -> Result<BTreeMap<usize, Vec<Detection>>, StoreError> {
        let rows = sqlx::query(&self.sql("SELECT frame_idx, label, score, x1, y1, x2, y2 FROM detections WHERE scene_id = ? AND detector = ? ORDER BY frame_idx, rowid"))
            .bind(scene_id)
            .bind(key)
            .fetch_all(&self.pool)
            .await?;
        let mut out: BTreeMap<usize, Vec<Detection>> = BTreeMap::new();
        for r in rows {
            let idx: i64 = r.try_get("frame_idx")?;
            let list = out.entry(idx as usize).or_default();
            let label: String = r.try_get("label")?;
            if label == CANDIDATES_NONE {
                continue;
            }
            let f = |k: &str| r.try_get::<f64, _>(k).map(|v| v as f32);
            list.push(Detection {
                label,
                score: f("score")?,
                bbox: [f("x1")?, f("y1")?, f("x2")?, f("y2")?],
            });
        }
        Ok(out)
    }

    /// Reset indexing progress (before (re-)indexing with `detector`), dropping the
    /// detector's cached boxes and every cached candidate.
    pub async fn reset_index(
        &self,
        scene_id: &str,
        detector: &str,
        total: usize,
    ) -> Result<(), StoreError> {
        let mut tx = self.pool.begin().await?;
        sqlx::query(&self.sql(format!(
            "DELETE FROM detections WHERE scene_id = ? AND (detector = ? OR {ANY_CANDIDATES})"
        )))
        .bind(scene_id)
        .bind(detector)
        .execute(&mut *tx)
        .await?;
        sqlx::query(&self.sql(format!("UPDATE scenes SET status = 'indexing', index_detector = ?, index_done = 0, index_total = ?, error = NULL WHERE id = ? AND status NOT IN {HIDDEN_STATES}")))
            .bind(detector)
            .bind(total as i64)
            .bind(scene_id)
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(())
    }

    /// All cached detections of a scene for one detector, by frame index.
    pub async fn detections(
        &self,
        scene_id: &str,
        detector: &str,
    ) -> Result<BTreeMap<usize, Vec<Detection>>, StoreError> {
        let rows = sqlx::query(&self.sql("SELECT frame_idx, label, score, x1, y1, x2, y2 FROM detections WHERE scene_id = ? AND detector = ? ORDER BY frame_idx, score DESC"))
            .bind(scene_id)
            .bind(detector)
            .fetch_all(&self.pool)
            .await?;
        let mut out: BTreeMap<usize, Vec<Detection>> = BTreeMap::new();
        for r in rows {
            let idx: i64 = r.try_get("frame_idx")?;
            let f = |k: &str| r.try_get::<f64, _>(k).map(|v| v as f32);
            out.entry(idx as usize).or_default().push(Detection {
                label: r.try_get("label")?,
                score: f("score")?,
                bbox: [f("x1")?, f("y1")?, f("x2")?, f("y2")?],
            });
        }
        Ok(out)
    }
}
