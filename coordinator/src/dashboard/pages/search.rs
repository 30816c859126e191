//! `/searches/{id}`: the heading and links, the live part (progress,
//! counts, the workers and their jobs, learning curves; also the fragment
//! the refresh script reloads), the figures (from [`super::figures`]) and
//! the job table.

use maud::{html, Markup};
use shared::api::routes::Endpoint;
use shared::api::{JobState, SearchState};

use super::{
    badge, duration, elapsed, eta, figure, opt, pager, progress_bar, shell, when,
    FIGURES_REFRESH_MS, REFRESH_MS,
};
use crate::dashboard::chart::{short, ChartId};
use crate::dashboard::MAX_LEASED_SHOWN;
use crate::store::queue::SearchRow;
use crate::store::reads::{JobRow, LeasedJob};

/// One number of the stats row.
fn stat(label: &str, value: Markup) -> Markup {
    html! { div.stat { span.muted { (label) } b { (value) } } }
}

/// The live part of a search page: progress, counts, workers, curves.
pub fn live(
    r: &SearchRow,
    leased: &[LeasedJob],
    points: &[String],
    curves_svg: &str,
    curves_live: bool,
    now: i64,
) -> Markup {
    let running = r.status == SearchState::Running;
    let counts = [
        ("Queued", r.jobs.queued),
        ("Running", r.jobs.leased),
        ("Done", r.jobs.done),
        ("Failed", r.jobs.failed),
        ("Cancelled", r.jobs.cancelled),
        ("Workers busy", r.workers_busy),
    ];
    // Only the first MAX_LEASED_SHOWN running jobs are listed.
    let unlisted = (leased.len() as u64 == MAX_LEASED_SHOWN as u64
        && r.jobs.leased > leased.len() as u64)
        .then(|| r.jobs.leased - leased.len() as u64);
    let what = if curves_live {
        "running jobs"
    } else {
        "the latest finished jobs"
    };
    html! {
        div data-running=(running) data-key=(r.doc_key()) {
            div.card { (progress_bar(&r.jobs)) }
            div.stats {
                (stat("Status", badge(r.status.as_str())))
                @for (label, n) in counts {
                    (stat(label, html! { (n) }))
                }
                (stat("Elapsed", html! { (elapsed(r, now)) }))
                (stat("ETA", html! { (eta(r)) }))
                (stat("Trials converged", html! {
                    (r.converged) " " span.muted { "/ " (r.not_converged) " not" }
                }))
                (stat("Sampling shortfall", html! { (r.shortfall) }))
            }
            h2 { "Workers and their jobs" }
            @if leased.is_empty() {
                div.empty { "No job of this search is running now." }
            } @else {
                table {
                    thead {
                        tr {
                            th { "Worker" } th { "Job" } th { "Point" } th.num { "Trial" }
                            th { "Phase" } th { "Training progress" } th.num { "Success rate" }
                            th.num { "Mean return" } th { "Running for" } th { "Lease expires in" }
                        }
                    }
                    tbody {
                        @for (j, p) in leased.iter().zip(points) {
                            (leased_row(j, p, now))
                        }
                    }
                }
                @if let Some(n) = unlisted {
                    p.muted { (n) " more running jobs not listed." }
                }
            }
            h2 { "Learning curves" }
            (figure(
                &r.id,
                ChartId::LearningCurves,
                curves_svg,
                &format!("Success rate and mean return of {what}, from the workers' heartbeats."),
            ))
        }
    }
}

/// One running job: its worker, point, phase and latest heartbeat.
fn leased_row(j: &LeasedJob, point: &str, now: i64) -> Markup {
    let prog = j.progress.as_ref();
    let steps = prog
        .map(|p| {
            let pct = if p.total_env_steps > 0 {
                100.0 * p.env_steps as f64 / p.total_env_steps as f64
            } else {
                0.0
            };
            format!("{} / {} steps ({pct:.0}%)", p.env_steps, p.total_env_steps)
        })
        .unwrap_or_else(|| "–".into());
    let running_for = j.leased_at.map(|t| (now - t) as f64 / 1000.0);
    let expires_in = j.lease_expires_at.map(|t| (t - now).max(0) as f64 / 1000.0);
    html! {
        tr {
            td { (j.worker) }
            td {
                a href=(Endpoint::JobDetail.path_of(j.id)) { (j.id) }
                @if j.attempts > 0 {
                    " " span.muted { "(retry " (j.attempts) ")" }
                }
            }
            td { (point) }
            td.num { (j.trial) }
            td { (j.phase.as_deref().unwrap_or("starting")) }
            td { (steps) }
            td.num { (opt(prog.and_then(|p| p.success_rate))) }
            td.num { (opt(prog.and_then(|p| p.mean_return))) }
            td { (running_for.map_or_else(|| "–".into(), duration)) }
            td { (expires_in.map_or_else(|| "–".into(), duration)) }
        }
    }
}

