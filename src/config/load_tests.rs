//! Tests of the layered loader, with a stand-in environment.

use super::*;

fn env(pairs: &[(&str, &str)]) -> Vec<(String, String)> {
    pairs
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
}

fn load(file: Option<&str>, vars: &[(&str, &str)], flags: Flags) -> Result<Config, ConfigError> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("grounder.toml");
    if let Some(text) = file {
        std::fs::write(&path, text).unwrap();
    }
    resolve(&Sources {
        file: file.map(|_| path.as_path()),
        env: &env(vars),
        flags,
    })
}

fn flag_addr(a: &str) -> Flags {
    Flags {
        addr: Some(a.into()),
        ..Flags::default()
    }
}

#[test]
fn file_then_environment_then_flags() {
    let file = Some("addr = \"10.0.0.1:1\"\nworkers = 3\nmax_attempts = 5\n");
    let env_addr = [("GROUNDER_ADDR", "10.0.0.2:2"), ("GROUNDER_WORKERS", "4")];
    let c = load(file, &[], Flags::default()).unwrap();
    assert_eq!(
        (c.addr.as_str(), c.workers, c.max_attempts),
        ("10.0.0.1:1", 3, 5)
    );
    let c = load(file, &env_addr, Flags::default()).unwrap();
    assert_eq!(
        (c.addr.as_str(), c.workers, c.max_attempts),
        ("10.0.0.2:2", 4, 5)
    );
    let c = load(file, &env_addr, flag_addr("10.0.0.3:3")).unwrap();
    assert_eq!((c.addr.as_str(), c.workers), ("10.0.0.3:3", 4));
    let c = load(None, &[], Flags::default()).unwrap();
    assert_eq!((c.addr.as_str(), c.workers), ("127.0.0.1:8080", 2));
}

#[test]
fn nested_keys_come_from_the_environment() {
    let c = load(
        Some("[agent.geometry]\nchamfer_threshold = 0.7\nmax_views = 4\n"),
        &[
            ("GROUNDER_AGENT__GEOMETRY__CHAMFER_THRESHOLD", "0.2"),
            ("GROUNDER_AGENT__GEOMETRY__SUPPORT__ENABLED", "false"),
            ("GROUNDER_VLM__TIMEOUT_MS", "1234"),
        ],
        Flags::default(),
    )
    .unwrap();
    let g = &c.agent.geometry;
    assert_eq!((g.chamfer_threshold, g.max_views), (0.2, 4));
    assert!(!g.support.enabled);
    assert_eq!(c.vlm.map(|v| v.timeout_ms), Some(1234));
}

#[test]
fn older_variable_names_keep_working() {
    let c = load(
        None,
        &[
            ("GROUNDER_VLM_BASE_URL", "http://127.0.0.1:9/v1"),
            ("GROUNDER_VLM_MODEL", "m"),
            ("OPENAI_API_KEY", "sk-openai"),
            ("GROUNDER_DETECTOR", "oracle"),
            ("GROUNDER_ALLOW_ANONYMOUS", "1"),
            ("GROUNDER_VISION_CONCURRENCY", "3"),
            ("GROUNDER_MODEL_DIR", "/m"),
            ("GROUNDER_LOG", "debug"),
            ("GROUNDER_CONFIG", "/nowhere.toml"),
        ],
        Flags::default(),
    )
    .unwrap();
    let v = c.vlm.clone().unwrap();
    assert_eq!(
        (v.base_url.as_str(), v.model.as_str()),
        ("http://127.0.0.1:9/v1", "m")
    );
    assert_eq!(v.api_key.expose(), "sk-openai");
    assert_eq!(c.detector, "oracle");
    assert!(c.allow_anonymous);
    assert_eq!(c.vision().concurrency, 3);
    assert_eq!(c.vision().model_dir, std::path::PathBuf::from("/m"));
    // The service's own name for the key wins over OPENAI_API_KEY.
    let c = load(
        None,
        &[("OPENAI_API_KEY", "sk-a"), ("GROUNDER_VLM_API_KEY", "sk-b")],
        Flags::default(),
    )
    .unwrap();
    assert_eq!(c.vlm.unwrap().api_key.expose(), "sk-b");
}

