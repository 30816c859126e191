//! HTTP client of the coordinator's worker endpoints, with errors sorted
//! into what the worker should do about them, and a capped exponential
//! backoff with jitter for transient failures.

use std::time::Duration;

use rand::Rng;
use reqwest::StatusCode;
use serde::de::DeserializeOwned;
use serde::Serialize;
use shared::api::{
    ErrorBody, FailReport, Heartbeat, HeartbeatAck, JobStateAck, Lease, LeaseRequest,
    ReleaseRequest, ResultAck, ResultUpload,
};

/// What went wrong with a call.
#[derive(Debug, thiserror::Error)]
pub enum CallError {
    /// Unreachable, timed out, 5xx or 429: retry later.
    #[error("coordinator unavailable: {0}")]
    Transient(String),
    /// 409: the lease is gone (expired, taken over, job done or cancelled);
    /// drop the job.
    #[error("lease lost: {0}")]
    Conflict(String),
    /// 404: the job no longer exists (another coordinator database?).
    #[error("not found: {0}")]
    NotFound(String),
    /// A lease this worker cannot read: the coordinator runs a different
    /// version of the job spec (an unknown or missing field). The job has
    /// been reported failed with this message, so that it shows in the
    /// job's `last_error` instead of the lease silently expiring.
    #[error("job spec refused: {0}")]
    Incompatible(String),
    /// Any other 4xx: our request is wrong; retrying will not help.
    #[error("request refused ({status}): {message}")]
    Rejected {
        /// HTTP status.
        status: u16,
        /// The coordinator's message.
        message: String,
    },
}

impl CallError {
    /// Worth retrying.
    pub fn is_transient(&self) -> bool {
        matches!(self, Self::Transient(_))
    }
}

/// Client of one coordinator.
#[derive(Debug, Clone)]
pub struct Client {
    http: reqwest::Client,
    base: String,
    token: Option<String>,
}

impl Client {
    /// A client of `base` (e.g. `http://127.0.0.1:8080`).
    pub fn new(base: &str, token: Option<String>) -> anyhow::Result<Self> {
        let http = reqwest::Client::builder()
            .connect_timeout(Duration::from_secs(10))
            .timeout(Duration::from_secs(120))
            .build()?;
        Ok(Self {
            http,
            base: base.trim_end_matches('/').to_string(),
            token,
        })
    }

    /// The base URL.
    pub fn base(&self) -> &str {
        &self.base
    }

    async fn post<B: Serialize, T: DeserializeOwned>(
        &self,
        path: &str,
        body: &B,
    ) -> Result<Option<T>, CallError> {
        match self.post_text(path, body).await? {
            None => Ok(None),
            Some(text) => serde_json::from_str(&text)
                .map(Some)
                .map_err(|e| CallError::Transient(format!("POST {path}: reading answer: {e}"))),
        }
    }

    /// A call's successful answer body (`None` for 204), or its error.
    async fn post_text<B: Serialize>(
        &self,
        path: &str,
        body: &B,
    ) -> Result<Option<String>, CallError> {
        let mut req = self.http.post(format!("{}{path}", self.base)).json(body);
        if let Some(t) = &self.token {
            req = req.bearer_auth(t);
        }
        let resp = req
            .send()
            .await
            .map_err(|e| CallError::Transient(format!("POST {path}: {e}")))?;
        let status = resp.status();
        if status == StatusCode::NO_CONTENT {
            return Ok(None);
        }
        if status.is_success() {
            return resp
                .text()
                .await
                .map(Some)
                .map_err(|e| CallError::Transient(format!("POST {path}: reading answer: {e}")));
        }
        let text = resp.text().await.unwrap_or_default();
        let message = serde_json::from_str::<ErrorBody>(&text)
            .map(|b| b.error)
            .unwrap_or(text);
        Err(match status {
            StatusCode::CONFLICT => CallError::Conflict(message),
            StatusCode::NOT_FOUND => CallError::NotFound(message),
            StatusCode::TOO_MANY_REQUESTS | StatusCode::REQUEST_TIMEOUT => {
                CallError::Transient(format!("POST {path}: {status}: {message}"))
            }
            s if s.is_server_error() => {
                CallError::Transient(format!("POST {path}: {status}: {message}"))
            }
            s => CallError::Rejected {
                status: s.as_u16(),
                message,
            },
        })
    }

