//! The grid's aggregation (docs/science.md#aggregation): each trial's and
//! each point's summary of the inputs ([`super::inputs`]), and the analysed grid ([`GridWork`]: every episode
//! resampled once) that the result document ([`super::report`]) and the
//! leave-one-trial-out report ([`super::holdout`]) are both built from.

use std::collections::BTreeMap;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::costs::{K_AREA, K_CORR};
use super::digest::{digest_grid, DigestedTrial, PointDigests, TopEpisode, TrialDigest};
use super::inputs::WeightInput;
use super::methods::GridScorer;
use super::observables::{Observables, PathFeatures};
use super::posterior::{prior_weights, GridPosterior, PosteriorOptions};
use super::preprocess::ResampledPath;
use super::solvers::{solver_table, OptimumAtPoint, SolverAtPoint, SolverTag, TrialBest};
use super::stats::{mean, mean_sem, pointwise_mean, pointwise_sd};
use super::AnalysisError;

/// Knobs of [`build_report`](super::build_report); defaults are those of docs/science.md#rankings.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default)]
pub struct ReportOptions {
    /// Softmax gain of the area ranking (docs/science.md#rankings: 30).
    pub k_area: f64,
    /// Softmax gain of the correlation ranking (docs/science.md#rankings: 100).
    pub k_corr: f64,
    /// Which param names the inferred value (docs/science.md#reward: "w1").
    pub label_param: String,
    /// The posterior over the grid (docs/inference.md).
    pub posterior: PosteriorOptions,
}

impl Default for ReportOptions {
    fn default() -> Self {
        Self {
            k_area: K_AREA,
            k_corr: K_CORR,
            label_param: "w1".to_string(),
            posterior: PosteriorOptions::default(),
        }
    }
}

impl ReportOptions {
    /// Gains must be finite and non-negative (0 gives a uniform ranking).
    pub fn validate(&self) -> Result<(), AnalysisError> {
        for (name, value) in [("k_area", self.k_area), ("k_corr", self.k_corr)] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(AnalysisError::InvalidOption { name, value });
            }
        }
        self.posterior.validate()
    }
}

/// Per-trial line of a [`WeightSummary`].
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct TrialSummary {
    /// Trial number.
    pub trial: u32,
    /// Training seed.
    pub seed: u64,
    /// Whether training converged.
    pub converged: bool,
    /// Final training success rate; `null` if the input was not finite.
    pub final_success_rate: Option<f64>,
    /// Mean area over the trial's resampled episodes; `null` if none.
    pub area: Option<f64>,
    /// Mean torque usage over the trial's kept episodes; `null` if none.
    pub torque_usage: Option<f64>,
    /// Successful episodes found while sampling.
    pub successes_found: u32,
    /// Successful episodes wanted.
    pub successes_wanted: u32,
    /// Kept episodes received.
    pub episodes: u32,
    /// Kept episodes whose path could be resampled.
    pub episodes_resampled: u32,
    /// Whether this trial entered the means (converged and resampled).
    pub used: bool,
    /// The solver variant that produced it.
    #[serde(default)]
    pub solver: SolverTag,
}

