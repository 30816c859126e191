//! End-to-end checks of `irlgrid holdout` on real run directories: tiny
//! policies trained by `irlgrid train --no-sample`, whose `samples.json` is
//! replaced by hand-made bulging paths with known separations, so the
//! expected recovery is known without trusting the code under test.

use std::path::Path;
use std::process::{Command, Output};

use shared::test_support::StandUp;

fn irlgrid(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_irlgrid"))
        .args(args)
        .output()
        .unwrap()
}

/// A stand-up path bulging forward by `amp` (m), 200 Hz, as `samples.json`
/// carries an episode.
fn episode(amp: f64, ret: f64) -> serde_json::Value {
    let e = StandUp::new(amp)
        .sampled(61, 0.3)
        .rising(0.6, 0.38)
        .ret(ret)
        .steps(6)
        .episode();
    serde_json::to_value(e).unwrap()
}

/// A run directory at (w1, seed) whose kept episodes bulge by `amp`.
fn run_dir(root: &Path, w1: &str, seed: u32, amp: f64) {
    let dir = root.join(format!("w1_{w1}_s{seed}"));
    let out = irlgrid(&[
        "train",
        "--w1",
        w1,
        "--seed",
        &seed.to_string(),
        "--steps",
        "1024",
        "--eval-episodes",
        "200",
        "--no-sample",
        "--quiet",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let samples = serde_json::json!({
        "episodes": [episode(amp, 900.0), episode(amp + 0.002, 890.0)],
        "successes_found": 1000, "successes_wanted": 1000, "attempts": 1000
    });
    std::fs::write(dir.join("samples.json"), samples.to_string()).unwrap();
}

#[test]
fn holdout_counts_a_stray_trial_two_grid_steps_off_as_a_miss() {
    let root = tempfile::tempdir().unwrap();
    for (w1, amps) in [
        ("1", [0.02, 0.025, 0.03]),
        ("4", [0.06, 0.065, 0.07]),
        // The third w1 = 16 policy moves like a w1 = 1 one.
        ("16", [0.12, 0.125, 0.022]),
    ] {
        for (k, amp) in amps.into_iter().enumerate() {
            run_dir(root.path(), w1, 10 + k as u32, amp);
        }
    }
    let json = root.path().join("holdout.json");
    let out = irlgrid(&[
        "holdout",
        "--runs",
        root.path().to_str().unwrap(),
        "--out",
        json.to_str().unwrap(),
        "--require-within-one",
        "0.8",
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("9 cases; by area difference 8 exact, 8 within one grid step (89 %)"),
        "{stdout}"
    );
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap();
    assert_eq!(doc["values"], serde_json::json!([1.0, 4.0, 16.0]));
    assert_eq!(
        doc["methods"]["area"]["confusion"][2],
        serde_json::json!([1, 0, 2])
    );
    // Every case carries its true value and, per method, probabilities
    // aligned with `values`; the top level carries the coverage table.
    let cases = doc["case_list"].as_array().unwrap();
    assert_eq!(cases.len(), 9);
    for c in cases {
        assert!(c["value"].is_number());
        for m in ["area", "correlation", "posterior"] {
            let p = c["methods"][m]["probabilities"].as_array().unwrap();
            assert_eq!(p.len(), 3, "{m}");
            let total: f64 = p.iter().map(|v| v.as_f64().unwrap()).sum();
            assert!((total - 1.0).abs() < 1e-9, "{m}: {total}");
        }
    }
    let levels = doc["coverage"]["posterior"]["levels"].as_array().unwrap();
    let nominal: Vec<f64> = levels
        .iter()
        .map(|l| l["level"].as_f64().unwrap())
        .collect();
    assert_eq!(nominal, vec![0.5, 0.8, 0.9, 0.95]);
    assert!(doc["coverage"]["area"]["gain_nats"].is_number());
    assert!(
        stdout.contains("calibration of the highest-probability sets"),
        "{stdout}"
    );

    // Asking for more than that fails with the reason.
    let strict = irlgrid(&[
        "holdout",
        "--runs",
        root.path().to_str().unwrap(),
        "--require-within-one",
        "0.95",
    ]);
    assert_eq!(strict.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&strict.stderr).contains("8 of 9 held-out trials (89 %)"));
}

#[test]
fn holdout_rejects_bad_input_with_status_2() {
    let empty = tempfile::tempdir().unwrap();
    let out = irlgrid(&["holdout", "--runs", empty.path().to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("neither a run directory"));
    let out = irlgrid(&["holdout", "--runs", ".", "--require-within-one", "1.5"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--require-within-one must be in [0, 1]"));
}
