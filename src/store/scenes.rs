//! Scene, frame and detection rows.

use futures::StreamExt;
use nalgebra::Matrix4;
use serde::Serialize;
use sqlx::Row;
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use super::{now_rfc3339, Store, StoreError};
use crate::geometry::DepthMap;
use crate::geometry::{FrameCamera, Intrinsics};
use crate::scene::depth_file::{self, DepthKey};
use crate::scene::import::ImportedScene;
use crate::scene::model::{pose_from_blob, pose_to_blob};
use crate::scene::{FrameData, SceneData};

/// Scene states no reader sees: the row exists only so that a crash mid-import or
/// mid-delete can be finished at start-up (see `store::lifecycle`).
pub(crate) const HIDDEN_STATES: &str = "('importing', 'deleting')";

/// A scene as listed over the API.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct SceneRecord {
    pub id: String,
    /// Folder name of the uploaded scene.
    pub name: String,
    /// `indexing`, `ready` or `failed`.
    pub status: String,
    /// `scannet` (FORMATS §1a), `posed` (§1b), or the capture format it was converted from (`sens`, `tum`, `nerfstudio` or `arkitscenes`).
    pub layout: String,
    /// Number of frames.
    pub frames: i64,
    /// Names of frames whose pose is not finite; they are never used.
    pub unusable_frames: Vec<String>,
    /// [width, height] of the colour images.
    pub color_size: [i64; 2],
    /// [width, height] of the depth images.
    pub depth_size: [i64; 2],
    pub has_instance_masks: bool,
    /// Detector indexing progress.
    pub index: IndexProgress,
    pub error: Option<String>,
    pub created_at: String,
    /// Bumped on every change of the scene's frames (appended or removed).
    pub revision: i64,
    /// The API key that uploaded the scene (not shown).
    #[serde(skip)]
    pub owner: Option<i64>,
}

#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct IndexProgress {
    pub detector: Option<String>,
    pub done: i64,
    pub total: i64,
}

fn json_of<T: Serialize>(v: &T) -> String {
    serde_json::to_string(v).unwrap_or_else(|_| "null".into())
}

fn matrix_json(m: &Matrix4<f64>) -> String {
    let v: Vec<f64> = (0..16).map(|i| m[(i / 4, i % 4)]).collect();
    json_of(&v)
}

impl Store {
    /// Insert a validated scene and its frames in one transaction.
    pub async fn insert_scene(
        &self,
        id: &str,
        scene: &ImportedScene,
        status: &str,
        detector: Option<&str>,
        owner: Option<i64>,
        upload_bytes: u64,
    ) -> Result<(), StoreError> {
        let mut tx = self.pool.begin().await?;
        let usable = scene.frames.iter().filter(|f| f.usable).count() as i64;
        sqlx::query(&self.sql("INSERT INTO scenes (id, name, layout, status, color_width, color_height, depth_width, depth_height, \
             color_k, depth_k, axis_align, has_instances, frame_count, unusable_count, index_detector, index_done, index_total, created_at, owner, upload_bytes, holder) \
             VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,0,?,?,?,?,?)"))
        .bind(id)
        .bind(&scene.name)
        .bind(
            scene
                .format
                .map_or(scene.layout.as_str(), |f| f.as_str()),
        )
        .bind(status)
        .bind(scene.color.width as i64)
        .bind(scene.color.height as i64)
        .bind(scene.depth_size.0 as i64)
        .bind(scene.depth_size.1 as i64)
        .bind(json_of(&scene.color))
        .bind(scene.depth.as_ref().map(json_of))
        .bind(scene.axis_align.as_ref().map(matrix_json))
        .bind(scene.frames.iter().any(|f| f.instance_path.is_some()) as i64)
        .bind(scene.frames.len() as i64)
        .bind(scene.frames.len() as i64 - usable)
        .bind(detector)
        .bind(if detector.is_some() { usable } else { 0 })
        .bind(now_rfc3339())
        .bind(owner)
        .bind(upload_bytes as i64)
        .bind(self.replica.as_str())
        .execute(&mut *tx)
        .await?;
        for f in &scene.frames {
            sqlx::query(&self.sql("INSERT INTO frames (scene_id, idx, name, pose, usable, depth) VALUES (?,?,?,?,?,?)"))
                .bind(id)
                .bind(f.idx as i64)
                .bind(&f.name)
                .bind(pose_to_blob(&f.pose))
                .bind(f.usable as i64)
                .bind(&f.depth_blob)
                .execute(&mut *tx)
                .await?;
        }
        tx.commit().await?;
        Ok(())
    }

