//! Cost of the inference that runs without training: the identifiability
//! report (leave-one-trial-out over every trial, every method) of a 7 x 20
//! grid, and scoring 1000 subjects against that grid. Each trial keeps 10
//! episodes of 70 COM samples, like a real job's upload.
//!
//! cargo bench -p shared --bench inference

use std::collections::BTreeMap;

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use shared::analysis::{
    build_report_with, EpisodeRecord, Identifiability, ReportOptions, SubjectPath, TrialInput,
    WeightInput,
};
use shared::test_support::StandUp;

fn episode(a: f64, b: f64) -> EpisodeRecord {
    StandUp::real_sized(a).wobble(b).ret(930.0 + a).episode()
}

/// The paper grid with 20 trials per value; bulges vary by trial and episode
/// in a fixed pattern (no random numbers, so every run builds the same grid).
fn grid() -> Vec<WeightInput> {
    [0.1, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0]
        .iter()
        .enumerate()
        .map(|(k, &w1)| WeightInput {
            params: BTreeMap::from([("w1".to_string(), w1)]),
            trials: (0..20u32)
                .map(|t| TrialInput {
                    trial: t,
                    seed: u64::from(t),
                    final_success_rate: 1.0,
                    converged: true,
                    episodes: (0..10)
                        .map(|e| {
                            let wobble = (f64::from(t) * 1.7 + f64::from(e) * 0.3).sin();
                            episode(0.03 + 0.01 * k as f64 + 0.008 * wobble, 0.004 * wobble)
                        })
                        .collect(),
                    successes_found: 1000,
                    successes_wanted: 1000,
                    solver: Default::default(),
                })
                .collect(),
        })
        .collect()
}

fn subjects(n: usize) -> Vec<SubjectPath> {
    (0..n)
        .map(|i| {
            let e = episode(0.03 + 0.06 * (i as f64 / n as f64), 0.002);
            SubjectPath {
                subject: format!("s{i}"),
                t: e.com_t,
                x: e.com_x,
                z: e.com_z,
            }
        })
        .collect()
}

fn inference(c: &mut Criterion) {
    let weights = grid();
    let opts = ReportOptions::default();
    let mut group = c.benchmark_group("inference_7x20");
    group.sample_size(10);
    group.bench_function("identifiability_report", |b| {
        b.iter(|| {
            let doc = build_report_with(black_box(&weights), &[], &opts, Identifiability::Always);
            assert_eq!(doc.identifiability.map(|h| h.cases), Some(140));
        })
    });
    let many = subjects(1000);
    group.bench_function("score_1000_subjects", |b| {
        b.iter(|| {
            let doc = build_report_with(black_box(&weights), &many, &opts, Identifiability::Never);
            assert_eq!(doc.subjects.len(), 1000);
        })
    });
    group.finish();
}

criterion_group!(benches, inference);
criterion_main!(benches);
