//! Seeded smoke tests of the whole trainer, the policy file and evaluation
//! (tiny budgets: the learning itself is measured in release mode).

use std::ops::ControlFlow;

use super::*;
use crate::env::EnvConfig;

fn tiny() -> PpoConfig {
    PpoConfig {
        env_steps: 2 * 8 * 32,
        n_envs: 8,
        n_steps: 32,
        epochs: 2,
        minibatch_size: 64,
        hidden: vec![16, 16],
        ..PpoConfig::default()
    }
}

fn train_tiny(seed: u64) -> TrainOutput {
    train(&tiny(), &EnvConfig::with_w1(2.0), seed, &mut |_| {
        ControlFlow::Continue(())
    })
    .unwrap()
}

#[test]
fn training_is_a_pure_function_of_config_and_seed() {
    let a = train_tiny(7);
    let b = train_tiny(7);
    assert_eq!(a.policy.to_json(), b.policy.to_json());
    assert_eq!(a.curve, b.curve);
    let c = train_tiny(8);
    assert_ne!(a.policy.to_json(), c.policy.to_json());
}

#[test]
fn training_reports_every_update_and_records_its_inputs() {
    let mut seen = Vec::new();
    let out = train(&tiny(), &EnvConfig::with_w1(2.0), 3, &mut |p| {
        seen.push(p.env_steps);
        ControlFlow::Continue(())
    })
    .unwrap();
    assert_eq!(seen, vec![256, 512]);
    assert_eq!(out.env_steps, 512);
    assert_eq!(out.curve.len(), 2);
    let p = &out.curve[1];
    assert_eq!(p.total_env_steps, 512);
    assert!(p.policy_loss.is_finite() && p.value_loss.is_finite() && p.approx_kl.is_finite());
    assert!((0.0..=1.0).contains(&p.success_rate));
    assert!(p.mean_episode_length > 0.0);
    // The policy records w1, the effective env and the config.
    assert_eq!(out.policy.w1(), 2.0);
    assert!(!out.policy.env.observe_time);
    assert_eq!(out.policy.obs_dim, 6);
    assert_eq!(out.policy.ppo, tiny());
    assert_eq!(out.policy.seed, 3);
}

#[test]
fn breaking_from_the_callback_cancels() {
    let err = train(&tiny(), &EnvConfig::default(), 1, &mut |_| {
        ControlFlow::Break(())
    })
    .unwrap_err();
    assert!(matches!(err, PpoError::Cancelled));
}

#[test]
fn terminal_mode_trains_with_the_time_feature() {
    let cfg = PpoConfig {
        time_limit: TimeLimit::Terminal,
        ..tiny()
    };
    let out = train(&cfg, &EnvConfig::default(), 1, &mut |_| {
        ControlFlow::Continue(())
    })
    .unwrap();
    assert_eq!(out.policy.obs_dim, 7);
    assert!(out.policy.env.observe_time);
    // The file keeps the effective environment, so it reloads and evaluates.
    let back = TrainedPolicy::from_json(&out.policy.to_json()).unwrap();
    assert_eq!(evaluate(&back, 10, 1).unwrap().episodes, 10);
}

#[test]
fn invalid_inputs_are_errors_not_panics() {
    let bad = PpoConfig {
        minibatch_size: 7,
        ..tiny()
    };
    let err = train(&bad, &EnvConfig::default(), 1, &mut |_| {
        ControlFlow::Continue(())
    })
    .unwrap_err();
    assert!(matches!(err, PpoError::InvalidConfig(_)), "{err}");
    let env = EnvConfig {
        max_steps: 0,
        ..EnvConfig::default()
    };
    let err = train(&tiny(), &env, 1, &mut |_| ControlFlow::Continue(())).unwrap_err();
    assert!(matches!(err, PpoError::Env(_)), "{err}");
}

#[test]
fn policy_file_round_trips_exactly() {
    let out = train_tiny(5);
    let json = out.policy.to_json();
    let back = TrainedPolicy::from_json(&json).unwrap();
    assert_eq!(back, out.policy);
    assert_eq!(back.to_json(), json);
}

#[test]
fn malformed_and_incompatible_policy_files_are_clear_errors() {
    let good = train_tiny(5).policy;
    let check = |text: &str, want: &str| {
        let err = TrainedPolicy::from_json(text).unwrap_err().to_string();
        assert!(err.contains(want), "expected {want:?} in {err:?}");
    };
    check("not json", "malformed policy file");
    check("{}", "missing \"format\"");
    check(
        r#"{"format": "something-else", "version": 1}"#,
        "incompatible policy file: format",
    );
    let mut v: serde_json::Value = serde_json::from_str(&good.to_json()).unwrap();
    v["version"] = 99.into();
    check(&v.to_string(), "version 99");
    let mut v: serde_json::Value = serde_json::from_str(&good.to_json()).unwrap();
    v["policy"]["params"].as_array_mut().unwrap().pop();
    check(&v.to_string(), "parameters");
    let mut v: serde_json::Value = serde_json::from_str(&good.to_json()).unwrap();
    v["obs_dim"] = 7.into();
    check(&v.to_string(), "obs_dim");
    let mut v: serde_json::Value = serde_json::from_str(&good.to_json()).unwrap();
    v["log_std"] = serde_json::json!([0.0, 0.0]);
    check(&v.to_string(), "log_std");
    let mut v: serde_json::Value = serde_json::from_str(&good.to_json()).unwrap();
    v["env"]["reward"]["w1"] = (-1.0).into();
    check(&v.to_string(), "w1");
    let mut v: serde_json::Value = serde_json::from_str(&good.to_json()).unwrap();
    v["policy"]["params"][0] = serde_json::json!("x");
    check(&v.to_string(), "malformed policy file");
    let mut nan = good.clone();
    nan.value.params[3] = f64::NAN;
    assert!(nan
        .validate()
        .unwrap_err()
        .to_string()
        .contains("not finite"));
}

#[test]
fn evaluation_is_deterministic_and_counts_every_episode() {
    let policy = train_tiny(2).policy;
    let a = evaluate(&policy, 70, 9).unwrap();
    let b = evaluate(&policy, 70, 9).unwrap();
    assert_eq!(a, b);
    assert_eq!(a.episodes, 70);
    assert!((0.0..=1.0).contains(&a.success_rate));
    assert!(a.mean_torque_usage > 0.0 && a.mean_episode_length >= 1.0);
    assert!(matches!(evaluate(&policy, 0, 1), Err(PpoError::NoEpisodes)));
}
