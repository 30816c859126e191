use std::collections::{BTreeMap, HashSet};

use shared::api::{job_seed, variant_seed, JobPhase};

use super::*;
use crate::domain::DomainError;

async fn db() -> (tempfile::TempDir, Db) {
    let dir = tempfile::tempdir().unwrap();
    let db = Db::open(&dir.path().join("q.db")).await.unwrap();
    (dir, db)
}

fn search(id: &str, w1: &[f64], trials: u32) -> NewSearch {
    NewSearch {
        id: id.into(),
        name: id.into(),
        request: "{}".into(),
        config: "{}".into(),
        trials,
        base_seed: 42,
        threshold: 0.5,
        replace_unconverged: false,
        max_trials_per_point: trials,
        max_attempts: 2,
        subjects_csv: None,
        points: w1
            .iter()
            .map(|&w| BTreeMap::from([("w1".to_string(), w)]))
            .collect(),
        refine: None,
        variants: 1,
    }
}

fn output(rate: f64) -> JobOutput {
    JobOutput {
        final_success_rate: rate,
        successes_wanted: 1,
        ..JobOutput::default()
    }
}

async fn done(db: &Db, c: &Claimed, rate: f64) -> StoreResult<Completion> {
    complete_with(
        db,
        c.job_id,
        &c.token,
        Upload::of(output(rate)).unwrap(),
        0.5,
        1,
    )
    .await
}

/// A search's job counts, checked against a recount from the jobs and
/// results tables: every test that reads counts also checks that the
/// triggers of `search_counts` kept them through whatever it did (leases,
/// uploads, failures, releases, expiries, cancellations, extensions).
async fn counts(db: &Db, id: &str) -> JobCounts {
    let row = search_rows(db, Some(id)).await.unwrap().pop().unwrap();
    let mut jobs = JobCounts::default();
    let by_state: Vec<(String, i64)> =
        sqlx::query_as("select status, count(*) from jobs where search_id = ?1 group by status")
            .bind(id)
            .fetch_all(&db.read)
            .await
            .unwrap();
    for (state, n) in by_state {
        let n = n as u64;
        match JobState::parse(&state).unwrap() {
            JobState::Queued => jobs.queued = n,
            JobState::Leased => jobs.leased = n,
            JobState::Done => jobs.done = n,
            JobState::Failed => jobs.failed = n,
            JobState::Cancelled => jobs.cancelled = n,
        }
        jobs.total += n;
    }
    assert_eq!(row.jobs, jobs, "job counts kept by triggers vs recounted");
    let (results, converged, shortfall, mean_ms): (i64, i64, i64, Option<f64>) = sqlx::query_as(
        "select count(r.job_id), coalesce(sum(r.converged), 0),
                coalesce(sum(r.successes_found < r.successes_wanted), 0),
                (select avg(finished_at - leased_at) from jobs
                  where search_id = ?1 and status = ?2)
         from job_results r join jobs j on j.id = r.job_id where j.search_id = ?1",
    )
    .bind(id)
    .bind(JobState::Done.as_str())
    .fetch_one(&db.read)
    .await
    .unwrap();
    assert_eq!(
        (row.converged, row.not_converged, row.shortfall),
        (
            converged as u64,
            (results - converged) as u64,
            shortfall as u64
        ),
        "result tallies kept by triggers vs recounted"
    );
    match (row.mean_job_ms, mean_ms) {
        (Some(a), Some(b)) => assert!((a - b).abs() <= 1e-9 * b.abs().max(1.0), "{a} vs {b}"),
        (a, b) => assert_eq!(a, b, "mean job time kept by triggers vs recounted"),
    }
    row.jobs
}

#[tokio::test]
async fn every_job_is_leased_once_in_trial_major_order_then_search_completes() {
    let (_d, db) = db().await;
    assert_eq!(
        insert_search(&db, &search("a", &[1.0, 2.0], 2), 0)
            .await
            .unwrap(),
        4
    );
    let mut seen = Vec::new();
    let mut last = Effects::default();
    while let (Some(c), _) = claim_with(&db, "w", 60_000, 1, true).await.unwrap() {
        assert_eq!(c.attempt, 1);
        seen.push((c.trial, c.point_idx));
        let p = BTreeMap::from([("w1".to_string(), [1.0, 2.0][c.point_idx as usize])]);
        assert_eq!(c.seed, job_seed(42, &p, c.trial));
        last = done(&db, &c, 1.0).await.unwrap().effects;
    }
    assert_eq!(seen, vec![(0, 0), (0, 1), (1, 0), (1, 1)]);
    assert_eq!(last.completed, vec!["a".to_string()]);
    let row = search_rows(&db, Some("a")).await.unwrap().pop().unwrap();
    assert_eq!(row.status, SearchState::Completed);
    assert_eq!((row.jobs.done, row.jobs.total, row.converged), (4, 4, 4));
    assert_eq!(outputs(&db, "a").await.unwrap().len(), 4);
}

