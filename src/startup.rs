//! Building and running the service.

use crate::config::ServeArgs;

pub async fn serve(_args: ServeArgs) -> anyhow::Result<()> {
    anyhow::bail!("grounder serve is not built yet")
}
