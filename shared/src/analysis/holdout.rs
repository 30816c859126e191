//! Leave-one-trial-out recovery and calibration: how well a finished grid
//! identifies the reward value of a policy it has not seen, by every
//! inference method (docs/inference.md#calibration). Built only from the
//! pieces of the result document.
//!
//! Each usable trial in turn plays a synthetic subject: its highest-return
//! kept episode (a raw COM path, exactly as a subject CSV would carry it) is
//! scored with every [`Method`] against the grid rebuilt *without that
//! trial*: its point's weight mean and the posterior are recomputed from
//! the other trials. The grid is resampled once; each case then costs one
//! mean over one point's trials and one posterior fit over the trials'
//! summary vectors, so the report's cost grows linearly with the number of
//! trials times the grid size. A grid of 7 values x 10 trials gives 70
//! recovery cases without training a single extra policy.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::aggregate::{analyse_grid, GridWork, ReportOptions};
use super::calibration::{calibrate_sets, Calibration, SetRule};
use super::inputs::WeightInput;
use super::methods::{posterior_result, score_subject, GridScorer, Method};
use super::observables::Observables;
use super::solvers::SolverKind;

/// One method's answer for one held-out trial.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct CaseMethod {
    /// Label value inferred; `null` if none could be.
    pub inferred: Option<f64>,
    /// Grid steps between the inferred and the true value: 0 is exact, 1 a
    /// neighbour in the sorted values. `null` when nothing was inferred.
    pub steps: Option<u32>,
    /// Probabilities over the grid, aligned with the report's `values`.
    pub probabilities: Vec<f64>,
}

/// One held-out trial.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct HoldOutCase {
    /// The trial's own (true) label value, e.g. its w1.
    pub value: f64,
    /// Trial number within its grid point.
    pub trial: u32,
    /// Training seed.
    pub seed: u64,
    /// The solver variant of the trial.
    #[serde(default)]
    pub solver: String,
    /// Every method's answer.
    pub methods: BTreeMap<Method, CaseMethod>,
}

/// Leave-one-solver-out for one held-out solver variant.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct SolverHoldOut {
    /// The variant held out.
    pub solver: String,
    /// Its kind.
    pub kind: SolverKind,
    /// Its trials scored against the grid of the other variants.
    pub cases: u32,
    /// Per method: coverage, set sizes and gain over those cases.
    pub coverage: BTreeMap<Method, Calibration>,
    /// Per method: cases inferred within one grid step.
    pub within_one: BTreeMap<Method, u32>,
}

/// Tally of one method over all cases.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct HoldOutTally {
    /// Cases whose inferred value is the true one.
    pub exact: u32,
    /// Cases whose inferred value is the true one or a grid neighbour.
    pub within_one: u32,
    /// `confusion[i][j]`: cases of grid value `values[i]` inferred as
    /// `values[j]` (rows true, columns inferred; a case with nothing
    /// inferred is in no column).
    pub confusion: Vec<Vec<u32>>,
}

/// Per grid value: how its own trials were recovered.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct HoldOutRow {
    /// The grid value.
    pub value: f64,
    /// Its held-out cases.
    pub cases: u32,
    /// Of those, per method, inferred within one grid step.
    pub within_one: BTreeMap<Method, u32>,
}

/// The leave-one-trial-out result.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct HoldOutReport {
    /// The grid's label values in increasing order: grid steps count here.
    pub values: Vec<f64>,
    /// Cases scored.
    pub cases: u32,
    /// Per method: exact and within-one counts and the confusion matrix.
    pub methods: BTreeMap<Method, HoldOutTally>,
    /// Per method: coverage of the highest-probability sets at 50 / 80 / 90
    /// / 95 %, mean set sizes, and the log score against uniform.
    pub coverage: BTreeMap<Method, Calibration>,
    /// One row per grid value, in `values` order (index i is `values[i]`).
    pub per_value: Vec<HoldOutRow>,
    /// Every case, grid value by grid value.
    pub case_list: Vec<HoldOutCase>,
    /// Trials or grid points that could not be held out, and why.
    pub notes: Vec<String>,
    /// Leave-one-solver-out, one row per held-out solver variant; empty
    /// for a grid of one solver.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub by_solver: Vec<SolverHoldOut>,
    /// Leave-one-solver-out over the cases of every variant together.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub by_solver_overall: BTreeMap<Method, Calibration>,
    /// The observable set the report's posterior used.
    #[serde(default = "Observables::legacy")]
    pub observables: Observables,
    /// The posterior's identifiability with each observable set the grid
    /// can compute (docs/inference.md#observables), the report's own among
    /// them: then a user sees whether shape or timing carries the
    /// information.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub by_observables: Vec<ObservablesHoldOut>,
}