/// Aggregate of one reward-grid point (docs/science.md#aggregation). Path and statistic fields
/// are `null` when no trial is usable.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct WeightSummary {
    /// Reward parameters (non-finite entries dropped, with a note).
    pub params: BTreeMap<String, f64>,
    /// The label param's value; 0 if the param is missing (with a note).
    pub value: f64,
    /// Finished trials.
    pub trials_done: u32,
    /// Converged trials.
    pub trials_converged: u32,
    /// Converged trials with at least one resampled episode; only these
    /// enter the means.
    pub trials_used: u32,
    /// Weight mean x: pointwise mean of the used trials' mean paths.
    pub mean_x: Option<Vec<f64>>,
    /// Weight mean z.
    pub mean_z: Option<Vec<f64>>,
    /// Pointwise sample SD of x across trial means (0 for one trial).
    pub sd_x: Option<Vec<f64>>,
    /// Pointwise sample SD of z across trial means.
    pub sd_z: Option<Vec<f64>>,
    /// Mean over used trials of the trial area.
    pub area_mean: Option<f64>,
    /// SEM of the trial area across used trials (0 for one trial).
    pub area_sem: Option<f64>,
    /// Mean over used trials of the trial torque usage (N m s).
    pub torque_usage_mean: Option<f64>,
    /// SEM of the trial torque usage across used trials.
    pub torque_usage_sem: Option<f64>,
    /// Mean final success rate over all finished trials.
    pub success_rate_mean: Option<f64>,
    /// Resampled x of the highest-return episode among used trials.
    pub top_x: Option<Vec<f64>>,
    /// Resampled z of that episode.
    pub top_z: Option<Vec<f64>>,
    /// Return of that episode.
    pub top_return: Option<f64>,
    /// Trials whose sampling found fewer successes than wanted (docs/science.md#sampling).
    pub shortfall_trials: u32,
    /// One line per finished trial, in input order.
    pub trials: Vec<TrialSummary>,
    /// Per solver variant with a usable trial here: what it reached and
    /// its gap to the optimum (docs/inference.md#solver-quality).
    #[serde(default)]
    pub solvers: Vec<SolverAtPoint>,
    /// The best movement an optimizer variant found here, if the search
    /// has one.
    #[serde(default)]
    pub optimum: Option<OptimumAtPoint>,
}

fn finite(v: Option<f64>) -> Option<f64> {
    v.filter(|x| x.is_finite())
}

fn count(n: usize) -> u32 {
    u32::try_from(n).unwrap_or(u32::MAX)
}

/// "w1=0.5, w2=1" for notes; the grid index when there are no params.
pub(super) fn describe(index: usize, params: &BTreeMap<String, f64>) -> String {
    if params.is_empty() {
        format!("grid point #{index}")
    } else {
        super::point_label(params)
    }
}

/// A trial's analysed data, before aggregation.
pub(crate) struct TrialWork {
    pub(crate) summary: TrialSummary,
    /// The digest of its output: mean paths and top episode.
    digest: Arc<TrialDigest>,
    /// What the posterior can use of the top path: its shape summary and
    /// timing (docs/inference.md#summary, docs/science.md#timing).
    features: Option<PathFeatures>,
    /// Index of the trial's solver variant in [`GridWork::solvers`].
    pub(crate) solver: usize,
}

impl TrialWork {
    /// The trial's top path and summary, when it is usable for the posterior.
    pub(crate) fn top_path(&self) -> Option<&ResampledPath> {
        self.digest.top.as_ref().map(|t| &t.path)
    }

    /// The top path's features for the posterior.
    pub(crate) fn features(&self) -> Option<&PathFeatures> {
        self.features.as_ref()
    }
}

/// One analysed grid point: its summary and its trials' work, aligned with
/// `summary.trials`.
pub(crate) struct PointWork {
    pub(crate) summary: WeightSummary,
    pub(crate) trials: Vec<TrialWork>,
}

/// The analysed grid: every episode resampled once, every trial summarised.
/// The document, the posterior and the leave-one-trial-out report are all
/// built from it.
pub(crate) struct GridWork {
    pub(crate) points: Vec<PointWork>,
    pub(crate) label_values: Vec<Option<f64>>,
    /// The grid's solver variants, in order of first appearance.
    pub(crate) solvers: Vec<SolverTag>,
}

impl GridWork {
    /// Mean trial path of the used trials of point `i`, leaving out every
    /// trial for which `skip(trial index, trial)` holds, as the document
    /// computes it.
    pub(crate) fn mean_x_where(
        &self,
        i: usize,
        skip: impl Fn(usize, &TrialWork) -> bool,
    ) -> Option<Vec<f64>> {
        let xs: Vec<&[f64]> = self.points[i]
            .trials
            .iter()
            .enumerate()
            .filter(|(t, w)| w.summary.used && !skip(*t, w))
            .map(|(_, w)| w.digest.mean_x.as_slice())
            .collect();
        pointwise_mean(&xs)
            .ok()
            .filter(|v| v.iter().all(|x| x.is_finite()))
    }