#[tokio::test]
async fn every_solver_variant_of_every_point_and_trial_is_one_job_with_its_own_seed() {
    let (_d, db) = db().await;
    let mut s = search("a", &[1.0, 2.0], 2);
    s.variants = 3;
    assert_eq!(insert_search(&db, &s, 0).await.unwrap(), 12);
    let mut seen = Vec::new();
    while let (Some(c), _) = claim_with(&db, "w", 60_000, 1, true).await.unwrap() {
        let p = BTreeMap::from([("w1".to_string(), [1.0, 2.0][c.point_idx as usize])]);
        assert_eq!(c.seed, variant_seed(42, &p, c.trial, c.variant));
        seen.push((c.trial, c.point_idx, c.variant));
        done(&db, &c, 1.0).await.unwrap();
    }
    // Trial-major; the variants of one (point, trial) together.
    let want: Vec<(u32, u32, u32)> = (0..2)
        .flat_map(|t| (0..2).flat_map(move |p| (0..3).map(move |v| (t, p, v))))
        .collect();
    assert_eq!(seen, want);
    let outs = outputs(&db, "a").await.unwrap();
    assert_eq!(outs.len(), 12);
    assert_eq!(outs.iter().filter(|o| o.variant == 2).count(), 4);
}

#[tokio::test]
async fn replacements_count_per_solver_variant() {
    let (_d, db) = db().await;
    let mut s = search("a", &[1.0], 1);
    s.variants = 2;
    s.replace_unconverged = true;
    s.max_trials_per_point = 2;
    insert_search(&db, &s, 0).await.unwrap();
    // Variant 0 converges; variant 1 does not and gets one replacement
    // (trial 1 of variant 1), then stops at the cap.
    let mut replaced = Vec::new();
    while let (Some(c), _) = claim_with(&db, "w", 60_000, 1, true).await.unwrap() {
        let rate = if c.variant == 0 { 1.0 } else { 0.0 };
        if done(&db, &c, rate).await.unwrap().replacement {
            replaced.push(c.variant);
        }
    }
    assert_eq!(replaced, vec![1]);
    let outs = outputs(&db, "a").await.unwrap();
    let keys: Vec<(u32, u32)> = outs.iter().map(|o| (o.variant, o.trial)).collect();
    assert_eq!(keys, vec![(0, 0), (1, 0), (1, 1)]);
}

#[tokio::test]
async fn stale_or_duplicate_upload_is_409_and_changes_nothing() {
    let (_d, db) = db().await;
    insert_search(&db, &search("a", &[1.0], 1), 0)
        .await
        .unwrap();
    let (c, _) = claim_with(&db, "w", 60_000, 1, true).await.unwrap();
    let c = c.unwrap();
    let mut wrong = c.clone();
    wrong.token = "0".repeat(32);
    assert!(matches!(
        done(&db, &wrong, 1.0).await,
        Err(StoreError::Conflict(_))
    ));
    assert_eq!(counts(&db, "a").await.leased, 1);
    done(&db, &c, 0.9).await.unwrap();
    let e = done(&db, &c, 0.1).await.unwrap_err();
    assert!(
        matches!(e, StoreError::Conflict(ref m) if m.contains("already accepted")),
        "{e}"
    );
    let outs = outputs(&db, "a").await.unwrap();
    assert_eq!(outs.len(), 1);
    assert_eq!(outs[0].output.final_success_rate, 0.9);
    let mut missing = c.clone();
    missing.job_id = 999;
    assert!(matches!(
        done(&db, &missing, 1.0).await,
        Err(StoreError::NotFound(_))
    ));
}

