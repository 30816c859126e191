//! The result document (docs/science.md#aggregation): per-reward-value aggregation of the trials'
//! kept episodes ([`super::aggregate`]), per-subject costs, rankings and inferred values, and its
//! tidy CSV form. This is what `irlgrid analyze` prints and what the
//! coordinator's REST API serves, so every number in it is finite: a value
//! that cannot be computed is `null` and a human-readable note says why.

use std::fmt::Write as _;

use serde::{Deserialize, Serialize};

use super::aggregate::{analyse_digests, describe, GridWork, ReportOptions, WeightSummary};
use super::digest::{digest_grid, PointDigests};
use super::holdout::{hold_out_from_work, HoldOutReport};
use super::inputs::WeightInput;
use super::methods::{score_subject, GridScorer, Method, MethodResult, MethodResults};
use super::observables::PathFeatures;
use super::preprocess::resample_path;
use super::subjects::{csv_field, SubjectPath};
use super::timing::stand_up_timing;

/// One subject against the grid (docs/science.md#paper-metrics and
/// docs/inference.md). Vectors
/// inside `methods` are indexed like [`ResultDocument::weights`].
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct SubjectSummary {
    /// Subject label.
    pub subject: String,
    /// Resampled x (60 points); `null` if preprocessing failed.
    pub x: Option<Vec<f64>>,
    /// Resampled z (60 points); `null` if preprocessing failed.
    pub z: Option<Vec<f64>>,
    /// Trajectory area; `null` if preprocessing failed.
    pub area: Option<f64>,
    /// Every inference method's answer, keyed by method.
    pub methods: MethodResults,
    /// Why the subject could not be analysed, if it could not.
    pub error: Option<String>,
}

impl SubjectSummary {
    /// One method's result.
    pub fn method(&self, m: Method) -> Option<&MethodResult> {
        self.methods.get(&m)
    }

    /// The value a method inferred.
    pub fn inferred(&self, m: Method) -> Option<f64> {
        self.method(m).and_then(|r| r.inferred)
    }
}

/// The analysis result: grid aggregates, subject matches, and notes on
/// anything skipped (unresampleable episodes, empty grid points, failed
/// subjects, ...).
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct ResultDocument {
    /// Version of the analysis that built the document
    /// ([`ANALYSIS_VERSION`]); a stored document of an older one is rebuilt.
    #[serde(default)]
    pub analysis_version: u32,
    /// One entry per input grid point, in input order.
    pub weights: Vec<WeightSummary>,
    /// One entry per input subject, in input order.
    pub subjects: Vec<SubjectSummary>,
    /// Leave-one-trial-out recovery and calibration of every method on the
    /// grid's own trials (docs/inference.md#calibration); `null` until every
    /// labelled grid point has [`IDENTIFIABILITY_MIN_TRIALS`] usable trials,
    /// unless asked for.
    #[serde(default)]
    pub identifiability: Option<HoldOutReport>,
    /// Human-readable warnings.
    pub notes: Vec<String>,
}

/// Version of the document's shape and methods: 2 added the keyed
/// `methods` (with the posterior) and the identifiability report; 3 the
/// solver variants (per-point solver table, the solver-robust posterior
/// beside the one-solver one, credible intervals, leave-one-solver-out).
pub const ANALYSIS_VERSION: u32 = 3;

/// Usable trials every labelled grid point needs before a partial document
/// carries its identifiability report.
pub const IDENTIFIABILITY_MIN_TRIALS: u32 = 3;

/// When [`build_report_with`] computes the identifiability report.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Identifiability {
    /// Never (scoring subjects only).
    Never,
    /// Once every labelled point has [`IDENTIFIABILITY_MIN_TRIALS`] usable trials.
    WhenReady,
    /// Whenever at least one point can hold a trial out (a finished grid).
    Always,
}

fn failed_subject(name: &str, n_weights: usize, error: String) -> SubjectSummary {
    SubjectSummary {
        subject: name.to_string(),
        x: None,
        z: None,
        area: None,
        methods: Method::ALL
            .iter()
            .map(|&m| (m, MethodResult::unavailable(n_weights, error.clone())))
            .collect(),
        error: Some(error),
    }
}

fn summarise_subject(
    s: &SubjectPath,
    grid: &GridWork,
    scorer: &GridScorer,
    notes: &mut Vec<String>,
) -> SubjectSummary {
    let n = grid.points.len();
    let path = match resample_path(&s.x, &s.z) {
        Ok(p) => p,
        Err(e) => {
            notes.push(format!("subject {:?}: not analysed: {e}", s.subject));
            return failed_subject(&s.subject, n, e.to_string());
        }
    };
    // A subject whose times are unusable keeps its shape-only answers; the
    // reader has already checked that they increase.
    let timing = stand_up_timing(&s.t, &s.x, &s.z).ok();
    let features = PathFeatures::new(&path, timing, scorer.posterior_opts.components);
    let methods = match score_subject(&path, features.as_ref(), scorer) {
        Ok(m) => m,
        Err(e) => {
            notes.push(format!("subject {:?}: costs failed: {e}", s.subject));
            return failed_subject(&s.subject, n, e.to_string());
        }
    };
    for (m, r) in &methods {
        if let Some(i) = r.inferred_index {
            if grid.label_values[i].is_none() {
                notes.push(format!(
                    "subject {:?}: best {} match {} has no label value",
                    s.subject,
                    m.title(),
                    describe(i, &grid.points[i].summary.params)
                ));
            }
        }
    }
    SubjectSummary {
        subject: s.subject.clone(),
        x: Some(path.x),
        z: Some(path.z),
        area: Some(path.area),
        methods,
        error: None,
    }
}

/// Options that failed validation fall back to the defaults, with a note.
fn checked_options<'a>(
    opts: &'a ReportOptions,
    defaults: &'a mut Option<ReportOptions>,
    notes: &mut Vec<String>,
) -> &'a ReportOptions {
    match opts.validate() {
        Ok(()) => opts,
        Err(e) => {
            notes.push(format!("{e}; using the default options instead"));
            defaults.insert(ReportOptions {
                label_param: opts.label_param.clone(),
                ..ReportOptions::default()
            })
        }
    }
}

