//! Property tests on the coordinator's input validation: search
//! submission (`intake::prepare_search`), result uploads
//! (`intake::validate_output`) and heartbeats. Arbitrary input never
//! panics and gives a 400 naming a field or a value that keeps the
//! documented limits; valid generated input is accepted and round-trips.
//!
//! `PROPTEST_CASES=10000 cargo test -p coordinator --test prop_validation`
//! searches longer.

use std::collections::{BTreeMap, BTreeSet};

use coordinator::domain::DomainError;
use coordinator::intake::{
    prepare_search, validate_heartbeat, validate_output, MAX_JOBS, MAX_POINTS,
};
use proptest::prelude::*;
use serde_json::{json, Value};
use shared::analysis::EpisodeRecord;
use shared::api::{Heartbeat, JobOutput, Partial, ResolvedConfig, ResultUpload, SearchRequest};

fn cases(default: u32) -> ProptestConfig {
    let n = std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default);
    ProptestConfig::with_cases(n)
}

/// Numbers JSON can carry, edge cases included.
fn number() -> impl Strategy<Value = Value> {
    prop_oneof![
        any::<i64>().prop_map(Value::from),
        any::<u64>().prop_map(Value::from),
        (-1e3..1e3f64).prop_map(Value::from),
        any::<f64>().prop_map(Value::from),
        Just(json!(0)),
        Just(json!(-1)),
        Just(json!(1e308)),
        Just(json!(u32::MAX)),
    ]
}

/// Any JSON value, a few levels deep.
fn json_value() -> impl Strategy<Value = Value> {
    let leaf = prop_oneof![
        Just(Value::Null),
        any::<bool>().prop_map(Value::Bool),
        number(),
        ".{0,10}".prop_map(Value::String),
    ];
    leaf.prop_recursive(3, 32, 5, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..5).prop_map(Value::Array),
            prop::collection::btree_map("[a-z_0-9]{1,12}", inner, 0..5)
                .prop_map(|m| Value::Object(m.into_iter().collect())),
        ]
    })
}

const SEARCH_FIELDS: &[&str] = &[
    "name",
    "reward_grid",
    "trials",
    "seed",
    "training",
    "sampling",
    "env",
    "subjects_csv",
    "convergence_threshold",
    "replace_unconverged",
    "max_trials_per_point",
    "max_attempts",
];

/// Config-shaped values: objects with the configs' real field names.
fn config_value() -> impl Strategy<Value = Value> {
    let key = prop_oneof![
        Just("env_steps"),
        Just("n_envs"),
        Just("learning_rate"),
        Just("hidden"),
        Just("successful_episodes"),
        Just("top_k"),
        Just("max_attempts"),
        Just("reward"),
        Just("w1"),
        Just("max_steps"),
        Just("bogus"),
    ];
    prop_oneof![
        json_value(),
        prop::collection::btree_map(key, prop_oneof![number(), json_value()], 0..4)
            .prop_map(|m| Value::Object(m.into_iter().map(|(k, v)| (k.to_string(), v)).collect())),
    ]
}

/// Search-request-shaped JSON: the real field names with arbitrary or
/// plausible values, sometimes an unknown field.
fn search_json() -> impl Strategy<Value = Value> {
    let grid = prop_oneof![
        json_value(),
        prop::collection::btree_map(
            prop_oneof![
                Just("w1".to_string()),
                Just("tall_reward".to_string()),
                "[a-z1]{1,6}"
            ],
            prop::collection::vec(
                prop_oneof![(-5.0..50.0f64).prop_map(Value::from), number()],
                0..20
            )
            .prop_map(Value::Array),
            0..6
        )
        .prop_map(|m| Value::Object(m.into_iter().collect())),
    ];
    let value_for = move |k: &str| -> BoxedStrategy<Value> {
        match k {
            "reward_grid" => grid.clone().boxed(),
            "training" | "sampling" | "env" => config_value().boxed(),
            "trials" | "max_trials_per_point" | "max_attempts" | "seed" => {
                prop_oneof![(0u32..500).prop_map(Value::from), number()].boxed()
            }
            _ => json_value().boxed(),
        }
    };
    prop::collection::btree_set(prop::sample::select(SEARCH_FIELDS), 0..SEARCH_FIELDS.len())
        .prop_flat_map(move |keys| {
            let parts: Vec<_> = keys
                .into_iter()
                .map(|k| value_for(k).prop_map(move |v| (k.to_string(), v)))
                .collect();
            (parts, any::<bool>())
        })
        .prop_map(|(parts, extra)| {
            let mut m: serde_json::Map<String, Value> = parts.into_iter().collect();
            if extra {
                m.insert("unknown_field".into(), json!(1));
            }
            Value::Object(m)
        })
}