    /// Posterior summaries of the used trials of every point, each with
    /// its solver's index, leaving out every trial for which `skip(point,
    /// trial index, trial)` holds.
    pub(crate) fn summaries_where(
        &self,
        obs: Observables,
        skip: impl Fn(usize, usize, &TrialWork) -> bool,
    ) -> Vec<Vec<(usize, Vec<f64>)>> {
        self.points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                p.trials
                    .iter()
                    .enumerate()
                    .filter(|(t, w)| w.summary.used && !skip(i, *t, w))
                    .filter_map(|(_, w)| Some((w.solver, w.features.as_ref()?.summary(obs)?)))
                    .collect()
            })
            .collect()
    }

    /// [`GridWork::summaries_where`] leaving out the one trial `skip =
    /// (point, trial index)`.
    pub(crate) fn summaries_without(
        &self,
        obs: Observables,
        skip: Option<(usize, usize)>,
    ) -> Vec<Vec<(usize, Vec<f64>)>> {
        self.summaries_where(obs, |i, t, _| Some((i, t)) == skip)
    }

    /// The shortest and longest stand-up duration (docs/science.md#timing)
    /// of the used trials' top paths, if any has one.
    pub(crate) fn duration_range(&self) -> Option<(f64, f64)> {
        let ds = self
            .points
            .iter()
            .flat_map(|p| &p.trials)
            .filter(|w| w.summary.used)
            .filter_map(|w| Some(w.features.as_ref()?.timing.as_ref()?.duration));
        ds.fold(None, |acc, d| match acc {
            None => Some((d, d)),
            Some((lo, hi)) => Some((f64::min(lo, d), f64::max(hi, d))),
        })
    }

    /// Indices of the points by increasing label value, the order of a
    /// credible interval, when the grid is one ordered parameter: every
    /// point labelled, no two with the same value. `None` otherwise (a
    /// grid over several parameters keeps highest-probability sets).
    pub(crate) fn value_order(&self) -> Option<Vec<usize>> {
        let mut values: Vec<f64> = self.label_values.iter().copied().collect::<Option<_>>()?;
        let mut order: Vec<usize> = (0..values.len()).collect();
        order.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
        values.sort_by(f64::total_cmp);
        values.windows(2).all(|w| w[0] < w[1]).then_some(order)
    }

    /// A scorer for the solver-robust posterior alone (no paper means, no
    /// one-solver model), as the per-observable-set report needs it.
    pub(crate) fn posterior_scorer<'a>(
        &self,
        summaries: &[Vec<(usize, Vec<f64>)>],
        opts: &'a ReportOptions,
    ) -> GridScorer<'a> {
        let posterior = GridPosterior::fit_solvers(summaries, &opts.posterior);
        self.scorer_with(vec![None; self.points.len()], posterior, None, opts)
    }

    /// A scorer over the grid with the given means and posterior summaries.
    pub(crate) fn scorer<'a>(
        &self,
        means: Vec<Option<&'a [f64]>>,
        summaries: &[Vec<(usize, Vec<f64>)>],
        opts: &'a ReportOptions,
    ) -> GridScorer<'a> {
        let posterior = GridPosterior::fit_solvers(summaries, &opts.posterior);
        // With one solver the two models are the same: fit and score once.
        let solvers: std::collections::BTreeSet<usize> =
            summaries.iter().flatten().map(|(v, _)| *v).collect();
        let one_solver = if solvers.len() <= 1 {
            None
        } else {
            let untagged: Vec<Vec<Vec<f64>>> = summaries
                .iter()
                .map(|ys| ys.iter().map(|(_, y)| y.clone()).collect())
                .collect();
            Some(GridPosterior::fit(&untagged, &opts.posterior))
        };
        self.scorer_with(means, posterior, one_solver, opts)
    }

    fn scorer_with<'a>(
        &self,
        means: Vec<Option<&'a [f64]>>,
        posterior: Result<GridPosterior, super::posterior::PosteriorError>,
        one_solver: Option<Result<GridPosterior, super::posterior::PosteriorError>>,
        opts: &'a ReportOptions,
    ) -> GridScorer<'a> {
        let available: Vec<bool> = match &posterior {
            Ok(p) => p
                .available()
                .iter()
                .zip(&self.label_values)
                .map(|(a, v)| *a && v.is_some())
                .collect(),
            Err(_) => vec![false; self.points.len()],
        };
        let values: Vec<f64> = self.label_values.iter().map(|v| v.unwrap_or(0.0)).collect();
        GridScorer {
            means,
            label_values: self.label_values.clone(),
            prior: prior_weights(&values, &available, opts.posterior.prior),
            posterior,
            one_solver,
            order: self.value_order(),
            k_area: opts.k_area,
            k_corr: opts.k_corr,
            posterior_opts: &opts.posterior,
            durations: self.duration_range(),
        }
    }
}

