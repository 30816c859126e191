//! The inference methods as one keyed collection: the paper's area
//! difference and correlation (docs/science.md#paper-metrics) and the
//! posterior over the grid (docs/inference.md). Every consumer (the result
//! document, `holdout`, the CSV, the CLI tables and the dashboard) iterates
//! [`Method::ALL`] and reads a [`MethodResult`], so a new method is one new
//! variant here and one scoring arm in [`score_subject`].

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::costs::subject_costs;
use super::observables::PathFeatures;
use super::posterior::{
    shortest_interval_set, GridPosterior, OutOfModel, PosteriorError, PosteriorOptions,
};
use super::preprocess::ResampledPath;
use super::AnalysisError;

/// One way of inferring a subject's grid value.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Smallest area difference `D` to the weight mean (the paper's).
    Area,
    /// Largest clipped correlation `rho` with the weight mean (the paper's).
    Correlation,
    /// Most probable grid point under the posterior (the project's): the
    /// solver-robust one, which models the spread between the grid's
    /// solver variants (docs/inference.md#solver-spread); with one solver
    /// it equals [`Method::PosteriorOneSolver`].
    Posterior,
    /// The posterior that takes every trial as a draw from one solver,
    /// kept for comparison (docs/inference.md#likelihood).
    PosteriorOneSolver,
}

impl Method {
    /// Every method, in display order.
    pub const ALL: [Method; 4] = [
        Method::Area,
        Method::Correlation,
        Method::Posterior,
        Method::PosteriorOneSolver,
    ];

    /// Whether the method's probabilities are a posterior (its credible
    /// sets are intervals over one ordered parameter), rather than one of
    /// the paper's softmax displays.
    pub fn is_posterior(self) -> bool {
        matches!(self, Self::Posterior | Self::PosteriorOneSolver)
    }

    /// The key in JSON documents.
    pub fn key(self) -> &'static str {
        match self {
            Self::Area => "area",
            Self::Correlation => "correlation",
            Self::Posterior => "posterior",
            Self::PosteriorOneSolver => "posterior_one_solver",
        }
    }

    /// A title for tables and figures.
    pub fn title(self) -> &'static str {
        match self {
            Self::Area => "area difference",
            Self::Correlation => "correlation",
            Self::Posterior => "posterior",
            Self::PosteriorOneSolver => "posterior, one solver",
        }
    }

    /// CSV quantity of the inferred value (the names the CSV always had).
    pub fn csv_inferred(self) -> &'static str {
        match self {
            Self::Area => "inferred_area",
            Self::Correlation => "inferred_corr",
            Self::Posterior => "inferred_posterior",
            Self::PosteriorOneSolver => "inferred_posterior_one_solver",
        }
    }

    /// CSV quantity and symbol of the per-point score.
    pub fn csv_score(self) -> &'static str {
        match self {
            Self::Area => "area_difference",
            Self::Correlation => "correlation",
            Self::Posterior => "log_likelihood",
            Self::PosteriorOneSolver => "log_likelihood_one_solver",
        }
    }

    /// CSV quantity of the per-point probabilities.
    pub fn csv_probability(self) -> &'static str {
        match self {
            Self::Area => "ranking_area",
            Self::Correlation => "ranking_corr",
            Self::Posterior => "posterior",
            Self::PosteriorOneSolver => "posterior_one_solver",
        }
    }

    /// What the probabilities are, for figure captions.
    pub fn probability_caption(self) -> &'static str {
        match self {
            Self::Area => "softmax over the grid of -K_area x D (display ranking, K_area = 30)",
            Self::Correlation => {
                "softmax over the grid of K_corr x rho (display ranking, K_corr = 100)"
            }
            Self::Posterior => {
                "posterior probability over the grid, modelling the spread between solvers \
                 (calibrated by leave-one-trial-out and leave-one-solver-out)"
            }
            Self::PosteriorOneSolver => {
                "posterior probability over the grid, every trial taken as one solver's"
            }
        }
    }

    /// Symbol of the score.
    pub fn score_symbol(self) -> &'static str {
        match self {
            Self::Area => "D",
            Self::Correlation => "rho",
            Self::Posterior | Self::PosteriorOneSolver => "log p",
        }
    }
}

