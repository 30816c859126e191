//! `irlgrid run`: the whole grid on this machine in one command. Starts a
//! coordinator on a local SQLite file with in-process workers, submits the
//! search (default: a reduced paper grid on the shipped synthetic demo
//! subjects), shows progress bars, prints the inferred w1 table, and keeps
//! the coordinator up for browsing until Ctrl-C (or exits with `--exit`).

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use serde_json::{json, Value};
use shared::analysis::ResultDocument;
use shared::api::{JobInfo, JobState, Refinement, SearchState, SearchStatus};
use tokio::sync::watch;

use irlgrid_client::Client;
use shared::api::routes::Endpoint;

use super::client::refused;
use super::coordinator::{init_tracing, runtime, shutdown_signal};
use super::tables::subject_table;
use super::InputError;

/// The shipped synthetic demo subjects (`examples/demo_subjects.csv`, planted
/// values in `examples/demo_subjects.json`), embedded so that `irlgrid run`
/// works from any directory.
pub const DEMO_SUBJECTS_CSV: &str = include_str!("../../examples/demo_subjects.csv");

#[derive(clap::Args, Debug)]
pub struct RunArgs {
    /// Search request JSON (default: the embedded reduced paper grid).
    pub file: Option<PathBuf>,
    /// In-process worker jobs (default: the number of cores).
    #[arg(long, env = "IRLGRID_WORKERS")]
    pub workers: Option<usize>,
    /// Coordinator listen address (falls back to a free port if taken).
    #[arg(long, env = "IRLGRID_BIND", default_value = "127.0.0.1:8080")]
    pub bind: SocketAddr,
    /// SQLite database file.
    #[arg(long, env = "IRLGRID_DB", default_value = "irlgrid-run.db")]
    pub db: PathBuf,
    /// Exit when the search completes instead of serving until Ctrl-C.
    #[arg(long, env = "IRLGRID_EXIT")]
    pub exit: bool,
    /// Also write the finished search's result document (JSON) here.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// The default search: the paper's w1 grid with fewer trials, a smaller
/// training budget and fewer sampled episodes, so that it finishes in
/// minutes on a laptop, scored against the demo subjects. Two solvers, PPO
/// and the trajectory optimizer (a reduced one), so that the answers carry
/// the spread between solvers (docs/inference.md#solver-spread): the demo
/// subjects come from policies trained at another budget on perturbed
/// bodies, which is itself a change of solver. The optimizer skips its
/// stretched searches: under the paper's reward the optimum is a fast
/// stand-up that the restarts find, and stretching (built for the slow
/// optimum of `power`, docs/reward-study.md) would double its time here.
pub fn default_search() -> Value {
    json!({
        "name": "demo: reduced paper grid, two solvers",
        "reward_grid": {"w1": [0.1, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0]},
        "trials": 2,
        "seed": 2024,
        "training": {"env_steps": 1_000_000},
        "sampling": {"successful_episodes": 100, "top_k": 10, "max_attempts": 2000},
        "solvers": [
            {"name": "ppo", "kind": "ppo"},
            {"name": "optimizer", "kind": "optimizer",
             "optimizer": {"population": 192, "elites": 18, "iterations": 150, "restarts": 2,
                           "stretch_rounds": 0}}
        ],
        "subjects_csv": DEMO_SUBJECTS_CSV,
    })
}

fn bar_style(template: &str) -> ProgressStyle {
    ProgressStyle::with_template(template)
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> ")
}

fn params_label(j: &JobInfo) -> String {
    shared::api::point_label(&j.params)
}

/// Polls (every 0.5 s) a completed search whose refinement round is still
/// undecided at most this often before giving up on it.
const STALLED_POLLS: u32 = 120;

/// Polls the search and draws one overall bar plus one bar per running job
/// until the search is no longer running (and, if it refines, until its
/// refinement has settled).
async fn watch_progress(client: &Client, id: &str) -> anyhow::Result<SearchStatus> {
    let multi = MultiProgress::new();
    let overall = multi.add(ProgressBar::new(1));
    overall.set_style(bar_style(
        "{prefix:>8} [{bar:40}] {pos}/{len} jobs  {msg}  ({elapsed_precise})",
    ));
    overall.set_prefix("search");
    let mut bars: HashMap<i64, ProgressBar> = HashMap::new();
    let mut stalled = 0u32;
    loop {
        let s: SearchStatus = client.search(id).await?;
        overall.set_length(s.jobs.total.max(1));
        overall.set_position(s.jobs.done + s.jobs.failed);
        overall.set_message(format!(
            "{} converged, {} not, {} failed{}",
            s.trials_converged,
            s.trials_not_converged,
            s.jobs.failed,
            s.eta_secs
                .filter(|_| s.status == SearchState::Running)
                .map(|e| format!(", eta {e:.0}s"))
                .unwrap_or_default()
        ));
        let jobs: Vec<JobInfo> = client.jobs(id).await?;
        let leased: HashMap<i64, &JobInfo> = jobs
            .iter()
            .filter(|j| j.status == JobState::Leased)
            .map(|j| (j.id, j))
            .collect();
        bars.retain(|jid, b| {
            let keep = leased.contains_key(jid);
            if !keep {
                b.finish_and_clear();
                multi.remove(b);
            }
            keep
        });
        for (jid, j) in &leased {
            let b = bars.entry(*jid).or_insert_with(|| {
                let b = multi.add(ProgressBar::new(1));
                b.set_style(bar_style("{prefix:>8} [{bar:40}] {percent:>3}%  {msg}"));
                b.set_prefix(format!("job {jid}"));
                b
            });
            let (done, total, sr) = match &j.progress {
                Some(p) => (p.env_steps, p.total_env_steps.max(1), p.success_rate),
                None => (0, 1, None),
            };
            b.set_length(total);
            b.set_position(done.min(total));
            let phase = match j.phase {
                Some(shared::api::JobPhase::Sampling) => "sampling",
                _ => "training",
            };
            b.set_message(format!(
                "{} trial {} {phase}{}",
                params_label(j),
                j.trial,
                sr.map(|r| format!(", success {:.0}%", r * 100.0))
                    .unwrap_or_default()
            ));
        }
        // A completed search that refines runs again once its next round
        // is decided: wait for that, or for the refinement to settle.
        let refining =
            s.status == SearchState::Completed && client.refinement(id).await?.state == "pending";
        // A round is decided within a second or so; one that never comes
        // (its build failed, see the coordinator's log) must not hang us.
        stalled = if refining { stalled + 1 } else { 0 };
        if stalled > STALLED_POLLS {
            eprintln!(
                "note: the search completed but its next refinement round was not decided \
                 within {} s; see the coordinator's log",
                STALLED_POLLS / 2
            );
        }
        if s.status != SearchState::Running && (!refining || stalled > STALLED_POLLS) {
            for b in bars.values() {
                b.finish_and_clear();
            }
            overall.finish();
            return Ok(s);
        }
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
}

fn fmt_pm(mean: Option<f64>, sem: Option<f64>) -> String {
    match (mean, sem) {
        (Some(m), Some(s)) => format!("{m:>8.3} ± {s:<7.3}"),
        (Some(m), None) => format!("{m:>8.3}          "),
        _ => format!("{:>8}          ", "-"),
    }
}

/// The per-weight statistics and the inferred w1 of each subject.
pub fn summary_table(doc: &ResultDocument) -> String {
    let mut out = String::new();
    out.push_str(&format!(
        "{:<22} {:>6} {:>9} {:>8}  {:<18} {:<18}\n",
        "point", "trials", "converged", "success", "area (mean ± SEM)", "torque N m s"
    ));
    for w in &doc.weights {
        let label = shared::api::point_label(&w.params);
        out.push_str(&format!(
            "{:<22} {:>6} {:>9} {:>8}  {} {}\n",
            label,
            w.trials_done,
            w.trials_converged,
            w.success_rate_mean
                .map(|s| format!("{:.0}%", s * 100.0))
                .unwrap_or_else(|| "-".into()),
            fmt_pm(w.area_mean, w.area_sem),
            fmt_pm(w.torque_usage_mean, w.torque_usage_sem),
        ));
    }
    out.push_str(&solver_table(doc));
    out.push_str(&subject_table(doc));
    for n in &doc.notes {
        out.push_str(&format!("note: {n}\n"));
    }
    out
}

/// How good each solver was at each point (docs/inference.md#solver-quality):
/// its mean best return and, for PPO, its gap to the optimizer's best; ""
/// for a search of one solver without an optimizer.
pub fn solver_table(doc: &ResultDocument) -> String {
    if !doc
        .weights
        .iter()
        .any(|w| w.solvers.len() > 1 || w.optimum.is_some())
    {
        return String::new();
    }
    let mut out = format!(
        "\n{:<22} {:<16} {:>6} {:>12} {:>8} {:>9} {:>7}\n",
        "point", "solver", "trials", "best return", "gap %", "duration", "area"
    );
    for w in &doc.weights {
        for sp in &w.solvers {
            let num = |v: Option<f64>, digits: usize| {
                v.map_or("-".to_string(), |x| format!("{x:.digits$}"))
            };
            out.push_str(&format!(
                "{:<22} {:<16} {:>6} {:>12} {:>8} {:>9} {:>7}\n",
                shared::api::point_label(&w.params),
                sp.solver.name,
                sp.trials_used,
                num(sp.best_return_mean, 1),
                num(sp.gap_pct, 2),
                num(sp.duration_mean, 2),
                num(sp.area_mean, 3),
            ));
        }
    }
    out
}

pub fn run(args: RunArgs) -> anyhow::Result<()> {
    init_tracing("warn");
    let body: Value = match &args.file {
        Some(f) => {
            let text = std::fs::read_to_string(f)
                .map_err(|e| InputError(format!("cannot read {}: {e}", f.display())))?;
            serde_json::from_str(&text)
                .map_err(|e| InputError(format!("{} is not valid JSON: {e}", f.display())))?
        }
        None => default_search(),
    };
    let workers = args.workers.unwrap_or_else(worker::config::default_jobs);
    if workers == 0 {
        return Err(InputError("--workers must be at least 1".into()).into());
    }
    runtime()?.block_on(async move {
        let mut cfg = coordinator::CoordinatorConfig::new(args.bind, &args.db);
        let running = match coordinator::start(cfg.clone()).await {
            Ok(r) => r,
            Err(e) if format!("{e:#}").contains("binding") => {
                eprintln!("note: {} is taken; using a free port", args.bind);
                cfg.bind = SocketAddr::new(args.bind.ip(), 0);
                coordinator::start(cfg).await?
            }
            Err(e) => return Err(e),
        };
        let url = running.url();
        eprintln!("coordinator at {url} (database {})", args.db.display());
        // The one HTTP client of this command (the in-process workers
        // have their own).
        let client = Client::new(&url, None)?;
        let created = client.submit(&body).await.map_err(refused)?;
        eprintln!(
            "search {} submitted: {} jobs, {workers} worker jobs",
            created.id, created.jobs
        );
        eprintln!("dashboard: {url}/searches/{}", created.id);

        let (stop, stopped) = watch::channel(false);
        let spool = tempfile_dir()?;
        let mut wcfg = worker::WorkerConfig::new(&url);
        wcfg.jobs = workers;
        wcfg.name = "run".into();
        wcfg.spool_dir = spool.clone();
        wcfg.lease_wait_secs = 2;
        let workers_task = tokio::spawn(worker::run(wcfg, stopped));

        let finished = tokio::select! {
            s = watch_progress(&client, &created.id) => Some(s?),
            _ = shutdown_signal() => None,
        };
        let _ = stop.send(true);
        let _ = workers_task.await;
        let _ = std::fs::remove_dir_all(&spool);
        if let Some(s) = finished {
            let doc: ResultDocument = client
                .results(&created.id)
                .await
                .context("reading the result document")?
                .document
                .into_owned();
            if let Some(path) = &args.out {
                std::fs::write(path, serde_json::to_string_pretty(&doc)?)
                    .with_context(|| format!("writing {}", path.display()))?;
            }
            println!("\nsearch {} {}", s.id, s.status.as_str());
            print!("{}", summary_table(&doc));
            let refinement: Refinement = client
                .refinement(&created.id)
                .await
                .context("reading the refinement")?;
            if refinement.spec.is_some() {
                print!("\n{}", super::client::refinement_text(&refinement));
            }
            if !args.exit {
                eprintln!(
                    "\ndashboard: {url}/searches/{id}\nresults:   {results}\nserving until Ctrl-C",
                    id = s.id,
                    results = client.url(Endpoint::Results, Some(&s.id)),
                );
                shutdown_signal().await;
            }
        }
        running.shutdown().await
    })
}

fn tempfile_dir() -> anyhow::Result<PathBuf> {
    let d = std::env::temp_dir().join(format!("irlgrid-run-spool-{}", std::process::id()));
    std::fs::create_dir_all(&d).with_context(|| format!("creating {}", d.display()))?;
    Ok(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_search_carries_the_valid_demo_subjects() {
        let body = default_search();
        let csv = body["subjects_csv"].as_str().expect("subjects_csv is text");
        let subjects = shared::analysis::parse_subjects_csv(csv).expect("demo subjects parse");
        assert!(subjects.len() >= 3, "only {} demo subjects", subjects.len());
        assert!(subjects.iter().all(|s| s.subject.starts_with("synthetic-")));
    }

    #[test]
    fn summary_prints_each_method_and_the_credible_set() {
        use shared::analysis::{
            build_report, parse_subjects_csv, Method, ReportOptions, WeightInput,
        };
        // A two-point grid from the API test fixtures' shape: bulging
        // stand-ups, three trials each.
        let episode = |bulge: f64| {
            shared::test_support::StandUp::new(bulge)
                .sampled(40, 0.39)
                .torque_usage(50.0)
                .steps(8)
                .episode()
        };
        let weights: Vec<WeightInput> = [(0.5, 0.05), (4.0, 0.15)]
            .iter()
            .map(|&(w1, b)| WeightInput {
                params: [("w1".to_string(), w1)].into(),
                trials: (0..3)
                    .map(|t| shared::analysis::TrialInput {
                        trial: t,
                        seed: u64::from(t),
                        final_success_rate: 1.0,
                        converged: true,
                        episodes: vec![episode(b + 0.004 * f64::from(t))],
                        successes_found: 1000,
                        successes_wanted: 1000,
                        solver: Default::default(),
                    })
                    .collect(),
            })
            .collect();
        let body = default_search();
        let subjects = parse_subjects_csv(body["subjects_csv"].as_str().unwrap()).unwrap();
        let doc = build_report(&weights, &subjects[..1], &ReportOptions::default());
        let table = summary_table(&doc);
        for col in [
            "inferred (area difference)",
            "inferred (correlation)",
            "inferred (posterior)",
            "90 % credible set",
            "out of model",
        ] {
            assert!(table.contains(col), "{col} missing:\n{table}");
        }
        let set = doc.subjects[0].methods[&Method::Posterior]
            .credible_set
            .as_ref()
            .unwrap()
            .describe();
        assert!(table.contains(&set), "{set} missing:\n{table}");
    }
}
