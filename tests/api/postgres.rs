//! The shared API tests on PostgreSQL: this test binary runs again with
//! TEST_POSTGRES_SERVER set, so that `helpers::test_config` gives every test server a
//! database of its own on a throwaway cluster (see `pg.rs`), selecting the job lifecycle
//! (7 tests), scenes (3), idempotency (2), keys (5), events (1), frames (1), webhooks (2),
//! polling (3), problems (1), internal errors (1) and formats (3) tests: 29, the same tests
//! that run on SQLite in this binary's ordinary run.

use std::process::Command;

#[test]
fn the_shared_api_tests_pass_on_postgres() {
    if std::env::var_os(crate::helpers::pg::SERVER_ENV).is_some() {
        return; // this is the copy started below
    }
    let Some(server) = crate::helpers::pg::server() else {
        return;
    };
    let exe = std::env::current_exe().expect("test binary");
    let out = Command::new(exe)
        .args([
            "jobs::",
            "scenes::",
            "idempotency::",
            "keys::",
            "events::",
            "frames::",
        ])
        .args([
            "webhooks::",
            "polling::",
            "problems::",
            "internal_errors::",
            "formats::",
        ])
        .args(["--skip", "postgres::", "--test-threads=2"])
        .env(crate::helpers::pg::SERVER_ENV, &server)
        .output()
        .expect("run the tests again");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "the shared tests failed on PostgreSQL:\n{stdout}\n{stderr}"
    );
    let passed: usize = stdout
        .lines()
        .filter_map(|l| l.strip_prefix("test result: ok. "))
        .filter_map(|l| l.split(' ').next()?.parse::<usize>().ok())
        .sum();
    eprintln!("{passed} shared tests passed on PostgreSQL");
    assert!(
        passed >= 29,
        "too few tests ran on PostgreSQL ({passed}):\n{stdout}"
    );
}
