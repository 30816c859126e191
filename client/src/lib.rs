//! The typed HTTP client of the coordinator's API, the one both the CLI
//! (`irlgrid submit`, `status`, `results`, `score`, `extend`, `refine`,
//! `run`, `health`) and the worker use. URLs come from the route table
//! (`shared::api::routes`); bodies and answers are the wire types of
//! `shared::api`. Errors are sorted into what the caller should do about
//! them ([`CallError`]).

use std::time::Duration;

use reqwest::header::CONTENT_TYPE;
use reqwest::StatusCode;
use serde::de::DeserializeOwned;
use serde::Serialize;
use shared::analysis::WeightInput;
use shared::api::routes::{Endpoint, Method};
use shared::api::{
    Created, ErrorBody, ExtendRequest, Extended, FailReport, Heartbeat, HeartbeatAck, JobDetail,
    JobInfo, JobStateAck, Lease, LeaseRequest, PageQuery, RefineRequest, Refinement,
    ReleaseRequest, ResultAck, ResultUpload, ResultsView, ScoreQuery, ScoredSubjects, SearchStatus,
};

/// What went wrong with a call.
#[derive(Debug, thiserror::Error)]
pub enum CallError {
    /// No answer: the coordinator cannot be reached or did not answer in
    /// time. Retry later.
    #[error("cannot reach the coordinator: {0}")]
    Unreachable(String),
    /// 5xx, 429 or 408, or an answer that could not be read: retry later.
    #[error("coordinator unavailable: {0}")]
    Transient(String),
    /// 409: the lease is gone (expired, taken over, job done or cancelled),
    /// or the search is in a state that refuses the call.
    #[error("conflict: {0}")]
    Conflict(String),
    /// 404: no such search or job (another coordinator database?).
    #[error("not found: {0}")]
    NotFound(String),
    /// A lease this worker cannot read: the coordinator runs a different
    /// version of the job spec (an unknown or missing field). The job has
    /// been reported failed with this message, so that it shows in the
    /// job's `last_error` instead of the lease silently expiring.
    #[error("job spec refused: {0}")]
    Incompatible(String),
    /// Any other 4xx: the request is wrong; retrying will not help.
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
        matches!(self, Self::Transient(_) | Self::Unreachable(_))
    }

    /// The HTTP status of a refusal (4xx), if this is one.
    pub fn refusal_status(&self) -> Option<u16> {
        match self {
            Self::Conflict(_) => Some(409),
            Self::NotFound(_) => Some(404),
            Self::Rejected { status, .. } => Some(*status),
            _ => None,
        }
    }

    /// The coordinator's own message of a refusal, or this error's text.
    pub fn message(&self) -> String {
        match self {
            Self::Conflict(m) | Self::NotFound(m) => m.clone(),
            Self::Rejected { message, .. } => message.clone(),
            other => other.to_string(),
        }
    }
}

/// A request body.
#[derive(Debug, Clone)]
pub enum Body {
    /// None (the reads).
    Empty,
    /// JSON text.
    Json(Vec<u8>),
    /// CSV text (`text/csv`).
    Csv(String),
}

impl Body {
    /// The JSON form of `value`.
    pub fn json<T: Serialize + ?Sized>(value: &T) -> Self {
        // Serializing our own wire types (and JSON values) cannot fail.
        Self::Json(serde_json::to_vec(value).unwrap_or_default())
    }
}

/// Client of one coordinator: one connection pool, the base URL and the
/// bearer token sent with every call.
#[derive(Debug, Clone)]
pub struct Client {
    http: reqwest::Client,
    base: String,
    token: Option<String>,
}

