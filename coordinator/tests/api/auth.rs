use reqwest::StatusCode;
use serde_json::json;

use coordinator::auth::{Access, ROUTES};

use crate::helpers::*;

async fn status_with(app: &TestApp, method: &str, path: &str) -> StatusCode {
    let r = app
        .client
        .request(method.parse().unwrap(), format!("{}{path}", app.url));
    r.send().await.unwrap().status()
}

/// Every (method, path) of the OpenAPI document that needs a token: the
/// test enumerates them from the document (which another test pins to the
/// router), so a new guarded route cannot escape it.
fn guarded_routes(doc: &serde_json::Value) -> Vec<(String, String)> {
    let mut out = Vec::new();
    for (path, ops) in doc["paths"].as_object().unwrap() {
        for (method, op) in ops.as_object().unwrap() {
            let method = method.to_uppercase();
            if op["x-irlgrid-role"] == "open" {
                assert!(op.get("security").is_none(), "{method} {path} is open");
                continue;
            }
            assert!(
                path.starts_with(API_PREFIX),
                "{method} {path}: guarded routes live under /api/v1 (the token guard)"
            );
            assert!(
                op["security"].is_array() && op["responses"]["401"].is_object(),
                "{method} {path}: a guarded route must declare bearer security and its 401"
            );
            out.push((method, path.clone()));
        }
    }
    out
}

