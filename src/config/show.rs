//! `grounder config`: the effective configuration as TOML, secrets hidden.

use super::Config;

/// What a secret is printed as.
pub const HIDDEN: &str = "***";

/// Keys that may be left unset; printed as comments so that every key is listed.
pub const OPTIONAL_KEYS: &[(&str, &str)] = &[
    ("database_url", "sqlite:// grounder.db in data_dir"),
    ("model_dir", "./models"),
    ("ort_dylib", "ORT_DYLIB_PATH, else ./.ort/"),
    ("prompts_dir", "the built-in prompts"),
];

/// The configuration as TOML, every key with its value; the VLM API key as `"***"` when set.
pub fn to_toml(cfg: &Config) -> anyhow::Result<String> {
    let mut cfg = cfg.clone();
    let key_set = cfg.vlm.as_ref().is_some_and(|v| !v.api_key.is_empty());
    if cfg.vlm.is_none() {
        cfg.vlm = Some(crate::vlm::VlmConfig::default());
    }
    if let Some(url) = &cfg.database_url {
        cfg.database_url = Some(crate::store::redact(url));
    }
    let mut value = toml::Value::try_from(&cfg)?;
    tidy_floats(&mut value);
    if let Some(vlm) = value.get_mut("vlm").and_then(|v| v.as_table_mut()) {
        let shown = if key_set { HIDDEN } else { "" };
        vlm.insert("api_key".into(), toml::Value::String(shown.into()));
    }
    let mut out = String::new();
    for (key, unset) in OPTIONAL_KEYS {
        if value.get(key).is_none() {
            out.push_str(&format!("# {key} is not set: {unset}\n"));
        }
    }
    out.push_str(&toml::to_string(&value)?);
    Ok(out)
}

/// Numbers that are `f32` settings print as written (0.2, not 0.20000000298023224).
fn tidy_floats(v: &mut toml::Value) {
    match v {
        toml::Value::Float(x) => {
            let narrow = *x as f32;
            if f64::from(narrow) == *x {
                if let Ok(short) = narrow.to_string().parse::<f64>() {
                    *x = short;
                }
            }
        }
        toml::Value::Array(a) => a.iter_mut().for_each(tidy_floats),
        toml::Value::Table(t) => t.iter_mut().for_each(|(_, v)| tidy_floats(v)),
        _ => {}
    }
}

/// `grounder config`: print the configuration `serve` would use with these arguments.
pub fn run(args: &super::ServeArgs) -> anyhow::Result<()> {
    let cfg = Config::load(args)?;
    print!("{}", to_toml(&cfg)?);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_api_key_is_hidden_and_every_table_is_printed() {
        let cfg = Config {
            vlm: Some(crate::vlm::VlmConfig {
                api_key: crate::vlm::ApiKey::new("sk-very-secret"),
                ..Default::default()
            }),
            ..Config::default()
        };
        let text = to_toml(&cfg).unwrap();
        assert!(!text.contains("sk-very-secret"), "{text}");
        assert!(text.contains("api_key = \"***\""), "{text}");
        for table in ["[agent.geometry.support]", "[vlm]", "[agent.candidates]"] {
            assert!(text.contains(table), "{table} missing: {text}");
        }
        assert!(text.contains("# prompts_dir is not set"), "{text}");
        assert!(text.contains("preselect_score = 0.2\n"), "{text}");
        // What is printed reads back as the same configuration (once the key is given).
        let back: Config = toml::from_str(&text.replace("\"***\"", "\"sk-very-secret\"")).unwrap();
        assert_eq!(
            toml::to_string(&back).unwrap(),
            toml::to_string(&cfg).unwrap()
        );
    }
}
