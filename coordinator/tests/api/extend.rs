//! `POST /api/v1/searches/{id}/extend`: a finished search grows, keeps its
//! results, and its document and caches follow.

use std::collections::BTreeMap;

use reqwest::StatusCode;
use serde_json::json;
use shared::api::job_seed;

use crate::helpers::*;

fn w1s(doc: &serde_json::Value) -> Vec<f64> {
    doc["weights"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w["params"]["w1"].as_f64().unwrap())
        .collect()
}

#[tokio::test]
async fn a_completed_search_grows_keeps_its_results_and_its_document_follows() {
    let app = spawn_app().await;
    let id = app.submit(&search_body(&[0.5, 4.0], 2)).await;
    let first = app.drain(&output(0.9, 3, 0.05)).await;
    assert_eq!(first.len(), 4);
    let before = app.wait_final(&id).await;
    assert_eq!(w1s(&before), vec![0.5, 4.0]);
    let (_, jobs_before) = app.get(&E::SearchJobs.path_of(&id)).await;

    let (st, v) = app
        .post(
            &E::Extend.path_of(&id),
            &json!({"trials": 3, "reward_grid": {"w1": [2.0]}}),
        )
        .await;
    assert_eq!(st, StatusCode::OK, "{v}");
    assert_eq!(
        v,
        json!({"id": id, "status": "running", "trials": 3, "points": 3, "points_added": 1,
               "jobs_added": 5, "extension": 1})
    );
    // The cached final document is gone: partial, with the new job count.
    let s = app.status(&id).await;
    assert_eq!(s.status, shared::api::SearchState::Running);
    assert_eq!(
        (s.points, s.trials, s.jobs.total, s.jobs.queued),
        (3, 3, 9, 5)
    );
    assert!(s.finished_at.is_none());
    let partial = app.results(&id).await;
    assert_eq!(partial["partial"], json!(true));
    assert_eq!(partial["jobs"]["total"], json!(9));
    assert_eq!(w1s(&partial), vec![0.5, 2.0, 4.0]);

    // The finished jobs are exactly as they were.
    let (_, jobs_after) = app.get(&E::SearchJobs.path_of(&id)).await;
    for j in jobs_before.as_array().unwrap() {
        let now = jobs_after
            .as_array()
            .unwrap()
            .iter()
            .find(|k| k["id"] == j["id"])
            .unwrap();
        assert_eq!(now, j);
    }
    // New leases carry the new point's parameters and the rule's seeds.
    let mut seen = Vec::new();
    while let Some(l) = app.lease("w").await {
        let p = BTreeMap::from([("w1".to_string(), l.spec.params["w1"])]);
        assert_eq!(l.spec.seed, job_seed(7, &p, l.spec.trial));
        seen.push((l.spec.params["w1"], l.spec.trial));
        let (st, v) = app
            .upload(l.job_id, &l.lease_token, &output(0.9, 3, 0.05))
            .await;
        assert_eq!(st, StatusCode::OK, "{v}");
    }
    seen.sort_by(|a, b| a.partial_cmp(b).unwrap());
    assert_eq!(seen, vec![(0.5, 2), (2.0, 0), (2.0, 1), (2.0, 2), (4.0, 2)]);
    let after = app.wait_final(&id).await;
    assert_eq!(w1s(&after), vec![0.5, 2.0, 4.0]);
    for w in after["weights"].as_array().unwrap() {
        assert_eq!(w["trials_done"], 3, "{w}");
    }
    assert_eq!(after["jobs"]["done"], 9);
}

#[tokio::test]
async fn extend_refuses_bad_input_unknown_and_cancelled_searches() {
    let app = spawn_app().await;
    let id = app.submit(&search_body(&[1.0, 2.0], 2)).await;
    let path = E::Extend.path_of(&id);
    for (body, field) in [
        (json!({}), "body"),
        (json!({"trials": 1}), "trials"),
        (json!({"trials": 0}), "trials"),
        (json!({"trials": 101}), "trials"),
        (json!({"reward_grid": {"w1": [2.0]}}), "reward_grid.w1[0]"),
        (
            json!({"reward_grid": {"w1": [3.0, 3.0]}}),
            "reward_grid.w1[1]",
        ),
        (json!({"reward_grid": {"w1": [-1.0]}}), "reward_grid.w1[0]"),
        (json!({"reward_grid": {"w2": [1.0]}}), "reward_grid.w2"),
        (json!({"trials": 3, "seed": 1}), "invalid JSON body"),
    ] {
        let (st, v) = app.post(&path, &body).await;
        assert_eq!(st, StatusCode::BAD_REQUEST, "{body}: {v}");
        let msg = v["error"].as_str().unwrap();
        assert!(msg.starts_with(field), "{body}: {msg}");
    }
    assert_eq!(app.status(&id).await.jobs.total, 4);
    let (st, _) = app
        .post(&E::Extend.path_of("nope"), &json!({"trials": 3}))
        .await;
    assert_eq!(st, StatusCode::NOT_FOUND);
    let (st, _) = app.cancel(&id).await;
    assert_eq!(st, StatusCode::OK);
    let (st, v) = app.post(&path, &json!({"trials": 3})).await;
    assert_eq!(st, StatusCode::CONFLICT, "{v}");
    assert!(v["error"].as_str().unwrap().contains("cancelled"), "{v}");
    assert_eq!(app.status(&id).await.jobs.total, 4);
}

#[tokio::test]
async fn concurrent_extends_over_http_duplicate_no_job() {
    let app = spawn_app().await;
    let id = app.submit(&search_body(&[1.0, 2.0], 2)).await;
    let path = E::Extend.path_of(&id);
    let bodies = [
        json!({"trials": 4}),
        json!({"trials": 4}),
        json!({"reward_grid": {"w1": [3.0]}}),
        json!({"reward_grid": {"w1": [3.0]}}),
        json!({"reward_grid": {"w1": [8.0]}}),
    ];
    let (a, b, c, d, e) = tokio::join!(
        app.post(&path, &bodies[0]),
        app.post(&path, &bodies[1]),
        app.post(&path, &bodies[2]),
        app.post(&path, &bodies[3]),
        app.post(&path, &bodies[4])
    );
    let answers = [a, b, c, d, e];
    let ok = answers
        .iter()
        .filter(|(st, _)| *st == StatusCode::OK)
        .count();
    // One of each pair of equal requests wins; 8 is alone.
    assert_eq!(ok, 3, "{answers:?}");
    for (st, v) in &answers {
        assert!(
            *st == StatusCode::OK || *st == StatusCode::BAD_REQUEST,
            "{st} {v}"
        );
    }
    let (_, jobs) = app.get(&E::SearchJobs.path_of(&id)).await;
    let keys: Vec<(String, u64)> = jobs
        .as_array()
        .unwrap()
        .iter()
        .map(|j| (j["params"]["w1"].to_string(), j["trial"].as_u64().unwrap()))
        .collect();
    let distinct: std::collections::HashSet<_> = keys.iter().collect();
    assert_eq!(distinct.len(), keys.len());
    assert_eq!(keys.len(), 4 * 4);
}
