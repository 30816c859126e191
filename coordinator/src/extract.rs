//! Request extractors whose rejections answer `{"error": "..."}` (an
//! [`ApiError`] naming the field), shared by the API routes and the
//! dashboard.

use axum::body::{Body, Bytes};
use axum::extract::rejection::JsonRejection;
use axum::extract::{FromRequest, FromRequestParts, Request};
use axum::http::{header, HeaderMap};
use serde::de::DeserializeOwned;

use crate::error::ApiError;

/// JSON body extractor whose rejection is an [`ApiError`] naming the field.
///
/// A body that parses is read with plain `serde_json`; only a refused one
/// is read again through `axum::Json`, whose path-tracking parser names
/// the offending field. (Tracking the path of every number of a 230 KB
/// upload cost about a twentieth of the coordinator's CPU under load,
/// docs/RELIABILITY.md#where-the-cpu-goes.) The answers are `axum::Json`'s
/// in every case: the same content-type rule, body limit and messages.
pub struct ApiJson<T>(pub T);

impl<T: DeserializeOwned, S: Send + Sync> FromRequest<S> for ApiJson<T> {
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &S) -> Result<Self, ApiError> {
        let headers = req.headers().clone();
        let bytes = Bytes::from_request(req, state)
            .await
            .map_err(|e| ApiError::from(JsonRejection::from(e)))?;
        if is_json(&headers) {
            if let Ok(v) = serde_json::from_slice(&bytes) {
                return Ok(Self(v));
            }
        }
        // Refused (or a content type this check does not know): let
        // axum::Json say why, from the bytes already read.
        let mut again = Request::new(Body::from(bytes));
        *again.headers_mut() = headers;
        let axum::Json(v) = axum::Json::<T>::from_request(again, state).await?;
        Ok(Self(v))
    }
}

/// `Content-Type: application/json`, with or without parameters: the
/// common case, checked strictly; anything else goes to `axum::Json`'s own
/// rule.
fn is_json(headers: &HeaderMap) -> bool {
    headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.split(';').next())
        .is_some_and(|essence| essence.trim().eq_ignore_ascii_case("application/json"))
}

/// Path extractor whose rejection is an [`ApiError`].
#[derive(FromRequestParts)]
#[from_request(via(axum::extract::Path), rejection(ApiError))]
pub struct ApiPath<T>(pub T);

#[cfg(test)]
mod tests {
    use axum::http::StatusCode;
    use axum::response::IntoResponse;
    use serde::Deserialize;

    use super::*;

    #[derive(Debug, Deserialize, PartialEq)]
    struct Body2 {
        a: Vec<f64>,
        b: String,
    }

    fn request(content_type: Option<&str>, body: &str) -> Request {
        let mut r = Request::new(Body::from(body.to_string()));
        if let Some(ct) = content_type {
            r.headers_mut()
                .insert(header::CONTENT_TYPE, ct.parse().unwrap());
        }
        r
    }

    /// The status and message `axum::Json` (mapped to `ApiError`) gives.
    async fn axum_answer(content_type: Option<&str>, body: &str) -> (StatusCode, String) {
        let e = axum::Json::<Body2>::from_request(request(content_type, body), &())
            .await
            .map(|_| ())
            .map_err(ApiError::from)
            .unwrap_err();
        answer(e)
    }

    async fn ours(content_type: Option<&str>, body: &str) -> Result<Body2, (StatusCode, String)> {
        ApiJson::<Body2>::from_request(request(content_type, body), &())
            .await
            .map(|ApiJson(v)| v)
            .map_err(answer)
    }

    fn answer(e: ApiError) -> (StatusCode, String) {
        let msg = e.to_string();
        (e.into_response().status(), msg)
    }

    #[tokio::test]
    async fn accepts_what_axum_accepts_and_refuses_with_axums_message() {
        let good = r#"{"a": [1.5, 2], "b": "x"}"#;
        for ct in [
            "application/json",
            "application/json; charset=utf-8",
            "Application/JSON",
        ] {
            assert_eq!(
                ours(Some(ct), good).await.unwrap(),
                Body2 {
                    a: vec![1.5, 2.0],
                    b: "x".into()
                }
            );
        }
        // A +json type is axum's to accept.
        assert!(ours(Some("application/vnd.irl+json"), good).await.is_ok());
        for (ct, body) in [
            (Some("application/json"), r#"{"a": [1.5, "no"], "b": "x"}"#),
            (
                Some("application/json"),
                r#"{"a": [1.5], "b": "x"} trailing"#,
            ),
            (Some("application/json"), r#"{"a": [1.5]}"#),
            (Some("application/json"), "not json"),
            (Some("text/plain"), good),
            (None, good),
        ] {
            let (status, msg) = axum_answer(ct, body).await;
            assert_eq!(ours(ct, body).await.unwrap_err(), (status, msg.clone()));
            assert!(status.is_client_error(), "{status} {msg}");
        }
        // The path of the offending field is named, as before.
        let (_, msg) = ours(Some("application/json"), r#"{"a": [1.5, "no"], "b": "x"}"#)
            .await
            .unwrap_err();
        assert!(msg.contains("a[1]"), "{msg}");
    }
}
