//! The dashboard: server-rendered HTML pages over the queue and
//! the result documents, hand-drawn SVG charts of the paper's figures, a
//! little plain JavaScript for live refresh, and the optional login.
//!
//! Routes (all `GET` unless noted):
//! - `/` — every search, newest first, paginated (`?page=N`);
//! - `/searches/{id}` — live progress, the figures, the job table
//!   (`?jobs_page=N&jobs_status=STATE`);
//! - `/searches/{id}/charts/{name}.svg` — one chart as a standalone SVG;
//! - `/fragments/searches`, `/fragments/searches/{id}/live`,
//!   `/fragments/searches/{id}/figures` — the parts the script refreshes;
//! - `/login` (`GET` form, `POST` check), `POST /logout`, `/dashboard.js`.
//!
//! Layout: this file holds the routes and handlers (they read, then hand
//! plain data to the templates); [`pages`] the HTML as maud templates (with
//! the style sheet and script in `assets/`); [`chart`] the SVG charts the
//! pages embed and `/searches/{id}/charts/` serves; [`auth`] the login.
//!
//! Reads go through the store ([`queue::search_rows`],
//! [`crate::store::reads::job_curves`], [`results::document`], and the paged lists of
//! [`crate::store::reads`], each bounded by `LIMIT`).

pub mod auth;
pub mod chart;
mod figure_cache;
pub mod pages;

use std::sync::Arc;

use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use axum::http::{header, StatusCode};
use axum::middleware::from_fn_with_state;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use maud::{Markup, PreEscaped};
use serde::Deserialize;
use shared::api::{point_label_with, JobState, SearchState};

use crate::auth::Tokens;
use crate::domain::results::{self, Current};
use crate::domain::DomainError;
use crate::error::ApiError;
use crate::extract::ApiPath;
use crate::state::AppState;
use crate::store::queue::{self, SearchRow};
use crate::store::reads::{job_curves, job_page, leased_jobs, recent_done, search_page, LeasedJob};
use crate::store::{now_ms, StoreError};
use chart::{ChartId, Curve};
use figure_cache::FigureCache;

/// Searches per page of `/`.
pub const SEARCHES_PER_PAGE: i64 = 25;
/// Jobs per page of a search's job table.
pub const JOBS_PER_PAGE: i64 = 50;
/// Running jobs listed (with their worker) on a search page.
pub const MAX_LEASED_SHOWN: i64 = 64;
/// Jobs whose learning curves are drawn.
pub const MAX_CURVES: i64 = 8;
/// Per-subject figures drawn inline (all stay downloadable).
pub const MAX_SUBJECT_FIGURES: usize = 60;

/// State of the dashboard's handlers.
#[derive(Clone)]
pub struct DashState {
    /// The coordinator's state.
    pub app: AppState,
    /// Search pages' figures, drawn once per document.
    figures: Arc<FigureCache>,
}

impl DashState {
    /// Whether pages show a logout button (a login is in force).
    pub fn login_in_force(&self) -> bool {
        !Tokens::of(&self.app.cfg).reads_open()
    }
}

/// The dashboard's routes, ready to `.merge` into the coordinator's
/// router. Pages need the admin or reader token unless reads are public
/// (`public_reads`).
pub fn router(app: AppState) -> Router<AppState> {
    let st = DashState {
        app,
        figures: Arc::default(),
    };
    let protected = Router::new()
        .route("/", get(index))
        .route("/searches/{id}", get(search))
        .route("/searches/{id}/charts/{file}", get(chart_svg))
        .route("/fragments/searches", get(index_fragment))
        .route("/fragments/searches/{id}/live", get(live_fragment))
        .route("/fragments/searches/{id}/figures", get(figures_fragment))
        .route_layer(from_fn_with_state(st.clone(), auth::require));
    Router::new()
        .merge(protected)
        .route("/login", get(auth::login_form).post(auth::login))
        .route("/logout", post(auth::logout))
        .route("/dashboard.js", get(script))
        .with_state(st)
}

/// An HTML or SVG page failed: an HTML-friendly wrapper of [`ApiError`].
pub struct PageError(ApiError);

impl From<ApiError> for PageError {
    fn from(e: ApiError) -> Self {
        Self(e)
    }
}

impl From<DomainError> for PageError {
    fn from(e: DomainError) -> Self {
        Self(ApiError::from(e))
    }
}

impl From<StoreError> for PageError {
    fn from(e: StoreError) -> Self {
        Self(ApiError::from(e))
    }
}

impl From<anyhow::Error> for PageError {
    fn from(e: anyhow::Error) -> Self {
        Self(ApiError::Internal(e))
    }
}

impl From<sqlx::Error> for PageError {
    fn from(e: sqlx::Error) -> Self {
        Self(ApiError::from(e))
    }
}

