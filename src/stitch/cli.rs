//! `grounder stitch-plan` and `grounder retrieval-bench`.

#[derive(Debug, clap::Args)]
pub struct StitchPlanArgs {}

#[derive(Debug, clap::Args)]
pub struct RetrievalBenchArgs {}

pub fn run_plan(_args: StitchPlanArgs) -> anyhow::Result<()> {
    anyhow::bail!("grounder stitch-plan is not built yet")
}

pub async fn run_retrieval_bench(_args: RetrievalBenchArgs) -> anyhow::Result<()> {
    anyhow::bail!("grounder retrieval-bench is not built yet")
}
