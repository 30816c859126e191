use std::time::Duration;

use reqwest::StatusCode;
use serde_json::json;

use crate::helpers::*;

#[tokio::test]
async fn expired_lease_goes_to_another_worker_and_the_late_upload_gets_409() {
    let app = spawn_with(Opts {
        lease_secs: Some(1),
        ..Opts::default()
    })
    .await;
    let id = app.submit(&search_body(&[1.0], 1)).await;
    let slow = app.lease("slow").await.unwrap();
    assert!(app.lease("fast").await.is_none());
    tokio::time::sleep(Duration::from_millis(1300)).await;
    let fast = app.lease("fast").await.unwrap();
    assert_eq!(fast.job_id, slow.job_id);
    assert_eq!(fast.spec.attempt, 2);
    assert_ne!(fast.lease_token, slow.lease_token);
    let (st, v) = app
        .upload(slow.job_id, &slow.lease_token, &output(0.9, 3, 0.1))
        .await;
    assert_eq!(st, StatusCode::CONFLICT, "{v}");
    let (st, v) = app
        .upload(fast.job_id, &fast.lease_token, &output(0.8, 3, 0.2))
        .await;
    assert_eq!(st, StatusCode::OK, "{v}");
    let (st, _) = app
        .upload(fast.job_id, &fast.lease_token, &output(0.1, 3, 0.3))
        .await;
    assert_eq!(st, StatusCode::CONFLICT);
    let doc = app.wait_final(&id).await;
    assert_eq!(doc["weights"][0]["trials_done"], 1);
    assert_eq!(doc["weights"][0]["trials"][0]["final_success_rate"], 0.8);
    let (_, jobs) = app.get(&E::SearchJobs.path_of(&id)).await;
    assert_eq!(jobs[0]["attempts"], 1);
    assert_eq!(jobs[0]["worker"], "fast");
    let (_, m) = app.get_text("/metrics").await;
    assert!(m.contains("irlgrid_leases_expired_total 1"), "{m}");
    assert!(m.contains("irlgrid_uploads_rejected_total 2"), "{m}");
}

#[tokio::test]
async fn heartbeats_keep_the_lease_and_record_the_learning_curve() {
    let app = spawn_with(Opts {
        lease_secs: Some(1),
        ..Opts::default()
    })
    .await;
    app.submit(&search_body(&[1.0], 1)).await;
    let l = app.lease("w").await.unwrap();
    for k in 0..4u64 {
        tokio::time::sleep(Duration::from_millis(400)).await;
        let p = json!([{"env_steps": k * 100, "total_env_steps": 1000, "mean_return": 10.0 * k as f64,
                        "success_rate": 0.1 * k as f64}]);
        let (st, v) = app.heartbeat(l.job_id, &l.lease_token, p).await;
        assert_eq!(st, StatusCode::OK, "{v}");
    }
    assert!(app.lease("other").await.is_none());
    let (st, d) = app.get(&E::JobDetail.path_of(l.job_id)).await;
    assert_eq!(st, StatusCode::OK);
    assert_eq!(d["status"], "leased");
    assert_eq!(d["curve"].as_array().unwrap().len(), 4);
    assert_eq!(d["progress"]["env_steps"], 300);
    assert_eq!(d["phase"], "training");
    let (st, _) = app.heartbeat(l.job_id, "0123456789abcdef", json!([])).await;
    assert_eq!(st, StatusCode::CONFLICT);
    let (st, _) = app.heartbeat(999, &l.lease_token, json!([])).await;
    assert_eq!(st, StatusCode::NOT_FOUND);
}

#[tokio::test]
async fn failures_retry_until_max_attempts_then_fail_with_the_last_error() {
    let app = spawn_app().await;
    let mut body = search_body(&[1.0], 1);
    body["max_attempts"] = json!(2);
    let id = app.submit(&body).await;
    let l = app.lease("w").await.unwrap();
    let (st, v) = app.fail(l.job_id, &l.lease_token, "diverged").await;
    assert_eq!((st, v["status"].as_str()), (StatusCode::OK, Some("queued")));
    let l = app.lease("w").await.unwrap();
    let (st, v) = app.fail(l.job_id, &l.lease_token, "diverged again").await;
    assert_eq!((st, v["status"].as_str()), (StatusCode::OK, Some("failed")));
    let doc = app.wait_final(&id).await;
    assert!(
        doc["notes"].to_string().contains("diverged again"),
        "{}",
        doc["notes"]
    );
    assert_eq!(doc["weights"][0]["trials_done"], 0);
    let s = app.status(&id).await;
    assert_eq!((s.jobs.failed, s.jobs.done), (1, 0));
}

