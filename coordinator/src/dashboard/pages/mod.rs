//! HTML of the dashboard, as [`maud`] templates: the page shell (inline
//! CSS, strict CSP), the login and error pages and the pieces every page
//! shares (badges, progress bars, pagers, figures). The pages themselves are
//! in the submodules: [`searches`] (the list at `/`), [`search`] (one
//! search's page and its live part) and [`figures`] (its results).
//!
//! maud escapes every spliced value (`(expr)`), in text and in attributes,
//! so user text (search and subject names, workers, notes, error text) can
//! only ever be text. The one way around it is [`PreEscaped`], used for our
//! own assets and for the SVG of the [`chart`](super::chart) module only,
//! each with a comment saying why.

mod figures;
mod search;
mod searches;

use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use maud::{html, Markup, PreEscaped, DOCTYPE};
use shared::api::routes::Endpoint;
use shared::api::{JobCounts, SearchState};

use super::chart::{short, ChartId};
use crate::store::queue::SearchRow;
use crate::store::rfc3339;

pub use figures::figures;
pub use search::{live, search_page, SearchPage};
pub use searches::{index_page, search_table};

/// Content-Security-Policy of every page: nothing from elsewhere, scripts
/// only from `/dashboard.js`.
pub const CSP: &str = "default-src 'none'; style-src 'unsafe-inline'; script-src 'self'; \
                       connect-src 'self'; img-src 'self' data:; form-action 'self'; \
                       frame-ancestors 'none'; base-uri 'none'";

/// Milliseconds between refreshes of a running search's live part.
pub const REFRESH_MS: u64 = 3000;
/// Least milliseconds between refreshes of a running search's figures.
pub const FIGURES_REFRESH_MS: u64 = 15_000;

/// The style sheet, inlined into every page's `<style>` (the CSP allows
/// inline styles and no style sheet URL).
const STYLE: &str = include_str!("../assets/dashboard.css");

/// The refresh script, served at `/dashboard.js` (the CSP allows scripts
/// from `'self'` only, none inline); what it does is said at its top.
pub const SCRIPT: &str = include_str!("../assets/dashboard.js");

// ---------------------------------------------------------------- answers

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
pub fn html(status: StatusCode, body: Markup) -> Response {
    let mut resp = (
        status,
        [(header::CONTENT_TYPE, "text/html; charset=utf-8")],
        body.into_string(),
    )
        .into_response();
    secure(&mut resp);
    resp
}

/// An HTML fragment answer (for the refresh script).
pub fn fragment(body: Markup) -> Response {
    html(StatusCode::OK, body)
}

/// The page around `content`: head with the style sheet (and the refresh
/// script when `script`), the top bar (with a logout button when
/// `logout`).
fn shell(title: &str, logout: bool, script: bool, content: Markup) -> Markup {
    html! {
        (DOCTYPE)
        html lang="en" {
            head {
                meta charset="utf-8";
                meta name="viewport" content="width=device-width, initial-scale=1";
                title { (title) " - irlgrid" }
                // Our own style sheet, compiled in: escaping it would break
                // its quotes (a <style> element holds raw text).
                style { (PreEscaped(STYLE)) }
                @if script {
                    script src="/dashboard.js" defer {}
                }
            }
            body {
                header.top {
                    a href="/" { "irlgrid dashboard" }
                    a href="/" { "All searches" }
                    a href=(Endpoint::OpenApi.path()) { "API" }
                    span.sp {}
                    @if logout {
                        form method="post" action="/logout" {
                            button type="submit" { "Log out" }
                        }
                    }
                }
                main { (content) }
            }
        }
    }
}

/// The login form (also shown, 401, after a wrong token).
pub fn login_page(next: &str, error: Option<&str>, status: StatusCode) -> Response {
    let body = html! {
        form.login.card method="post" action="/login" {
            h1 { "Log in" }
            p.muted {
                "This coordinator requires its token (" code { "IRLGRID_TOKEN" }
                ") to view the dashboard."
            }
            @if let Some(e) = error {
                p.err { (e) }
            }
            label for="token" { "Token" }
            input #token name="token" type="password" autocomplete="current-password"
                required autofocus;
            input type="hidden" name="next" value=(next);
            button type="submit" { "Log in" }
        }
    };
    html(status, shell("Log in", false, false, body))
}

/// An error page.
pub fn error_page(status: StatusCode, msg: &str) -> Response {
    let body = html! {
        h1 { (status.as_u16()) " " (status.canonical_reason().unwrap_or("")) }
        p { (msg) }
        p { a href="/" { "All searches" } }
    };
    html(status, shell("Error", false, false, body))
}

// ---------------------------------------------------------------- text

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

/// A number of a table ([`short`]), `–` when there is none.
fn opt(v: Option<f64>) -> String {
    v.map(short).unwrap_or_else(|| "–".into())
}

