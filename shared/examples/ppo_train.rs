//! Release-mode training measurement: trains one (w1, seed) and prints the
//! learning curve every few updates, the wall time, throughput, a fresh
//! 200-episode stochastic evaluation, and (unless SAMPLE=0) the trend
//! numbers of the trial (docs/science.md#sampling,
//! docs/science.md#aggregation): mean torque usage and mean COM-path area
//! of its 10 best of 1000 successful episodes.
//!
//! `cargo run --release -p shared --example ppo_train -- W1 SEED [PPO_JSON]`
//! where PPO_JSON is an optional partial `PpoConfig` (serde defaults fill the
//! rest), e.g. '{"env_steps": 2000000, "init_log_std": -1.0}'.
//!
//! The grid measurement behind the defaults (one run at a time):
//! `for w in 0.1 0.5 1 2 4 8 16; do for s in 1 2 3 4 5; do
//!   target/release/examples/ppo_train $w $s | grep -E 'RESULT|TREND'; done; done`

use std::ops::ControlFlow;
use std::time::Instant;

use shared::analysis::resample_path;
use shared::env::EnvConfig;
use shared::ppo::{evaluate, train, PpoConfig};
use shared::sample::{sample, SamplingConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let w1: f64 = args.get(1).map_or(Ok(1.0), |s| s.parse())?;
    let seed: u64 = args.get(2).map_or(Ok(1), |s| s.parse())?;
    let cfg: PpoConfig = match args.get(3) {
        Some(j) => serde_json::from_str(j)?,
        None => PpoConfig::default(),
    };
    let every: u64 = std::env::var("EVERY")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(50);
    let env = EnvConfig::with_w1(w1);
    let start = Instant::now();
    let out = train(&cfg, &env, seed, &mut |p| {
        if p.update % every == 0 {
            println!(
                "{:>9} ret {:>8.1} succ {:.3} len {:>5.1} pl {:>7.4} vl {:>7.4} ent {:>6.3} kl {:.4} clip {:.3} ev {:.3} std {:.3}",
                p.env_steps, p.mean_return, p.success_rate, p.mean_episode_length, p.policy_loss,
                p.value_loss, p.entropy, p.approx_kl, p.clip_fraction, p.explained_variance, p.action_std
            );
        }
        ControlFlow::Continue(())
    })?;
    let secs = start.elapsed().as_secs_f64();
    let eval = evaluate(&out.policy, 200, seed ^ 0x00e7_a1a7_e000)?;
    println!(
        "RESULT w1 {w1} seed {seed} steps {} secs {secs:.1} sps {:.0} final_success {:.3} return {:.1} torque {:.1} len {:.1}",
        out.env_steps,
        out.env_steps as f64 / secs,
        eval.success_rate,
        eval.mean_return,
        eval.mean_torque_usage,
        eval.mean_episode_length
    );
    if std::env::var("SAMPLE").as_deref() != Ok("0") {
        let t = Instant::now();
        let s = sample(
            &out.policy,
            &SamplingConfig::default(),
            seed ^ 0x5a3b_1e00_0000_0000,
        )?;
        let k = s.episodes.len().max(1) as f64;
        let torque = s.episodes.iter().map(|e| e.torque_usage).sum::<f64>() / k;
        let mut area = 0.0;
        for e in &s.episodes {
            area += resample_path(&e.com_x, &e.com_z)?.area;
        }
        println!(
            "TREND w1 {w1} seed {seed} successes {}/{} attempts {} kept {} top_torque {torque:.2} top_area {:.4} top_len {:.1} secs {:.1}",
            s.successes_found,
            s.successes_wanted,
            s.attempts,
            s.episodes.len(),
            area / k,
            s.episodes.iter().map(|e| f64::from(e.steps)).sum::<f64>() / k,
            t.elapsed().as_secs_f64()
        );
    }
    Ok(())
}
