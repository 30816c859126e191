//! HTML of the dashboard: the page shell (inline CSS, strict CSP), the
//! search list, a search's live part, figures and job table, the login
//! and error pages, and the refresh script. Every piece of data is
//! escaped with [`esc`].

use std::fmt::Write as _;

use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use shared::analysis::{Method, ResultDocument, SubjectRefinement};
use shared::api::routes::Endpoint;
use shared::api::{JobCounts, JobState, Refinement, SearchState};

use super::charts::{self, ChartId};
use super::svg::{esc, short};
use super::MAX_SUBJECT_FIGURES;
use crate::store::queue::SearchRow;
use crate::store::reads::{JobRow, LeasedJob};
use crate::store::rfc3339;

/// Content-Security-Policy of every page: nothing from elsewhere, scripts
/// only from `/dashboard.js`.
pub const CSP: &str = "default-src 'none'; style-src 'unsafe-inline'; script-src 'self'; \
                       connect-src 'self'; img-src 'self' data:; form-action 'self'; \
                       frame-ancestors 'none'; base-uri 'none'";

/// Milliseconds between refreshes of a running search's live part.
pub const REFRESH_MS: u64 = 3000;
/// Least milliseconds between refreshes of a running search's figures.
pub const FIGURES_REFRESH_MS: u64 = 15_000;