impl Client {
    /// A client of `base` (e.g. `http://127.0.0.1:8080`) that sends
    /// `token` as its bearer token. Calls give up after 120 s, the
    /// coordinator's own request timeout.
    pub fn new(base: &str, token: Option<String>) -> Result<Self, reqwest::Error> {
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

    /// The full URL of an endpoint (`id` fills its `{id}`), for links
    /// printed to the user.
    pub fn url(&self, endpoint: Endpoint, id: Option<&str>) -> String {
        format!("{}{}", self.base, path(endpoint, id))
    }

    /// Calls an endpoint and returns its answer's text (`None` for 204),
    /// or the refusal sorted by what to do about it. The one place a
    /// request is sent.
    pub async fn call(
        &self,
        endpoint: Endpoint,
        id: Option<&str>,
        query: &[(&str, &str)],
        body: Body,
    ) -> Result<Option<String>, CallError> {
        let path = path(endpoint, id);
        let method = endpoint.method();
        let what = format!("{} {path}", method.as_str());
        let mut req = match method {
            Method::Get => self.http.get(format!("{}{path}", self.base)),
            Method::Post => self.http.post(format!("{}{path}", self.base)),
        };
        if !query.is_empty() {
            req = req.query(query);
        }
        req = match body {
            Body::Empty => req,
            Body::Json(b) => req.header(CONTENT_TYPE, "application/json").body(b),
            Body::Csv(t) => req.header(CONTENT_TYPE, "text/csv").body(t),
        };
        if let Some(t) = &self.token {
            req = req.bearer_auth(t);
        }
        let resp = req
            .send()
            .await
            .map_err(|e| CallError::Unreachable(format!("{what} at {}: {e}", self.base)))?;
        let status = resp.status();
        if status == StatusCode::NO_CONTENT {
            return Ok(None);
        }
        if status.is_success() {
            return resp
                .text()
                .await
                .map(Some)
                .map_err(|e| CallError::Transient(format!("{what}: reading answer: {e}")));
        }
        let text = resp.text().await.unwrap_or_default();
        let message = serde_json::from_str::<ErrorBody>(&text)
            .map(|b| b.error)
            .unwrap_or(text);
        Err(match status {
            StatusCode::CONFLICT => CallError::Conflict(message),
            StatusCode::NOT_FOUND => CallError::NotFound(message),
            StatusCode::TOO_MANY_REQUESTS | StatusCode::REQUEST_TIMEOUT => {
                CallError::Transient(format!("{what}: {status}: {message}"))
            }
            s if s.is_server_error() => {
                CallError::Transient(format!("{what}: {status}: {message}"))
            }
            s => CallError::Rejected {
                status: s.as_u16(),
                message,
            },
        })
    }

    /// Calls an endpoint and reads its answer as `T`.
    async fn typed<T: DeserializeOwned>(
        &self,
        endpoint: Endpoint,
        id: Option<&str>,
        body: Body,
    ) -> Result<T, CallError> {
        let text = self
            .call(endpoint, id, &[], body)
            .await?
            .ok_or_else(|| CallError::Transient(format!("{}: empty answer", path(endpoint, id))))?;
        decode(endpoint, id, &text)
    }

    /// `GET /healthz`: whether the coordinator answers and its database
    /// works (within 10 s).
    pub async fn healthz(&self) -> Result<(), CallError> {
        let url = self.url(Endpoint::Healthz, None);
        let resp = self
            .http
            .get(&url)
            .timeout(Duration::from_secs(10))
            .send()
            .await
            .map_err(|e| CallError::Unreachable(format!("GET {url}: {e}")))?;
        let status = resp.status();
        if status.is_success() {
            Ok(())
        } else {
            Err(CallError::Transient(format!("GET {url}: {status}")))
        }
    }

    // ------------------------------------------------------------ searches

    /// Submits a search: a [`shared::api::SearchRequest`], or a request's
    /// JSON as a user wrote it (the coordinator checks it and names the
    /// offending field).
    pub async fn submit<B: Serialize + ?Sized>(&self, request: &B) -> Result<Created, CallError> {
        self.typed(Endpoint::Submit, None, Body::json(request))
            .await
    }

    /// Every search, newest first (page after page).
    pub async fn searches(&self) -> Result<Vec<SearchStatus>, CallError> {
        let mut all = Vec::new();
        loop {
            let page = self
                .searches_page(&PageQuery {
                    limit: Some(PageQuery::MAX_LIMIT),
                    offset: Some(u32::try_from(all.len()).unwrap_or(u32::MAX)),
                })
                .await?;
            let last = page.len() < PageQuery::MAX_LIMIT as usize;
            all.extend(page);
            if last {
                return Ok(all);
            }
        }
    }

    /// One page of searches, newest first.
    pub async fn searches_page(&self, page: &PageQuery) -> Result<Vec<SearchStatus>, CallError> {
        let (limit, offset) = (page.limit().to_string(), page.offset().to_string());
        let text = self
            .call(
                Endpoint::ListSearches,
                None,
                &[("limit", &limit), ("offset", &offset)],
                Body::Empty,
            )
            .await?
            .ok_or_else(|| CallError::Transient("empty answer to the search list".into()))?;
        decode(Endpoint::ListSearches, None, &text)
    }

    /// One search's status.
    pub async fn search(&self, id: &str) -> Result<SearchStatus, CallError> {
        self.typed(Endpoint::SearchStatus, Some(id), Body::Empty)
            .await
    }

    /// Cancels a search.
    pub async fn cancel(&self, id: &str) -> Result<SearchStatus, CallError> {
        self.typed(Endpoint::Cancel, Some(id), Body::Empty).await
    }

    /// Extends a search.
    pub async fn extend(&self, id: &str, req: &ExtendRequest) -> Result<Extended, CallError> {
        self.typed(Endpoint::Extend, Some(id), Body::json(req))
            .await
    }

    /// Asks for a refinement of a search toward its subjects.
    pub async fn refine(&self, id: &str, req: &RefineRequest) -> Result<Refinement, CallError> {
        self.typed(Endpoint::Refine, Some(id), Body::json(req))
            .await
    }

    /// A search's refinement so far.
    pub async fn refinement(&self, id: &str) -> Result<Refinement, CallError> {
        self.typed(Endpoint::Refinement, Some(id), Body::Empty)
            .await
    }

    /// A search's result document with its state.
    pub async fn results(&self, id: &str) -> Result<ResultsView<'static>, CallError> {
        self.typed(Endpoint::Results, Some(id), Body::Empty).await
    }

