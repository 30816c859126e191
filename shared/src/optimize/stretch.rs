//! Slower versions of a movement, as starting points for the search
//! (docs/science.md#optimal-reference).
//!
//! Under a power cost a slower stand-up can be cheaper, but the cross-entropy
//! method refines the movement it starts from: a 10-step stand-up is not a
//! small change of an 8-step one, since every action of the plan must change
//! together to stay balanced on the way. Stretching a plan in time proposes
//! that coordinated change directly.
//!
//! If a joint path q(t) is followed at speed 1/s, q_s(t) = q(t / s), its
//! velocities scale by 1/s and its accelerations by 1/s^2. In
//! `M(q) q'' + C(q, q') + G(q) = tau + P(q, q')` the inertial and
//! velocity-squared terms then scale by 1/s^2, gravity G not at all, and the
//! backward pull P (linear in the COM's upward speed) by 1/s, so the torque
//! that follows the slower path is
//!
//! ```text
//! tau_s(t) = G + (tau - G + P) / s^2 - P / s,   all at the original time t / s.
//! ```
//!
//! An open-loop plan of this unstable body drifts off any path within a few
//! steps, and the actions are held over a control step, so that feed-forward
//! alone does not stand up. The stretched plan therefore adds a feedback term
//! that pulls the body back onto the slowed path, computed while the plan is
//! played from the squat; the actions it applied are the new plan (open-loop
//! again: the model is deterministic). The search then refines it.

use super::ACTION_DIM;
use crate::env::{Episode, Task};
use crate::sim::{Model, State};

/// Natural frequency (rad/s) of the feedback that keeps a stretched plan on
/// its path: well below the control rate's Nyquist limit (63 rad/s at 20 Hz)
/// and well above the movement's own (a stand-up lasts 0.3-1 s).
const TRACK_OMEGA: f64 = 12.0;
/// Damping ratio of that feedback (critically damped).
const TRACK_ZETA: f64 = 1.0;

/// The state at the start of every control step of `actions` played from
/// the noise-free squat, until the episode ends (so one more state than
/// steps taken), and the clipped actions applied.
pub fn state_path(task: &Task, actions: &[f64]) -> (Vec<State>, Vec<[f64; ACTION_DIM]>) {
    let cfg = task.config();
    let mut ep = Episode::new(squat(task));
    let mut states = vec![ep.state];
    let mut applied = Vec::new();
    for row in actions.chunks(ACTION_DIM).take(cfg.max_steps as usize) {
        applied.push(task.model().torque(row).1);
        let info = task.step(&mut ep, row, |_| {});
        states.push(ep.state);
        if info.outcome.is_done() {
            break;
        }
    }
    (states, applied)
}

fn squat(task: &Task) -> State {
    let sim = &task.config().sim;
    let mut s = [0.0; 6];
    s[..3].copy_from_slice(&sim.q0);
    s[3..].copy_from_slice(&sim.qd0);
    s
}

/// The original plan's state at time `t` (in control steps), linearly
/// interpolated between step boundaries, and the action held at `t`; past
/// the end, the last state at rest and no action.
fn at_time(states: &[State], applied: &[[f64; 3]], t: f64) -> (State, Option<[f64; 3]>) {
    let n = applied.len();
    if t >= n as f64 {
        let mut s = states[n];
        s[3..].fill(0.0);
        return (s, None);
    }
    let i = t.floor() as usize;
    let frac = t - i as f64;
    let mut s = [0.0; 6];
    for j in 0..6 {
        s[j] = states[i][j] + frac * (states[i + 1][j] - states[i][j]);
    }
    (s, Some(applied[i]))
}