/// Builds the result document (docs/science.md#aggregation): aggregates every grid point's
/// converged, resampleable trials (trial mean = pointwise mean of its
/// resampled episodes; weight mean = pointwise mean of trial means; SD across
/// trial means; trial area = mean area of its resampled episodes; trial
/// torque usage = mean over its kept episodes; mean and SEM of both across
/// used trials), fits the posterior over the grid (docs/inference.md), then
/// scores each subject with every [`Method`]. The identifiability report is
/// included once every labelled point has [`IDENTIFIABILITY_MIN_TRIALS`]
/// usable trials. Never fails: problems become notes and `null`s. Invalid
/// options fall back to the defaults, with a note.
pub fn build_report(
    weights: &[WeightInput],
    subjects: &[SubjectPath],
    opts: &ReportOptions,
) -> ResultDocument {
    build_report_with(weights, subjects, opts, Identifiability::WhenReady)
}

/// [`build_report`] with an explicit choice of when the identifiability
/// report is computed.
pub fn build_report_with(
    weights: &[WeightInput],
    subjects: &[SubjectPath],
    opts: &ReportOptions,
    identifiability: Identifiability,
) -> ResultDocument {
    build_report_from(&digest_grid(weights), subjects, opts, identifiability)
}

/// [`build_report_with`] from the grid's trial digests
/// ([`super::digest`]): the same document, without the raw episodes.
pub fn build_report_from(
    points: &[PointDigests],
    subjects: &[SubjectPath],
    opts: &ReportOptions,
    identifiability: Identifiability,
) -> ResultDocument {
    let mut notes = Vec::new();
    let mut defaults = None;
    let opts = checked_options(opts, &mut defaults, &mut notes);
    let grid = analyse_digests(points, opts, &mut notes);
    if !subjects.is_empty() && grid.points.iter().all(|p| p.summary.mean_x.is_none()) {
        notes.push("no grid point has a mean path; subjects cannot be matched".to_string());
    }
    let means: Vec<Option<&[f64]>> = grid
        .points
        .iter()
        .map(|p| p.summary.mean_x.as_deref())
        .collect();
    let summaries = grid.summaries_without(opts.posterior.observables, None);
    let scorer = grid.scorer(means, &summaries, opts);
    if let (Err(e), false) = (&scorer.posterior, subjects.is_empty()) {
        notes.push(format!("posterior over the grid not available: {e}"));
    }
    let subject_summaries = subjects
        .iter()
        .map(|s| summarise_subject(s, &grid, &scorer, &mut notes))
        .collect();
    let identifiability = held_out_block(&grid, opts, identifiability);
    ResultDocument {
        analysis_version: ANALYSIS_VERSION,
        weights: grid.points.into_iter().map(|p| p.summary).collect(),
        subjects: subject_summaries,
        identifiability,
        notes,
    }
}

/// The identifiability block of a document over `points`, by itself: what
/// [`build_report_from`] puts in `identifiability` with the same arguments.
/// A running search's coordinator builds it apart from the rest of the
/// document, because it costs far more (a refit per held-out trial).
pub fn identifiability_from(
    points: &[PointDigests],
    opts: &ReportOptions,
    when: Identifiability,
) -> Option<HoldOutReport> {
    let mut defaults = None;
    let opts = checked_options(opts, &mut defaults, &mut Vec::new());
    let grid = analyse_digests(points, opts, &mut Vec::new());
    held_out_block(&grid, opts, when)
}

/// The rule of [`Identifiability`] on an analysed grid.
fn held_out_block(
    grid: &GridWork,
    opts: &ReportOptions,
    when: Identifiability,
) -> Option<HoldOutReport> {
    let ready = grid
        .points
        .iter()
        .zip(&grid.label_values)
        .filter(|(_, v)| v.is_some())
        .all(|(p, _)| p.summary.trials_used >= IDENTIFIABILITY_MIN_TRIALS);
    match when {
        Identifiability::Never => None,
        Identifiability::WhenReady if !ready || grid.points.is_empty() => None,
        _ => Some(hold_out_from_work(grid, opts)).filter(|r| r.cases > 0),
    }
}

/// Identifies the rows of one [`report_to_csv`] group.
struct Row<'a> {
    section: &'a str,
    subject: &'a str,
    param: Option<f64>,
    trial: Option<u32>,
}

/// The CSV being written by [`report_to_csv`].
struct CsvOut(String);

impl CsvOut {
    /// One row; nothing for a `null` value.
    fn put(&mut self, r: &Row, point: Option<usize>, quantity: &str, value: Option<f64>) {
        let Some(v) = value else { return };
        let param = r.param.map(|p| format!("{p:?}")).unwrap_or_default();
        let trial = r.trial.map(|t| t.to_string()).unwrap_or_default();
        let point = point.map(|p| p.to_string()).unwrap_or_default();
        // Writing to a String cannot fail.
        let _ = writeln!(
            self.0,
            "{},{},{param},{trial},{point},{quantity},{v:?}",
            r.section,
            csv_field(r.subject)
        );
    }

    /// One row per point, numbered from 1 as in docs/science.md#paper-metrics.
    fn path(&mut self, r: &Row, quantity: &str, v: &Option<Vec<f64>>) {
        for (k, x) in v.iter().flatten().enumerate() {
            self.put(r, Some(k + 1), quantity, Some(*x));
        }
    }
}