#[tokio::test]
async fn expired_lease_is_requeued_then_fails_after_max_attempts() {
    let (_d, db) = db().await;
    insert_search(&db, &search("a", &[1.0], 1), 0)
        .await
        .unwrap();
    let (c1, _) = claim_with(&db, "w1", 1_000, 0, true).await.unwrap();
    let c1 = c1.unwrap();
    // Not yet expired: nothing to lease.
    assert!(claim_with(&db, "w2", 1_000, 500, true)
        .await
        .unwrap()
        .0
        .is_none());
    let (c2, eff) = claim_with(&db, "w2", 1_000, 2_000, true).await.unwrap();
    let c2 = c2.unwrap();
    assert_eq!(eff.expired, 1);
    assert_eq!((c2.job_id, c2.attempt), (c1.job_id, 2));
    assert!(matches!(
        done(&db, &c1, 1.0).await,
        Err(StoreError::Conflict(_))
    ));
    let hb = heartbeat(
        &db,
        c1.job_id,
        &c1.token,
        JobPhase::Training,
        &[],
        1_000,
        2_100,
    )
    .await;
    assert!(matches!(hb, Err(StoreError::Conflict(_))));
    // Second expiry uses the last attempt (max_attempts = 2).
    let eff = sweep_expired(&db, 10_000).await.unwrap();
    assert_eq!(eff.expired, 1);
    assert_eq!(eff.completed, vec!["a".to_string()]);
    let jobs = list_jobs(&db, "a").await.unwrap();
    assert_eq!(jobs[0].status, JobState::Failed);
    assert_eq!(jobs[0].attempts, 2);
    assert!(jobs[0]
        .last_error
        .as_deref()
        .unwrap()
        .contains("lease expired (owner w2)"));
    // The failure says that it was the attempts that ran out.
    assert!(jobs[0]
        .last_error
        .as_deref()
        .unwrap()
        .ends_with("; all 2 attempts used"));
}

#[tokio::test]
async fn a_job_that_lost_its_lease_waits_behind_fresh_jobs() {
    // Ordering by id alone re-leased a lost job to the next worker that
    // asked, so dying workers spent one job's attempts again and again.
    let (_d, db) = db().await;
    insert_search(&db, &search("a", &[1.0, 2.0], 2), 0)
        .await
        .unwrap();
    let first = claim_with(&db, "w1", 1_000, 0, true)
        .await
        .unwrap()
        .0
        .unwrap();
    // The lease expires; the next claims take the three fresh jobs first.
    let mut later = Vec::new();
    for k in 0..4 {
        let c = claim_with(&db, "w2", 100_000, 2_000 + k, true)
            .await
            .unwrap()
            .0
            .unwrap();
        later.push((c.job_id, c.attempt));
    }
    let fresh: Vec<i64> = later[..3].iter().map(|&(id, _)| id).collect();
    assert!(!fresh.contains(&first.job_id), "{later:?}");
    assert!(later[..3].iter().all(|&(_, a)| a == 1), "{later:?}");
    assert_eq!(later[3], (first.job_id, 2));
}

#[tokio::test]
async fn heartbeat_extends_the_lease_and_keeps_a_bounded_curve() {
    let (_d, db) = db().await;
    insert_search(&db, &search("a", &[1.0], 1), 0)
        .await
        .unwrap();
    let c = claim_with(&db, "w", 1_000, 0, true)
        .await
        .unwrap()
        .0
        .unwrap();
    let p = |s: u64| ProgressPoint {
        env_steps: s,
        total_env_steps: 10_000,
        success_rate: Some(0.5),
        ..ProgressPoint::default()
    };
    for k in 0..3 {
        let batch: Vec<_> = (0..300).map(|i| p(k * 300 + i)).collect();
        heartbeat(
            &db,
            c.job_id,
            &c.token,
            JobPhase::Training,
            &batch,
            1_000,
            900 * (k as i64 + 1),
        )
        .await
        .unwrap();
    }
    // Lease now runs to 2700 + 1000: not expired at 3000.
    assert_eq!(sweep_expired(&db, 3_000).await.unwrap().expired, 0);
    let (info, curve) = job_detail(&db, c.job_id).await.unwrap().unwrap();
    assert!(
        curve.len() as i64 <= HISTORY_CAP && curve.len() > 200,
        "{}",
        curve.len()
    );
    assert_eq!(curve.last().unwrap().env_steps, 899);
    assert!(curve.windows(2).all(|w| w[0].env_steps < w[1].env_steps));
    assert_eq!(info.progress.unwrap().env_steps, 899);
    assert_eq!(info.phase, Some(JobPhase::Training));
}

#[tokio::test]
async fn searches_share_workers_evenly() {
    let (_d, db) = db().await;
    insert_search(&db, &search("a", &[1.0, 2.0, 3.0, 4.0], 1), 0)
        .await
        .unwrap();
    insert_search(&db, &search("b", &[1.0, 2.0, 3.0, 4.0], 1), 0)
        .await
        .unwrap();
    let mut by = Vec::new();
    for _ in 0..6 {
        by.push(
            claim_with(&db, "w", 60_000, 1, true)
                .await
                .unwrap()
                .0
                .unwrap()
                .search_id,
        );
    }
    let a = by.iter().filter(|s| *s == "a").count();
    assert_eq!(a, 3, "{by:?}");
}

