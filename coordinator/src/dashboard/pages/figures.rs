//! The results part of a search page, from its (partial or final) result
//! document: the grid points, the solvers, the paper's figures, the
//! identifiability checks, the inferred value of each subject by every
//! method, the refinement rounds and the analysis' notes. It is also the
//! fragment the refresh script reloads when the job counts change.

use maud::{html, Markup};
use shared::analysis::{Method, ResultDocument, SubjectRefinement, SubjectSummary};
use shared::api::routes::Endpoint;
use shared::api::{Refinement, SearchState};

use super::{figure, opt};
use crate::dashboard::chart::{self, short, ChartId};
use crate::dashboard::MAX_SUBJECT_FIGURES;
use crate::store::queue::SearchRow;

/// Notes listed on the page (the JSON has all).
const MAX_NOTES: usize = 50;

/// The figures of a search from its (partial or final) result document.
pub fn figures(
    r: &SearchRow,
    doc: &ResultDocument,
    label: &str,
    refinement: Option<&Refinement>,
) -> Markup {
    let id = r.id.as_str();
    let partial = r.status != SearchState::Completed;
    let any_trials = doc.weights.iter().any(|w| w.trials_done > 0);
    html! {
        p.links {
            "Results: "
            a href=(Endpoint::Results.path_of(id)) { "JSON" }
            a href=(Endpoint::ResultsCsv.path_of(id)) { "CSV" }
            a href=(Endpoint::Outputs.path_of(id)) { "raw trial outputs (JSON)" }
            @if partial {
                " " span.muted { "(partial while the search runs)" }
            }
        }
        @if !any_trials {
            div.empty { "No results yet: the figures appear here as jobs finish." }
        } @else {
            (grid_section(doc, refinement))
            (solver_section(doc))
            h2 { "Fig. 2 - area and torque usage" }
            (figure(
                id,
                ChartId::Fig2,
                &chart::fig2(doc, label, false),
                &format!("Mean COM-path area and mean torque usage per {label}, error bars +-1 SEM across converged trials."),
            ))
            h2 { "Fig. 3 - trajectories" }
            (figure(
                id,
                ChartId::Fig3,
                &chart::fig3(doc, label, false),
                &format!("Highest-return trajectory and mean of the trial means per {label}, normalized x-z plane (start at the origin, rise 1)."),
            ))
            h2 { "Identifiability" }
            (figure(
                id,
                ChartId::Confusion,
                &chart::confusion(doc, label, false),
                &format!("Every usable trial scored as a subject against the grid rebuilt without it: how often each method recovers its true {label}."),
            ))
            (figure(
                id,
                ChartId::Coverage,
                &chart::coverage(doc, false),
                "How often the 50 / 80 / 90 / 95 % highest-probability sets of each method hold the true value; on the diagonal a method is calibrated (docs/inference.md#calibration).",
            ))
            (solver_holdout_section(doc))
            (observables_section(doc))
            @if doc.subjects.is_empty() {
                h2 { "Subjects" }
                div.empty {
                    "This search has no subjects, so there are no rankings (Figs. 4, 6), subject \
                     fits (Figs. 5, 7) or inferred values. Submit the search with "
                    code { "subjects_csv" } " to get them."
                }
            } @else {
                (subject_sections(id, doc, label, refinement))
            }
        }
        (notes(doc))
    }
}

/// Per grid point: trials, the paper's two observables, success; points
/// added by refinement carry a badge.
fn grid_section(doc: &ResultDocument, refinement: Option<&Refinement>) -> Markup {
    let refined = refined_values(refinement);
    html! {
        h2 { "Grid points" }
        table {
            thead {
                tr {
                    th { "Point" } th.num { "Trials done" } th.num { "Converged" }
                    th.num { "Used" } th.num { "Area" } th.num { "+- SEM" }
                    th.num { "Torque usage" } th.num { "+- SEM" }
                    th.num { "Mean success rate" } th.num { "Shortfall trials" }
                }
            }
            tbody {
                @for w in &doc.weights {
                    tr {
                        td {
                            (chart::point_label(w))
                            @if let Some((_, round)) = refined.iter().find(|(v, _)| *v == w.value) {
                                " "
                                span.badge.refined title={ "added by refinement round " (round) } {
                                    "refined r" (round)
                                }
                            }
                        }
                        td.num { (w.trials_done) }
                        td.num { (w.trials_converged) }
                        td.num { (w.trials_used) }
                        td.num { (opt(w.area_mean)) }
                        td.num { (opt(w.area_sem)) }
                        td.num { (opt(w.torque_usage_mean)) }
                        td.num { (opt(w.torque_usage_sem)) }
                        td.num { (opt(w.success_rate_mean)) }
                        td.num { (w.shortfall_trials) }
                    }
                }
            }
        }
    }
}

