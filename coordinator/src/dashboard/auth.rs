//! Who may read the dashboard. With a token configured the pages require
//! the admin or the reader token (see [`crate::auth`]): a login form checks
//! it (constant time) and sets an
//! HttpOnly, SameSite=Strict session cookie; a `?token=` in a page URL does
//! the same and is stripped at once by a redirect. The cookie holds
//! HMAC-SHA256(token, fixed label), not the token, so it survives restarts
//! and dies when the token changes. Without a token, or with public reads,
//! every page is open.

use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::Form;
use hmac::{Hmac, Mac};
use serde::Deserialize;
use sha2::Sha256;

use super::pages;
use super::DashState;
use crate::auth::{ct_eq, Tokens};

/// Name of the session cookie.
pub const COOKIE: &str = "irlgrid_dashboard";
/// Session lifetime (the cookie's Max-Age): 30 days.
pub const COOKIE_MAX_AGE_SECS: u64 = 30 * 86_400;
/// Pause after a wrong token, to slow down guessing.
const WRONG_TOKEN_DELAY_MS: u64 = 300;

/// The HTTP trace layer's span: method and path, never the query string
/// (a dashboard link may carry `?token=`), unlike tower-http's default
/// span, which records the whole URI.
pub fn request_span<B>(req: &axum::http::Request<B>) -> tracing::Span {
    tracing::debug_span!(
        "request",
        method = %req.method(),
        path = %req.uri().path(),
        version = ?req.version()
    )
}

