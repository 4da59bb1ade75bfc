//! API keys: creation, lookup by secret, revocation. Only a SHA-256 of each secret is kept.

use base64::Engine;
use rand::RngCore;
use sha2::{Digest, Sha256};
use sqlx::Row;

use super::{now_rfc3339, Store, StoreError};

/// A key as stored (never the secret).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct KeyRecord {
    pub id: i64,
    pub name: String,
    pub admin: bool,
    pub max_running_jobs: Option<i64>,
    pub max_scene_bytes: Option<i64>,
    pub created_at: String,
    pub revoked_at: Option<String>,
}

/// What `create_key` returns: the record and the two secrets, shown once.
#[derive(Debug, Clone)]
pub struct NewKey {
    pub record: KeyRecord,
    /// `gk_...`: goes in `Authorization: Bearer`.
    pub secret: String,
    /// `whsec_<base64>`: verifies this key's webhooks.
    pub webhook_secret: String,
}

/// Options of a new key.
#[derive(Debug, Clone, Default)]
pub struct KeySpec {
    pub name: String,
    pub admin: bool,
    pub max_running_jobs: Option<i64>,
    pub max_scene_bytes: Option<i64>,
}

/// Hex SHA-256 of a presented secret: the lookup key.
pub fn secret_hash(secret: &str) -> String {
    hex::encode(Sha256::digest(secret.as_bytes()))
}

fn key_from_row(r: &sqlx::any::AnyRow) -> Result<KeyRecord, StoreError> {
    Ok(KeyRecord {
        id: r.try_get("id")?,
        name: r.try_get("name")?,
        admin: r.try_get::<i64, _>("admin")? != 0,
        max_running_jobs: r.try_get("max_running_jobs")?,
        max_scene_bytes: r.try_get("max_scene_bytes")?,
        created_at: r.try_get("created_at")?,
        revoked_at: r.try_get("revoked_at")?,
    })
}

const KEY_COLS: &str = "id, name, admin, max_running_jobs, max_scene_bytes, created_at, revoked_at";

impl Store {
    /// Create a key; `Ok(None)` when an active key already has this name.
    pub async fn create_key(&self, spec: &KeySpec) -> Result<Option<NewKey>, StoreError> {
        let mut raw = [0u8; 32];
        rand::rngs::OsRng.fill_bytes(&mut raw);
        let secret = format!(
            "gk_{}",
            base64::engine::general_purpose::URL_SAFE_NO_PAD.encode(raw)
        );
        let mut hook = [0u8; 32];
        rand::rngs::OsRng.fill_bytes(&mut hook);
        let hook_b64 = base64::engine::general_purpose::STANDARD.encode(hook);
        let row = sqlx::query(&self.sql(format!(
            "INSERT INTO api_keys (name, secret_sha256, admin, max_running_jobs, max_scene_bytes, webhook_secret, created_at) \
             VALUES (?,?,?,?,?,?,?) ON CONFLICT DO NOTHING RETURNING {KEY_COLS}"
        )))
        .bind(&spec.name)
        .bind(secret_hash(&secret))
        .bind(spec.admin as i64)
        .bind(spec.max_running_jobs)
        .bind(spec.max_scene_bytes)
        .bind(&hook_b64)
        .bind(now_rfc3339())
        .fetch_optional(&self.pool)
        .await?;
        let Some(row) = row else { return Ok(None) };
        Ok(Some(NewKey {
            record: key_from_row(&row)?,
            secret,
            webhook_secret: format!("whsec_{hook_b64}"),
        }))
    }

    /// All keys, revoked ones included, oldest first.
    pub async fn list_keys(&self) -> Result<Vec<KeyRecord>, StoreError> {
        let rows = sqlx::query(&self.sql(format!("SELECT {KEY_COLS} FROM api_keys ORDER BY id")))
            .fetch_all(&self.pool)
            .await?;
        rows.iter().map(key_from_row).collect()
    }

    /// Revoke the active key of this name; false when there is none.
    pub async fn revoke_key(&self, name: &str) -> Result<bool, StoreError> {
        let r = sqlx::query(
            &self.sql("UPDATE api_keys SET revoked_at = ? WHERE name = ? AND revoked_at IS NULL"),
        )
        .bind(now_rfc3339())
        .bind(name)
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected() > 0)
    }

    /// The active key whose secret has this hash.
    pub async fn key_by_hash(&self, hash: &str) -> Result<Option<KeyRecord>, StoreError> {
        let row = sqlx::query(&self.sql(format!(
            "SELECT {KEY_COLS} FROM api_keys WHERE secret_sha256 = ? AND revoked_at IS NULL"
        )))
        .bind(hash)
        .fetch_optional(&self.pool)
        .await?;
        row.as_ref().map(key_from_row).transpose()
    }

    /// Whether any active key exists (then every `/v1/` request needs one).
    pub async fn any_active_key(&self) -> Result<bool, StoreError> {
        let n: i64 =
            sqlx::query_scalar(&self.sql("SELECT COUNT(*) FROM api_keys WHERE revoked_at IS NULL"))
                .fetch_one(&self.pool)
                .await?;
        Ok(n > 0)
    }

    /// The webhook secret (`whsec_...`) of the active key of this name.
    pub async fn webhook_secret_by_name(&self, name: &str) -> Result<Option<String>, StoreError> {
        let s: Option<String> = sqlx::query_scalar(
            &self.sql("SELECT webhook_secret FROM api_keys WHERE name = ? AND revoked_at IS NULL"),
        )
        .bind(name)
        .fetch_optional(&self.pool)
        .await?;
        Ok(s.map(|b| format!("whsec_{b}")))
    }

    /// The raw HMAC key of a key id (revoked keys still sign their jobs' webhooks).
    pub async fn webhook_key_bytes(&self, key_id: i64) -> Result<Option<Vec<u8>>, StoreError> {
        let s: Option<String> =
            sqlx::query_scalar(&self.sql("SELECT webhook_secret FROM api_keys WHERE id = ?"))
                .bind(key_id)
                .fetch_optional(&self.pool)
                .await?;
        match s {
            None => Ok(None),
            Some(b) => base64::engine::general_purpose::STANDARD
                .decode(b)
                .map(Some)
                .map_err(|e| StoreError::Corrupt(format!("webhook secret of key {key_id}: {e}"))),
        }
    }

    /// Jobs of this owner that are queued or running.
    pub async fn active_jobs_of(&self, owner: i64) -> Result<i64, StoreError> {
        Ok(sqlx::query_scalar(
            &self.sql(
                "SELECT COUNT(*) FROM jobs WHERE owner = ? AND status IN ('queued','running')",
            ),
        )
        .bind(owner)
        .fetch_one(&self.pool)
        .await?)
    }

    /// Upload bytes of this owner's stored scenes.
    pub async fn scene_bytes_of(&self, owner: i64) -> Result<i64, StoreError> {
        Ok(sqlx::query_scalar(&self.sql(
            "SELECT CAST(COALESCE(SUM(upload_bytes), 0) AS BIGINT) FROM scenes WHERE owner = ?",
        ))
        .bind(owner)
        .fetch_one(&self.pool)
        .await?)
    }
}