#[tokio::test]
async fn release_returns_the_job_without_using_an_attempt() {
    let app = spawn_app().await;
    app.submit(&search_body(&[1.0], 1)).await;
    let l = app.lease("w").await.unwrap();
    let (st, v) = app.release(l.job_id, &l.lease_token).await;
    assert_eq!((st, v["status"].as_str()), (StatusCode::OK, Some("queued")));
    assert_eq!(
        app.release(l.job_id, &l.lease_token).await.0,
        StatusCode::CONFLICT
    );
    let l2 = app.lease("w").await.unwrap();
    assert_eq!((l2.job_id, l2.spec.attempt), (l.job_id, 2));
    let (_, d) = app.get(&E::JobDetail.path_of(l.job_id)).await;
    assert_eq!(d["attempts"], 0);
}

#[tokio::test]
async fn releases_beyond_max_attempts_never_fail_the_job() {
    // A worker pre-empted again and again (Slurm time limits, pod
    // evictions) hands its job back each time: the job stays queued with
    // no attempt used and is still done once in the end.
    let app = spawn_app().await;
    let mut body = search_body(&[1.0], 1);
    body["max_attempts"] = json!(2);
    let id = app.submit(&body).await;
    for n in 1..=5u32 {
        let l = app.lease("preempted").await.unwrap();
        assert_eq!(l.spec.attempt, n);
        let (st, v) = app.release(l.job_id, &l.lease_token).await;
        assert_eq!((st, v["status"].as_str()), (StatusCode::OK, Some("queued")));
    }
    let l = app.lease("last").await.unwrap();
    let (st, _) = app
        .upload(l.job_id, &l.lease_token, &output(0.9, 3, 0.1))
        .await;
    assert_eq!(st, StatusCode::OK);
    let (_, d) = app.get(&E::JobDetail.path_of(l.job_id)).await;
    assert_eq!(
        (d["attempts"].as_u64(), d["status"].as_str()),
        (Some(0), Some("done"))
    );
    let s = app.status(&id).await;
    assert_eq!((s.jobs.done, s.jobs.failed, s.jobs.total), (1, 0, 1));
}

#[tokio::test]
async fn unconverged_trials_are_replaced_up_to_the_cap() {
    let app = spawn_app().await;
    let mut body = search_body(&[1.0], 2);
    body["replace_unconverged"] = json!(true);
    body["max_trials_per_point"] = json!(3);
    let id = app.submit(&body).await;
    let mut seeds = Vec::new();
    let mut n = 0;
    while let Some(l) = app.lease("w").await {
        seeds.push(l.spec.seed);
        n += 1;
        let rate = if n == 1 { 0.1 } else { 0.9 };
        let (st, v) = app
            .upload(l.job_id, &l.lease_token, &output(rate, 3, 0.1))
            .await;
        assert_eq!(st, StatusCode::OK);
        assert_eq!(v["replacement_enqueued"], json!(n == 1));
    }
    assert_eq!(n, 3);
    seeds.sort();
    seeds.dedup();
    assert_eq!(seeds.len(), 3);
    let doc = app.wait_final(&id).await;
    assert_eq!(doc["weights"][0]["trials_done"], 3);
    assert_eq!(doc["weights"][0]["trials_converged"], 2);
}

#[tokio::test]
async fn lease_request_long_polls_until_a_search_arrives() {
    let app = spawn_app().await;
    let url = app.url.clone();
    let waiter = tokio::spawn(async move {
        let r = reqwest::Client::new()
            .post(format!("{url}/api/v1/leases"))
            .json(&json!({"worker": "w", "wait_secs": 10}))
            .send()
            .await
            .unwrap();
        r.status()
    });
    tokio::time::sleep(Duration::from_millis(300)).await;
    let t0 = std::time::Instant::now();
    app.submit(&search_body(&[1.0], 1)).await;
    assert_eq!(waiter.await.unwrap(), StatusCode::OK);
    assert!(t0.elapsed() < Duration::from_secs(2));
    let (st, _) = app
        .post(E::Lease.path(), &json!({"worker": "w", "wait_secs": 0}))
        .await;
    assert_eq!(st, StatusCode::NO_CONTENT);
}