/// Inputs of [`search_page`].
pub struct SearchPage<'a> {
    /// The search.
    pub row: &'a SearchRow,
    /// [`live`] HTML.
    pub live: Markup,
    /// [`super::figures`] HTML.
    pub figures: Markup,
    /// This page of the job table.
    pub jobs: &'a [JobRow],
    /// Point text of each job.
    pub job_points: &'a [String],
    /// State filter of the job table.
    pub jobs_status: Option<JobState>,
    /// Page of the job table.
    pub jobs_page: i64,
    /// Jobs per page.
    pub jobs_per_page: i64,
    /// Show the logout button.
    pub logout: bool,
}

/// `/searches/{id}`.
pub fn search_page(p: SearchPage) -> Markup {
    let r = p.row;
    let id = r.id.as_str();
    let running = r.status == SearchState::Running;
    // While the search runs, the script reloads the live part (and the
    // figures when the counts change).
    let live_src = running.then(|| format!("/fragments/searches/{id}/live"));
    let body = html! {
        p.muted { a href="/" { "Searches" } " / " (id) }
        h1 { (r.name) " " (badge(r.status.as_str())) }
        p.muted {
            (r.points) " grid points x " (r.trials) " trials, convergence threshold "
            (short(r.threshold)) " | submitted " (when(r.created_at))
            @if let Some(t) = r.started_at { " | started " (when(t)) }
            @if let Some(t) = r.finished_at { " | finished " (when(t)) }
        }
        p.links {
            a href=(Endpoint::SearchStatus.path_of(id)) { "status JSON" }
            a href=(Endpoint::SearchJobs.path_of(id)) { "jobs JSON" }
            a href=(Endpoint::Results.path_of(id)) { "results JSON" }
            a href=(Endpoint::ResultsCsv.path_of(id)) { "results CSV" }
        }
        h2 { "Progress" }
        div #live .live data-src=[live_src] data-every=[running.then_some(REFRESH_MS)]
            data-figures=[running.then_some("figures")] {
            (p.live)
        }
        div #figures data-src={ "/fragments/searches/" (id) "/figures" } data-key=(r.doc_key())
            data-min-interval=(FIGURES_REFRESH_MS) {
            (p.figures)
        }
        (job_table(&p))
    };
    shell(&r.name, p.logout, true, body)
}

/// The job table of a search page: a filter by state, a page of jobs.
fn job_table(p: &SearchPage) -> Markup {
    let r = p.row;
    let filtered_total = match p.jobs_status {
        None => r.jobs.total,
        Some(JobState::Queued) => r.jobs.queued,
        Some(JobState::Leased) => r.jobs.leased,
        Some(JobState::Done) => r.jobs.done,
        Some(JobState::Failed) => r.jobs.failed,
        Some(JobState::Cancelled) => r.jobs.cancelled,
    } as i64;
    let pages = (filtered_total + p.jobs_per_page - 1) / p.jobs_per_page;
    let base = format!("/searches/{}", r.id);
    let page_base = match p.jobs_status {
        Some(st) => format!("{base}?jobs_status={}", st.as_str()),
        None => base.clone(),
    };
    html! {
        h2 #jobs { "Jobs" }
        p.pager {
            "Show: "
            a href={ (base) "#jobs" } { "all (" (r.jobs.total) ")" }
            @for st in JobState::ALL {
                a href={ (base) "?jobs_status=" (st.as_str()) "#jobs" } { (st.as_str()) }
            }
        }
        @if p.jobs.is_empty() {
            div.empty { "No jobs here." }
        } @else {
            table {
                thead {
                    tr {
                        th { "Job" } th { "Point" } th.num { "Trial" } th { "Status" }
                        th { "Worker" } th.num { "Attempts" } th.num { "Final success" }
                        th { "Converged" } th.num { "Successes" } th.num { "Time" }
                        th { "Last error" }
                    }
                }
                tbody {
                    @for (j, pt) in p.jobs.iter().zip(p.job_points) {
                        (job_row(j, pt))
                    }
                }
            }
        }
        (pager(&page_base, "jobs_page", p.jobs_page, pages, "previous", "next"))
    }
}

/// One job of the job table.
fn job_row(j: &JobRow, point: &str) -> Markup {
    let converged = match j.converged {
        Some(true) => "yes",
        Some(false) => "no",
        None => "",
    };
    // The start of the error text: the job's page has all of it.
    let error: String = j
        .last_error
        .as_deref()
        .unwrap_or_default()
        .chars()
        .take(200)
        .collect();
    html! {
        tr {
            td {
                a href=(Endpoint::JobDetail.path_of(j.id)) title={ "seed " (j.seed) } { (j.id) }
            }
            td { (point) }
            td.num { (j.trial) }
            td { (badge(&j.status)) }
            td { (j.worker.as_deref().unwrap_or_default()) }
            td.num { (j.attempts) }
            td.num { (opt(j.final_success_rate)) }
            td { (converged) }
            td.num {
                @if let Some((f, w)) = j.successes { (f) " / " (w) }
            }
            td.num { (j.duration_secs.map(duration).unwrap_or_default()) }
            td { (error) }
        }
    }
}