/// Leave-one-out of the (solver-robust) posterior with one observable set.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct ObservablesHoldOut {
    /// The observable set.
    pub observables: Observables,
    /// Leave-one-trial-out: coverage at 50 / 80 / 90 / 95 %, mean set
    /// sizes and gain.
    pub coverage: Calibration,
    /// Held-out trials whose MAP is the true value.
    pub exact: u32,
    /// Held-out trials whose MAP is within one grid step.
    pub within_one: u32,
    /// Per grid value (the report's `values` order): its cases and how
    /// many were within one grid step.
    pub per_value: Vec<(u32, u32)>,
    /// Leave-one-solver-out per held-out variant (grids of two or more).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub by_solver: Vec<SolverCalibration>,
    /// Leave-one-solver-out over every variant's cases.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub by_solver_overall: Option<Calibration>,
}

/// One held-out variant's calibration under one observable set.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct SolverCalibration {
    /// The variant held out.
    pub solver: String,
    /// Its trials' calibration against the grid of the others.
    pub coverage: Calibration,
    /// Of its trials, inferred within one grid step.
    pub within_one: u32,
}

impl HoldOutReport {
    /// One method's tally.
    pub fn tally(&self, m: Method) -> Option<&HoldOutTally> {
        self.methods.get(&m)
    }
}

/// Runs the leave-one-trial-out recovery over `weights` (see the module
/// docs). A trial is held out when it entered its grid point's means
/// (converged, with a resampleable episode) and its grid point keeps at
/// least one other usable trial, so that the value stays on the grid.
/// Grid points without the label param are skipped with a note; never
/// fails.
pub fn hold_out_recovery(weights: &[WeightInput], opts: &ReportOptions) -> HoldOutReport {
    let mut notes = Vec::new();
    let grid = analyse_grid(weights, opts, &mut notes);
    // Problems of single episodes are the document's notes, not the report's.
    hold_out_from_work(&grid, opts)
}

