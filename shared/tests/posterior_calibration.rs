//! Calibration of the posterior on synthetic grids whose trials are drawn
//! from known distributions: each trial's stand-up path bulges by
//! `a sin(pi s) + b sin(2 pi s)` with (a, b) drawn from a Gaussian around
//! its grid point's centre, neighbouring centres overlapping. Held out one
//! at a time, the posterior's 90 % sets must hold the true value in 85 to
//! 95 % of the cases, and its log score must beat a uniform guess.

use std::collections::BTreeMap;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use shared::analysis::{
    hold_out_recovery, EpisodeRecord, Method, ReportOptions, TrialInput, WeightInput,
};
use shared::test_support::StandUp;

fn episode(a: f64, b: f64) -> EpisodeRecord {
    StandUp::real_sized(a).wobble(b).episode()
}

/// A grid of `points` values whose trial bulges (a, b) are drawn around
/// centres `0.012 k` and `0.004 k` with SDs 0.008 and 0.006: neighbours
/// overlap, so the posterior must spread its mass.
fn synthetic_grid(seed: u64, points: usize, trials: u32) -> Vec<WeightInput> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let na = Normal::new(0.0, 0.008).unwrap();
    let nb = Normal::new(0.0, 0.006).unwrap();
    (0..points)
        .map(|k| {
            let (ca, cb) = (0.012 * k as f64, 0.004 * k as f64);
            WeightInput {
                params: BTreeMap::from([("w1".to_string(), 2f64.powi(k as i32))]),
                trials: (0..trials)
                    .map(|t| TrialInput {
                        trial: t,
                        seed: 1000 + u64::from(t),
                        final_success_rate: 1.0,
                        converged: true,
                        episodes: vec![episode(
                            0.03 + ca + na.sample(&mut rng),
                            cb + nb.sample(&mut rng),
                        )],
                        successes_found: 1000,
                        successes_wanted: 1000,
                        solver: Default::default(),
                    })
                    .collect(),
            }
        })
        .collect()
}

#[test]
fn posterior_ninety_percent_sets_cover_the_truth_85_to_95_percent_of_the_time() {
    let (mut covered, mut cases, mut gain) = (0.0, 0.0, 0.0);
    for seed in 0..6 {
        let grid = synthetic_grid(seed, 6, 15);
        let r = hold_out_recovery(&grid, &ReportOptions::default());
        let cal = &r.coverage[&Method::Posterior];
        let at90 = cal.levels.iter().find(|l| l.level == 0.9).unwrap();
        covered += at90.coverage * f64::from(cal.cases);
        cases += f64::from(cal.cases);
        gain += cal.gain_nats * f64::from(cal.cases);
    }
    let coverage = covered / cases;
    let gain = gain / cases;
    eprintln!("posterior 90 % coverage {coverage:.3}, gain {gain:.3} nats over {cases} cases");
    assert_eq!(cases, 6.0 * 6.0 * 15.0);
    assert!(
        (0.85..=0.95).contains(&coverage),
        "observed 90 % coverage {coverage:.3} over {cases} cases"
    );
    assert!(gain > 0.1, "gain over uniform {gain:.3} nats");
}

#[test]
fn well_separated_points_give_confident_correct_posteriors() {
    // Centres 0.05 apart in a, SD 0.002: every trial is recovered exactly
    // and the true value gets nearly all the mass.
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let noise = Normal::new(0.0, 0.002).unwrap();
    let grid: Vec<WeightInput> = (0..3)
        .map(|k| WeightInput {
            params: BTreeMap::from([("w1".to_string(), [0.5, 2.0, 8.0][k])]),
            trials: (0..8)
                .map(|t| TrialInput {
                    trial: t,
                    seed: u64::from(t),
                    final_success_rate: 1.0,
                    converged: true,
                    episodes: vec![episode(
                        0.02 + 0.05 * k as f64 + noise.sample(&mut rng),
                        noise.sample(&mut rng),
                    )],
                    successes_found: 1000,
                    successes_wanted: 1000,
                    solver: Default::default(),
                })
                .collect(),
        })
        .collect();
    let r = hold_out_recovery(&grid, &ReportOptions::default());
    let t = &r.methods[&Method::Posterior];
    assert_eq!(t.exact, 24);
    let cal = &r.coverage[&Method::Posterior];
    assert!(cal.gain_nats > 3f64.ln() - 0.05, "{cal:?}");
    assert!(cal.levels.iter().all(|l| l.mean_set_size < 1.2), "{cal:?}");
}