#[tokio::test]
async fn unconverged_trials_get_replacements_up_to_the_cap() {
    let (_d, db) = db().await;
    let mut s = search("a", &[1.0], 1);
    s.replace_unconverged = true;
    s.max_trials_per_point = 3;
    insert_search(&db, &s, 0).await.unwrap();
    let mut trials = HashSet::new();
    let mut replacements = 0;
    while let (Some(c), _) = claim_with(&db, "w", 60_000, 1, true).await.unwrap() {
        trials.insert(c.trial);
        let r = done(&db, &c, 0.1).await.unwrap();
        assert!(!r.converged);
        replacements += u32::from(r.replacement);
    }
    assert_eq!(replacements, 2);
    assert_eq!(trials, HashSet::from([0, 1, 2]));
    let row = search_rows(&db, Some("a")).await.unwrap().pop().unwrap();
    assert_eq!(
        (row.status, row.not_converged, row.converged),
        (SearchState::Completed, 3, 0)
    );
    // Converged on the first replacement: no more.
    let (_d, db) = self::db().await;
    insert_search(&db, &s, 0).await.unwrap();
    let c = claim_with(&db, "w", 60_000, 1, true)
        .await
        .unwrap()
        .0
        .unwrap();
    assert!(done(&db, &c, 0.0).await.unwrap().replacement);
    let c = claim_with(&db, "w", 60_000, 1, true)
        .await
        .unwrap()
        .0
        .unwrap();
    assert_eq!(c.trial, 1);
    let r = done(&db, &c, 0.8).await.unwrap();
    assert!(r.converged && !r.replacement);
    assert_eq!(r.effects.completed, vec!["a".to_string()]);
}

#[tokio::test]
async fn release_requeues_without_using_an_attempt_and_fail_uses_one() {
    let (_d, db) = db().await;
    insert_search(&db, &search("a", &[1.0], 1), 0)
        .await
        .unwrap();
    let c = claim_with(&db, "w", 60_000, 1, true)
        .await
        .unwrap()
        .0
        .unwrap();
    release(&db, c.job_id, &c.token).await.unwrap();
    assert!(matches!(
        release(&db, c.job_id, &c.token).await,
        Err(StoreError::Conflict(_))
    ));
    let c = claim_with(&db, "w", 60_000, 1, true)
        .await
        .unwrap()
        .0
        .unwrap();
    let (st, _) = fail(&db, c.job_id, &c.token, "boom", 2).await.unwrap();
    assert_eq!(st, JobState::Queued);
    let c = claim_with(&db, "w", 60_000, 3, true)
        .await
        .unwrap()
        .0
        .unwrap();
    assert_eq!(c.attempt, 3);
    let (st, eff) = fail(&db, c.job_id, &c.token, "boom again", 4)
        .await
        .unwrap();
    assert_eq!(st, JobState::Failed);
    assert_eq!(eff.completed, vec!["a".to_string()]);
    let j = &list_jobs(&db, "a").await.unwrap()[0];
    assert_eq!((j.attempts, j.lease_count), (2, 3));
    assert_eq!(
        j.last_error.as_deref(),
        Some("boom again; all 2 attempts used")
    );
}

#[tokio::test]
async fn cancel_stops_queued_and_leased_jobs_but_keeps_done_ones() {
    let (_d, db) = db().await;
    insert_search(&db, &search("a", &[1.0, 2.0, 3.0], 1), 0)
        .await
        .unwrap();
    let c1 = claim_with(&db, "w", 60_000, 1, true)
        .await
        .unwrap()
        .0
        .unwrap();
    done(&db, &c1, 1.0).await.unwrap();
    let c2 = claim_with(&db, "w", 60_000, 1, true)
        .await
        .unwrap()
        .0
        .unwrap();
    assert_eq!(cancel(&db, "a", 5).await.unwrap(), SearchState::Cancelled);
    assert_eq!(cancel(&db, "a", 6).await.unwrap(), SearchState::Cancelled);
    assert!(matches!(
        cancel(&db, "zzz", 6).await,
        Err(StoreError::NotFound(_))
    ));
    let hb = heartbeat(&db, c2.job_id, &c2.token, JobPhase::Training, &[], 1_000, 7).await;
    assert!(matches!(hb, Err(StoreError::Conflict(ref m)) if m.contains("cancelled")));
    assert!(claim_with(&db, "w", 60_000, 8, true)
        .await
        .unwrap()
        .0
        .is_none());
    let n = counts(&db, "a").await;
    assert_eq!((n.done, n.cancelled, n.queued, n.leased), (1, 2, 0, 0));
}

#[tokio::test]
async fn completed_search_cannot_be_cancelled() {
    let (_d, db) = db().await;
    insert_search(&db, &search("a", &[1.0], 1), 0)
        .await
        .unwrap();
    let c = claim_with(&db, "w", 60_000, 1, true)
        .await
        .unwrap()
        .0
        .unwrap();
    done(&db, &c, 1.0).await.unwrap();
    assert!(matches!(
        cancel(&db, "a", 2).await,
        Err(StoreError::Conflict(_))
    ));
}