/// What a successful `prepare_search` must satisfy.
fn check_search_outcome(req: &SearchRequest) -> Result<(), TestCaseError> {
    match prepare_search(req, "id".into()) {
        Ok(s) => {
            prop_assert!(!s.points.is_empty() && s.points.len() <= MAX_POINTS);
            let product: usize = req.reward_grid.values().map(Vec::len).product();
            prop_assert_eq!(s.points.len(), product);
            prop_assert!(s.points.len() as u64 * u64::from(s.max_trials_per_point) <= MAX_JOBS);
            prop_assert!((1..=100).contains(&s.trials));
            prop_assert!(s.max_trials_per_point >= s.trials);
            prop_assert!((0.0..=1.0).contains(&s.threshold));
            prop_assert!((1..=20).contains(&s.max_attempts));
            // The stored request and resolved config read back.
            let back: SearchRequest = serde_json::from_str(&s.request).unwrap();
            prop_assert_eq!(&back, req);
            let cfg: ResolvedConfig = serde_json::from_str(&s.config).unwrap();
            prop_assert_eq!(serde_json::to_string(&cfg).unwrap(), s.config);
        }
        Err(DomainError::Invalid(msg)) => prop_assert!(!msg.is_empty()),
        Err(other) => prop_assert!(false, "unexpected error kind: {other:?}"),
    }
    Ok(())
}

proptest! {
    #![proptest_config(cases(300))]

    #[test]
    fn search_validation_never_panics(v in search_json()) {
        // The JSON extractor's step (typed error on mismatch), then ours.
        if let Ok(req) = serde_json::from_value::<SearchRequest>(v) {
            check_search_outcome(&req)?;
        }
    }

    #[test]
    fn search_validation_never_panics_on_typed_requests(
        name in ".{0,220}",
        grid in prop::collection::btree_map("[a-z_1]{1,12}", prop::collection::vec(any::<f64>(), 0..70), 0..6),
        trials in any::<u32>(),
        threshold in prop::option::of(any::<f64>()),
        cap in prop::option::of(any::<u32>()),
        attempts in prop::option::of(any::<u32>()),
        replace in any::<bool>(),
        csv in prop::option::of(".{0,200}"),
    ) {
        let req = SearchRequest {
            name,
            reward_grid: grid,
            trials,
            convergence_threshold: threshold,
            max_trials_per_point: cap,
            max_attempts: attempts,
            replace_unconverged: replace,
            subjects_csv: csv,
            ..SearchRequest::default()
        };
        check_search_outcome(&req)?;
    }

    #[test]
    fn valid_searches_are_accepted_with_every_grid_point(
        w1 in prop::collection::btree_set(1u32..2000, 1..16),
        trials in 1u32..=20,
        seed in any::<u64>(),
        threshold in 0.0..=1.0f64,
        replace in any::<bool>(),
        env_steps in 1u64..1_000_000,
    ) {
        let values: Vec<f64> = w1.iter().map(|&v| f64::from(v) / 100.0).collect();
        let req = SearchRequest {
            name: "prop".into(),
            reward_grid: BTreeMap::from([("w1".to_string(), values.clone())]),
            trials,
            seed,
            training: Some(Partial::from_value(json!({"env_steps": env_steps})).unwrap()),
            convergence_threshold: Some(threshold),
            replace_unconverged: replace,
            ..SearchRequest::default()
        };
        let s = prepare_search(&req, "id".into()).map_err(|e| TestCaseError::fail(e.to_string()))?;
        let got: BTreeSet<u64> = s.points.iter().map(|p| p["w1"].to_bits()).collect();
        prop_assert_eq!(got, values.iter().map(|v| v.to_bits()).collect::<BTreeSet<_>>());
        let cfg: ResolvedConfig = serde_json::from_str(&s.config).unwrap();
        prop_assert_eq!(cfg.training.env_steps, env_steps);
        check_search_outcome(&req)?;
    }
}

// ---------------------------------------------------------------- uploads

/// The resolved configuration of a search asking for 10 successes, top 10.
fn resolved() -> ResolvedConfig {
    let req = SearchRequest {
        reward_grid: BTreeMap::from([("w1".to_string(), vec![1.0])]),
        trials: 1,
        sampling: Some(
            Partial::from_value(json!({"successful_episodes": 10, "top_k": 10})).unwrap(),
        ),
        ..SearchRequest::default()
    };
    serde_json::from_str(&prepare_search(&req, "id".into()).unwrap().config).unwrap()
}

fn any_float() -> impl Strategy<Value = f64> {
    prop_oneof![
        4 => -10.0..10.0f64,
        1 => any::<f64>(),
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(-0.0),
    ]
}

fn any_episode() -> impl Strategy<Value = EpisodeRecord> {
    (
        prop::collection::vec(any_float(), 0..30),
        prop::collection::vec(any_float(), 0..30),
        prop::collection::vec(any_float(), 0..30),
        any_float(),
        any_float(),
        any::<u32>(),
    )
        .prop_map(
            |(com_t, com_x, com_z, ret, torque_usage, steps)| EpisodeRecord {
                com_t,
                com_x,
                com_z,
                ret,
                torque_usage,
                steps,
            },
        )
}