/// [`hold_out_recovery`] on an already analysed grid.
pub(crate) fn hold_out_from_work(grid: &GridWork, opts: &ReportOptions) -> HoldOutReport {
    let mut notes = Vec::new();
    // Grid order: indices of the labelled points by increasing value.
    let mut order: Vec<usize> = Vec::new();
    for (i, v) in grid.label_values.iter().enumerate() {
        if v.is_some() {
            order.push(i);
        } else {
            notes.push(format!(
                "grid point #{i} has no parameter {:?}; not held out",
                opts.label_param
            ));
        }
    }
    let value = |i: usize| grid.label_values[i].unwrap_or(0.0);
    order.sort_by(|&a, &b| value(a).total_cmp(&value(b)));
    let values: Vec<f64> = order.iter().map(|&i| value(i)).collect();
    let n = values.len();
    let full_means: Vec<Option<&[f64]>> = grid
        .points
        .iter()
        .map(|p| p.summary.mean_x.as_deref())
        .collect();
    let mut case_list = Vec::new();
    for (row, &wi) in order.iter().enumerate() {
        let point = &grid.points[wi];
        let usable: Vec<usize> = (0..point.trials.len())
            .filter(|&t| point.trials[t].summary.used)
            .collect();
        if usable.len() < 2 {
            notes.push(format!(
                "{} = {}: {} usable trial(s); holding one out would take the value off the grid",
                opts.label_param,
                point.summary.value,
                usable.len()
            ));
            continue;
        }
        for &t in &usable {
            let reduced_mean = grid.mean_x_where(wi, |k, _| k == t);
            let mut means = full_means.clone();
            means[wi] = reduced_mean.as_deref();
            let summaries = grid.summaries_without(opts.posterior.observables, Some((wi, t)));
            let scorer = grid.scorer(means, &summaries, opts);
            match held_out_case(grid, &order, row, wi, t, &scorer) {
                Some(case) => case_list.push(case),
                None => notes.push(format!(
                    "{} = {}, trial {}: no kept episode has a finite return; not held out",
                    opts.label_param, point.summary.value, point.trials[t].summary.trial
                )),
            }
        }
    }
    let set_rule = |m: Method| {
        if m.is_posterior() && grid.value_order().is_some() {
            SetRule::Interval
        } else {
            SetRule::HighestProbability
        }
    };
    let cases: Vec<&HoldOutCase> = case_list.iter().collect();
    let coverage = coverage_of(&cases, &values, set_rule);
    let (by_solver, by_solver_overall) =
        leave_one_solver_out(grid, opts, &order, &values, set_rule);
    // Confusion matrices, true grid index x inferred; the tallies and the
    // per-value rows are derived from them (and the case counts) below.
    let grid_index = |v: f64| values.iter().position(|&g| g == v);
    let mut confusion: BTreeMap<Method, Vec<Vec<u32>>> = Method::ALL
        .iter()
        .map(|&m| (m, vec![vec![0u32; n]; n]))
        .collect();
    let mut cases_per_row = vec![0u32; n];
    for c in &case_list {
        let Some(row) = grid_index(c.value) else {
            continue;
        };
        cases_per_row[row] += 1;
        for (m, r) in &c.methods {
            if let Some(j) = r.inferred.and_then(grid_index) {
                confusion.get_mut(m).expect("every method has a matrix")[row][j] += 1;
            }
        }
    }
    let per_value = (0..n)
        .map(|i| HoldOutRow {
            value: values[i],
            cases: cases_per_row[i],
            within_one: confusion.iter().map(|(m, c)| (*m, band(c, i))).collect(),
        })
        .collect();
    let methods = confusion
        .into_iter()
        .map(|(m, c)| {
            let tally = HoldOutTally {
                exact: (0..n).map(|i| c[i][i]).sum(),
                within_one: (0..n).map(|i| band(&c, i)).sum(),
                confusion: c,
            };
            (m, tally)
        })
        .collect();
    let by_observables = by_observables(grid, opts, &order, &values);
    HoldOutReport {
        values,
        cases: u32::try_from(case_list.len()).unwrap_or(u32::MAX),
        methods,
        coverage,
        per_value,
        case_list,
        notes,
        by_solver,
        by_solver_overall,
        observables: opts.posterior.observables,
        by_observables,
    }
}

/// The observable sets the grid can compute: `shape` always, the timing
/// sets when some usable trial's top path has a timing.
fn computable_sets(grid: &GridWork) -> Vec<Observables> {
    let timed = grid
        .points
        .iter()
        .flat_map(|p| &p.trials)
        .any(|w| w.summary.used && w.features().is_some_and(|f| f.timing.is_some()));
    Observables::ALL
        .into_iter()
        .filter(|o| timed || !o.has_profile())
        .collect()
}

/// The posterior's answer for trial `t` of point `wi` under `scorer`,
/// aligned with the sorted values `order`; `None` without one.
fn posterior_case(
    grid: &GridWork,
    order: &[usize],
    wi: usize,
    t: usize,
    scorer: &GridScorer,
) -> Option<Vec<f64>> {
    let held = &grid.points[wi].trials[t];
    let r = posterior_result(held.features(), scorer, &scorer.posterior);
    r.unavailable
        .is_none()
        .then(|| order.iter().map(|&i| r.probabilities[i]).collect())
}

