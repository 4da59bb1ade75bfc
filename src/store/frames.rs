//! Frames added to and removed from a stored scene (scenes that grow).

use sqlx::Row;

use super::{Store, StoreError};
use crate::geometry::Intrinsics;
use crate::scene::import::ImportedScene;
use crate::scene::model::pose_to_blob;

/// What removing a frame did.
#[derive(Debug, PartialEq, Eq)]
pub enum FrameRemoval {
    NoFrame,
    /// A job on the scene runs, or the scene is being indexed.
    Busy(&'static str),
    /// The scene's only frame: delete the scene instead.
    LastFrame,
    /// Removed; its files (stem under color/ and instance/) can go.
    Removed {
        file: String,
    },
}

impl Store {
    /// The scene's colour camera, depth camera and depth size.
    pub async fn load_scene_camera(
        &self,
        scene_id: &str,
    ) -> Result<Option<(Intrinsics, Option<Intrinsics>, (u32, u32))>, StoreError> {
        let Some(r) = sqlx::query(
            &self
                .sql("SELECT color_k, depth_k, depth_width, depth_height FROM scenes WHERE id = ?"),
        )
        .bind(scene_id)
        .fetch_optional(&self.pool)
        .await?
        else {
            return Ok(None);
        };
        let corrupt = |w: &str| StoreError::Corrupt(format!("scene {scene_id}: {w}"));
        let color: Intrinsics = serde_json::from_str(&r.try_get::<String, _>("color_k")?)
            .map_err(|_| corrupt("colour intrinsics"))?;
        let depth = match r.try_get::<Option<String>, _>("depth_k")? {
            Some(t) => Some(serde_json::from_str(&t).map_err(|_| corrupt("depth intrinsics"))?),
            None => None,
        };
        let dw: i64 = r.try_get("depth_width")?;
        let dh: i64 = r.try_get("depth_height")?;
        Ok(Some((color, depth, (dw as u32, dh as u32))))
    }

    /// The scene's frame names in order.
    pub async fn frame_names(&self, scene_id: &str) -> Result<Vec<String>, StoreError> {
        Ok(
            sqlx::query_scalar(
                &self.sql("SELECT name FROM frames WHERE scene_id = ? ORDER BY idx"),
            )
            .bind(scene_id)
            .fetch_all(&self.pool)
            .await?,
        )
    }

    /// Append validated frames (their colour files already stored under `file` stems =
    /// frame names) after the scene's last frame; bump the revision. With a detector and
    /// new usable frames, the scene goes `indexing` with the new frames added to the
    /// total. Returns the first new frame's idx.
    pub async fn append_frames(
        &self,
        scene_id: &str,
        frames: &ImportedScene,
        detector: Option<&str>,
    ) -> Result<usize, StoreError> {
        let mut tx = self.pool.begin().await?;
        let count: i64 =
            sqlx::query_scalar(&self.sql("SELECT COUNT(*) FROM frames WHERE scene_id = ?"))
                .bind(scene_id)
                .fetch_one(&mut *tx)
                .await?;
        let usable = frames.frames.iter().filter(|f| f.usable).count() as i64;
        for (i, f) in frames.frames.iter().enumerate() {
            sqlx::query(&self.sql("INSERT INTO frames (scene_id, idx, name, pose, usable, depth, file) VALUES (?,?,?,?,?,?,?)"))
                .bind(scene_id)
                .bind(count + i as i64)
                .bind(&f.name)
                .bind(pose_to_blob(&f.pose))
                .bind(f.usable as i64)
                .bind(&f.depth_blob)
                .bind(&f.name)
                .execute(&mut *tx)
                .await?;
        }
        let n = frames.frames.len() as i64;
        sqlx::query(&self.sql("UPDATE scenes SET frame_count = frame_count + ?, unusable_count = unusable_count + ?, revision = revision + 1 WHERE id = ?"))
        .bind(n)
        .bind(n - usable)
        .bind(scene_id)
        .execute(&mut *tx)
        .await?;
        if let (Some(d), true) = (detector, usable > 0) {
            sqlx::query(&self.sql("UPDATE scenes SET status = 'indexing', index_detector = ?, index_total = index_total + ?, error = NULL WHERE id = ?"))
                .bind(d)
                .bind(usable)
                .bind(scene_id)
                .execute(&mut *tx)
                .await?;
        }
        tx.commit().await?;
        Ok(count as usize)
    }

