//! `grounder keys`: create, list and revoke API keys, and show a key's webhook secret.
//! Works on the data directory directly, also while the server runs.

use clap::{Args, Subcommand};
use std::path::PathBuf;

use crate::config::{Config, ServeArgs};
use crate::store::{KeySpec, Store};

#[derive(Debug, Args)]
pub struct KeysArgs {
    /// Directory holding the database (as for `serve`).
    #[arg(long, env = "GROUNDER_DATA_DIR", global = true)]
    pub data_dir: Option<PathBuf>,
    /// Optional TOML configuration file (its `data_dir` is used).
    #[arg(long, env = "GROUNDER_CONFIG", global = true)]
    pub config: Option<PathBuf>,
    #[command(subcommand)]
    pub command: KeysCommand,
}

#[derive(Debug, Subcommand)]
pub enum KeysCommand {
    /// Create a key; prints its secret (gk_...) and webhook secret (whsec_...) once.
    Create {
        #[arg(long)]
        name: String,
        /// Sees every key's scenes and jobs, and may read /metrics.
        #[arg(long)]
        admin: bool,
        /// Most queued + running jobs at once.
        #[arg(long)]
        max_running_jobs: Option<u32>,
        /// Most bytes of uploaded scenes stored at once.
        #[arg(long)]
        max_scene_bytes: Option<u64>,
    },
    /// List keys (never their secrets).
    List,
    /// Revoke the key of this name.
    Revoke { name: String },
    /// Print the webhook secret (whsec_...) of the key of this name.
    WebhookSecret { name: String },
}

fn check_name(name: &str) -> anyhow::Result<()> {
    let ok = !name.is_empty()
        && name.len() <= 64
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'));
    if !ok {
        anyhow::bail!("key name {name:?} must be 1 to 64 letters, digits, '-', '_' or '.'");
    }
    Ok(())
}

/// Run a `keys` subcommand, printing to stdout.
pub async fn run(args: KeysArgs) -> anyhow::Result<()> {
    let cfg = Config::load(&ServeArgs {
        addr: None,
        data_dir: args.data_dir.clone(),
        config: args.config.clone(),
        role: None,
        allow_anonymous: false,
    })?;
    let store = Store::open_config(&cfg).await?;
    match args.command {
        KeysCommand::Create {
            name,
            admin,
            max_running_jobs,
            max_scene_bytes,
        } => {
            check_name(&name)?;
            let max_scene_bytes = match max_scene_bytes {
                Some(b) => Some(
                    i64::try_from(b)
                        .map_err(|_| anyhow::anyhow!("--max-scene-bytes {b} is too large"))?,
                ),
                None => None,
            };
            let k = store
                .create_key(&KeySpec {
                    name: name.clone(),
                    admin,
                    max_running_jobs: max_running_jobs.map(i64::from),
                    max_scene_bytes,
                })
                .await?
                .ok_or_else(|| anyhow::anyhow!("a key named {name:?} exists already"))?;
            println!("{}", k.secret);
            println!("{}", k.webhook_secret);
            eprintln!("key {name:?} created: the first line goes in `Authorization: Bearer`, the second verifies its webhooks; the key is not shown again");
        }
        KeysCommand::List => {
            println!("name\tadmin\tmax_running_jobs\tmax_scene_bytes\tcreated_at\trevoked_at");
            let opt = |v: Option<i64>| v.map(|n| n.to_string()).unwrap_or_else(|| "-".into());
            for k in store.list_keys().await? {
                println!(
                    "{}\t{}\t{}\t{}\t{}\t{}",
                    k.name,
                    k.admin,
                    opt(k.max_running_jobs),
                    opt(k.max_scene_bytes),
                    k.created_at,
                    k.revoked_at.unwrap_or_else(|| "-".into())
                );
            }
        }
        KeysCommand::Revoke { name } => {
            if !store.revoke_key(&name).await? {
                anyhow::bail!("no active key named {name:?}");
            }
            println!("revoked {name}");
        }
        KeysCommand::WebhookSecret { name } => {
            let s = store
                .webhook_secret_by_name(&name)
                .await?
                .ok_or_else(|| anyhow::anyhow!("no active key named {name:?}"))?;
            println!("{s}");
        }
    }
    Ok(())
}