/// Pins the group-commit writer's connection to the pages the file has
/// (SQLite never sets max_page_count below the file's size, so 1 pins it
/// there) or lifts the cap: SQLite then refuses any write that needs a new
/// page with SQLITE_FULL, as on a full disk, and rolls the whole
/// transaction back.
async fn cap_writer_pages(db: &Db, capped: bool) {
    let p = crate::store::WriterPragma::Full(capped);
    db.writer_pragma(p).await.unwrap();
}

#[tokio::test]
async fn full_disk_in_a_group_commit_answers_unavailable_and_every_answer_matches_the_file() {
    let (_d, db) = db().await;
    insert_search(&db, &search("a", &[1.0, 2.0, 3.0], 1), 0)
        .await
        .unwrap();
    let (c, _) = claim_with(&db, "w", 60_000, 1, true).await.unwrap();
    let c = c.unwrap();
    cap_writer_pages(&db, true).await;
    // An upload far larger than any free page, racing two claims into the
    // same group: the upload fails with SQLITE_FULL (SQLite rolls the whole
    // group back), and no other answer may claim what the file does not
    // hold.
    let mut big = Upload::of(output(0.9)).unwrap();
    big.output = (0..400_000u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
        .collect();
    let (up, k1, k2) = tokio::join!(
        complete_with(&db, c.job_id, &c.token, big.clone(), 0.5, 2),
        claim_with(&db, "x", 60_000, 2, true),
        claim_with(&db, "y", 60_000, 2, true),
    );
    let e = up.unwrap_err();
    assert!(
        matches!(&e, StoreError::Unavailable(m) if m.contains("SQLITE_FULL")),
        "{e:?}"
    );
    let mut granted = 0;
    for k in [k1, k2] {
        match k {
            Ok((Some(_), _)) => granted += 1,
            Ok((None, _)) => panic!("two jobs were queued"),
            Err(e) => assert!(matches!(e, StoreError::Unavailable(_)), "{e:?}"),
        }
    }
    let n = counts(&db, "a").await;
    assert_eq!((n.done, n.leased, n.queued), (0, 1 + granted, 2 - granted));
    assert!(outputs(&db, "a").await.unwrap().is_empty());
    // Space returns: the same upload under the same lease is accepted.
    cap_writer_pages(&db, false).await;
    complete_with(&db, c.job_id, &c.token, big, 0.5, 3)
        .await
        .unwrap();
    assert_eq!(counts(&db, "a").await.done, 1);
    let ok: String = sqlx::query_scalar("pragma integrity_check")
        .fetch_one(&db.read)
        .await
        .unwrap();
    assert_eq!(ok, "ok");
}

#[test]
fn lease_verdict_accepts_only_the_current_token_of_a_leased_job() {
    let leased = |t: &str| Some((JobState::Leased, Some(t.to_string())));
    assert!(lease_verdict(1, leased("abcd"), "abcd").is_ok());
    for wrong in ["abce", "abc", "abcde", "", "ABCD"] {
        let e = lease_verdict(1, leased("abcd"), wrong).unwrap_err();
        assert!(matches!(e, StoreError::Conflict(_)), "{wrong}: {e}");
    }
    // The right token no longer counts once the job left `leased`.
    let done = Some((JobState::Done, Some("abcd".to_string())));
    let e = lease_verdict(1, done, "abcd").unwrap_err();
    assert!(e.to_string().contains("already accepted"), "{e}");
    let queued = Some((JobState::Queued, None));
    assert!(matches!(
        lease_verdict(1, queued, "abcd"),
        Err(StoreError::Conflict(_))
    ));
    assert!(matches!(
        lease_verdict(1, None, "abcd"),
        Err(StoreError::NotFound(_))
    ));
}

#[test]
fn eta_is_zero_when_not_running_and_unknown_before_a_job_finishes() {
    let mut r = SearchRow {
        id: "x".into(),
        name: "x".into(),
        status: SearchState::Running,
        trials: 1,
        threshold: 0.5,
        created_at: 0,
        started_at: None,
        finished_at: None,
        points: 1,
        jobs: shared::api::JobCounts {
            queued: 3,
            leased: 1,
            done: 2,
            failed: 0,
            cancelled: 0,
            total: 6,
        },
        converged: 2,
        not_converged: 0,
        shortfall: 0,
        workers_busy: 1,
        mean_job_ms: None,
    };
    assert_eq!(r.eta_secs(), None);
    r.mean_job_ms = Some(2000.0);
    assert_eq!(r.eta_secs(), Some(8.0));
    assert_eq!(r.doc_key(), "running:2:0:6:1");
    r.status = SearchState::Completed;
    assert_eq!(r.eta_secs(), Some(0.0));
    assert_eq!(r.doc_key(), "completed:2:0:6:1");
}

// ------------------------------------------------------------ extensions

fn ext(trials: Option<u32>, w1: &[f64]) -> shared::api::ExtendRequest {
    shared::api::ExtendRequest {
        trials,
        reward_grid: if w1.is_empty() {
            BTreeMap::new()
        } else {
            BTreeMap::from([("w1".to_string(), w1.to_vec())])
        },
    }
}

/// Every stored output of a search as (point, trial, seed, output JSON), to
/// check that an extension leaves them as they were.
async fn output_rows(db: &Db, id: &str) -> Vec<(u32, u32, u64, String)> {
    outputs(db, id)
        .await
        .unwrap()
        .iter()
        .map(|o| {
            (
                o.point_idx,
                o.trial,
                o.seed,
                serde_json::to_string(&o.output).unwrap(),
            )
        })
        .collect()
}

async fn extend_by(
    db: &Db,
    id: &str,
    req: shared::api::ExtendRequest,
    now: i64,
) -> Result<shared::api::Extended, DomainError> {
    let text = serde_json::to_string(&req).unwrap();
    extend(
        db,
        id,
        &text,
        move |g| crate::intake::plan_extension(&req, g),
        now,
    )
    .await
}

/// (w1, trial, seed) of every job of a search.
async fn job_keys(db: &Db, id: &str) -> Vec<(u64, u32, u64)> {
    let mut v: Vec<_> = list_jobs(db, id)
        .await
        .unwrap()
        .iter()
        .map(|j| (j.params["w1"].to_bits(), j.trial, j.seed))
        .collect();
    v.sort_unstable();
    v
}

async fn drain_all(db: &Db, rate: f64) -> Effects {
    let mut last = Effects::default();
    while let (Some(c), _) = claim_with(db, "w", 60_000, 1, true).await.unwrap() {
        last = done(db, &c, rate).await.unwrap().effects;
    }
    last
}

#[tokio::test]
async fn extending_gives_exactly_the_jobs_of_the_larger_search_and_keeps_finished_results() {
    let (_d, db) = db().await;
    insert_search(&db, &search("a", &[1.0, 2.0], 2), 0)
        .await
        .unwrap();
    assert_eq!(drain_all(&db, 1.0).await.completed, vec!["a".to_string()]);
    let before = list_jobs(&db, "a").await.unwrap();
    let outs_before = output_rows(&db, "a").await;

    let d = extend_by(&db, "a", ext(Some(4), &[4.0, 0.5]), 5)
        .await
        .unwrap();
    assert_eq!(
        (
            d.status,
            d.trials,
            d.points,
            d.points_added,
            d.jobs_added,
            d.extension
        ),
        (SearchState::Running, 4, 4, 2, 12, 1)
    );
    let row = search_rows(&db, Some("a")).await.unwrap().pop().unwrap();
    assert_eq!(
        (row.status, row.trials, row.points),
        (SearchState::Running, 4, 4)
    );
    assert_eq!(
        (row.jobs.done, row.jobs.queued, row.jobs.total),
        (4, 12, 16)
    );
    assert_eq!(row.finished_at, None);
    assert_eq!(final_document(&db, "a").await.unwrap(), None);

    // The same (point, trial, seed) set as a search that had 4 values x 4
    // trials from the start.
    insert_search(&db, &search("b", &[0.5, 1.0, 2.0, 4.0], 4), 0)
        .await
        .unwrap();
    assert_eq!(job_keys(&db, "a").await, job_keys(&db, "b").await);
    cancel(&db, "b", 6).await.unwrap();

    // Finished jobs and their results are untouched.
    let after = list_jobs(&db, "a").await.unwrap();
    for j in &before {
        let now = after.iter().find(|k| k.id == j.id).unwrap();
        assert_eq!(now, j);
    }
    let outs_after = output_rows(&db, "a").await;
    assert_eq!(outs_after, outs_before);

    // New jobs go out trial-major after the old ones; the search completes
    // again once they are done.
    let mut seen = Vec::new();
    let mut last = Effects::default();
    while let (Some(c), _) = claim_with(&db, "w", 60_000, 7, true).await.unwrap() {
        seen.push((c.trial, c.point_idx));
        last = done(&db, &c, 1.0).await.unwrap().effects;
    }
    assert_eq!(
        seen,
        vec![
            (0, 2),
            (0, 3),
            (1, 2),
            (1, 3),
            (2, 0),
            (2, 1),
            (2, 2),
            (2, 3),
            (3, 0),
            (3, 1),
            (3, 2),
            (3, 3)
        ]
    );
    assert_eq!(last.completed, vec!["a".to_string()]);
    let row = search_rows(&db, Some("a")).await.unwrap().pop().unwrap();
    assert_eq!((row.status, row.jobs.done), (SearchState::Completed, 16));
}

#[tokio::test]
async fn concurrent_extensions_apply_one_after_the_other_and_duplicate_nothing() {
    let (_d, db) = db().await;
    insert_search(&db, &search("a", &[1.0, 2.0], 2), 0)
        .await
        .unwrap();
    // The same extension twice at once: one wins, the other is refused.
    let (x, y) = tokio::join!(
        extend_by(&db, "a", ext(Some(3), &[3.0]), 1),
        extend_by(&db, "a", ext(Some(3), &[3.0]), 1)
    );
    let oks = [&x, &y].iter().filter(|r| r.is_ok()).count();
    assert_eq!(oks, 1, "{x:?} {y:?}");
    let refused = if x.is_err() { x } else { y }.unwrap_err();
    assert!(
        matches!(refused, DomainError::Invalid(ref m) if m.contains("reward_grid.w1[0]")),
        "{refused}"
    );
    // Different extensions at once: both apply.
    let (p, q, r) = tokio::join!(
        extend_by(&db, "a", ext(None, &[4.0]), 2),
        extend_by(&db, "a", ext(Some(5), &[]), 2),
        extend_by(&db, "a", ext(None, &[5.0]), 2)
    );
    let many = [p, q, r];
    assert!(many.iter().all(|r| r.is_ok()), "{many:?}");
    let keys = job_keys(&db, "a").await;
    let distinct: HashSet<_> = keys.iter().map(|(w, t, _)| (*w, *t)).collect();
    assert_eq!(distinct.len(), keys.len(), "a (point, trial) is duplicated");
    assert_eq!(keys.len(), 5 * 5);
    let row = search_rows(&db, Some("a")).await.unwrap().pop().unwrap();
    assert_eq!((row.points, row.trials), (5, 5));
    let exts: Vec<u32> = many.iter().map(|r| r.as_ref().unwrap().extension).collect();
    let mut sorted = exts.clone();
    sorted.sort_unstable();
    assert_eq!(sorted, vec![2, 3, 4]);
}

#[tokio::test]
async fn cancelled_searches_cannot_grow_and_bad_extensions_change_nothing() {
    let (_d, db) = db().await;
    insert_search(&db, &search("a", &[1.0, 2.0], 2), 0)
        .await
        .unwrap();
    let keys = job_keys(&db, "a").await;
    for (req, field) in [
        (ext(Some(1), &[]), "trials"),
        (ext(Some(2), &[]), "trials"),
        (ext(None, &[2.0]), "reward_grid.w1[0]"),
        (ext(Some(101), &[]), "trials"),
    ] {
        let e = extend_by(&db, "a", req.clone(), 1).await.unwrap_err();
        assert!(
            matches!(e, DomainError::Invalid(ref m) if m.starts_with(field)),
            "{req:?}: {e}"
        );
    }
    let mut other = ext(None, &[]);
    other.reward_grid.insert("tall_reward".into(), vec![1.0]);
    let e = extend_by(&db, "a", other, 1).await.unwrap_err();
    assert!(
        matches!(e, DomainError::Invalid(ref m) if m.starts_with("reward_grid.tall_reward")),
        "{e}"
    );
    assert_eq!(job_keys(&db, "a").await, keys);
    let row = search_rows(&db, Some("a")).await.unwrap().pop().unwrap();
    assert_eq!((row.points, row.trials), (2, 2));

    assert!(matches!(
        extend_by(&db, "nope", ext(Some(3), &[]), 1).await,
        Err(DomainError::NotFound(_))
    ));
    cancel(&db, "a", 2).await.unwrap();
    let e = extend_by(&db, "a", ext(Some(3), &[]), 3).await.unwrap_err();
    assert!(
        matches!(e, DomainError::Conflict(ref m) if m.contains("cancelled")),
        "{e}"
    );
    assert_eq!(job_keys(&db, "a").await, keys);
}

#[tokio::test]
async fn raising_trials_tops_up_replacements_and_raises_the_cap() {
    let (_d, db) = db().await;
    let mut s = search("a", &[1.0], 2);
    s.replace_unconverged = true;
    s.max_trials_per_point = 4;
    insert_search(&db, &s, 0).await.unwrap();
    // Trial 0 does not converge: replacement trial 2; then all converge.
    let c = claim_with(&db, "w", 60_000, 1, true)
        .await
        .unwrap()
        .0
        .unwrap();
    assert!(done(&db, &c, 0.0).await.unwrap().replacement);
    drain_all(&db, 1.0).await;
    assert_eq!(job_keys(&db, "a").await.len(), 3);
    // 2 -> 3 trials: trial 2 exists (a replacement) and 1, 2 converged
    // with trial 0 not: one more replacement (trial 3) is needed.
    let d = extend_by(&db, "a", ext(Some(3), &[]), 2).await.unwrap();
    assert_eq!(d.jobs_added, 1);
    let trials: Vec<u32> = job_keys(&db, "a").await.iter().map(|k| k.1).collect();
    assert_eq!(trials, vec![0, 1, 2, 3]);
    // The cap grew with the trials (4 x 3/2 = 6).
    let cap: i64 = sqlx::query_scalar("select max_trials_per_point from searches where id = 'a'")
        .fetch_one(&db.read)
        .await
        .unwrap();
    assert_eq!(cap, 6);
}

#[tokio::test]
async fn status_counts_kept_by_triggers_match_a_recount_after_every_kind_of_change() {
    let (_d, db) = db().await;
    let mut s = search("a", &[1.0, 2.0], 2);
    s.replace_unconverged = true;
    s.max_trials_per_point = 3;
    insert_search(&db, &s, 0).await.unwrap();
    insert_search(&db, &search("b", &[1.0], 1), 0)
        .await
        .unwrap();
    counts(&db, "a").await;
    let claim = |now| claim_with(&db, "w", 1_000, now, true);
    // Converged, unconverged (a replacement follows), released, failed.
    let c = claim(1).await.unwrap().0.unwrap();
    done(&db, &c, 1.0).await.unwrap();
    counts(&db, &c.search_id).await;
    let c = claim(2).await.unwrap().0.unwrap();
    done(&db, &c, 0.1).await.unwrap();
    counts(&db, &c.search_id).await;
    let c = claim(3).await.unwrap().0.unwrap();
    release(&db, c.job_id, &c.token).await.unwrap();
    counts(&db, &c.search_id).await;
    let c = claim(4).await.unwrap().0.unwrap();
    fail(&db, c.job_id, &c.token, "boom", 5).await.unwrap();
    counts(&db, &c.search_id).await;
    // A lease that expires, then an extension, then a cancellation.
    claim(6).await.unwrap().0.unwrap();
    sweep_expired(&db, 10_000).await.unwrap();
    counts(&db, "a").await;
    counts(&db, "b").await;
    extend_by(&db, "a", ext(Some(3), &[3.0]), 11_000)
        .await
        .unwrap();
    let n = counts(&db, "a").await;
    assert!(n.queued > 0, "{n:?}");
    cancel(&db, "a", 12_000).await.unwrap();
    let n = counts(&db, "a").await;
    assert_eq!((n.queued, n.leased), (0, 0));
    assert!(n.done >= 2 && n.cancelled > 0, "{n:?}");
    drain_all(&db, 1.0).await;
    assert_eq!(counts(&db, "b").await.done, 1);
}

#[tokio::test]
async fn job_curves_read_in_one_query_what_job_detail_reads_per_job() {
    let (_d, db) = db().await;
    insert_search(&db, &search("a", &[1.0, 2.0, 3.0], 1), 0)
        .await
        .unwrap();
    let mut claimed = Vec::new();
    for w in ["w1", "w2", "w3"] {
        claimed.push(
            claim_with(&db, w, 10_000, 0, true)
                .await
                .unwrap()
                .0
                .unwrap(),
        );
    }
    let p = |s: u64| ProgressPoint {
        env_steps: s,
        total_env_steps: 1_000,
        mean_return: Some(s as f64),
        ..ProgressPoint::default()
    };
    // The first and last jobs report progress; the middle one does not.
    for (k, c) in [&claimed[0], &claimed[2]].into_iter().enumerate() {
        let batch: Vec<_> = (0..5).map(|i| p(100 * k as u64 + i)).collect();
        heartbeat(
            &db,
            c.job_id,
            &c.token,
            JobPhase::Training,
            &batch,
            10_000,
            10,
        )
        .await
        .unwrap();
    }
    let ids: Vec<i64> = claimed.iter().rev().map(|c| c.job_id).collect();
    let curves = crate::store::reads::job_curves(&db, &ids).await.unwrap();
    assert_eq!(
        curves.iter().map(|c| c.id).collect::<Vec<_>>(),
        vec![claimed[2].job_id, claimed[0].job_id],
        "asked order, the job without progress left out"
    );
    for curve in &curves {
        let (info, points) = job_detail(&db, curve.id).await.unwrap().unwrap();
        assert_eq!(curve.points, points);
        assert_eq!(
            (curve.point_idx, curve.trial, curve.worker.clone()),
            (info.point_idx, info.trial, info.worker)
        );
    }
    assert!(crate::store::reads::job_curves(&db, &[])
        .await
        .unwrap()
        .is_empty());
}
