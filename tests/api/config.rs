//! The layered configuration seen from outside: `grounder config`, start-up refusals with
//! exit code 2, and a nested key from the environment changing what the service does.

use crate::helpers::{test_config, TestApp};
use grounder::config::load::{resolve, Flags, Sources};
use grounder::store::Store;
use std::process::{Command, Output};
use std::time::Duration;

const BIN: &str = env!("CARGO_BIN_EXE_grounder");

/// Run the binary with only the given variables in its environment.
fn run(args: &[&str], vars: &[(&str, &str)]) -> Output {
    let mut c = Command::new(BIN);
    c.args(args).env_clear();
    for (k, v) in vars {
        c.env(k, v);
    }
    c.output().expect("run grounder")
}

fn value_of(toml_text: &str, key: &str) -> Option<String> {
    toml_text
        .lines()
        .find_map(|l| l.strip_prefix(&format!("{key} = ")).map(str::to_string))
}

#[test]
fn grounder_config_prints_file_environment_and_flag_layers_in_order() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("g.toml");
    std::fs::write(
        &file,
        "addr = \"10.0.0.1:1\"\nworkers = 3\nmax_attempts = 7\n[vlm]\napi_key = \"sk-from-file\"\n",
    )
    .unwrap();
    let f = file.to_str().unwrap();
    let env = [("GROUNDER_ADDR", "10.0.0.2:2"), ("GROUNDER_WORKERS", "5")];
    let o = run(&["config", "--config", f, "--addr", "10.0.0.3:3"], &env);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8(o.stdout).unwrap();
    assert_eq!(value_of(&text, "addr").as_deref(), Some("\"10.0.0.3:3\""));
    assert_eq!(value_of(&text, "workers").as_deref(), Some("5"));
    assert_eq!(value_of(&text, "max_attempts").as_deref(), Some("7"));
    assert!(!text.contains("sk-from-file"), "{text}");
    assert!(text.contains("api_key = \"***\""), "{text}");
    // Without the flag the environment wins over the file; GROUNDER_CONFIG names the file.
    let o = run(&["config"], &[env[0], env[1], ("GROUNDER_CONFIG", f)]);
    let text = String::from_utf8(o.stdout).unwrap();
    assert_eq!(value_of(&text, "addr").as_deref(), Some("\"10.0.0.2:2\""));
    assert_eq!(value_of(&text, "max_attempts").as_deref(), Some("7"));
}

#[test]
fn a_bad_value_or_a_misspelt_variable_stops_start_up_with_code_2_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    for (var, value, key) in [
        (
            "GROUNDER_AGENT__GEOMETRY__CHAMFER_THRESHOLD",
            "wide",
            "agent.geometry.chamfer_threshold",
        ),
        (
            "GROUNDER_AGENT__GEOMETRY__CHAMFER_TRESHOLD",
            "0.2",
            "agent.geometry.chamfer_treshold",
        ),
        ("GROUNDER_WORKERS", "-1", "workers"),
    ] {
        for cmd in [&["serve", "--data-dir", d][..], &["config"][..]] {
            let o = run(cmd, &[(var, value)]);
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{cmd:?} {var}: {err}");
            assert_eq!(err.trim().lines().count(), 1, "{err}");
            assert!(err.contains(key) && err.contains(var), "{err}");
        }
    }
}

/// Candidates cached for the scene once it is indexed (empty when none were computed).
async fn candidates_after_upload(vars: &[(&str, &str)]) -> usize {
    let dir = tempfile::tempdir().unwrap();
    let env: Vec<(String, String)> = vars
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    let loaded = resolve(&Sources {
        file: None,
        env: &env,
        flags: Flags::default(),
    })
    .expect("valid configuration");
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.agent = loaded.agent;
    let key = cfg.agent.candidates.cache_key(&cfg.agent.geometry.layout);
    cfg.detector = "oracle".into();
    let app = TestApp::spawn_with(cfg).await;
    let (tar, _) = crate::agent_fixture::scene_tar();
    let r = app
        .upload(std::fs::read(tar).unwrap(), "application/x-tar")
        .await;
    assert_eq!(r.status().as_u16(), 201);
    let v: serde_json::Value = r.json().await.unwrap();
    let id = v["id"].as_str().unwrap().to_string();
    if let Err(s) = app.wait_scene(&id, "ready", Duration::from_secs(60)).await {
        panic!("not indexed: {s}");
    }
    let store = Store::open(dir.path()).await.unwrap();
    let cands = store.detections(&id, &key).await.unwrap();
    cands.values().map(Vec::len).sum()
}

#[tokio::test]
async fn a_nested_key_from_the_environment_changes_what_the_service_does() {
    let on = candidates_after_upload(&[]).await;
    assert!(on > 0, "the default configuration computes candidates");
    let off = candidates_after_upload(&[("GROUNDER_AGENT__CANDIDATES__ENABLED", "false")]).await;
    assert_eq!(
        off, 0,
        "GROUNDER_AGENT__CANDIDATES__ENABLED=false was ignored"
    );
}

/// Tables whose entries are data (class names), documented as one key.
const MAP_KEYS: &[&str] = &["agent.geometry.layout.class_depth"];

fn leaf_keys(prefix: &str, v: &toml::Value, out: &mut Vec<String>) {
    match v {
        toml::Value::Table(t) if !MAP_KEYS.contains(&prefix) => {
            for (k, v) in t {
                let path = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                leaf_keys(&path, v, out);
            }
        }
        _ => out.push(prefix.to_string()),
    }
}

/// Every key `grounder config` prints, set or not.
fn effective_keys() -> Vec<String> {
    let o = run(&["config"], &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8(o.stdout).unwrap();
    let value: toml::Value = toml::from_str(&text).unwrap();
    let mut keys = Vec::new();
    leaf_keys("", &value, &mut keys);
    // Keys left unset are printed as comments: "# model_dir is not set: ...".
    keys.extend(text.lines().filter_map(|l| {
        l.strip_prefix("# ")
            .and_then(|r| r.split_once(" is not set"))
            .map(|(k, _)| k.to_string())
    }));
    keys
}

#[test]
fn every_key_of_the_effective_configuration_is_in_the_reference() {
    let keys = effective_keys();
    assert!(keys.len() > 100, "too few keys walked: {}", keys.len());
    let doc_path = concat!(env!("CARGO_MANIFEST_DIR"), "/docs/configuration.md");
    let doc = std::fs::read_to_string(doc_path).unwrap();
    let missing: Vec<_> = keys
        .iter()
        .filter(|k| !doc.contains(&format!("| `{k}` |")))
        .collect();
    assert!(
        missing.is_empty(),
        "keys missing from docs/configuration.md: {missing:?}"
    );
}

#[test]
fn every_key_the_readme_names_is_a_key_of_the_configuration() {
    let keys = effective_keys();
    let readme =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md")).unwrap();
    // The first cell of each row of the README's configuration table.
    let section = readme
        .split("\n| key | default | what |")
        .nth(1)
        .expect("the README has a configuration table");
    let named: Vec<String> = section
        .lines()
        .skip(2)
        .take_while(|l| l.starts_with('|'))
        .filter_map(|l| l.split('|').nth(1))
        .flat_map(|cell| {
            cell.split(',')
                .map(|k| k.trim().trim_matches('`').to_string())
                .collect::<Vec<_>>()
        })
        .collect();
    assert!(named.len() >= 10, "too few README keys read: {named:?}");
    let unknown: Vec<_> = named.iter().filter(|k| !keys.contains(k)).collect();
    assert!(
        unknown.is_empty(),
        "README names keys the service does not have: {unknown:?}"
    );
}