    fn scene_from_row(
        row: &sqlx::any::AnyRow,
        unusable: Vec<String>,
    ) -> Result<SceneRecord, StoreError> {
        Ok(SceneRecord {
            id: row.try_get("id")?,
            name: row.try_get("name")?,
            status: row.try_get("status")?,
            layout: row.try_get("layout")?,
            frames: row.try_get("frame_count")?,
            unusable_frames: unusable,
            color_size: [row.try_get("color_width")?, row.try_get("color_height")?],
            depth_size: [row.try_get("depth_width")?, row.try_get("depth_height")?],
            has_instance_masks: row.try_get::<i64, _>("has_instances")? != 0,
            index: IndexProgress {
                detector: row.try_get("index_detector")?,
                done: row.try_get("index_done")?,
                total: row.try_get("index_total")?,
            },
            error: row.try_get("error")?,
            created_at: row.try_get("created_at")?,
            revision: row.try_get("revision")?,
            owner: row.try_get("owner")?,
        })
    }

    async fn unusable_names(&self, id: &str) -> Result<Vec<String>, StoreError> {
        let rows = sqlx::query(
            &self.sql("SELECT name FROM frames WHERE scene_id = ? AND usable = 0 ORDER BY idx"),
        )
        .bind(id)
        .fetch_all(&self.pool)
        .await?;
        rows.iter()
            .map(|r| r.try_get::<String, _>("name").map_err(StoreError::from))
            .collect()
    }

    pub async fn get_scene(&self, id: &str) -> Result<Option<SceneRecord>, StoreError> {
        let Some(row) = sqlx::query(&self.sql(format!(
            "SELECT * FROM scenes WHERE id = ? AND status NOT IN {HIDDEN_STATES}"
        )))
        .bind(id)
        .fetch_optional(&self.pool)
        .await?
        else {
            return Ok(None);
        };
        let unusable = self.unusable_names(id).await?;
        Ok(Some(Self::scene_from_row(&row, unusable)?))
    }

    /// Scenes, oldest first; only `owner`'s when given.
    pub async fn list_scenes(&self, owner: Option<i64>) -> Result<Vec<SceneRecord>, StoreError> {
        let rows = sqlx::query(&self.sql(format!(
            "SELECT * FROM scenes WHERE (?1 IS NULL OR owner = ?1) AND status NOT IN {HIDDEN_STATES} \
             ORDER BY created_at, id"
        )))
        .bind(owner)
        .fetch_all(&self.pool)
        .await?;
        let mut out = Vec::with_capacity(rows.len());
        for row in &rows {
            let id: String = row.try_get("id")?;
            out.push(Self::scene_from_row(row, self.unusable_names(&id).await?)?);
        }
        Ok(out)
    }

    /// Start deleting a scene unless a job on it is running: its queued jobs are canceled
    /// and the row turns `deleting` (hidden from readers). Returns false when refused. The
    /// caller removes the files, then the row ([`Store::remove_deleting_scene`]); a crash in
    /// between is finished by the start-up sweep.
    pub async fn delete_scene_if_idle(&self, id: &str) -> Result<bool, StoreError> {
        let r = self.delete_scene_if_idle_tx(id).await;
        self.job_cache.invalidate();
        self.events.changed_all();
        r
    }

