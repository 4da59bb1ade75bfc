//! Loading [`Config`] in layers with figment: built-in defaults (with the `method` preset),
//! the TOML file, the environment, then command-line flags; later layers win.
//!
//! Every key can be set from the environment as `GROUNDER_` + its path in capitals with `__`
//! between levels (`GROUNDER_AGENT__GEOMETRY__CHAMFER_THRESHOLD=0.2`). A few older names
//! keep working ([`LEGACY_VARS`]). Any other `GROUNDER_` variable that is not one of the
//! [`NON_CONFIG_VARS`] is read as a key path, so a misspelt one is refused like an unknown
//! key in the file.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use figment::providers::{Format, Serialized, Toml};
use figment::value::{Dict, Map, Value};
use figment::{Figment, Metadata, Profile, Provider};

use super::{Config, Method};

/// Prefix of every configuration variable.
pub const PREFIX: &str = "GROUNDER_";

/// `GROUNDER_` variables that are not configuration keys (read by other parts: the file's
/// location, logging, the command-line client, tests and development helpers).
pub const NON_CONFIG_VARS: &[&str] = &[
    "GROUNDER_CONFIG",
    "GROUNDER_LOG",
    "GROUNDER_KEY",
    "GROUNDER_URL",
    "GROUNDER_BIN",
    "GROUNDER_WRITE_DOCS",
    "GROUNDER_VIEWER_DIR",
];

/// Older variable names and the key each sets. `OPENAI_API_KEY` is used only when no
/// `GROUNDER_` variable sets the VLM key.
pub const LEGACY_VARS: &[(&str, &str)] = &[
    ("GROUNDER_VLM_BASE_URL", "vlm.base_url"),
    ("GROUNDER_VLM_MODEL", "vlm.model"),
    ("GROUNDER_VLM_API_KEY", "vlm.api_key"),
];

/// A configuration that cannot be used; its message is one line naming the key, where
/// the value came from and what was expected. The CLI exits with code 2 on it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConfigError(pub String);

impl std::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ConfigError {}

/// What the command line says (the highest layer).
#[derive(Debug, Clone, Default)]
pub struct Flags {
    pub addr: Option<String>,
    pub data_dir: Option<PathBuf>,
    pub role: Option<super::Role>,
    pub allow_anonymous: bool,
}

/// The environment layer: key paths read from variables, and which variable set each.
struct EnvLayer {
    dict: Dict,
    /// Dotted key path -> variable name.
    names: BTreeMap<String, String>,
}

impl EnvLayer {
    fn new(vars: &[(String, String)]) -> Self {
        let mut layer = EnvLayer {
            dict: Dict::new(),
            names: BTreeMap::new(),
        };
        let mut key_from_grounder_var = false;
        for (name, value) in vars {
            let Some(rest) = name.strip_prefix(PREFIX) else {
                continue;
            };
            if NON_CONFIG_VARS.contains(&name.as_str()) || rest.is_empty() {
                continue;
            }
            if let Some((_, path)) = LEGACY_VARS.iter().find(|(n, _)| n == name) {
                // Older names held plain strings and an empty value meant "not set".
                if !value.trim().is_empty() {
                    key_from_grounder_var |= *path == "vlm.api_key";
                    layer.insert(path, Value::from(value.trim().to_string()), name);
                }
                continue;
            }
            let path = rest.to_ascii_lowercase().replace("__", ".");
            key_from_grounder_var |= path == "vlm.api_key";
            let parsed = if path == "vlm.api_key" {
                Value::from(value.clone())
            } else {
                value.parse().unwrap_or_else(|_| Value::from(value.clone()))
            };
            layer.insert(&path, parsed, name);
        }
        if !key_from_grounder_var {
            if let Some((name, v)) = vars.iter().find(|(n, _)| n == "OPENAI_API_KEY") {
                if !v.trim().is_empty() {
                    layer.insert("vlm.api_key", Value::from(v.trim().to_string()), name);
                }
            }
        }
        layer
    }

    fn insert(&mut self, path: &str, value: Value, name: &str) {
        if let Some(d) = figment::util::nest(path, value).into_dict() {
            self.dict = std::mem::take(&mut self.dict).merge(d);
        }
        self.names.insert(path.to_string(), name.to_string());
    }
}

/// Merges dictionaries key by key (`b` wins).
trait MergeDict {
    fn merge(self, other: Dict) -> Dict;
}

impl MergeDict for Dict {
    fn merge(mut self, other: Dict) -> Dict {
        for (k, v) in other {
            let merged = match (self.remove(&k), v) {
                (Some(Value::Dict(_, a)), Value::Dict(tag, b)) => Value::Dict(tag, a.merge(b)),
                (_, v) => v,
            };
            self.insert(k, merged);
        }
        self
    }
}

impl Provider for EnvLayer {
    fn metadata(&self) -> Metadata {
        Metadata::named("environment")
    }

    fn data(&self) -> Result<Map<Profile, Dict>, figment::Error> {
        Ok(Profile::Default.collect(self.dict.clone()))
    }
}

/// Everything the configuration is made from.
pub struct Sources<'a> {
    pub file: Option<&'a Path>,
    /// The process environment (or a test's stand-in).
    pub env: &'a [(String, String)],
    pub flags: Flags,
}

