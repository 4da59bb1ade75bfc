//! Service configuration: flags and environment variables, with an optional TOML file
//! for everything else. Precedence: flag > environment > file > default.

use serde::Deserialize;
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, clap::Args)]
pub struct ServeArgs {
    /// Address to listen on.
    #[arg(long, env = "GROUNDER_ADDR")]
    pub addr: Option<String>,
    /// Directory holding the database and scene files.
    #[arg(long, env = "GROUNDER_DATA_DIR")]
    pub data_dir: Option<PathBuf>,
    /// Optional TOML configuration file (keys as in `Config`).
    #[arg(long, env = "GROUNDER_CONFIG")]
    pub config: Option<PathBuf>,
    /// Serve without API keys on a non-loopback address (anyone reaching the port sees
    /// everything). Also GROUNDER_ALLOW_ANONYMOUS=1.
    #[arg(long)]
    pub allow_anonymous: bool,
}

/// Everything the service can be configured with.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    pub addr: String,
    pub data_dir: PathBuf,
    /// Largest accepted upload body in bytes (413 above).
    pub max_upload_bytes: u64,
    /// Largest total unpacked size of an archive in bytes.
    pub max_unpacked_bytes: u64,
    /// Most entries an archive may hold.
    pub max_archive_files: u64,
    /// Most pixels one uploaded image (colour, depth, instance mask) may declare; checked
    /// from the image's header before decoding (413 `image_too_large` above).
    pub max_image_pixels: u64,
    /// Concurrent grounding jobs.
    pub workers: usize,
    /// Attempts before a job that keeps dying with the process is failed.
    pub max_attempts: i64,
    /// Indexing attempts before a scene whose indexing keeps dying with the process (out
    /// of memory, a crashing model) ends `failed` instead of being resumed again.
    pub max_index_attempts: i64,
    /// The pipeline the workers run: "vlm" (the method) or "test:delay_ms=N" (testing).
    pub pipeline: String,
    /// Detector used to index uploaded scenes ("none" to skip indexing).
    pub detector: String,
    /// Segmenter used by the pipeline.
    pub segmenter: String,
    /// Folder with the vendored models (default: ./models, or GROUNDER_MODEL_DIR).
    pub model_dir: Option<PathBuf>,
    /// Path of libonnxruntime (else ORT_DYLIB_PATH, else ./.ort/).
    pub ort_dylib: Option<PathBuf>,
    /// Folder whose prompt files override the built-in ones (GROUNDER_PROMPTS_DIR).
    pub prompts_dir: Option<PathBuf>,
    /// Answer without API keys (when none exist) even on a non-loopback address.
    pub allow_anonymous: bool,
    /// Accept webhook URLs on loopback and private addresses (tests, closed networks).
    pub webhook_allow_private: bool,
    /// Fault injection for the crash tests: pause this long between the steps of a scene
    /// import or delete (env `GROUNDER_TEST_STEP_PAUSE_MS`; 0, the default, in service).
    #[serde(skip)]
    pub test_step_pause_ms: u64,
    /// Method settings (`[agent]` table).
    pub agent: crate::agent::AgentParams,
    /// VLM client settings used instead of `VlmConfig::from_env()` when set (tests and
    /// embedding; not read from the file).
    #[serde(skip)]
    pub vlm: Option<crate::vlm::VlmConfig>,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            addr: "127.0.0.1:8080".into(),
            data_dir: PathBuf::from("./data"),
            max_upload_bytes: 2 << 30,
            max_unpacked_bytes: 8 << 30,
            max_archive_files: 200_000,
            max_image_pixels: crate::scene::import::DEFAULT_MAX_IMAGE_PIXELS,
            workers: 2,
            max_attempts: 3,
            max_index_attempts: 3,
            pipeline: "vlm".into(),
            detector: "centernet".into(),
            segmenter: "depth".into(),
            model_dir: None,
            ort_dylib: None,
            prompts_dir: None,
            allow_anonymous: false,
            webhook_allow_private: false,
            test_step_pause_ms: 0,
            agent: crate::agent::AgentParams::default(),
            vlm: None,
        }
    }
}

impl Config {
    /// Vision settings derived from this configuration.
    pub fn vision(&self) -> crate::vision::VisionConfig {
        let mut v = crate::vision::VisionConfig::from_env();
        v.detector = self.detector.clone();
        v.segmenter = self.segmenter.clone();
        if let Some(d) = &self.model_dir {
            v.model_dir = d.clone();
        }
        if self.ort_dylib.is_some() {
            v.ort_dylib = self.ort_dylib.clone();
        }
        v
    }

