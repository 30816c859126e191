//! Prometheus text metrics: event counters, request latency histograms per
//! route, and job counts by state read from the database at scrape time.

use std::collections::BTreeMap;
use std::fmt::Write;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use axum::extract::{MatchedPath, Request, State};
use axum::middleware::Next;
use axum::response::Response;

/// Upper bounds (seconds) of the latency histogram buckets.
pub const BUCKETS: [f64; 12] = [
    0.001, 0.0025, 0.005, 0.01, 0.02, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 10.0,
];

#[derive(Debug, Default, Clone)]
struct Histogram {
    counts: [u64; BUCKETS.len()],
    count: u64,
    sum: f64,
}

/// Event counters.
#[derive(Debug, Default)]
pub struct Metrics {
    /// Searches accepted.
    pub searches_created: AtomicU64,
    /// Leases granted.
    pub leases_granted: AtomicU64,
    /// Lease requests answered with no job.
    pub leases_empty: AtomicU64,
    /// Leases that expired and were swept.
    pub leases_expired: AtomicU64,
    /// Heartbeats accepted.
    pub heartbeats: AtomicU64,
    /// Results accepted.
    pub uploads_accepted: AtomicU64,
    /// Results refused (stale lease, duplicate, invalid).
    pub uploads_rejected: AtomicU64,
    /// Failures reported by workers.
    pub jobs_failed_reports: AtomicU64,
    /// Leases released by workers.
    pub leases_released: AtomicU64,
    latency: Mutex<BTreeMap<(String, String, u16), Histogram>>,
}

impl Metrics {
    /// Adds one to a counter.
    pub fn inc(c: &AtomicU64) {
        c.fetch_add(1, Ordering::Relaxed);
    }

    /// Records one request.
    pub fn observe(&self, method: &str, route: &str, status: u16, secs: f64) {
        let mut map = self.latency.lock().unwrap_or_else(|p| p.into_inner());
        let h = map
            .entry((method.to_string(), route.to_string(), status))
            .or_default();
        h.count += 1;
        h.sum += secs;
        for (i, &b) in BUCKETS.iter().enumerate() {
            if secs <= b {
                h.counts[i] += 1;
            }
        }
    }

    /// The exposition text; `jobs` are the counts by state.
    pub fn render(&self, jobs: &BTreeMap<String, i64>) -> String {
        let mut out = String::new();
        let counters = [
            (
                "irlgrid_searches_created_total",
                "Searches accepted.",
                &self.searches_created,
            ),
            (
                "irlgrid_leases_granted_total",
                "Leases granted.",
                &self.leases_granted,
            ),
            (
                "irlgrid_lease_requests_empty_total",
                "Lease requests answered with no job.",
                &self.leases_empty,
            ),
            (
                "irlgrid_leases_expired_total",
                "Leases that expired and went back to the queue or failed.",
                &self.leases_expired,
            ),
            (
                "irlgrid_heartbeats_total",
                "Heartbeats accepted.",
                &self.heartbeats,
            ),
            (
                "irlgrid_uploads_accepted_total",
                "Job results accepted.",
                &self.uploads_accepted,
            ),
            (
                "irlgrid_uploads_rejected_total",
                "Job results refused (stale lease, duplicate or invalid).",
                &self.uploads_rejected,
            ),
            (
                "irlgrid_job_failures_reported_total",
                "Job failures reported by workers.",
                &self.jobs_failed_reports,
            ),
            (
                "irlgrid_leases_released_total",
                "Leases released unfinished by workers.",
                &self.leases_released,
            ),
        ];
        for (name, help, c) in counters {
            let _ = writeln!(out, "# HELP {name} {help}\n# TYPE {name} counter");
            let _ = writeln!(out, "{name} {}", c.load(Ordering::Relaxed));
        }
        let _ = writeln!(
            out,
            "# HELP irlgrid_jobs Jobs by state (queued: waiting for a worker; leased: running, one per busy worker slot).\n# TYPE irlgrid_jobs gauge"
        );
        for (state, n) in jobs {
            let _ = writeln!(out, "irlgrid_jobs{{state=\"{state}\"}} {n}");
        }
        let name = "irlgrid_http_request_duration_seconds";
        let _ = writeln!(
            out,
            "# HELP {name} HTTP request latency by route.\n# TYPE {name} histogram"
        );
        let map = self.latency.lock().unwrap_or_else(|p| p.into_inner());
        for ((method, route, status), h) in map.iter() {
            let labels = format!("method=\"{method}\",route=\"{route}\",status=\"{status}\"");
            for (i, b) in BUCKETS.iter().enumerate() {
                let _ = writeln!(out, "{name}_bucket{{{labels},le=\"{b}\"}} {}", h.counts[i]);
            }
            let _ = writeln!(out, "{name}_bucket{{{labels},le=\"+Inf\"}} {}", h.count);
            let _ = writeln!(out, "{name}_sum{{{labels}}} {}", h.sum);
            let _ = writeln!(out, "{name}_count{{{labels}}} {}", h.count);
        }
        out
    }
}

/// Middleware: time every request under its route template (its state is
/// the app's [`Metrics`], so the metrics need nothing else of the app).
pub async fn track(State(metrics): State<Arc<Metrics>>, req: Request, next: Next) -> Response {
    let start = Instant::now();
    let method = req.method().to_string();
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map(|p| p.as_str().to_string())
        .unwrap_or_else(|| "unmatched".to_string());
    let resp = next.run(req).await;
    metrics.observe(
        &method,
        &route,
        resp.status().as_u16(),
        start.elapsed().as_secs_f64(),
    );
    resp
}
