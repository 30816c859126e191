//! Operations helpers for deployments: `irlgrid health` (a container health
//! probe that needs no curl in a `FROM scratch` image) and `irlgrid backup`
//! (a consistent copy of the live database).

use std::path::PathBuf;
use std::time::Duration;

use super::coordinator::runtime;

#[derive(clap::Args, Debug)]
pub struct HealthArgs {
    /// URL to probe; exit status 0 when it answers HTTP 200 within the timeout.
    #[arg(long, default_value = "http://127.0.0.1:8080/healthz")]
    url: String,
    /// Timeout in seconds.
    #[arg(long, default_value_t = 2.0)]
    timeout: f64,
}

pub fn health(args: HealthArgs) -> anyhow::Result<()> {
    let timeout = Duration::try_from_secs_f64(args.timeout).map_err(|_| {
        super::InputError(format!(
            "--timeout must be a positive number, got {}",
            args.timeout
        ))
    })?;
    runtime()?
        .block_on(irlgrid_client::probe(&args.url, timeout))
        .map_err(|e| anyhow::anyhow!(e))
}

#[derive(clap::Args, Debug)]
pub struct BackupArgs {
    /// The coordinator's database file (it may be in use).
    #[arg(long, env = "IRLGRID_DB")]
    db: PathBuf,
    /// Where to write the copy (must not exist).
    #[arg(long)]
    out: PathBuf,
}

pub fn backup(args: BackupArgs) -> anyhow::Result<()> {
    runtime()?.block_on(coordinator::store::backup::backup(&args.db, &args.out))?;
    eprintln!("backed up {} to {}", args.db.display(), args.out.display());
    Ok(())
}
