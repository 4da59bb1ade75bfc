//! `deploy/compose.yaml`, checked without a container runtime: its grounder services'
//! settings are read as the service reads them (every `GROUNDER_*` variable must be a
//! configuration key), the roles, the database URL, the bucket, the services each depends
//! on and the published ports are checked; then three real `grounder serve` processes run
//! with exactly those environments (the compose services' host names replaced by this
//! test's own PostgreSQL and moto server, `/data` by temp dirs) and a job submitted through
//! the API replica succeeds.

use grounder::config::load::{resolve, Flags, Sources};
use grounder::config::{Config, Role};
use serde_json::Value as Json;
use serde_norway::Value;
use std::collections::{BTreeMap, HashSet};
use std::time::{Duration, Instant};

use crate::helpers::{client, get_json_at, pg, submit_job, upload_tiny_scene_to};
use crate::spawned::{start_server, Server};

const COMPOSE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/deploy/compose.yaml");
const DOCKERFILE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/Dockerfile");

/// The compose file with its `<<` merge keys applied.
fn compose() -> Value {
    let text = std::fs::read_to_string(COMPOSE).expect("read deploy/compose.yaml");
    let mut v: Value = serde_norway::from_str(&text).expect("deploy/compose.yaml is YAML");
    v.apply_merge().expect("merge keys");
    v
}

fn services(c: &Value) -> &serde_norway::Mapping {
    c.get("services")
        .and_then(Value::as_mapping)
        .expect("a services mapping")
}

/// The services built from this repository (the grounder replicas), by name.
fn replicas(c: &Value) -> BTreeMap<String, &Value> {
    services(c)
        .iter()
        .filter(|(_, s)| s.get("image").and_then(Value::as_str) == Some("grounder:local"))
        .map(|(n, s)| (n.as_str().expect("service name").to_string(), s))
        .collect()
}

/// A service's environment as (name, value); every value must be a string.
fn environment(service: &Value) -> Vec<(String, String)> {
    let env = service
        .get("environment")
        .and_then(Value::as_mapping)
        .expect("an environment mapping");
    env.iter()
        .map(|(k, v)| {
            let k = k.as_str().expect("variable name").to_string();
            let v = v
                .as_str()
                .unwrap_or_else(|| panic!("{k} must be a quoted string in compose.yaml: {v:?}"));
            (k, v.to_string())
        })
        .collect()
}

fn var<'a>(env: &'a [(String, String)], name: &str) -> &'a str {
    env.iter()
        .find(|(k, _)| k == name)
        .map(|(_, v)| v.as_str())
        .unwrap_or_else(|| panic!("{name} is not set"))
}

/// The configuration a replica with `env` (and no file, no flags) runs with.
fn config_of(name: &str, env: &[(String, String)]) -> Config {
    resolve(&Sources {
        file: None,
        env,
        flags: Flags::default(),
    })
    .unwrap_or_else(|e| panic!("{name}: grounder would refuse this environment (exit 2): {e}"))
}

/// Host ports published by a service (`"HOST:CONTAINER"` entries) and container ports.
fn ports(service: &Value) -> Vec<(u16, u16)> {
    let Some(list) = service.get("ports").and_then(Value::as_sequence) else {
        return Vec::new();
    };
    list.iter()
        .map(|p| {
            let p = p.as_str().expect("ports as \"HOST:CONTAINER\" strings");
            let (h, c) = p.rsplit_once(':').expect("HOST:CONTAINER");
            let h = h.rsplit(':').next().unwrap_or(h);
            (
                h.parse().expect("host port"),
                c.parse().expect("container port"),
            )
        })
        .collect()
}

/// The port the image's `GROUNDER_ADDR` listens on.
fn image_port() -> u16 {
    let text = std::fs::read_to_string(DOCKERFILE).expect("Dockerfile");
    let at = text
        .find("GROUNDER_ADDR=")
        .expect("the Dockerfile sets GROUNDER_ADDR");
    let addr: String = text[at + "GROUNDER_ADDR=".len()..]
        .chars()
        .take_while(|c| !c.is_whitespace())
        .collect();
    addr.rsplit(':')
        .next()
        .and_then(|p| p.parse().ok())
        .expect("GROUNDER_ADDR host:port")
}

