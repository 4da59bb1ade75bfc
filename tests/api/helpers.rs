//! Test helpers: a real server on port 0 with a temp data dir, and tiny scene archives.

use grounder::config::Config;
use grounder::startup::Application;
use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

/// The throwaway PostgreSQL of the tests that run on both backends.
#[path = "pg.rs"]
pub mod pg;

pub struct TestApp {
    pub addr: SocketAddr,
    pub client: reqwest::Client,
    pub data_dir: PathBuf,
    _dir: Option<tempfile::TempDir>,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    handle: Option<tokio::task::JoinHandle<()>>,
}

/// A shell script that waits for this test process to end (polling once a second), then
/// runs `then`: a watchdog for what a test starts outside the process (a database cluster,
/// a mock server), so that a test binary killed or aborted leaves nothing running.
pub fn after_this_process(then: &str) -> String {
    format!(
        "while [ -d /proc/{me} ]; do sleep 1; done; {then}",
        me = std::process::id()
    )
}

/// A test server's configuration: SQLite in `data_dir`, or in the PostgreSQL run (see
/// `pg.rs`) a database of its own on the test cluster.
pub fn test_config(data_dir: PathBuf) -> Config {
    Config {
        addr: "127.0.0.1:0".into(),
        database_url: pg::database_for(&data_dir),
        data_dir,
        pipeline: "test:delay_ms=100".into(),
        detector: "none".into(),
        ..Config::default()
    }
}

impl TestApp {
    pub async fn spawn() -> TestApp {
        let dir = tempfile::tempdir().expect("tempdir");
        let cfg = test_config(dir.path().to_path_buf());
        let mut app = Self::spawn_with(cfg).await;
        app._dir = Some(dir);
        app
    }

    pub async fn spawn_with(cfg: Config) -> TestApp {
        Self::spawn_with_env(cfg, &grounder::config::load::process_env()).await
    }

    /// A server whose outside settings (`AWS_*`) come from `env`, not the process's.
    pub async fn spawn_with_env(cfg: Config, env: &[(String, String)]) -> TestApp {
        let data_dir = cfg.data_dir.clone();
        let app = Application::build_with_env(cfg, env)
            .await
            .expect("build app");
        let addr = app.local_addr().expect("addr");
        let (tx, rx) = tokio::sync::oneshot::channel::<()>();
        let handle = tokio::spawn(async move {
            app.run_until(async move {
                let _ = rx.await;
            })
            .await
            .expect("server");
        });
        TestApp {
            addr,
            client: client(),
            data_dir,
            _dir: None,
            stop: Some(tx),
            handle: Some(handle),
        }
    }

    pub fn url(&self, path: &str) -> String {
        format!("http://{}{}", self.addr, path)
    }

    /// GET `path` (as any answer: the caller checks the status).
    pub async fn get(&self, path: &str) -> reqwest::Response {
        self.client.get(self.url(path)).send().await.expect("get")
    }

    /// POST `path` with no body.
    pub async fn post_empty(&self, path: &str) -> reqwest::Response {
        self.client.post(self.url(path)).send().await.expect("post")
    }

    /// DELETE `path`.
    pub async fn delete(&self, path: &str) -> reqwest::Response {
        self.client
            .delete(self.url(path))
            .send()
            .await
            .expect("delete")
    }

    pub async fn upload(&self, body: Vec<u8>, content_type: &str) -> reqwest::Response {
        self.client
            .post(self.url("/v1/scenes"))
            .header("Content-Type", content_type)
            .body(body)
            .send()
            .await
            .expect("upload")
    }

    /// Upload the tiny scene of `frames` frames (a tar, no top folder), assert 201 and
    /// return the scene id.
    pub async fn upload_tiny_scene(&self, frames: usize) -> String {
        upload_tiny_scene_to(&self.client, &self.url(""), frames).await
    }

    /// Submit one job for `query` on `scene_id`, assert 202 and return the job id.
    pub async fn submit_job(&self, scene_id: &str, query: &str) -> String {
        submit_job(&self.client, &self.url(""), scene_id, query).await
    }

    pub async fn get_json(&self, path: &str) -> (u16, serde_json::Value) {
        let r = self.client.get(self.url(path)).send().await.expect("get");
        let s = r.status().as_u16();
        (s, r.json().await.unwrap_or(serde_json::Value::Null))
    }