    /// A search's jobs.
    pub async fn jobs(&self, id: &str) -> Result<Vec<JobInfo>, CallError> {
        self.typed(Endpoint::SearchJobs, Some(id), Body::Empty)
            .await
    }

    /// A search's aggregation input (every done trial by grid point).
    pub async fn outputs(&self, id: &str) -> Result<Vec<WeightInput>, CallError> {
        self.typed(Endpoint::Outputs, Some(id), Body::Empty).await
    }

    /// One job with its learning curve.
    pub async fn job(&self, job_id: i64) -> Result<JobDetail, CallError> {
        let id = job_id.to_string();
        self.typed(Endpoint::JobDetail, Some(&id), Body::Empty)
            .await
    }

    /// Scores subjects (CSV `subject,time,x,z`) against a search's finished
    /// trials; `save` also adds them to the search. The answer's text, for
    /// a caller that prints it raw; [`Client::score_subjects`] reads it.
    pub async fn score_subjects_text(
        &self,
        id: &str,
        csv: String,
        query: &ScoreQuery,
    ) -> Result<String, CallError> {
        let mut pairs: Vec<(&str, &str)> = Vec::new();
        if query.save {
            pairs.push(("save", "true"));
        }
        if let Some(o) = &query.observables {
            pairs.push(("observables", o));
        }
        self.call(Endpoint::ScoreSubjects, Some(id), &pairs, Body::Csv(csv))
            .await?
            .ok_or_else(|| CallError::Transient("empty answer to scoring".into()))
    }

    /// Scores subjects, read typed.
    pub async fn score_subjects(
        &self,
        id: &str,
        csv: String,
        query: &ScoreQuery,
    ) -> Result<ScoredSubjects, CallError> {
        let text = self.score_subjects_text(id, csv, query).await?;
        decode(Endpoint::ScoreSubjects, Some(id), &text)
    }

    // -------------------------------------------------------------- worker