    /// `GET /healthz`: whether the coordinator answers and its database
    /// works.
    pub async fn healthz(&self) -> Result<(), CallError> {
        let resp = self
            .http
            .get(format!("{}/healthz", self.base))
            .timeout(Duration::from_secs(10))
            .send()
            .await
            .map_err(|e| CallError::Transient(format!("GET /healthz: {e}")))?;
        let status = resp.status();
        if status.is_success() {
            Ok(())
        } else {
            Err(CallError::Transient(format!("GET /healthz: {status}")))
        }
    }

    /// Asks for a job, waiting up to `wait_secs` at the coordinator.
    ///
    /// The spec is parsed strictly ([`shared::api::JobSpec`] and its configurations deny
    /// unknown fields). A lease whose spec does not parse is reported failed
    /// with the reason and answered as [`CallError::Incompatible`].
    pub async fn lease(&self, worker: &str, wait_secs: u32) -> Result<Option<Lease>, CallError> {
        let req = LeaseRequest {
            worker: worker.to_string(),
            wait_secs,
        };
        let Some(text) = self.post_text("/api/v1/leases", &req).await? else {
            return Ok(None);
        };
        let err = match parse_lease(&text) {
            Ok(lease) => return Ok(Some(lease)),
            Err(e) => e,
        };
        let Some((job_id, lease_token)) = lease_handle(&text) else {
            return Err(CallError::Transient(format!(
                "POST /api/v1/leases: reading answer: {err}"
            )));
        };
        let message = format!(
            "worker {} cannot read this job's spec (coordinator and worker run different \
             versions?): {err}",
            env!("CARGO_PKG_VERSION")
        );
        let report = FailReport {
            lease_token,
            error: message.clone(),
        };
        if let Err(e) = self.fail(job_id, &report).await {
            tracing::warn!(job_id, error = %e, "could not report an unreadable job spec");
        }
        Err(CallError::Incompatible(format!("job {job_id}: {message}")))
    }

    /// Renews a lease and reports progress.
    pub async fn heartbeat(&self, job_id: i64, hb: &Heartbeat) -> Result<HeartbeatAck, CallError> {
        self.post(&format!("/api/v1/jobs/{job_id}/heartbeat"), hb)
            .await?
            .ok_or_else(|| CallError::Transient("empty heartbeat answer".into()))
    }

    /// Uploads a result.
    pub async fn result(&self, job_id: i64, up: &ResultUpload) -> Result<ResultAck, CallError> {
        self.post(&format!("/api/v1/jobs/{job_id}/result"), up)
            .await?
            .ok_or_else(|| CallError::Transient("empty result answer".into()))
    }

    /// Reports a failure.
    pub async fn fail(&self, job_id: i64, f: &FailReport) -> Result<JobStateAck, CallError> {
        self.post(&format!("/api/v1/jobs/{job_id}/fail"), f)
            .await?
            .ok_or_else(|| CallError::Transient("empty fail answer".into()))
    }

    /// Hands a job back unfinished.
    pub async fn release(&self, job_id: i64, token: &str) -> Result<JobStateAck, CallError> {
        self.post(
            &format!("/api/v1/jobs/{job_id}/release"),
            &ReleaseRequest {
                lease_token: token.to_string(),
            },
        )
        .await?
        .ok_or_else(|| CallError::Transient("empty release answer".into()))
    }
}

