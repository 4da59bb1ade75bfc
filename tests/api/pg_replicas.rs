//! Replicas on PostgreSQL looking after each other: a replica starting beside live ones
//! keeps their idempotency keys in flight, their imports and the files they may be
//! writing, and releases only what dead replicas left (at once at start-up, and within a
//! lease once a replica stops heartbeating); and indexing cut off by a killed replica is
//! taken over by a worker replica, one indexer at a time.

use crate::helpers::*;
use crate::spawned::start_server;
use grounder::store::{idempotency::Begin, Store};
use std::path::Path;
use std::time::{Duration, Instant, SystemTime};

const LEASE_S: u64 = 2;

async fn count(store: &Store, sql: &str, arg: &str) -> i64 {
    sqlx::query_scalar(sql)
        .bind(arg)
        .fetch_one(&store.pool)
        .await
        .unwrap()
}

/// A folder with one file, both last changed `age` ago.
fn folder_aged(dir: &Path, age: Duration) {
    std::fs::create_dir_all(dir).unwrap();
    let file = dir.join("part.bin");
    std::fs::write(&file, b"x").unwrap();
    let then = SystemTime::now() - age;
    for p in [&file, &dir.to_path_buf()] {
        std::fs::File::open(p).unwrap().set_modified(then).unwrap();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_replica_releases_only_what_dead_replicas_left() {
    let Some(server) = pg::server() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let url = pg::database(&server, &format!("replicas-{}", uuid::Uuid::now_v7()));
    let cfg = || {
        let mut c = test_config(dir.path().to_path_buf());
        c.database_url = Some(url.clone());
        c.lease_seconds = LEASE_S;
        c.sweep_grace_secs = 60;
        c
    };
    // A scene stored by a first replica, which then stops.
    let first = TestApp::spawn_with(cfg()).await;
    let sid = first.upload_tiny_scene(3).await;
    first.stop().await;

    // Replica X is alive (it heartbeats) and mid-request and mid-import; replica Z died
    // mid-request (no heartbeat).
    let x = Store::connect(&url, dir.path())
        .await
        .unwrap()
        .with_lease_seconds(LEASE_S);
    let z = Store::connect(&url, dir.path())
        .await
        .unwrap()
        .with_lease_seconds(LEASE_S);
    x.heartbeat().await.unwrap();
    let begin = |s: &Store, key: &'static str| {
        let s = s.clone();
        async move {
            s.idempotency_begin(0, "POST /v1/jobs", key, "h")
                .await
                .unwrap()
        }
    };
    assert_eq!(begin(&x, "x-key").await, Begin::Proceed);
    assert_eq!(begin(&z, "z-key").await, Begin::Proceed);
    sqlx::query("UPDATE scenes SET status = 'importing', holder = $1 WHERE id = $2")
        .bind(x.replica.as_str())
        .bind(&sid)
        .execute(&x.pool)
        .await
        .unwrap();
    // Leftovers no row names: settled ones (untouched for 2 h) and fresh ones.
    let scenes = dir.path().join("scenes");
    let tmp = dir.path().join("tmp");
    folder_aged(&scenes.join("orphan-old"), Duration::from_secs(7200));
    folder_aged(&scenes.join("orphan-fresh"), Duration::ZERO);
    folder_aged(&tmp.join("spool-old"), Duration::from_secs(7200));
    folder_aged(&tmp.join("spool-fresh"), Duration::ZERO);

    let b = TestApp::spawn_with(cfg()).await;
    let key_left = |k: &'static str| {
        let x = x.clone();
        async move { count(&x, "SELECT COUNT(*) FROM idempotency WHERE key = $1", k).await }
    };
    let scene_left =
        || async { count(&x, "SELECT COUNT(*) FROM scenes WHERE id = $1", &sid).await };
    assert_eq!(key_left("z-key").await, 0, "a dead replica's key stayed");
    assert_eq!(
        key_left("x-key").await,
        1,
        "a live replica's key was released"
    );
    assert_eq!(scene_left().await, 1, "a live replica's import was undone");
    assert!(
        scenes.join(&sid).is_dir(),
        "a live import's files were removed"
    );
    assert!(
        !scenes.join("orphan-old").exists(),
        "a settled orphan stayed"
    );
    assert!(!tmp.join("spool-old").exists(), "a settled spool stayed");
    assert!(
        scenes.join("orphan-fresh").is_dir(),
        "a fresh folder was removed"
    );
    assert!(
        tmp.join("spool-fresh").is_dir(),
        "a fresh spool was removed"
    );
    // The live key still answers "in flight" to another replica.
    assert_eq!(begin(&z, "x-key").await, Begin::InFlight);

    // While X heartbeats, over several lease periods, nothing of X's goes.
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(LEASE_S * 2) {
        x.heartbeat().await.unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
    }
    assert_eq!(
        key_left("x-key").await,
        1,
        "a live replica's key was released"
    );
    assert_eq!(scene_left().await, 1, "a live replica's import was undone");

    // X stops heartbeating: within a lease and a housekeeping period its key is released
    // and its import undone (row and files).
    let stopped = Instant::now();
    let bound = Duration::from_millis(LEASE_S * 1000 + LEASE_S * 1000 / 3) + Duration::from_secs(2);
    while key_left("x-key").await + scene_left().await > 0 || scenes.join(&sid).exists() {
        assert!(
            stopped.elapsed() < bound,
            "X's key or import still there {:?} after its last heartbeat",
            stopped.elapsed()
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let released = stopped.elapsed();
    assert!(
        released >= Duration::from_millis(LEASE_S * 1000 - 400),
        "released {released:?} after the last heartbeat, before the lease ran out"
    );
    eprintln!("a stopped replica's key and import released {released:?} after its last heartbeat");
    b.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_replica_takes_over_indexing_that_a_killed_replica_left() {
    let Some(server) = pg::server() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let url = pg::database(&server, &format!("reindex-{}", uuid::Uuid::now_v7()));
    let lease = LEASE_S.to_string();
    // A slow detector: 19 usable frames of 150 ms, about 3 s of indexing.
    let env = |role: &'static str| {
        vec![
            ("GROUNDER_DATABASE_URL", url.clone()),
            ("GROUNDER_LEASE_SECONDS", lease.clone()),
            ("GROUNDER_DETECTOR", "oracle:delay_ms=150".to_string()),
            ("GROUNDER_ROLE", role.to_string()),
        ]
    };
    let start = |role: &'static str| {
        let e = env(role);
        let e: Vec<(&str, &str)> = e.iter().map(|(k, v)| (*k, v.as_str())).collect();
        start_server(dir.path(), &e)
    };
    let mut a = start("all");
    let _worker = start("worker");
    let store = Store::connect(&url, dir.path()).await.unwrap();
    let sid = upload_scene_to(&client(), &a.base, crate::crash::scene_with_masks(20)).await;
    let state = || async {
        let row: (String, Option<String>, i64) =
            sqlx::query_as("SELECT status, index_owner, index_done FROM scenes WHERE id = $1")
                .bind(&sid)
                .fetch_one(&store.pool)
                .await
                .unwrap();
        row
    };
    // A indexes; the worker, beside it, leaves its live lease alone.
    let t = Instant::now();
    let owner_a = loop {
        let (status, owner, done) = state().await;
        assert_eq!(status, "indexing", "indexing ended before the kill");
        if let (Some(o), true) = (owner, done > 0) {
            break o;
        }
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "A never started indexing"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    tokio::time::sleep(Duration::from_millis(LEASE_S * 1000 / 2)).await;
    let (status, owner, _) = state().await;
    assert_eq!(
        (status.as_str(), owner.as_deref()),
        ("indexing", Some(owner_a.as_str())),
        "the worker took over a live indexer's scene"
    );

    a.signal("-KILL");
    let killed = Instant::now();
    let mut owners = std::collections::BTreeSet::new();
    let bound =
        Duration::from_millis(LEASE_S * 1000 + LEASE_S * 1000 / 3 + 3000) + Duration::from_secs(6);
    loop {
        let (status, owner, _) = state().await;
        owners.extend(owner);
        if status == "ready" {
            break;
        }
        assert_eq!(status, "indexing", "{sid}");
        assert!(
            killed.elapsed() < bound,
            "the scene is still indexing {:?} after the kill",
            killed.elapsed()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    owners.remove(&owner_a);
    assert_eq!(owners.len(), 1, "one indexer took over: {owners:?}");
    let attempts: i64 = sqlx::query_scalar("SELECT index_attempts FROM scenes WHERE id = $1")
        .bind(&sid)
        .fetch_one(&store.pool)
        .await
        .unwrap();
    assert_eq!(attempts, 0, "attempts are reset once indexing ends");
    eprintln!(
        "indexing taken over and done {:?} after the kill",
        killed.elapsed()
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_indexer_holds_a_scene_until_its_lease_runs_out() {
    use grounder::store::Claim;
    let Some(server) = pg::server() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let url = pg::database(&server, &format!("claims-{}", uuid::Uuid::now_v7()));
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.database_url = Some(url.clone());
    let app = TestApp::spawn_with(cfg).await;
    let sid = app.upload_tiny_scene(3).await;
    app.stop().await;
    let open = || async {
        Store::connect(&url, dir.path())
            .await
            .unwrap()
            .with_lease_seconds(1)
    };
    let (a, b) = (open().await, open().await);
    assert!(a.claim_indexing(&sid, "a", Claim::Start).await.unwrap());
    assert!(!b.claim_indexing(&sid, "b", Claim::Start).await.unwrap());
    assert!(!b.claim_indexing(&sid, "b", Claim::TakeOver).await.unwrap());
    assert!(b.indexing_held(&sid).await.unwrap());
    assert!(a.renew_indexing(&sid, "a").await.unwrap());
    assert!(!b.renew_indexing(&sid, "b").await.unwrap());
    assert!(b.unclaimed_indexing().await.unwrap().is_empty());
    // a stops renewing: once the lease ran out, b takes the scene over, and a can neither
    // renew nor record an outcome.
    tokio::time::sleep(Duration::from_millis(1300)).await;
    assert!(!b.indexing_held(&sid).await.unwrap());
    assert!(b.claim_indexing(&sid, "b", Claim::TakeOver).await.unwrap());
    assert!(!a.renew_indexing(&sid, "a").await.unwrap());
    assert!(!a
        .end_indexing(&sid, "a", "failed", Some("x"))
        .await
        .unwrap());
    assert!(b.end_indexing(&sid, "b", "ready", None).await.unwrap());
    let (status, owner): (String, Option<String>) =
        sqlx::query_as("SELECT status, index_owner FROM scenes WHERE id = $1")
            .bind(&sid)
            .fetch_one(&a.pool)
            .await
            .unwrap();
    assert_eq!((status.as_str(), owner), ("ready", None));
    // Force takes it whatever the lease (the only process, at start-up).
    assert!(a.claim_indexing(&sid, "a", Claim::Start).await.unwrap());
    assert!(b.claim_indexing(&sid, "b", Claim::Force).await.unwrap());
    assert!(!a.renew_indexing(&sid, "a").await.unwrap());
}