/// Everything about the subjects: the rankings, the posterior, the table of
/// inferred values, the refinement, each subject's fit.
fn subject_sections(
    id: &str,
    doc: &ResultDocument,
    label: &str,
    refinement: Option<&Refinement>,
) -> Markup {
    html! {
        h2 { "Figs. 4 and 6 - rankings" }
        (figure(
            id,
            ChartId::Fig4,
            &chart::heatmap(doc, label, Method::Area, false),
            "Softmax over the grid of -K_area x D (area difference); the outlined cell is the inferred value.",
        ))
        (figure(
            id,
            ChartId::Fig6,
            &chart::heatmap(doc, label, Method::Correlation, false),
            "Softmax over the grid of K_corr x rho (correlation); the outlined cell is the inferred value.",
        ))
        h2 { "Posterior over the grid" }
        (figure(
            id,
            ChartId::Posterior,
            &chart::heatmap(doc, label, Method::Posterior, false),
            "Posterior probability of each grid value given the subject's path (docs/inference.md); the outlined cell is the most probable value.",
        ))
        (inferred_table(doc, label))
        @if let Some(r) = refinement {
            (refinement_section(r, label))
        }
        h2 { "Figs. 5 and 7 - subjects against their best-fitting mean paths" }
        @for (i, sub) in doc.subjects.iter().enumerate().take(MAX_SUBJECT_FIGURES) {
            @if let Some(svg) = chart::subject_fit(doc, label, i, false) {
                (figure(
                    id,
                    ChartId::Subject(i),
                    &svg,
                    &format!(
                        "Subject {} (dashed) against the mean path of its inferred {label} by each metric, band +-1 SD across trial means.",
                        sub.subject
                    ),
                ))
            }
        }
        @if doc.subjects.len() > MAX_SUBJECT_FIGURES {
            p.muted {
                "Figures of the first " (MAX_SUBJECT_FIGURES) " of " (doc.subjects.len())
                " subjects are shown; the others are at "
                code { "/searches/" (id) "/charts/subject-N.svg" } "."
            }
        }
    }
}

/// The inferred value of each subject by every method of [`Method::ALL`]
/// (the paper's methods with their score at the value), the posterior's
/// credible set and out-of-model flag, the subject's area and any note.
fn inferred_table(doc: &ResultDocument, label: &str) -> Markup {
    html! {
        h2 { "Inferred " (label) " per subject" }
        table #inferred {
            thead {
                tr {
                    th { "Subject" }
                    @for m in Method::ALL {
                        th.num {
                            @if m.is_posterior() { "MAP " } @else { "Inferred " }
                            (label) " (" (m.title()) ")"
                        }
                        @if !m.is_posterior() {
                            th.num { (m.score_symbol()) " at it" }
                        }
                    }
                    th { "90 % credible set" }
                    th.num { "Subject area" }
                    th { "Note" }
                }
            }
            tbody {
                @for sub in &doc.subjects {
                    (inferred_row(sub))
                }
            }
        }
    }
}

/// One subject's row of [`inferred_table`].
fn inferred_row(sub: &SubjectSummary) -> Markup {
    let post = sub.method(Method::Posterior);
    let set = post
        .and_then(|p| p.credible_set.as_ref())
        .map_or_else(|| "-".to_string(), |c| c.describe());
    let out_of_model = post
        .and_then(|p| p.out_of_model.as_ref())
        .filter(|o| o.flagged);
    let note = sub
        .error
        .as_deref()
        .or_else(|| post.and_then(|p| p.unavailable.as_deref()))
        .unwrap_or_default();
    html! {
        tr {
            td { (sub.subject) }
            @for m in Method::ALL {
                td.num { b { (opt(sub.inferred(m))) } }
                @if !m.is_posterior() {
                    td.num { (opt(chart::best(m, sub).and_then(|i| chart::raw(m, sub, i)))) }
                }
            }
            td.credible {
                (set)
                @if let Some(o) = out_of_model {
                    " "
                    span.badge.out-of-model title={
                        "largest tail probability " (format!("{:.1e}", o.p_value))
                        " is below " (o.threshold) ": the path is implausible under every grid point"
                    } {
                        "out of model"
                        @if let Some(reason) = &o.reason { " (" (reason) ")" }
                    }
                }
            }
            td.num { (opt(sub.area)) }
            td { (note) }
        }
    }
}