    /// Asks for a job, waiting up to `wait_secs` at the coordinator.
    ///
    /// The spec is parsed strictly ([`shared::api::JobSpec`] and its
    /// configurations deny unknown fields). A lease whose spec does not
    /// parse is reported failed with the reason and answered as
    /// [`CallError::Incompatible`].
    pub async fn lease(&self, worker: &str, wait_secs: u32) -> Result<Option<Lease>, CallError> {
        let req = LeaseRequest {
            worker: worker.to_string(),
            wait_secs,
        };
        let Some(text) = self
            .call(Endpoint::Lease, None, &[], Body::json(&req))
            .await?
        else {
            return Ok(None);
        };
        let err = match parse_lease(&text) {
            Ok(lease) => return Ok(Some(lease)),
            Err(e) => e,
        };
        let Some((job_id, lease_token)) = lease_handle(&text) else {
            return Err(CallError::Transient(format!(
                "{}: reading answer: {err}",
                Endpoint::Lease.path()
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
        let id = job_id.to_string();
        self.typed(Endpoint::Heartbeat, Some(&id), Body::json(hb))
            .await
    }

    /// Uploads a result.
    pub async fn result(&self, job_id: i64, up: &ResultUpload) -> Result<ResultAck, CallError> {
        let id = job_id.to_string();
        self.typed(Endpoint::Result, Some(&id), Body::json(up))
            .await
    }

    /// Reports a failure.
    pub async fn fail(&self, job_id: i64, f: &FailReport) -> Result<JobStateAck, CallError> {
        let id = job_id.to_string();
        self.typed(Endpoint::Fail, Some(&id), Body::json(f)).await
    }

    /// Hands a job back unfinished.
    pub async fn release(&self, job_id: i64, token: &str) -> Result<JobStateAck, CallError> {
        let id = job_id.to_string();
        let body = ReleaseRequest {
            lease_token: token.to_string(),
        };
        self.typed(Endpoint::Release, Some(&id), Body::json(&body))
            .await
    }
}

/// Whether `url` answers HTTP 200 within `timeout`: the container health
/// probe (`irlgrid health`), which takes any URL.
pub async fn probe(url: &str, timeout: Duration) -> Result<(), String> {
    let http = reqwest::Client::builder()
        .timeout(timeout)
        .build()
        .map_err(|e| e.to_string())?;
    let resp = http
        .get(url)
        .send()
        .await
        .map_err(|e| format!("{url} did not answer: {e}"))?;
    if resp.status() != StatusCode::OK {
        return Err(format!("{url} answered {}", resp.status()));
    }
    Ok(())
}

/// An endpoint's path, `{id}` filled in when given.
fn path(endpoint: Endpoint, id: Option<&str>) -> String {
    match id {
        Some(id) => endpoint.path_of(id),
        None => endpoint.template().to_string(),
    }
}

/// An answer read as `T`; the error names the endpoint and the field.
fn decode<T: DeserializeOwned>(
    endpoint: Endpoint,
    id: Option<&str>,
    text: &str,
) -> Result<T, CallError> {
    let de = &mut serde_json::Deserializer::from_str(text);
    serde_path_to_error::deserialize(de).map_err(|e| {
        CallError::Transient(format!(
            "{}: reading answer: {}: {}",
            path(endpoint, id),
            e.path(),
            e.inner()
        ))
    })
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

    #[test]
    fn a_lease_whose_spec_does_not_parse_can_still_be_reported() {
        let text = r#"{"job_id": 3, "lease_token": "t", "spec": {"curriculum": 1}}"#;
        let e = parse_lease(text).unwrap_err();
        assert!(e.starts_with("spec"), "{e}");
        assert_eq!(lease_handle(text), Some((3, "t".to_string())));
        assert_eq!(lease_handle("{}"), None);
    }

    #[test]
    fn paths_come_from_the_route_table() {
        let c = Client::new("http://h:1/", None).unwrap();
        assert_eq!(c.base(), "http://h:1");
        assert_eq!(
            c.url(Endpoint::ResultsCsv, Some("s")),
            "http://h:1/api/v1/searches/s/results.csv"
        );
        assert_eq!(c.url(Endpoint::Lease, None), "http://h:1/api/v1/leases");
    }

    #[test]
    fn refusals_keep_their_status_and_message() {
        let e = CallError::Rejected {
            status: 400,
            message: "trials: must be in 1..=100".into(),
        };
        assert_eq!(e.refusal_status(), Some(400));
        assert_eq!(e.message(), "trials: must be in 1..=100");
        assert_eq!(CallError::NotFound("x".into()).refusal_status(), Some(404));
        assert!(CallError::Unreachable("x".into()).is_transient());
        assert_eq!(CallError::Transient("x".into()).refusal_status(), None);
    }
}
