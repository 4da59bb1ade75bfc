//! A throwaway PostgreSQL for the tests: `initdb` into a temp dir and `pg_ctl start` on a
//! free port (as the `postgres` user when the tests run as root), stopped and removed by
//! a watchdog once the test process is gone.
//!
//! Rule: the binaries come from the Debian `postgresql` package, which `.ci/run` installs
//! and then sets CI_REQUIRE_POSTGRES=1. Without the binaries a test needing
//! PostgreSQL fails when that variable is set, and otherwise is skipped with a loud
//! message on stderr. With the binaries, a cluster that cannot start always fails.
//!
//! Tests that run on both backends call `helpers::test_config` / `helpers::open_store`:
//! when TEST_POSTGRES_SERVER holds a server URL (set by `postgres::the_shared_api_tests_pass_on_postgres`
//! for the copy of this test binary it runs), each data dir gets its own database there.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;

/// Set to a server URL (`postgres://postgres@127.0.0.1:PORT`): the shared tests use it.
pub const SERVER_ENV: &str = "TEST_POSTGRES_SERVER";

/// A PostgreSQL binary from PATH or the Debian package's folder.
fn pg_bin(name: &str) -> Option<PathBuf> {
    let from_path = std::env::var_os("PATH").and_then(|p| {
        std::env::split_paths(&p)
            .map(|d| d.join(name))
            .find(|f| f.is_file())
    });
    from_path.or_else(|| {
        let mut dirs: Vec<PathBuf> = std::fs::read_dir("/usr/lib/postgresql")
            .ok()?
            .filter_map(|e| e.ok().map(|e| e.path().join("bin")))
            .collect();
        dirs.sort();
        dirs.into_iter()
            .rev()
            .map(|d| d.join(name))
            .find(|f| f.is_file())
    })
}

fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
        .unwrap_or(false)
}

/// `program args` as the postgres user when we are root.
fn as_pg_user(program: &Path) -> Command {
    if is_root() {
        let mut c = Command::new("runuser");
        c.args(["-u", "postgres", "--"]).arg(program);
        c
    } else {
        Command::new(program)
    }
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

fn start_cluster() -> Result<String, String> {
    let initdb = pg_bin("initdb").ok_or("no initdb")?;
    let pg_ctl = pg_bin("pg_ctl").ok_or("no pg_ctl")?;
    let dir = std::env::temp_dir().join(format!("grounder-pg-{}", uuid::Uuid::now_v7()));
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    if is_root() {
        let ok = Command::new("chown")
            .args(["postgres:postgres"])
            .arg(&dir)
            .status()
            .map_err(|e| e.to_string())?;
        if !ok.success() {
            return Err("cannot give the cluster's folder to the postgres user".into());
        }
    }
    let data = dir.join("data");
    let out = as_pg_user(&initdb)
        .arg("-D")
        .arg(&data)
        .args(["-A", "trust", "-U", "postgres", "-E", "UTF8", "--no-sync"])
        .output()
        .map_err(|e| format!("initdb: {e}"))?;
    if !out.status.success() {
        return Err(format!(
            "initdb failed: {}",
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    let port = free_port();
    let opts = format!(
        "-p {port} -k {} -c listen_addresses=127.0.0.1 -c max_connections=400 -c fsync=off \
         -c synchronous_commit=off -c full_page_writes=off",
        dir.display()
    );
    let out = as_pg_user(&pg_ctl)
        .arg("-D")
        .arg(&data)
        .args(["-o", &opts, "-l"])
        .arg(dir.join("log"))
        .args(["-w", "-t", "60", "start"])
        .output()
        .map_err(|e| format!("pg_ctl: {e}"))?;
    if !out.status.success() {
        let log = std::fs::read_to_string(dir.join("log")).unwrap_or_default();
        return Err(format!(
            "pg_ctl start failed: {} {log}",
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    // The watchdog outlives us by at most a second: it stops the cluster and removes it.
    let script = crate::helpers::after_this_process(&format!(
        "'{ctl}' -D '{data}' stop -m immediate >/dev/null 2>&1; rm -rf '{dir}'",
        ctl = pg_ctl.display(),
        data = data.display(),
        dir = dir.display(),
    ));
    let mut watchdog = if is_root() {
        let mut c = Command::new("runuser");
        c.args(["-u", "postgres", "--", "sh", "-c", &script]);
        c
    } else {
        let mut c = Command::new("sh");
        c.args(["-c", &script]);
        c
    };
    watchdog
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| format!("watchdog: {e}"))?;
    Ok(format!("postgres://postgres@127.0.0.1:{port}"))
}

/// This process's cluster (started on first use), or None (test skipped, message
/// printed) when PostgreSQL is not installed and CI does not require it.
pub fn server() -> Option<String> {
    static SERVER: OnceLock<Result<String, String>> = OnceLock::new();
    if let Ok(url) = std::env::var(SERVER_ENV) {
        return Some(url);
    }
    if pg_bin("initdb").is_none() || pg_bin("pg_ctl").is_none() {
        let required = std::env::var("CI_REQUIRE_POSTGRES").is_ok_and(|v| v == "1");
        assert!(
            !required,
            "CI_REQUIRE_POSTGRES=1 but initdb/pg_ctl are not installed (Debian package postgresql)"
        );
        eprintln!("\n!!!!! SKIPPED: PostgreSQL is not installed (initdb, pg_ctl); install the Debian package postgresql or run .ci/run !!!!!\n");
        return None;
    }
    match SERVER.get_or_init(start_cluster) {
        Ok(url) => Some(url.clone()),
        Err(e) => panic!("PostgreSQL is installed but a test cluster cannot start: {e}"),
    }
}

/// A fresh database on `server` named after `key`; its URL.
pub fn database(server: &str, key: &str) -> String {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    key.hash(&mut h);
    let name = format!("t{:016x}", h.finish());
    let psql = pg_bin("psql").expect("psql (Debian package postgresql-client)");
    let out = Command::new(psql)
        .arg(format!("{server}/postgres"))
        .args(["-q", "-v", "ON_ERROR_STOP=0", "-c"])
        .arg(format!("CREATE DATABASE {name}"))
        .output()
        .expect("run psql");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.trim().is_empty() || err.contains("already exists"),
        "cannot create database {name}: {err}"
    );
    format!("{server}/{name}")
}

/// Run one SQL statement on `server` as the superuser; "already exists" is fine.
pub fn run_sql(server: &str, sql: &str) {
    let psql = pg_bin("psql").expect("psql (Debian package postgresql-client)");
    let out = Command::new(psql)
        .arg(format!("{server}/postgres"))
        .args(["-q", "-v", "ON_ERROR_STOP=0", "-c", sql])
        .output()
        .expect("run psql");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.trim().is_empty() || err.contains("already exists"),
        "{sql}: {err}"
    );
}

/// The database the shared tests use for `data_dir`: None (SQLite in the data dir) unless
/// this run is the PostgreSQL one.
pub fn database_for(data_dir: &Path) -> Option<String> {
    let server = std::env::var(SERVER_ENV).ok()?;
    Some(database(&server, &data_dir.display().to_string()))
}
