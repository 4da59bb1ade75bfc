//! `storage = "s3://bucket/prefix"` against a real S3-compatible server: the Python `moto`
//! server, started here (installed by `.ci/run`; without it these tests fail, saying so).
//! Two replicas are modelled by two processes' worth of state: replica B is a second
//! server on a copy of replica A's SQLite file with an EMPTY data dir, sharing A's bucket
//! (the shared `database_url` is another branch's work).

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::Duration;

use grounder::storage::Storage;

use crate::helpers::{client, tar_of, test_config, tiny_scene_files, TestApp};

/// A moto server on a free port, killed when dropped, or by its watchdog within a second
/// of this test process ending without dropping it (killed, or aborted by a panic).
pub(crate) struct Moto {
    child: Child,
    watchdog: Option<Child>,
    port: u16,
}

impl Drop for Moto {
    fn drop(&mut self) {
        // The watchdog first: once the server is reaped its pid may be another process's.
        if let Some(w) = self.watchdog.as_mut() {
            let _ = w.kill();
            let _ = w.wait();
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A shell that waits for this test process to end, then kills process `pid`.
fn watchdog(pid: u32) -> Option<Child> {
    let script = crate::helpers::after_this_process(&format!("kill {pid} 2>/dev/null"));
    Command::new("sh")
        .args(["-c", &script])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .ok()
}

impl Moto {
    pub(crate) async fn start() -> Moto {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .expect("free port")
            .port();
        let child = Command::new("python3")
            .args(["-m", "moto.server", "-H", "127.0.0.1", "-p", &port.to_string()])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start python3 -m moto.server ({e}); run .ci/run, which installs moto[server]"));
        let watchdog = watchdog(child.id());
        let mut moto = Moto {
            child,
            watchdog,
            port,
        };
        let client = client();
        for _ in 0..200 {
            if let Ok(Some(status)) = moto.child.try_wait() {
                panic!("the moto server exited at once ({status}): is moto[server] installed? .ci/run installs it");
            }
            if client.get(moto.endpoint()).send().await.is_ok() {
                return moto;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        panic!("the moto server did not answer on port {port} within 10 s");
    }

    fn endpoint(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    /// The AWS_* settings that point the object store client at this server.
    pub(crate) fn env(&self) -> Vec<(String, String)> {
        [
            ("AWS_ENDPOINT_URL", self.endpoint()),
            ("AWS_REGION", "us-east-1".into()),
            ("AWS_ACCESS_KEY_ID", "test".into()),
            ("AWS_SECRET_ACCESS_KEY", "test".into()),
            ("AWS_ALLOW_HTTP", "true".into()),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect()
    }

    pub(crate) async fn create_bucket(&self, name: &str) {
        let r = client()
            .put(format!("{}/{name}", self.endpoint()))
            .send()
            .await
            .expect("create bucket");
        assert!(r.status().is_success(), "create bucket: {}", r.status());
    }
}

/// A storage on `bucket/prefix` with its cache in `dir`.
async fn open(moto: &Moto, url: &str, dir: &Path, cache_bytes: u64) -> Arc<Storage> {
    Storage::open(url, dir, cache_bytes, &moto.env())
        .await
        .expect("open storage")
}

/// A scene's objects but the points export (which a replica adds in the background).
async fn scene_files(s: &Storage, id: &str) -> std::collections::HashMap<String, u64> {
    let mut all = objects(s, &format!("scenes/{id}")).await;
    all.retain(|n, _| !n.starts_with("points_"));
    all
}

/// Objects under `rel` in the bucket: name -> size.
async fn objects(s: &Storage, rel: &str) -> std::collections::HashMap<String, u64> {
    s.remote().expect("a bucket").list(rel).await.expect("list")
}

pub(crate) fn copy_db(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for f in ["grounder.db", "grounder.db-wal", "grounder.db-shm"] {
        if from.join(f).exists() {
            std::fs::copy(from.join(f), to.join(f)).expect("copy db");
        }
    }
}

#[tokio::test]
async fn a_scene_uploaded_on_replica_a_is_fetched_from_the_bucket_by_replica_b() {
    let moto = Moto::start().await;
    moto.create_bucket("scenes-ab").await;
    let url = "s3://scenes-ab/fleet";
    let dir_a = tempfile::tempdir().expect("tempdir");
    let dir_b = tempfile::tempdir().expect("tempdir");
    let cfg = |d: &Path| grounder::config::Config {
        storage: url.into(),
        ..test_config(d.to_path_buf())
    };

    // Replica A stores the scene: its files are in the bucket once the upload answers.
    let a = TestApp::spawn_with_env(cfg(dir_a.path()), &moto.env()).await;
    let r = a
        .upload(
            tar_of(&tiny_scene_files(3), Some("room")),
            "application/x-tar",
        )
        .await;
    assert_eq!(r.status().as_u16(), 201);
    let scene: serde_json::Value = r.json().await.expect("json");
    let id = scene["id"].as_str().expect("id").to_string();
    assert_eq!(scene["status"], "ready");
    let probe_dir = tempfile::tempdir().expect("tempdir");
    let probe = open(&moto, url, probe_dir.path(), 1 << 30).await;
    let in_bucket = scene_files(&probe, &id).await;
    let local_a =
        grounder::storage::local_files(&dir_a.path().join("scenes").join(&id)).expect("A's files");
    let colour = local_a.iter().filter(|(n, _)| n.starts_with("color/"));
    assert_eq!(colour.count(), 3, "{local_a:?}");
    assert!(in_bucket.contains_key("color/0.jpg"), "{in_bucket:?}");
    // Local caches (the points export, the mapped depth file) are each replica's own.
    let cache = |n: &str| n.starts_with("points_") || grounder::scene::depth_file::is_depth_file(n);
    for (name, size) in local_a.iter().filter(|(n, _)| !cache(n)) {
        assert_eq!(in_bucket.get(name), Some(size), "{name} in the bucket");
    }
    let a_frame = std::fs::read(dir_a.path().join("scenes").join(&id).join("color/1.jpg"))
        .expect("A's frame");
    a.stop().await;

    // Replica B: A's database, an empty data dir otherwise, A's own files gone.
    copy_db(dir_a.path(), dir_b.path());
    std::fs::remove_dir_all(dir_a.path().join("scenes")).expect("rm A's scenes");
    assert!(!dir_b.path().join("scenes").exists());
    let b = TestApp::spawn_with_env(cfg(dir_b.path()), &moto.env()).await;
    let r = b.create_job(&id, "the chair").await;
    assert_eq!(r.status().as_u16(), 202);
    let job: serde_json::Value = r.json().await.expect("json");
    let job_id = job["id"].as_str().expect("job id").to_string();
    let done = b.wait_job(&job_id, Duration::from_secs(30)).await;
    assert_eq!(done["status"], "succeeded", "{done}");

    // B fetched the scene from the bucket into its cache: same files, same bytes.
    let b_scene = dir_b.path().join("scenes").join(&id);
    let local_b: std::collections::HashMap<_, _> = grounder::storage::local_files(&b_scene)
        .expect("B's cached files")
        .into_iter()
        .filter(|(n, _)| !cache(n))
        .collect();
    assert_eq!(local_b, in_bucket, "B's cache holds what the bucket holds");
    assert_eq!(
        std::fs::read(b_scene.join("color/1.jpg")).expect("B's frame"),
        a_frame
    );
    let r = b.get(&format!("/v1/scenes/{id}/frames/1.jpg")).await;
    assert_eq!(r.status().as_u16(), 200);
    assert_eq!(r.bytes().await.expect("bytes").to_vec(), a_frame);

    // The job's artifact is in the bucket, and served from there once the local copy goes.
    let arts = objects(&probe, &format!("artifacts/{job_id}")).await;
    assert!(arts.contains_key("test.txt"), "{arts:?}");
    std::fs::remove_dir_all(dir_b.path().join("artifacts").join(&job_id)).expect("rm artifacts");
    let r = b
        .get(&format!("/v1/jobs/{job_id}/artifacts/test.txt"))
        .await;
    assert_eq!(r.status().as_u16(), 200);
    assert_eq!(r.text().await.expect("text"), "the chair");
    let r = b
        .get(&format!("/v1/jobs/{job_id}/artifacts/nothing.jpg"))
        .await;
    assert_eq!(r.status().as_u16(), 404);

    // Deleting the scene removes its objects and its jobs' artifacts from the bucket.
    let r = b.delete(&format!("/v1/scenes/{id}")).await;
    assert_eq!(r.status().as_u16(), 204);
    assert!(objects(&probe, &format!("scenes/{id}")).await.is_empty());
    assert!(objects(&probe, &format!("artifacts/{job_id}"))
        .await
        .is_empty());
    assert!(!b_scene.exists());
    b.stop().await;
}

/// A scene's files in a local folder, stored through `s`; returns its size in bytes.
async fn put_scene(s: &Arc<Storage>, id: &str, bytes: usize) -> u64 {
    let dir = s.scene_dir(id).join("color");
    std::fs::create_dir_all(&dir).expect("mkdir");
    std::fs::write(dir.join("0.jpg"), vec![id.len() as u8; bytes]).expect("write");
    drop(s.store_scene(id).await.expect("store"));
    bytes as u64
}

#[tokio::test]
async fn the_cache_evicts_idle_scenes_least_recently_used_first_and_respects_its_bound() {
    let moto = Moto::start().await;
    moto.create_bucket("cache").await;
    let url = "s3://cache/p";
    let writer_dir = tempfile::tempdir().expect("tempdir");
    let writer = open(&moto, url, writer_dir.path(), 1 << 30).await;
    for id in ["s1", "s2", "s3"] {
        put_scene(&writer, id, 1000).await;
    }
    // Room for two scenes of 1000 bytes, not three.
    let bound = 2500;
    let reader_dir = tempfile::tempdir().expect("tempdir");
    let reader = open(&moto, url, reader_dir.path(), bound).await;
    let held = |id: &str| reader.scene_dir(id).join("color/0.jpg").is_file();
    assert!(!held("s1"));
    drop(reader.acquire_scene("s1", 0).await.expect("s1"));
    drop(reader.acquire_scene("s2", 0).await.expect("s2"));
    assert_eq!(reader.downloads(), 2);
    assert!(held("s1") && held("s2"));
    // s1 used again: s2 is now the least recently used.
    drop(reader.acquire_scene("s1", 0).await.expect("s1 again"));
    assert_eq!(
        reader.downloads(),
        2,
        "a held scene is not downloaded again"
    );
    let pin3 = reader.acquire_scene("s3", 0).await.expect("s3");
    assert!(reader.cached_bytes() <= bound, "{}", reader.cached_bytes());
    assert!(held("s1") && held("s3") && !held("s2"), "s2 evicted");
    assert_eq!(reader.downloads(), 3);
    // Scenes in use stay even beyond the bound; idle ones go.
    let pin1 = reader.acquire_scene("s1", 0).await.expect("s1 pinned");
    let pin2 = reader.acquire_scene("s2", 0).await.expect("s2 back");
    assert!(held("s1") && held("s2") && held("s3"));
    assert_eq!(reader.cached_bytes(), 3000, "all three are in use");
    drop((pin1, pin3));
    drop(pin2);
    drop(reader.acquire_scene("s2", 0).await.expect("s2"));
    assert!(reader.cached_bytes() <= bound, "{}", reader.cached_bytes());
    assert!(held("s2"));
    // The scene grew on another replica (revision 1): the held, older copy gets the
    // files it lacks, without a full download.
    std::fs::write(writer.scene_dir("s2").join("color/1.jpg"), b"new frame").expect("write");
    writer.sync_scene("s2").await.expect("sync");
    assert!(!reader.scene_dir("s2").join("color/1.jpg").exists());
    let downloads = reader.downloads();
    drop(
        reader
            .acquire_scene("s2", 1)
            .await
            .expect("s2 at revision 1"),
    );
    assert_eq!(
        std::fs::read(reader.scene_dir("s2").join("color/1.jpg")).expect("new frame"),
        b"new frame"
    );
    assert_eq!(reader.downloads(), downloads);
    // A scene the bucket does not hold is an error, not an empty folder.
    let e = reader
        .acquire_scene("nope", 0)
        .await
        .err()
        .map(|e| e.to_string());
    assert!(e.unwrap_or_default().contains("holds no files"));
    assert!(!reader.scene_dir("nope").exists());
    // A restarted reader knows what its cache holds (no download for a held scene).
    drop(reader);
    let again = open(&moto, url, reader_dir.path(), bound).await;
    assert!(again.cached_bytes() <= bound && again.cached_bytes() > 0);
    let before = again.downloads();
    for id in ["s1", "s2", "s3"] {
        if again.scene_dir(id).join(".complete").is_file() {
            drop(again.acquire_scene(id, 0).await.expect("held"));
        }
    }
    assert_eq!(again.downloads(), before);
}
