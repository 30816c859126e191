//! Property tests on the parsers that read outside input: the
//! subject CSV reader and the policy file reader. Arbitrary input never
//! panics and gives either a typed error or a value that passes the
//! parser's own checks; valid generated input round-trips exactly.
//!
//! A few hundred cases per property keep `cargo test` quick;
//! `PROPTEST_CASES=10000 cargo test -p shared --test prop_parsers` runs a
//! longer search.

use std::collections::BTreeMap;

use proptest::prelude::*;
use rand::SeedableRng;
use serde_json::Value;
use shared::analysis::{parse_subjects_csv, subjects_to_csv, AnalysisError, SubjectPath};
use shared::env::EnvConfig;
use shared::ppo::normalize::RunningMeanStd;
use shared::ppo::{ActorCritic, PpoConfig, PpoError, TrainedPolicy};

fn cases(default: u32) -> ProptestConfig {
    let n = std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default);
    ProptestConfig::with_cases(n)
}

/// Any JSON value, a few levels deep.
fn json_value() -> impl Strategy<Value = Value> {
    let leaf = prop_oneof![
        Just(Value::Null),
        any::<bool>().prop_map(Value::Bool),
        any::<i64>().prop_map(Value::from),
        any::<u64>().prop_map(Value::from),
        any::<f64>()
            .prop_map(|f| serde_json::Number::from_f64(f).map_or(Value::Null, Value::Number)),
        ".{0,12}".prop_map(Value::String),
    ];
    leaf.prop_recursive(4, 48, 6, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..6).prop_map(Value::Array),
            prop::collection::btree_map("[a-z_]{1,10}", inner, 0..6)
                .prop_map(|m| Value::Object(m.into_iter().collect())),
        ]
    })
}

// ---------------------------------------------------------------- CSV

/// Text that looks like a subject CSV: the header (usually) and rows of
/// plausible and implausible fields.
fn csv_like() -> impl Strategy<Value = String> {
    let field = prop_oneof![
        "[a-z]{1,4}",
        "-?[0-9]{1,3}(\\.[0-9]{1,3})?",
        Just(String::new()),
        Just("NaN".to_string()),
        Just("inf".to_string()),
        Just("1e999".to_string()),
        "\"[a-z,\" ]{0,5}\"?",
        " +",
        ".{0,4}",
    ];
    let row = prop::collection::vec(field, 0..6).prop_map(|f| f.join(","));
    (
        prop_oneof![
            Just("subject,time,x,z".to_string()),
            Just("\u{feff}subject,time,x,z  ".to_string()),
            ".{0,20}"
        ],
        prop::collection::vec(row, 0..30),
        prop_oneof![Just("\n"), Just("\r\n")],
    )
        .prop_map(|(h, rows, nl)| {
            let mut s = h;
            for r in rows {
                s.push_str(nl);
                s.push_str(&r);
            }
            s
        })
}

/// Checks what the reader promises for any input.
fn check_csv_outcome(text: &str) -> Result<(), TestCaseError> {
    match parse_subjects_csv(text) {
        Ok(subjects) => {
            prop_assert!(!subjects.is_empty());
            for s in &subjects {
                prop_assert!(!s.subject.is_empty());
                prop_assert!(s.t.len() >= 4);
                prop_assert_eq!(s.t.len(), s.x.len());
                prop_assert_eq!(s.t.len(), s.z.len());
                prop_assert!(s.t.windows(2).all(|w| w[0] < w[1]));
                prop_assert!(s.t.iter().chain(&s.x).chain(&s.z).all(|v| v.is_finite()));
            }
            // What was read writes and reads back the same.
            prop_assert_eq!(
                parse_subjects_csv(&subjects_to_csv(&subjects)).unwrap(),
                subjects
            );
        }
        Err(AnalysisError::Csv { line, msg }) => {
            prop_assert!(line >= 1);
            prop_assert!(!msg.is_empty());
        }
        Err(other) => prop_assert!(false, "unexpected error kind: {other}"),
    }
    Ok(())
}

fn finite() -> impl Strategy<Value = f64> {
    prop_oneof![
        -1e6..1e6f64,
        Just(0.0),
        Just(-0.0),
        Just(1e-300),
        Just(-1e300)
    ]
}

/// Valid subjects: distinct non-empty names without line breaks (any
/// other character, commas and quotes included), 4-40 samples each in
/// strictly increasing time.
fn subjects() -> impl Strategy<Value = Vec<SubjectPath>> {
    let path = (
        prop::collection::vec((0.001..10.0f64, finite(), finite()), 4..40),
        -100.0..100.0f64,
    )
        .prop_map(|(steps, t0)| {
            let mut t = t0;
            let (mut ts, mut xs, mut zs) = (Vec::new(), Vec::new(), Vec::new());
            for (dt, x, z) in steps {
                t += dt;
                ts.push(t);
                xs.push(x);
                zs.push(z);
            }
            (ts, xs, zs)
        });
    prop::collection::btree_map("[^\\r\\n]{1,12}", path, 1..5).prop_map(|m: BTreeMap<_, _>| {
        m.into_iter()
            .map(|(subject, (t, x, z))| SubjectPath { subject, t, x, z })
            .collect()
    })
}