    pub async fn create_job(&self, scene_id: &str, query: &str) -> reqwest::Response {
        self.client
            .post(self.url("/v1/jobs"))
            .json(&serde_json::json!({"scene_id": scene_id, "query": query}))
            .send()
            .await
            .expect("job")
    }

    /// Poll a job until its status is terminal (or the timeout passes).
    pub async fn wait_job(&self, id: &str, timeout: Duration) -> serde_json::Value {
        let ended = |j: &serde_json::Value| {
            matches!(
                j["status"].as_str(),
                Some("succeeded" | "failed" | "canceled")
            )
            .then_some(true)
        };
        let (Ok(j) | Err(j)) = self
            .poll(&format!("/v1/jobs/{id}"), 25, timeout, ended)
            .await;
        j
    }

    /// Poll a job until its status is `status`: `Ok` with the job's document then, `Err`
    /// with the last document seen when the timeout passed first.
    pub async fn wait_status(
        &self,
        id: &str,
        status: &str,
        timeout: Duration,
    ) -> Result<serde_json::Value, serde_json::Value> {
        let reached = |j: &serde_json::Value| (j["status"] == status).then_some(true);
        self.poll(&format!("/v1/jobs/{id}"), 10, timeout, reached)
            .await
    }

    /// Poll a scene until its status is `until`: `Ok` with the scene's document then, `Err`
    /// with the last document seen when it settled on another status (anything but
    /// `indexing`) or the timeout passed first.
    pub async fn wait_scene(
        &self,
        id: &str,
        until: &str,
        timeout: Duration,
    ) -> Result<serde_json::Value, serde_json::Value> {
        let settled = |s: &serde_json::Value| {
            if s["status"] == until {
                Some(true)
            } else {
                (s["status"] != "indexing").then_some(false)
            }
        };
        self.poll(&format!("/v1/scenes/{id}"), 20, timeout, settled)
            .await
    }

    /// GET `path` every `every_ms` until `settle` decides (`Some(true)`: `Ok` with the
    /// document, `Some(false)`: `Err` with it) or the timeout passes (`Err` with the last
    /// document seen).
    async fn poll(
        &self,
        path: &str,
        every_ms: u64,
        timeout: Duration,
        settle: impl Fn(&serde_json::Value) -> Option<bool>,
    ) -> Result<serde_json::Value, serde_json::Value> {
        let start = std::time::Instant::now();
        loop {
            let (_, doc) = self.get_json(path).await;
            match settle(&doc) {
                Some(true) => return Ok(doc),
                Some(false) => return Err(doc),
                None if start.elapsed() > timeout => return Err(doc),
                None => tokio::time::sleep(Duration::from_millis(every_ms)).await,
            }
        }
    }

    /// Stop the server gracefully and wait for it.
    pub async fn stop(mut self) -> Option<tempfile::TempDir> {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
        if let Some(h) = self.handle.take() {
            let _ = h.await;
        }
        self._dir.take()
    }
}

/// Assert that scene document `s` is `ready` with all of its `usable` frames indexed.
pub fn assert_indexed(s: &serde_json::Value, usable: i64) {
    assert_eq!(
        (
            s["status"].as_str(),
            s["index"]["done"].as_i64(),
            s["index"]["total"].as_i64()
        ),
        (Some("ready"), Some(usable), Some(usable)),
        "{s}"
    );
}

/// Files of a tiny synthetic ScanNet-layout scene: (relative path, bytes).
pub fn tiny_scene_files(frames: usize) -> Vec<(String, Vec<u8>)> {
    let (cw, ch, dw, dh) = (64u32, 48u32, 32u32, 24u32);
    let mut files = Vec::new();
    for i in 0..frames {
        let name = i * 20;
        let img = image::RgbImage::from_fn(cw, ch, |x, y| {
            image::Rgb([(x * 4) as u8, (y * 5) as u8, (i * 40) as u8])
        });
        let mut jpg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpg, 90)
            .encode_image(&img)
            .expect("jpeg");
        files.push((format!("color/{name}.jpg"), jpg));
        let depth = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(dw, dh, |x, _| {
            image::Luma([1000 + x as u16 * 10])
        });
        let mut png = Vec::new();
        depth
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .expect("png");
        files.push((format!("depth/{name}.png"), png));
        let pose = if i == frames - 1 && frames > 2 {
            "-inf -inf -inf -inf\n-inf -inf -inf -inf\n-inf -inf -inf -inf\n-inf -inf -inf -inf\n"
                .to_string()
        } else {
            format!("1 0 0 {}\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", i as f64 * 0.5)
        };
        files.push((format!("pose/{name}.txt"), pose.into_bytes()));
    }
    files.push((
        "intrinsic/intrinsic_color.txt".into(),
        b"50 0 32 0\n0 50 24 0\n0 0 1 0\n0 0 0 1\n".to_vec(),
    ));
    files.push((
        "axis_align_matrix.txt".into(),
        b"1 0 0 1\n0 1 0 2\n0 0 1 3\n0 0 0 1\n".to_vec(),
    ));
    files
}

