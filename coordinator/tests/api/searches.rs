use std::collections::HashSet;

use reqwest::StatusCode;
use serde_json::json;
use shared::analysis::{build_report, ReportOptions, WeightInput};

use crate::helpers::*;

#[tokio::test]
async fn completed_search_serves_final_results_consistent_with_build_report() {
    let app = spawn_app().await;
    let id = app.submit(&search_body(&[0.5, 4.0], 2)).await;
    let mut ids = Vec::new();
    let mut k = 0.0;
    while let Some(l) = app.lease("w").await {
        assert_eq!(l.spec.search_id, id);
        assert_eq!(l.spec.training.env_steps, 1000);
        k += 0.01;
        let (st, v) = app
            .upload(l.job_id, &l.lease_token, &output(0.9, 3, 0.05 + k))
            .await;
        assert_eq!(st, StatusCode::OK, "{v}");
        ids.push(l.job_id);
    }
    assert_eq!(ids.len(), 4);
    assert_eq!(ids.iter().collect::<HashSet<_>>().len(), 4);
    let doc = app.wait_final(&id).await;
    assert_eq!(doc["status"], "completed");
    assert_eq!(doc["jobs"]["done"], 4);
    let weights = doc["weights"].as_array().unwrap();
    assert_eq!(weights.len(), 2);
    for w in weights {
        assert_eq!(w["trials_done"], 2);
        assert_eq!(w["trials_converged"], 2);
    }
    // Same document as the analysis library on the served inputs.
    let (st, inputs) = app.get(&E::Outputs.path_of(&id)).await;
    assert_eq!(st, StatusCode::OK);
    let inputs: Vec<WeightInput> = serde_json::from_value(inputs).unwrap();
    let local = build_report(&inputs, &[], &ReportOptions::default());
    let served: shared::analysis::ResultDocument = serde_json::from_value(doc.clone()).unwrap();
    assert_eq!(served.weights, local.weights);
    let (st, csv) = app.get_text(&E::ResultsCsv.path_of(&id)).await;
    assert_eq!(st, StatusCode::OK);
    assert!(csv.starts_with("section,subject,param_value"), "{csv}");
    let s = app.status(&id).await;
    assert_eq!((s.jobs.done, s.jobs.total, s.trials_converged), (4, 4, 4));
    assert!(s.finished_at.is_some() && s.started_at.is_some());
    let (_, list) = app.get(E::ListSearches.path()).await;
    assert_eq!(list.as_array().unwrap().len(), 1);
}

#[tokio::test]
async fn partial_results_count_shortfall_and_unconverged_trials() {
    let app = spawn_app().await;
    let id = app.submit(&search_body(&[1.0, 2.0], 2)).await;
    // 1st job: converged; 2nd: not converged; 3rd: converged with a shortfall.
    for (rate, found) in [(0.9, 3), (0.2, 1), (0.7, 2)] {
        let l = app.lease("w").await.unwrap();
        let (st, v) = app
            .upload(l.job_id, &l.lease_token, &output(rate, found, 0.1))
            .await;
        assert_eq!(st, StatusCode::OK, "{v}");
        assert_eq!(v["converged"], json!(rate >= 0.5));
    }
    let doc = app.results(&id).await;
    assert_eq!(doc["partial"], true);
    assert!(
        doc["notes"].to_string().contains("partial: 3 of 4"),
        "{}",
        doc["notes"]
    );
    let s = app.status(&id).await;
    assert_eq!(
        (
            s.trials_converged,
            s.trials_not_converged,
            s.trials_with_shortfall
        ),
        (2, 1, 2)
    );
    assert_eq!(s.jobs.queued, 1);
    let w: u64 = doc["weights"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w["trials_done"].as_u64().unwrap())
        .sum();
    assert_eq!(w, 3);
    let text = doc.to_string();
    assert!(!text.contains("NaN"));
}

#[tokio::test]
async fn concurrent_searches_share_workers() {
    let app = spawn_app().await;
    let a = app.submit(&search_body(&[1.0, 2.0, 3.0], 2)).await;
    let b = app.submit(&search_body(&[1.0, 2.0, 3.0], 2)).await;
    let mut got = Vec::new();
    for _ in 0..6 {
        got.push(app.lease("w").await.unwrap().spec.search_id);
    }
    let na = got.iter().filter(|s| **s == a).count();
    let nb = got.iter().filter(|s| **s == b).count();
    assert_eq!((na, nb), (3, 3));
    let s = app.status(&a).await;
    assert_eq!(s.workers_busy, 1);
    assert_eq!(s.jobs.leased, 3);
}

