//! `irlgrid sample`: trajectories (docs/science.md#sampling) from a saved policy, as a JSON
//! `SampleOutput` (the same shape as a run directory's samples.json).

use std::path::PathBuf;

use anyhow::{Context, Result};
use shared::sample::{sample, SampleError, SamplingConfig};

use super::evaluate::load_policy;
use super::InputError;

#[derive(clap::Args, Debug)]
pub struct SampleArgs {
    /// A policy.json written by `irlgrid train`.
    #[arg(long)]
    policy: PathBuf,
    /// Seed of the initial-state and action noise.
    #[arg(long)]
    seed: u64,
    /// Output JSON file.
    #[arg(long)]
    out: PathBuf,
    /// Successful episodes to collect (default 1000).
    #[arg(long)]
    successes: Option<u32>,
    /// Successful episodes to keep, best return first (default 10).
    #[arg(long)]
    top_k: Option<u32>,
    /// Cap on episodes tried (default 20000).
    #[arg(long)]
    max_attempts: Option<u32>,
}

pub fn run(args: SampleArgs) -> Result<()> {
    let policy = load_policy(&args.policy)?;
    let defaults = SamplingConfig::default();
    let successful_episodes = args.successes.unwrap_or(defaults.successful_episodes);
    let cfg = SamplingConfig {
        successful_episodes,
        // Asking for fewer successes than the default top_k keeps them all.
        top_k: args
            .top_k
            .unwrap_or(defaults.top_k.min(successful_episodes.max(1))),
        max_attempts: args.max_attempts.unwrap_or(defaults.max_attempts),
        ..defaults
    };
    let out = sample(&policy, &cfg, args.seed).map_err(|e| match e {
        SampleError::InvalidConfig(_) => anyhow::Error::from(InputError(e.to_string())),
        e => anyhow::Error::from(e),
    })?;
    std::fs::write(&args.out, serde_json::to_string(&out)?)
        .with_context(|| format!("writing {}", args.out.display()))?;
    println!(
        "{} successes in {} attempts (wanted {}), kept {}{}; wrote {}",
        out.successes_found,
        out.attempts,
        out.successes_wanted,
        out.episodes.len(),
        if out.successes_found < out.successes_wanted {
            " (SHORTFALL: attempt cap reached)"
        } else {
            ""
        },
        args.out.display()
    );
    Ok(())
}
