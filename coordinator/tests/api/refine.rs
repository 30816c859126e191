//! Adaptive refinement (`"refine"` in a search request, `POST
//! /api/v1/searches/{id}/refine`) on synthetic uploads, without training:
//! a world in which a trial's path bulges by `bulge(w1)`, linear in log w1,
//! so every subject's true w1 is known and the grid brackets it in log w1.

use std::time::{Duration, Instant};

use reqwest::StatusCode;
use serde_json::{json, Value};

use crate::helpers::*;

const PAPER: [f64; 7] = [0.1, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0];

/// The synthetic world's path bulge at `w1`.
fn bulge(w1: f64) -> f64 {
    0.08 + 0.03 * w1.ln()
}

/// A refining search over the paper grid with subjects planted at `planted`.
fn refining_search(planted: &[(&str, f64)], refine: Value) -> Value {
    let mut body = search_body(&PAPER, 3);
    let subjects: Vec<(&str, f64)> = planted.iter().map(|(n, w)| (*n, bulge(*w))).collect();
    body["subjects_csv"] = json!(subjects_csv(&subjects));
    body["refine"] = refine;
    body
}

/// Works every job the search hands out (round after round) until its
/// refinement has settled; the uploaded path bulges by `bulge(w1)` plus a
/// little trial-to-trial spread. Returns the refinement and the jobs run.
async fn run_until_settled(app: &TestApp, id: &str) -> (Value, usize) {
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut jobs = 0;
    loop {
        while let Some(l) = app.lease("w").await {
            let w1 = l.spec.params["w1"];
            let spread = 0.002 * (f64::from(l.spec.trial % 3) - 1.0);
            let mut out = output(0.95, 3, bulge(w1) + spread);
            // Both episodes on the trial's bulge, so that every statistic
            // of a trial (mean path, best episode) sits at bulge(w1).
            out.episodes[1] = out.episodes[0].clone();
            let (st, v) = app.upload(l.job_id, &l.lease_token, &out).await;
            assert_eq!(st, StatusCode::OK, "{v}");
            jobs += 1;
        }
        let (st, r) = app.get(&E::Refinement.path_of(id)).await;
        assert_eq!(st, StatusCode::OK, "{r}");
        if r["state"] == "settled" {
            return (r, jobs);
        }
        assert!(Instant::now() < deadline, "refinement did not settle: {r}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

fn subject<'a>(round: &'a Value, name: &str) -> &'a Value {
    round["subjects"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["subject"] == name)
        .unwrap()
}

#[tokio::test]
async fn refinement_adds_shared_midpoints_and_stops_at_the_target_ratio() {
    let app = spawn_app().await;
    let planted = [("a", 5.7), ("b", 6.0), ("c", 11.3)];
    let id = app
        .submit(&refining_search(
            &planted,
            json!({"rounds": 3, "target_ratio": 1.2}),
        ))
        .await;
    let (r, jobs) = run_until_settled(&app, &id).await;
    let rounds = r["rounds"].as_array().unwrap();
    assert_eq!(r["spec"]["trials"], 3, "{r}");

    // Round 0 reads the paper grid: a and b sit between 4 and 8 and ask
    // for the same geometric midpoint, which is added once; c asks for the
    // midpoint of 8 and 16.
    let r0 = &rounds[0];
    for name in ["a", "b"] {
        let s = subject(r0, name);
        assert_eq!(
            (s["lo"].as_f64(), s["hi"].as_f64()),
            (Some(4.0), Some(8.0)),
            "{s}"
        );
        assert_eq!(s["midpoint"], json!(5.657), "{s}");
    }
    assert_eq!(subject(r0, "c")["midpoint"], json!(11.31));
    assert_eq!(r0["added"], json!([5.657, 11.31]));

    // Every later round narrows each pair; the last one adds nothing and
    // says why, and every pair is then within the target ratio.
    let last = rounds.last().unwrap();
    assert_eq!(last["added"], json!([]), "{r}");
    assert!(
        last["stop"].as_str().unwrap().contains("target ratio"),
        "{last}"
    );
    assert!(rounds.len() <= 4, "at most 3 rounds of added points: {r}");
    for (name, truth) in planted {
        let s = subject(last, name);
        let est = s["estimate"].as_f64().unwrap();
        assert!((est / truth - 1.0).abs() < 0.15, "{name}: {est} vs {truth}");
        assert!(s["ratio"].as_f64().unwrap() < 1.2, "{s}");
    }

    // Each added point got its 3 trials, once: the jobs run are the grid's
    // plus 3 per added value, and the document shows every value in order.
    let added: Vec<f64> = rounds
        .iter()
        .flat_map(|r| {
            r["added"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
        })
        .collect();
    assert_eq!(jobs, 3 * (PAPER.len() + added.len()));
    let doc = app.results(&id).await;
    assert_eq!(doc["partial"], json!(false));
    let values: Vec<f64> = doc["weights"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w["value"].as_f64().unwrap())
        .collect();
    let mut want: Vec<f64> = PAPER.iter().copied().chain(added).collect();
    want.sort_by(f64::total_cmp);
    assert_eq!(values, want);
    let s = app.status(&id).await;
    assert_eq!(s.status, shared::api::SearchState::Completed);
}

#[tokio::test]
async fn refinement_stops_after_its_rounds_and_added_points_take_their_own_trials() {
    let app = spawn_app().await;
    // A target ratio no grid reaches in one round: the single round is used
    // up, and its points get 2 trials, not the search's 3.
    let id = app
        .submit(&refining_search(
            &[("a", 5.7)],
            json!({"rounds": 1, "trials": 2, "target_ratio": 1.01}),
        ))
        .await;
    let (r, jobs) = run_until_settled(&app, &id).await;
    let rounds = r["rounds"].as_array().unwrap();
    assert_eq!(rounds.len(), 2, "{r}");
    assert_eq!(rounds[0]["added"], json!([5.657]));
    assert_eq!(rounds[1]["stop"], json!("all 1 rounds used"));
    assert!(subject(&rounds[1], "a")["midpoint"].is_number());
    assert_eq!(jobs, 3 * PAPER.len() + 2);

    // Asking again on the settled search continues from there, at once.
    let (st, v) = app
        .post(
            &E::Refine.path_of(&id),
            &json!({"rounds": 1, "trials": 2, "target_ratio": 1.01}),
        )
        .await;
    assert_eq!(st, StatusCode::OK, "{v}");
    assert_eq!(v["spec"]["first_round"], 2, "{v}");
    let (r, jobs) = run_until_settled(&app, &id).await;
    assert_eq!(jobs, 2, "one more point with 2 trials: {r}");
    assert_eq!(r["rounds"].as_array().unwrap().len(), 4, "{r}");

    // Raising the search's trials raises every point, refined ones too:
    // 7 grid points from 3 to 4, 2 refined ones from 2 to 4.
    let (st, v) = app
        .post(&E::Extend.path_of(&id), &json!({"trials": 4}))
        .await;
    assert_eq!(st, StatusCode::OK, "{v}");
    assert_eq!(v["jobs_added"], 7 + 2 * 2, "{v}");
}

#[tokio::test]
async fn a_coordinator_restarted_as_a_round_ends_refines_once() {
    let mut app = spawn_app().await;
    let planted = [("a", 5.7), ("c", 11.3)];
    let id = app
        .submit(&refining_search(&planted, json!({"rounds": 3})))
        .await;
    // Finish the grid and restart at once: the round is decided before
    // the restart or after it (the completed search is picked up again),
    // never twice.
    while let Some(l) = app.lease("w").await {
        let mut out = output(0.95, 3, bulge(l.spec.params["w1"]));
        out.episodes[1] = out.episodes[0].clone();
        app.upload(l.job_id, &l.lease_token, &out).await;
    }
    app.restart().await;
    let (r, _) = run_until_settled(&app, &id).await;
    let rounds = r["rounds"].as_array().unwrap();
    for (k, round) in rounds.iter().enumerate() {
        assert_eq!(round["round"], k, "{r}");
    }
    assert_eq!(rounds[0]["added"], json!([5.657, 11.31]));
    let (_, jobs) = app.get(&E::SearchJobs.path_of(&id)).await;
    let mut keys: Vec<(f64, u64)> = jobs
        .as_array()
        .unwrap()
        .iter()
        .map(|j| {
            (
                j["params"]["w1"].as_f64().unwrap(),
                j["trial"].as_u64().unwrap(),
            )
        })
        .collect();
    let n = keys.len();
    keys.sort_by(|a, b| a.partial_cmp(b).unwrap());
    keys.dedup();
    assert_eq!(keys.len(), n, "no (point, trial) twice");
}

#[tokio::test]
async fn refine_refuses_bad_input_with_the_field() {
    let app = spawn_app().await;
    let bad = [
        (json!({"rounds": 0}), "refine.rounds"),
        (json!({"rounds": 11}), "refine.rounds"),
        (json!({"trials": 0}), "refine.trials"),
        (json!({"target_ratio": 1.0}), "refine.target_ratio"),
        (json!({"min_pair_mass": 1.5}), "refine.min_pair_mass"),
        (json!({"target_ratio": "x"}), "refine"),
        (json!({"depth": 2}), "refine"),
    ];
    for (refine, field) in bad {
        let (st, v) = app
            .post(
                E::ListSearches.path(),
                &refining_search(&[("a", 2.0)], refine.clone()),
            )
            .await;
        assert_eq!(st, StatusCode::BAD_REQUEST, "{refine}: {v}");
        assert!(
            v["error"].as_str().unwrap().contains(field),
            "{refine}: {v}"
        );
    }
    // No subjects, or a grid of two parameters.
    let mut body = search_body(&PAPER, 2);
    body["refine"] = json!({});
    let (st, v) = app.post(E::Submit.path(), &body).await;
    assert_eq!(st, StatusCode::BAD_REQUEST);
    assert!(v["error"].as_str().unwrap().contains("subjects"), "{v}");
    let mut body = refining_search(&[("a", 2.0)], json!({}));
    body["reward_grid"]["success_bonus"] = json!([500.0, 1000.0]);
    let (st, v) = app.post(E::Submit.path(), &body).await;
    assert_eq!(st, StatusCode::BAD_REQUEST);
    assert!(
        v["error"].as_str().unwrap().contains("one parameter"),
        "{v}"
    );

    // The refine route: unknown search, no subjects, cancelled search.
    let (st, _) = app.post(&E::Refine.path_of("nope"), &json!({})).await;
    assert_eq!(st, StatusCode::NOT_FOUND);
    let plain = app.submit(&search_body(&[1.0, 2.0], 1)).await;
    let (st, v) = app.post(&E::Refine.path_of(&plain), &json!({})).await;
    assert_eq!(st, StatusCode::BAD_REQUEST, "{v}");
    assert!(v["error"].as_str().unwrap().contains("no subjects"), "{v}");
    let id = app.submit(&refining_search(&[("a", 2.0)], json!({}))).await;
    app.cancel(&id).await;
    let (st, v) = app.post(&E::Refine.path_of(&id), &json!({})).await;
    assert_eq!(st, StatusCode::CONFLICT, "{v}");
    let (st, v) = app.get(&E::Refinement.path_of(&id)).await;
    assert_eq!(st, StatusCode::OK);
    assert_eq!(v["state"], "pending");
    assert_eq!(v["rounds"], json!([]));
}
