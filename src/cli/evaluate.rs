//! `irlgrid evaluate`: stochastic evaluation of a saved policy: success rate, return and
//! torque usage over fresh stochastic episodes.

use std::path::{Path, PathBuf};

use anyhow::Result;
use shared::ppo::{evaluate, TrainedPolicy};

use super::InputError;

#[derive(clap::Args, Debug)]
pub struct EvaluateArgs {
    /// A policy.json written by `irlgrid train`.
    #[arg(long)]
    policy: PathBuf,
    /// Episodes to run (actions sampled from the policy's Gaussian).
    #[arg(long, default_value_t = 200)]
    episodes: u32,
    /// Seed of the initial-state noise and the action noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Print the report as JSON instead of text.
    #[arg(long)]
    json: bool,
}

pub fn run(args: EvaluateArgs) -> Result<()> {
    if args.episodes == 0 {
        return Err(InputError("--episodes must be at least 1".into()).into());
    }
    let policy = load_policy(&args.policy)?;
    let report = evaluate(&policy, args.episodes, args.seed)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!("policy: {} (w1 = {})", args.policy.display(), policy.w1());
        println!("episodes: {}", report.episodes);
        println!("success rate: {:.4}", report.success_rate);
        println!("mean return: {:.3}", report.mean_return);
        println!("mean torque usage: {:.3} N m s", report.mean_torque_usage);
        println!(
            "mean episode length: {:.2} steps",
            report.mean_episode_length
        );
    }
    Ok(())
}

/// Reads and validates a policy file; any problem with it is bad input.
pub fn load_policy(path: &Path) -> Result<TrainedPolicy> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| InputError(format!("cannot read policy {}: {e}", path.display())))?;
    TrainedPolicy::from_json(&text)
        .map_err(|e| InputError(format!("{}: {e}", path.display())).into())
}