/// A trial's work from its digest (docs/science.md#aggregation): the
/// notes that need the job's facts, its summary line and its features.
fn analyse_trial(
    label: &str,
    trial: &DigestedTrial,
    solver: usize,
    components: usize,
    notes: &mut Vec<String>,
) -> TrialWork {
    let tag = format!("{label}, trial {}", trial.trial);
    let d = &trial.digest;
    notes.extend(d.notes.iter().map(|n| format!("{tag}: {n}")));
    let used = trial.converged && d.episodes_resampled > 0;
    if trial.converged && d.episodes_resampled == 0 {
        notes.push(format!(
            "{tag}: converged but none of its {} episode(s) could be resampled; left out of the means",
            d.episodes
        ));
    }
    let timing = match d.top.as_ref().map(|t| &t.timing) {
        Some(Ok(t)) => Some(t.clone()),
        Some(Err(err)) if used => {
            notes.push(format!(
                "{tag}: the top episode's timing is not usable ({err}); left out of the timing \
                 observables"
            ));
            None
        }
        _ => None,
    };
    let features = d
        .top
        .as_ref()
        .and_then(|t| PathFeatures::new(&t.path, timing, components));
    if used && features.is_none() {
        notes.push(format!(
            "{tag}: no resampled episode has a finite return; left out of the posterior"
        ));
    }
    TrialWork {
        summary: TrialSummary {
            trial: trial.trial,
            seed: trial.seed,
            converged: trial.converged,
            final_success_rate: d.final_success_rate,
            area: d.area,
            torque_usage: d.torque_usage,
            successes_found: d.successes_found,
            successes_wanted: d.successes_wanted,
            episodes: d.episodes,
            episodes_resampled: d.episodes_resampled,
            used,
            solver: trial.solver.clone(),
        },
        digest: trial.digest.clone(),
        features,
        solver,
    }
}

