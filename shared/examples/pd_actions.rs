//! Writes `examples/pd_rise.csv`: the normalized actions of a simple
//! gravity-compensating PD controller that tracks a cosine path from the
//! squat towards standing. Replayed open-loop by `irlgrid simulate`, they
//! reproduce its run exactly (the simulator is deterministic): the body rises
//! to about 97 % of standing height within a second, then the backward pull
//! and the saturating torques tip it over. A hand-tuned PD is not enough for
//! this task; that is what the learner is for.
//!
//! cargo run --release -p shared --example pd_actions > examples/pd_rise.csv

use shared::env::{EnvConfig, Episode, Task};

fn main() {
    let cfg = EnvConfig::default();
    let task = Task::new(&cfg).expect("default config is valid");
    let model = task.model();
    let s = &cfg.sim;
    let mut ep = Episode::new([s.q0[0], s.q0[1], s.q0[2], 0.0, 0.0, 0.0]);
    println!("a1,a2,a3");
    let (kp, kd) = ([300.0, 500.0, 400.0], [60.0, 80.0, 70.0]);
    // Track a smooth (cosine) path from the squat to upright over `rise` steps.
    let rise = 24.0;
    // Finish with the knee slightly bent, away from its over-straightening limit.
    let stand = [0.02, -0.08, 0.05];
    for step in 0..cfg.max_steps {
        let g = model.gravity(&ep.state[..3]);
        let phase = (f64::from(step) / rise).min(1.0);
        let blend = 0.5 * (1.0 + (std::f64::consts::PI * phase).cos());
        let mut a = [0.0; 3];
        for i in 0..3 {
            let target = s.q0[i] * blend + stand[i] * (1.0 - blend);
            let tau = g[i] - kp[i] * (ep.state[i] - target) - kd[i] * ep.state[3 + i];
            a[i] = (tau / s.tau_max[i]).clamp(-1.0, 1.0);
        }
        println!("{},{},{}", a[0], a[1], a[2]);
        let info = task.step(&mut ep, &a, |_| {});
        if info.outcome.is_done() {
            eprintln!("{} after {} steps", info.outcome.as_str(), info.episode_len);
            break;
        }
    }
}
