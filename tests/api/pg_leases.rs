//! Leases on PostgreSQL, replica by replica: a claimed job is skipped by other replicas,
//! a lease that runs out puts the job back (as an attempt) for any replica, the old holder
//! can then neither renew nor finish it, a cancel through one replica wakes another, and
//! a job whose leases keep running out fails `too_many_attempts` after three.

use crate::helpers::*;
use grounder::config::Role;
use grounder::store::{JobStatus, Store};
use std::time::Duration;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn leases_move_jobs_between_replicas_and_give_up_after_three_attempts() {
    let Some(server) = crate::helpers::pg::server() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let url = crate::helpers::pg::database(&server, &format!("leases-{}", uuid::Uuid::now_v7()));
    // An API-only replica: it stores scenes and jobs but runs none.
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.database_url = Some(url.clone());
    cfg.role = Role::Api;
    let app = TestApp::spawn_with(cfg).await;
    let sid = app.upload_tiny_scene(3).await;
    let job = |q: &'static str| {
        let app = &app;
        let sid = sid.clone();
        async move { app.submit_job(&sid, q).await }
    };
    let id = job("the chair").await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (_, j) = app.get_json(&format!("/v1/jobs/{id}")).await;
    assert_eq!(j["status"], "queued", "an api replica ran a job: {j}");

    let a = Store::connect(&url, dir.path())
        .await
        .unwrap()
        .with_lease_seconds(1);
    let b = Store::connect(&url, dir.path())
        .await
        .unwrap()
        .with_lease_seconds(1);
    let claimed = a.claim_next_job().await.unwrap().expect("a claims the job");
    assert_eq!((claimed.id.as_str(), claimed.attempts), (id.as_str(), 1));
    assert!(
        b.claim_next_job().await.unwrap().is_none(),
        "b took a's job"
    );
    assert!(a.renew_lease(&id).await.unwrap());
    assert!(!b.renew_lease(&id).await.unwrap(), "b renewed a's lease");
    assert!(!b
        .finish_job(&id, JobStatus::Succeeded, None, None)
        .await
        .unwrap());
    assert_eq!(
        b.expire_leases(3).await.unwrap(),
        (0, 0),
        "a live lease expired"
    );

    // a stops renewing: within the lease, b requeues the job and runs it.
    tokio::time::sleep(Duration::from_millis(1300)).await;
    assert_eq!(b.expire_leases(3).await.unwrap(), (1, 0));
    assert!(
        !a.renew_lease(&id).await.unwrap(),
        "a kept a lease that ran out"
    );
    let again = b.claim_next_job().await.unwrap().expect("b claims it");
    assert_eq!((again.id.as_str(), again.attempts), (id.as_str(), 2));
    assert!(!a
        .finish_job(&id, JobStatus::Succeeded, None, None)
        .await
        .unwrap());

    // A cancel through the API replica reaches b's waiters by notification.
    let mut changes = b.events.subscribe(&id);
    let r = app.post_empty(&format!("/v1/jobs/{id}/cancel")).await;
    assert!(r.status().is_success(), "{}", r.status());
    tokio::time::timeout(Duration::from_secs(5), changes.changed())
        .await
        .expect("b hears of the cancel")
        .unwrap();
    assert!(
        !b.renew_lease(&id).await.unwrap(),
        "b renews a canceled job"
    );
    assert!(!b
        .finish_job(&id, JobStatus::Succeeded, None, None)
        .await
        .unwrap());

    // A job whose lease runs out three times fails too_many_attempts.
    let id2 = job("the table").await;
    for attempt in 1..=3 {
        let j = a.claim_next_job().await.unwrap().expect("claim");
        assert_eq!((j.id.as_str(), j.attempts), (id2.as_str(), attempt));
        tokio::time::sleep(Duration::from_millis(1200)).await;
        let want = if attempt < 3 { (1, 0) } else { (0, 1) };
        assert_eq!(b.expire_leases(3).await.unwrap(), want, "attempt {attempt}");
    }
    let (_, j) = app.get_json(&format!("/v1/jobs/{id2}")).await;
    assert_eq!(j["status"], "failed", "{j}");
    assert_eq!(j["error"]["code"], "too_many_attempts", "{j}");
    app.stop().await;
}
