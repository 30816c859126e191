//! `irlgrid optimize`: the best open-loop movement a reward allows, found by
//! trajectory optimization without a learner (docs/science.md#optimal-reference),
//! and `irlgrid presets`.

use std::path::PathBuf;

use anyhow::{Context, Result};
use serde::Serialize;
use shared::env::{preset, presets, EnvConfig};
use shared::optimize::{optimize_ladder, stand_up_area, OptimizeConfig, Optimum};

use super::InputError;

#[derive(clap::Args, Debug)]
pub struct OptimizeArgs {
    /// Torque-cost weight w1, or several separated by commas: they are solved
    /// by continuation from the lowest up, and the output is then a JSON array.
    #[arg(long, value_delimiter = ',', required = true)]
    w1: Vec<f64>,
    /// Reward preset (see `irlgrid presets`); default `paper`.
    #[arg(long, default_value = shared::env::DEFAULT_PRESET)]
    preset: String,
    /// Override a reward field, `name=value` (repeatable), e.g. `effort_exponent=2` or
    /// `effort_term=power`; applied after the preset.
    #[arg(long = "set", value_name = "NAME=VALUE")]
    set: Vec<String>,
    /// Candidate sequences per cross-entropy iteration.
    #[arg(long, default_value_t = OptimizeConfig::default().population)]
    population: usize,
    /// Iterations per restart.
    #[arg(long, default_value_t = OptimizeConfig::default().iterations)]
    iterations: usize,
    /// Independent restarts (the best wins; their spread is printed).
    #[arg(long, default_value_t = OptimizeConfig::default().restarts)]
    restarts: usize,
    /// Time-stretch factors (above 1 slower) tried before each stretched
    /// search: it starts from the best plan so far played at whichever
    /// factor earns most.
    #[arg(long, value_delimiter = ',', default_values_t = OptimizeConfig::default().stretch)]
    stretch: Vec<f64>,
    /// Stretched searches after the restarts (0: none, the optimizer as it
    /// was before stretching).
    #[arg(long, default_value_t = OptimizeConfig::default().stretch_rounds)]
    stretch_rounds: usize,
    /// Shape constraint: the best movement whose path area (the paper's, of
    /// the preprocessed path) is this value, by a penalty on the distance.
    /// Compared with the unconstrained optimum, it says what the shape costs.
    #[arg(long, allow_hyphen_values = true)]
    area_target: Option<f64>,
    /// Weight of the area penalty (return points per unit area squared).
    #[arg(long, default_value_t = OptimizeConfig::default().area_weight)]
    area_weight: f64,
    /// Threads evaluating candidates (0 = all cores; the answer does not
    /// depend on it). A search's optimizer job uses one.
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Seed of the optimizer's noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Output JSON.
    #[arg(long)]
    out: PathBuf,
}

/// `optimize`'s output file: the optimum plus its path area.
#[derive(Serialize)]
struct OptimumFile<'a> {
    preset: &'a str,
    /// Area of the best path (docs/science.md#area), when it stands up: the
    /// paper's area of the preprocessed, resampled path, as for PPO's paths
    /// and subjects, so the two compare.
    area: Option<f64>,
    #[serde(flatten)]
    optimum: &'a Optimum,
}

/// Applies a preset and `name=value` overrides to the default task.
pub fn env_from(preset_name: &str, sets: &[String]) -> Result<EnvConfig, InputError> {
    let mut env = EnvConfig {
        reward: preset(preset_name)
            .and_then(|p| p.reward())
            .map_err(|e| InputError(e.to_string()))?,
        ..EnvConfig::default()
    };
    let mut reward = serde_json::to_value(&env.reward).map_err(|e| InputError(e.to_string()))?;
    for s in sets {
        let (k, v) = s
            .split_once('=')
            .ok_or_else(|| InputError(format!("--set {s:?}: expected NAME=VALUE")))?;
        // Numbers stay numbers; a word such as `power` is a string.
        let v: serde_json::Value = serde_json::from_str(v.trim())
            .unwrap_or_else(|_| serde_json::Value::String(v.trim().to_string()));
        shared::env::overlay(&mut reward, &serde_json::json!({ k.trim(): v }));
    }
    env.reward = serde_json::from_value(reward).map_err(|e| InputError(format!("--set: {e}")))?;
    env.reward
        .validate()
        .map_err(|e| InputError(format!("--set: {e}")))?;
    Ok(env)
}

pub fn run(args: OptimizeArgs) -> Result<()> {
    let env = env_from(&args.preset, &args.set)?;
    let cfg = OptimizeConfig {
        population: args.population,
        elites: (args.population / 10).max(1),
        iterations: args.iterations,
        restarts: args.restarts,
        seed: args.seed,
        threads: args.threads,
        area_target: args.area_target,
        area_weight: args.area_weight,
        stretch: args.stretch.clone(),
        stretch_rounds: args.stretch_rounds,
        ..OptimizeConfig::default()
    };
    cfg.validate().map_err(|e| InputError(e.to_string()))?;
    let optima =
        optimize_ladder(&env, &args.w1, &cfg).map_err(|e| InputError(format!("--w1: {e}")))?;
    let files: Vec<OptimumFile> = optima
        .iter()
        .map(|o| OptimumFile {
            preset: &args.preset,
            area: stand_up_area(&o.best),
            optimum: o,
        })
        .collect();
    let text = match files.as_slice() {
        [one] => serde_json::to_string_pretty(one)?,
        many => serde_json::to_string_pretty(many)?,
    };
    std::fs::write(&args.out, text).with_context(|| format!("writing {}", args.out.display()))?;
    for f in &files {
        let b = &f.optimum.best;
        let spread: Vec<String> = f
            .optimum
            .restart_returns
            .iter()
            .map(|r| format!("{r:.1}"))
            .collect();
        println!(
            "optimum at w1 = {} ({}): {} after {} steps ({:.2} s), return {:.2}, torque usage {:.1} N m s, area {}; restarts [{}]",
            f.optimum.env.reward.w1,
            args.preset,
            b.outcome,
            b.steps,
            b.duration,
            b.ret,
            b.torque_usage,
            f.area.map_or("-".to_string(), |a| format!("{a:.4}")),
            spread.join(", ")
        );
    }
    Ok(())
}

/// `irlgrid presets`: every reward preset as JSON.
pub fn list_presets() -> Result<()> {
    println!("{}", serde_json::to_string_pretty(&presets())?);
    Ok(())
}