    async fn delete_scene_if_idle_tx(&self, id: &str) -> Result<bool, StoreError> {
        // IMMEDIATE: the check and the writes hold the write lock from the start. A deferred
        // transaction that reads first cannot upgrade once another connection has written
        // (SQLite answers "database is locked" at once, without waiting).
        let mut tx = self.begin_write().await?;
        let busy: i64 = sqlx::query_scalar(
            &self.sql("SELECT COUNT(*) FROM jobs WHERE scene_id = ? AND status = 'running'"),
        )
        .bind(id)
        .fetch_one(&mut *tx)
        .await?;
        if busy > 0 {
            return Ok(false);
        }
        sqlx::query(&self.sql("UPDATE jobs SET status = 'canceled', finished_at = ?, error = ? WHERE scene_id = ? AND status = 'queued'"))
            .bind(now_rfc3339())
            .bind(r#"{"code":"scene_deleted","detail":"the scene was deleted before the job ran"}"#)
            .bind(id)
            .execute(&mut *tx)
            .await?;
        sqlx::query(&self.sql("UPDATE scenes SET status = 'deleting', holder = ? WHERE id = ?"))
            .bind(self.replica.as_str())
            .bind(id)
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(true)
    }

    pub async fn set_scene_status(
        &self,
        id: &str,
        status: &str,
        error: Option<&str>,
    ) -> Result<(), StoreError> {
        // A scene being imported or deleted keeps that state (an indexer racing a delete
        // must not bring the row back).
        sqlx::query(&self.sql(format!(
            "UPDATE scenes SET status = ?, error = ? WHERE id = ? AND status NOT IN {HIDDEN_STATES}"
        )))
        .bind(status)
        .bind(error)
        .bind(id)
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    /// Scenes left `indexing` by a previous process (indexing is restarted for them).
    pub async fn scenes_with_status(&self, status: &str) -> Result<Vec<String>, StoreError> {
        Ok(
            sqlx::query_scalar(&self.sql("SELECT id FROM scenes WHERE status = ?"))
                .bind(status)
                .fetch_all(&self.pool)
                .await?,
        )
    }

    /// Load a scene for the pipeline: cameras and decoded depth for every frame. None when
    /// the scene is gone or being deleted.
    pub async fn load_scene(
        &self,
        id: &str,
        scene_dir: &Path,
    ) -> Result<Option<SceneData>, StoreError> {
        let Some(s) =
            sqlx::query(&self.sql("SELECT * FROM scenes WHERE id = ? AND status <> 'deleting'"))
                .bind(id)
                .fetch_optional(&self.pool)
                .await?
        else {
            return Ok(None);
        };
        let corrupt = |what: &str| StoreError::Corrupt(format!("scene {id}: {what}"));
        let color: Intrinsics = serde_json::from_str(&s.try_get::<String, _>("color_k")?)
            .map_err(|_| corrupt("colour intrinsics"))?;
        let depth_k: Option<Intrinsics> = match s.try_get::<Option<String>, _>("depth_k")? {
            Some(t) => Some(serde_json::from_str(&t).map_err(|_| corrupt("depth intrinsics"))?),
            None => None,
        };
        let align = match s.try_get::<Option<String>, _>("axis_align")? {
            Some(t) => {
                let v: Vec<f64> =
                    serde_json::from_str(&t).map_err(|_| corrupt("axis alignment"))?;
                if v.len() != 16 {
                    return Err(corrupt("axis alignment"));
                }
                Some(Matrix4::from_row_slice(&v))
            }
            None => None,
        };
        let dw: i64 = s.try_get("depth_width")?;
        let dh: i64 = s.try_get("depth_height")?;
        let rows = sqlx::query(&self.sql(
            "SELECT idx, name, pose, usable, CAST(LENGTH(depth) AS BIGINT) AS depth_len, COALESCE(file, CAST(idx AS TEXT)) AS file FROM frames WHERE scene_id = ? ORDER BY idx",
        ))
        .bind(id)
        .fetch_all(&self.pool)
        .await?;
        let mut raw = Vec::with_capacity(rows.len());
        let mut blob_sizes = Vec::with_capacity(rows.len());
        for r in rows {
            blob_sizes.push(r.try_get::<Option<i64>, _>("depth_len")?.unwrap_or(0) as u64);
            raw.push((
                r.try_get::<i64, _>("idx")?,
                r.try_get::<String, _>("name")?,
                r.try_get::<Vec<u8>, _>("pose")?,
                r.try_get::<i64, _>("usable")? != 0,
                r.try_get::<String, _>("file")?,
            ));
        }
        let key = DepthKey {
            frames: raw.len(),
            width: dw as u32,
            height: dh as u32,
            blob_sizes,
        };
        let depths = self.scene_depth(id, scene_dir, &key).await?;
        let scene_dir_owned = scene_dir.to_path_buf();
        let align_m = align.unwrap_or_else(Matrix4::identity);
        let frames = tokio::task::spawn_blocking(move || {
            let scene_dir = scene_dir_owned;
            raw.into_iter()
                .zip(depths)
                .map(|((idx, name, pose, usable, file), depth)| {
                    let pose = pose_from_blob(&pose).ok_or_else(|| format!("frame {name} pose"))?;
                    let inst = scene_dir.join("instance").join(format!("{file}.png"));
                    Ok(FrameData {
                        idx: idx as usize,
                        name,
                        usable,
                        camera: FrameCamera {
                            color,
                            depth: depth_k,
                            depth_size: (dw as u32, dh as u32),
                            pose,
                            align: align_m,
                        },
                        depth: Arc::new(depth),
                        color_path: scene_dir.join("color").join(format!("{file}.jpg")),
                        instance_path: inst.is_file().then_some(inst),
                    })
                })
                .collect::<Result<Vec<_>, String>>()
        })
        .await
        .map_err(|e| StoreError::Corrupt(format!("scene {id}: loader failed: {e}")))?
        .map_err(|w| corrupt(&w))?;
        let labels_path = scene_dir.join("instance").join("labels.json");
        let instance_labels = std::fs::read_to_string(&labels_path).ok().and_then(|t| {
            let m: BTreeMap<String, String> = serde_json::from_str(&t).ok()?;
            Some(
                m.into_iter()
                    .filter_map(|(k, v)| Some((k.parse().ok()?, v)))
                    .collect(),
            )
        });
        Ok(Some(SceneData {
            id: id.to_string(),
            color,
            depth: depth_k,
            axis_align: align,
            frames,
            instance_labels,
            room: Default::default(),
        }))
    }
}

impl Store {
    /// Every frame's depth of a scene, in frame order: windows onto the scene's mapped depth
    /// file (`scene::depth_file`), which is written first from the stored blobs when there
    /// is none yet (one blob in memory at a time). Where the file cannot be written (a
    /// read-only folder), the blobs are decoded into memory as before, with a warning.
    async fn scene_depth(
        &self,
        id: &str,
        scene_dir: &Path,
        key: &DepthKey,
    ) -> Result<Vec<DepthMap>, StoreError> {
        let corrupt = |what: String| StoreError::Corrupt(format!("scene {id}: {what}"));
        let open = |dir: std::path::PathBuf, key: DepthKey| async move {
            tokio::task::spawn_blocking(move || depth_file::open(&dir, &key)).await
        };
        match open(scene_dir.to_path_buf(), key.clone()).await {
            Ok(Ok(Some(maps))) => return Ok(maps),
            Ok(Ok(None)) => {}
            Ok(Err(e)) => tracing::warn!(scene = %id, "cannot map the depth file: {e}"),
            Err(e) => return Err(corrupt(format!("depth loader failed: {e}"))),
        }
        // Blobs go one by one to a writer thread, which decodes and appends them.
        let (tx, mut rx) = tokio::sync::mpsc::channel::<Vec<u8>>(2);
        let (dir, k) = (scene_dir.to_path_buf(), key.clone());
        let writer = tokio::task::spawn_blocking(move || {
            depth_file::write(&dir, &k, std::iter::from_fn(|| rx.blocking_recv()))
        });
        let depth_sql = self.sql("SELECT depth FROM frames WHERE scene_id = ? ORDER BY idx");
        let mut rows = sqlx::query(&depth_sql).bind(id).fetch(&self.pool);
        let mut read_error = None;
        while let Some(r) = rows.next().await {
            match r.and_then(|r| r.try_get::<Vec<u8>, _>("depth")) {
                Ok(blob) => {
                    if tx.send(blob).await.is_err() {
                        break; // the writer stopped; its error says why
                    }
                }
                Err(e) => {
                    read_error = Some(e);
                    break;
                }
            }
        }
        drop(rows);
        drop(tx);
        let written = writer
            .await
            .map_err(|e| corrupt(format!("depth writer failed: {e}")))?;
        if let Some(e) = read_error {
            return Err(e.into());
        }
        match written {
            Ok(()) => match open(scene_dir.to_path_buf(), key.clone()).await {
                Ok(Ok(Some(maps))) => return Ok(maps),
                Ok(Ok(None)) => {
                    tracing::warn!(scene = %id, "the depth file just written is not there")
                }
                Ok(Err(e)) => tracing::warn!(scene = %id, "cannot map the depth file: {e}"),
                Err(e) => return Err(corrupt(format!("depth loader failed: {e}"))),
            },
            Err(depth_file::WriteError::Corrupt(e)) => return Err(corrupt(format!("depth: {e}"))),
            Err(depth_file::WriteError::Io(e)) => {
                tracing::warn!(scene = %id, "cannot write the depth file, decoding depth into memory: {e:#}")
            }
        }
        let rows =
            sqlx::query(&self.sql("SELECT depth FROM frames WHERE scene_id = ? ORDER BY idx"))
                .bind(id)
                .fetch_all(&self.pool)
                .await?;
        let (w, h) = (key.width, key.height);
        let decoded = tokio::task::spawn_blocking(move || {
            rows.iter()
                .enumerate()
                .map(|(i, r)| {
                    let blob: Vec<u8> = r.try_get("depth")?;
                    depth_file::decode(&blob, w, h)
                        .ok_or_else(|| StoreError::Corrupt(format!("frame {i} depth")))
                })
                .collect::<Result<Vec<_>, StoreError>>()
        })
        .await
        .map_err(|e| corrupt(format!("depth loader failed: {e}")))?;
        decoded.map_err(|e| corrupt(e.to_string()))
    }
}
