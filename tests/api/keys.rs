//! Issue 19: API keys, isolation between keys, quotas, anonymous access rules, the CLI.

use crate::helpers::*;
use serde_json::{json, Value};

struct Keyed {
    app: TestApp,
    alice: reqwest::Client,
    bob: reqwest::Client,
    admin: reqwest::Client,
    /// The secrets of alice and bob (for the browser's ways of carrying a key).
    alice_key: String,
    bob_key: String,
    _dir: tempfile::TempDir,
}

async fn keyed(quota_jobs: Option<i64>, quota_bytes: Option<i64>) -> Keyed {
    let dir = tempfile::tempdir().unwrap();
    let (a, _) = create_key(dir.path(), "alice", false, quota_jobs, quota_bytes).await;
    let (b, _) = create_key(dir.path(), "bob", false, None, None).await;
    let (root, _) = create_key(dir.path(), "root", true, None, None).await;
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.pipeline = "test:delay_ms=2000".into();
    let app = TestApp::spawn_with(cfg).await;
    Keyed {
        app,
        alice: client_with_key(&a),
        bob: client_with_key(&b),
        admin: client_with_key(&root),
        alice_key: a.clone(),
        bob_key: b.clone(),
        _dir: dir,
    }
}

async fn upload(app: &TestApp, c: &reqwest::Client) -> reqwest::Response {
    c.post(app.url("/v1/scenes"))
        .header("content-type", "application/x-tar")
        .body(tar_of(&tiny_scene_files(3), None))
        .send()
        .await
        .unwrap()
}

async fn new_job(app: &TestApp, c: &reqwest::Client, scene: &str) -> reqwest::Response {
    c.post(app.url("/v1/jobs"))
        .json(&json!({"scene_id": scene, "query": "the chair"}))
        .send()
        .await
        .unwrap()
}

async fn get(app: &TestApp, c: &reqwest::Client, path: &str) -> (u16, Value) {
    let r = c.get(app.url(path)).send().await.unwrap();
    let s = r.status().as_u16();
    (s, r.json().await.unwrap_or(Value::Null))
}

fn ids(v: &Value, field: &str) -> Vec<String> {
    v[field]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x["id"].as_str().unwrap().to_string())
        .collect()
}