    /// Resolve the configuration from the command line, environment and file.
    pub fn load(args: &ServeArgs) -> anyhow::Result<Self> {
        let mut cfg = match &args.config {
            Some(path) => Self::from_file(path)?,
            None => Self::default(),
        };
        if let Some(a) = &args.addr {
            cfg.addr = a.clone();
        }
        if let Some(d) = &args.data_dir {
            cfg.data_dir = d.clone();
        }
        cfg.apply_env()?;
        if args.allow_anonymous {
            cfg.allow_anonymous = true;
        }
        Ok(cfg)
    }

    fn from_file(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow::anyhow!("cannot read config file {}: {e}", path.display()))?;
        toml::from_str(&text)
            .map_err(|e| anyhow::anyhow!("invalid config file {}: {e}", path.display()))
    }

    fn apply_env(&mut self) -> anyhow::Result<()> {
        fn num<T: std::str::FromStr>(key: &str, into: &mut T) -> anyhow::Result<()> {
            if let Ok(v) = std::env::var(key) {
                *into = v
                    .parse()
                    .map_err(|_| anyhow::anyhow!("{key}={v:?} is not a valid number"))?;
            }
            Ok(())
        }
        if let Ok(v) = std::env::var("GROUNDER_PIPELINE") {
            self.pipeline = v;
        }
        if let Ok(v) = std::env::var("GROUNDER_DETECTOR") {
            self.detector = v;
        }
        if let Ok(v) = std::env::var("GROUNDER_SEGMENTER") {
            self.segmenter = v;
        }
        if let Ok(v) = std::env::var("GROUNDER_PROMPTS_DIR") {
            self.prompts_dir = Some(PathBuf::from(v));
        }
        if let Ok(v) = std::env::var("GROUNDER_MODEL_DIR") {
            self.model_dir = Some(PathBuf::from(v));
        }
        fn flag(key: &str, into: &mut bool) -> anyhow::Result<()> {
            if let Ok(v) = std::env::var(key) {
                *into = match v.trim().to_ascii_lowercase().as_str() {
                    "1" | "true" | "yes" | "on" => true,
                    "0" | "false" | "no" | "off" | "" => false,
                    _ => anyhow::bail!("{key}={v:?} is not 1 or 0"),
                };
            }
            Ok(())
        }
        flag("GROUNDER_ALLOW_ANONYMOUS", &mut self.allow_anonymous)?;
        flag(
            "GROUNDER_WEBHOOK_ALLOW_PRIVATE",
            &mut self.webhook_allow_private,
        )?;
        num("GROUNDER_WORKERS", &mut self.workers)?;
        num("GROUNDER_MAX_UPLOAD_BYTES", &mut self.max_upload_bytes)?;
        num("GROUNDER_MAX_UNPACKED_BYTES", &mut self.max_unpacked_bytes)?;
        num("GROUNDER_MAX_ARCHIVE_FILES", &mut self.max_archive_files)?;
        num("GROUNDER_MAX_IMAGE_PIXELS", &mut self.max_image_pixels)?;
        num("GROUNDER_MAX_INDEX_ATTEMPTS", &mut self.max_index_attempts)?;
        num("GROUNDER_TEST_STEP_PAUSE_MS", &mut self.test_step_pause_ms)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Config, toml::de::Error> {
        toml::from_str(text)
    }

    #[test]
    fn a_misspelt_nested_key_is_an_error_naming_it() {
        let err = parse("[agent.geometry.consensus]\nmask_vote = false\n")
            .err()
            .map(|e| e.to_string());
        let msg = err.unwrap_or_default();
        assert!(msg.contains("mask_vote"), "{msg}");
        for text in [
            "[agent]\nimage_limit = 3\nbogus = 1\n",
            "[agent.geometry.support]\nwal_cut = false\n",
        ] {
            assert!(parse(text).is_err(), "accepted {text:?}");
        }
    }

    #[test]
    fn correct_nested_keys_are_read() {
        let cfg = parse("workers = 3\n[agent]\nimage_limit = 5\n[agent.geometry.consensus]\nmask_votes = false\n[agent.geometry.support]\nwall_cut = false\n")
            .expect("valid config");
        assert_eq!(cfg.workers, 3);
        assert_eq!(cfg.agent.image_limit, 5);
        assert!(!cfg.agent.geometry.consensus.mask_votes);
        assert!(!cfg.agent.geometry.support.wall_cut);
    }
}