impl Sources<'_> {
    fn flags_dict(&self) -> Dict {
        let mut d = Dict::new();
        if let Some(a) = &self.flags.addr {
            d.insert("addr".into(), Value::from(a.clone()));
        }
        if let Some(p) = &self.flags.data_dir {
            d.insert("data_dir".into(), Value::from(p.display().to_string()));
        }
        if let Some(r) = self.flags.role {
            let name = match r {
                super::Role::All => "all",
                super::Role::Api => "api",
                super::Role::Worker => "worker",
            };
            d.insert("role".into(), Value::from(name));
        }
        if self.flags.allow_anonymous {
            d.insert("allow_anonymous".into(), Value::from(true));
        }
        d
    }

    /// The file as a dictionary (to say whether it set a key), or why it cannot be read.
    fn file_dict(&self) -> Result<Option<Dict>, ConfigError> {
        let Some(path) = self.file else {
            return Ok(None);
        };
        let text = std::fs::read_to_string(path).map_err(|e| {
            ConfigError(format!(
                "configuration file {}: cannot be read: {}",
                path.display(),
                e.kind()
            ))
        })?;
        let dict = Toml::string(&text)
            .data()
            .map_err(|e| ConfigError(format!("configuration file {}: {e}", path.display())))?
            .remove(&Profile::Default)
            .unwrap_or_default();
        Ok(Some(dict))
    }
}

/// Resolve the configuration from its layers.
pub fn resolve(src: &Sources<'_>) -> Result<Config, ConfigError> {
    let env = EnvLayer::new(src.env);
    let file = src.file_dict()?;
    let flags = src.flags_dict();
    let mut upper = Figment::new();
    if let Some(path) = src.file {
        upper = upper.merge(Toml::file_exact(path));
    }
    let upper = upper.merge(env).merge(Serialized::defaults(flags.clone()));
    let explain = |e: figment::Error| explain(e, src, &file, &flags);
    // The preset is chosen first: it decides the defaults the other layers override.
    let method = match upper.find_value("method") {
        Ok(_) => upper.extract_inner::<Method>("method").map_err(explain)?,
        Err(_) => Method::default(),
    };
    let mut defaults = Config {
        method,
        vlm: Some(crate::vlm::VlmConfig::default()),
        ..Config::default()
    };
    method.apply(&mut defaults.agent);
    let mut cfg: Config = Figment::from(Serialized::defaults(defaults))
        .merge(upper)
        .extract_lossy()
        .map_err(explain)?;
    if let Some(v) = cfg.vlm.as_mut() {
        if v.base_url.contains(".openai.azure.com") {
            v.auth_style = crate::vlm::AuthStyle::ApiKeyHeader;
        }
    }
    Ok(cfg)
}

/// The process environment, read once.
pub fn process_env() -> Vec<(String, String)> {
    std::env::vars_os()
        .filter_map(|(k, v)| Some((k.into_string().ok()?, v.into_string().ok()?)))
        .collect()
}

fn has_path(dict: &Dict, path: &[String]) -> bool {
    let mut cur = dict;
    for (i, k) in path.iter().enumerate() {
        match cur.get(k) {
            Some(Value::Dict(_, d)) => cur = d,
            Some(_) => return i + 1 == path.len(),
            None => return false,
        }
    }
    true
}

/// One line: the key, its source and what was expected.
fn explain(e: figment::Error, src: &Sources<'_>, file: &Option<Dict>, flags: &Dict) -> ConfigError {
    use figment::error::Kind;
    let mut path = e.path.clone();
    if let Kind::UnknownField(field, _) = &e.kind {
        if path.last() != Some(field) {
            path.push(field.clone());
        }
    }
    let key = path.join(".");
    let env = EnvLayer::new(src.env);
    let source = if has_path(flags, &path) {
        "command-line flag".to_string()
    } else if let Some(name) = env.names.get(&key).or_else(|| {
        let under = format!("{key}.");
        env.names
            .iter()
            .find(|(k, _)| k.starts_with(&under))
            .map(|(_, n)| n)
    }) {
        format!("environment variable {name}")
    } else if let (Some(f), Some(p)) = (file, src.file) {
        if has_path(f, &path) {
            format!("configuration file {}", p.display())
        } else {
            "built-in default".to_string()
        }
    } else {
        "built-in default".to_string()
    };
    let what = match &e.kind {
        Kind::UnknownField(field, expected) => {
            let known = if expected.is_empty() {
                String::new()
            } else {
                format!(" (known here: {})", expected.join(", "))
            };
            format!("unknown key {field:?}{known}")
        }
        Kind::InvalidType(actual, expected) => format!("expected {expected}, found {actual}"),
        Kind::InvalidValue(actual, expected) => format!("expected {expected}, found {actual}"),
        Kind::UnknownVariant(v, expected) => {
            format!(
                "unknown value {v:?}, expected one of {}",
                expected.join(", ")
            )
        }
        other => other.to_string(),
    };
    if key.is_empty() {
        ConfigError(format!("configuration ({source}): {what}"))
    } else {
        ConfigError(format!("configuration key `{key}` ({source}): {what}"))
    }
}

#[cfg(test)]
#[path = "load_tests.rs"]
mod tests;