const STYLE: &str = r#"
*{box-sizing:border-box}
body{margin:0;font:14px/1.45 -apple-system,"Segoe UI",Helvetica,Arial,sans-serif;color:#1d2330;background:#f4f6f9}
header.top{background:#1f2a44;color:#fff;padding:10px 24px;display:flex;align-items:center;gap:24px}
header.top a{color:#fff;text-decoration:none;font-weight:600}
header.top .sp{flex:1}
header.top form{margin:0}
header.top button{background:none;border:1px solid #8fa0c4;color:#fff;border-radius:4px;padding:3px 10px;cursor:pointer}
main{max-width:1400px;margin:0 auto;padding:18px 24px 48px}
h1{font-size:22px;margin:6px 0 4px}
h2{font-size:17px;margin:26px 0 8px;border-bottom:1px solid #d7dce5;padding-bottom:4px}
a{color:#1f5fbf}
.muted{color:#6b7385}
.card{background:#fff;border:1px solid #dde2ea;border-radius:6px;padding:14px 16px;margin:12px 0}
table{border-collapse:collapse;width:100%;background:#fff}
th,td{text-align:left;padding:5px 8px;border-bottom:1px solid #e8ebf0;vertical-align:top}
th{background:#f0f3f7;font-weight:600;font-size:13px}
td.num,th.num{text-align:right;font-variant-numeric:tabular-nums}
.badge{display:inline-block;padding:1px 8px;border-radius:10px;font-size:12px;font-weight:600;color:#fff}
.b-running{background:#2f6fdb}.b-completed{background:#23884a}.b-cancelled{background:#8a8f99}
.out-of-model{background:#b35806;margin-left:6px}
.refined{background:#6a3d9a;margin-left:6px}
.b-queued{background:#8a8f99}.b-leased{background:#2f6fdb}.b-done{background:#23884a}.b-failed{background:#c62f2f}
.bar{display:flex;height:12px;min-width:160px;background:#e5e8ee;border-radius:6px;overflow:hidden}
.bar span{display:block;height:100%}
.s-done{background:#2e9e5b}.s-failed{background:#d64545}.s-leased{background:#4b86e8}.s-cancelled{background:#b7bcc6}
.stats{display:flex;flex-wrap:wrap;gap:10px;margin:10px 0}
.stat{background:#fff;border:1px solid #dde2ea;border-radius:6px;padding:8px 12px;min-width:120px}
.stat b{display:block;font-size:18px}
.links a{margin-right:14px}
figure{margin:14px 0;background:#fff;border:1px solid #dde2ea;border-radius:6px;padding:10px;overflow-x:auto}
figcaption{font-size:13px;color:#4a5263;margin-top:6px}
svg.chart{max-width:100%;height:auto}
.pager a,.pager span{margin-right:10px}
.notes li{font-size:13px;color:#4a5263}
.empty{padding:18px;color:#6b7385;background:#fff;border:1px dashed #c9cfda;border-radius:6px}
.err{color:#b02020}
form.login{max-width:420px;margin:60px auto}
form.login input[type=password]{width:100%;padding:8px;font-size:15px;margin:8px 0 12px}
form.login button{padding:7px 18px;font-size:15px}
code{background:#eef1f5;padding:1px 4px;border-radius:3px}
"#;

/// Sets the headers every dashboard HTML answer carries.
fn secure(resp: &mut Response) {
    let h = resp.headers_mut();
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(CSP),
    );
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    h.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
}

/// A full HTML page answer.
pub fn html(status: StatusCode, body: String) -> Response {
    let mut resp = (
        status,
        [(header::CONTENT_TYPE, "text/html; charset=utf-8")],
        body,
    )
        .into_response();
    secure(&mut resp);
    resp
}

/// An HTML fragment answer (for the refresh script).
pub fn fragment(body: String) -> Response {
    html(StatusCode::OK, body)
}

fn shell(title: &str, logout: bool, script: bool, content: &str) -> String {
    let logout = if logout {
        r#"<form method="post" action="/logout"><button type="submit">Log out</button></form>"#
    } else {
        ""
    };
    let script = if script {
        r#"<script src="/dashboard.js" defer></script>"#
    } else {
        ""
    };
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\
         <title>{t} - irlgrid</title><style>{STYLE}</style>{script}</head>\
         <body><header class=\"top\"><a href=\"/\">irlgrid dashboard</a>\
         <a href=\"/\">All searches</a><a href=\"{api}\">API</a>\
         <span class=\"sp\"></span>{logout}</header><main>{content}</main></body></html>\n",
        t = esc(title),
        api = Endpoint::OpenApi.path(),
    )
}

/// The login form (also shown, 401, after a wrong token).
pub fn login_page(next: &str, error: Option<&str>, status: StatusCode) -> Response {
    let err = error
        .map(|e| format!("<p class=\"err\">{}</p>", esc(e)))
        .unwrap_or_default();
    let body = format!(
        "<form class=\"login card\" method=\"post\" action=\"/login\">\
         <h1>Log in</h1><p class=\"muted\">This coordinator requires its token \
         (<code>IRLGRID_TOKEN</code>) to view the dashboard.</p>{err}\
         <label for=\"token\">Token</label>\
         <input id=\"token\" name=\"token\" type=\"password\" autocomplete=\"current-password\" required autofocus>\
         <input type=\"hidden\" name=\"next\" value=\"{n}\">\
         <button type=\"submit\">Log in</button></form>",
        n = esc(next)
    );
    html(status, shell("Log in", false, false, &body))
}

/// An error page.
pub fn error_page(status: StatusCode, msg: &str) -> Response {
    let body = format!(
        "<h1>{} {}</h1><p>{}</p><p><a href=\"/\">All searches</a></p>",
        status.as_u16(),
        esc(status.canonical_reason().unwrap_or("")),
        esc(msg)
    );
    html(status, shell("Error", false, false, &body))
}

/// "3m 05s" style duration.
pub fn duration(secs: f64) -> String {
    if !secs.is_finite() || secs < 0.0 {
        return "–".into();
    }
    let s = secs.round() as u64;
    match s {
        0 => "<1s".into(),
        1..=59 => format!("{s}s"),
        60..=3599 => format!("{}m {:02}s", s / 60, s % 60),
        3600..=86_399 => format!("{}h {:02}m", s / 3600, s / 60 % 60),
        _ => format!("{}d {}h", s / 86_400, s / 3600 % 24),
    }
}

/// "2024-05-01 12:00:03 UTC".
pub fn when(ms: i64) -> String {
    let t = rfc3339(ms);
    format!("{} {} UTC", &t[..10], &t[11..19])
}

fn badge(state: &str) -> String {
    format!("<span class=\"badge b-{0}\">{0}</span>", esc(state))
}

/// A stacked progress bar of finished / running jobs.
fn progress_bar(j: &JobCounts) -> String {
    let total = j.total.max(1) as f64;
    let pct = |n: u64| 100.0 * n as f64 / total;
    let finished = j.done + j.failed;
    format!(
        "<div class=\"bar\" title=\"{d} done, {f} failed, {l} running, {q} queued, {c} cancelled\">\
         <span class=\"s-done\" style=\"width:{:.2}%\"></span>\
         <span class=\"s-failed\" style=\"width:{:.2}%\"></span>\
         <span class=\"s-leased\" style=\"width:{:.2}%\"></span>\
         <span class=\"s-cancelled\" style=\"width:{:.2}%\"></span></div>\
         <span class=\"muted\">{finished} / {t} jobs ({:.0}%)</span>",
        pct(j.done),
        pct(j.failed),
        pct(j.leased),
        pct(j.cancelled),
        pct(finished),
        d = j.done,
        f = j.failed,
        l = j.leased,
        q = j.queued,
        c = j.cancelled,
        t = j.total,
    )
}

fn elapsed(r: &SearchRow, now: i64) -> String {
    match r.started_at {
        None => "not started".into(),
        Some(s) => duration((r.finished_at.unwrap_or(now) - s) as f64 / 1000.0),
    }
}

fn eta(r: &SearchRow) -> String {
    match (r.status, r.eta_secs()) {
        (SearchState::Running, Some(s)) => duration(s),
        (SearchState::Running, None) => "after the first job".into(),
        _ => "–".into(),
    }
}

fn pager(base: &str, param: &str, page: i64, pages: i64) -> String {
    if pages <= 1 {
        return String::new();
    }
    let sep = if base.contains('?') { '&' } else { '?' };
    let mut s = String::from("<p class=\"pager\">");
    if page > 1 {
        let _ = write!(
            s,
            "<a href=\"{}{sep}{param}={}\">&larr; newer</a>",
            esc(base),
            page - 1
        );
    }
    let _ = write!(s, "<span>page {page} of {pages}</span>");
    if page < pages {
        let _ = write!(
            s,
            "<a href=\"{}{sep}{param}={}\">older &rarr;</a>",
            esc(base),
            page + 1
        );
    }
    s.push_str("</p>");
    s
}

/// The search list (refreshed while a listed search runs).
pub fn search_table(rows: &[SearchRow], page: i64, total: i64, per_page: i64, now: i64) -> String {
    let running = rows.iter().any(|r| r.status == SearchState::Running);
    let mut s = format!("<div data-running=\"{running}\" data-key=\"\">");
    if total == 0 {
        s.push_str(
            "<div class=\"empty\">No searches yet. Submit one with <code>irlgrid submit FILE.json</code>, \
             <code>POST /api/v1/searches</code>, or start a local one with <code>irlgrid run</code>.</div></div>",
        );
        return s;
    }
    if rows.is_empty() {
        let _ = write!(s, "<div class=\"empty\">No searches on page {page}. <a href=\"/\">First page</a></div></div>");
        return s;
    }
    s.push_str(
        "<table><thead><tr><th>Name</th><th>Status</th><th>Progress</th>\
         <th class=\"num\">Queued</th><th class=\"num\">Running</th><th class=\"num\">Done</th>\
         <th class=\"num\">Failed</th><th class=\"num\">Workers</th><th>Submitted</th>\
         <th>Elapsed</th><th>ETA</th></tr></thead><tbody>",
    );
    for r in rows {
        let _ = write!(
            s,
            "<tr><td><a href=\"/searches/{id}\">{name}</a><div class=\"muted\">{points} points x {trials} trials</div></td>\
             <td>{status}</td><td>{bar}</td><td class=\"num\">{q}</td><td class=\"num\">{l}</td>\
             <td class=\"num\">{d}</td><td class=\"num\">{f}</td><td class=\"num\">{w}</td>\
             <td>{created}</td><td>{el}</td><td>{eta}</td></tr>",
            id = esc(&r.id),
            name = esc(&r.name),
            points = r.points,
            trials = r.trials,
            status = badge(r.status.as_str()),
            bar = progress_bar(&r.jobs),
            q = r.jobs.queued,
            l = r.jobs.leased,
            d = r.jobs.done,
            f = r.jobs.failed,
            w = r.workers_busy,
            created = when(r.created_at),
            el = elapsed(r, now),
            eta = eta(r),
        );
    }
    s.push_str("</tbody></table>");
    let pages = (total + per_page - 1) / per_page;
    s.push_str(&pager("/", "page", page, pages));
    s.push_str("</div>");
    s
}

/// `/`.
pub fn index_page(table: &str, page: i64, running: bool, logout: bool) -> String {
    let refresh = if running {
        format!(
            " data-src=\"/fragments/searches?page={page}\" data-every=\"{}\"",
            REFRESH_MS * 2
        )
    } else {
        String::new()
    };
    let body = format!(
        "<h1>Searches</h1><p class=\"muted\">Reward-parameter searches on this coordinator, newest first.</p>\
         <div id=\"searches\" class=\"live\"{refresh}>{table}</div>"
    );
    shell("Searches", logout, true, &body)
}

fn stat(label: &str, value: &str) -> String {
    format!(
        "<div class=\"stat\"><span class=\"muted\">{}</span><b>{}</b></div>",
        esc(label),
        value
    )
}

/// The live part of a search page: progress, counts, workers, curves.
pub fn live(
    r: &SearchRow,
    leased: &[LeasedJob],
    points: &[String],
    curves_svg: &str,
    curves_live: bool,
    now: i64,
) -> String {
    let running = r.status == SearchState::Running;
    let key = r.doc_key();
    let mut s = format!(
        "<div data-running=\"{running}\" data-key=\"{}\">",
        esc(&key)
    );
    let _ = write!(s, "<div class=\"card\">{}</div>", progress_bar(&r.jobs));
    s.push_str("<div class=\"stats\">");
    s.push_str(&stat("Status", &badge(r.status.as_str())));
    for (label, n) in [
        ("Queued", r.jobs.queued),
        ("Running", r.jobs.leased),
        ("Done", r.jobs.done),
        ("Failed", r.jobs.failed),
        ("Cancelled", r.jobs.cancelled),
        ("Workers busy", r.workers_busy),
    ] {
        s.push_str(&stat(label, &n.to_string()));
    }
    s.push_str(&stat("Elapsed", &esc(&elapsed(r, now))));
    s.push_str(&stat("ETA", &esc(&eta(r))));
    s.push_str(&stat(
        "Trials converged",
        &format!(
            "{} <span class=\"muted\">/ {} not</span>",
            r.converged, r.not_converged
        ),
    ));
    s.push_str(&stat("Sampling shortfall", &r.shortfall.to_string()));
    s.push_str("</div>");
    s.push_str("<h2>Workers and their jobs</h2>");
    if leased.is_empty() {
        s.push_str("<div class=\"empty\">No job of this search is running now.</div>");
    } else {
        s.push_str(
            "<table><thead><tr><th>Worker</th><th>Job</th><th>Point</th><th class=\"num\">Trial</th>\
             <th>Phase</th><th>Training progress</th><th class=\"num\">Success rate</th>\
             <th class=\"num\">Mean return</th><th>Running for</th><th>Lease expires in</th></tr></thead><tbody>",
        );
        for (j, p) in leased.iter().zip(points) {
            let prog = j.progress.as_ref();
            let steps = prog
                .map(|p| {
                    let pct = if p.total_env_steps > 0 {
                        100.0 * p.env_steps as f64 / p.total_env_steps as f64
                    } else {
                        0.0
                    };
                    format!("{} / {} steps ({pct:.0}%)", p.env_steps, p.total_env_steps)
                })
                .unwrap_or_else(|| "–".into());
            let _ = write!(
                s,
                "<tr><td>{w}</td><td><a href=\"{href}\">{id}</a>{att}</td><td>{p}</td>\
                 <td class=\"num\">{t}</td><td>{ph}</td><td>{steps}</td><td class=\"num\">{sr}</td>\
                 <td class=\"num\">{ret}</td><td>{run}</td><td>{exp}</td></tr>",
                w = esc(&j.worker),
                id = j.id,
                href = Endpoint::JobDetail.path_of(j.id),
                att = if j.attempts > 0 {
                    format!(" <span class=\"muted\">(retry {})</span>", j.attempts)
                } else {
                    String::new()
                },
                p = esc(p),
                t = j.trial,
                ph = esc(j.phase.as_deref().unwrap_or("starting")),
                steps = esc(&steps),
                sr = prog
                    .and_then(|p| p.success_rate)
                    .map(short)
                    .unwrap_or_else(|| "–".into()),
                ret = prog
                    .and_then(|p| p.mean_return)
                    .map(short)
                    .unwrap_or_else(|| "–".into()),
                run = j
                    .leased_at
                    .map(|t| duration((now - t) as f64 / 1000.0))
                    .unwrap_or_else(|| "–".into()),
                exp = j
                    .lease_expires_at
                    .map(|t| duration((t - now).max(0) as f64 / 1000.0))
                    .unwrap_or_else(|| "–".into()),
            );
        }
        s.push_str("</tbody></table>");
        if leased.len() as u64 == super::MAX_LEASED_SHOWN as u64
            && r.jobs.leased > leased.len() as u64
        {
            let _ = write!(
                s,
                "<p class=\"muted\">{} more running jobs not listed.</p>",
                r.jobs.leased - leased.len() as u64
            );
        }
    }
    let what = if curves_live {
        "running jobs"
    } else {
        "the latest finished jobs"
    };
    let _ = write!(s, "<h2>Learning curves</h2>");
    s.push_str(&figure(
        &r.id,
        ChartId::LearningCurves,
        curves_svg,
        &format!("Success rate and mean return of {what}, from the workers' heartbeats."),
    ));
    s.push_str("</div>");
    s
}

fn figure(id: &str, chart: ChartId, svg: &str, caption: &str) -> String {
    let name = chart.file_name();
    let stem = name.trim_end_matches(".svg");
    format!(
        "<figure data-chart=\"{stem}\">{svg}<figcaption>{} \
         <a href=\"/searches/{}/charts/{}\" download=\"{}\">Download SVG</a></figcaption></figure>",
        esc(caption),
        esc(id),
        esc(&name),
        esc(&name)
    )
}

fn opt(v: Option<f64>) -> String {
    v.map(short).unwrap_or_else(|| "–".into())
}

/// The round of refinement that added each value (`value -> round`).
fn refined_values(refinement: Option<&Refinement>) -> Vec<(f64, u32)> {
    refinement
        .map(|r| {
            r.rounds
                .iter()
                .flat_map(|round| round.added.iter().map(move |&v| (v, round.round + 1)))
                .collect()
        })
        .unwrap_or_default()
}

/// The refinement section: what was asked for, and per subject the
/// estimate and bracketing pair after each round.
fn refinement_section(r: &Refinement, label: &str) -> String {
    let Some(spec) = &r.spec else {
        return String::new();
    };
    let mut s = format!(
        "<h2 id=\"refinement\">Refinement toward the subjects</h2><p class=\"muted\">Up to {} \
         rounds, {} trials per added point, until each subject's two neighbouring candidates are \
         within a ratio of {} ({}). <a href=\"{}\">JSON</a></p>",
        spec.rounds,
        spec.trials,
        short(spec.target_ratio),
        esc(&r.state),
        Endpoint::Refinement.path_of(esc(&r.id))
    );
    if r.rounds.is_empty() {
        s.push_str(
            "<div class=\"empty\">The first round is decided when the grid has finished.</div>",
        );
        return s;
    }
    s.push_str("<table id=\"refine-rounds\"><thead><tr><th>Subject</th>");
    for round in &r.rounds {
        let head = if round.round == 0 {
            "grid as submitted".to_string()
        } else {
            format!("after round {}", round.round)
        };
        let _ = write!(s, "<th class=\"num\">{head}</th>");
    }
    s.push_str("</tr></thead><tbody>");
    for first in &r.rounds[0].subjects {
        let name = first.subject.as_str();
        let _ = write!(s, "<tr><td>{}</td>", esc(name));
        for round in &r.rounds {
            let cell = round
                .subjects
                .iter()
                .find(|x| x.subject == name)
                .map_or_else(|| "–".to_string(), refinement_cell);
            let _ = write!(s, "<td class=\"num\">{cell}</td>");
        }
        s.push_str("</tr>");
    }
    s.push_str("<tr><td><i>points added</i></td>");
    for round in &r.rounds {
        let added = if round.added.is_empty() {
            round.stop.clone().unwrap_or_else(|| "none".into())
        } else {
            round
                .added
                .iter()
                .map(|&v| format!("{label}={}", short(v)))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let _ = write!(s, "<td class=\"num\">{}</td>", esc(&added));
    }
    s.push_str(
        "</tr></tbody></table><p class=\"muted\">Each cell: the subject's most likely value \
         [the bracketing pair of neighbours] → the midpoint it asked for.</p>",
    );
    s
}

/// One subject's cell of the refinement table.
fn refinement_cell(x: &SubjectRefinement) -> String {
    let pair = match (x.lo, x.hi) {
        (Some(lo), Some(hi)) => format!(" [{}, {}]", short(lo), short(hi)),
        _ => String::new(),
    };
    let ask = x
        .midpoint
        .map(|m| format!(" → {}", short(m)))
        .unwrap_or_default();
    format!("<b>{}</b>{}{}", opt(x.estimate), esc(&pair), esc(&ask))
}

/// The figures of a search from its (partial or final) result document.
pub fn figures(
    r: &SearchRow,
    doc: &ResultDocument,
    label: &str,
    refinement: Option<&Refinement>,
) -> String {
    let id = r.id.as_str();
    let mut s = String::new();
    let partial = r.status != SearchState::Completed;
    let _ = write!(
        s,
        "<p class=\"links\">Results: <a href=\"{0}\">JSON</a>\
         <a href=\"{2}\">CSV</a>\
         <a href=\"{3}\">raw trial outputs (JSON)</a>{1}</p>",
        Endpoint::Results.path_of(esc(id)),
        if partial {
            " <span class=\"muted\">(partial while the search runs)</span>"
        } else {
            ""
        },
        Endpoint::ResultsCsv.path_of(esc(id)),
        Endpoint::Outputs.path_of(esc(id)),
    );
    let any_trials = doc.weights.iter().any(|w| w.trials_done > 0);
    if !any_trials {
        s.push_str(
            "<div class=\"empty\">No results yet: the figures appear here as jobs finish.</div>",
        );
        s.push_str(&notes(doc));
        return s;
    }
    // Per grid point summary.
    let _ = write!(
        s,
        "<h2>Grid points</h2><table><thead><tr><th>Point</th><th class=\"num\">Trials done</th>\
         <th class=\"num\">Converged</th><th class=\"num\">Used</th><th class=\"num\">Area</th>\
         <th class=\"num\">+- SEM</th><th class=\"num\">Torque usage</th><th class=\"num\">+- SEM</th>\
         <th class=\"num\">Mean success rate</th><th class=\"num\">Shortfall trials</th></tr></thead><tbody>"
    );
    let refined = refined_values(refinement);
    for w in &doc.weights {
        let tag = refined
            .iter()
            .find(|(v, _)| *v == w.value)
            .map(|(_, round)| {
                format!(" <span class=\"badge refined\" title=\"added by refinement round {round}\">refined r{round}</span>")
            })
            .unwrap_or_default();
        let _ = write!(
            s,
            "<tr><td>{}{tag}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>\
             <td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>\
             <td class=\"num\">{}</td><td class=\"num\">{}</td></tr>",
            esc(&charts::point_label(w)),
            w.trials_done,
            w.trials_converged,
            w.trials_used,
            opt(w.area_mean),
            opt(w.area_sem),
            opt(w.torque_usage_mean),
            opt(w.torque_usage_sem),
            opt(w.success_rate_mean),
            w.shortfall_trials
        );
    }
    s.push_str("</tbody></table>");
    s.push_str(&solver_section(doc));
    s.push_str("<h2>Fig. 2 - area and torque usage</h2>");
    s.push_str(&figure(
        id,
        ChartId::Fig2,
        &charts::fig2(doc, label, false),
        &format!("Mean COM-path area and mean torque usage per {label}, error bars +-1 SEM across converged trials."),
    ));
    s.push_str("<h2>Fig. 3 - trajectories</h2>");
    s.push_str(&figure(
        id,
        ChartId::Fig3,
        &charts::fig3(doc, label, false),
        &format!("Highest-return trajectory and mean of the trial means per {label}, normalized x-z plane (start at the origin, rise 1)."),
    ));
    s.push_str("<h2>Identifiability</h2>");
    s.push_str(&figure(
        id,
        ChartId::Confusion,
        &charts::confusion(doc, label, false),
        &format!("Every usable trial scored as a subject against the grid rebuilt without it: how often each method recovers its true {label}."),
    ));
    s.push_str(&figure(
        id,
        ChartId::Coverage,
        &charts::coverage(doc, false),
        "How often the 50 / 80 / 90 / 95 % highest-probability sets of each method hold the true value; on the diagonal a method is calibrated (docs/inference.md#calibration).",
    ));
    s.push_str(&solver_holdout_section(doc));
    s.push_str(&observables_section(doc));
    if doc.subjects.is_empty() {
        s.push_str(
            "<h2>Subjects</h2><div class=\"empty\">This search has no subjects, so there are no \
             rankings (Figs. 4, 6), subject fits (Figs. 5, 7) or inferred values. Submit the \
             search with <code>subjects_csv</code> to get them.</div>",
        );
        s.push_str(&notes(doc));
        return s;
    }
    s.push_str("<h2>Figs. 4 and 6 - rankings</h2>");
    s.push_str(&figure(
        id,
        ChartId::Fig4,
        &charts::heatmap(doc, label, Method::Area, false),
        "Softmax over the grid of -K_area x D (area difference); the outlined cell is the inferred value.",
    ));
    s.push_str(&figure(
        id,
        ChartId::Fig6,
        &charts::heatmap(doc, label, Method::Correlation, false),
        "Softmax over the grid of K_corr x rho (correlation); the outlined cell is the inferred value.",
    ));
    s.push_str("<h2>Posterior over the grid</h2>");
    s.push_str(&figure(
        id,
        ChartId::Posterior,
        &charts::heatmap(doc, label, Method::Posterior, false),
        "Posterior probability of each grid value given the subject's path (docs/inference.md); the outlined cell is the most probable value.",
    ));
    let _ = write!(
        s,
        "<h2>Inferred {0} per subject</h2><table id=\"inferred\"><thead><tr><th>Subject</th>\
         <th class=\"num\">Inferred {0} (area)</th><th class=\"num\">D at it</th>\
         <th class=\"num\">Inferred {0} (correlation)</th><th class=\"num\">rho at it</th>\
         <th class=\"num\">MAP {0} (posterior)</th><th>90 % credible set</th>\
         <th class=\"num\">Subject area</th><th>Note</th></tr></thead><tbody>",
        esc(label)
    );
    for sub in &doc.subjects {
        let at_best = |m: Method| charts::best(m, sub).and_then(|i| charts::raw(m, sub, i));
        let post = sub.method(Method::Posterior);
        let set = post
            .and_then(|p| p.credible_set.as_ref())
            .map_or_else(|| "-".to_string(), |c| c.describe());
        let badge = match post.and_then(|p| p.out_of_model.as_ref()) {
            Some(o) if o.flagged => format!(
                " <span class=\"badge out-of-model\" title=\"largest tail probability {:.1e} \
                 is below {}: the path is implausible under every grid point\">out of model{}</span>",
                o.p_value,
                o.threshold,
                o.reason
                    .as_deref()
                    .map(|r| format!(" ({})", esc(r)))
                    .unwrap_or_default()
            ),
            _ => String::new(),
        };
        let note = sub
            .error
            .clone()
            .or_else(|| post.and_then(|p| p.unavailable.clone()))
            .unwrap_or_default();
        let _ = write!(
            s,
            "<tr><td>{}</td><td class=\"num\"><b>{}</b></td><td class=\"num\">{}</td>\
             <td class=\"num\"><b>{}</b></td><td class=\"num\">{}</td>\
             <td class=\"num\"><b>{}</b></td><td class=\"credible\">{}{}</td>\
             <td class=\"num\">{}</td><td>{}</td></tr>",
            esc(&sub.subject),
            opt(sub.inferred(Method::Area)),
            opt(at_best(Method::Area)),
            opt(sub.inferred(Method::Correlation)),
            opt(at_best(Method::Correlation)),
            opt(sub.inferred(Method::Posterior)),
            esc(&set),
            badge,
            opt(sub.area),
            esc(&note)
        );
    }
    s.push_str("</tbody></table>");
    if let Some(r) = refinement {
        s.push_str(&refinement_section(r, label));
    }
    s.push_str("<h2>Figs. 5 and 7 - subjects against their best-fitting mean paths</h2>");
    for (i, _) in doc.subjects.iter().enumerate().take(MAX_SUBJECT_FIGURES) {
        if let Some(svg) = charts::subject_fit(doc, label, i, false) {
            s.push_str(&figure(
                id,
                ChartId::Subject(i),
                &svg,
                &format!(
                    "Subject {} (dashed) against the mean path of its inferred {label} by each metric, band +-1 SD across trial means.",
                    doc.subjects[i].subject
                ),
            ));
        }
    }
    if doc.subjects.len() > MAX_SUBJECT_FIGURES {
        let _ = write!(
            s,
            "<p class=\"muted\">Figures of the first {MAX_SUBJECT_FIGURES} of {} subjects are shown; \
             the others are at <code>/searches/{}/charts/subject-N.svg</code>.</p>",
            doc.subjects.len(),
            esc(id)
        );
    }
    s.push_str(&notes(doc));
    s
}

/// "How good was the solver here": per grid point, each solver variant's
/// mean best return, duration and area, and each PPO variant's gap to the
/// optimizer's best return (docs/inference.md#solver-quality). Empty for a
/// search of one solver without an optimizer.
fn solver_section(doc: &ResultDocument) -> String {
    let many = doc
        .weights
        .iter()
        .any(|w| w.solvers.len() > 1 || w.optimum.is_some());
    if !many {
        return String::new();
    }
    let mut s = String::from(
        "<h2>Solvers at each grid point</h2><table id=\"solvers\"><thead><tr><th>Point</th>\
         <th>Solver</th><th>Kind</th><th class=\"num\">Trials used</th>\
         <th class=\"num\">Best return (mean)</th><th class=\"num\">Gap to optimum %</th>\
         <th class=\"num\">Duration s</th><th class=\"num\">Area</th></tr></thead><tbody>",
    );
    for w in &doc.weights {
        for sp in &w.solvers {
            let _ = write!(
                s,
                "<tr><td>{}</td><td>{}</td><td>{}</td><td class=\"num\">{}</td>\
                 <td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>\
                 <td class=\"num\">{}</td></tr>",
                esc(&charts::point_label(w)),
                esc(&sp.solver.name),
                sp.solver.kind.as_str(),
                sp.trials_used,
                opt(sp.best_return_mean),
                sp.gap_pct.map_or("-".to_string(), |g| format!("{g:.2}")),
                opt(sp.duration_mean),
                opt(sp.area_mean),
            );
        }
    }
    s.push_str(
        "</tbody></table><p class=\"muted\">Each trial counts with its best kept episode. The \
         optimizer starts from the noise-free squat, PPO from noisy starts; a gap of a few per \
         cent is a good solver.</p>",
    );
    s
}

/// Leave-one-solver-out calibration (docs/inference.md#leave-one-solver-out):
/// each variant's trials scored against the grid of the other variants.
fn solver_holdout_section(doc: &ResultDocument) -> String {
    let Some(h) = doc
        .identifiability
        .as_ref()
        .filter(|h| !h.by_solver.is_empty())
    else {
        return String::new();
    };
    let mut s = String::from(
        "<h3>Leave-one-solver-out</h3><table id=\"solver-holdout\"><thead><tr>\
         <th>Held-out solver</th><th>Method</th><th class=\"num\">Cases</th>\
         <th class=\"num\">50 %</th><th class=\"num\">80 %</th><th class=\"num\">90 %</th>\
         <th class=\"num\">95 %</th><th class=\"num\">Mean 90 % set</th>\
         <th class=\"num\">Gain (nats)</th></tr></thead><tbody>",
    );
    let rows = h
        .by_solver
        .iter()
        .map(|b| (b.solver.as_str(), &b.coverage))
        .chain(std::iter::once(("all", &h.by_solver_overall)));
    for (solver, coverage) in rows {
        for m in [Method::Posterior, Method::PosteriorOneSolver] {
            let Some(c) = coverage.get(&m) else { continue };
            let _ = write!(
                s,
                "<tr><td>{}</td><td>{}</td><td class=\"num\">{}</td>",
                esc(solver),
                m.title(),
                c.cases
            );
            for l in &c.levels {
                let _ = write!(s, "<td class=\"num\">{:.2}</td>", l.coverage);
            }
            let size = c.at(0.9).map_or(0.0, |l| l.mean_set_size);
            let _ = write!(
                s,
                "<td class=\"num\">{size:.1}</td><td class=\"num\">{:.2}</td></tr>",
                c.gain_nats
            );
        }
    }
    s.push_str(
        "</tbody></table><p class=\"muted\">A calibrated posterior holds the held-out solver's \
         true value about as often as each level says: the answer survives a change of solver.</p>",
    );
    s
}

/// The posterior's identifiability with each observable set the grid can
/// compute (docs/inference.md#observables): whether shape or timing
/// carries the information for this preset and grid.
fn observables_section(doc: &ResultDocument) -> String {
    let Some(h) = doc
        .identifiability
        .as_ref()
        .filter(|h| !h.by_observables.is_empty())
    else {
        return String::new();
    };
    let mut s = format!(
        "<h3>Evidence: shape or timing</h3><p class=\"muted\">This search's posterior uses \
         <b>{}</b>. Leave-one-trial-out coverage of the credible sets, mean 90 % set size, gain \
         and recovery within one grid step, per observable set; with several solver variants, \
         leave-one-solver-out coverage at 90 %.</p><table id=\"observables\"><thead><tr>\
         <th>Observables</th><th class=\"num\">Cases</th><th class=\"num\">50 %</th>\
         <th class=\"num\">80 %</th><th class=\"num\">90 %</th><th class=\"num\">95 %</th>\
         <th class=\"num\">Mean 90 % set</th><th class=\"num\">Gain (nats)</th>\
         <th class=\"num\">Within one</th><th class=\"num\">Leave-one-solver-out 90 %</th>\
         </tr></thead><tbody>",
        esc(h.observables.key())
    );
    for o in &h.by_observables {
        let c = &o.coverage;
        let _ = write!(
            s,
            "<tr><td>{}</td><td class=\"num\">{}</td>",
            esc(o.observables.key()),
            c.cases
        );
        for l in &c.levels {
            let _ = write!(s, "<td class=\"num\">{:.2}</td>", l.coverage);
        }
        let lovo = o
            .by_solver_overall
            .as_ref()
            .and_then(|c| c.at(0.9))
            .map_or("-".to_string(), |l| format!("{:.2}", l.coverage));
        let _ = write!(
            s,
            "<td class=\"num\">{:.1}</td><td class=\"num\">{:.2}</td>\
             <td class=\"num\">{}/{}</td><td class=\"num\">{lovo}</td></tr>",
            shared::analysis::holdout::set_size_at(c, 0.9),
            c.gain_nats,
            o.within_one,
            c.cases
        );
    }
    s.push_str("</tbody></table>");
    s
}

fn notes(doc: &ResultDocument) -> String {
    if doc.notes.is_empty() {
        return String::new();
    }
    let mut s = format!(
        "<details class=\"card\"><summary>Notes from the analysis ({})</summary><ul class=\"notes\">",
        doc.notes.len()
    );
    for n in doc.notes.iter().take(50) {
        let _ = write!(s, "<li>{}</li>", esc(n));
    }
    if doc.notes.len() > 50 {
        let _ = write!(
            s,
            "<li>... and {} more (see the JSON)</li>",
            doc.notes.len() - 50
        );
    }
    s.push_str("</ul></details>");
    s
}

/// Inputs of [`search_page`].
pub struct SearchPage<'a> {
    /// The search.
    pub row: &'a SearchRow,
    /// [`live`] HTML.
    pub live: &'a str,
    /// [`figures`] HTML.
    pub figures: &'a str,
    /// This page of the job table.
    pub jobs: &'a [JobRow],
    /// Point text of each job.
    pub job_points: &'a [String],
    /// State filter of the job table.
    pub jobs_status: Option<JobState>,
    /// Page of the job table.
    pub jobs_page: i64,
    /// Jobs per page.
    pub jobs_per_page: i64,
    /// Show the logout button.
    pub logout: bool,
}

/// `/searches/{id}`.
pub fn search_page(p: SearchPage) -> String {
    let r = p.row;
    let id = esc(&r.id);
    let running = r.status == SearchState::Running;
    let mut s = format!(
        "<p class=\"muted\"><a href=\"/\">Searches</a> / {id}</p><h1>{} {}</h1>\
         <p class=\"muted\">{} grid points x {} trials, convergence threshold {} | submitted {}{}{}</p>\
         <p class=\"links\"><a href=\"{status_json}\">status JSON</a>\
         <a href=\"{jobs_json}\">jobs JSON</a>\
         <a href=\"{results_json}\">results JSON</a>\
         <a href=\"{results_csv}\">results CSV</a></p>",
        esc(&r.name),
        badge(r.status.as_str()),
        r.points,
        r.trials,
        short(r.threshold),
        when(r.created_at),
        r.started_at.map(|t| format!(" | started {}", when(t))).unwrap_or_default(),
        r.finished_at.map(|t| format!(" | finished {}", when(t))).unwrap_or_default(),
        status_json = Endpoint::SearchStatus.path_of(&id),
        jobs_json = Endpoint::SearchJobs.path_of(&id),
        results_json = Endpoint::Results.path_of(&id),
        results_csv = Endpoint::ResultsCsv.path_of(&id),
    );
    let refresh = if running {
        format!(
            " data-src=\"/fragments/searches/{id}/live\" data-every=\"{REFRESH_MS}\" data-figures=\"figures\""
        )
    } else {
        String::new()
    };
    let key = r.doc_key();
    let _ = write!(
        s,
        "<h2>Progress</h2><div id=\"live\" class=\"live\"{refresh}>{}</div>\
         <div id=\"figures\" data-src=\"/fragments/searches/{id}/figures\" data-key=\"{}\" \
         data-min-interval=\"{FIGURES_REFRESH_MS}\">{}</div>",
        p.live,
        esc(&key),
        p.figures
    );
    // Job table.
    let filtered_total = match p.jobs_status {
        None => r.jobs.total,
        Some(JobState::Queued) => r.jobs.queued,
        Some(JobState::Leased) => r.jobs.leased,
        Some(JobState::Done) => r.jobs.done,
        Some(JobState::Failed) => r.jobs.failed,
        Some(JobState::Cancelled) => r.jobs.cancelled,
    } as i64;
    s.push_str("<h2 id=\"jobs\">Jobs</h2><p class=\"pager\">Show: ");
    let base = format!("/searches/{}", r.id);
    let _ = write!(
        s,
        "<a href=\"{}#jobs\">all ({})</a>",
        esc(&base),
        r.jobs.total
    );
    for st in JobState::ALL {
        let _ = write!(
            s,
            "<a href=\"{}?jobs_status={1}#jobs\">{1}</a>",
            esc(&base),
            st.as_str()
        );
    }
    s.push_str("</p>");
    if p.jobs.is_empty() {
        s.push_str("<div class=\"empty\">No jobs here.</div>");
    } else {
        s.push_str(
            "<table><thead><tr><th>Job</th><th>Point</th><th class=\"num\">Trial</th><th>Status</th>\
             <th>Worker</th><th class=\"num\">Attempts</th><th class=\"num\">Final success</th>\
             <th>Converged</th><th class=\"num\">Successes</th><th class=\"num\">Time</th><th>Last error</th></tr></thead><tbody>",
        );
        for (j, pt) in p.jobs.iter().zip(p.job_points) {
            let _ = write!(
                s,
                "<tr><td><a href=\"{12}\" title=\"seed {11}\">{0}</a></td><td>{1}</td><td class=\"num\">{2}</td>\
                 <td>{3}</td><td>{4}</td><td class=\"num\">{5}</td><td class=\"num\">{6}</td><td>{7}</td>\
                 <td class=\"num\">{8}</td><td class=\"num\">{9}</td><td>{10}</td></tr>",
                j.id,
                esc(pt),
                j.trial,
                badge(&j.status),
                esc(j.worker.as_deref().unwrap_or("")),
                j.attempts,
                opt(j.final_success_rate),
                match j.converged {
                    Some(true) => "yes",
                    Some(false) => "no",
                    None => "",
                },
                j.successes
                    .map(|(f, w)| format!("{f} / {w}"))
                    .unwrap_or_default(),
                j.duration_secs.map(duration).unwrap_or_default(),
                esc(&j.last_error.clone().unwrap_or_default().chars().take(200).collect::<String>()),
                j.seed,
                Endpoint::JobDetail.path_of(j.id),
            );
        }
        s.push_str("</tbody></table>");
    }
    let pages = (filtered_total + p.jobs_per_page - 1) / p.jobs_per_page;
    let base = match p.jobs_status {
        Some(st) => format!("{base}?jobs_status={}", st.as_str()),
        None => base,
    };
    s.push_str(
        &pager(&base, "jobs_page", p.jobs_page, pages)
            .replace("newer", "previous")
            .replace("older", "next"),
    );
    shell(&r.name, p.logout, true, &s)
}

/// The refresh script: every element with `data-src` and `data-every`
/// reloads its content from `data-src` while the content says
/// `data-running="true"`; a live part with `data-figures` also reloads
/// that element when the job counts change (at most every
/// `data-min-interval` ms while running, at once when it stops).
pub const SCRIPT: &str = r#""use strict";
(function () {
  function get(url) {
    return fetch(url, { credentials: "same-origin", cache: "no-store" }).then(function (r) {
      if (r.status === 401) { window.location.reload(); return null; }
      if (!r.ok) { return null; }
      return r.text();
    }, function () { return null; });
  }
  function figures(el, key, now) {
    var last = parseInt(el.getAttribute("data-loaded-at") || "0", 10);
    var min = parseInt(el.getAttribute("data-min-interval") || "15000", 10);
    if (!now && Date.now() - last < min) { return; }
    el.setAttribute("data-loaded-at", String(Date.now()));
    get(el.getAttribute("data-src")).then(function (html) {
      if (html === null) { return; }
      el.innerHTML = html;
      el.setAttribute("data-key", key);
    });
  }
  function watch(el) {
    var every = parseInt(el.getAttribute("data-every"), 10);
    if (!(every >= 500)) { return; }
    var fig = el.getAttribute("data-figures");
    function tick() {
      get(el.getAttribute("data-src")).then(function (html) {
        var again = true;
        if (html !== null) {
          el.innerHTML = html;
          var m = el.querySelector("[data-running]");
          again = !!m && m.getAttribute("data-running") === "true";
          var key = m ? m.getAttribute("data-key") : "";
          var f = fig ? document.getElementById(fig) : null;
          if (f && key && f.getAttribute("data-key") !== key) { figures(f, key, !again); }
        }
        if (again) { window.setTimeout(tick, html === null ? every * 3 : every); }
      });
    }
    window.setTimeout(tick, every);
  }
  function start() {
    var figs = document.querySelectorAll("[data-min-interval]");
    for (var i = 0; i < figs.length; i++) { figs[i].setAttribute("data-loaded-at", String(Date.now())); }
    var els = document.querySelectorAll(".live[data-src]");
    for (var j = 0; j < els.length; j++) { watch(els[j]); }
  }
  if (document.readyState === "loading") { document.addEventListener("DOMContentLoaded", start); } else { start(); }
})();
"#;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_read_naturally() {
        assert_eq!(duration(0.2), "<1s");
        assert_eq!(duration(42.0), "42s");
        assert_eq!(duration(185.0), "3m 05s");
        assert_eq!(duration(7_260.0), "2h 01m");
        assert_eq!(duration(200_000.0), "2d 7h");
        assert_eq!(duration(f64::NAN), "–");
    }

    #[test]
    fn when_is_utc_text() {
        assert_eq!(when(1_700_000_000_000), "2023-11-14 22:13:20 UTC");
    }

    #[test]
    fn login_page_escapes_next() {
        let r = login_page("/\"><script>", None, StatusCode::OK);
        assert_eq!(r.status(), StatusCode::OK);
        assert!(r.headers().get(header::CONTENT_SECURITY_POLICY).is_some());
    }
}
