//! The S3-compatible bucket behind `s3://bucket/prefix`, through the `object_store`
//! crate: whole folders up and down, one object in and out, prefixes removed.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use futures::{StreamExt, TryStreamExt};
use object_store::aws::{AmazonS3Builder, AmazonS3ConfigKey};
use object_store::path::Path as Key;
use object_store::{BackoffConfig, ClientOptions, ObjectStore, PutPayload, RetryConfig};

use super::StorageError;

/// A bucket and the key prefix everything of this service lives under.
pub struct Remote {
    store: Arc<dyn ObjectStore>,
    /// `""` or `a/b` (no leading or trailing slash).
    prefix: String,
    /// `s3://bucket/prefix`, for messages.
    pub url: String,
}

/// How long a request to the bucket may take before it fails (settings
/// `storage_connect_timeout_secs`, `storage_request_timeout_secs`, `storage_retries`,
/// `storage_retry_timeout_secs`). A bucket that cannot be reached fails a request after
/// at most `retries` more tries, none started later than `retry_timeout` after the first:
/// within about `retry_timeout + request_timeout`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RemoteLimits {
    pub connect_timeout: Duration,
    pub request_timeout: Duration,
    pub retries: usize,
    pub retry_timeout: Duration,
}

impl Default for RemoteLimits {
    fn default() -> Self {
        Self {
            connect_timeout: Duration::from_secs(5),
            request_timeout: Duration::from_secs(60),
            retries: 3,
            retry_timeout: Duration::from_secs(15),
        }
    }
}

impl RemoteLimits {
    /// The longest a failing request takes: every try but the last starts within
    /// `retry_timeout`, and each lasts at most `request_timeout`.
    pub fn worst_case(&self) -> Duration {
        self.retry_timeout + self.request_timeout
    }
}

fn err(what: impl std::fmt::Display, e: impl std::fmt::Display) -> StorageError {
    StorageError::Remote(format!("{what}: {e}"))
}

impl Remote {
    /// Connect to `bucket` with settings from the `AWS_*` variables of `env`
    /// (AWS_ENDPOINT_URL, AWS_REGION, AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY,
    /// AWS_ALLOW_HTTP, ...), requests bounded by `limits`. Nothing is contacted yet.
    pub fn connect(
        bucket: &str,
        prefix: &str,
        env: &[(String, String)],
        limits: &RemoteLimits,
    ) -> Result<Self, StorageError> {
        // Client options first: the AWS_* variables below set some of them too
        // (AWS_ALLOW_HTTP), and `with_client_options` would replace those.
        let mut b = AmazonS3Builder::new()
            .with_bucket_name(bucket)
            .with_client_options(
                ClientOptions::new()
                    .with_connect_timeout(limits.connect_timeout)
                    .with_timeout(limits.request_timeout),
            )
            .with_retry(RetryConfig {
                backoff: BackoffConfig::default(),
                max_retries: limits.retries,
                retry_timeout: limits.retry_timeout,
            });
        for (name, value) in env {
            if !name.starts_with("AWS_") {
                continue;
            }
            if let Ok(key) = name.to_ascii_lowercase().parse::<AmazonS3ConfigKey>() {
                b = b.with_config(key, value);
            }
        }
        let store = b
            .build()
            .map_err(|e| StorageError::Config(format!("s3://{bucket}: {e}")))?;
        let prefix = prefix.trim_matches('/').to_string();
        let url = if prefix.is_empty() {
            format!("s3://{bucket}")
        } else {
            format!("s3://{bucket}/{prefix}")
        };
        Ok(Self {
            store: Arc::new(store),
            prefix,
            url,
        })
    }

    /// The key of `rel` (slash-separated) under the prefix.
    pub fn key(&self, rel: &str) -> Key {
        let joined = if self.prefix.is_empty() {
            rel.to_string()
        } else {
            format!("{}/{rel}", self.prefix)
        };
        Key::from(joined.as_str())
    }

    /// Every object under folder `rel`: its path relative to the folder, and its size.
    pub async fn list(&self, rel: &str) -> Result<HashMap<String, u64>, StorageError> {
        let dir = self.key(rel);
        let mut out = HashMap::new();
        let mut stream = self.store.list(Some(&dir));
        while let Some(meta) = stream.next().await {
            let meta = meta.map_err(|e| err(format!("cannot list {}", self.show(rel)), e))?;
            let name: Option<Vec<String>> = meta
                .location
                .prefix_match(&dir)
                .map(|parts| parts.map(|p| p.as_ref().to_string()).collect());
            if let Some(name) = name {
                out.insert(name.join("/"), meta.size);
            }
        }
        Ok(out)
    }

    /// Names of the folders directly under folder `rel`.
    pub async fn children(&self, rel: &str) -> Result<Vec<String>, StorageError> {
        let dir = self.key(rel);
        let listed = self
            .store
            .list_with_delimiter(Some(&dir))
            .await
            .map_err(|e| err(format!("cannot list {}", self.show(rel)), e))?;
        Ok(listed
            .common_prefixes
            .iter()
            .filter_map(|p| p.filename().map(str::to_string))
            .collect())
    }

    /// Store `bytes` at `rel`.
    pub async fn put(&self, rel: &str, bytes: Vec<u8>) -> Result<(), StorageError> {
        self.store
            .put(&self.key(rel), PutPayload::from(bytes))
            .await
            .map_err(|e| err(format!("cannot write {}", self.show(rel)), e))?;
        Ok(())
    }