fn summarise_weight(
    index: usize,
    w: &PointDigests,
    opts: &ReportOptions,
    solvers: &[SolverTag],
    notes: &mut Vec<String>,
) -> PointWork {
    let label = describe(index, &w.params);
    let params: BTreeMap<String, f64> = w
        .params
        .iter()
        .filter(|(_, v)| v.is_finite())
        .map(|(k, v)| (k.clone(), *v))
        .collect();
    if params.len() < w.params.len() {
        notes.push(format!("{label}: non-finite parameter(s) dropped"));
    }
    let value = match params.get(&opts.label_param) {
        Some(v) => *v,
        None => {
            notes.push(format!(
                "{label}: no finite parameter {:?}; its value is reported as 0 and it is never inferred",
                opts.label_param
            ));
            0.0
        }
    };
    let work: Vec<TrialWork> = w
        .trials
        .iter()
        .map(|t| {
            let solver = solvers.iter().position(|s| *s == t.solver).unwrap_or(0);
            analyse_trial(&label, t, solver, opts.posterior.components, notes)
        })
        .collect();
    let used: Vec<&TrialWork> = work.iter().filter(|t| t.summary.used).collect();
    if used.is_empty() {
        notes.push(format!(
            "{label}: no usable trials ({} done, {} converged); its paths and statistics are null",
            w.trials.len(),
            work.iter().filter(|t| t.summary.converged).count()
        ));
    }
    let xs: Vec<&[f64]> = used.iter().map(|t| t.digest.mean_x.as_slice()).collect();
    let zs: Vec<&[f64]> = used.iter().map(|t| t.digest.mean_z.as_slice()).collect();
    let areas: Vec<f64> = used.iter().filter_map(|t| t.summary.area).collect();
    let torques: Vec<f64> = used.iter().filter_map(|t| t.summary.torque_usage).collect();
    let rates: Vec<f64> = work
        .iter()
        .filter_map(|t| t.summary.final_success_rate)
        .collect();
    let (area_mean, area_sem) = mean_sem(&areas).unzip();
    let (torque_usage_mean, torque_usage_sem) = mean_sem(&torques).unzip();
    let mut top: Option<&TopEpisode> = None;
    for t in &used {
        if let Some(cand) = &t.digest.top {
            if top.is_none_or(|best| cand.ret > best.ret) {
                top = Some(cand);
            }
        }
    }
    let all_finite = |v: Vec<f64>| Some(v).filter(|v| v.iter().all(|x| x.is_finite()));
    let bests: Vec<TrialBest> = used
        .iter()
        .filter_map(|t| {
            let top = t.digest.top.as_ref()?;
            Some(TrialBest {
                solver: t.solver,
                ret: top.ret,
                duration: top.duration,
                area: top.path.area,
            })
        })
        .collect();
    let (solver_rows, optimum) = solver_table(solvers, &bests);
    let summary = WeightSummary {
        params,
        value,
        trials_done: count(w.trials.len()),
        trials_converged: count(work.iter().filter(|t| t.summary.converged).count()),
        trials_used: count(used.len()),
        mean_x: pointwise_mean(&xs).ok().and_then(all_finite),
        mean_z: pointwise_mean(&zs).ok().and_then(all_finite),
        sd_x: pointwise_sd(&xs).ok().and_then(all_finite),
        sd_z: pointwise_sd(&zs).ok().and_then(all_finite),
        area_mean: finite(area_mean),
        area_sem: finite(area_sem),
        torque_usage_mean: finite(torque_usage_mean),
        torque_usage_sem: finite(torque_usage_sem),
        success_rate_mean: finite(mean(&rates)),
        top_x: top.map(|t| t.path.x.clone()),
        top_z: top.map(|t| t.path.z.clone()),
        top_return: top.map(|t| t.ret),
        shortfall_trials: count(
            w.trials
                .iter()
                .filter(|t| t.digest.successes_found < t.digest.successes_wanted)
                .count(),
        ),
        trials: work.iter().map(|t| t.summary.clone()).collect(),
        solvers: solver_rows,
        optimum,
    };
    PointWork {
        summary,
        trials: work,
    }
}

/// Resamples and aggregates every grid point once (see
/// [`build_report`](super::build_report)).
pub(crate) fn analyse_grid(
    weights: &[WeightInput],
    opts: &ReportOptions,
    notes: &mut Vec<String>,
) -> GridWork {
    analyse_digests(&digest_grid(weights), opts, notes)
}

/// Aggregates every grid point from its trials' digests.
pub(crate) fn analyse_digests(
    points: &[PointDigests],
    opts: &ReportOptions,
    notes: &mut Vec<String>,
) -> GridWork {
    let mut solvers: Vec<SolverTag> = Vec::new();
    for t in points.iter().flat_map(|w| &w.trials) {
        if !solvers.contains(&t.solver) {
            solvers.push(t.solver.clone());
        }
    }
    let points: Vec<PointWork> = points
        .iter()
        .enumerate()
        .map(|(i, w)| summarise_weight(i, w, opts, &solvers, notes))
        .collect();
    let label_values = points
        .iter()
        .map(|p| p.summary.params.get(&opts.label_param).copied())
        .collect();
    GridWork {
        points,
        label_values,
        solvers,
    }
}