impl IntoResponse for PageError {
    fn into_response(self) -> Response {
        let status = self.0.status();
        let msg = match &self.0 {
            ApiError::Internal(e) => {
                tracing::error!(error = format!("{e:#}"), "dashboard page failed");
                "internal error".to_string()
            }
            other => other.to_string(),
        };
        pages::error_page(status, &msg)
    }
}

/// The search's label parameter (the one inferred; `w1` by default).
fn label_param(info: &queue::SearchInfo) -> String {
    info.resolved.report.label_param.clone()
}

/// "w1=0.5" for grid point `idx` of a search.
fn point_text(info: &queue::SearchInfo, idx: u32) -> String {
    info.points
        .get(idx as usize)
        .map(|p| point_label_with(p, chart::short))
        .unwrap_or_else(|| format!("point {idx}"))
}

/// Learning curves of the running jobs, or of the latest finished ones
/// when nothing runs.
async fn curves(
    app: &AppState,
    info: &queue::SearchInfo,
    leased: &[LeasedJob],
) -> anyhow::Result<(Vec<Curve>, bool)> {
    let (ids, live): (Vec<i64>, bool) = if leased.is_empty() {
        (recent_done(&app.db, &info.id, MAX_CURVES).await?, false)
    } else {
        (
            leased
                .iter()
                .take(MAX_CURVES as usize)
                .map(|j| j.id)
                .collect(),
            true,
        )
    };
    let out = job_curves(&app.db, &ids)
        .await?
        .into_iter()
        .map(|job| Curve {
            label: format!(
                "job {} ({} trial {}{})",
                job.id,
                point_text(info, job.point_idx),
                job.trial,
                job.worker.map(|w| format!(", {w}")).unwrap_or_default()
            ),
            points: job.points,
        })
        .collect();
    Ok((out, live))
}

// ---------------------------------------------------------------- handlers

/// `?page=N`.
#[derive(Debug, Deserialize, Default)]
pub struct PageQuery {
    page: Option<i64>,
}

/// The page asked for; a malformed query string means the first page.
fn page_of(q: &Result<Query<PageQuery>, QueryRejection>) -> i64 {
    q.as_ref()
        .ok()
        .and_then(|q| q.page)
        .unwrap_or(1)
        .clamp(1, 1_000_000)
}

async fn index(
    State(st): State<DashState>,
    q: Result<Query<PageQuery>, QueryRejection>,
) -> Result<Response, PageError> {
    let page = page_of(&q);
    let (total, rows) = search_page(&st.app.db, page, SEARCHES_PER_PAGE).await?;
    let table = pages::search_table(&rows, page, total, SEARCHES_PER_PAGE, now_ms());
    Ok(pages::html(
        StatusCode::OK,
        pages::index_page(
            table,
            page,
            rows.iter().any(|r| r.status == SearchState::Running),
            st.login_in_force(),
        ),
    ))
}

async fn index_fragment(
    State(st): State<DashState>,
    q: Result<Query<PageQuery>, QueryRejection>,
) -> Result<Response, PageError> {
    let page = page_of(&q);
    let (total, rows) = search_page(&st.app.db, page, SEARCHES_PER_PAGE).await?;
    Ok(pages::fragment(pages::search_table(
        &rows,
        page,
        total,
        SEARCHES_PER_PAGE,
        now_ms(),
    )))
}

/// `?jobs_page=N&jobs_status=STATE` of a search page.
#[derive(Debug, Deserialize, Default)]
pub struct JobsQuery {
    jobs_page: Option<i64>,
    jobs_status: Option<String>,
}

async fn one_row(app: &AppState, id: &str) -> Result<SearchRow, ApiError> {
    queue::search_rows(&app.db, Some(id))
        .await?
        .pop()
        .ok_or_else(|| ApiError::NotFound(format!("no search with id {id}")))
}

/// What the live part of the page of the search `row` shows.
async fn live_html(app: &AppState, row: &SearchRow) -> Result<Markup, PageError> {
    let id = row.id.as_str();
    let info = app.search_info(id).await?;
    let leased = leased_jobs(&app.db, id, MAX_LEASED_SHOWN).await?;
    let (curves, live) = curves(app, &info, &leased).await?;
    let curves_svg = chart::learning_curves(&curves, false);
    let points: Vec<String> = leased
        .iter()
        .map(|j| point_text(&info, j.point_idx))
        .collect();
    Ok(pages::live(
        row,
        &leased,
        &points,
        &curves_svg,
        live,
        now_ms(),
    ))
}