#[tokio::test]
async fn every_guarded_route_needs_the_bearer_token() {
    let app = spawn_with(Opts {
        token: Some("s3cret-token"),
        ..Opts::default()
    })
    .await;
    let id = app.submit(&search_body(&[1.0], 1)).await; // helper sends the token
    let lease = app.lease("holder").await.unwrap();
    // The document this coordinator serves.
    let (st, doc) = app.get(E::OpenApi.path()).await;
    assert_eq!(st, StatusCode::OK);
    let routes = guarded_routes(&doc);
    // The writes, the five worker calls and the seven reads.
    assert!(routes.len() >= 15, "{routes:?}");
    let before = app.get(&E::SearchJobs.path_of(&id)).await;
    for (method, template) in &routes {
        let path = if template.starts_with(E::SearchStatus.template()) {
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
    assert_eq!(app.get(&E::SearchJobs.path_of(&id)).await, before);
    let (_, list) = app.get(E::ListSearches.path()).await;
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
    // Reads are closed too; health, metrics and the document stay open;
    // the right token works.
    assert_eq!(
        status_with(&app, "GET", &E::Results.path_of(&id)).await,
        StatusCode::UNAUTHORIZED
    );
    for open in ["/healthz", "/metrics", E::OpenApi.path()] {
        assert_eq!(
            status_with(&app, "GET", open).await,
            StatusCode::OK,
            "{open}"
        );
    }
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

/// Who calls: no token, an unknown one, or one of the three roles.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Caller {
    None,
    Wrong,
    Reader,
    Worker,
    Admin,
}

const ADMIN: &str = "admin-secret";
const WORKER: &str = "worker-secret";
const READER: &str = "reader-secret";

impl Caller {
    const ALL: [Caller; 5] = [
        Caller::None,
        Caller::Wrong,
        Caller::Reader,
        Caller::Worker,
        Caller::Admin,
    ];

    fn token(self) -> Option<&'static str> {
        match self {
            Caller::None => None,
            Caller::Wrong => Some("not-a-token"),
            Caller::Reader => Some(READER),
            Caller::Worker => Some(WORKER),
            Caller::Admin => Some(ADMIN),
        }
    }

    /// The auth status expected on a route needing `access`, or `None`
    /// when the call must get past auth (any status but 401 and 403).
    fn refusal(self, access: Access) -> Option<StatusCode> {
        let allowed = match (self, access) {
            (_, Access::Open) | (Caller::Admin, _) => true,
            (Caller::None | Caller::Wrong, _) => return Some(StatusCode::UNAUTHORIZED),
            (Caller::Reader, a) => a == Access::Read,
            (Caller::Worker, a) => a == Access::Worker,
        };
        (!allowed).then_some(StatusCode::FORBIDDEN)
    }
}

/// Every route of the one access table times every caller. The table is
/// the one the middleware enforces and the OpenAPI document states; the
/// router serves exactly its routes (`searches.rs` checks that).
#[tokio::test]
async fn every_route_gives_each_role_its_status() {
    let app = spawn_with(Opts {
        token: Some(ADMIN),
        worker_token: Some(WORKER),
        read_token: Some(READER),
        ..Opts::default()
    })
    .await;
    let id = app.submit(&search_body(&[1.0, 2.0], 1)).await;
    let lease = app.lease("holder").await.unwrap();
    let (_, doc) = app.get(E::OpenApi.path()).await;
    for route in ROUTES {
        let (method, template, access) = (route.method.as_str(), &route.path, &route.access);
        let op = &doc["paths"][*template][method.to_lowercase()];
        assert_eq!(
            op["x-irlgrid-role"],
            access.name(),
            "{method} {template}: the document states another role"
        );
        let path = if template.starts_with(E::SearchStatus.template()) {
            template.replace("{id}", &id)
        } else {
            template.replace("{id}", &lease.job_id.to_string())
        };
        for caller in Caller::ALL {
            let mut r = app
                .client
                .request(method.parse().unwrap(), format!("{}{path}", app.url))
                .json(
                    &json!({"lease_token": "0".repeat(32), "worker": "w", "wait_secs": 0,
                              "error": "x", "reward_grid": {"w1": [3.0]}, "trials": 1}),
                );
            if let Some(t) = caller.token() {
                r = r.bearer_auth(t);
            }
            let resp = r.send().await.unwrap();
            let st = resp.status();
            let body = resp.text().await.unwrap();
            match caller.refusal(*access) {
                Some(want) => assert_eq!(st, want, "{method} {template} as {caller:?}: {body}"),
                None => assert!(
                    st != StatusCode::UNAUTHORIZED
                        && st != StatusCode::FORBIDDEN
                        && !st.is_server_error(),
                    "{method} {template} as {caller:?} must pass auth, got {st}: {body}"
                ),
            }
        }
    }
}

#[tokio::test]
async fn results_need_a_token_and_a_reader_token_reads_them() {
    let app = spawn_with(Opts {
        token: Some(ADMIN),
        read_token: Some(READER),
        ..Opts::default()
    })
    .await;
    let id = app.submit(&search_body(&[1.0], 1)).await;
    let url = format!("{}/api/v1/searches/{id}/results", app.url);
    let r = app.client.get(&url).send().await.unwrap();
    assert_eq!(r.status(), StatusCode::UNAUTHORIZED);
    assert!(!r.text().await.unwrap().contains("subject"));
    let r = app
        .client
        .get(&url)
        .bearer_auth(READER)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    // A dashboard session (the page links to this JSON) reads, but never
    // writes.
    let cookie = format!(
        "{}={}",
        coordinator::dashboard::auth::COOKIE,
        coordinator::dashboard::auth::session_value(READER)
    );
    let r = app
        .client
        .get(&url)
        .header("cookie", &cookie)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    let admin_cookie = format!(
        "{}={}",
        coordinator::dashboard::auth::COOKIE,
        coordinator::dashboard::auth::session_value(ADMIN)
    );
    let r = app
        .client
        .post(format!("{}/api/v1/searches/{id}/cancel", app.url))
        .header("cookie", &admin_cookie)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::UNAUTHORIZED);
    // Only the admin token configured: it reads as before it wrote.
    let only_admin = spawn_with(Opts {
        token: Some(ADMIN),
        ..Opts::default()
    })
    .await;
    let id = only_admin.submit(&search_body(&[1.0], 1)).await;
    only_admin.results(&id).await;
}

#[tokio::test]
async fn public_reads_open_reads_and_pages_but_not_writes() {
    let app = spawn_with(Opts {
        token: Some(ADMIN),
        worker_token: Some(WORKER),
        public_reads: true,
        ..Opts::default()
    })
    .await;
    let id = app.submit(&search_body(&[1.0], 1)).await;
    for path in [
        E::Results.path_of(&id),
        E::ListSearches.path().to_string(),
        format!("/searches/{id}"),
        "/".to_string(),
    ] {
        assert_eq!(
            status_with(&app, "GET", &path).await,
            StatusCode::OK,
            "{path}"
        );
    }
    let r = app
        .client
        .post(format!("{}/api/v1/searches/{id}/cancel", app.url))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::UNAUTHORIZED);
    let r = app
        .client
        .post(format!("{}/api/v1/searches/{id}/cancel", app.url))
        .bearer_auth(WORKER)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::FORBIDDEN);
    let (_, doc) = app.get(E::OpenApi.path()).await;
    assert_eq!(
        doc["paths"][E::Results.template()]["get"]["security"],
        json!([])
    );
}