    /// Remove frame `name` unless a job on the scene runs or it is being indexed. Later
    /// frames (and their cached detections) move up one image id; the revision is bumped.
    pub async fn remove_frame_if_idle(
        &self,
        scene_id: &str,
        name: &str,
    ) -> Result<FrameRemoval, StoreError> {
        let mut tx = self.pool.begin().await?;
        let running: i64 = sqlx::query_scalar(
            &self.sql("SELECT COUNT(*) FROM jobs WHERE scene_id = ? AND status = 'running'"),
        )
        .bind(scene_id)
        .fetch_one(&mut *tx)
        .await?;
        if running > 0 {
            return Ok(FrameRemoval::Busy("a job on the scene is running"));
        }
        let status: Option<String> =
            sqlx::query_scalar(&self.sql("SELECT status FROM scenes WHERE id = ?"))
                .bind(scene_id)
                .fetch_optional(&mut *tx)
                .await?;
        if status.as_deref() == Some("indexing") {
            return Ok(FrameRemoval::Busy("the scene is being indexed"));
        }
        let Some(row) = sqlx::query(&self.sql("SELECT idx, usable, COALESCE(file, CAST(idx AS TEXT)) AS file FROM frames WHERE scene_id = ? AND name = ?"))
        .bind(scene_id)
        .bind(name)
        .fetch_optional(&mut *tx)
        .await?
        else {
            return Ok(FrameRemoval::NoFrame);
        };
        let idx: i64 = row.try_get("idx")?;
        let usable = row.try_get::<i64, _>("usable")? != 0;
        let file: String = row.try_get("file")?;
        let count: i64 =
            sqlx::query_scalar(&self.sql("SELECT COUNT(*) FROM frames WHERE scene_id = ?"))
                .bind(scene_id)
                .fetch_one(&mut *tx)
                .await?;
        if count <= 1 {
            return Ok(FrameRemoval::LastFrame);
        }
        // Files keep their stems while image ids move.
        sqlx::query(
            &self.sql(
                "UPDATE frames SET file = CAST(idx AS TEXT) WHERE scene_id = ? AND file IS NULL",
            ),
        )
        .bind(scene_id)
        .execute(&mut *tx)
        .await?;
        sqlx::query(&self.sql("DELETE FROM frames WHERE scene_id = ? AND idx = ?"))
            .bind(scene_id)
            .bind(idx)
            .execute(&mut *tx)
            .await?;
        sqlx::query(&self.sql("DELETE FROM detections WHERE scene_id = ? AND frame_idx = ?"))
            .bind(scene_id)
            .bind(idx)
            .execute(&mut *tx)
            .await?;
        // Two steps, so that no two rows share a key on the way.
        sqlx::query(&self.sql("UPDATE frames SET idx = -idx WHERE scene_id = ? AND idx > ?"))
            .bind(scene_id)
            .bind(idx)
            .execute(&mut *tx)
            .await?;
        sqlx::query(&self.sql("UPDATE frames SET idx = -idx - 1 WHERE scene_id = ? AND idx < 0"))
            .bind(scene_id)
            .execute(&mut *tx)
            .await?;
        sqlx::query(&self.sql(
            "UPDATE detections SET frame_idx = frame_idx - 1 WHERE scene_id = ? AND frame_idx > ?",
        ))
        .bind(scene_id)
        .bind(idx)
        .execute(&mut *tx)
        .await?;
        let (u, indexed) = if usable { (0, 1) } else { (1, 0) };
        sqlx::query(&self.sql(format!("UPDATE scenes SET frame_count = frame_count - 1, unusable_count = unusable_count - ?, \
             index_total = {max}(index_total - ?, 0), index_done = {max}(index_done - ?, 0), revision = revision + 1 WHERE id = ?", max = self.greatest())))
        .bind(u)
        .bind(if status.is_some() { indexed } else { 0 })
        .bind(if status.is_some() { indexed } else { 0 })
        .bind(scene_id)
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(FrameRemoval::Removed { file })
    }
}
