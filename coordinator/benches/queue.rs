//! Queue-overhead benchmark (target >= 4,500 lease+complete cycles/s with
//! p99 < 20 ms on 2 cores, docs/performance.md#queue-overhead): 64 concurrent simulated
//! workers doing empty jobs (lease, then upload an empty result) against the
//! real coordinator on loopback with a temporary SQLite file.
//!
//! `cargo bench -p coordinator --bench queue` (env: `BENCH_WORKERS`,
//! `BENCH_SECS`). Prints cycles per second and request latency percentiles.

use std::time::{Duration, Instant};

use serde_json::json;

#[path = "../tests/support/mod.rs"]
mod support;
use shared::api::routes::Endpoint as E;
use support::{empty_output, env_or, percentile, search_json, sorted};

fn main() -> anyhow::Result<()> {
    let workers: usize = env_or("BENCH_WORKERS", 64);
    let secs: u64 = env_or("BENCH_SECS", 10);
    // The server and the simulated workers get their own runtimes (both on
    // this machine's cores, as in a one-box deployment).
    let server_rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let (running, _dir) = server_rt.block_on(support::start(|cfg| cfg.lease_secs = 300))?;
    let url = running.url();
    let client_rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let (cycles, lat_lease, lat_result, elapsed) = client_rt.block_on(async {
        let http = reqwest::Client::builder()
            .pool_max_idle_per_host(workers)
            .build()?;
        // 8 searches x 6,400 empty jobs (64 points x 100 trials).
        let grid: Vec<f64> = (0..64).map(|i| f64::from(i) * 0.1).collect();
        for k in 0..8 {
            let r = http
                .post(format!("{url}{}", E::Submit.path()))
                .json(&search_json(&format!("bench {k}"), &grid, 100, 1))
                .send()
                .await?;
            anyhow::ensure!(r.status() == 201, "submit failed: {}", r.text().await?);
        }
        let deadline = Instant::now() + Duration::from_secs(secs);
        let t0 = Instant::now();
        let mut tasks = Vec::new();
        for w in 0..workers {
            let http = http.clone();
            let url = url.clone();
            tasks.push(tokio::spawn(async move {
                let mut lease_ms = Vec::new();
                let mut result_ms = Vec::new();
                let mut n = 0u64;
                let worker = format!("bench-{w}");
                while Instant::now() < deadline {
                    let t = Instant::now();
                    let r = http
                        .post(format!("{url}{}", E::Lease.path()))
                        .json(&json!({"worker": worker}))
                        .send()
                        .await?;
                    let status = r.status();
                    let body = r.bytes().await?;
                    lease_ms.push(t.elapsed().as_secs_f64() * 1e3);
                    if status == 204 {
                        break;
                    }
                    let lease: serde_json::Value = serde_json::from_slice(&body)?;
                    let t = Instant::now();
                    let r = http
                        .post(format!("{url}{}", E::Result.path_of(&lease["job_id"])))
                        .json(&json!({"lease_token": lease["lease_token"], "output": empty_output(1)}))
                        .send()
                        .await?;
                    anyhow::ensure!(r.status() == 200, "upload failed: {}", r.status());
                    r.bytes().await?;
                    result_ms.push(t.elapsed().as_secs_f64() * 1e3);
                    n += 1;
                }
                anyhow::Ok((n, lease_ms, result_ms))
            }));
        }
        let (mut cycles, mut ll, mut lr) = (0u64, Vec::new(), Vec::new());
        for t in tasks {
            let (n, a, b) = t.await??;
            cycles += n;
            ll.extend(a);
            lr.extend(b);
        }
        anyhow::Ok((cycles, ll, lr, t0.elapsed()))
    })?;
    let all = sorted(lat_lease.iter().chain(&lat_result).copied().collect());
    let l = sorted(lat_lease);
    let r = sorted(lat_result);
    let rate = cycles as f64 / elapsed.as_secs_f64();
    println!(
        "queue overhead: {workers} concurrent workers, empty jobs, {:.1} s",
        elapsed.as_secs_f64()
    );
    println!("  lease+complete cycles: {cycles} ({rate:.0} cycles/s; target >= 4500)");
    println!(
        "  request latency ms: p50 {:.2}  p90 {:.2}  p99 {:.2}  max {:.2} (target p99 < 20)",
        percentile(&all, 0.5),
        percentile(&all, 0.9),
        percentile(&all, 0.99),
        all.last().copied().unwrap_or(f64::NAN)
    );
    println!(
        "  lease p99 {:.2} ms, result p99 {:.2} ms",
        percentile(&l, 0.99),
        percentile(&r, 0.99)
    );
    server_rt.block_on(running.shutdown())?;
    Ok(())
}