/// "How good was the solver here": per grid point, each solver variant's
/// mean best return, duration and area, and each PPO variant's gap to the
/// optimizer's best return (docs/inference.md#solver-quality). Empty for a
/// search of one solver without an optimizer.
fn solver_section(doc: &ResultDocument) -> Markup {
    let many = doc
        .weights
        .iter()
        .any(|w| w.solvers.len() > 1 || w.optimum.is_some());
    html! {
        @if many {
            h2 { "Solvers at each grid point" }
            table #solvers {
                thead {
                    tr {
                        th { "Point" } th { "Solver" } th { "Kind" } th.num { "Trials used" }
                        th.num { "Best return (mean)" } th.num { "Gap to optimum %" }
                        th.num { "Duration s" } th.num { "Area" }
                    }
                }
                tbody {
                    @for w in &doc.weights {
                        @for sp in &w.solvers {
                            tr {
                                td { (chart::point_label(w)) }
                                td { (sp.solver.name) }
                                td { (sp.solver.kind.as_str()) }
                                td.num { (sp.trials_used) }
                                td.num { (opt(sp.best_return_mean)) }
                                td.num { (sp.gap_pct.map_or("-".to_string(), |g| format!("{g:.2}"))) }
                                td.num { (opt(sp.duration_mean)) }
                                td.num { (opt(sp.area_mean)) }
                            }
                        }
                    }
                }
            }
            p.muted {
                "Each trial counts with its best kept episode. The optimizer starts from the \
                 noise-free squat, PPO from noisy starts; a gap of a few per cent is a good solver."
            }
        }
    }
}

/// Leave-one-solver-out calibration (docs/inference.md#leave-one-solver-out):
/// each variant's trials scored against the grid of the other variants.
fn solver_holdout_section(doc: &ResultDocument) -> Markup {
    let Some(h) = doc
        .identifiability
        .as_ref()
        .filter(|h| !h.by_solver.is_empty())
    else {
        return html! {};
    };
    let rows = h
        .by_solver
        .iter()
        .map(|b| (b.solver.as_str(), &b.coverage))
        .chain(std::iter::once(("all", &h.by_solver_overall)));
    html! {
        h3 { "Leave-one-solver-out" }
        table #solver-holdout {
            thead {
                tr {
                    th { "Held-out solver" } th { "Method" } th.num { "Cases" }
                    th.num { "50 %" } th.num { "80 %" } th.num { "90 %" } th.num { "95 %" }
                    th.num { "Mean 90 % set" } th.num { "Gain (nats)" }
                }
            }
            tbody {
                @for (solver, coverage) in rows {
                    @for m in [Method::Posterior, Method::PosteriorOneSolver] {
                        @if let Some(c) = coverage.get(&m) {
                            tr {
                                td { (solver) }
                                td { (m.title()) }
                                td.num { (c.cases) }
                                @for l in &c.levels {
                                    td.num { (format!("{:.2}", l.coverage)) }
                                }
                                td.num {
                                    (format!("{:.1}", c.at(0.9).map_or(0.0, |l| l.mean_set_size)))
                                }
                                td.num { (format!("{:.2}", c.gain_nats)) }
                            }
                        }
                    }
                }
            }
        }
        p.muted {
            "A calibrated posterior holds the held-out solver's true value about as often as \
             each level says: the answer survives a change of solver."
        }
    }
}