#[test]
fn a_bad_value_names_the_key_the_variable_and_the_expectation() {
    let e = load(
        None,
        &[("GROUNDER_AGENT__GEOMETRY__CHAMFER_THRESHOLD", "big")],
        Flags::default(),
    )
    .unwrap_err()
    .0;
    assert!(e.contains("`agent.geometry.chamfer_threshold`"), "{e}");
    assert!(
        e.contains("environment variable GROUNDER_AGENT__GEOMETRY__CHAMFER_THRESHOLD"),
        "{e}"
    );
    assert!(e.contains("expected") && e.contains("big"), "{e}");
    assert!(!e.contains('\n'), "{e}");
    let e = load(Some("workers = \"many\"\n"), &[], Flags::default())
        .unwrap_err()
        .0;
    assert!(
        e.contains("`workers`") && e.contains("configuration file"),
        "{e}"
    );
    let e = load(None, &[("GROUNDER_METHOD", "papr")], Flags::default())
        .unwrap_err()
        .0;
    assert!(e.contains("`method`") && e.contains("paper"), "{e}");
}

#[test]
fn a_misspelt_variable_is_refused_naming_it() {
    for (var, key) in [
        (
            "GROUNDER_AGENT__GEOMETRY__CHAMFR_THRESHOLD",
            "chamfr_threshold",
        ),
        ("GROUNDER_WORKRS", "workrs"),
        ("GROUNDER_VLM__MODLE", "modle"),
        ("GROUNDER_AGENTS__IMAGE_LIMIT", "agents"),
    ] {
        let e = load(None, &[(var, "2")], Flags::default()).unwrap_err().0;
        assert!(e.contains(var) && e.contains(key), "{var}: {e}");
    }
    // Variables of other programs are none of our business.
    assert!(load(
        None,
        &[("GROUNDERX", "1"), ("PATH", "/bin")],
        Flags::default()
    )
    .is_ok());
}

#[test]
fn a_missing_file_is_an_error() {
    let e = resolve(&Sources {
        file: Some(std::path::Path::new("/nonexistent/grounder.toml")),
        env: &[],
        flags: Flags::default(),
    })
    .unwrap_err()
    .0;
    assert!(e.contains("/nonexistent/grounder.toml"), "{e}");
}

#[test]
fn the_paper_preset_gives_the_paper_box_settings_and_keys_still_override_it() {
    let c = load(Some("method = \"paper\"\n"), &[], Flags::default()).unwrap();
    let g = &c.agent.geometry;
    assert_eq!(c.method, Method::Paper);
    assert_eq!(g.chamfer_threshold, 0.1);
    assert_eq!(g.cluster_voxel, 0.0);
    assert!(!g.support.enabled && !g.depth_fill.enabled && !g.layout.enabled);
    assert!(!g.consensus.mask_votes && !g.consensus.free_space);
    assert_eq!((g.erode_kernel, g.keep_components, g.max_views), (15, 2, 7));
    assert_eq!((g.sor_neighbors, g.sor_std_ratio), (5, 1.0));
    // A setting given alongside the preset wins, from the file or the environment.
    let c = load(
        Some("method = \"paper\"\n[agent.geometry]\nchamfer_threshold = 0.3\n"),
        &[("GROUNDER_AGENT__GEOMETRY__SUPPORT__ENABLED", "true")],
        Flags::default(),
    )
    .unwrap();
    assert_eq!(c.agent.geometry.chamfer_threshold, 0.3);
    assert!(c.agent.geometry.support.enabled);
    assert!(!c.agent.geometry.layout.enabled);
    // The preset from the environment; the default is ours.
    let c = load(None, &[("GROUNDER_METHOD", "paper")], Flags::default()).unwrap();
    assert_eq!(c.agent.geometry.chamfer_threshold, 0.1);
    let c = load(None, &[], Flags::default()).unwrap();
    assert_eq!(c.method, Method::Grounder);
    assert_eq!(c.agent.geometry.chamfer_threshold, 0.5);
    assert!(c.agent.geometry.support.enabled);
}