#[tokio::test]
async fn two_keys_cannot_see_each_others_scenes_or_jobs() {
    let k = keyed(None, None).await;
    let app = &k.app;
    let sa = upload_tiny_scene_to(&k.alice, &app.url(""), 3).await;
    let sb = upload_tiny_scene_to(&k.bob, &app.url(""), 3).await;
    let ja = submit_job(&k.alice, &app.url(""), &sa, "the chair").await;

    // Bob: alice's scene and job do not exist for him.
    let (s, p) = get(app, &k.bob, &format!("/v1/scenes/{sa}")).await;
    assert_eq!((s, p["code"].as_str()), (404, Some("scene_not_found")));
    let (s, p) = get(app, &k.bob, &format!("/v1/jobs/{ja}")).await;
    assert_eq!((s, p["code"].as_str()), (404, Some("job_not_found")));
    for path in [
        format!("/v1/jobs/{ja}/events"),
        format!("/v1/jobs/{ja}/artifacts/grid_0.jpg"),
        format!("/v1/jobs/{ja}/object.ply"),
        format!("/v1/jobs/{ja}/masks/00000.png"),
        format!("/v1/scenes/{sa}/points.ply"),
        format!("/v1/scenes/{sa}/frames"),
        format!("/v1/scenes/{sa}/frames/00000.jpg"),
    ] {
        let (s, _) = get(app, &k.bob, &path).await;
        assert_eq!(s, 404, "{path}");
    }
    // A browser opens the viewer with ?key= once, then carries the page's cookie; both
    // are the caller's key (GET only), and another key's scene stays hidden.
    let page = |q: String| {
        let c = app.client.clone();
        let url = app.url(&q);
        async move { c.get(url).send().await.unwrap().status().as_u16() }
    };
    assert_eq!(
        page(format!("/v1/scenes/{sa}/view?key={}", k.alice_key)).await,
        200
    );
    assert_eq!(
        page(format!("/v1/scenes/{sa}/view?key={}", k.bob_key)).await,
        404
    );
    assert_eq!(page(format!("/v1/scenes/{sa}/view")).await, 401);
    let with_cookie = app
        .client
        .get(app.url(&format!("/v1/scenes/{sa}/frames")))
        .header("Cookie", format!("other=1; grounder_key={}", k.alice_key))
        .send()
        .await
        .unwrap()
        .status()
        .as_u16();
    assert_eq!(with_cookie, 200);
    let r = k
        .bob
        .post(app.url(&format!("/v1/jobs/{ja}/cancel")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 404);
    let r = k
        .bob
        .delete(app.url(&format!("/v1/scenes/{sa}")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 404);
    // ... and he cannot run a job on her scene.
    let r = new_job(app, &k.bob, &sa).await;
    assert_eq!(r.status().as_u16(), 404);
    assert_eq!(r.json::<Value>().await.unwrap()["code"], "scene_not_found");

    // Lists show only one's own.
    let (_, l) = get(app, &k.bob, "/v1/scenes").await;
    assert_eq!(ids(&l, "scenes"), vec![sb.clone()]);
    let (_, l) = get(app, &k.bob, "/v1/jobs").await;
    assert!(ids(&l, "jobs").is_empty());
    let (_, l) = get(app, &k.alice, "/v1/scenes").await;
    assert_eq!(ids(&l, "scenes"), vec![sa.clone()]);
    let (_, l) = get(app, &k.alice, "/v1/jobs").await;
    assert_eq!(ids(&l, "jobs"), vec![ja.clone()]);
    let (s, _) = get(app, &k.alice, &format!("/v1/jobs/{ja}")).await;
    assert_eq!(s, 200);

    // The admin sees everything.
    let (_, l) = get(app, &k.admin, "/v1/scenes").await;
    let mut all = ids(&l, "scenes");
    all.sort();
    let mut want = vec![sa.clone(), sb.clone()];
    want.sort();
    assert_eq!(all, want);
    let (s, _) = get(app, &k.admin, &format!("/v1/jobs/{ja}")).await;
    assert_eq!(s, 200);
    k.app.stop().await;
}

#[tokio::test]
async fn without_a_valid_key_requests_are_401_and_metrics_need_an_admin() {
    let k = keyed(None, None).await;
    let app = &k.app;
    let plain = client();
    for path in ["/v1/scenes", "/v1/jobs", "/v1/jobs/x", "/metrics"] {
        let r = plain.get(app.url(path)).send().await.unwrap();
        assert_eq!(r.status().as_u16(), 401, "{path}");
        assert_eq!(r.headers()["www-authenticate"], "Bearer");
        assert_eq!(r.headers()["content-type"], "application/problem+json");
        assert_eq!(r.json::<Value>().await.unwrap()["code"], "unauthorized");
    }
    let wrong = client_with_key("gk_not-a-key");
    let (s, p) = get(app, &wrong, "/v1/scenes").await;
    assert_eq!((s, p["code"].as_str()), (401, Some("unauthorized")));
    for path in ["/healthz", "/readyz", "/openapi.yaml"] {
        let r = plain.get(app.url(path)).send().await.unwrap();
        assert_eq!(r.status().as_u16(), 200, "{path} stays open");
    }
    let r = k.alice.get(app.url("/metrics")).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 403);
    let r = k.admin.get(app.url("/metrics")).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 200);
    k.app.stop().await;
}

#[tokio::test]
async fn quotas_answer_429_with_retry_after() {
    let scene_len = tar_of(&tiny_scene_files(3), None).len() as i64;
    let k = keyed(Some(2), Some(scene_len + scene_len / 2)).await;
    let app = &k.app;
    let sid = upload_tiny_scene_to(&k.alice, &app.url(""), 3).await;
    // A second scene would exceed the stored bytes.
    let r = upload(app, &k.alice).await;
    assert_eq!(r.status().as_u16(), 429);
    assert!(r.headers().contains_key("retry-after"));
    assert_eq!(r.json::<Value>().await.unwrap()["code"], "quota_exceeded");
    // Two jobs fit (they stay queued/running 2 s), a third does not; a batch of two
    // after one is refused whole.
    assert_eq!(new_job(app, &k.alice, &sid).await.status().as_u16(), 202);
    let r = k
        .alice
        .post(app.url("/v1/jobs"))
        .json(&json!({"scene_id": sid, "queries": ["a", "b"]}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 429);
    assert_eq!(new_job(app, &k.alice, &sid).await.status().as_u16(), 202);
    let r = new_job(app, &k.alice, &sid).await;
    assert_eq!(r.status().as_u16(), 429);
    let secs: u64 = r.headers()["retry-after"]
        .to_str()
        .unwrap()
        .parse()
        .unwrap();
    assert!(secs > 0);
    let (_, l) = get(app, &k.alice, "/v1/jobs").await;
    assert_eq!(ids(&l, "jobs").len(), 2, "refused requests created nothing");
    k.app.stop().await;
}

#[tokio::test]
async fn without_keys_a_public_address_needs_allow_anonymous() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.addr = "0.0.0.0:0".into();
    let err = grounder::startup::Application::build(cfg.clone())
        .await
        .err()
        .expect("refused");
    assert!(err.to_string().contains("--allow-anonymous"), "{err}");
    cfg.allow_anonymous = true;
    let app = TestApp::spawn_with(cfg.clone()).await;
    let url = format!("http://127.0.0.1:{}/v1/scenes", app.addr.port());
    let r = reqwest::get(&url).await.unwrap();
    assert_eq!(r.status().as_u16(), 200, "anonymous access when allowed");
    app.stop().await;
    // With a key, the same address is fine without the flag.
    create_key(dir.path(), "k", false, None, None).await;
    cfg.allow_anonymous = false;
    let app = TestApp::spawn_with(cfg).await;
    let url = format!("http://127.0.0.1:{}/v1/scenes", app.addr.port());
    let r = reqwest::get(&url).await.unwrap();
    assert_eq!(r.status().as_u16(), 401);
    app.stop().await;
}

