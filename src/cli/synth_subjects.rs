//! `irlgrid synth-subjects`: clearly labelled *synthetic* subjects for demos
//! and recovery tests. For each planted w1 it trains (or reuses) a policy,
//! samples successful stand-ups, picks one per subject, optionally puts it on
//! a perturbed body and adds measurement noise, and writes the subject CSV
//! plus a sidecar JSON recording everything that was planted.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;
use shared::analysis::{subjects_to_csv, SubjectPath};
use shared::env::EnvConfig;
use shared::ppo::{self, PpoConfig, TrainedPolicy};
use shared::sample::{self, SamplingConfig};

use super::InputError;

#[derive(clap::Args, Debug)]
pub struct SynthSubjectsArgs {
    /// Planted torque weights, comma-separated (one or more subjects each).
    #[arg(
        long,
        value_delimiter = ',',
        required = true,
        allow_negative_numbers = true
    )]
    w1: Vec<f64>,
    /// Seed of everything random here (training, sampling, body, noise).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Output subject CSV; the sidecar goes next to it with `.json`.
    #[arg(long)]
    out: PathBuf,
    /// Subjects per planted w1.
    #[arg(long, default_value_t = 1)]
    per_weight: u32,
    /// Training budget per policy (env steps); default: the trainer's default.
    #[arg(long)]
    steps: Option<u64>,
    /// Directory of cached policies (`w1_<value>/policy.json`): reused when
    /// present, written after training.
    #[arg(long)]
    policies: Option<PathBuf>,
    /// Relative body-parameter perturbation: each segment's mass and length
    /// are scaled by an independent factor in [1 - F, 1 + F].
    #[arg(long, default_value_t = 0.0)]
    body_perturbation: f64,
    /// Standard deviation of Gaussian measurement noise added to x and z (m).
    #[arg(long, default_value_t = 0.0)]
    noise_m: f64,
    /// Keep every k-th 200 Hz sample (2 gives 100 Hz motion capture).
    #[arg(long, default_value_t = 2)]
    decimate: usize,
}

/// The sidecar JSON: what was planted, so a recovery check can score itself.
#[derive(Serialize)]
struct Sidecar {
    synthetic: bool,
    note: &'static str,
    seed: u64,
    body_perturbation: f64,
    noise_m: f64,
    decimate: usize,
    subjects: Vec<PlantedSubject>,
}

#[derive(Serialize)]
struct PlantedSubject {
    subject: String,
    planted_w1: f64,
    policy_seed: u64,
    policy_env_steps: u64,
    /// Successful episodes found / tried when sampling on the subject's body.
    sampling_success_rate: f64,
    /// Mass and length factors per segment [shank, thigh, trunk].
    mass_scale: [f64; 3],
    length_scale: [f64; 3],
    episode_return: f64,
    episode_steps: u32,
}

pub fn run(args: SynthSubjectsArgs) -> Result<()> {
    validate(&args)?;
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let mut subjects = Vec::new();
    let mut planted = Vec::new();
    for (wi, &w1) in args.w1.iter().enumerate() {
        let policy_seed = args.seed.wrapping_mul(1000).wrapping_add(wi as u64);
        let policy = policy_for(&args, w1, policy_seed)?;
        for k in 0..args.per_weight {
            let name = format!("synthetic-w1-{w1}-{}", k + 1);
            let (mass_scale, length_scale, env) =
                perturbed_body(&policy.env, args.body_perturbation, &mut rng);
            let mut on_body = policy.clone();
            on_body.env = env;
            let cfg = SamplingConfig {
                successful_episodes: 20,
                top_k: 20,
                max_attempts: 20_000,
                n_envs: 32,
            };
            let out = sample::sample(&on_body, &cfg, rng.gen())
                .with_context(|| format!("sampling subject {name}"))?;
            if out.episodes.is_empty() {
                anyhow::bail!(
                    "subject {name}: the w1 = {w1} policy never stood up on this body in {} tries; \
                     train longer (--steps) or lower --body-perturbation",
                    out.attempts
                );
            }
            // A typical success, not the best one: people are not optimal.
            let ep = &out.episodes[rng.gen_range(0..out.episodes.len())];
            let noise = Normal::new(0.0, args.noise_m.max(f64::MIN_POSITIVE))?;
            let keep = |i: &usize| i.is_multiple_of(args.decimate) || *i == ep.com_t.len() - 1;
            let idx: Vec<usize> = (0..ep.com_t.len()).filter(keep).collect();
            let mut jitter = |v: f64| {
                if args.noise_m > 0.0 {
                    v + noise.sample(&mut rng)
                } else {
                    v
                }
            };
            subjects.push(SubjectPath {
                subject: name.clone(),
                t: idx.iter().map(|&i| ep.com_t[i]).collect(),
                x: idx.iter().map(|&i| jitter(ep.com_x[i])).collect(),
                z: idx.iter().map(|&i| jitter(ep.com_z[i])).collect(),
            });
            planted.push(PlantedSubject {
                subject: name,
                planted_w1: w1,
                policy_seed,
                policy_env_steps: policy.env_steps,
                sampling_success_rate: out.success_rate(),
                mass_scale,
                length_scale,
                episode_return: ep.ret,
                episode_steps: ep.steps,
            });
        }
    }
    write_file(&args.out, &subjects_to_csv(&subjects))?;
    let sidecar = Sidecar {
        synthetic: true,
        note: "SYNTHETIC subjects generated by irlgrid synth-subjects from the project's own \
               simulator and PPO policies with planted w1 values; not human data",
        seed: args.seed,
        body_perturbation: args.body_perturbation,
        noise_m: args.noise_m,
        decimate: args.decimate,
        subjects: planted,
    };
    let sidecar_path = args.out.with_extension("json");
    write_file(&sidecar_path, &serde_json::to_string_pretty(&sidecar)?)?;
    eprintln!(
        "wrote {} synthetic subjects to {} (planted values in {})",
        subjects.len(),
        args.out.display(),
        sidecar_path.display()
    );
    Ok(())
}