/// The cookie value proving knowledge of `token`.
pub fn session_value(token: &str) -> String {
    // HMAC accepts keys of any length.
    let mut mac = Hmac::<Sha256>::new_from_slice(token.as_bytes())
        .unwrap_or_else(|_| unreachable!("HMAC takes any key length"));
    mac.update(b"irlgrid dashboard session v1");
    mac.finalize()
        .into_bytes()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Whether the request carries a valid session cookie for `token`.
pub fn has_session(headers: &HeaderMap, token: &str) -> bool {
    let want = session_value(token);
    headers
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .filter_map(|kv| kv.trim().split_once('='))
        .any(|(k, v)| k == COOKIE && ct_eq(v, &want))
}

fn set_cookie(token: &str) -> HeaderValue {
    let v = format!(
        "{COOKIE}={}; Path=/; HttpOnly; SameSite=Strict; Max-Age={COOKIE_MAX_AGE_SECS}",
        session_value(token)
    );
    HeaderValue::from_str(&v).unwrap_or_else(|_| HeaderValue::from_static(""))
}

fn clear_cookie() -> HeaderValue {
    HeaderValue::from_static("irlgrid_dashboard=; Path=/; HttpOnly; SameSite=Strict; Max-Age=0")
}

/// Decodes `%XX` escapes and `+` of a form-urlencoded component (invalid
/// escapes are kept as they are).
pub fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        match b[i] {
            b'+' => out.push(b' '),
            b'%' if i + 2 < b.len() => {
                let hex = std::str::from_utf8(&b[i + 1..i + 3]).ok();
                match hex.and_then(|h| u8::from_str_radix(h, 16).ok()) {
                    Some(v) => {
                        out.push(v);
                        i += 2;
                    }
                    None => out.push(b'%'),
                }
            }
            c => out.push(c),
        }
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Percent-encodes a path-and-query for use as a `next=` parameter.
pub fn percent_encode(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for b in s.bytes() {
        if b.is_ascii_alphanumeric() || b"-._~/".contains(&b) {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// Splits a query into the `token` value (if any) and the rest, kept
/// byte-for-byte.
pub fn split_token(query: Option<&str>) -> (Option<String>, String) {
    let mut token = None;
    let mut rest = Vec::new();
    for pair in query.unwrap_or("").split('&').filter(|p| !p.is_empty()) {
        let (k, v) = pair.split_once('=').unwrap_or((pair, ""));
        if percent_decode(k) == "token" {
            token = Some(percent_decode(v));
        } else {
            rest.push(pair);
        }
    }
    (token, rest.join("&"))
}

/// A safe local redirect target: a path on this site, else `/`.
pub fn safe_next(next: Option<&str>) -> String {
    match next {
        Some(n)
            if n.starts_with('/')
                && !n.starts_with("//")
                && !n.starts_with("/\\")
                && !n.chars().any(|c| c.is_control() || c == '\\')
                && n.len() <= 2000 =>
        {
            n.to_string()
        }
        _ => "/".to_string(),
    }
}

fn see_other(to: &str) -> Response {
    let loc = HeaderValue::from_str(to).unwrap_or_else(|_| HeaderValue::from_static("/"));
    (StatusCode::SEE_OTHER, [(header::LOCATION, loc)]).into_response()
}

/// The tokens that open the pages (admin, reader), or `None` when no
/// login is needed.
fn needs_login(st: &DashState) -> Option<Vec<&str>> {
    let tokens = Tokens::of(&st.app.cfg);
    if tokens.reads_open() {
        return None;
    }
    Some(tokens.dashboard_tokens())
}

/// The accepted token equal to `given`, if any (every one compared).
fn matching<'a>(accepted: &[&'a str], given: &str) -> Option<&'a str> {
    accepted
        .iter()
        .fold(None, |found, t| match (found, ct_eq(given, t)) {
            (None, true) => Some(*t),
            _ => found,
        })
}

/// Middleware on every protected dashboard route.
pub async fn require(State(st): State<DashState>, req: Request, next: Next) -> Response {
    let Some(accepted) = needs_login(&st) else {
        return next.run(req).await;
    };
    let (given, rest) = split_token(req.uri().query());
    let path = req.uri().path().to_string();
    if let Some(given) = given {
        // The token travels in the URL only this once: answer with the
        // cookie and the same address without it.
        if let Some(token) = matching(&accepted, &given) {
            let to = if rest.is_empty() {
                path
            } else {
                format!("{path}?{rest}")
            };
            let mut resp = see_other(&safe_next(Some(&to)));
            resp.headers_mut()
                .insert(header::SET_COOKIE, set_cookie(token));
            resp.headers_mut().insert(
                header::REFERRER_POLICY,
                HeaderValue::from_static("no-referrer"),
            );
            return resp;
        }
        tokio::time::sleep(std::time::Duration::from_millis(WRONG_TOKEN_DELAY_MS)).await;
        let to = if rest.is_empty() {
            path
        } else {
            format!("{path}?{rest}")
        };
        return pages::login_page(
            &to,
            Some("That token is not correct."),
            StatusCode::UNAUTHORIZED,
        );
    }
    if accepted.iter().any(|t| has_session(req.headers(), t)) {
        return next.run(req).await;
    }
    // Pages send the browser to the form; charts and the script's
    // fragments just say 401 (the script then reloads the page).
    let is_page =
        req.method() == Method::GET && !path.ends_with(".svg") && !path.starts_with("/fragments/");
    if is_page {
        let to = if rest.is_empty() {
            path
        } else {
            format!("{path}?{rest}")
        };
        return see_other(&format!("/login?next={}", percent_encode(&to)));
    }
    (
        StatusCode::UNAUTHORIZED,
        [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
        "log in to the dashboard first (/login)\n",
    )
        .into_response()
}

/// `GET /login` query.
#[derive(Debug, Deserialize)]
pub struct NextQuery {
    next: Option<String>,
}

/// `GET /login`: the form (or straight on when no login is needed).
pub async fn login_form(
    State(st): State<DashState>,
    q: Result<Query<NextQuery>, QueryRejection>,
) -> Response {
    let next = safe_next(q.as_ref().ok().and_then(|q| q.next.as_deref()));
    match needs_login(&st) {
        None => see_other(&next),
        Some(_) => pages::login_page(&next, None, StatusCode::OK),
    }
}

/// `POST /login` form body.
#[derive(Debug, Deserialize)]
pub struct LoginForm {
    token: String,
    #[serde(default)]
    next: Option<String>,
}

/// `POST /login`: checks the token, sets the cookie, goes to `next`.
pub async fn login(State(st): State<DashState>, Form(f): Form<LoginForm>) -> Response {
    let next = safe_next(f.next.as_deref());
    let Some(accepted) = needs_login(&st) else {
        return see_other(&next);
    };
    if let Some(token) = matching(&accepted, f.token.trim()) {
        let mut resp = see_other(&next);
        resp.headers_mut()
            .insert(header::SET_COOKIE, set_cookie(token));
        return resp;
    }
    tokio::time::sleep(std::time::Duration::from_millis(WRONG_TOKEN_DELAY_MS)).await;
    pages::login_page(
        &next,
        Some("That token is not correct."),
        StatusCode::UNAUTHORIZED,
    )
}

/// `POST /logout`: forgets the cookie.
pub async fn logout() -> Response {
    let mut resp = see_other("/login");
    resp.headers_mut()
        .insert(header::SET_COOKIE, clear_cookie());
    resp
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn session_value_depends_on_the_token_and_hides_it() {
        let a = session_value("s3cret");
        assert_eq!(a.len(), 64);
        assert!(!a.contains("s3cret"));
        assert_ne!(a, session_value("s3cret2"));
        assert_eq!(a, session_value("s3cret"));
    }

    #[test]
    fn cookie_is_found_among_others() {
        let mut h = HeaderMap::new();
        h.insert(
            header::COOKIE,
            HeaderValue::from_str(&format!("a=1; {COOKIE}={}; b=2", session_value("t"))).unwrap(),
        );
        assert!(has_session(&h, "t"));
        assert!(!has_session(&h, "u"));
        assert!(!has_session(&HeaderMap::new(), "t"));
    }

    #[test]
    fn token_is_split_from_the_query_keeping_the_rest() {
        assert_eq!(
            split_token(Some("token=a%2Bb+c&page=2")),
            (Some("a+b c".into()), "page=2".into())
        );
        assert_eq!(
            split_token(Some("page=2&jobs=x")),
            (None, "page=2&jobs=x".into())
        );
        assert_eq!(
            split_token(Some("tok%65n=z")),
            (Some("z".into()), String::new())
        );
        assert_eq!(split_token(None), (None, String::new()));
        assert_eq!(percent_decode("%zz%4"), "%zz%4");
    }

    #[test]
    fn next_must_stay_on_this_site() {
        assert_eq!(safe_next(Some("/searches/x?page=2")), "/searches/x?page=2");
        assert_eq!(safe_next(Some("//evil.example")), "/");
        assert_eq!(safe_next(Some("/\\evil.example")), "/");
        assert_eq!(safe_next(Some("https://evil.example")), "/");
        assert_eq!(safe_next(Some("/a\r\nSet-Cookie: x")), "/");
        assert_eq!(safe_next(None), "/");
    }
}
