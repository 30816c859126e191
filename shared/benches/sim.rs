//! Control steps per second of the body model and task: one environment, and
//! a batch of 64 stepped over contiguous buffers. Each control step is 10 RK4
//! sub-steps, so sub-steps/s = 10 x the reported element rate.
//!
//! cargo bench -p shared --bench sim

use criterion::{black_box, criterion_group, criterion_main, Criterion, Throughput};
use shared::env::{BatchEnv, EnvConfig, Episode, Task};

/// A fixed, bounded action pattern (the episode logic resets on termination).
fn action(k: usize) -> [f64; 3] {
    let x = k as f64 * 0.1;
    [0.3 * x.sin(), 0.5 * x.cos(), -0.2 * x.sin()]
}

fn single(c: &mut Criterion) {
    let cfg = EnvConfig::default();
    let task = Task::new(&cfg).unwrap();
    let start = task.initial_state(&mut rand::rngs::mock::StepRng::new(0, 0));
    let mut group = c.benchmark_group("control_steps");
    group.throughput(Throughput::Elements(1000));
    group.bench_function("single_env_1000_steps", |b| {
        b.iter(|| {
            let mut ep = Episode::new(start);
            for k in 0..1000 {
                let info = task.step(&mut ep, &action(k), |_| {});
                if info.outcome.is_done() {
                    ep = Episode::new(start);
                }
            }
            black_box(ep.state)
        })
    });
    let n = 64;
    let mut batch = BatchEnv::new(&cfg, n, 1).unwrap();
    let actions: Vec<f64> = (0..n).flat_map(action).collect();
    group.throughput(Throughput::Elements(n as u64 * 16));
    group.bench_function("batch_64_envs_16_steps", |b| {
        b.iter(|| {
            for _ in 0..16 {
                black_box(batch.step(&actions).unwrap());
            }
        })
    });
    group.finish();
}

criterion_group!(benches, single);
criterion_main!(benches);
