//! `grounder oracle-vlm`, `grounder eval`, `grounder convert`.

pub use super::oracle_vlm::OracleVlmArgs;

#[derive(Debug, clap::Args)]
pub struct EvalArgs {}

#[derive(Debug, clap::Args)]
pub struct ConvertArgs {}

pub async fn run_oracle_vlm(args: OracleVlmArgs) -> anyhow::Result<()> {
    super::oracle_vlm::run(args).await
}

pub async fn run_eval(_args: EvalArgs) -> anyhow::Result<()> {
    anyhow::bail!("grounder eval is not built yet")
}

pub fn run_convert(_args: ConvertArgs) -> anyhow::Result<()> {
    anyhow::bail!("grounder convert is not built yet")
}