fn validate(args: &SynthSubjectsArgs) -> Result<()> {
    let bad = |m: String| Err(InputError(m).into());
    if let Some(w) = args.w1.iter().find(|w| !(w.is_finite() && **w >= 0.0)) {
        return bad(format!("--w1: {w} is not a finite value >= 0"));
    }
    if !(0.0..0.5).contains(&args.body_perturbation) {
        return bad(format!(
            "--body-perturbation must be in [0, 0.5), got {}",
            args.body_perturbation
        ));
    }
    if !(args.noise_m.is_finite() && args.noise_m >= 0.0) {
        return bad(format!(
            "--noise-m must be finite and >= 0, got {}",
            args.noise_m
        ));
    }
    if args.decimate == 0 || args.per_weight == 0 {
        return bad("--decimate and --per-weight must be at least 1".into());
    }
    if args.out.extension().is_some_and(|e| e == "json") {
        return bad("--out must not end in .json (the sidecar takes that name)".into());
    }
    Ok(())
}

/// Loads a cached policy for `w1`, or trains one (and caches it).
fn policy_for(args: &SynthSubjectsArgs, w1: f64, seed: u64) -> Result<TrainedPolicy> {
    let cached = args
        .policies
        .as_ref()
        .map(|d| d.join(format!("w1_{w1}")).join("policy.json"));
    if let Some(path) = cached.as_ref().filter(|p| p.exists()) {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let policy = TrainedPolicy::from_json(&text)
            .with_context(|| format!("loading {}", path.display()))?;
        if policy.env.reward.w1 != w1 {
            return Err(InputError(format!(
                "{} was trained with w1 = {}, not {w1}",
                path.display(),
                policy.env.reward.w1
            ))
            .into());
        }
        eprintln!("w1 = {w1}: reusing {}", path.display());
        return Ok(policy);
    }
    let mut cfg = PpoConfig::default();
    if let Some(steps) = args.steps {
        cfg.env_steps = steps;
    }
    cfg.validate().map_err(|e| InputError(e.to_string()))?;
    eprintln!(
        "w1 = {w1}: training {} env steps (seed {seed})",
        cfg.env_steps
    );
    let mut last_tenth = 0;
    let out = ppo::train(&cfg, &EnvConfig::with_w1(w1), seed, &mut |p| {
        let tenth = p.env_steps * 10 / p.total_env_steps.max(1);
        if tenth > last_tenth {
            last_tenth = tenth;
            eprintln!(
                "  {:>3}%  success rate {:.2}  mean return {:.1}",
                tenth * 10,
                p.success_rate,
                p.mean_return
            );
        }
        ControlFlow::Continue(())
    })?;
    if let Some(path) = cached {
        write_file(&path, &out.policy.to_json())?;
    }
    Ok(out.policy)
}

/// The policy's body with each segment's mass and length scaled by a factor
/// in [1 - f, 1 + f]; the COM offset scales with the length and the inertia
/// with mass x length^2 (a uniformly scaled segment).
fn perturbed_body(
    env: &EnvConfig,
    f: f64,
    rng: &mut ChaCha8Rng,
) -> ([f64; 3], [f64; 3], EnvConfig) {
    let mut env = env.clone();
    let (mut ms, mut ls) = ([1.0; 3], [1.0; 3]);
    if f > 0.0 {
        let sim = &mut env.sim;
        for (i, seg) in [&mut sim.shank, &mut sim.thigh, &mut sim.trunk]
            .into_iter()
            .enumerate()
        {
            ms[i] = rng.gen_range(1.0 - f..=1.0 + f);
            ls[i] = rng.gen_range(1.0 - f..=1.0 + f);
            seg.mass *= ms[i];
            seg.length *= ls[i];
            seg.com *= ls[i];
            seg.inertia *= ms[i] * ls[i] * ls[i];
        }
    }
    (ms, ls, env)
}

fn write_file(path: &Path, text: &str) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}
