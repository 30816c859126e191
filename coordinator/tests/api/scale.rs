//! Documents from trial summaries, compact output storage, the paged
//! search list, and databases from before trial summaries.

use std::collections::BTreeMap;

use reqwest::StatusCode;
use serde_json::{json, Value};
use shared::analysis::{
    build_report_with, parse_subjects_csv, EpisodeRecord, Identifiability, ResultDocument,
    TrialInput, WeightInput,
};
use shared::api::{JobOutput, ResolvedConfig};

use crate::helpers::*;

/// Outputs with everything aggregation distinguishes: converged or not,
/// shortfalls, an episode that cannot be resampled.
fn varied_output(job: i64) -> JobOutput {
    let k = job as f64;
    let rate = if job % 4 == 3 { 0.2 } else { 0.9 - 0.01 * k };
    let found = [3, 2, 1][job as usize % 3];
    let mut o = output(rate, found, 0.05 + 0.013 * k);
    if job % 5 == 2 && o.episodes.len() == 2 {
        o.episodes[1] = EpisodeRecord {
            com_t: vec![0.0, 0.1, 0.2],
            com_x: vec![0.0, 0.1, 0.0],
            com_z: vec![0.6, 0.8, 1.0],
            ret: 2000.0,
            torque_usage: 5.0,
            steps: 1,
        };
    }
    o
}

/// Runs a 3-point, 3-trial search with subjects; uploads `varied_output`
/// for every job, stopping after `stop_after` uploads if given. Returns the
/// search id and the raw inputs as uploaded, by point then trial.
async fn run_search(app: &TestApp, stop_after: Option<usize>) -> (String, Vec<WeightInput>) {
    let mut body = search_body(&[0.5, 2.0, 8.0], 3);
    body["subjects_csv"] = json!(subjects_csv(&[("a", 0.06), ("b", 0.09)]));
    let id = app.submit(&body).await;
    let mut weights: Vec<WeightInput> = [0.5, 2.0, 8.0]
        .iter()
        .map(|w| WeightInput {
            params: BTreeMap::from([("w1".to_string(), *w)]),
            trials: Vec::new(),
        })
        .collect();
    let mut n = 0;
    while let Some(l) = app.lease("w").await {
        let o = varied_output(l.job_id);
        let (st, v) = app.upload(l.job_id, &l.lease_token, &o).await;
        assert_eq!(st, StatusCode::OK, "{v}");
        weights[l.spec.point_idx as usize].trials.push(TrialInput {
            trial: l.spec.trial,
            seed: l.spec.seed,
            final_success_rate: o.final_success_rate,
            converged: v["converged"].as_bool().unwrap(),
            episodes: o.episodes,
            successes_found: o.successes_found,
            successes_wanted: o.successes_wanted,
            solver: Default::default(),
        });
        n += 1;
        if Some(n) == stop_after {
            break;
        }
    }
    for w in &mut weights {
        w.trials.sort_by_key(|t| t.trial);
    }
    (id, weights)
}

/// A connection of its own to the app's database file (the app may be
/// running or stopped).
async fn open_db(app: &TestApp) -> sqlx::SqliteConnection {
    crate::support::connect(&app.dir.path().join("c.db"))
        .await
        .unwrap()
}

/// The search's report options and subjects as stored.
async fn stored_config(
    app: &TestApp,
    id: &str,
) -> (ResolvedConfig, Vec<shared::analysis::SubjectPath>) {
    let (config, csv): (String, String) =
        sqlx::query_as("select config, subjects_csv from searches where id = ?1")
            .bind(id)
            .fetch_one(&mut open_db(app).await)
            .await
            .unwrap();
    (
        serde_json::from_str(&config).unwrap(),
        parse_subjects_csv(&csv).unwrap(),
    )
}

/// The served document without the view's own fields.
fn document_of(mut served: Value) -> Value {
    let m = served.as_object_mut().unwrap();
    for k in ["search_id", "status", "partial", "jobs"] {
        m.remove(k).unwrap();
    }
    served
}