/// [`ObservablesHoldOut`] for every computable set: the posterior alone,
/// by leave-one-trial-out and (with two or more variants)
/// leave-one-solver-out, the same cases as the report's own.
fn by_observables(
    grid: &GridWork,
    opts: &ReportOptions,
    order: &[usize],
    values: &[f64],
) -> Vec<ObservablesHoldOut> {
    let rule = if grid.value_order().is_some() {
        SetRule::Interval
    } else {
        SetRule::HighestProbability
    };
    let n = values.len();
    let mut out = Vec::new();
    for obs in computable_sets(grid) {
        let mut o = opts.clone();
        o.posterior.observables = obs;
        let mut cases: Vec<(usize, Vec<f64>)> = Vec::new();
        let mut per_value = vec![(0u32, 0u32); n];
        let (mut exact, mut within_one) = (0u32, 0u32);
        let mut tally = |row: usize, probs: Vec<f64>, cases: &mut Vec<(usize, Vec<f64>)>| {
            let map = super::costs::argmax_first(&probs).filter(|&j| probs[j] > 0.0);
            let steps = map.map(|j| j.abs_diff(row));
            per_value[row].0 += 1;
            if steps.is_some_and(|s| s <= 1) {
                per_value[row].1 += 1;
                within_one += 1;
            }
            exact += u32::from(steps == Some(0));
            cases.push((row, probs));
        };
        for (row, &wi) in order.iter().enumerate() {
            let point = &grid.points[wi];
            let usable: Vec<usize> = (0..point.trials.len())
                .filter(|&t| point.trials[t].summary.used)
                .collect();
            if usable.len() < 2 {
                continue;
            }
            for &t in &usable {
                let summaries = grid.summaries_without(obs, Some((wi, t)));
                let scorer = grid.posterior_scorer(&summaries, &o);
                if let Some(p) = posterior_case(grid, order, wi, t, &scorer) {
                    tally(row, p, &mut cases);
                }
            }
        }
        let refs: Vec<(usize, &[f64])> = cases.iter().map(|(r, p)| (*r, p.as_slice())).collect();
        let Some(coverage) = calibrate_sets(&refs, n, rule) else {
            continue;
        };
        let (by_solver, by_solver_overall) = if grid.solvers.len() < 2 {
            (Vec::new(), None)
        } else {
            let mut all: Vec<(usize, Vec<f64>)> = Vec::new();
            let mut rows = Vec::new();
            for (v, tag) in grid.solvers.iter().enumerate() {
                let summaries = grid.summaries_where(obs, |_, _, w| w.solver == v);
                let scorer = grid.posterior_scorer(&summaries, &o);
                let mut mine: Vec<(usize, Vec<f64>)> = Vec::new();
                for (row, &wi) in order.iter().enumerate() {
                    if summaries[wi].is_empty() {
                        continue;
                    }
                    for (t, w) in grid.points[wi].trials.iter().enumerate() {
                        if w.solver == v && w.summary.used {
                            if let Some(p) = posterior_case(grid, order, wi, t, &scorer) {
                                mine.push((row, p));
                            }
                        }
                    }
                }
                let refs: Vec<(usize, &[f64])> =
                    mine.iter().map(|(r, p)| (*r, p.as_slice())).collect();
                if let Some(coverage) = calibrate_sets(&refs, n, rule) {
                    let within = mine
                        .iter()
                        .filter(|(row, p)| {
                            super::costs::argmax_first(p)
                                .filter(|&j| p[j] > 0.0)
                                .is_some_and(|j| j.abs_diff(*row) <= 1)
                        })
                        .count();
                    rows.push(SolverCalibration {
                        solver: tag.name.clone(),
                        coverage,
                        within_one: u32::try_from(within).unwrap_or(u32::MAX),
                    });
                }
                all.extend(mine);
            }
            let refs: Vec<(usize, &[f64])> = all.iter().map(|(r, p)| (*r, p.as_slice())).collect();
            (rows, calibrate_sets(&refs, n, rule))
        };
        out.push(ObservablesHoldOut {
            observables: obs,
            coverage,
            exact,
            within_one,
            per_value,
            by_solver,
            by_solver_overall,
        });
    }
    out
}

/// Cases of row `i` of a confusion matrix inferred within one grid step.
fn band(m: &[Vec<u32>], i: usize) -> u32 {
    let n = m.len();
    (i.saturating_sub(1)..(i + 2).min(n)).map(|j| m[i][j]).sum()
}