/// A credible set over the grid, with its members' label values.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct CredibleSummary {
    /// Label values of the members, in grid order.
    pub values: Vec<f64>,
    /// Indices of the members into the document's `weights`.
    pub indices: Vec<usize>,
    /// Mass held.
    pub mass: f64,
    /// Mass asked for.
    pub level: f64,
}

impl CredibleSummary {
    /// "0.1 - 4, 92 %" when the members are neighbours on the grid (their
    /// indices consecutive), else every member: "0.1, 1, 2; 93 %". A single
    /// member is shown alone.
    pub fn describe(&self) -> String {
        let pct = (100.0 * self.mass).floor();
        let adjacent = self.indices.windows(2).all(|w| w[1] == w[0] + 1);
        match self.values.as_slice() {
            [] => "-".to_string(),
            [one] => format!("{one}, {pct:.0} %"),
            [first, .., last] if adjacent => format!("{first} - {last}, {pct:.0} %"),
            all => {
                let list: Vec<String> = all.iter().map(|v| v.to_string()).collect();
                format!("{}; {pct:.0} %", list.join(", "))
            }
        }
    }
}

impl CredibleSummary {
    /// What the set says about identifiability, in words, on a grid of
    /// `n_points` labelled values (docs/inference.md#reading-a-result):
    /// a set holding all but at most one value says the value is not
    /// identifiable here; an interval from either end of the grid over at
    /// least three values bounds it on one side only. `None` for a set
    /// that pins the value down better than that.
    pub fn verdict(&self, n_points: usize, lowest: f64, highest: f64) -> Option<String> {
        let k = self.values.len();
        let (first, last) = (*self.values.first()?, *self.values.last()?);
        if n_points >= 3 && k + 1 >= n_points {
            return Some("not identifiable here: the set spans most of the grid".to_string());
        }
        if k >= 3 && first == lowest {
            return Some(format!(
                "only bounded above: {last} or below, not told apart"
            ));
        }
        if k >= 3 && last == highest {
            return Some(format!(
                "only bounded below: {first} or above, not told apart"
            ));
        }
        None
    }
}

/// One method's answer for one subject. Vectors are aligned with the
/// document's `weights`.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct MethodResult {
    /// The method's per-point score (`D`, `rho` or log predictive density);
    /// `null` where the point has no mean path or density.
    pub scores: Vec<Option<f64>>,
    /// Probabilities over the grid (the paper's softmax displays, or the
    /// posterior); 0 where the point has no score.
    pub probabilities: Vec<f64>,
    /// Index into `weights` of the inferred point.
    pub inferred_index: Option<usize>,
    /// Label value of the inferred point.
    pub inferred: Option<f64>,
    /// Posterior only: the credible set.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub credible_set: Option<CredibleSummary>,
    /// Posterior only: the out-of-model test.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub out_of_model: Option<OutOfModel>,
    /// Why the method gave no answer, if it gave none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unavailable: Option<String>,
}

impl MethodResult {
    /// No answer, for `n` grid points, with the reason.
    pub fn unavailable(n: usize, reason: String) -> Self {
        Self {
            scores: vec![None; n],
            probabilities: vec![0.0; n],
            inferred_index: None,
            inferred: None,
            credible_set: None,
            out_of_model: None,
            unavailable: Some(reason),
        }
    }
}

/// Every method's result for one subject, keyed by method.
pub type MethodResults = BTreeMap<Method, MethodResult>;

