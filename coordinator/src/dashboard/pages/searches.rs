//! `/`: every search, newest first, a page at a time; the table is also
//! the fragment the refresh script reloads while a listed search runs.

use maud::{html, Markup};
use shared::api::SearchState;

use super::{badge, elapsed, eta, pager, progress_bar, shell, when, REFRESH_MS};
use crate::store::queue::SearchRow;

/// The search list (refreshed while a listed search runs).
pub fn search_table(rows: &[SearchRow], page: i64, total: i64, per_page: i64, now: i64) -> Markup {
    let running = rows.iter().any(|r| r.status == SearchState::Running);
    let pages = (total + per_page - 1) / per_page;
    html! {
        div data-running=(running) data-key="" {
            @if total == 0 {
                div.empty {
                    "No searches yet. Submit one with " code { "irlgrid submit FILE.json" } ", "
                    code { "POST /api/v1/searches" } ", or start a local one with "
                    code { "irlgrid run" } "."
                }
            } @else if rows.is_empty() {
                div.empty { "No searches on page " (page) ". " a href="/" { "First page" } }
            } @else {
                table {
                    thead {
                        tr {
                            th { "Name" } th { "Status" } th { "Progress" }
                            th.num { "Queued" } th.num { "Running" } th.num { "Done" }
                            th.num { "Failed" } th.num { "Workers" } th { "Submitted" }
                            th { "Elapsed" } th { "ETA" }
                        }
                    }
                    tbody {
                        @for r in rows {
                            tr {
                                td {
                                    a href={ "/searches/" (r.id) } { (r.name) }
                                    div.muted { (r.points) " points x " (r.trials) " trials" }
                                }
                                td { (badge(r.status.as_str())) }
                                td { (progress_bar(&r.jobs)) }
                                td.num { (r.jobs.queued) }
                                td.num { (r.jobs.leased) }
                                td.num { (r.jobs.done) }
                                td.num { (r.jobs.failed) }
                                td.num { (r.workers_busy) }
                                td { (when(r.created_at)) }
                                td { (elapsed(r, now)) }
                                td { (eta(r)) }
                            }
                        }
                    }
                }
                (pager("/", "page", page, pages, "newer", "older"))
            }
        }
    }
}

/// `/`, around the [`search_table`].
pub fn index_page(table: Markup, page: i64, running: bool, logout: bool) -> Markup {
    // While a listed search runs, the script reloads the table.
    let src = running.then(|| format!("/fragments/searches?page={page}"));
    let every = running.then_some(REFRESH_MS * 2);
    let body = html! {
        h1 { "Searches" }
        p.muted { "Reward-parameter searches on this coordinator, newest first." }
        div #searches .live data-src=[src] data-every=[every] { (table) }
    };
    shell("Searches", logout, true, body)
}