fn identifiability_csv(csv: &mut CsvOut, h: &HoldOutReport) {
    for o in &h.by_observables {
        let r = Row {
            section: "observables",
            subject: o.observables.key(),
            param: None,
            trial: None,
        };
        let c = &o.coverage;
        csv.put(&r, None, "cases", Some(f64::from(c.cases)));
        for l in &c.levels {
            let pct = (l.level * 100.0).round();
            csv.put(&r, None, &format!("coverage_{pct}"), Some(l.coverage));
            csv.put(&r, None, &format!("set_size_{pct}"), Some(l.mean_set_size));
        }
        csv.put(&r, None, "gain_nats", Some(c.gain_nats));
        csv.put(&r, None, "exact", Some(f64::from(o.exact)));
        csv.put(&r, None, "within_one", Some(f64::from(o.within_one)));
        if let Some(lovo) = &o.by_solver_overall {
            for l in &lovo.levels {
                let pct = (l.level * 100.0).round();
                csv.put(
                    &r,
                    None,
                    &format!("solver_coverage_{pct}"),
                    Some(l.coverage),
                );
            }
            csv.put(&r, None, "solver_gain_nats", Some(lovo.gain_nats));
        }
        for (i, (cases, within)) in o.per_value.iter().enumerate() {
            let r = Row {
                param: h.values.get(i).copied(),
                ..r
            };
            csv.put(&r, None, "cases", Some(f64::from(*cases)));
            csv.put(&r, None, "within_one", Some(f64::from(*within)));
        }
    }
    for (m, tally) in &h.methods {
        for (i, row) in tally.confusion.iter().enumerate() {
            let r = Row {
                section: "confusion",
                subject: m.key(),
                param: h.values.get(i).copied(),
                trial: None,
            };
            for (j, c) in row.iter().enumerate() {
                csv.put(&r, Some(j + 1), "cases", Some(f64::from(*c)));
            }
        }
        for p in &h.per_value {
            let r = Row {
                section: "recovery",
                subject: m.key(),
                param: Some(p.value),
                trial: None,
            };
            csv.put(&r, None, "cases", Some(f64::from(p.cases)));
            let within = p.within_one.get(m).copied().map(f64::from);
            csv.put(&r, None, "within_one", within);
        }
    }
    for (m, cal) in &h.coverage {
        let r = Row {
            section: "coverage",
            subject: m.key(),
            param: None,
            trial: None,
        };
        for l in &cal.levels {
            let pct = (l.level * 100.0).round();
            csv.put(&r, None, &format!("coverage_{pct}"), Some(l.coverage));
            csv.put(&r, None, &format!("set_size_{pct}"), Some(l.mean_set_size));
        }
        csv.put(&r, None, "mean_log_prob", Some(cal.mean_log_prob));
        csv.put(&r, None, "gain_nats", Some(cal.gain_nats));
    }
    let held_out = h
        .by_solver
        .iter()
        .map(|b| (b.solver.as_str(), &b.coverage))
        .chain((!h.by_solver_overall.is_empty()).then_some(("all", &h.by_solver_overall)));
    for (solver, coverage) in held_out {
        let r = Row {
            section: "solver_coverage",
            subject: solver,
            param: None,
            trial: None,
        };
        for (m, cal) in coverage {
            let k = m.key();
            csv.put(&r, None, &format!("{k}_cases"), Some(f64::from(cal.cases)));
            for l in &cal.levels {
                let pct = (l.level * 100.0).round();
                csv.put(&r, None, &format!("{k}_coverage_{pct}"), Some(l.coverage));
                csv.put(
                    &r,
                    None,
                    &format!("{k}_set_size_{pct}"),
                    Some(l.mean_set_size),
                );
            }
            csv.put(&r, None, &format!("{k}_gain_nats"), Some(cal.gain_nats));
        }
    }
}

/// Header of [`report_to_csv`].
pub const REPORT_CSV_HEADER: &str = "section,subject,param_value,trial,point,quantity,value";