#[tokio::test]
async fn final_and_partial_documents_from_summaries_equal_documents_from_raw_outputs() {
    let app = spawn_app().await;
    // Partial: 5 of 9 jobs done.
    let (id, weights) = run_search(&app, Some(5)).await;
    let (cfg, subjects) = stored_config(&app, &id).await;
    let served = document_of(app.results(&id).await);
    let mut local = build_report_with(&weights, &subjects, &cfg.report, Identifiability::WhenReady);
    local
        .notes
        .push("partial: 5 of 9 jobs finished; the search is still running".into());
    assert!(
        served == serde_json::to_value(&local).unwrap(),
        "partial documents differ"
    );
    // Final: the rest done.
    let app2 = spawn_app().await;
    let (id, weights) = run_search(&app2, None).await;
    let (cfg, subjects) = stored_config(&app2, &id).await;
    let served = document_of(app2.wait_final(&id).await);
    let local = build_report_with(&weights, &subjects, &cfg.report, Identifiability::Always);
    assert!(local.identifiability.is_some() && local.subjects.len() == 2);
    assert!(
        local.notes.iter().any(|n| n.contains("not resampled")),
        "{:?}",
        local.notes
    );
    assert!(
        served == serde_json::to_value(&local).unwrap(),
        "final documents differ"
    );
    // Served from storage: the stored text is the document.
    let stored: String = sqlx::query_scalar("select final_document from searches where id = ?1")
        .bind(&id)
        .fetch_one(&mut open_db(&app2).await)
        .await
        .unwrap();
    let stored: ResultDocument = serde_json::from_str(&stored).unwrap();
    assert_eq!(stored, local);
    // The finished document is served as stored, spliced into the view:
    // the same bytes the typed view would give.
    let (st, text) = app2.get_text(&E::Results.path_of(&id)).await;
    assert_eq!(st, StatusCode::OK);
    let s = app2.status(&id).await;
    let view = shared::api::ResultsView {
        search_id: std::borrow::Cow::Borrowed(&id),
        status: s.status,
        partial: false,
        jobs: std::borrow::Cow::Borrowed(&s.jobs),
        document: std::borrow::Cow::Borrowed(&stored),
    };
    assert_eq!(text, serde_json::to_string(&view).unwrap());
}

#[tokio::test]
async fn outputs_are_stored_compact_and_served_byte_for_byte_as_uploaded() {
    let app = spawn_app().await;
    let (id, weights) = run_search(&app, None).await;
    let (st, text) = app.get_text(&E::Outputs.path_of(&id)).await;
    assert_eq!(st, StatusCode::OK);
    assert_eq!(text, serde_json::to_string(&weights).unwrap());
    let (blobs, rows, summaries): (i64, i64, i64) = sqlx::query_as(
        "select (select count(*) from job_results where typeof(output) = 'blob'),
                (select count(*) from job_results),
                (select count(*) from trial_summaries)",
    )
    .fetch_one(&mut open_db(&app).await)
    .await
    .unwrap();
    assert_eq!((blobs, rows, summaries), (9, 9, 9));
}