/// Time the search has run (to now while it runs).
fn elapsed(r: &SearchRow, now: i64) -> String {
    match r.started_at {
        None => "not started".into(),
        Some(s) => duration((r.finished_at.unwrap_or(now) - s) as f64 / 1000.0),
    }
}

/// Time left of a running search.
fn eta(r: &SearchRow) -> String {
    match (r.status, r.eta_secs()) {
        (SearchState::Running, Some(s)) => duration(s),
        (SearchState::Running, None) => "after the first job".into(),
        _ => "–".into(),
    }
}

// ---------------------------------------------------------------- pieces

/// A state (of a search or a job) as a coloured badge.
fn badge(state: &str) -> Markup {
    html! { span class={ "badge b-" (state) } { (state) } }
}

/// A stacked progress bar of finished / running jobs.
fn progress_bar(j: &JobCounts) -> Markup {
    let total = j.total.max(1) as f64;
    let pct = |n: u64| 100.0 * n as f64 / total;
    let width = |n: u64| format!("width:{:.2}%", pct(n));
    let finished = j.done + j.failed;
    let title = format!(
        "{} done, {} failed, {} running, {} queued, {} cancelled",
        j.done, j.failed, j.leased, j.queued, j.cancelled
    );
    html! {
        div.bar title=(title) {
            span.s-done style=(width(j.done)) {}
            span.s-failed style=(width(j.failed)) {}
            span.s-leased style=(width(j.leased)) {}
            span.s-cancelled style=(width(j.cancelled)) {}
        }
        span.muted { (finished) " / " (j.total) " jobs (" (format!("{:.0}", pct(finished))) "%)" }
    }
}

/// Links to the page before and after `page` of `pages`: `base` with
/// `param=N` added; `back` and `forward` name the two directions.
fn pager(base: &str, param: &str, page: i64, pages: i64, back: &str, forward: &str) -> Markup {
    let sep = if base.contains('?') { '&' } else { '?' };
    html! {
        @if pages > 1 {
            p.pager {
                @if page > 1 {
                    a href={ (base) (sep) (param) "=" (page - 1) } { "← " (back) }
                }
                span { "page " (page) " of " (pages) }
                @if page < pages {
                    a href={ (base) (sep) (param) "=" (page + 1) } { (forward) " →" }
                }
            }
        }
    }
}

/// A chart with its caption and download link.
fn figure(id: &str, chart: ChartId, svg: &str, caption: &str) -> Markup {
    let name = chart.file_name();
    let stem = name.trim_end_matches(".svg");
    html! {
        figure data-chart=(stem) {
            // The chart module's own SVG: it escapes every piece of text it
            // draws (axis labels and legends hold user text) in its writer.
            (PreEscaped(svg))
            figcaption {
                (caption) " "
                a href={ "/searches/" (id) "/charts/" (name) } download=(name) { "Download SVG" }
            }
        }
    }
}

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

    fn body_of(r: Response) -> String {
        let bytes =
            futures_util::FutureExt::now_or_never(axum::body::to_bytes(r.into_body(), usize::MAX))
                .expect("a ready body")
                .expect("a body");
        String::from_utf8(bytes.to_vec()).expect("UTF-8")
    }

    #[test]
    fn login_page_escapes_next() {
        let r = login_page("/\"><script>", Some("<b>wrong</b>"), StatusCode::OK);
        assert_eq!(r.status(), StatusCode::OK);
        assert!(r.headers().get(header::CONTENT_SECURITY_POLICY).is_some());
        let b = body_of(r);
        assert!(b.contains("value=\"/&quot;&gt;&lt;script&gt;\""), "{b}");
        assert!(b.contains("&lt;b&gt;wrong&lt;/b&gt;"), "{b}");
        assert!(!b.contains("<script>"), "{b}");
    }

    #[test]
    fn error_page_escapes_the_message() {
        let b = body_of(error_page(StatusCode::NOT_FOUND, "no search <x> & \"y\""));
        assert!(b.contains("<h1>404 Not Found</h1>"), "{b}");
        assert!(b.contains("no search &lt;x&gt; &amp; &quot;y&quot;"), "{b}");
    }

    #[test]
    fn the_style_sheet_is_inlined_verbatim() {
        let b = body_of(error_page(StatusCode::NOT_FOUND, "x"));
        assert!(b.contains(r#"font:14px/1.45 -apple-system,"Segoe UI""#));
        assert!(b.starts_with("<!DOCTYPE html><html lang=\"en\">"), "{b}");
    }

    #[test]
    fn pagers_link_both_ways() {
        let p = pager("/s?x=1", "page", 2, 3, "newer", "older").into_string();
        assert!(p.contains("href=\"/s?x=1&amp;page=1\""), "{p}");
        assert!(p.contains("page 2 of 3"));
        assert!(p.contains("href=\"/s?x=1&amp;page=3\""), "{p}");
        assert!(pager("/", "page", 1, 1, "a", "b").into_string().is_empty());
    }
}
