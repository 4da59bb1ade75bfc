//! Failover on PostgreSQL with real processes: three `grounder serve` replicas on one
//! database and either one shared data dir or each its own data dir on one S3 bucket
//! (a moto server), 60 jobs submitted round-robin through them; one
//! replica is SIGKILLed mid-job and another SIGTERMed. Every job ends succeeded exactly
//! once (one `succeeded` status event each), within the lease time plus the job time of
//! the kill, and none is lost.

use crate::helpers::*;
use crate::spawned::{start_server, Server};
use serde_json::Value;
use std::time::{Duration, Instant};

const JOBS: usize = 60;
const LEASE_S: u64 = 3;
const JOB_MS: u64 = 300;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_replicas_lose_no_job_when_one_is_killed_and_one_stopped() {
    let Some(server) = pg::server() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let shared = [dir.path(), dir.path(), dir.path()];
    failover(&server, shared, &[]).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_replicas_on_one_bucket_lose_no_job_when_one_is_killed_and_one_stopped() {
    let Some(server) = pg::server() else {
        return;
    };
    let moto = crate::storage::Moto::start().await;
    moto.create_bucket("failover").await;
    let mut env = moto.env();
    env.push(("GROUNDER_STORAGE".into(), "s3://failover/replicas".into()));
    // Each replica its own data dir: the scene reaches replicas 1 and 2 through the bucket.
    let dirs: Vec<tempfile::TempDir> = (0..3).map(|_| tempfile::tempdir().unwrap()).collect();
    failover(
        &server,
        [dirs[0].path(), dirs[1].path(), dirs[2].path()],
        &env,
    )
    .await;
}

/// The failover run: replicas on `dirs` with `extra` settings (see the module docs).
async fn failover(server: &str, dirs: [&std::path::Path; 3], extra: &[(String, String)]) {
    let started = Instant::now();
    let dir = dirs[0];
    let url = pg::database(server, &format!("failover-{}", uuid::Uuid::now_v7()));
    let lease = LEASE_S.to_string();
    let pipeline = format!("test:delay_ms={JOB_MS}");
    let mut env = vec![
        ("GROUNDER_DATABASE_URL", url.as_str()),
        ("GROUNDER_LEASE_SECONDS", lease.as_str()),
        ("GROUNDER_PIPELINE", pipeline.as_str()),
        ("GROUNDER_WORKERS", "2"),
    ];
    env.extend(extra.iter().map(|(k, v)| (k.as_str(), v.as_str())));
    let mut replicas: Vec<Server> = dirs.iter().map(|d| start_server(d, &env)).collect();
    let c = client();

    let sid = upload_tiny_scene_to(&c, &replicas[0].base, 3).await;
    let mut ids = Vec::new();
    for i in 0..JOBS {
        let base = &replicas[i % 3].base;
        ids.push(submit_job(&c, base, &sid, &format!("object {i}")).await);
    }

    // Kill replica 1 while it runs a job: once all three replicas hold leases.
    let store = grounder::store::Store::connect(&url, dir).await.unwrap();
    let t = Instant::now();
    loop {
        let holders: i64 = sqlx::query_scalar(
            "SELECT COUNT(DISTINCT lease_owner) FROM jobs WHERE status = 'running'",
        )
        .fetch_one(&store.pool)
        .await
        .unwrap();
        if holders == 3 {
            break;
        }
        assert!(
            t.elapsed() < Duration::from_secs(20),
            "three replicas never ran jobs at once"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    replicas[1].signal("-KILL");
    let killed_at = Instant::now();
    let killed_wall = time::OffsetDateTime::now_utc();
    tokio::time::sleep(Duration::from_millis(400)).await;
    replicas[2].signal("-TERM");

    // Replica 0 finishes everything.
    let base = replicas[0].base.clone();
    let deadline = Duration::from_secs(LEASE_S) + Duration::from_millis(JOB_MS * JOBS as u64);
    let mut left: Vec<String> = ids.clone();
    while !left.is_empty() {
        let mut still = Vec::new();
        for id in &left {
            let j: Value = get_json_at(&c, &format!("{base}/v1/jobs/{id}")).await;
            match j["status"].as_str() {
                Some("succeeded") => {}
                Some("queued" | "running") => still.push(id.clone()),
                _ => panic!("job {id} did not succeed: {j}"),
            }
        }
        left = still;
        assert!(
            killed_at.elapsed() < deadline + Duration::from_secs(10),
            "{} jobs still unfinished {:?} after the kill",
            left.len(),
            killed_at.elapsed()
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }

    // Exactly one completion each, and the killed replica's jobs came back as attempts.
    let store = grounder::store::Store::connect(&url, dir).await.unwrap();
    let rows: Vec<(String, i64)> = sqlx::query_as(
        "SELECT job_id, COUNT(*) FROM job_events \
         WHERE kind = 'status' AND data LIKE '%\"succeeded\"%' GROUP BY job_id",
    )
    .fetch_all(&store.pool)
    .await
    .unwrap();
    assert_eq!(rows.len(), JOBS, "jobs with a success event");
    assert!(
        rows.iter().all(|(_, n)| *n == 1),
        "a job succeeded twice: {rows:?}"
    );
    // Replicas on data dirs of their own ran jobs on a scene they got from the bucket.
    for d in dirs.iter().filter(|d| **d != dir) {
        assert!(
            d.join("scenes").join(&sid).is_dir(),
            "a replica on its own data dir never fetched the scene"
        );
    }
    let retried: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM jobs WHERE attempts > 1")
        .fetch_one(&store.pool)
        .await
        .unwrap();
    assert!(retried >= 1, "no job of the killed replica was retried");
    // Each retried job finished within the lease (its last renewal came before the kill),
    // one sweep period, its wait for a worker and its own run (queued jobs are claimed in
    // order, so a requeued one is next), plus slack for two loaded cores.
    let bound = Duration::from_millis(LEASE_S * 1000 + LEASE_S * 1000 / 3 + 2 * JOB_MS)
        + Duration::from_secs(3);
    let finished: Vec<String> =
        sqlx::query_scalar("SELECT finished_at FROM jobs WHERE attempts > 1")
            .fetch_all(&store.pool)
            .await
            .unwrap();
    let mut latest = time::Duration::ZERO;
    for at in &finished {
        let at = time::OffsetDateTime::parse(at, &time::format_description::well_known::Rfc3339)
            .unwrap();
        let after = at - killed_wall;
        latest = latest.max(after);
        assert!(
            after < time::Duration::try_from(bound).unwrap(),
            "a retried job finished {after} after the kill (bound {bound:?})"
        );
    }
    eprintln!(
        "failover: {JOBS} jobs, {retried} retried after the kill (the last done {latest} after it, bound {bound:?}), {:?} in all",
        started.elapsed()
    );
}

#[tokio::test]
async fn a_worker_replica_answers_only_its_health_endpoints() {
    let dir = tempfile::tempdir().unwrap();
    let s = start_server(dir.path(), &[("GROUNDER_ROLE", "worker")]);
    let c = client();
    let r = c.get(format!("{}/healthz", s.base)).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 200);
    let r = c.get(format!("{}/v1/scenes", s.base)).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 404);
    let p: Value = r.json().await.unwrap();
    assert!(
        p["detail"].as_str().unwrap_or("").contains("--role worker"),
        "{p}"
    );
}