#[tokio::test]
async fn cancel_stops_the_search_and_keeps_finished_results() {
    let app = spawn_app().await;
    let id = app.submit(&search_body(&[1.0, 2.0], 2)).await;
    let l1 = app.lease("w").await.unwrap();
    app.upload(l1.job_id, &l1.lease_token, &output(0.9, 3, 0.1))
        .await;
    let l2 = app.lease("w").await.unwrap();
    let (st, v) = app.cancel(&id).await;
    assert_eq!(st, StatusCode::OK, "{v}");
    assert_eq!(v["status"], "cancelled");
    assert_eq!(v["jobs"]["cancelled"], 3);
    assert_eq!(v["jobs"]["done"], 1);
    // The worker of a cancelled job learns it at its next heartbeat.
    let (st, v) = app.heartbeat(l2.job_id, &l2.lease_token, json!([])).await;
    assert_eq!(st, StatusCode::CONFLICT, "{v}");
    assert!(v["error"].as_str().unwrap().contains("cancelled"));
    let (st, _) = app
        .upload(l2.job_id, &l2.lease_token, &output(0.9, 3, 0.1))
        .await;
    assert_eq!(st, StatusCode::CONFLICT);
    assert!(app.lease("w").await.is_none());
    let doc = app.results(&id).await;
    assert_eq!(doc["status"], "cancelled");
    assert!(doc["notes"].to_string().contains("cancelled"));
    // Cancelling twice is fine; unknown ids are 404.
    assert_eq!(app.cancel(&id).await.0, StatusCode::OK);
    assert_eq!(app.cancel("nope").await.0, StatusCode::NOT_FOUND);
}

#[tokio::test]
async fn restart_on_the_same_file_loses_and_duplicates_nothing() {
    let mut app = spawn_app().await;
    let id = app.submit(&search_body(&[1.0, 2.0, 3.0], 2)).await;
    let l1 = app.lease("w").await.unwrap();
    app.upload(l1.job_id, &l1.lease_token, &output(0.9, 3, 0.1))
        .await;
    let l2 = app.lease("w").await.unwrap();
    app.restart().await;
    // The lease survives the restart: its worker can still finish.
    let (st, v) = app
        .upload(l2.job_id, &l2.lease_token, &output(0.9, 3, 0.1))
        .await;
    assert_eq!(st, StatusCode::OK, "{v}");
    let rest = app.drain(&output(0.9, 3, 0.1)).await;
    assert_eq!(rest.len(), 4);
    let doc = app.wait_final(&id).await;
    assert_eq!(doc["jobs"]["done"], 6);
    app.restart().await;
    let again = app.results(&id).await;
    assert_eq!(again["weights"], doc["weights"]);
    let (_, jobs) = app.get(&E::SearchJobs.path_of(&id)).await;
    assert!(jobs
        .as_array()
        .unwrap()
        .iter()
        .all(|j| j["lease_count"] == 1));
}

#[tokio::test]
async fn metrics_carry_the_queued_and_leased_gauges_autoscalers_read() {
    // docs/deploy.md#autoscaling names these two series: keep them.
    let app = spawn_app().await;
    let (_, m) = app.get_text("/metrics").await;
    for needle in [
        "irlgrid_jobs{state=\"queued\"} 0\n",
        "irlgrid_jobs{state=\"leased\"} 0\n",
    ] {
        assert!(m.contains(needle), "missing {needle} in\n{m}");
    }
    app.submit(&search_body(&[1.0, 2.0], 2)).await;
    let _busy = app.lease("w").await.unwrap();
    let (_, m) = app.get_text("/metrics").await;
    for needle in [
        "irlgrid_jobs{state=\"queued\"} 3\n",
        "irlgrid_jobs{state=\"leased\"} 1\n",
    ] {
        assert!(m.contains(needle), "missing {needle} in\n{m}");
    }
}

#[tokio::test]
async fn healthz_metrics_and_openapi_answer() {
    let app = spawn_app().await;
    let (st, v) = app.get("/healthz").await;
    assert_eq!((st, v["status"].as_str()), (StatusCode::OK, Some("ok")));
    let id = app.submit(&search_body(&[1.0], 1)).await;
    app.drain(&output(0.9, 3, 0.1)).await;
    app.wait_final(&id).await;
    let (st, m) = app.get_text("/metrics").await;
    assert_eq!(st, StatusCode::OK);
    for needle in [
        "irlgrid_jobs{state=\"done\"} 1",
        "irlgrid_uploads_accepted_total 1",
        "irlgrid_leases_granted_total 1",
        "irlgrid_leases_expired_total 0",
        &format!(
            "irlgrid_http_request_duration_seconds_bucket{{method=\"POST\",route=\"{}\"",
            E::Lease.path()
        ),
    ] {
        assert!(m.contains(needle), "missing {needle} in\n{m}");
    }
    let (st, doc) = app.get(E::OpenApi.path()).await;
    assert_eq!(st, StatusCode::OK);
    assert_eq!(doc["openapi"], "3.1.0");
    // Every documented route exists in the router (no "no route" 404).
    for route in coordinator::routes::ROUTES {
        let (method, path) = (route.method.as_str(), &route.path);
        let p = path.replace("{id}", "1");
        let r = app
            .client
            .request(method.parse().unwrap(), format!("{}{p}", app.url))
            .json(&json!({}))
            .send()
            .await
            .unwrap();
        let body = r.text().await.unwrap();
        assert!(!body.contains("no route"), "{method} {path}: {body}");
        assert!(
            doc["paths"][*path][method.to_lowercase()].is_object(),
            "{method} {path}"
        );
    }
}
