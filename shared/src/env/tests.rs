//! Every reward and termination rule of docs/science.md#task and
//! docs/science.md#reward, one focused test each, plus
//! the batch's reproducibility and auto-reset.

use super::*;
use crate::sim::State;

fn task(w1: f64) -> Task {
    Task::new(&EnvConfig::with_w1(w1)).unwrap()
}

fn height(task: &Task, s: &State) -> f64 {
    task.model().com(s).z / task.model().h_stand()
}

#[test]
fn success_reward_uses_the_step_count() {
    let t = task(1.0);
    let standing = [0.0; 6];
    assert_eq!(
        t.score(&standing, 7, 0.5),
        (1000.0 - 70.0, Outcome::Success)
    );
    assert_eq!(t.score(&standing, 60, 0.5), (400.0, Outcome::Success));
}

#[test]
fn each_joint_limit_fails_with_the_height_deficit_penalty() {
    let t = task(1.0);
    let cfg = SimConfig::default();
    for joint in 0..3 {
        for (limit, push) in [(cfg.q_min[joint], -1e-3), (cfg.q_max[joint], 1e-3)] {
            // Start from a pose above half height and move one joint just
            // past its limit (the knee's lower limit needs a forward shank).
            let mut s: State = if joint == 1 && push < 0.0 {
                [0.89, -2.4, 1.6, 0.0, 0.0, 0.0]
            } else {
                [0.2, -1.0, 1.0, 0.0, 0.0, 0.0]
            };
            s[joint] = limit + push;
            let h = height(&t, &s);
            let (r, o) = t.score(&s, 3, 0.0);
            assert_eq!(o, Outcome::Fail, "joint {joint} at {}", s[joint]);
            assert!((r - (-100.0 - 400.0 * (1.0 - h))).abs() < 1e-12);
            // Just inside the limit the step is not a failure.
            s[joint] = limit - push;
            assert!(height(&t, &s) >= 0.5);
            assert_ne!(t.score(&s, 3, 0.0).1, Outcome::Fail, "joint {joint} inside");
        }
    }
}

use crate::sim::SimConfig;

#[test]
fn low_height_fails() {
    let t = task(1.0);
    // A deep crouch inside every joint limit with the COM below half height.
    let s: State = [0.85, -2.35, 2.5, 0.0, 0.0, 0.0];
    let h = height(&t, &s);
    assert!(h < 0.5, "precondition: h = {h}");
    let (r, o) = t.score(&s, 1, 0.0);
    assert_eq!(o, Outcome::Fail);
    assert!((r - (-100.0 - 400.0 * (1.0 - h))).abs() < 1e-12);
}

#[test]
fn paper_literal_fail_penalty_uses_height() {
    let mut cfg = EnvConfig::default();
    cfg.reward.fail_penalty = FailPenalty::PaperLiteral;
    let t = Task::new(&cfg).unwrap();
    let s: State = [0.85, -2.35, 2.5, 0.0, 0.0, 0.0];
    let h = height(&t, &s);
    assert_eq!(t.score(&s, 1, 0.0), (-100.0 - 400.0 * h, Outcome::Fail));
}

#[test]
fn failure_is_checked_before_success() {
    let t = task(1.0);
    // Knee slightly over-straightened: standing tall and still, yet outside the limit.
    let s: State = [0.0, 0.11, 0.0, 0.0, 0.0, 0.0];
    assert!(height(&t, &s) >= 0.99);
    assert_eq!(t.score(&s, 5, 0.0).1, Outcome::Fail);
}

#[test]
fn tall_but_moving_earns_plus_one_whatever_the_torque() {
    let t = task(16.0);
    let s: State = [0.0, 0.0, 0.0, 0.3, 0.0, 0.0];
    assert!(height(&t, &s) >= 0.99);
    assert!(t.model().com(&s).speed() >= 0.1);
    assert_eq!(t.score(&s, 5, 1.7), (1.0, Outcome::Running));
}

#[test]
fn running_reward_is_height_minus_weighted_action_norm() {
    let t = task(2.0);
    let s: State = [0.3, -1.2, 1.0, 0.0, 0.0, 0.0];
    let h = height(&t, &s);
    assert!((0.5..0.99).contains(&h));
    let (r, o) = t.score(&s, 10, 0.75);
    assert_eq!(o, Outcome::Running);
    assert!((r - (h - 2.0 * 0.75)).abs() < 1e-15);
}

#[test]
fn time_limit_truncates_with_only_the_running_reward() {
    let t = task(1.0);
    let s: State = [0.3, -1.2, 1.0, 0.0, 0.0, 0.0];
    let h = height(&t, &s);
    assert_eq!(t.score(&s, 59, 0.5).1, Outcome::Running);
    let (r, o) = t.score(&s, 60, 0.5);
    assert_eq!(o, Outcome::Truncated);
    assert!((r - (h - 0.5)).abs() < 1e-15);
}

#[test]
fn step_clips_actions_and_accumulates_torque_usage() {
    let t = task(1.0);
    let mut ep = Episode::new(t.initial_state(&mut rand::rngs::mock::StepRng::new(0, 0)));
    let mut ep2 = ep;
    let info = t.step(&mut ep, &[5.0, -5.0, 0.5], |_| {});
    let info2 = t.step(&mut ep2, &[1.0, -1.0, 0.5], |_| {});
    assert_eq!(info, info2, "actions beyond [-1, 1] are clipped");
    let tau_norm = (200.0_f64.powi(2) + 400.0_f64.powi(2) + 150.0_f64.powi(2)).sqrt();
    assert!((info.episode_torque_usage - tau_norm * 0.05).abs() < 1e-12);
    assert_eq!(info.episode_len, 1);
    let a_norm = (1.0_f64 + 1.0 + 0.25).sqrt();
    if info.outcome == Outcome::Running {
        let h = height(&t, &ep.state);
        assert!((info.reward - (h - a_norm)).abs() < 1e-12);
    }
}