/// Trial `t` of point `wi` (at `row` of the sorted values `order`) scored
/// as a subject with every method against `scorer`; `None` when it has no
/// top path.
fn held_out_case(
    grid: &GridWork,
    order: &[usize],
    row: usize,
    wi: usize,
    t: usize,
    scorer: &GridScorer,
) -> Option<HoldOutCase> {
    let held = &grid.points[wi].trials[t];
    let path = held.top_path()?;
    // Only a path of the wrong length fails, and resampled paths all have
    // the same length.
    let results = score_subject(path, held.features(), scorer).ok()?;
    let values: Vec<f64> = order
        .iter()
        .map(|&i| grid.label_values[i].unwrap_or(0.0))
        .collect();
    let methods = results
        .into_iter()
        .map(|(m, r)| {
            let col = r.inferred.and_then(|v| values.iter().position(|&g| g == v));
            let case = CaseMethod {
                inferred: r.inferred,
                steps: col.map(|j| u32::try_from(j.abs_diff(row)).unwrap_or(u32::MAX)),
                probabilities: order.iter().map(|&i| r.probabilities[i]).collect(),
            };
            (m, case)
        })
        .collect();
    Some(HoldOutCase {
        value: grid.points[wi].summary.value,
        trial: held.summary.trial,
        seed: held.summary.seed,
        solver: held.summary.solver.name.clone(),
        methods,
    })
}

/// Every method's calibration over `cases` against the sorted `values`.
fn coverage_of(
    cases: &[&HoldOutCase],
    values: &[f64],
    set_rule: impl Fn(Method) -> SetRule,
) -> BTreeMap<Method, Calibration> {
    let grid_index = |v: f64| values.iter().position(|&g| g == v);
    Method::ALL
        .iter()
        .filter_map(|&m| {
            let scored: Vec<(usize, &[f64])> = cases
                .iter()
                .filter_map(|c| {
                    let truth = grid_index(c.value)?;
                    Some((truth, c.methods.get(&m)?.probabilities.as_slice()))
                })
                .collect();
            Some((m, calibrate_sets(&scored, values.len(), set_rule(m))?))
        })
        .collect()
}

/// Leave-one-solver-out (docs/inference.md#leave-one-solver-out): for each
/// solver variant of a grid with two or more, the grid is rebuilt without
/// any of its trials and each of its usable trials is scored against the
/// rest, as a path from a solver the grid has never seen. Empty for a grid
/// of one solver.
fn leave_one_solver_out(
    grid: &GridWork,
    opts: &ReportOptions,
    order: &[usize],
    values: &[f64],
    set_rule: impl Fn(Method) -> SetRule + Copy,
) -> (Vec<SolverHoldOut>, BTreeMap<Method, Calibration>) {
    if grid.solvers.len() < 2 {
        return (Vec::new(), BTreeMap::new());
    }
    let mut all: Vec<HoldOutCase> = Vec::new();
    let mut rows = Vec::new();
    for (v, tag) in grid.solvers.iter().enumerate() {
        let means_owned: Vec<Option<Vec<f64>>> = (0..grid.points.len())
            .map(|i| grid.mean_x_where(i, |_, w| w.solver == v))
            .collect();
        let means: Vec<Option<&[f64]>> = means_owned.iter().map(|m| m.as_deref()).collect();
        let summaries = grid.summaries_where(opts.posterior.observables, |_, _, w| w.solver == v);
        let scorer = grid.scorer(means, &summaries, opts);
        let mut mine = Vec::new();
        for (row, &wi) in order.iter().enumerate() {
            // A point the other solvers never reached cannot be recovered
            // by them; its trials are not scored.
            if means_owned[wi].is_none() {
                continue;
            }
            let point = &grid.points[wi];
            for (t, w) in point.trials.iter().enumerate() {
                if w.solver == v && w.summary.used {
                    mine.extend(held_out_case(grid, order, row, wi, t, &scorer));
                }
            }
        }
        let refs: Vec<&HoldOutCase> = mine.iter().collect();
        let within_one = Method::ALL
            .iter()
            .map(|&m| {
                let k = mine
                    .iter()
                    .filter(|c| {
                        c.methods
                            .get(&m)
                            .and_then(|r| r.steps)
                            .is_some_and(|s| s <= 1)
                    })
                    .count();
                (m, u32::try_from(k).unwrap_or(u32::MAX))
            })
            .collect();
        rows.push(SolverHoldOut {
            solver: tag.name.clone(),
            kind: tag.kind,
            cases: u32::try_from(mine.len()).unwrap_or(u32::MAX),
            coverage: coverage_of(&refs, values, set_rule),
            within_one,
        });
        all.extend(mine);
    }
    let refs: Vec<&HoldOutCase> = all.iter().collect();
    (rows, coverage_of(&refs, values, set_rule))
}