fn cli(dir: &std::path::Path, args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_grounder"))
        .arg("keys")
        .args(args)
        .arg("--data-dir")
        .arg(dir)
        .envs(crate::helpers::database_env(dir))
        .env_remove("GROUNDER_CONFIG")
        .output()
        .expect("run grounder keys")
}

// Multi-threaded: the CLI runs as a blocking child process while the server in this same
// runtime must keep serving (on one thread a server transaction caught mid-way by the
// block held the database lock until the CLI gave up: "database is locked").
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_keys_cli_creates_lists_revokes_and_shows_webhook_secrets() {
    let dir = tempfile::tempdir().unwrap();
    let out = cli(
        dir.path(),
        &["create", "--name", "robot1", "--max-running-jobs", "3"],
    );
    assert!(out.status.success(), "{out:?}");
    let text = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let (secret, whsec) = (lines[0], lines[1]);
    assert!(
        secret.starts_with("gk_") && whsec.starts_with("whsec_"),
        "{text}"
    );
    // Only a hash is stored.
    let (db, wal) = if crate::helpers::pg::database_for(dir.path()).is_none() {
        let db = std::fs::read(dir.path().join("grounder.db")).unwrap();
        let wal = std::fs::read(dir.path().join("grounder.db-wal")).unwrap_or_default();
        (db, wal)
    } else {
        let store = crate::helpers::open_store(dir.path()).await;
        let rows: Vec<String> =
            sqlx::query_scalar("SELECT name || secret_sha256 || webhook_secret FROM api_keys")
                .fetch_all(&store.pool)
                .await
                .unwrap();
        assert!(!rows.is_empty(), "the key is in the database");
        (rows.concat().into_bytes(), Vec::new())
    };
    let has = |hay: &[u8]| hay.windows(secret.len()).any(|w| w == secret.as_bytes());
    assert!(!has(&db) && !has(&wal), "the secret is not in the database");

    let out = cli(dir.path(), &["create", "--name", "robot1"]);
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.starts_with("error:") && err.contains("exists"), "{err}");

    let out = cli(dir.path(), &["webhook-secret", "robot1"]);
    assert_eq!(String::from_utf8(out.stdout).unwrap().trim(), whsec);

    let out = cli(dir.path(), &["list"]);
    let list = String::from_utf8(out.stdout).unwrap();
    assert!(
        list.lines().any(|l| l.starts_with("robot1\tfalse\t3\t-\t")),
        "{list}"
    );

    // The key works against a server on the same data dir, until revoked.
    let app = TestApp::spawn_with(test_config(dir.path().to_path_buf())).await;
    let c = client_with_key(secret);
    let (s, _) = get(&app, &c, "/v1/scenes").await;
    assert_eq!(s, 200);
    let out = cli(dir.path(), &["revoke", "robot1"]);
    assert!(out.status.success(), "{out:?}");
    tokio::time::sleep(grounder::api::auth::TTL + std::time::Duration::from_millis(200)).await;
    let (s, _) = get(&app, &c, "/v1/scenes").await;
    assert_eq!(s, 401, "a revoked key is refused within the cache TTL");
    let out = cli(dir.path(), &["revoke", "robot1"]);
    assert!(!out.status.success());
    app.stop().await;
}
