use reqwest::StatusCode;
use serde_json::json;

use crate::helpers::*;

async fn status_with(app: &TestApp, method: &str, path: &str) -> StatusCode {
    let r = app
        .client
        .request(method.parse().unwrap(), format!("{}{path}", app.url));
    r.send().await.unwrap().status()
}

/// Every (method, path) of the OpenAPI document that is not a read: the
/// test enumerates them from the document (which another test pins to the
/// router), so a new write or worker route cannot escape it.
fn write_routes(doc: &serde_json::Value) -> Vec<(String, String)> {
    let mut out = Vec::new();
    for (path, ops) in doc["paths"].as_object().unwrap() {
        for (method, op) in ops.as_object().unwrap() {
            let method = method.to_uppercase();
            if method == "GET" || method == "HEAD" {
                assert!(op.get("security").is_none(), "{method} {path} is a read");
                continue;
            }
            assert!(
                path.starts_with("/api/v1/"),
                "{method} {path}: writes live under /api/v1 (the token guard)"
            );
            assert!(
                op["security"].is_array() && op["responses"]["401"].is_object(),
                "{method} {path}: a write must declare bearer security and its 401"
            );
            out.push((method, path.clone()));
        }
    }
    out
}

#[tokio::test]
async fn writes_and_worker_calls_need_the_bearer_token() {
    let app = spawn_with(Opts {
        token: Some("s3cret-token"),
        ..Opts::default()
    })
    .await;
    let id = app.submit(&search_body(&[1.0], 1)).await; // helper sends the token
    let lease = app.lease("holder").await.unwrap();
    // The document this coordinator serves.
    let (st, doc) = app.get("/api/v1/openapi.json").await;
    assert_eq!(st, StatusCode::OK);
    let routes = write_routes(&doc);
    // searches, cancel, leases, heartbeat, result, fail, release at least.
    assert!(routes.len() >= 7, "{routes:?}");
    let before = app.get(&format!("/api/v1/searches/{id}/jobs")).await;
    for (method, template) in &routes {
        let path = if template.starts_with("/api/v1/searches/") {
            template.replace("{id}", &id)
        } else {
            template.replace("{id}", &lease.job_id.to_string())
        };
        assert!(!path.contains('{'), "{path}: unknown path parameter");
        for auth in [
            None,
            Some("Bearer wrong"),
            Some("Bearer s3cret-tokenX"),
            Some("Bearer s3cret-toke"),
            Some("Bearer "),
            Some("Basic s3cret-token"),
            Some("s3cret-token"),
        ] {
            let mut r = app
                .client
                .request(method.parse().unwrap(), format!("{}{path}", app.url))
                // A body that would be valid with the token.
                .json(&json!({"lease_token": lease.lease_token, "worker": "w",
                              "error": "x", "reward_grid": {"w1": [2.0]}, "trials": 1}));
            if let Some(a) = auth {
                r = r.header("authorization", a);
            }
            let st = r.send().await.unwrap().status();
            assert_eq!(
                st,
                StatusCode::UNAUTHORIZED,
                "{method} {path} with {auth:?}"
            );
        }
    }
    // Nothing was changed by the refused calls.
    assert_eq!(
        app.get(&format!("/api/v1/searches/{id}/jobs")).await,
        before
    );
    let (_, list) = app.get("/api/v1/searches").await;
    assert_eq!(list.as_array().unwrap().len(), 1);
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
        status_with(&app, "GET", &format!("/api/v1/searches/{id}")).await,
        StatusCode::OK
    );
    assert_eq!(status_with(&app, "GET", "/healthz").await, StatusCode::OK);
    let (st, v) = app
        .heartbeat(lease.job_id, &lease.lease_token, json!([]))
        .await;
    assert_eq!(st, StatusCode::OK, "{v}");
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
