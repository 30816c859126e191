//! Result-document benchmark: a finished search's document built from
//! 140, 1,400 and 10,000 accepted real-sized outputs (10 trajectories of
//! 400 samples each; 10,000 is the most jobs one search may have), and a
//! finished document read back.
//!
//! `cargo bench -p coordinator --bench documents` (env: `BENCH_SIZES`,
//! default `140,1400,10000`; `BENCH_SAMPLES`, samples per trajectory,
//! default 400; `BENCH_READS`, reads timed per size, default 50).
//!
//! Each size gets a fresh database filled through the store's own write
//! path (lease, digest and compress, accept). Then the search's stored
//! document is dropped and the build timed (`results::document` on a
//! completed search: read every trial summary, aggregate, posterior,
//! identifiability, store), then the read of the stored document
//! (`results::document` again, as `GET .../results` does before encoding).
//! Prints the build time, the time per output, and read percentiles.

use std::time::Instant;

use coordinator::store::queue;
use serde_json::json;
use shared::api::routes::Endpoint as E;
use shared::api::JobOutput;

#[path = "../tests/support/mod.rs"]
mod support;
use support::{env_or, percentile, realistic_output, sorted};

/// (grid points, trials) for a number of outputs (at most 100 trials a point).
fn shape(n: usize) -> (usize, u32) {
    let trials = if n >= 1000 { 100 } else { 10 };
    (n / trials as usize, trials)
}

/// The reward grid of `points` points: `w1` alone up to the 64 values a
/// parameter may have, else `w1` (10 values) x `success_bonus`.
fn grid(points: usize) -> serde_json::Value {
    let w1 = |k: usize| (1..=k).map(|i| i as f64 * 0.25).collect::<Vec<f64>>();
    if points <= 64 {
        json!({ "w1": w1(points) })
    } else {
        let bonus: Vec<f64> = (1..=points / 10).map(|i| i as f64).collect();
        json!({ "w1": w1(10), "success_bonus": bonus })
    }
}

fn main() -> anyhow::Result<()> {
    let sizes: String = env_or("BENCH_SIZES", "140,1400,10000".to_string());
    let samples: usize = env_or("BENCH_SAMPLES", 400);
    let reads: usize = env_or("BENCH_READS", 50);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    println!(
        "{:>8} {:>7} {:>7} {:>10} {:>12} {:>10} {:>10} {:>10} {:>10}",
        "outputs",
        "points",
        "trials",
        "fill s",
        "build ms",
        "us/output",
        "read p50",
        "read p99",
        "doc KiB"
    );
    for n in sizes.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let n: usize = n.parse()?;
        rt.block_on(one(n, samples, reads))?;
    }
    Ok(())
}

async fn one(n: usize, samples: usize, reads: usize) -> anyhow::Result<()> {
    let (points, trials) = shape(n);
    let (running, _dir) = support::start(|_| {}).await?;
    let state = running.state.clone();
    let http = reqwest::Client::new();
    let r = http
        .post(format!("{}{}", running.url(), E::Submit.path()))
        .json(&json!({
            "name": "bench", "reward_grid": grid(points), "trials": trials, "seed": 1,
            "training": {"env_steps": 1000},
            "sampling": {"successful_episodes": 10, "top_k": 10, "max_attempts": 1000}
        }))
        .send()
        .await?;
    anyhow::ensure!(r.status() == 201, "submit: {}", r.text().await?);
    let id = r.json::<serde_json::Value>().await?["id"]
        .as_str()
        .unwrap_or_default()
        .to_string();
    // Fill through the store's write path, a few uploads in flight.
    let t0 = Instant::now();
    let mut tasks = Vec::new();
    for w in 0..4 {
        let state = state.clone();
        tasks.push(tokio::spawn(async move {
            let mut done = 0usize;
            loop {
                let now = coordinator::store::now_ms();
                let (c, _) =
                    queue::claim_with(&state.db, &format!("b{w}"), 600_000, now, false).await?;
                let Some(c) = c else { return anyhow::Ok(done) };
                let out: JobOutput =
                    serde_json::from_value(realistic_output(10, samples, 10, c.job_id as u64))?;
                let up = tokio::task::spawn_blocking(move || queue::Upload::of(out)).await??;
                let d = queue::complete_with(&state.db, c.job_id, &c.token, up, 0.5, now).await?;
                state.apply(d.effects);
                done += 1;
            }
        }));
    }
    let mut filled = 0;
    for t in tasks {
        filled += t.await??;
    }
    anyhow::ensure!(filled == n, "filled {filled} of {n}");
    let fill = t0.elapsed().as_secs_f64();
    // Let the finalizer build and store it once, then drop it and time a build.
    while !has_final(&state, &id).await? {
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    drop_final(&state, &id).await?;
    let t = Instant::now();
    let (_, doc) = coordinator::domain::results::document(&state, &id).await?;
    let build = t.elapsed().as_secs_f64() * 1e3;
    anyhow::ensure!(doc.identifiability.is_some(), "no identifiability block");
    let kib = serde_json::to_vec(&*doc)?.len() as f64 / 1024.0;
    anyhow::ensure!(
        has_final(&state, &id).await?,
        "the built document was not stored"
    );
    // Reads as a client sees them: GET .../results over loopback.
    let url = format!("{}{}", running.url(), E::Results.path_of(&id));
    let mut lat = Vec::with_capacity(reads);
    for _ in 0..reads {
        let t = Instant::now();
        let r = http.get(&url).send().await?;
        anyhow::ensure!(r.status() == 200, "read: {}", r.status());
        std::hint::black_box(r.bytes().await?);
        lat.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let lat = sorted(lat);
    println!(
        "{n:>8} {points:>7} {trials:>7} {fill:>10.1} {build:>12.1} {:>10.1} {:>10.2} {:>10.2} {kib:>10.0}",
        build * 1e3 / n as f64,
        percentile(&lat, 0.5),
        percentile(&lat, 0.99),
    );
    running.shutdown().await?;
    Ok(())
}

async fn conn(state: &coordinator::AppState) -> anyhow::Result<sqlx::SqliteConnection> {
    support::connect(&state.cfg.db).await
}

/// Whether the search's final document is stored.
async fn has_final(state: &coordinator::AppState, id: &str) -> anyhow::Result<bool> {
    Ok(
        sqlx::query_scalar("select final_document is not null from searches where id = ?1")
            .bind(id)
            .fetch_one(&mut conn(state).await?)
            .await?,
    )
}

/// Drops the stored final document, so that the next read builds it.
async fn drop_final(state: &coordinator::AppState, id: &str) -> anyhow::Result<()> {
    sqlx::query("update searches set final_document = null where id = ?1")
        .bind(id)
        .execute(&mut conn(state).await?)
        .await?;
    Ok(())
}