/// What the figures part of a search page shows, drawn once per document
/// and refinement ([`figure_cache`]). The stamp names what the figures are
/// drawn from: the facts epoch (read first, so a change of the search's
/// stored data after it makes the stamp stale), the document (a completed
/// search's by its job counts, without reading it; a running one's by the
/// cached build a reader is served) and the refinement.
async fn figures_html(st: &DashState, id: &str) -> Result<Markup, PageError> {
    let app = &st.app;
    let epoch = app.facts_epoch();
    let info = app.search_info(id).await?;
    let refinement = results::refinement(app, id).await?;
    let refinement = refinement.spec.is_some().then_some(refinement);
    let refined = match &refinement {
        Some(r) => serde_json::to_string(r).map_err(anyhow::Error::from)?,
        None => String::new(),
    };
    let final_stamp = |row: &SearchRow| format!("{epoch}:final:{}:{refined}", row.doc_key());
    let row = one_row(app, id).await?;
    if row.status == SearchState::Completed {
        if let Some(html) = st.figures.get(id, &final_stamp(&row)) {
            return Ok(PreEscaped(html.to_string()));
        }
    }
    let (row, current) = results::current(app, id).await?;
    let stamp = match &current {
        Current::Final(_) => final_stamp(&row),
        Current::Partial(p) => format!("{epoch}:partial:{}:{:?}:{refined}", p.key, p.built),
    };
    if let Some(html) = st.figures.get(id, &stamp) {
        return Ok(PreEscaped(html.to_string()));
    }
    let html = pages::figures(
        &row,
        &current.doc(),
        &label_param(&info),
        refinement.as_ref(),
    )
    .into_string();
    st.figures.put(id, stamp, html.as_str().into());
    Ok(PreEscaped(html))
}

async fn search(
    State(st): State<DashState>,
    ApiPath(id): ApiPath<String>,
    q: Result<Query<JobsQuery>, QueryRejection>,
) -> Result<Response, PageError> {
    let info = st.app.search_info(&id).await?;
    let row = one_row(&st.app, &id).await?;
    let q = q.map_err(ApiError::from)?.0;
    let status = match q.jobs_status.as_deref().filter(|s| !s.is_empty()) {
        None => None,
        Some(s) => Some(JobState::parse(s).ok_or_else(|| {
            ApiError::BadRequest(format!("jobs_status: unknown job state {s:?}"))
        })?),
    };
    let jobs_page = q.jobs_page.unwrap_or(1).clamp(1, 1_000_000);
    let jobs = job_page(&st.app.db, &id, status, jobs_page, JOBS_PER_PAGE).await?;
    let points: Vec<String> = jobs
        .iter()
        .map(|j| point_text(&info, j.point_idx))
        .collect();
    let live = live_html(&st.app, &row).await?;
    let figures = figures_html(&st, &id).await?;
    let body = pages::search_page(pages::SearchPage {
        row: &row,
        live,
        figures,
        jobs: &jobs,
        job_points: &points,
        jobs_status: status,
        jobs_page,
        jobs_per_page: JOBS_PER_PAGE,
        logout: st.login_in_force(),
    });
    Ok(pages::html(StatusCode::OK, body))
}

async fn live_fragment(
    State(st): State<DashState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Response, PageError> {
    let row = one_row(&st.app, &id).await?;
    Ok(pages::fragment(live_html(&st.app, &row).await?))
}

async fn figures_fragment(
    State(st): State<DashState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Response, PageError> {
    Ok(pages::fragment(figures_html(&st, &id).await?))
}

async fn chart_svg(
    State(st): State<DashState>,
    ApiPath((id, file)): ApiPath<(String, String)>,
) -> Result<Response, PageError> {
    let chart = file
        .strip_suffix(".svg")
        .and_then(ChartId::parse)
        .ok_or_else(|| ApiError::NotFound(format!("no chart named {file}")))?;
    let info = st.app.search_info(&id).await?;
    let body = match chart {
        ChartId::LearningCurves => {
            let leased = leased_jobs(&st.app.db, &id, MAX_CURVES).await?;
            let (c, _) = curves(&st.app, &info, &leased).await?;
            chart::learning_curves(&c, true)
        }
        other => {
            let (_, doc) = results::document(&st.app, &id).await?;
            chart::render(&doc, &label_param(&info), other, true)
                .ok_or_else(|| ApiError::NotFound(format!("no chart named {file}")))?
        }
    };
    let short_id: String = id.chars().take(8).collect();
    let disposition = format!(
        "inline; filename=\"irlgrid-{short_id}-{}\"",
        chart.file_name()
    );
    Ok((
        [
            (
                header::CONTENT_TYPE,
                "image/svg+xml; charset=utf-8".to_string(),
            ),
            (header::CONTENT_DISPOSITION, disposition),
            (header::CACHE_CONTROL, "no-store".to_string()),
            (
                header::CONTENT_SECURITY_POLICY,
                "default-src 'none'; style-src 'unsafe-inline'".to_string(),
            ),
            (header::X_CONTENT_TYPE_OPTIONS, "nosniff".to_string()),
        ],
        body,
    )
        .into_response())
}

async fn script() -> Response {
    (
        [
            (header::CONTENT_TYPE, "text/javascript; charset=utf-8"),
            (header::CACHE_CONTROL, "no-cache"),
            (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
        ],
        pages::SCRIPT,
    )
        .into_response()
}