/// What scoring a subject against a grid needs, aligned with the grid's
/// points: each point's weight mean x (if it has one), label value (if it
/// has one), the fitted posterior and its prior weights.
pub struct GridScorer<'a> {
    /// Weight mean x per point.
    pub means: Vec<Option<&'a [f64]>>,
    /// Label value per point.
    pub label_values: Vec<Option<f64>>,
    /// The solver-robust posterior model, or why there is none.
    pub posterior: Result<GridPosterior, PosteriorError>,
    /// The one-solver posterior model, or why there is none; `None` when
    /// the grid holds one solver and it is the same model as `posterior`.
    pub one_solver: Option<Result<GridPosterior, PosteriorError>>,
    /// Points by increasing label value when the grid is one ordered
    /// parameter: credible sets are then intervals in this order.
    pub order: Option<Vec<usize>>,
    /// Prior weights per point.
    pub prior: Vec<f64>,
    /// Softmax gains of the paper's displays.
    pub k_area: f64,
    /// See `k_area`.
    pub k_corr: f64,
    /// Posterior knobs.
    pub posterior_opts: &'a PosteriorOptions,
    /// Shortest and longest stand-up duration of the grid's trials (s),
    /// for the out-of-model reason (docs/science.md#timing).
    pub durations: Option<(f64, f64)>,
}

/// Scores one resampled path with every method; the posterior reads the
/// path's `features` (its shape summary and timing). Errors only when the
/// paper costs cannot be computed (a path of the wrong length); a posterior
/// that cannot be formed is an `unavailable` entry.
pub fn score_subject(
    path: &ResampledPath,
    features: Option<&PathFeatures>,
    g: &GridScorer,
) -> Result<MethodResults, AnalysisError> {
    let n = g.means.len();
    let avail: Vec<usize> = (0..n).filter(|&i| g.means[i].is_some()).collect();
    let means: Vec<&[f64]> = avail.iter().filter_map(|&i| g.means[i]).collect();
    let costs = subject_costs(&path.x, &means, g.k_area, g.k_corr)?;
    let finite = |v: f64| Some(v).filter(|v| v.is_finite());
    let mut out = MethodResults::new();
    for (method, scores, probs, best) in [
        (
            Method::Area,
            &costs.area_difference,
            &costs.ranking_area,
            costs.best_area,
        ),
        (
            Method::Correlation,
            &costs.correlation,
            &costs.ranking_corr,
            costs.best_corr,
        ),
    ] {
        let mut r = MethodResult {
            scores: vec![None; n],
            probabilities: vec![0.0; n],
            inferred_index: best.map(|j| avail[j]),
            inferred: None,
            credible_set: None,
            out_of_model: None,
            unavailable: None,
        };
        for (j, &i) in avail.iter().enumerate() {
            r.scores[i] = finite(scores[j]);
            r.probabilities[i] = probs[j];
        }
        r.inferred = r.inferred_index.and_then(|i| g.label_values[i]);
        if avail.is_empty() {
            r.unavailable = Some("no grid point has a mean path".to_string());
        }
        out.insert(method, r);
    }
    let robust = posterior_result(features, g, &g.posterior);
    let one_solver = match &g.one_solver {
        Some(model) => posterior_result(features, g, model),
        None => robust.clone(),
    };
    out.insert(Method::Posterior, robust);
    out.insert(Method::PosteriorOneSolver, one_solver);
    Ok(out)
}

