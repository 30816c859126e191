//! `irlgrid train`: one PPO training run into a run directory:
//! `policy.json`, `learning_curve.csv`, `summary.json` and, unless
//! `--no-sample`, `samples.json` (docs/science.md#sampling trajectories for `irlgrid analyze`).

use std::fmt::Write as _;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};
use shared::env::EnvConfig;
use shared::ppo::{evaluate, train, EvalReport, PpoConfig, PpoError, TrainProgress};
use shared::sample::{sample, SampleOutput, SamplingConfig};

use super::InputError;

#[derive(clap::Args, Debug)]
pub struct TrainArgs {
    /// Torque-cost weight w1 of the reward (docs/science.md#reward).
    #[arg(long, allow_negative_numbers = true)]
    w1: f64,
    /// Seed: the run is a pure function of (config, w1, seed).
    #[arg(long)]
    seed: u64,
    /// Training budget in environment steps (overrides the config's `env_steps`).
    #[arg(long)]
    steps: Option<u64>,
    /// JSON file with optional sections `ppo` (PpoConfig), `env` (EnvConfig)
    /// and `sampling` (SamplingConfig); missing fields take their defaults.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Reward preset the task starts from (`irlgrid presets`); the config
    /// file's `env.reward` fields override its values.
    #[arg(long, default_value = shared::env::DEFAULT_PRESET)]
    preset: String,
    /// Run directory to write (created if missing).
    #[arg(long)]
    out: PathBuf,
    /// Stochastic episodes of the final evaluation (at least 200).
    #[arg(long, default_value_t = 1000)]
    eval_episodes: u32,
    /// Skip trajectory sampling (no samples.json).
    #[arg(long)]
    no_sample: bool,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

/// The `--config` file.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainFile {
    /// PPO hyperparameters.
    pub ppo: PpoConfig,
    /// Task (w1 is taken from `--w1`).
    pub env: EnvConfig,
    /// Trajectory sampling after training.
    pub sampling: SamplingConfig,
}

/// `summary.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Summary {
    pub w1: f64,
    pub seed: u64,
    pub env_steps: u64,
    /// Training wall time (s), updates included, evaluation and sampling excluded.
    pub wall_seconds: f64,
    pub steps_per_second: f64,
    /// Success rate of a fresh stochastic evaluation after training.
    pub final_success_rate: f64,
    pub final_mean_return: f64,
    pub final_mean_torque_usage: f64,
    pub final_mean_episode_length: f64,
    pub eval_episodes: u32,
    pub eval_seed: u64,
    /// Success rate over the last update's rollout episodes.
    pub last_train_success_rate: f64,
    pub time_limit: shared::ppo::TimeLimit,
    pub fail_penalty: shared::env::FailPenalty,
    /// Reward preset the task started from (absent in older runs).
    #[serde(default)]
    pub preset: Option<String>,
    /// The resolved reward, w1 included (absent in older runs).
    #[serde(default)]
    pub reward: Option<shared::env::RewardConfig>,
    pub sampling: Option<SamplingSummary>,
}

/// Sampling part of `summary.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SamplingSummary {
    pub seed: u64,
    pub successes_found: u32,
    pub successes_wanted: u32,
    pub attempts: u32,
    pub kept: usize,
    pub wall_seconds: f64,
}

/// Seeds of the post-training evaluation and sampling: fixed offsets of the
/// training seed, so they never replay the training episodes' noise.
pub fn eval_seed(seed: u64) -> u64 {
    seed ^ 0x0e7a_1000_0000_0000
}
pub fn sample_seed(seed: u64) -> u64 {
    seed ^ 0x5a3b_1e00_0000_0000
}

