use reqwest::StatusCode;
use serde_json::{json, Value};

use crate::helpers::*;

async fn submit_err(app: &TestApp, body: Value) -> String {
    let (st, v) = app.post(E::Submit.path(), &body).await;
    assert_eq!(st, StatusCode::BAD_REQUEST, "{body} -> {v}");
    v["error"].as_str().unwrap().to_string()
}

fn with(mut body: Value, key: &str, value: Value) -> Value {
    body[key] = value;
    body
}

#[tokio::test]
async fn invalid_searches_are_400_naming_the_field() {
    let app = spawn_app().await;
    let ok = search_body(&[1.0], 1);
    let cases: Vec<(Value, &str)> = vec![
        (with(ok.clone(), "trials", json!(0)), "trials"),
        (with(ok.clone(), "trials", json!(1000)), "trials"),
        (with(ok.clone(), "trials", json!(-1)), "trials"),
        (with(ok.clone(), "trials", json!("two")), "trials"),
        (with(ok.clone(), "seed", json!(-5)), "seed"),
        (with(ok.clone(), "reward_grid", json!({})), "reward_grid"),
        (
            with(ok.clone(), "reward_grid", json!({"w1": []})),
            "reward_grid.w1",
        ),
        (
            with(ok.clone(), "reward_grid", json!({"w1": [-1.0]})),
            "reward_grid.w1[0]",
        ),
        (
            with(ok.clone(), "reward_grid", json!({"w1": ["a"]})),
            "reward_grid",
        ),
        (
            with(ok.clone(), "reward_grid", json!({"zeta": [1.0]})),
            "reward_grid.zeta",
        ),
        (
            with(
                ok.clone(),
                "reward_grid",
                json!({"w1": (0..100).map(f64::from).collect::<Vec<_>>()}),
            ),
            "reward_grid.w1",
        ),
        (
            with(ok.clone(), "training", json!({"env_steps": 0})),
            "training",
        ),
        (
            with(
                ok.clone(),
                "training",
                json!({"env_steps": 1_000_000_000u64}),
            ),
            "training.env_steps",
        ),
        (
            with(ok.clone(), "training", json!({"learning_rate": -1.0})),
            "learning_rate",
        ),
        (with(ok.clone(), "training", json!({"typo": 1})), "typo"),
        (with(ok.clone(), "training", json!([1, 2])), "training"),
        (
            with(ok.clone(), "sampling", json!({"top_k": 0})),
            "sampling",
        ),
        (
            with(
                ok.clone(),
                "sampling",
                json!({"successful_episodes": 1_000_000}),
            ),
            "sampling",
        ),
        (with(ok.clone(), "env", json!({"max_steps": 0})), "env"),
        (
            with(
                ok.clone(),
                "subjects_csv",
                json!("subject,time,x,z\na,0,0,zero\n"),
            ),
            "subjects_csv",
        ),
        (
            with(ok.clone(), "subjects_csv", json!("nonsense")),
            "subjects_csv",
        ),
        (
            with(ok.clone(), "convergence_threshold", json!(2.0)),
            "convergence_threshold",
        ),
        (with(ok.clone(), "max_attempts", json!(0)), "max_attempts"),
        (
            with(ok.clone(), "max_trials_per_point", json!(0)),
            "max_trials_per_point",
        ),
        (with(ok.clone(), "name", json!("x".repeat(500))), "name"),
        (with(ok.clone(), "unknown_field", json!(1)), "unknown_field"),
        (json!({"trials": 1}), "reward_grid"),
    ];
    for (body, needle) in cases {
        let e = submit_err(&app, body.clone()).await;
        assert!(
            e.contains(needle),
            "error for {body} should name {needle}: {e}"
        );
    }
    // Malformed JSON and NaN literals.
    for raw in [
        "{",
        "{\"reward_grid\": {\"w1\": [NaN]}, \"trials\": 1}",
        "[]",
        "",
    ] {
        let r = app
            .client
            .post(format!("{}/api/v1/searches", app.url))
            .header("content-type", "application/json")
            .body(raw)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), StatusCode::BAD_REQUEST, "{raw}");
        let v: Value = r.json().await.unwrap();
        assert!(v["error"].is_string());
    }
    let r = app
        .client
        .post(format!("{}/api/v1/searches", app.url))
        .body("{}")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::BAD_REQUEST, "missing content type");
    // Nothing was created.
    let (_, list) = app.get(E::ListSearches.path()).await;
    assert_eq!(list, json!([]));
}

#[tokio::test]
async fn oversized_bodies_are_413() {
    let app = spawn_with(Opts {
        body_limit: Some(64 * 1024),
        ..Opts::default()
    })
    .await;
    let body = with(
        search_body(&[1.0], 1),
        "subjects_csv",
        json!("x".repeat(100 * 1024)),
    );
    let (st, v) = app.post(E::Submit.path(), &body).await;
    assert_eq!(st, StatusCode::PAYLOAD_TOO_LARGE, "{v}");
    assert!(v["error"].is_string());
}