/// The report as a plain-text table for a terminal: per method the
/// recovery counts, the confusion matrix and the calibration table.
pub fn hold_out_table(r: &HoldOutReport, label: &str) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    let pct = |k: u32, n: u32| {
        if n == 0 {
            "-".to_string()
        } else {
            format!("{:.0} %", 100.0 * f64::from(k) / f64::from(n))
        }
    };
    let summary: Vec<String> = r
        .methods
        .iter()
        .map(|(m, t)| {
            format!(
                "by {} {} exact, {} within one grid step ({})",
                m.title(),
                t.exact,
                t.within_one,
                pct(t.within_one, r.cases)
            )
        })
        .collect();
    let _ = writeln!(
        out,
        "leave-one-trial-out recovery: {} cases; {}",
        r.cases,
        summary.join("; ")
    );
    for (m, t) in &r.methods {
        let _ = writeln!(
            out,
            "\n{} method, true {label} (rows) x inferred (columns):",
            m.title()
        );
        let _ = write!(out, "{:>8}", "");
        for v in &r.values {
            let _ = write!(out, "{v:>6}");
        }
        let _ = writeln!(out, "   within one");
        for (i, v) in r.values.iter().enumerate() {
            let _ = write!(out, "{v:>8}");
            for c in &t.confusion[i] {
                let _ = write!(out, "{c:>6}");
            }
            let p = &r.per_value[i];
            let k = p.within_one.get(m).copied().unwrap_or(0);
            let _ = writeln!(out, "   {k}/{}", p.cases);
        }
    }
    if !r.coverage.is_empty() {
        let _ = writeln!(
            out,
            "\ncalibration of the highest-probability sets (observed coverage, mean set size):"
        );
        let _ = write!(out, "{:<22}", "method");
        for l in super::calibration::COVERAGE_LEVELS {
            let _ = write!(out, "{:>14}", format!("{:.0} %", l * 100.0));
        }
        let _ = writeln!(out, "{:>12}", "gain (nats)");
        for (m, c) in &r.coverage {
            let _ = write!(out, "{:<22}", m.title());
            for l in &c.levels {
                let _ = write!(
                    out,
                    "{:>14}",
                    format!("{:.2} ({:.1})", l.coverage, l.mean_set_size)
                );
            }
            let _ = writeln!(out, "{:>12.2}", c.gain_nats);
        }
        let _ = writeln!(
            out,
            "gain: mean log probability of the true value minus log(1/{}) = {:.2}",
            r.values.len(),
            -(r.values.len().max(1) as f64).ln()
        );
    }
    if !r.by_solver.is_empty() {
        let _ = writeln!(
            out,
            "\nleave-one-solver-out: each variant's trials against the grid of the others \
             (coverage at 50 / 80 / 90 / 95 %, mean 90 % set size, gain in nats, within one step):"
        );
        let rows = r
            .by_solver
            .iter()
            .map(|b| (b.solver.as_str(), &b.coverage, Some(&b.within_one), b.cases))
            .chain(std::iter::once((
                "all",
                &r.by_solver_overall,
                None,
                r.by_solver.iter().map(|b| b.cases).sum(),
            )));
        for (solver, coverage, within, cases) in rows {
            for m in [Method::Posterior, Method::PosteriorOneSolver] {
                let Some(c) = coverage.get(&m) else { continue };
                let levels: Vec<String> = c
                    .levels
                    .iter()
                    .map(|l| format!("{:.2}", l.coverage))
                    .collect();
                let size = c.at(0.9).map_or(0.0, |l| l.mean_set_size);
                let within = within
                    .and_then(|w| w.get(&m))
                    .map_or("-".to_string(), |k| format!("{k}/{cases}"));
                let _ = writeln!(
                    out,
                    "{solver:<16} {:<22} {}  {size:>4.1}  {:>6.2}  {within}",
                    m.title(),
                    levels.join(" "),
                    c.gain_nats
                );
            }
        }
    }
    if !r.by_observables.is_empty() {
        let _ = writeln!(
            out,
            "\nposterior by observable set (this report's: {}); leave-one-trial-out coverage at \
             50 / 80 / 90 / 95 %, mean 90 % set size, gain in nats, within one step; \
             leave-one-solver-out coverage at 90 %:",
            r.observables
        );
        for o in &r.by_observables {
            let levels: Vec<String> = o
                .coverage
                .levels
                .iter()
                .map(|l| format!("{:.2}", l.coverage))
                .collect();
            let lovo = o
                .by_solver_overall
                .as_ref()
                .and_then(|c| c.at(0.9))
                .map_or("-".to_string(), |l| format!("{:.2}", l.coverage));
            let _ = writeln!(
                out,
                "{:<22} {}  {:>4.1}  {:>6.2}  {}/{}  {lovo}",
                o.observables.key(),
                levels.join(" "),
                set_size_at(&o.coverage, 0.9),
                o.coverage.gain_nats,
                o.within_one,
                o.coverage.cases
            );
        }
    }
    for n in &r.notes {
        let _ = writeln!(out, "note: {n}");
    }
    out
}