/// Capped exponential backoff with jitter: the n-th delay is drawn
/// uniformly from [d/2, d] with d = min(base * 2^n, max).
#[derive(Debug, Clone)]
pub struct Backoff {
    base: Duration,
    max: Duration,
    n: u32,
}

impl Backoff {
    /// A fresh backoff.
    pub fn new(base: Duration, max: Duration) -> Self {
        Self { base, max, n: 0 }
    }

    /// The next delay.
    pub fn next_delay(&mut self) -> Duration {
        let d = self
            .base
            .saturating_mul(1u32 << self.n.min(20))
            .min(self.max);
        self.n = self.n.saturating_add(1);
        let lo = d / 2;
        lo + (d - lo).mul_f64(rand::thread_rng().gen::<f64>())
    }

    /// Back to the first delay after a success.
    pub fn reset(&mut self) {
        self.n = 0;
    }
}

/// Parses a lease answer strictly; the error names the offending field's
/// path (`spec.training.bogus: unknown field ...`).
pub fn parse_lease(text: &str) -> Result<Lease, String> {
    let de = &mut serde_json::Deserializer::from_str(text);
    serde_path_to_error::deserialize(de).map_err(|e| {
        let path = e.path().to_string();
        if path == "." {
            e.inner().to_string()
        } else {
            format!("{path}: {}", e.inner())
        }
    })
}

/// The job id and lease token of a lease answer that did not parse as a
/// whole, so that the lease can still be reported.
fn lease_handle(text: &str) -> Option<(i64, String)> {
    let v: serde_json::Value = serde_json::from_str(text).ok()?;
    Some((
        v.get("job_id")?.as_i64()?,
        v.get("lease_token")?.as_str()?.to_string(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A lease as the coordinator of this version sends it.
    fn lease_json() -> serde_json::Value {
        let spec = crate::job::test_spec();
        serde_json::to_value(Lease {
            job_id: 3,
            lease_token: "t".into(),
            lease_secs: 60,
            heartbeat_secs: 20,
            spec,
        })
        .unwrap()
    }

    #[test]
    fn a_spec_from_another_version_is_refused_naming_the_unknown_field() {
        let ok = lease_json();
        let lease = parse_lease(&ok.to_string()).unwrap();
        assert_eq!(lease.spec.seed, 7);
        // A newer coordinator's setting this worker does not know, in a
        // configuration and in the spec itself: refused, not dropped.
        let mut v = ok.clone();
        v["spec"]["training"]["new_knob"] = serde_json::json!(1);
        let e = parse_lease(&v.to_string()).unwrap_err();
        assert!(e.starts_with("spec.training"), "{e}");
        assert!(e.contains("new_knob"), "{e}");
        let mut v = ok.clone();
        v["spec"]["curriculum"] = serde_json::json!("x");
        let e = parse_lease(&v.to_string()).unwrap_err();
        assert!(e.contains("curriculum"), "{e}");
        // An older coordinator missing a field is refused too.
        let mut v = ok.clone();
        v["spec"].as_object_mut().unwrap().remove("sampling");
        let e = parse_lease(&v.to_string()).unwrap_err();
        assert!(e.contains("sampling"), "{e}");
        // The refused lease can still be reported against its job.
        assert_eq!(lease_handle(&v.to_string()), Some((3, "t".to_string())));
    }

    #[test]
    fn backoff_grows_to_its_cap_with_jitter_and_resets() {
        let mut b = Backoff::new(Duration::from_millis(100), Duration::from_secs(1));
        let d: Vec<_> = (0..8).map(|_| b.next_delay()).collect();
        assert!(d[0] >= Duration::from_millis(50) && d[0] <= Duration::from_millis(100));
        assert!(d[2] >= Duration::from_millis(200) && d[2] <= Duration::from_millis(400));
        for x in &d[4..] {
            assert!(*x >= Duration::from_millis(500) && *x <= Duration::from_secs(1));
        }
        b.reset();
        assert!(b.next_delay() <= Duration::from_millis(100));
    }
}