proptest! {
    #![proptest_config(cases(300))]

    #[test]
    fn csv_reader_never_panics_on_arbitrary_text(text in ".{0,400}") {
        check_csv_outcome(&text)?;
    }

    #[test]
    fn csv_reader_never_panics_on_csv_like_text(text in csv_like()) {
        check_csv_outcome(&text)?;
    }

    #[test]
    fn csv_reader_never_panics_on_arbitrary_bytes(bytes in prop::collection::vec(any::<u8>(), 0..300)) {
        check_csv_outcome(&String::from_utf8_lossy(&bytes))?;
    }

    #[test]
    fn valid_subjects_round_trip_through_csv(subjects in subjects()) {
        let text = subjects_to_csv(&subjects);
        let back = parse_subjects_csv(&text).map_err(|e| TestCaseError::fail(format!("{e}\n{text}")))?;
        prop_assert_eq!(back, subjects);
        // CRLF line ends read the same.
        prop_assert_eq!(parse_subjects_csv(&text.replace('\n', "\r\n")).unwrap(), parse_subjects_csv(&text).unwrap());
    }
}

// ---------------------------------------------------------------- policy

/// A valid policy with small random networks.
fn policy(hidden: &[usize], seed: u64, tall: bool) -> TrainedPolicy {
    let env = EnvConfig {
        observe_time: tall,
        ..EnvConfig::default()
    };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let model = ActorCritic::new(env.obs_dim(), 3, hidden, -0.5, &mut rng);
    let obs_dim = env.obs_dim();
    TrainedPolicy::new(
        model,
        RunningMeanStd::new(obs_dim),
        PpoConfig::default(),
        env,
        seed,
        seed % 100_000,
    )
}

fn check_policy_outcome(text: &str) -> Result<(), TestCaseError> {
    match TrainedPolicy::from_json(text) {
        Ok(p) => {
            prop_assert!(p.validate().is_ok());
            prop_assert!(p.model().is_ok());
            prop_assert_eq!(TrainedPolicy::from_json(&p.to_json()).unwrap(), p);
        }
        Err(PpoError::MalformedPolicy(m) | PpoError::IncompatiblePolicy(m)) => {
            prop_assert!(!m.is_empty());
        }
        // Config validation errors of the embedded ppo/env sections.
        Err(e) => prop_assert!(!e.to_string().is_empty()),
    }
    Ok(())
}

/// Replaces (or, in an object, sometimes removes) the value at a path
/// into `v` chosen by `picks` (objects and arrays only; a leaf on the way
/// is replaced itself).
fn mutate(v: &mut Value, picks: &[usize], replacement: Value) {
    let Some((&p, rest)) = picks.split_first() else {
        *v = replacement;
        return;
    };
    match v {
        Value::Object(m) if !m.is_empty() => {
            let k = m.keys().nth(p % m.len()).cloned().unwrap_or_default();
            if rest.is_empty() && p % 5 == 0 {
                m.remove(&k);
            } else if let Some(child) = m.get_mut(&k) {
                mutate(child, rest, replacement);
            }
        }
        Value::Array(a) if !a.is_empty() => {
            let i = p % a.len();
            mutate(&mut a[i], rest, replacement);
        }
        other => *other = replacement,
    }
}

proptest! {
    #![proptest_config(cases(300))]

    #[test]
    fn policy_reader_never_panics_on_arbitrary_text(text in ".{0,300}") {
        check_policy_outcome(&text)?;
    }

    #[test]
    fn policy_reader_never_panics_on_arbitrary_json_with_the_header(mut v in json_value(), body in json_value()) {
        // Past the format/version header, into field-level parsing.
        let mut obj = match body { Value::Object(m) => m, _ => serde_json::Map::new() };
        obj.insert("format".into(), "irlgrid-ppo-policy".into());
        obj.insert("version".into(), 1.into());
        if let Value::Object(extra) = &mut v { obj.append(extra); }
        check_policy_outcome(&Value::Object(obj).to_string())?;
    }

    #[test]
    fn mutated_policy_files_are_errors_or_valid(
        seed in any::<u64>(),
        picks in prop::collection::vec(any::<usize>(), 1..5),
        replacement in json_value(),
    ) {
        let mut v: Value = serde_json::from_str(&policy(&[4], seed, seed % 2 == 0).to_json()).unwrap();
        mutate(&mut v, &picks, replacement);
        check_policy_outcome(&v.to_string())?;
    }

    #[test]
    fn valid_policies_round_trip_exactly(
        hidden in prop::collection::vec(1usize..9, 0..3),
        seed in any::<u64>(),
        tall in any::<bool>(),
    ) {
        let p = policy(&hidden, seed, tall);
        let json = p.to_json();
        let back = TrainedPolicy::from_json(&json).map_err(|e| TestCaseError::fail(e.to_string()))?;
        prop_assert_eq!(&back, &p);
        prop_assert_eq!(back.to_json(), json);
    }
}