/// POST the tar archive `tar` to `{base}/v1/scenes` with `client` (which may carry a key),
/// assert 201 and return the scene id.
pub async fn upload_scene_to(client: &reqwest::Client, base: &str, tar: Vec<u8>) -> String {
    let r = client
        .post(format!("{base}/v1/scenes"))
        .header("Content-Type", "application/x-tar")
        .body(tar)
        .send()
        .await
        .expect("upload");
    id_of(r, 201, &format!("upload to {base}")).await
}

/// [`upload_scene_to`] with the tiny scene of `frames` frames (a tar, no top folder).
pub async fn upload_tiny_scene_to(client: &reqwest::Client, base: &str, frames: usize) -> String {
    upload_scene_to(client, base, tar_of(&tiny_scene_files(frames), None)).await
}

/// POST one job `{scene_id, query}` to `{base}/v1/jobs` with `client`, assert 202 and
/// return the job id.
pub async fn submit_job(
    client: &reqwest::Client,
    base: &str,
    scene_id: &str,
    query: &str,
) -> String {
    let r = client
        .post(format!("{base}/v1/jobs"))
        .json(&serde_json::json!({"scene_id": scene_id, "query": query}))
        .send()
        .await
        .expect("job");
    id_of(r, 202, &format!("job {query:?} at {base}")).await
}

/// Assert that `r` has the status `want` (else fail with `what` and the body) and return
/// the `id` of its JSON body.
async fn id_of(r: reqwest::Response, want: u16, what: &str) -> String {
    let status = r.status().as_u16();
    let body: serde_json::Value = r.json().await.unwrap_or(serde_json::Value::Null);
    assert_eq!(status, want, "{what}: {body}");
    body["id"].as_str().expect("an id").to_string()
}

/// GET `url` with `client` and parse the answer as JSON (of any status).
pub async fn get_json_at(client: &reqwest::Client, url: &str) -> serde_json::Value {
    let r = client.get(url).send().await.expect("get");
    r.json().await.expect("a JSON answer")
}

/// An answer's status, content type ("" when none) and JSON body (Null when not JSON), as
/// a problem+json check needs them.
pub async fn problem(r: reqwest::Response) -> (u16, String, serde_json::Value) {
    let s = r.status().as_u16();
    let ct = r
        .headers()
        .get("content-type")
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
        .to_string();
    (s, ct, r.json().await.unwrap_or(serde_json::Value::Null))
}

/// Every file below `dir` (none when it does not exist).
pub fn files_under(dir: &std::path::Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() {
                out.extend(files_under(&p));
            } else {
                out.push(p);
            }
        }
    }
    out
}

/// Every file below the folder `dir` (which must exist) with its size, sorted: what a
/// test compares before and after to see that nothing was written there. Half-written
/// (`*.tmp`) and dot files count too; a file gone between listing and sizing is left out.
pub fn files_and_sizes(dir: &std::path::Path) -> Vec<(PathBuf, u64)> {
    assert!(dir.is_dir(), "no folder {}", dir.display());
    let mut v: Vec<_> = files_under(dir)
        .into_iter()
        .filter_map(|p| {
            let n = std::fs::metadata(&p).ok()?.len();
            Some((p, n))
        })
        .collect();
    v.sort();
    v
}