#[tokio::test]
async fn a_database_from_before_summaries_migrates_in_place_at_start_up() {
    let mut app = spawn_app().await;
    let (id, weights) = run_search(&app, None).await;
    let before = document_of(app.wait_final(&id).await);
    app.stop().await;
    // Make it look like a database of the previous schema: JSON text
    // outputs, no summaries, no cached document.
    {
        let mut conn = open_db(&app).await;
        sqlx::query("delete from trial_summaries")
            .execute(&mut conn)
            .await
            .unwrap();
        sqlx::query("update searches set final_document = null")
            .execute(&mut conn)
            .await
            .unwrap();
        let mut jobs: Vec<i64> = sqlx::query_scalar("select job_id from job_results")
            .fetch_all(&mut conn)
            .await
            .unwrap();
        jobs.sort();
        for j in jobs {
            let text = serde_json::to_string(&varied_output(j)).unwrap();
            sqlx::query("update job_results set output = ?1 where job_id = ?2")
                .bind(text)
                .bind(j)
                .execute(&mut conn)
                .await
                .unwrap();
        }
        let texts: i64 =
            sqlx::query_scalar("select count(*) from job_results where typeof(output) = 'text'")
                .fetch_one(&mut conn)
                .await
                .unwrap();
        assert_eq!(texts, 9);
        sqlx::Connection::close(conn).await.unwrap();
    }
    app.restart().await;
    let (blobs, summaries): (i64, i64) = sqlx::query_as(
        "select (select count(*) from job_results where typeof(output) = 'blob'),
                (select count(*) from trial_summaries)",
    )
    .fetch_one(&mut open_db(&app).await)
    .await
    .unwrap();
    assert_eq!((blobs, summaries), (9, 9));
    let (st, text) = app.get_text(&E::Outputs.path_of(&id)).await;
    assert_eq!(st, StatusCode::OK);
    assert_eq!(text, serde_json::to_string(&weights).unwrap());
    assert!(document_of(app.wait_final(&id).await) == before);
}

#[tokio::test]
async fn the_search_list_pages_newest_first_with_the_total_in_a_header() {
    let app = spawn_app().await;
    let mut ids = Vec::new();
    for _ in 0..3 {
        ids.push(app.submit(&search_body(&[1.0], 1)).await);
    }
    ids.reverse();
    let page = |q: &'static str| {
        let app = &app;
        async move {
            let r = app
                .client
                .get(format!("{}/api/v1/searches{q}", app.url))
                .send()
                .await
                .unwrap();
            let st = r.status();
            let total = r
                .headers()
                .get("x-total-count")
                .map(|v| v.to_str().unwrap().to_string());
            let v: Value = r.json().await.unwrap();
            (st, total, v)
        }
    };
    let listed = |v: &Value| -> Vec<String> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|s| s["id"].as_str().unwrap().to_string())
            .collect()
    };
    let (st, total, v) = page("").await;
    assert_eq!((st, total.as_deref()), (StatusCode::OK, Some("3")));
    assert_eq!(listed(&v), ids);
    let (_, _, v) = page("?limit=2").await;
    assert_eq!(listed(&v), ids[..2]);
    let (_, total, v) = page("?limit=2&offset=2").await;
    assert_eq!(
        (listed(&v), total.as_deref()),
        (ids[2..].to_vec(), Some("3"))
    );
    let (_, _, v) = page("?limit=0").await;
    assert_eq!(listed(&v), ids[..1]);
    let (st, _, v) = page("?limit=lots").await;
    assert_eq!(st, StatusCode::BAD_REQUEST, "{v}");
    let (st, _, v) = page("?page=2").await;
    assert_eq!(st, StatusCode::BAD_REQUEST, "{v}");
}

/// The committed final document of the fixed search [`run_search`] runs.
fn golden_path() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/api/golden/final_document.json")
}

/// A refactor of the coordinator keeps the result document of a fixed
/// search: the same uploads give the committed document, value for value.
/// A change that is meant to change the document regenerates it with
/// `IRLGRID_BLESS=1 cargo test -p coordinator --test api fixed_search` and says
/// why in its commit.
#[tokio::test]
async fn the_final_document_of_a_fixed_search_is_the_committed_one() {
    let app = spawn_app().await;
    let (id, _) = run_search(&app, None).await;
    let served = document_of(app.wait_final(&id).await);
    let path = golden_path();
    if std::env::var("IRLGRID_BLESS").is_ok_and(|v| v == "1") {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, serde_json::to_string_pretty(&served).unwrap() + "\n").unwrap();
        eprintln!("wrote {}", path.display());
        return;
    }
    let want: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    assert!(
        served == want,
        "the final document differs from {} (regenerate it with IRLGRID_BLESS=1 only if the \
         change is meant to change documents)",
        path.display()
    );
}
