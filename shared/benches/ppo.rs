//! PPO throughput: whole training updates with the default network and
//! rollout shape (environment steps per second, updates included), and the
//! batched MLP passes they are made of.
//!
//! `CARGO_TARGET_DIR=... cargo bench -p shared --bench ppo`

use std::hint::black_box;
use std::ops::ControlFlow;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use shared::env::EnvConfig;
use shared::ppo::mlp::{Mlp, MlpWorkspace};
use shared::ppo::real::Real;
use shared::ppo::{train, PpoConfig};

fn training(c: &mut Criterion) {
    let mut group = c.benchmark_group("train");
    group.sample_size(10);
    let base = PpoConfig::default();
    // Four default-sized updates (rollout + all minibatch epochs) per run.
    let cfg = PpoConfig {
        env_steps: 4 * base.batch_size() as u64,
        ..base
    };
    group.throughput(Throughput::Elements(cfg.env_steps));
    let env = EnvConfig::with_w1(1.0);
    group.bench_function("default_config_4_updates", |b| {
        b.iter(|| {
            let out = train(&cfg, &env, 1, &mut |_| ControlFlow::Continue(())).unwrap();
            black_box(out.env_steps)
        })
    });
    group.finish();
}

fn mlp_group<T: Real>(c: &mut Criterion, name: &str) {
    let mut group = c.benchmark_group(name);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let net: Mlp<T> = Mlp::<f64>::orthogonal(&[6, 64, 64, 3], 2f64.sqrt(), 0.01, &mut rng).cast();
    for batch in [64usize, 256, 1024] {
        let x: Vec<T> = (0..6 * batch)
            .map(|i| T::from_f64(((i * 37) % 11) as f64 * 0.1 - 0.5))
            .collect();
        let d_out = vec![T::from_f64(0.01); 3 * batch];
        let mut grad = vec![T::ZERO; net.params().len()];
        let mut ws = MlpWorkspace::new();
        group.throughput(Throughput::Elements(batch as u64));
        group.bench_function(format!("forward_{batch}"), |b| {
            b.iter(|| black_box(net.forward(&x, &mut ws)[0]))
        });
        group.bench_function(format!("forward_backward_{batch}"), |b| {
            b.iter(|| {
                net.forward(&x, &mut ws);
                net.backward(&x, &mut ws, &d_out, &mut grad, None);
                black_box(grad[0])
            })
        });
    }
    group.finish();
}

/// The training precision (`Net` = f32) and f64 for comparison.
fn mlp(c: &mut Criterion) {
    mlp_group::<f32>(c, "mlp_f32_6x64x64x3");
    mlp_group::<f64>(c, "mlp_f64_6x64x64x3");
}

criterion_group!(benches, training, mlp);
criterion_main!(benches);
