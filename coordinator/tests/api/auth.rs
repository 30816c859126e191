use reqwest::StatusCode;
use serde_json::json;

use crate::helpers::*;

async fn status_with(app: &TestApp, method: &str, path: &str, auth: Option<&str>) -> StatusCode {
    let mut r = app
        .client
        .request(method.parse().unwrap(), format!("{}{path}", app.url))
        .json(&json!({}));
    if let Some(a) = auth {
        r = r.header("authorization", a);
    }
    r.send().await.unwrap().status()
}

#[tokio::test]
async fn writes_and_worker_calls_need_the_bearer_token() {
    let app = spawn_with(Opts {
        token: Some("s3cret-token"),
        ..Opts::default()
    })
    .await;
    let id = app.submit(&search_body(&[1.0], 1)).await; // helper sends the token
    for (method, path) in [
        ("POST", "/api/v1/searches".to_string()),
        ("POST", format!("/api/v1/searches/{id}/cancel")),
        ("POST", "/api/v1/leases".to_string()),
        ("POST", "/api/v1/jobs/1/heartbeat".to_string()),
        ("POST", "/api/v1/jobs/1/result".to_string()),
        ("POST", "/api/v1/jobs/1/fail".to_string()),
        ("POST", "/api/v1/jobs/1/release".to_string()),
    ] {
        for auth in [
            None,
            Some("Bearer wrong"),
            Some("Bearer s3cret-tokenX"),
            Some("s3cret-token"),
        ] {
            assert_eq!(
                status_with(&app, method, &path, auth).await,
                StatusCode::UNAUTHORIZED,
                "{method} {path} with {auth:?}"
            );
        }
    }
    let r = app
        .client
        .post(format!("{}/api/v1/leases", app.url))
        .json(&json!({"worker": "w"}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::UNAUTHORIZED);
    assert_eq!(r.headers()["www-authenticate"], "Bearer");
    let body: serde_json::Value = r.json().await.unwrap();
    assert!(body["error"].as_str().unwrap().contains("token"));
    // Reads stay open; the right token works.
    assert_eq!(
        status_with(&app, "GET", &format!("/api/v1/searches/{id}"), None).await,
        StatusCode::OK
    );
    assert_eq!(
        status_with(&app, "GET", "/healthz", None).await,
        StatusCode::OK
    );
    assert!(app.lease("w").await.is_some());
    // Nothing was changed by the refused calls.
    assert_eq!(
        app.status(&id).await.status,
        shared::api::SearchState::Running
    );
}

#[tokio::test]
async fn non_loopback_bind_without_token_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let cfg =
        coordinator::CoordinatorConfig::new("0.0.0.0:0".parse().unwrap(), dir.path().join("c.db"));
    let err = coordinator::start(cfg).await.err().expect("must refuse");
    assert!(err.to_string().contains("--insecure"), "{err}");
}
