//! `POST /api/v1/searches/{id}/subjects`: new subjects scored against a
//! search's finished trials, with no job run; `?save=true` stores them.

use reqwest::StatusCode;
use serde_json::{json, Value};

use crate::helpers::*;

async fn post_csv(
    app: &TestApp,
    path: &str,
    body: String,
    token: Option<&str>,
) -> (StatusCode, Value) {
    let mut r = app
        .client
        .post(format!("{}{path}", app.url))
        .header("content-type", "text/csv")
        .body(body);
    if let Some(t) = token {
        r = r.bearer_auth(t);
    }
    let r = r.send().await.unwrap();
    let st = r.status();
    let text = r.text().await.unwrap();
    (
        st,
        serde_json::from_str(&text).unwrap_or(Value::String(text)),
    )
}

/// A completed two-point search whose trials bulge about 0.05 (w1 = 0.5)
/// and 0.15 (w1 = 4), three trials each.
async fn finished_search(app: &TestApp) -> String {
    let id = app.submit(&search_body(&[0.5, 4.0], 3)).await;
    let mut k = 0;
    while let Some(l) = app.lease("w").await {
        let bulge = if l.spec.params["w1"] == 0.5 {
            0.05
        } else {
            0.15
        };
        k += 1;
        let out = output(0.95, 3, bulge + 0.003 * f64::from(k % 3));
        let (st, v) = app.upload(l.job_id, &l.lease_token, &out).await;
        assert_eq!(st, StatusCode::OK, "{v}");
    }
    app.wait_final(&id).await;
    id
}

#[tokio::test]
async fn scoring_returns_every_method_and_save_adds_subjects_to_the_document() {
    let app = spawn_with(Opts {
        token: Some("admin-secret"),
        ..Opts::default()
    })
    .await;
    let id = finished_search(&app).await;
    let path = E::ScoreSubjects.path_of(&id);
    let csv = subjects_csv(&[("near-0.5", 0.052), ("near-4", 0.151)]);

    // Not saved: the answer has the subject block, the document is unchanged.
    let (st, v) = post_csv(&app, &path, csv.clone(), Some("admin-secret")).await;
    assert_eq!(st, StatusCode::OK, "{v}");
    assert_eq!(v["saved"], json!(false));
    let subs = v["subjects"].as_array().unwrap();
    assert_eq!(subs.len(), 2);
    assert_eq!(v["points"].as_array().unwrap().len(), 2);
    for (s, want) in subs.iter().zip([0.5, 4.0]) {
        for m in ["area", "correlation", "posterior"] {
            assert_eq!(s["methods"][m]["inferred"], json!(want), "{m}: {s}");
        }
        let post = &s["methods"]["posterior"];
        assert!(post["credible_set"]["mass"].as_f64().unwrap() >= 0.9);
        assert_eq!(post["out_of_model"]["flagged"], json!(false));
    }
    assert!(app.results(&id).await["subjects"]
        .as_array()
        .unwrap()
        .is_empty());

    // JSON body, saved: the final document now shows the subjects.
    let (st, v) = app
        .post(
            &format!("{path}?save=true"),
            &json!({ "subjects_csv": csv }),
        )
        .await;
    assert_eq!(st, StatusCode::OK, "{v}");
    assert_eq!(v["saved"], json!(true));
    let doc = app.results(&id).await;
    let names: Vec<&str> = doc["subjects"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["subject"].as_str().unwrap())
        .collect();
    assert_eq!(names, vec!["near-0.5", "near-4"]);
    assert_eq!(doc["partial"], json!(false));
    // The same names again would make two subjects one: refused.
    let (st, v) = app
        .post(
            &format!("{path}?save=true"),
            &json!({ "subjects_csv": csv }),
        )
        .await;
    assert_eq!(st, StatusCode::CONFLICT, "{v}");
    assert!(v["error"].as_str().unwrap().contains("near-0.5"), "{v}");
}

#[tokio::test]
async fn scoring_refuses_bad_input_with_the_reason() {
    let app = spawn_with(Opts {
        token: Some("admin-secret"),
        ..Opts::default()
    })
    .await;
    let id = finished_search(&app).await;
    let path = E::ScoreSubjects.path_of(&id);
    let tok = Some("admin-secret");

    // A bad CSV gets the line number.
    let bad = "subject,time,x,z\ns1,0.0,0.0,0.6\ns1,0.1,oops,0.7\n".to_string();
    let (st, v) = post_csv(&app, &path, bad, tok).await;
    assert_eq!(st, StatusCode::BAD_REQUEST, "{v}");
    assert!(v["error"].as_str().unwrap().contains("line 3"), "{v}");

    // No token, wrong token.
    let good = subjects_csv(&[("s", 0.05)]);
    let (st, _) = post_csv(&app, &path, good.clone(), None).await;
    assert_eq!(st, StatusCode::UNAUTHORIZED);
    let (st, _) = post_csv(&app, &path, good.clone(), Some("wrong")).await;
    assert_eq!(st, StatusCode::UNAUTHORIZED);

    // Unknown search; unknown query parameter; unknown JSON field.
    let (st, _) = post_csv(&app, &E::ScoreSubjects.path_of("nope"), good.clone(), tok).await;
    assert_eq!(st, StatusCode::NOT_FOUND);
    let (st, v) = post_csv(&app, &format!("{path}?keep=1"), good.clone(), tok).await;
    assert_eq!(st, StatusCode::BAD_REQUEST, "{v}");
    let (st, v) = app
        .post(&path, &json!({"subjects_csv": good, "extra": 1}))
        .await;
    assert_eq!(st, StatusCode::BAD_REQUEST, "{v}");
}

#[tokio::test]
async fn scoring_a_search_without_a_converged_trial_is_a_conflict() {
    let app = spawn_app().await;
    let id = app.submit(&search_body(&[0.5, 4.0], 1)).await;
    let path = E::ScoreSubjects.path_of(&id);
    let csv = subjects_csv(&[("s", 0.05)]);
    // Nothing finished yet.
    let (st, v) = post_csv(&app, &path, csv.clone(), None).await;
    assert_eq!(st, StatusCode::CONFLICT, "{v}");
    // One trial finished but did not converge.
    let l = app.lease("w").await.unwrap();
    let (st, _) = app
        .upload(l.job_id, &l.lease_token, &output(0.1, 3, 0.05))
        .await;
    assert_eq!(st, StatusCode::OK);
    let (st, v) = post_csv(&app, &path, csv, None).await;
    assert_eq!(st, StatusCode::CONFLICT, "{v}");
    assert!(v["error"].as_str().unwrap().contains("converged"), "{v}");
}