/// The posterior's identifiability with each observable set the grid can
/// compute (docs/inference.md#observables): whether shape or timing
/// carries the information for this preset and grid.
fn observables_section(doc: &ResultDocument) -> Markup {
    let Some(h) = doc
        .identifiability
        .as_ref()
        .filter(|h| !h.by_observables.is_empty())
    else {
        return html! {};
    };
    html! {
        h3 { "Evidence: shape or timing" }
        p.muted {
            "This search's posterior uses " b { (h.observables.key()) } ". Leave-one-trial-out \
             coverage of the credible sets, mean 90 % set size, gain and recovery within one \
             grid step, per observable set; with several solver variants, leave-one-solver-out \
             coverage at 90 %."
        }
        table #observables {
            thead {
                tr {
                    th { "Observables" } th.num { "Cases" } th.num { "50 %" }
                    th.num { "80 %" } th.num { "90 %" } th.num { "95 %" }
                    th.num { "Mean 90 % set" } th.num { "Gain (nats)" }
                    th.num { "Within one" } th.num { "Leave-one-solver-out 90 %" }
                }
            }
            tbody {
                @for o in &h.by_observables {
                    @let c = &o.coverage;
                    tr {
                        td { (o.observables.key()) }
                        td.num { (c.cases) }
                        @for l in &c.levels {
                            td.num { (format!("{:.2}", l.coverage)) }
                        }
                        td.num {
                            (format!("{:.1}", shared::analysis::holdout::set_size_at(c, 0.9)))
                        }
                        td.num { (format!("{:.2}", c.gain_nats)) }
                        td.num { (o.within_one) "/" (c.cases) }
                        td.num {
                            (o.by_solver_overall
                                .as_ref()
                                .and_then(|c| c.at(0.9))
                                .map_or("-".to_string(), |l| format!("{:.2}", l.coverage)))
                        }
                    }
                }
            }
        }
    }
}

/// The round of refinement that added each value (`value -> round`).
fn refined_values(refinement: Option<&Refinement>) -> Vec<(f64, u32)> {
    refinement
        .map(|r| {
            r.rounds
                .iter()
                .flat_map(|round| round.added.iter().map(move |&v| (v, round.round + 1)))
                .collect()
        })
        .unwrap_or_default()
}

/// The refinement section: what was asked for, and per subject the
/// estimate and bracketing pair after each round.
fn refinement_section(r: &Refinement, label: &str) -> Markup {
    let Some(spec) = &r.spec else {
        return html! {};
    };
    html! {
        h2 #refinement { "Refinement toward the subjects" }
        p.muted {
            "Up to " (spec.rounds) " rounds, " (spec.trials) " trials per added point, until \
             each subject's two neighbouring candidates are within a ratio of "
            (short(spec.target_ratio)) " (" (r.state) "). "
            a href=(Endpoint::Refinement.path_of(&r.id)) { "JSON" }
        }
        @if r.rounds.is_empty() {
            div.empty { "The first round is decided when the grid has finished." }
        } @else {
            table #refine-rounds {
                thead {
                    tr {
                        th { "Subject" }
                        @for round in &r.rounds {
                            th.num {
                                @if round.round == 0 {
                                    "grid as submitted"
                                } @else {
                                    "after round " (round.round)
                                }
                            }
                        }
                    }
                }
                tbody {
                    @for first in &r.rounds[0].subjects {
                        @let name = first.subject.as_str();
                        tr {
                            td { (name) }
                            @for round in &r.rounds {
                                td.num {
                                    @match round.subjects.iter().find(|x| x.subject == name) {
                                        Some(x) => { (refinement_cell(x)) }
                                        None => { "–" }
                                    }
                                }
                            }
                        }
                    }
                    tr {
                        td { i { "points added" } }
                        @for round in &r.rounds {
                            td.num {
                                @if round.added.is_empty() {
                                    (round.stop.as_deref().unwrap_or("none"))
                                } @else {
                                    (round
                                        .added
                                        .iter()
                                        .map(|&v| format!("{label}={}", short(v)))
                                        .collect::<Vec<_>>()
                                        .join(", "))
                                }
                            }
                        }
                    }
                }
            }
            p.muted {
                "Each cell: the subject's most likely value [the bracketing pair of neighbours] \
                 → the midpoint it asked for."
            }
        }
    }
}

/// One subject's cell of the refinement table: its estimate, the pair of
/// neighbours around it and the midpoint it asked for.
fn refinement_cell(x: &SubjectRefinement) -> Markup {
    html! {
        b { (opt(x.estimate)) }
        @if let (Some(lo), Some(hi)) = (x.lo, x.hi) {
            " [" (short(lo)) ", " (short(hi)) "]"
        }
        @if let Some(m) = x.midpoint {
            " → " (short(m))
        }
    }
}

/// The analysis' notes (the first [`MAX_NOTES`]), folded.
fn notes(doc: &ResultDocument) -> Markup {
    html! {
        @if !doc.notes.is_empty() {
            details.card {
                summary { "Notes from the analysis (" (doc.notes.len()) ")" }
                ul.notes {
                    @for n in doc.notes.iter().take(MAX_NOTES) {
                        li { (n) }
                    }
                    @if doc.notes.len() > MAX_NOTES {
                        li { "... and " (doc.notes.len() - MAX_NOTES) " more (see the JSON)" }
                    }
                }
            }
        }
    }
}