#[tokio::test]
async fn unknown_ids_and_routes_are_404_and_bad_ids_400() {
    let app = spawn_app().await;
    for path in [
        E::SearchStatus.path_of("nope"),
        E::Results.path_of("nope"),
        E::ResultsCsv.path_of("nope"),
        E::SearchJobs.path_of("nope"),
        E::Outputs.path_of("nope"),
        E::JobDetail.path_of(12345),
        format!("{API_PREFIX}/nothing"),
    ] {
        let (st, v) = app.get(&path).await;
        assert_eq!(st, StatusCode::NOT_FOUND, "{path}: {v}");
        assert!(v["error"].is_string(), "{path}: {v}");
    }
    let (st, v) = app.get(&E::JobDetail.path_of("abc")).await;
    assert_eq!(st, StatusCode::BAD_REQUEST, "{v}");
    let (st, v) = app
        .post(&E::Heartbeat.path_of("abc"), &json!({"lease_token": "x"}))
        .await;
    assert_eq!(st, StatusCode::BAD_REQUEST, "{v}");
    let r = app
        .client
        .delete(format!("{}{}", app.url, E::ListSearches.path()))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::METHOD_NOT_ALLOWED);
}

#[tokio::test]
async fn malformed_uploads_are_400_and_change_nothing() {
    let app = spawn_app().await;
    let id = app.submit(&search_body(&[1.0], 1)).await;
    let l = app.lease("w").await.unwrap();
    let good = output(0.9, 3, 0.1);
    let mut cases: Vec<(Value, &str)> = Vec::new();
    let enc = |o: &shared::api::JobOutput| serde_json::to_value(o).unwrap();
    let mut o = good.clone();
    o.episodes[0].com_x.pop();
    cases.push((enc(&o), "com_x"));
    let mut o = good.clone();
    o.final_success_rate = 1.5;
    cases.push((enc(&o), "final_success_rate"));
    let mut o = good.clone();
    o.successes_found = 5;
    cases.push((enc(&o), "successes_found"));
    let mut o = good.clone();
    o.successes_wanted = 7;
    cases.push((enc(&o), "successes_wanted"));
    let mut o = good.clone();
    o.episodes.push(episode(0.1));
    cases.push((enc(&o), "episodes"));
    let mut o = good.clone();
    o.episodes[0].torque_usage = -1.0;
    cases.push((enc(&o), "torque_usage"));
    let mut o = good.clone();
    o.episodes[1].com_t.reverse();
    cases.push((enc(&o), "backwards"));
    let mut o = good.clone();
    o.episodes[0].com_t.truncate(1);
    o.episodes[0].com_x.truncate(1);
    o.episodes[0].com_z.truncate(1);
    cases.push((enc(&o), "com_t"));
    let mut v = enc(&good);
    v["episodes"][0]["com_z"][3] = json!("NaN");
    cases.push((v, "com_z"));
    let mut v = enc(&good);
    v["extra"] = json!(1);
    cases.push((v, "extra"));
    for (out, needle) in cases {
        let (st, v) = app
            .post(
                &E::Result.path_of(l.job_id),
                &json!({"lease_token": l.lease_token, "output": out}),
            )
            .await;
        assert_eq!(st, StatusCode::BAD_REQUEST, "{needle}: {v}");
        assert!(
            v["error"].as_str().unwrap().contains(needle),
            "{needle}: {v}"
        );
    }
    // Non-finite numbers cannot even be written in JSON.
    let raw = format!(
        "{{\"lease_token\":\"{}\",\"output\":{{\"final_success_rate\":1e999}}}}",
        l.lease_token
    );
    let r = app
        .client
        .post(format!("{}/api/v1/jobs/{}/result", app.url, l.job_id))
        .header("content-type", "application/json")
        .body(raw)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::BAD_REQUEST);
    // Bad heartbeats.
    for (p, needle) in [
        (
            json!([{"env_steps": 1, "total_env_steps": 10, "success_rate": 3.0}]),
            "success_rate",
        ),
        (
            json!([{"env_steps": "x", "total_env_steps": 10}]),
            "env_steps",
        ),
    ] {
        let (st, v) = app.heartbeat(l.job_id, &l.lease_token, p).await;
        assert_eq!(st, StatusCode::BAD_REQUEST, "{v}");
        assert!(v["error"].as_str().unwrap().contains(needle), "{v}");
    }
    let (st, _) = app.heartbeat(l.job_id, "", json!([])).await;
    assert_eq!(st, StatusCode::BAD_REQUEST);
    let (st, v) = app.post(E::Lease.path(), &json!({"worker": ""})).await;
    assert_eq!(st, StatusCode::BAD_REQUEST, "{v}");
    let (st, v) = app
        .post(E::Lease.path(), &json!({"worker": "w", "wait_secs": 99}))
        .await;
    assert_eq!(st, StatusCode::BAD_REQUEST, "{v}");
    // The job is untouched and still accepts the good upload.
    let s = app.status(&id).await;
    assert_eq!((s.jobs.leased, s.jobs.done), (1, 0));
    let (st, v) = app.upload(l.job_id, &l.lease_token, &good).await;
    assert_eq!(st, StatusCode::OK, "{v}");
}