/// The result document as one tidy (long-format) CSV, one number per row,
/// header [`REPORT_CSV_HEADER`]:
/// - `weight` rows: `param_value` = the label value; scalars (`trials_done`,
///   `trials_converged`, `trials_used`, `shortfall_trials`,
///   `success_rate_mean`, `area_mean`, `area_sem`, `torque_usage_mean`,
///   `torque_usage_sem`, `top_return`) with empty `point`, and the paths
///   `mean_x`, `mean_z`, `sd_x`, `sd_z`, `top_x`, `top_z` with `point`
///   1..60 (1-based, as in docs/science.md#paper-metrics).
/// - `trial` rows: `param_value`, `trial`; `converged` and `used` as 0/1,
///   `final_success_rate`, `area`, `torque_usage`, `successes_found`,
///   `successes_wanted`, `episodes`, `episodes_resampled`.
/// - `subject` rows: `subject`; `area`, `inferred_area`, `inferred_corr`,
///   and `x`, `z` with `point` 1..60.
/// - `subject` rows also carry, per method, `inferred_area`,
///   `inferred_corr`, `inferred_posterior`, and for the posterior
///   `credible_mass`, `credible_size`, `out_of_model` (0/1) and
///   `out_of_model_p`.
/// - `cost` rows: `subject`, `param_value`; per method its score and
///   probabilities: `area_difference` and `ranking_area`, `correlation` and
///   `ranking_corr` (the paper-metric matrices), `log_likelihood` and
///   `posterior`.
/// - `solver` rows: `subject` = the solver variant, `param_value`;
///   `trials_used`, `best_return_mean`, `best_return_max`,
///   `duration_mean`, `area_mean`, `gap_pct` (PPO variants against the
///   optimum). `optimum` rows: `subject` = the optimizer variant,
///   `param_value`; `best_return`, `duration`, `area`.
/// - `solver_coverage` rows (leave-one-solver-out): `subject` = the held-out
///   variant, or `all`; per method `<key>_cases`, `<key>_coverage_50`,
///   `<key>_set_size_50`, ... and `<key>_gain_nats`.
/// - `observables` rows (the posterior with each observable set the grid
///   can compute, docs/inference.md#observables): `subject` = the set
///   (`shape`, `timing`, ...); with empty `param_value` `cases`,
///   `coverage_50`, `set_size_50`, ..., `gain_nats`, `exact`,
///   `within_one`, and for grids of several solver variants
///   `solver_coverage_50`, ... and `solver_gain_nats`
///   (leave-one-solver-out); with `param_value` a grid value, its `cases`
///   and `within_one`.
/// - With an identifiability report, `subject` holds the method key:
///   `confusion` rows (`param_value` the true value, `point` the 1-based
///   index of the inferred value in the report's sorted values, quantity
///   `cases`), `recovery` rows (`param_value`; `cases`, `within_one`) and
///   `coverage` rows (`coverage_50`, `set_size_50`, ... for each level,
///   `mean_log_prob`, `gain_nats`).
///
/// `null` values have no row. Notes, seeds and errors are text and stay in
/// the JSON document only.
pub fn report_to_csv(doc: &ResultDocument) -> String {
    let mut csv = CsvOut(format!("{REPORT_CSV_HEADER}\n"));
    let flag = |b: bool| Some(if b { 1.0 } else { 0.0 });
    for w in &doc.weights {
        let r = Row {
            section: "weight",
            subject: "",
            param: Some(w.value),
            trial: None,
        };
        for (q, v) in [
            ("trials_done", Some(f64::from(w.trials_done))),
            ("trials_converged", Some(f64::from(w.trials_converged))),
            ("trials_used", Some(f64::from(w.trials_used))),
            ("shortfall_trials", Some(f64::from(w.shortfall_trials))),
            ("success_rate_mean", w.success_rate_mean),
            ("area_mean", w.area_mean),
            ("area_sem", w.area_sem),
            ("torque_usage_mean", w.torque_usage_mean),
            ("torque_usage_sem", w.torque_usage_sem),
            ("top_return", w.top_return),
        ] {
            csv.put(&r, None, q, v);
        }
        for sp in &w.solvers {
            let r = Row {
                section: "solver",
                subject: &sp.solver.name,
                param: Some(w.value),
                trial: None,
            };
            for (q, v) in [
                ("trials_used", Some(f64::from(sp.trials_used))),
                ("best_return_mean", sp.best_return_mean),
                ("best_return_max", sp.best_return_max),
                ("duration_mean", sp.duration_mean),
                ("area_mean", sp.area_mean),
                ("gap_pct", sp.gap_pct),
            ] {
                csv.put(&r, None, q, v);
            }
        }
        if let Some(o) = &w.optimum {
            let r = Row {
                section: "optimum",
                subject: &o.solver,
                param: Some(w.value),
                trial: None,
            };
            csv.put(&r, None, "best_return", Some(o.best_return));
            csv.put(&r, None, "duration", o.duration);
            csv.put(&r, None, "area", o.area);
        }
        for (q, v) in [
            ("mean_x", &w.mean_x),
            ("mean_z", &w.mean_z),
            ("sd_x", &w.sd_x),
            ("sd_z", &w.sd_z),
            ("top_x", &w.top_x),
            ("top_z", &w.top_z),
        ] {
            csv.path(&r, q, v);
        }
        for t in &w.trials {
            let r = Row {
                section: "trial",
                subject: "",
                param: Some(w.value),
                trial: Some(t.trial),
            };
            for (q, v) in [
                ("converged", flag(t.converged)),
                ("used", flag(t.used)),
                ("final_success_rate", t.final_success_rate),
                ("area", t.area),
                ("torque_usage", t.torque_usage),
                ("successes_found", Some(f64::from(t.successes_found))),
                ("successes_wanted", Some(f64::from(t.successes_wanted))),
                ("episodes", Some(f64::from(t.episodes))),
                ("episodes_resampled", Some(f64::from(t.episodes_resampled))),
            ] {
                csv.put(&r, None, q, v);
            }
        }
    }
    for s in &doc.subjects {
        let r = Row {
            section: "subject",
            subject: &s.subject,
            param: None,
            trial: None,
        };
        csv.put(&r, None, "area", s.area);
        for (m, res) in &s.methods {
            csv.put(&r, None, m.csv_inferred(), res.inferred);
            if let Some(c) = &res.credible_set {
                csv.put(&r, None, "credible_mass", Some(c.mass));
                csv.put(&r, None, "credible_size", Some(c.indices.len() as f64));
            }
            if let Some(o) = &res.out_of_model {
                csv.put(&r, None, "out_of_model", flag(o.flagged));
                csv.put(&r, None, "out_of_model_p", Some(o.p_value));
            }
        }
        csv.path(&r, "x", &s.x);
        csv.path(&r, "z", &s.z);
        for (i, w) in doc.weights.iter().enumerate() {
            let r = Row {
                section: "cost",
                subject: &s.subject,
                param: Some(w.value),
                trial: None,
            };
            for (m, res) in &s.methods {
                csv.put(
                    &r,
                    None,
                    m.csv_score(),
                    res.scores.get(i).copied().flatten(),
                );
                csv.put(
                    &r,
                    None,
                    m.csv_probability(),
                    res.probabilities.get(i).copied(),
                );
            }
        }
    }
    if let Some(h) = &doc.identifiability {
        identifiability_csv(&mut csv, h);
    }
    csv.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::inputs::{EpisodeRecord, TrialInput};
    use crate::analysis::preprocess::ResampledPath;
    use crate::analysis::solvers::{SolverKind, SolverTag};
    use crate::analysis::Observables;
    use crate::test_support::StandUp;
    use std::collections::BTreeMap;

    /// A bulging stand-up path: x = amp sin(pi s), z = 0.6 + 0.4 s.
    fn episode(amp: f64, ret: f64, torque_usage: f64) -> EpisodeRecord {
        StandUp::new(amp)
            .ret(ret)
            .torque_usage(torque_usage)
            .episode()
    }

    fn broken_episode(torque_usage: f64) -> EpisodeRecord {
        EpisodeRecord {
            com_t: vec![0.0, 0.1, 0.2],
            com_x: vec![0.0, 0.1, 0.0],
            com_z: vec![0.6, 0.8, 1.0],
            ret: 2000.0,
            torque_usage,
            steps: 1,
        }
    }

    fn trial(n: u32, converged: bool, rate: f64, episodes: Vec<EpisodeRecord>) -> TrialInput {
        TrialInput {
            trial: n,
            seed: 1000 + u64::from(n),
            final_success_rate: rate,
            converged,
            episodes,
            successes_found: 1000,
            successes_wanted: 1000,
            solver: Default::default(),
        }
    }

    fn weight(w1: f64, trials: Vec<TrialInput>) -> WeightInput {
        WeightInput {
            params: BTreeMap::from([("w1".to_string(), w1)]),
            trials,
        }
    }

    fn resampled(amp: f64) -> ResampledPath {
        let e = episode(amp, 0.0, 0.0);
        resample_path(&e.com_x, &e.com_z).unwrap()
    }

    fn subject(name: &str, amp: f64) -> SubjectPath {
        StandUp::new(amp).subject(name)
    }

    /// w1 = 1: two used trials, one broken episode, one unconverged trial
    /// with a shortfall; w1 = 4: nothing usable; w1 = 16: one trial.
    fn grid() -> Vec<WeightInput> {
        let mut unconverged = trial(3, false, 0.2, vec![episode(0.9, 999.0, 1000.0)]);
        unconverged.successes_found = 12;
        vec![
            weight(
                1.0,
                vec![
                    trial(
                        1,
                        true,
                        0.9,
                        vec![episode(0.1, 900.0, 10.0), episode(0.2, 950.0, 20.0)],
                    ),
                    trial(
                        2,
                        true,
                        1.0,
                        vec![episode(0.3, 940.0, 40.0), broken_episode(60.0)],
                    ),
                    unconverged,
                ],
            ),
            weight(4.0, vec![trial(1, false, 0.0, vec![])]),
            weight(
                16.0,
                vec![trial(1, true, 0.8, vec![episode(-0.1, 800.0, 5.0)])],
            ),
        ]
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-12
    }

    fn assert_json_close(a: &serde_json::Value, b: &serde_json::Value) {
        use serde_json::Value;
        match (a, b) {
            (Value::Number(x), Value::Number(y)) => {
                let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
                assert!((x - y).abs() <= 1e-15 * x.abs().max(1.0), "{x} vs {y}");
            }
            (Value::Array(x), Value::Array(y)) => {
                assert_eq!(x.len(), y.len());
                x.iter().zip(y).for_each(|(p, q)| assert_json_close(p, q));
            }
            (Value::Object(x), Value::Object(y)) => {
                assert!(x.keys().eq(y.keys()));
                x.values()
                    .zip(y.values())
                    .for_each(|(p, q)| assert_json_close(p, q));
            }
            _ => assert_eq!(a, b),
        }
    }

    /// Two solvers over three points: PPO at amplitudes a + 0.004 t with
    /// returns 900 + t, and an optimizer 0.02 higher in amplitude with
    /// return 1000 + t.
    fn two_solver_grid() -> Vec<WeightInput> {
        let cem = SolverTag {
            name: "cem".into(),
            kind: SolverKind::Optimizer,
        };
        [(1.0, 0.1), (4.0, 0.2), (16.0, 0.3)]
            .iter()
            .map(|&(w1, a)| {
                let mut trials = Vec::new();
                for t in 0..3u32 {
                    let dt = 0.004 * f64::from(t);
                    trials.push(trial(
                        t,
                        true,
                        1.0,
                        vec![episode(a + dt, 900.0 + f64::from(t), 10.0)],
                    ));
                    let mut o = trial(
                        t,
                        true,
                        1.0,
                        vec![episode(a + 0.02 + dt, 1000.0 + f64::from(t), 10.0)],
                    );
                    o.solver = cem.clone();
                    trials.push(o);
                }
                weight(w1, trials)
            })
            .collect()
    }

    #[test]
    fn solver_variants_get_a_table_an_optimum_and_leave_one_solver_out() {
        let doc = build_report_with(
            &two_solver_grid(),
            &[subject("s", 0.21)],
            &ReportOptions::default(),
            Identifiability::Always,
        );
        let w = &doc.weights[1];
        assert_eq!(w.solvers.len(), 2);
        assert_eq!(w.solvers[0].solver, SolverTag::default());
        let opt = w.optimum.as_ref().unwrap();
        assert_eq!((opt.solver.as_str(), opt.best_return), ("cem", 1002.0));
        // PPO's mean best return 901 against 1002.
        let gap = w.solvers[0].gap_pct.unwrap();
        assert!((gap - 100.0 * 101.0 / 1002.0).abs() < 1e-9, "{gap}");
        assert_eq!(w.solvers[1].gap_pct, None);
        assert!((w.solvers[0].duration_mean.unwrap() - 0.8).abs() < 1e-12);
        let h = doc.identifiability.as_ref().unwrap();
        let held: Vec<(&str, u32)> = h
            .by_solver
            .iter()
            .map(|b| (b.solver.as_str(), b.cases))
            .collect();
        assert_eq!(held, vec![("ppo", 9), ("cem", 9)]);
        assert_eq!(h.by_solver_overall[&Method::Posterior].cases, 18);
        assert!(h
            .by_solver_overall
            .contains_key(&Method::PosteriorOneSolver));
        // The subject's credible set is an interval of neighbours.
        let set = doc.subjects[0].methods[&Method::Posterior]
            .credible_set
            .as_ref()
            .unwrap();
        assert!(set.indices.windows(2).all(|p| p[1] == p[0] + 1), "{set:?}");
        // The solver rows reach the CSV.
        let csv = report_to_csv(&doc);
        assert!(csv.contains("solver,ppo,4.0,,,gap_pct,"), "{csv}");
        assert!(csv.contains("optimum,cem,4.0,,,best_return,1002.0"));
        assert!(csv.contains("solver_coverage,cem,,,,posterior_coverage_90,"));
    }

    #[test]
    fn a_second_solver_widens_the_answer_for_a_solver_between_them() {
        // A path between the two solvers' paths at w1 = 4: the one-solver
        // model, which pools both as one, and the solver-robust model
        // agree on the point; the robust one is no more confident.
        let doc = build_report(
            &two_solver_grid(),
            &[subject("s", 0.215)],
            &ReportOptions::default(),
        );
        let p = |m: Method| doc.subjects[0].methods[&m].probabilities[1];
        assert_eq!(doc.subjects[0].inferred(Method::Posterior), Some(4.0));
        assert_eq!(
            doc.subjects[0].inferred(Method::PosteriorOneSolver),
            Some(4.0)
        );
        assert!(p(Method::Posterior) <= p(Method::PosteriorOneSolver) + 1e-12);
    }

    /// A stand-up whose timing is planted: the path of `StandUp::new(amp)`
    /// traversed at times `duration * s^p`, so `p` skews the speed
    /// profile and `duration` sets how long it takes.
    fn timed(amp: f64, duration: f64, p: f64) -> EpisodeRecord {
        let mut e = StandUp::new(amp).sampled(120, duration).episode();
        let last = (e.com_t.len() - 1) as f64;
        e.com_t = (0..e.com_t.len())
            .map(|k| duration * (k as f64 / last).powf(p))
            .collect();
        e
    }

    /// Three values whose stand-ups differ in duration (0.3, 0.45, 0.7 s)
    /// and speed profile, with the same shape at every value: only timing
    /// tells them apart.
    fn timing_grid() -> Vec<WeightInput> {
        [(1.0, 0.3, 0.8), (4.0, 0.45, 1.0), (16.0, 0.7, 1.25)]
            .iter()
            .map(|&(w1, d, p)| {
                // Three unrelated orders of the six trials, so that no two
                // features move together.
                let (amps, ds, ps) = (
                    [3.0, 0.0, 4.0, 1.0, 5.0, 2.0],
                    [0.0, 1.0, 2.0, 3.0, 4.0, 5.0],
                    [2.0, 5.0, 0.0, 3.0, 1.0, 4.0],
                );
                let trials = (0..6u32)
                    .map(|t| {
                        let k = t as usize;
                        let amp = 0.1 + 0.004 * amps[k];
                        let dt = d * (1.0 + 0.02 * (ds[k] - 2.5));
                        let pt = p + 0.015 * (ps[k] - 2.5);
                        trial(t, true, 1.0, vec![timed(amp, dt, pt)])
                    })
                    .collect();
                weight(w1, trials)
            })
            .collect()
    }

    fn timed_subject(name: &str, slow: f64) -> SubjectPath {
        let e = timed(0.105, 0.46, 1.01);
        SubjectPath {
            subject: name.to_string(),
            t: e.com_t.iter().map(|t| slow * t).collect(),
            x: e.com_x,
            z: e.com_z,
        }
    }

    fn with_observables(obs: Observables) -> ReportOptions {
        let mut o = ReportOptions::default();
        o.posterior.observables = obs;
        o
    }

    #[test]
    fn a_slowed_subject_is_out_of_model_by_duration_or_unchanged_by_relative_timing() {
        let subjects = [timed_subject("1x", 1.0), timed_subject("3x", 3.0)];
        let answer = |obs: Observables| {
            let doc = build_report(&timing_grid(), &subjects, &with_observables(obs));
            let post = |i: usize| doc.subjects[i].methods[&Method::Posterior].clone();
            (post(0), post(1))
        };
        // Absolute duration: the recorded stand-up is recovered, the slowed
        // one (1.24 s from onset to standing; the grid 0.25-0.67 s) is flagged
        // and says why.
        for obs in [Observables::Timing, Observables::ShapeTiming] {
            let (fast, slow) = answer(obs);
            assert_eq!(fast.inferred, Some(4.0), "{obs}");
            assert!(!fast.out_of_model.as_ref().unwrap().flagged, "{obs}");
            let oom = slow.out_of_model.unwrap();
            assert!(oom.flagged, "{obs}");
            let reason = oom.reason.unwrap();
            assert!(
                reason.starts_with("duration: this stand-up takes 1.24 s, the grid"),
                "{reason}"
            );
        }
        // Relative timing (and shape): the slowed copy gets the same answer.
        for obs in [
            Observables::RelativeTiming,
            Observables::ShapeRelativeTiming,
            Observables::Shape,
        ] {
            let (fast, slow) = answer(obs);
            assert_eq!(fast.inferred, slow.inferred, "{obs}");
            assert_eq!(fast.credible_set, slow.credible_set, "{obs}");
            for (a, b) in fast.probabilities.iter().zip(&slow.probabilities) {
                assert!((a - b).abs() < 1e-9, "{obs}");
            }
            assert!(!slow.out_of_model.unwrap().flagged, "{obs}");
        }
        // Timing recovers the value; shape, the same at every value, cannot.
        assert_eq!(answer(Observables::RelativeTiming).0.inferred, Some(4.0));
    }

    #[test]
    fn identifiability_is_reported_per_observable_set() {
        let doc = build_report_with(
            &timing_grid(),
            &[],
            &with_observables(Observables::Shape),
            Identifiability::Always,
        );
        let h = doc.identifiability.unwrap();
        assert_eq!(h.observables, Observables::Shape);
        let sets: Vec<Observables> = h.by_observables.iter().map(|o| o.observables).collect();
        assert_eq!(sets, Observables::ALL.to_vec());
        let get = |obs: Observables| {
            h.by_observables
                .iter()
                .find(|o| o.observables == obs)
                .unwrap()
        };
        // The report's own set agrees with its posterior's tally.
        let own = get(Observables::Shape);
        assert_eq!(own.coverage, h.coverage[&Method::Posterior]);
        assert_eq!(own.within_one, h.methods[&Method::Posterior].within_one);
        // Only timing separates the values: every held-out trial exact.
        let timing = get(Observables::Timing);
        assert_eq!(timing.exact, 18);
        assert!(timing.coverage.gain_nats > own.coverage.gain_nats + 0.5);
        assert_eq!(timing.per_value, vec![(6, 6); 3]);
        let csv = report_to_csv(&ResultDocument {
            identifiability: Some(h.clone()),
            ..doc
        });
        assert!(csv.contains("observables,timing,,,,exact,18.0"), "{csv}");
        assert!(csv.contains("observables,shape+timing,16.0,,,within_one,6.0"));
        let text = super::super::holdout::hold_out_table(&h, "w1");
        assert!(text.contains("posterior by observable set (this report's: shape)"));
    }

    #[test]
    fn a_search_stored_without_observables_reads_as_shape() {
        let o: ReportOptions = serde_json::from_str(r#"{"posterior": {"components": 2}}"#).unwrap();
        assert_eq!(o.posterior.observables, Observables::Shape);
        assert_eq!(
            ReportOptions::default().posterior.observables,
            Observables::default()
        );
    }

    #[test]
    fn weight_aggregates_match_hand_computation() {
        let doc = build_report(&grid(), &[], &ReportOptions::default());
        let w = &doc.weights[0];
        assert_eq!(
            (w.trials_done, w.trials_converged, w.trials_used),
            (3, 2, 2)
        );
        assert_eq!(w.shortfall_trials, 1);
        assert_eq!(w.value, 1.0);

        let (p1, p2, p3) = (resampled(0.1), resampled(0.2), resampled(0.3));
        // Trial means: trial 1 averages two episodes, trial 2 has one usable.
        let t1: Vec<f64> = (0..60).map(|k| (p1.x[k] + p2.x[k]) / 2.0).collect();
        let t2 = p3.x.clone();
        let mean_x = w.mean_x.as_ref().unwrap();
        let sd_x = w.sd_x.as_ref().unwrap();
        for k in 0..60 {
            assert!(close(mean_x[k], (t1[k] + t2[k]) / 2.0));
            // Sample SD of two values: |a - b| / sqrt(2).
            assert!(close(sd_x[k], (t1[k] - t2[k]).abs() / 2.0_f64.sqrt()));
        }
        let mean_z = w.mean_z.as_ref().unwrap();
        assert!(close(mean_z[0], 0.0) && close(mean_z[59], 1.0));

        let (a1, a2) = ((p1.area + p2.area) / 2.0, p3.area);
        assert!(close(w.area_mean.unwrap(), (a1 + a2) / 2.0));
        // SEM of two values: (|a - b| / sqrt 2) / sqrt 2.
        assert!(close(w.area_sem.unwrap(), (a1 - a2).abs() / 2.0));
        // Torque: trial 1 (10 + 20) / 2 = 15, trial 2 (40 + 60) / 2 = 50
        // (the broken episode was kept, so its torque counts).
        assert!(close(w.torque_usage_mean.unwrap(), 32.5));
        assert!(close(w.torque_usage_sem.unwrap(), 17.5));
        // Success rate over all done trials, the unconverged one included.
        assert!(close(w.success_rate_mean.unwrap(), (0.9 + 1.0 + 0.2) / 3.0));
        // Top episode: 950 (the unconverged trial's 999 does not count and
        // the broken episode's 2000 has no path).
        assert_eq!(w.top_return, Some(950.0));
        assert_eq!(w.top_x.as_ref(), Some(&p2.x));
        assert_eq!(w.trials.len(), 3);
        assert!(w.trials[0].used && w.trials[1].used && !w.trials[2].used);
        assert_eq!(w.trials[1].episodes, 2);
        assert_eq!(w.trials[1].episodes_resampled, 1);
        assert!(close(w.trials[2].torque_usage.unwrap(), 1000.0));
        assert!(doc
            .notes
            .iter()
            .any(|n| n.contains("w1=1, trial 2: episode 1 not resampled")));
    }

    #[test]
    fn single_trial_weight_has_zero_spread() {
        let doc = build_report(&grid(), &[], &ReportOptions::default());
        let w = &doc.weights[2];
        assert_eq!(w.trials_used, 1);
        assert!(w.sd_x.as_ref().unwrap().iter().all(|v| *v == 0.0));
        assert_eq!(w.area_sem, Some(0.0));
        assert_eq!(w.mean_x.as_ref(), Some(&resampled(-0.1).x));
    }

    #[test]
    fn point_without_usable_trials_has_null_paths_and_stats() {
        let doc = build_report(&grid(), &[], &ReportOptions::default());
        let w = &doc.weights[1];
        assert_eq!(
            (w.trials_done, w.trials_converged, w.trials_used),
            (1, 0, 0)
        );
        assert_eq!(w.mean_x, None);
        assert_eq!(w.sd_z, None);
        assert_eq!(w.area_mean, None);
        assert_eq!(w.torque_usage_sem, None);
        assert_eq!(w.top_x, None);
        assert_eq!(w.success_rate_mean, Some(0.0));
        let json = serde_json::to_value(w).unwrap();
        for key in [
            "mean_x",
            "mean_z",
            "sd_x",
            "sd_z",
            "area_mean",
            "area_sem",
            "top_x",
        ] {
            assert!(json[key].is_null(), "{key}");
        }
        assert!(doc
            .notes
            .iter()
            .any(|n| n.contains("w1=4: no usable trials")));
    }

    #[test]
    fn subjects_are_matched_against_points_with_paths() {
        let subjects = [subject("near w1=1 (synthetic)", 0.21), subject("bad", 0.0)];
        let mut bad = subjects;
        bad[1].x.truncate(3);
        bad[1].z.truncate(3);
        let doc = build_report(&grid(), &bad, &ReportOptions::default());
        let s = &doc.subjects[0];
        assert_eq!(s.error, None);
        assert_eq!(s.x.as_ref(), Some(&resampled(0.21).x));
        let mean_1 = doc.weights[0].mean_x.as_ref().unwrap();
        let mean_16 = doc.weights[2].mean_x.as_ref().unwrap();
        let sx = s.x.as_ref().unwrap();
        let d1: f64 = (0..60).map(|k| (sx[k] - mean_1[k]).abs()).sum();
        let d16: f64 = (0..60).map(|k| (sx[k] - mean_16[k]).abs()).sum();
        assert!(close(s.methods[&Method::Area].scores[0].unwrap(), d1));
        assert_eq!(s.methods[&Method::Area].scores[1], None);
        assert!(close(s.methods[&Method::Area].scores[2].unwrap(), d16));
        assert_eq!(s.methods[&Method::Correlation].scores[1], None);
        assert_eq!(s.methods[&Method::Area].probabilities[1], 0.0);
        assert_eq!(s.methods[&Method::Correlation].probabilities[1], 0.0);
        let e1 = (-30.0 * d1).exp();
        let e16 = (-30.0 * d16).exp();
        assert!(close(
            s.methods[&Method::Area].probabilities[0],
            e1 / (e1 + e16)
        ));
        assert!(close(
            s.methods[&Method::Area].probabilities.iter().sum::<f64>(),
            1.0
        ));
        assert!(close(
            s.methods[&Method::Correlation]
                .probabilities
                .iter()
                .sum::<f64>(),
            1.0
        ));
        assert_eq!(s.inferred(Method::Area), Some(1.0));
        // Both are sine bumps, but w1=16 bulges backwards: rho = -1 there.
        assert_eq!(s.inferred(Method::Correlation), Some(1.0));

        let b = &doc.subjects[1];
        assert!(b.error.as_ref().unwrap().contains("at least 4"));
        assert_eq!(
            (b.x.clone(), b.area, b.inferred(Method::Area)),
            (None, None, None)
        );
        assert_eq!(b.methods[&Method::Area].scores, vec![None; 3]);
        assert_eq!(b.methods[&Method::Area].probabilities, vec![0.0; 3]);
        assert!(doc.notes.iter().any(|n| n.starts_with("subject \"bad\"")));
    }

    #[test]
    fn report_json_round_trips_without_nan() {
        let mut weights = grid();
        // Non-finite inputs must not leak into the document.
        weights[0].trials[0].episodes[0].ret = f64::NAN;
        weights[0].trials[0].final_success_rate = f64::INFINITY;
        weights[2].trials[0].episodes[0].torque_usage = f64::NAN;
        weights[2].params.insert("w2".to_string(), f64::NAN);
        let subjects = [subject("s", 0.2)];
        let doc = build_report(&weights, &subjects, &ReportOptions::default());
        // Every number is finite: the Debug form of the numeric parts (notes
        // are free text and may quote the bad input, "w2=NaN") shows no NaN
        // and no inf.
        let debug = format!("{:?}", (&doc.weights, &doc.subjects));
        assert!(!debug.contains("NaN"));
        for (i, _) in debug.match_indices("inf") {
            let next = debug[i + 3..].chars().next();
            assert!(
                next.is_some_and(|c| c.is_alphanumeric() || c == '_'),
                "infinite value near {}",
                &debug[i.saturating_sub(40)..i + 3]
            );
        }
        // So the JSON holds no null in place of a number: it reads back into
        // the same document (to the last bit or so: serde_json's default float
        // parser is not always correctly rounded).
        let json = serde_json::to_string(&doc).unwrap();
        let back: ResultDocument = serde_json::from_str(&json).unwrap();
        assert_json_close(
            &serde_json::to_value(&back).unwrap(),
            &serde_json::to_value(&doc).unwrap(),
        );
        assert_eq!(doc.weights[0].trials[0].final_success_rate, None);
        assert_eq!(doc.weights[2].torque_usage_mean, None);
        assert!(!doc.weights[2].params.contains_key("w2"));
    }

    #[test]
    fn episode_record_return_field_is_named_return() {
        let json = serde_json::to_value(episode(0.1, 5.0, 1.0)).unwrap();
        assert_eq!(json["return"], 5.0);
        assert!(json.get("ret").is_none());
    }

    #[test]
    fn invalid_gains_fall_back_to_spec_defaults_with_a_note() {
        let opts = ReportOptions {
            k_area: f64::NAN,
            ..ReportOptions::default()
        };
        let doc = build_report(&grid(), &[subject("s", 0.2)], &opts);
        let good = build_report(&grid(), &[subject("s", 0.2)], &ReportOptions::default());
        assert_eq!(doc.subjects, good.subjects);
        assert!(doc.notes[0].contains("k_area"));
    }

    #[test]
    fn missing_label_param_reports_zero_value_and_is_never_inferred() {
        let mut weights = grid();
        weights[0].params = BTreeMap::from([("other".to_string(), 2.0)]);
        let doc = build_report(&weights, &[subject("s", 0.2)], &ReportOptions::default());
        assert_eq!(doc.weights[0].value, 0.0);
        assert_eq!(doc.subjects[0].inferred(Method::Area), None);
        assert!(doc.notes.iter().any(|n| n.contains("has no label value")));
    }

    #[test]
    fn empty_input_gives_empty_document() {
        let doc = build_report(&[], &[], &ReportOptions::default());
        assert!(doc.weights.is_empty() && doc.subjects.is_empty() && doc.notes.is_empty());
        assert_eq!(report_to_csv(&doc), format!("{REPORT_CSV_HEADER}\n"));
    }

    #[test]
    fn report_csv_is_tidy_and_omits_nulls() {
        let doc = build_report(
            &grid(),
            &[subject("a, quoted", 0.2)],
            &ReportOptions::default(),
        );
        let csv = report_to_csv(&doc);
        let mut lines = csv.lines();
        assert_eq!(lines.next(), Some(REPORT_CSV_HEADER));
        let rows: Vec<&str> = lines.collect();
        let count = |prefix: &str| rows.iter().filter(|r| r.starts_with(prefix)).count();
        // w1=1: 60 points for each of six path quantities.
        assert_eq!(count("weight,,1.0,,1,mean_x,"), 1);
        assert_eq!(count("weight,,1.0,,60,top_z,"), 1);
        assert_eq!(count("weight,,1.0,,,trials_done,3.0"), 1);
        // w1=4 has no paths: no mean rows, but its counts are there.
        assert_eq!(count("weight,,4.0,,1,mean_x"), 0);
        assert_eq!(count("weight,,4.0,,,trials_used,0.0"), 1);
        assert_eq!(count("trial,,1.0,2,,episodes_resampled,1.0"), 1);
        assert_eq!(count("subject,\"a, quoted\",,,,inferred_area,1.0"), 1);
        assert_eq!(count("cost,\"a, quoted\",4.0,,,ranking_area,0.0"), 1);
        assert_eq!(count("cost,\"a, quoted\",4.0,,,area_difference"), 0);
        assert_eq!(count("cost,\"a, quoted\",16.0,,,correlation,"), 1);
        for r in &rows {
            let value = r.rsplit(',').next().unwrap();
            assert!(value.parse::<f64>().unwrap().is_finite(), "{r}");
        }
    }
}