/// The torque that moves the body through state `s`'s pose with velocities
/// `1 / factor` of `s`'s and accelerations `1 / factor^2` of those `tau`
/// gives at `s` (the module's formula).
pub fn slowed_torque(model: &Model, s: &State, tau: [f64; 3], factor: f64) -> [f64; 3] {
    let g = model.gravity(&s[..3]);
    let pull = model.hip_force_to_joint(&s[..3], model.perturbation(s));
    std::array::from_fn(|j| g[j] + (tau[j] - g[j] + pull[j]) / (factor * factor) - pull[j] / factor)
}

/// `actions` (a flat plan of `max_steps` rows) played `factor` times slower
/// from the squat: the feed-forward torque of the module's formula along the
/// slowed path plus a critically damped feedback onto it, clipped to the
/// torque limits. Once the slowed path is over, the feedback holds its last
/// pose. Returns the actions applied, `max_steps` rows.
pub fn stretch(task: &Task, actions: &[f64], factor: f64) -> Vec<f64> {
    let cfg = task.config();
    let model = task.model();
    let steps = cfg.max_steps as usize;
    let (states, applied) = state_path(task, actions);
    let mut ep = Episode::new(squat(task));
    let mut out = Vec::with_capacity(steps * ACTION_DIM);
    let mut done = false;
    for k in 0..steps {
        if done {
            // The episode is over; the rest of the plan is never played.
            out.extend_from_slice(&[0.0; ACTION_DIM]);
            continue;
        }
        // Feed-forward from the original step held at the middle of this
        // one; feedback towards the slowed path at this step's start.
        let (mid, held) = at_time(&states, &applied, (k as f64 + 0.5) / factor);
        let (goal, _) = at_time(&states, &applied, k as f64 / factor);
        let tau = match held {
            Some(a) => {
                let orig: [f64; 3] = std::array::from_fn(|j| a[j] * cfg.sim.tau_max[j]);
                slowed_torque(model, &mid, orig, factor)
            }
            None => model.gravity(&mid[..3]),
        };
        let m = model.mass_matrix(&ep.state[..3]);
        let mut acc = [0.0; 3];
        for j in 0..3 {
            let v_goal = goal[3 + j] / factor;
            acc[j] = TRACK_OMEGA * TRACK_OMEGA * (goal[j] - ep.state[j])
                + 2.0 * TRACK_ZETA * TRACK_OMEGA * (v_goal - ep.state[3 + j]);
        }
        let mut row = [0.0; ACTION_DIM];
        for j in 0..3 {
            let fb: f64 = (0..3).map(|c| m[j][c] * acc[c]).sum();
            row[j] = ((tau[j] + fb) / cfg.sim.tau_max[j]).clamp(-1.0, 1.0);
        }
        out.extend_from_slice(&row);
        done = task.step(&mut ep, &row, |_| {}).outcome.is_done();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::EnvConfig;

    fn task() -> Task {
        Task::new(&EnvConfig {
            init_noise: 0.0,
            ..EnvConfig::with_w1(1.0)
        })
        .unwrap()
    }

    /// The time-scaling identity, checked against the equations of motion:
    /// at the slowed state (same pose, velocities / s) the slowed torque
    /// gives exactly the accelerations / s^2, for rising (pull on) and
    /// sinking (pull off) states alike.
    #[test]
    fn the_slowed_torque_scales_the_accelerations_by_one_over_s_squared() {
        let t = task();
        let m = t.model();
        for (s, tau) in [
            ([0.4, -1.6, 1.8, -0.5, 1.2, -0.9], [60.0, 250.0, 120.0]),
            ([0.3, -1.2, 1.4, 0.4, -1.0, 0.8], [-20.0, 100.0, 200.0]),
        ] {
            let qdd = m.accelerations(&s, &tau, m.perturbation(&s));
            for factor in [0.8, 1.5, 2.0, 3.0] {
                let mut slow = s;
                for v in &mut slow[3..] {
                    *v /= factor;
                }
                // The formula takes the original state: its pull is the
                // original speed's.
                let tau_s = slowed_torque(m, &s, tau, factor);
                let got = m.accelerations(&slow, &tau_s, m.perturbation(&slow));
                for j in 0..3 {
                    let want = qdd[j] / (factor * factor);
                    assert!((got[j] - want).abs() < 1e-9 * (1.0 + want.abs()), "{got:?}");
                }
            }
        }
    }

    /// Stretching by 1 gives back the plan as played: the feed-forward is
    /// the original torque and the body is on the path, so the feedback is
    /// zero.
    #[test]
    fn a_stretch_by_one_replays_the_plan() {
        let t = task();
        let steps = t.config().max_steps as usize;
        let g = t.model().gravity(&t.config().sim.q0);
        let plan: Vec<f64> = (0..steps)
            .flat_map(|k| {
                let w = 0.3 * (k as f64 * 0.7).sin();
                (0..3).map(move |j| g[j] / [200.0, 400.0, 300.0][j] + w)
            })
            .collect();
        let (_, applied) = state_path(&t, &plan);
        let again = stretch(&t, &plan, 1.0);
        for (k, row) in applied.iter().enumerate() {
            for j in 0..3 {
                assert!((again[k * 3 + j] - row[j]).abs() < 1e-9, "step {k}");
            }
        }
    }

    /// A plan that holds the squat against gravity is the same plan at any
    /// speed: nothing moves, so nothing scales.
    #[test]
    fn a_hold_stays_a_hold() {
        let t = task();
        let cfg = t.config();
        let g = t.model().gravity(&cfg.sim.q0);
        let hold: Vec<f64> = (0..cfg.max_steps as usize)
            .flat_map(|_| (0..3).map(|j| g[j] / cfg.sim.tau_max[j]))
            .collect();
        for factor in [0.5, 2.0] {
            let s = stretch(&t, &hold, factor);
            for (a, b) in s.iter().zip(&hold) {
                assert!((a - b).abs() < 1e-6, "{a} vs {b}");
            }
        }
    }

    /// A stretched plan follows the slowed path: played twice as slowly,
    /// the body passes through the original's poses at twice the time,
    /// within 0.1 rad (0.065 measured) and closer than the plan with
    /// every action simply held twice as long.
    #[test]
    fn a_stretched_plan_follows_the_slowed_path() {
        let t = task();
        let cfg = t.config();
        let steps = cfg.max_steps as usize;
        // A smooth rise: gravity at the squat plus an extra push that fades.
        let g = t.model().gravity(&cfg.sim.q0);
        let plan: Vec<f64> = (0..steps)
            .flat_map(|k| {
                let push = 0.15 * (-(k as f64) / 3.0).exp();
                (0..3).map(move |j| g[j] / cfg.sim.tau_max[j] + [0.0, push, 0.5 * push][j])
            })
            .collect();
        let held_twice: Vec<f64> = (0..steps)
            .flat_map(|k| plan[(k / 2) * 3..(k / 2) * 3 + 3].to_vec())
            .collect();
        let (orig, _) = state_path(&t, &plan);
        let (slow, _) = state_path(&t, &stretch(&t, &plan, 2.0));
        let (naive, _) = state_path(&t, &held_twice);
        let n = (orig.len() - 1).min(6);
        assert!(n >= 3, "the original plan ends after {n} steps");
        assert!(slow.len() > 2 * n, "the stretched plan ended early");
        // A path that ended before twice the original's time (a fall) is
        // as far off as can be.
        let off = |path: &[State]| -> f64 {
            if path.len() <= 2 * n {
                return f64::INFINITY;
            }
            (1..=n)
                .flat_map(|k| (0..3).map(move |j| (k, j)))
                .map(|(k, j)| (path[2 * k][j] - orig[k][j]).abs())
                .fold(0.0, f64::max)
        };
        let (d_slow, d_naive) = (off(&slow), off(&naive));
        assert!(d_slow < 0.1, "{d_slow} rad off the slowed path");
        assert!(
            d_slow < d_naive,
            "stretched {d_slow} rad off, held twice {d_naive}"
        );
    }
}