#[test]
fn the_compose_file_describes_replicas_that_can_start() {
    let c = compose();
    let all = services(&c);
    let names: HashSet<&str> = all.keys().filter_map(Value::as_str).collect();
    let reps = replicas(&c);
    assert_eq!(reps.len(), 3, "three grounder replicas: {:?}", reps.keys());

    // Dependencies name services that exist, with conditions compose knows.
    for (name, s) in all {
        let name = name.as_str().unwrap_or("?");
        match s.get("depends_on") {
            None => {}
            Some(Value::Sequence(list)) => {
                for d in list {
                    let d = d.as_str().expect("service name");
                    assert!(names.contains(d), "{name} depends on unknown service {d}");
                }
            }
            Some(Value::Mapping(m)) => {
                for (d, how) in m {
                    let d = d.as_str().expect("service name");
                    assert!(names.contains(d), "{name} depends on unknown service {d}");
                    let cond = how.get("condition").and_then(Value::as_str);
                    assert!(
                        matches!(
                            cond,
                            Some(
                                "service_started"
                                    | "service_healthy"
                                    | "service_completed_successfully"
                            )
                        ),
                        "{name} -> {d}: condition {cond:?}"
                    );
                    if cond == Some("service_healthy") {
                        assert!(
                            all.get(d).and_then(|s| s.get("healthcheck")).is_some(),
                            "{name} waits for {d} to be healthy but {d} has no healthcheck"
                        );
                    }
                }
            }
            Some(other) => panic!("{name}: depends_on {other:?}"),
        }
    }

    // Published host ports do not clash, and a replica's container port is the image's.
    let mut seen = HashSet::new();
    for (name, s) in all {
        for (host, _) in ports(s) {
            assert!(
                seen.insert(host),
                "host port {host} published twice ({name:?})"
            );
        }
    }
    let port = image_port();

    let postgres = all.get("postgres").expect("a postgres service");
    let pg_env = environment(postgres);
    let (mut api, mut workers, mut published_api) = (0, 0, 0);
    for (name, s) in &reps {
        let env = environment(s);
        let cfg = config_of(name, &env);
        let deps = s
            .get("depends_on")
            .expect("replicas depend on the database");
        assert!(
            deps.get("postgres").is_some(),
            "{name} does not wait for postgres"
        );
        // The database: PostgreSQL, on a service of this file, with its credentials.
        let url = url::Url::parse(cfg.database_url.as_deref().expect("database_url"))
            .expect("database URL");
        assert_eq!(url.scheme(), "postgres", "{name}");
        let host = url.host_str().unwrap_or("");
        assert!(
            names.contains(host),
            "{name}: database host {host} is no service"
        );
        assert_eq!(url.username(), var(&pg_env, "POSTGRES_USER"), "{name}");
        assert_eq!(
            url.password(),
            Some(var(&pg_env, "POSTGRES_PASSWORD")),
            "{name}"
        );
        assert_eq!(
            url.path(),
            format!("/{}", var(&pg_env, "POSTGRES_DB")),
            "{name}"
        );
        // The bucket: s3://, on the S3 service of this file, created by a service the
        // replica waits for.
        let storage = url::Url::parse(&cfg.storage).unwrap_or_else(|e| {
            panic!(
                "{name}: storage {:?} is no s3:// URL ({e}): replicas share the bucket",
                cfg.storage
            )
        });
        assert_eq!(storage.scheme(), "s3", "{name}: storage {:?}", cfg.storage);
        let bucket = storage.host_str().expect("bucket");
        let endpoint = url::Url::parse(var(&env, "AWS_ENDPOINT_URL")).expect("endpoint");
        let s3_host = endpoint.host_str().unwrap_or("");
        assert!(
            names.contains(s3_host),
            "{name}: S3 host {s3_host} is no service"
        );
        if endpoint.scheme() == "http" {
            assert_eq!(var(&env, "AWS_ALLOW_HTTP"), "true", "{name}: http endpoint");
        }
        let makes_bucket = all.iter().find(|(_, svc)| {
            let cmd = serde_norway::to_string(svc.get("command").unwrap_or(&Value::Null))
                .unwrap_or_default();
            cmd.contains(&format!("{endpoint}{bucket}"))
        });
        let (maker, _) =
            makes_bucket.unwrap_or_else(|| panic!("{name}: no service creates bucket {bucket}"));
        let maker = maker.as_str().unwrap_or("");
        assert_eq!(
            deps.get(maker)
                .and_then(|d| d.get("condition"))
                .and_then(Value::as_str),
            Some("service_completed_successfully"),
            "{name} does not wait for {maker}"
        );
        // Roles; replicas serving the API publish the image's port.
        api += cfg.role.serves_api() as usize;
        workers += cfg.role.runs_workers() as usize;
        let p = ports(s);
        if cfg.role.serves_api() && !p.is_empty() {
            published_api += 1;
        }
        assert!(
            p.iter().all(|(_, c)| *c == port),
            "{name} publishes a container port other than {port}: {p:?}"
        );
        if !cfg.role.serves_api() {
            assert!(p.is_empty(), "{name} ({:?}) publishes ports", cfg.role);
        }
        // Its own data dir: a volume of its own at the data dir.
        let vols = s
            .get("volumes")
            .and_then(Value::as_sequence)
            .expect("volumes");
        assert!(
            vols.iter()
                .filter_map(Value::as_str)
                .any(|v| v.ends_with(&format!(":{}", cfg.data_dir.display()))),
            "{name}: no volume at {}",
            cfg.data_dir.display()
        );
    }
    assert!(published_api >= 1, "no API replica publishes a port");
    assert!(api >= 1 && workers >= 1, "api {api}, workers {workers}");
    let roles: HashSet<String> = reps
        .iter()
        .map(|(n, s)| format!("{:?}", config_of(n, &environment(s)).role))
        .collect();
    assert_eq!(roles.len(), 3, "one replica of each role: {roles:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_compose_replicas_run_a_job_on_postgres_and_a_bucket() {
    let Some(server) = pg::server() else {
        return;
    };
    let c = compose();
    let moto = crate::storage::Moto::start().await;
    let moto_env = moto.env();
    let moto_endpoint = var(&moto_env, "AWS_ENDPOINT_URL").to_string();
    let test_pg = url::Url::parse(&server).expect("server URL");
    let db = format!("compose_{}", uuid::Uuid::now_v7().simple());
    let dirs: Vec<tempfile::TempDir> = (0..3).map(|_| tempfile::tempdir().unwrap()).collect();

    // The bucket GROUNDER_STORAGE names, made as the compose file's s3-bucket does.
    let reps = replicas(&c);
    let first = reps.values().next().expect("a replica");
    let bucket_url = var(&environment(first), "GROUNDER_STORAGE").to_string();
    let storage = url::Url::parse(&bucket_url).expect("storage URL");
    let bucket = storage.host_str().expect("bucket").to_string();
    let prefix = storage.path().trim_matches('/').to_string();
    moto.create_bucket(&bucket).await;

    let mut procs: Vec<(String, Role, Server)> = Vec::new();
    for (i, (name, s)) in reps.into_iter().enumerate() {
        let mut env = environment(s);
        let role = config_of(&name, &env).role;
        for (k, v) in env.iter_mut() {
            match k.as_str() {
                "GROUNDER_DATABASE_URL" => {
                    let mut u = url::Url::parse(v).expect("database URL");
                    if i == 0 {
                        let (user, pass) = (u.username(), u.password().unwrap_or(""));
                        pg::run_sql(
                            &server,
                            &format!("CREATE ROLE {user} LOGIN PASSWORD '{pass}'"),
                        );
                        pg::run_sql(&server, &format!("CREATE DATABASE {db} OWNER {user}"));
                    }
                    u.set_host(test_pg.host_str()).expect("host");
                    u.set_port(test_pg.port()).expect("port");
                    u.set_path(&db);
                    *v = u.to_string();
                }
                "GROUNDER_DATA_DIR" => *v = dirs[i].path().display().to_string(),
                "AWS_ENDPOINT_URL" => *v = moto_endpoint.clone(),
                _ => {}
            }
        }
        let env: Vec<(&str, &str)> = env.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
        // start_server adds only what compose leaves to the operator: the pipeline (a
        // test pipeline stands in for the VLM), no detector, and a free port.
        procs.push((name, role, start_server(dirs[i].path(), &env)));
    }
    let (_, _, api) = procs
        .iter()
        .find(|(_, r, _)| *r == Role::Api)
        .expect("an api replica");
    let http = client();
    let sid = upload_tiny_scene_to(&http, &api.base, 3).await;
    let id = submit_job(&http, &api.base, &sid, "the chair").await;
    let t = Instant::now();
    let job = loop {
        let j: Json = get_json_at(&http, &format!("{}/v1/jobs/{id}", api.base)).await;
        if !matches!(j["status"].as_str(), Some("queued" | "running")) {
            break j;
        }
        assert!(
            t.elapsed() < Duration::from_secs(30),
            "job never ended: {j}"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    assert_eq!(job["status"], "succeeded", "{job}");
    // The api replica ran nothing: a worker replica fetched the scene from the bucket.
    let listed = http
        .get(format!(
            "{moto_endpoint}/{bucket}?list-type=2&prefix={prefix}/scenes/{sid}/"
        ))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(
        listed.contains(&format!("{prefix}/scenes/{sid}/color/0.jpg")),
        "the scene is not in the bucket: {listed}"
    );
    let fetched = procs
        .iter()
        .zip(&dirs)
        .filter(|((_, r, _), d)| *r != Role::Api && d.path().join("scenes").join(&sid).is_dir())
        .count();
    assert!(fetched >= 1, "no worker replica fetched the scene");
}