/// Mean set size of a calibration at `level`.
pub fn set_size_at(c: &Calibration, level: f64) -> f64 {
    c.levels
        .iter()
        .find(|l| (l.level - level).abs() < 1e-9)
        .map_or(0.0, |l| l.mean_set_size)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::inputs::{EpisodeRecord, TrialInput};
    use crate::test_support::StandUp;
    use std::collections::BTreeMap;

    /// A bulging stand-up: x = amp sin(pi s), z = 0.6 + 0.4 s. After
    /// preprocessing its x is amp / 0.4 * sin(pi s) at the same arc-length
    /// positions up to the bulge's effect on chord length, so the area
    /// difference between two such paths grows with |amp_a - amp_b|.
    fn episode(amp: f64, ret: f64) -> EpisodeRecord {
        StandUp::new(amp).ret(ret).episode()
    }

    /// A converged trial whose best episode bulges by `amp` (a worse one
    /// bulges a little more, so the trial mean is not the top path).
    fn trial(n: u32, amp: f64) -> TrialInput {
        TrialInput {
            trial: n,
            seed: 1000 + u64::from(n),
            final_success_rate: 1.0,
            converged: true,
            episodes: vec![episode(amp, 900.0), episode(amp + 0.002, 800.0)],
            successes_found: 1000,
            successes_wanted: 1000,
            solver: Default::default(),
        }
    }

    fn weight(w1: f64, amps: &[f64]) -> WeightInput {
        WeightInput {
            params: BTreeMap::from([("w1".to_string(), w1)]),
            trials: amps
                .iter()
                .enumerate()
                .map(|(i, &a)| trial(i as u32, a))
                .collect(),
        }
    }

    #[test]
    fn well_separated_grid_recovers_every_trial_exactly() {
        // Given out of order: grid steps follow the values, not the input.
        let grid = [
            weight(4.0, &[0.20, 0.21]),
            weight(1.0, &[0.05, 0.06]),
            weight(2.0, &[0.10, 0.11]),
        ];
        let r = hold_out_recovery(&grid, &ReportOptions::default());
        assert_eq!(r.values, vec![1.0, 2.0, 4.0]);
        assert_eq!(r.cases, 6);
        assert_eq!(
            (
                r.methods[&Method::Area].exact,
                r.methods[&Method::Area].within_one
            ),
            (6, 6)
        );
        assert_eq!(
            r.methods[&Method::Area].confusion,
            vec![vec![2, 0, 0], vec![0, 2, 0], vec![0, 0, 2]]
        );
        assert!(r
            .case_list
            .iter()
            .all(|c| c.methods[&Method::Area].steps == Some(0)));
        assert!(r.notes.is_empty(), "{:?}", r.notes);
    }

    #[test]
    fn held_out_trial_is_scored_without_itself() {
        // w1 = 2 has trials bulging 0.10 and 0.30. With its own trial in the
        // mean (0.20) the 0.10 trial would be nearest w1 = 2 or tie; held
        // out, w1 = 2's mean is 0.30 and w1 = 1's (0.09, 0.11 -> 0.10) is an
        // exact match, so it is inferred as 1: a neighbour, not exact.
        let grid = [
            weight(1.0, &[0.09, 0.11]),
            weight(2.0, &[0.10, 0.30]),
            weight(4.0, &[0.60, 0.62]),
        ];
        let r = hold_out_recovery(&grid, &ReportOptions::default());
        let case = r
            .case_list
            .iter()
            .find(|c| c.value == 2.0 && c.trial == 0)
            .unwrap();
        assert_eq!(case.methods[&Method::Area].inferred, Some(1.0));
        assert_eq!(case.methods[&Method::Area].steps, Some(1));
        // The 0.30 trial: w1 = 2's mean is then 0.10, w1 = 4's 0.61; 0.30 is
        // nearer 0.10 (0.20 away) than 0.61 (0.31 away) -> inferred 2, exact.
        let other = r
            .case_list
            .iter()
            .find(|c| c.value == 2.0 && c.trial == 1)
            .unwrap();
        assert_eq!(other.methods[&Method::Area].inferred, Some(2.0));
    }

    #[test]
    fn a_trial_two_steps_off_is_a_miss_in_the_tally() {
        // w1 = 4's third trial bulges like w1 = 1: inferred 1, two steps off.
        let grid = [
            weight(1.0, &[0.05, 0.06]),
            weight(2.0, &[0.10, 0.11]),
            weight(4.0, &[0.20, 0.21, 0.055]),
        ];
        let r = hold_out_recovery(&grid, &ReportOptions::default());
        let odd = r
            .case_list
            .iter()
            .find(|c| c.value == 4.0 && c.trial == 2)
            .unwrap();
        assert_eq!(
            (
                odd.methods[&Method::Area].inferred,
                odd.methods[&Method::Area].steps
            ),
            (Some(1.0), Some(2))
        );
        assert_eq!(r.methods[&Method::Area].confusion[2][0], 1);
        assert_eq!(r.cases, 7);
        assert_eq!(r.methods[&Method::Area].within_one, 6);
        let row4 = r.per_value.iter().find(|p| p.value == 4.0).unwrap();
        assert_eq!((row4.cases, row4.within_one[&Method::Area]), (3, 2));
        let table = hold_out_table(&r, "w1");
        assert!(table.contains("7 cases"), "{table}");
        assert!(table.contains("6 within one grid step (86 %)"), "{table}");
    }

    #[test]
    fn single_trial_points_and_unconverged_trials_are_not_held_out() {
        let mut grid = vec![weight(1.0, &[0.05]), weight(2.0, &[0.10, 0.11, 0.12])];
        grid[1].trials[2].converged = false;
        let r = hold_out_recovery(&grid, &ReportOptions::default());
        assert_eq!(r.cases, 2, "only w1 = 2's two converged trials");
        assert_eq!(r.per_value[0].cases, 0);
        assert!(r.notes.iter().any(|n| n.contains("w1 = 1: 1 usable")));
        // The single-trial point still competes as a candidate.
        assert_eq!(r.values, vec![1.0, 2.0]);
    }

    #[test]
    fn a_trial_without_a_finite_return_is_skipped_with_a_note() {
        let mut grid = vec![weight(1.0, &[0.05, 0.06, 0.07]), weight(2.0, &[0.10, 0.11])];
        for e in &mut grid[0].trials[1].episodes {
            e.ret = f64::NAN;
        }
        let r = hold_out_recovery(&grid, &ReportOptions::default());
        assert_eq!(r.cases, 4);
        assert!(
            r.notes
                .iter()
                .any(|n| n == "w1 = 1, trial 1: no kept episode has a finite return; not held out"),
            "{:?}",
            r.notes
        );
    }

    #[test]
    fn empty_grid_gives_an_empty_report() {
        let r = hold_out_recovery(&[], &ReportOptions::default());
        assert_eq!(r.cases, 0);
        assert!(r.values.is_empty());
        assert!(hold_out_table(&r, "w1").contains("0 cases"));
    }
}