/// The posterior's answer (`model`, fitted from `g`'s grid) for a path's
/// features.
pub(crate) fn posterior_result(
    features: Option<&PathFeatures>,
    g: &GridScorer,
    model: &Result<GridPosterior, PosteriorError>,
) -> MethodResult {
    let n = g.means.len();
    let model = match model {
        Ok(m) => m,
        Err(e) => return MethodResult::unavailable(n, e.to_string()),
    };
    let obs = g.posterior_opts.observables;
    let Some(features) = features else {
        return MethodResult::unavailable(n, "the path has non-finite values".to_string());
    };
    let Some(y) = features.summary(obs) else {
        return MethodResult::unavailable(
            n,
            format!("the path has no usable times, which the observables {obs} need"),
        );
    };
    match model.score(&y, &g.prior, g.posterior_opts) {
        Ok(mut s) => {
            if let Some(i) = obs.duration_index(g.posterior_opts.components) {
                let p = model.marginal_tail(&y, i);
                if p < g.posterior_opts.out_of_model_p {
                    s.out_of_model.flagged = true;
                    s.out_of_model.p_value = s.out_of_model.p_value.min(p);
                    s.out_of_model.reason = Some(duration_reason(y[i].exp(), g.durations));
                }
            }
            if let Some(order) = &g.order {
                s.credible = shortest_interval_set(&s.probabilities, order, s.credible.level);
            }
            let values = s
                .credible
                .indices
                .iter()
                .filter_map(|&i| g.label_values[i])
                .collect();
            MethodResult {
                inferred: s.map.and_then(|i| g.label_values[i]),
                inferred_index: s.map,
                credible_set: Some(CredibleSummary {
                    values,
                    indices: s.credible.indices,
                    mass: s.credible.mass,
                    level: s.credible.level,
                }),
                out_of_model: Some(s.out_of_model),
                scores: s.log_likelihood,
                probabilities: s.probabilities,
                unavailable: None,
            }
        }
        Err(e) => MethodResult::unavailable(n, e.to_string()),
    }
}

/// The out-of-model reason of a stand-up whose duration the grid never
/// produces (docs/science.md#timing).
fn duration_reason(duration: f64, grid: Option<(f64, f64)>) -> String {
    let range = match grid {
        Some((lo, hi)) => format!("the grid's stand-ups take {lo:.2}-{hi:.2} s"),
        None => "the grid's stand-ups take other times".to_string(),
    };
    format!("duration: this stand-up takes {duration:.2} s, {range}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn method_keys_serialize_as_their_names_in_order() {
        let mut m = BTreeMap::new();
        for (i, k) in Method::ALL.iter().enumerate() {
            m.insert(*k, i);
        }
        let s = serde_json::to_string(&m).unwrap();
        assert_eq!(
            s,
            r#"{"area":0,"correlation":1,"posterior":2,"posterior_one_solver":3}"#
        );
        for k in Method::ALL {
            assert_eq!(
                serde_json::to_string(&k).unwrap(),
                format!("\"{}\"", k.key())
            );
        }
    }

    #[test]
    fn credible_set_description() {
        let c = CredibleSummary {
            values: vec![0.1, 0.5, 1.0, 2.0, 4.0],
            indices: vec![0, 1, 2, 3, 4],
            mass: 0.925,
            level: 0.9,
        };
        assert_eq!(c.describe(), "0.1 - 4, 92 %");
        let gap = CredibleSummary {
            values: vec![0.1, 1.0, 2.0],
            indices: vec![0, 2, 3],
            mass: 0.934,
            level: 0.9,
        };
        assert_eq!(gap.describe(), "0.1, 1, 2; 93 %");
        let one = CredibleSummary {
            values: vec![8.0],
            indices: vec![5],
            mass: 0.97,
            level: 0.9,
        };
        assert_eq!(one.describe(), "8, 97 %");
    }

    #[test]
    fn verdict_names_sets_that_span_the_grid_or_reach_one_end() {
        let set = |values: &[f64]| CredibleSummary {
            values: values.to_vec(),
            indices: (0..values.len()).collect(),
            mass: 0.9,
            level: 0.9,
        };
        let (lo, hi) = (0.1, 16.0);
        let wide = set(&[0.1, 0.5, 1.0, 2.0, 4.0, 8.0]);
        assert!(wide
            .verdict(7, lo, hi)
            .unwrap()
            .starts_with("not identifiable"));
        let low = set(&[0.1, 0.5, 1.0, 2.0]);
        assert_eq!(
            low.verdict(7, lo, hi).unwrap(),
            "only bounded above: 2 or below, not told apart"
        );
        let high = set(&[4.0, 8.0, 16.0]);
        assert!(high
            .verdict(7, lo, hi)
            .unwrap()
            .starts_with("only bounded below: 4"));
        assert_eq!(set(&[2.0, 4.0]).verdict(7, lo, hi), None);
        assert_eq!(set(&[0.5, 1.0, 2.0]).verdict(7, lo, hi), None);
    }
}