#[test]
fn zero_action_from_the_squat_falls_and_the_return_adds_up() {
    let t = task(1.0);
    let mut ep = Episode::new(t.initial_state(&mut rand::rngs::mock::StepRng::new(0, 0)));
    let mut sum = 0.0;
    let last = loop {
        let info = t.step(&mut ep, &[0.0; 3], |_| {});
        sum += info.reward;
        if info.outcome.is_done() {
            break info;
        }
    };
    assert_eq!(last.outcome, Outcome::Fail);
    assert!((last.episode_return - sum).abs() < 1e-9);
    assert!(last.episode_len < 60);
}

#[test]
fn observation_appends_time_fraction_only_when_switched_on() {
    let mut cfg = EnvConfig::default();
    assert_eq!(cfg.obs_dim(), 6);
    cfg.observe_time = true;
    let t = Task::new(&cfg).unwrap();
    let mut ep = Episode::new([0.1, 0.2, 0.3, 0.4, 0.5, 0.6]);
    ep.t = 15;
    let mut obs = [0.0; 7];
    t.observe(&ep, &mut obs);
    assert_eq!(obs, [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.25]);
}

#[test]
fn initial_noise_stays_within_bounds() {
    let t = task(1.0);
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(9);
    for _ in 0..1000 {
        let s = t.initial_state(&mut rng);
        for i in 0..3 {
            assert!((s[i] - t.config().sim.q0[i]).abs() <= 0.02);
            assert_eq!(s[3 + i], 0.0);
        }
    }
}

#[test]
fn batch_matches_single_environments_and_resets() {
    // Nine environments: one full block of eight and one padded block.
    const N: usize = 9;
    let cfg = EnvConfig::with_w1(1.0);
    let mut batch = BatchEnv::new(&cfg, N, 42).unwrap();
    batch.set_record_com(true);
    let t = task(1.0);
    let mut singles: Vec<Episode> = (0..N)
        .map(|i| {
            let mut o = [0.0; 6];
            o.copy_from_slice(&batch.observations()[i * 6..i * 6 + 6]);
            Episode::new(o)
        })
        .collect();
    let actions: Vec<f64> = (0..3 * N)
        .map(|k| ((k as f64) * 0.37).sin() * 0.6)
        .collect();
    let mut resets = 0;
    for _ in 0..70 {
        let infos = batch.step(&actions).unwrap().to_vec();
        for i in 0..N {
            let single = t.step(&mut singles[i], &actions[i * 3..i * 3 + 3], |_| {});
            // The batch's vector trigonometry is a polynomial, not libm, so
            // values agree to rounding, and outcomes exactly.
            let (b, s) = (infos[i], single);
            assert_eq!((b.outcome, b.episode_len), (s.outcome, s.episode_len));
            assert!((b.reward - s.reward).abs() < 1e-9, "{b:?} vs {s:?}");
            assert!((b.episode_return - s.episode_return).abs() < 1e-9);
            assert!((b.episode_torque_usage - s.episode_torque_usage).abs() < 1e-9);
            if single.outcome.is_done() {
                resets += 1;
                let close =
                    |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12);
                assert!(close(batch.final_observation(i), &singles[i].state[..]));
                let path = batch.finished_path(i);
                assert_eq!(path.t.len(), 1 + 10 * single.episode_len as usize);
                assert!(
                    (path.t[path.t.len() - 1] - 0.05 * f64::from(single.episode_len)).abs() < 1e-12
                );
                let c = t.model().com(&singles[i].state);
                assert!(close(
                    &[path.x[path.x.len() - 1], path.z[path.z.len() - 1]],
                    &[c.x, c.z]
                ));
                let mut o = [0.0; 6];
                o.copy_from_slice(&batch.observations()[i * 6..i * 6 + 6]);
                singles[i] = Episode::new(o);
            }
        }
    }
    assert!(resets >= N, "every env finished at least once");
}

#[test]
fn batch_is_reproducible_and_streams_differ() {
    let cfg = EnvConfig::default();
    let a = BatchEnv::new(&cfg, 3, 7).unwrap();
    let b = BatchEnv::new(&cfg, 3, 7).unwrap();
    let c = BatchEnv::new(&cfg, 3, 8).unwrap();
    assert_eq!(a.observations(), b.observations());
    assert_ne!(a.observations(), c.observations());
    assert_ne!(a.observations()[..6], a.observations()[6..12]);
}

#[test]
fn bad_inputs_are_typed_errors() {
    let cfg = EnvConfig::default();
    assert!(BatchEnv::new(&cfg, 0, 1).is_err());
    let mut b = BatchEnv::new(&cfg, 2, 1).unwrap();
    assert_eq!(
        b.step(&[0.0; 5]).unwrap_err(),
        EnvError::ActionShape {
            expected: 6,
            got: 5
        }
    );
    let mut r = RewardConfig::default();
    assert!(r.set_param("w1", -1.0).is_err());
    assert!(r.set_param("nope", 1.0).is_err());
    r.set_param("w1", 4.0).unwrap();
    assert_eq!(r.w1, 4.0);
    let json = r#"{"reward": {"w1": 2.0, "fail_penalty": "paper_literal"}}"#;
    let parsed: EnvConfig = serde_json::from_str(json).unwrap();
    assert_eq!(parsed.reward.w1, 2.0);
    assert_eq!(parsed.reward.fail_penalty, FailPenalty::PaperLiteral);
    assert_eq!(parsed.max_steps, 60);
}