/// Pack files as a tar under an optional top-level folder.
pub fn tar_of(files: &[(String, Vec<u8>)], top: Option<&str>) -> Vec<u8> {
    let mut b = tar::Builder::new(Vec::new());
    for (path, bytes) in files {
        let p = match top {
            Some(t) => format!("{t}/{path}"),
            None => path.clone(),
        };
        let mut h = tar::Header::new_gnu();
        h.set_size(bytes.len() as u64);
        h.set_mode(0o644);
        h.set_cksum();
        b.append_data(&mut h, p, bytes.as_slice())
            .expect("tar append");
    }
    b.into_inner().expect("tar finish")
}

pub fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(bytes).expect("gz");
    e.finish().expect("gz")
}

pub fn zip_of(files: &[(String, Vec<u8>)]) -> Vec<u8> {
    let mut z = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated);
    for (path, bytes) in files {
        z.start_file(path.as_str(), opts).expect("zip file");
        z.write_all(bytes).expect("zip write");
    }
    z.finish().expect("zip finish").into_inner()
}

/// The store a test server with this data dir uses (see [`test_config`]).
pub async fn open_store(data_dir: &std::path::Path) -> grounder::store::Store {
    match pg::database_for(data_dir) {
        Some(url) => grounder::store::Store::connect(&url, data_dir).await,
        None => grounder::store::Store::open(data_dir).await,
    }
    .expect("open store")
}

/// Environment for a `grounder` child process using the same database as [`test_config`].
pub fn database_env(data_dir: &std::path::Path) -> Vec<(String, String)> {
    pg::database_for(data_dir)
        .map(|u| vec![("GROUNDER_DATABASE_URL".to_string(), u)])
        .unwrap_or_default()
}

/// Create an API key in a data dir (as `grounder keys create` does): (secret, whsec).
pub async fn create_key(
    data_dir: &std::path::Path,
    name: &str,
    admin: bool,
    max_running_jobs: Option<i64>,
    max_scene_bytes: Option<i64>,
) -> (String, String) {
    let store = open_store(data_dir).await;
    let k = store
        .create_key(&grounder::store::KeySpec {
            name: name.into(),
            admin,
            max_running_jobs,
            max_scene_bytes,
        })
        .await
        .expect("create key")
        .expect("a new name");
    store.pool.close().await;
    (k.secret, k.webhook_secret)
}

/// A client whose every request carries `Authorization: Bearer <secret>`.
pub fn client_with_key(secret: &str) -> reqwest::Client {
    let mut h = reqwest::header::HeaderMap::new();
    h.insert(
        reqwest::header::AUTHORIZATION,
        format!("Bearer {secret}").parse().expect("header"),
    );
    client_builder().default_headers(h).build().expect("client")
}

/// How long any test request may take, its body included: a server that stops answering
/// fails the test that asked, instead of stalling the whole run.
pub const REQUEST_PATIENCE: Duration = Duration::from_secs(120);

/// A client whose every request is bounded by [`REQUEST_PATIENCE`].
pub fn client() -> reqwest::Client {
    client_builder().build().expect("client")
}

fn client_builder() -> reqwest::ClientBuilder {
    reqwest::Client::builder().timeout(REQUEST_PATIENCE)
}

/// One Server-Sent Event as received.
#[derive(Debug, Clone, PartialEq)]
pub struct Sse {
    pub id: Option<String>,
    pub event: String,
    pub data: serde_json::Value,
}

/// Read a whole event stream (until the server closes it) and parse its events.
pub async fn read_sse(resp: reqwest::Response) -> Vec<Sse> {
    let text = tokio::time::timeout(Duration::from_secs(20), resp.text())
        .await
        .expect("the stream ends")
        .expect("stream body");
    let mut out = Vec::new();
    for block in text.split("\n\n") {
        let (mut id, mut event, mut data) = (None, String::from("message"), String::new());
        let mut any = false;
        for line in block.lines() {
            if let Some(v) = line.strip_prefix("id:") {
                id = Some(v.trim().to_string());
                any = true;
            } else if let Some(v) = line.strip_prefix("event:") {
                event = v.trim().to_string();
                any = true;
            } else if let Some(v) = line.strip_prefix("data:") {
                data.push_str(v.strip_prefix(' ').unwrap_or(v));
                any = true;
            }
        }
        if any && !data.is_empty() {
            out.push(Sse {
                id,
                event,
                data: serde_json::from_str(&data).expect("event data is JSON"),
            });
        }
    }
    out
}