fn any_output() -> impl Strategy<Value = JobOutput> {
    (
        any_float(),
        prop_oneof![any::<u64>(), 0u64..1_000_000],
        0u32..15,
        prop_oneof![Just(10u32), any::<u32>()],
        prop_oneof![any::<u32>(), 0u32..100],
        prop::collection::vec(any_episode(), 0..12),
        any_float(),
        any_float(),
    )
        .prop_map(
            |(rate, steps, found, wanted, attempts, episodes, ts, ss)| JobOutput {
                final_success_rate: rate,
                env_steps: steps,
                successes_found: found,
                successes_wanted: wanted,
                sampling_attempts: attempts,
                episodes,
                train_secs: ts,
                sample_secs: ss,
            },
        )
}

/// A valid episode of `n` samples.
fn valid_episode() -> impl Strategy<Value = EpisodeRecord> {
    (
        2usize..500,
        0.001..0.1f64,
        -1e3..1e3f64,
        0.0..1e3f64,
        any::<u32>(),
    )
        .prop_map(|(n, dt, ret, torque, steps)| EpisodeRecord {
            com_t: (0..n).map(|i| i as f64 * dt).collect(),
            com_x: (0..n).map(|i| (i as f64 * 0.1).sin()).collect(),
            com_z: (0..n).map(|i| 0.6 + i as f64 * 1e-3).collect(),
            ret,
            torque_usage: torque,
            steps,
        })
}

proptest! {
    #![proptest_config(cases(300))]

    #[test]
    fn upload_validation_never_panics(out in any_output()) {
        let cfg = resolved();
        match validate_output(&out, &cfg, 0) {
            Ok(()) => {
                prop_assert!((0.0..=1.0).contains(&out.final_success_rate));
                prop_assert!(out.episodes.len() <= 10);
                prop_assert!(out.episodes.len() <= out.successes_found as usize);
                prop_assert_eq!(out.successes_wanted, 10);
                for e in &out.episodes {
                    prop_assert!(e.com_t.len() >= 2);
                    prop_assert!(e.com_t.len() == e.com_x.len() && e.com_t.len() == e.com_z.len());
                    prop_assert!(e.com_t.iter().chain(&e.com_x).chain(&e.com_z).all(|v| v.is_finite()));
                    prop_assert!(e.torque_usage.is_finite() && e.torque_usage >= 0.0);
                }
                // What is accepted is stored as JSON and reads back the same.
                let text = serde_json::to_string(&out).unwrap();
                prop_assert_eq!(serde_json::from_str::<JobOutput>(&text).unwrap(), out);
            }
            Err(DomainError::Invalid(msg)) => prop_assert!(msg.starts_with("output."), "{}", msg),
            Err(other) => prop_assert!(false, "unexpected error kind: {other:?}"),
        }
    }

    #[test]
    fn valid_uploads_are_accepted_and_round_trip(
        episodes in prop::collection::vec(valid_episode(), 0..=10),
        extra in 0u32..5,
        rate in 0.0..=1.0f64,
        token in "[0-9a-f]{32}",
    ) {
        let found = episodes.len() as u32 + extra.min(10 - episodes.len() as u32);
        let up = ResultUpload {
            lease_token: token,
            output: JobOutput {
                final_success_rate: rate,
                env_steps: 1000,
                successes_found: found,
                successes_wanted: 10,
                sampling_attempts: found + 3,
                episodes,
                train_secs: 1.0,
                sample_secs: 0.5,
            },
        };
        validate_output(&up.output, &resolved(), 0).map_err(|e| TestCaseError::fail(e.to_string()))?;
        let text = serde_json::to_string(&up).unwrap();
        prop_assert_eq!(serde_json::from_str::<ResultUpload>(&text).unwrap(), up);
    }

    #[test]
    fn upload_and_heartbeat_bodies_never_panic(v in json_value(), out in any_output(), token in ".{0,140}") {
        // Arbitrary JSON is a typed serde error or a value we then validate.
        if let Ok(up) = serde_json::from_value::<ResultUpload>(v.clone()) {
            let _ = validate_output(&up.output, &resolved(), 0);
        }
        if let Ok(hb) = serde_json::from_value::<Heartbeat>(v) {
            let _ = validate_heartbeat(&hb);
        }
        // A well-formed body with arbitrary numbers, and arbitrary tokens.
        // (Non-finite numbers have no JSON form: they become null and a
        // typed error.)
        let body = json!({"lease_token": token, "output": out});
        if let Ok(up) = serde_json::from_value::<ResultUpload>(body) {
            let _ = validate_output(&up.output, &resolved(), 0);
        }
        let hb = json!({"lease_token": token, "progress": [{"env_steps": 1, "total_env_steps": 1}]});
        let hb: Heartbeat = serde_json::from_value(hb).unwrap();
        match validate_heartbeat(&hb) {
            Ok(()) => prop_assert!(!hb.lease_token.is_empty() && hb.lease_token.len() <= 128),
            Err(DomainError::Invalid(_)) => {}
            Err(other) => prop_assert!(false, "unexpected error kind: {other:?}"),
        }
    }
}
