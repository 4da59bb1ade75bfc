//! Service configuration: flags, environment variables and an optional TOML file.

use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub struct ServeArgs {
    /// Address to listen on.
    #[arg(long, env = "GROUNDER_ADDR", default_value = "127.0.0.1:8080")]
    pub addr: String,
    /// Directory holding the database and scene files.
    #[arg(long, env = "GROUNDER_DATA_DIR", default_value = "./data")]
    pub data_dir: PathBuf,
    /// Optional TOML configuration file.
    #[arg(long, env = "GROUNDER_CONFIG")]
    pub config: Option<PathBuf>,
}