    /// The object at `rel`, or None when there is none.
    pub async fn get(&self, rel: &str) -> Result<Option<Vec<u8>>, StorageError> {
        let got = match self.store.get(&self.key(rel)).await {
            Ok(g) => g,
            Err(object_store::Error::NotFound { .. }) => return Ok(None),
            Err(e) => return Err(err(format!("cannot read {}", self.show(rel)), e)),
        };
        let bytes = got
            .bytes()
            .await
            .map_err(|e| err(format!("cannot read {}", self.show(rel)), e))?;
        Ok(Some(bytes.to_vec()))
    }

    /// Upload the files of local folder `dir` under folder `rel` that the bucket lacks (or
    /// holds with another size); `*.tmp` files (half-written) and the mapped depth file (a
    /// cache every replica builds from the database) are skipped. Returns how many were
    /// uploaded.
    pub async fn push_dir(&self, dir: &Path, rel: &str) -> Result<usize, StorageError> {
        let have = self.list(rel).await?;
        let files = local_files(dir)?;
        let mut n = 0;
        for (name, size) in files {
            if have.get(&name) == Some(&size) || crate::scene::depth_file::is_depth_file(&name) {
                continue;
            }
            let bytes = tokio::fs::read(dir.join(&name))
                .await
                .map_err(|e| StorageError::Local(format!("cannot read {name}: {e}")))?;
            self.put(&format!("{rel}/{name}"), bytes).await?;
            n += 1;
        }
        Ok(n)
    }

    /// Download the objects under folder `rel` into local folder `dir` (created) that it
    /// lacks (or holds with another size). Returns the bytes of the objects; an error when
    /// the folder holds nothing.
    pub async fn pull_dir(&self, rel: &str, dir: &Path) -> Result<u64, StorageError> {
        let objects = self.list(rel).await?;
        if objects.is_empty() {
            return Err(StorageError::Missing(format!(
                "{} holds no files",
                self.show(rel)
            )));
        }
        let mut total = 0;
        for (name, size) in &objects {
            let have = safe_join(dir, name).and_then(|p| std::fs::metadata(p).ok());
            if have.is_some_and(|m| m.len() == *size) {
                total += size;
                continue;
            }
            let Some(bytes) = self.get(&format!("{rel}/{name}")).await? else {
                return Err(StorageError::Missing(format!(
                    "{} vanished while it was read",
                    self.show(&format!("{rel}/{name}"))
                )));
            };
            let dest = safe_join(dir, name).ok_or_else(|| {
                StorageError::Remote(format!("object name {name:?} is not a relative path"))
            })?;
            if let Some(parent) = dest.parent() {
                tokio::fs::create_dir_all(parent)
                    .await
                    .map_err(|e| StorageError::Local(format!("cannot create a folder: {e}")))?;
            }
            total += bytes.len() as u64;
            tokio::fs::write(&dest, bytes)
                .await
                .map_err(|e| StorageError::Local(format!("cannot write {name}: {e}")))?;
        }
        Ok(total)
    }

    /// Remove every object under folder `rel` (none is fine).
    pub async fn delete_dir(&self, rel: &str) -> Result<(), StorageError> {
        let dir = self.key(rel);
        let locations = self.store.list(Some(&dir)).map_ok(|m| m.location).boxed();
        let mut deleted = self.store.delete_stream(locations);
        while let Some(r) = deleted.next().await {
            match r {
                Ok(_) | Err(object_store::Error::NotFound { .. }) => {}
                Err(e) => return Err(err(format!("cannot delete {}", self.show(rel)), e)),
            }
        }
        Ok(())
    }

    /// Remove the objects at `rels` (missing ones are fine).
    pub async fn delete(&self, rels: &[String]) -> Result<(), StorageError> {
        for rel in rels {
            match self.store.delete(&self.key(rel)).await {
                Ok(()) | Err(object_store::Error::NotFound { .. }) => {}
                Err(e) => return Err(err(format!("cannot delete {}", self.show(rel)), e)),
            }
        }
        Ok(())
    }

    fn show(&self, rel: &str) -> String {
        format!("{}/{rel}", self.url)
    }
}

/// `dir/name` when `name` is a plain relative path (no `..`, no root).
fn safe_join(dir: &Path, name: &str) -> Option<PathBuf> {
    let ok = !name.is_empty()
        && name
            .split('/')
            .all(|p| !p.is_empty() && p != "." && p != ".." && !p.contains('\\'));
    ok.then(|| dir.join(name))
}

/// Every file under `dir` (recursively): slash-separated relative name and size. Names
/// starting with `.` (the local marker, half-written files) and `*.tmp` are left out.
pub fn local_files(dir: &Path) -> Result<Vec<(String, u64)>, StorageError> {
    let mut out = Vec::new();
    let mut stack = vec![(dir.to_path_buf(), String::new())];
    while let Some((d, rel)) = stack.pop() {
        let rd = std::fs::read_dir(&d)
            .map_err(|e| StorageError::Local(format!("cannot read folder {rel:?}: {e}")))?;
        for entry in rd {
            let entry = entry.map_err(|e| StorageError::Local(format!("cannot read: {e}")))?;
            let name = entry.file_name().to_string_lossy().into_owned();
            if name.starts_with('.') || name.ends_with(".tmp") {
                continue;
            }
            let rel_name = if rel.is_empty() {
                name.clone()
            } else {
                format!("{rel}/{name}")
            };
            let meta = entry
                .metadata()
                .map_err(|e| StorageError::Local(format!("cannot read {rel_name}: {e}")))?;
            if meta.is_dir() {
                stack.push((entry.path(), rel_name));
            } else {
                out.push((rel_name, meta.len()));
            }
        }
    }
    Ok(out)
}