pub fn run(args: TrainArgs) -> Result<()> {
    let mut file = read_config(args.config.as_deref(), &args.preset)?;
    if let Some(steps) = args.steps {
        file.ppo.env_steps = steps;
    }
    file.env.reward.w1 = args.w1;
    if args.eval_episodes < 200 {
        return Err(InputError(format!(
            "--eval-episodes must be at least 200 (got {})",
            args.eval_episodes
        ))
        .into());
    }
    file.ppo.validate().map_err(|e| InputError(e.to_string()))?;
    file.env.validate().map_err(|e| InputError(e.to_string()))?;
    if !args.no_sample {
        file.sampling
            .validate()
            .map_err(|e| InputError(e.to_string()))?;
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating run directory {}", args.out.display()))?;

    let bar = progress_bar(
        file.ppo.n_updates() * file.ppo.batch_size() as u64,
        args.quiet,
    );
    let start = Instant::now();
    let out = train(&file.ppo, &file.env, args.seed, &mut |p: &TrainProgress| {
        bar.set_position(p.env_steps);
        bar.set_message(format!(
            "return {:>7.1}  success {:>5.1}%",
            p.mean_return,
            100.0 * p.success_rate
        ));
        ControlFlow::Continue(())
    })
    .map_err(|e| match e {
        PpoError::InvalidConfig(_) | PpoError::Env(_) => {
            anyhow::Error::from(InputError(e.to_string()))
        }
        e => anyhow::Error::from(e).context("training"),
    })?;
    let wall = start.elapsed().as_secs_f64();
    bar.finish_and_clear();

    write(&args.out.join("policy.json"), &out.policy.to_json())?;
    write(&args.out.join("learning_curve.csv"), &curve_csv(&out.curve))?;

    let eval: EvalReport = evaluate(&out.policy, args.eval_episodes, eval_seed(args.seed))
        .context("evaluating the trained policy")?;

    let sampling = if args.no_sample {
        None
    } else {
        let t = Instant::now();
        let s: SampleOutput = sample(&out.policy, &file.sampling, sample_seed(args.seed))
            .context("sampling trajectories")?;
        write(&args.out.join("samples.json"), &serde_json::to_string(&s)?)?;
        Some(SamplingSummary {
            seed: sample_seed(args.seed),
            successes_found: s.successes_found,
            successes_wanted: s.successes_wanted,
            attempts: s.attempts,
            kept: s.episodes.len(),
            wall_seconds: t.elapsed().as_secs_f64(),
        })
    };

    let summary = Summary {
        w1: args.w1,
        seed: args.seed,
        env_steps: out.env_steps,
        wall_seconds: wall,
        steps_per_second: out.env_steps as f64 / wall.max(1e-9),
        final_success_rate: eval.success_rate,
        final_mean_return: eval.mean_return,
        final_mean_torque_usage: eval.mean_torque_usage,
        final_mean_episode_length: eval.mean_episode_length,
        eval_episodes: eval.episodes,
        eval_seed: eval_seed(args.seed),
        last_train_success_rate: out.curve.last().map_or(0.0, |p| p.success_rate),
        time_limit: file.ppo.time_limit,
        fail_penalty: file.env.reward.fail_penalty,
        preset: Some(args.preset.clone()),
        reward: Some(file.env.reward.clone()),
        sampling,
    };
    write(
        &args.out.join("summary.json"),
        &serde_json::to_string_pretty(&summary)?,
    )?;
    println!(
        "trained w1 = {} seed {} for {} steps in {:.1} s ({:.0} steps/s): success rate {:.3}, mean return {:.1}, mean torque usage {:.1} N m s",
        args.w1,
        args.seed,
        out.env_steps,
        wall,
        summary.steps_per_second,
        eval.success_rate,
        eval.mean_return,
        eval.mean_torque_usage
    );
    if let Some(s) = &summary.sampling {
        println!(
            "sampled {} successes in {} attempts (wanted {}), kept {}{}",
            s.successes_found,
            s.attempts,
            s.successes_wanted,
            s.kept,
            if s.successes_found < s.successes_wanted {
                " (SHORTFALL: attempt cap reached)"
            } else {
                ""
            }
        );
    }
    println!("wrote {}", args.out.display());
    Ok(())
}

/// The `--config` file (if any) over the defaults, with the task's reward
/// starting from `preset`.
fn read_config(path: Option<&Path>, preset: &str) -> Result<TrainFile> {
    let reward = shared::env::preset(preset)
        .and_then(|p| p.reward())
        .map_err(|e| InputError(format!("--preset: {e}")))?;
    let mut file = TrainFile::default();
    file.env.reward = reward;
    let Some(path) = path else {
        return Ok(file);
    };
    let text = std::fs::read_to_string(path)
        .map_err(|e| InputError(format!("cannot read config {}: {e}", path.display())))?;
    let patch: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| InputError(format!("invalid config {}: {e}", path.display())))?;
    let mut merged = serde_json::to_value(&file)?;
    shared::env::overlay(&mut merged, &patch);
    serde_json::from_value(merged)
        .map_err(|e| InputError(format!("invalid config {}: {e}", path.display())).into())
}

fn write(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

/// `learning_curve.csv`: the columns first, diagnostics after.
pub fn curve_csv(curve: &[TrainProgress]) -> String {
    let mut s = String::from(
        "env_steps,mean_return,success_rate,mean_episode_length,policy_loss,value_loss,entropy,approx_kl,clip_fraction,explained_variance,learning_rate,action_std\n",
    );
    for p in curve {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{},{},{}",
            p.env_steps,
            p.mean_return,
            p.success_rate,
            p.mean_episode_length,
            p.policy_loss,
            p.value_loss,
            p.entropy,
            p.approx_kl,
            p.clip_fraction,
            p.explained_variance,
            p.learning_rate,
            p.action_std
        );
    }
    s
}

fn progress_bar(total: u64, quiet: bool) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(total);
    if let Ok(style) = ProgressStyle::with_template(
        "{elapsed_precise} [{bar:30}] {human_pos}/{human_len} steps {per_sec} eta {eta}  {msg}",
    ) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.enable_steady_tick(Duration::from_millis(250));
    bar
}
