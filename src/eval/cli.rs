//! `grounder oracle-vlm`, `grounder eval`, `grounder convert`.

#[derive(Debug, clap::Args)]
pub struct OracleVlmArgs {}

#[derive(Debug, clap::Args)]
pub struct EvalArgs {}

#[derive(Debug, clap::Args)]
pub struct ConvertArgs {}

pub async fn run_oracle_vlm(_args: OracleVlmArgs) -> anyhow::Result<()> {
    anyhow::bail!("grounder oracle-vlm is not built yet")
}

pub async fn run_eval(_args: EvalArgs) -> anyhow::Result<()> {
    anyhow::bail!("grounder eval is not built yet")
}

pub fn run_convert(_args: ConvertArgs) -> anyhow::Result<()> {
    anyhow::bail!("grounder convert is not built yet")
}
