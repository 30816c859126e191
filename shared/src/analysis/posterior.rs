//! The posterior over the grid (docs/inference.md): how probable a subject's
//! path is for a *single policy* trained at each grid point, turned into
//! probabilities over the grid with a prior, a MAP value, a credible set and
//! an out-of-model test.
//!
//! Every path is reduced to a short summary vector: its trajectory area and
//! the first few sine-series coefficients of its resampled x (a normalized
//! path starts and ends at x = 0, so a sine series is its natural basis).
//! At each grid point the summaries of its trials (one per trial: the
//! trial's highest-return kept episode, the same kind of path a held-out
//! trial or a person contributes) are modelled as a multivariate Student t
//! whose covariance is shrunk toward the covariance pooled within all grid
//! points. The trial is the unit of replication: the spread modelled is the
//! spread between independent solutions of the RL problem.

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use statrs::function::beta::beta_reg;
use statrs::function::gamma::ln_gamma;

use super::observables::Observables;
use super::AnalysisError;

/// Which prior over the grid points the posterior uses.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum Prior {
    /// Every grid point equally probable (right for a grid chosen up front
    /// and even in log; it favours any region where points are dense).
    Uniform,
    /// The default: uniform in log of the label value, each point weighted
    /// by the width of its cell in log space, so that a densely refined
    /// region (points added by an extension or refinement) is not favoured
    /// (docs/science.md#posterior-over-the-grid, docs/inference.md#prior).
    /// On a grid even in log it equals [`Prior::Uniform`].
    #[default]
    LogCell,
}

/// Knobs of the posterior; the defaults were chosen by measurement
/// (docs/inference.md#choosing-the-summary-and-estimator).
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct PosteriorOptions {
    /// Sine-series coefficients of x in the summary, beside the area.
    pub components: usize,
    /// Strength of the pooled covariance, in pseudo-trials: a point's
    /// covariance is its own scatter plus `pooling` times the pooled
    /// covariance, over `n - 1 + pooling`.
    pub pooling: f64,
    /// Mass the credible set must hold at least.
    pub credible_mass: f64,
    /// Out-of-model threshold: a subject is flagged when its tail
    /// probability is below this at every grid point.
    pub out_of_model_p: f64,
    /// Prior over the grid points.
    pub prior: Prior,
    /// Least spread between solver variants, as a multiple of the spread
    /// between one variant's trials: the between-solver covariance B is
    /// raised to at least this times W in every direction
    /// (docs/inference.md#solver-spread). Two or three variants of one
    /// trainer differ less than unlike solvers (or a person) do, so the B
    /// they estimate alone is too small. Used only where B is defined (two
    /// or more variants); 0 keeps the estimate as it is. A stored
    /// configuration without it reads as 0, the model it was built with.
    #[serde(default)]
    pub solver_spread_floor: f64,
    /// The evidence in the summary vector (docs/inference.md#observables);
    /// a stored configuration without it reads as `shape`.
    #[serde(default = "Observables::legacy")]
    pub observables: Observables,
}

impl Default for PosteriorOptions {
    fn default() -> Self {
        Self {
            components: 2,
            pooling: 8.0,
            credible_mass: 0.9,
            out_of_model_p: 0.001,
            prior: Prior::LogCell,
            solver_spread_floor: DEFAULT_SOLVER_SPREAD_FLOOR,
            observables: Observables::default(),
        }
    }
}

/// The default [`PosteriorOptions::solver_spread_floor`], chosen on the
/// paper grid's three-solver study (docs/inference.md#measured-across-solvers):
/// the smallest round value at which every held-out variant's 90 % sets
/// cover at least 0.83 of its trials with a margin.
pub const DEFAULT_SOLVER_SPREAD_FLOOR: f64 = 0.5;

/// Largest accepted [`PosteriorOptions::solver_spread_floor`]: beyond it
/// the between-solver part swamps every difference between grid points.
pub const MAX_SOLVER_SPREAD_FLOOR: f64 = 100.0;

/// Largest accepted [`PosteriorOptions::components`]: more coefficients
/// cannot be estimated from 8-20 trials per point.
pub const MAX_COMPONENTS: usize = 8;

impl PosteriorOptions {
    /// Every field in its documented range.
    pub fn validate(&self) -> Result<(), AnalysisError> {
        if self.components > MAX_COMPONENTS {
            return Err(AnalysisError::InvalidOption {
                name: "posterior.components",
                value: self.components as f64,
            });
        }
        let checks = [
            (
                "posterior.pooling",
                self.pooling,
                self.pooling.is_finite() && self.pooling >= 0.0,
            ),
            (
                "posterior.credible_mass",
                self.credible_mass,
                self.credible_mass > 0.0 && self.credible_mass < 1.0,
            ),
            (
                "posterior.solver_spread_floor",
                self.solver_spread_floor,
                self.solver_spread_floor.is_finite()
                    && (0.0..=MAX_SOLVER_SPREAD_FLOOR).contains(&self.solver_spread_floor),
            ),
            (
                "posterior.out_of_model_p",
                self.out_of_model_p,
                self.out_of_model_p > 0.0 && self.out_of_model_p < 1.0,
            ),
        ];
        for (name, value, ok) in checks {
            if !ok {
                return Err(AnalysisError::InvalidOption { name, value });
            }
        }
        Ok(())
    }

    /// Length of a summary vector.
    pub fn dim(&self) -> usize {
        self.observables.dim(self.components)
    }
}

/// Why no posterior could be formed over a grid.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PosteriorError {
    /// No grid point has two trials, so no spread between trials is known.
    #[error("no grid point has two usable trials; the posterior needs the spread between trials")]
    NoReplicates,
    /// Every trial at every point has the same summary.
    #[error("the trials do not vary at all (zero spread); the posterior is undefined")]
    ZeroSpread,
    /// The summaries have the wrong length.
    #[error("summary of length {found}, expected {expected}")]
    Dimension {
        /// Expected length.
        expected: usize,
        /// Length found.
        found: usize,
    },
}

/// The fitted predictive density of one grid point.
#[derive(Clone, Debug)]
struct PointDensity {
    mean: DVector<f64>,
    /// Cholesky factor L of the t scale matrix (scale = L L^T).
    chol_l: DMatrix<f64>,
    log_det: f64,
    /// Degrees of freedom.
    nu: f64,
}

impl PointDensity {
    /// Squared Mahalanobis distance of `y` under the scale matrix.
    fn mahalanobis2(&self, y: &DVector<f64>) -> f64 {
        let diff = y - &self.mean;
        // Solve L v = diff; |v|^2 = diff^T (L L^T)^-1 diff.
        match self.chol_l.solve_lower_triangular(&diff) {
            Some(v) => v.norm_squared(),
            None => f64::INFINITY,
        }
    }

    /// log of the multivariate Student-t density at `y`, and delta^2.
    fn log_density(&self, y: &DVector<f64>) -> (f64, f64) {
        let d = y.len() as f64;
        let nu = self.nu;
        let delta2 = self.mahalanobis2(y);
        let log_norm = ln_gamma((nu + d) / 2.0)
            - ln_gamma(nu / 2.0)
            - 0.5 * d * (nu * std::f64::consts::PI).ln()
            - 0.5 * self.log_det;
        (log_norm - 0.5 * (nu + d) * (delta2 / nu).ln_1p(), delta2)
    }
}

/// Upper tail probability of the F(d1, d2) distribution at `f`.
pub fn f_upper_tail(f: f64, d1: f64, d2: f64) -> f64 {
    if f.is_nan() {
        return 0.0;
    }
    if f <= 0.0 {
        return 1.0;
    }
    if f.is_infinite() {
        return 0.0;
    }
    // P(F > f) = I_{d2 / (d2 + d1 f)}(d2 / 2, d1 / 2).
    let x = d2 / (d2 + d1 * f);
    beta_reg(d2 / 2.0, d1 / 2.0, x).clamp(0.0, 1.0)
}

/// One solver's trials at one grid point: count, mean and scatter matrix
/// `sum (y - mean)(y - mean)^T`.
struct SolverStats {
    n: usize,
    mean: DVector<f64>,
    scatter: DMatrix<f64>,
}

/// The summaries of one point grouped by solver, in solver order.
fn solver_groups(ys: &[(usize, Vec<f64>)], d: usize) -> Vec<SolverStats> {
    let mut by: BTreeMap<usize, Vec<&Vec<f64>>> = BTreeMap::new();
    for (v, y) in ys {
        by.entry(*v).or_default().push(y);
    }
    by.into_values()
        .map(|ys| {
            let n = ys.len();
            let mut mean = DVector::zeros(d);
            for y in &ys {
                mean += DVector::from_column_slice(y);
            }
            mean /= n as f64;
            let mut scatter = DMatrix::zeros(d, d);
            for y in &ys {
                let e = DVector::from_column_slice(y) - &mean;
                scatter += &e * e.transpose();
            }
            SolverStats { n, mean, scatter }
        })
        .collect()
}

/// The between-solver covariance B with its degrees of freedom, pooled
/// over the points that hold two or more solvers; `None` when no point
/// does (one solver: nothing is known about the spread between solvers).
fn between_solver_covariance(
    groups: &[Vec<SolverStats>],
    within: &DMatrix<f64>,
    d: usize,
    floor: f64,
) -> Option<(DMatrix<f64>, f64)> {
    let mut scatter = DMatrix::zeros(d, d);
    let (mut dof, mut inv_n, mut cells) = (0usize, 0.0, 0usize);
    for gs in groups.iter().filter(|gs| gs.len() >= 2) {
        let v = gs.len() as f64;
        let centre = gs.iter().fold(DVector::zeros(d), |acc, g| acc + &g.mean) / v;
        for g in gs {
            let e = &g.mean - &centre;
            scatter += &e * e.transpose();
            inv_n += 1.0 / g.n as f64;
            cells += 1;
        }
        dof += gs.len() - 1;
    }
    if dof == 0 {
        return None;
    }
    // E[scatter / dof] = B + W * mean(1 / n): take the trials' own noise
    // out, and clip what estimation noise leaves negative.
    let raw = scatter / dof as f64 - within * (inv_n / cells as f64);
    let nu = (dof as f64 - d as f64 + 1.0).max(1.0);
    Some((floored(&raw, within, floor), nu))
}

/// `raw` with every eigenvalue relative to `within` raised to at least
/// `floor`: in the coordinates where W is the identity (W = L L^T, M =
/// L^-1 raw L^-T) M's eigenvalues are clipped from below and the result
/// mapped back, so that B >= floor W in the Loewner order and B keeps the
/// estimate wherever it is larger. With `floor` 0 this is the plain clip
/// to positive semi-definite. A W that is not positive definite (which
/// the caller's ridge prevents) falls back to the Euclidean clip.
fn floored(raw: &DMatrix<f64>, within: &DMatrix<f64>, floor: f64) -> DMatrix<f64> {
    let clip = |m: DMatrix<f64>, lo: f64| {
        let eig = nalgebra::SymmetricEigen::new(m);
        let clipped = eig.eigenvalues.map(|l| l.max(lo));
        &eig.eigenvectors * DMatrix::from_diagonal(&clipped) * eig.eigenvectors.transpose()
    };
    if floor <= 0.0 {
        return clip(raw.clone(), 0.0);
    }
    let Some(chol) = within.clone().cholesky() else {
        return clip(raw.clone(), 0.0);
    };
    let l = chol.l();
    let Some(l_inv) = l.clone().try_inverse() else {
        return clip(raw.clone(), 0.0);
    };
    let m = &l_inv * raw * l_inv.transpose();
    let m = (&m + m.transpose()) * 0.5;
    &l * clip(m, floor) * l.transpose()
}

/// The predictive density of a new path at one point (see
/// [`GridPosterior::fit_solvers`]); `None` for a point without trials.
fn point_density(
    gs: &[SolverStats],
    pooled: &DMatrix<f64>,
    between: Option<&(DMatrix<f64>, f64)>,
    ridge: &DMatrix<f64>,
    opts: &PosteriorOptions,
) -> Option<PointDensity> {
    if gs.is_empty() {
        return None;
    }
    let d = pooled.nrows();
    let v = gs.len() as f64;
    let n: usize = gs.iter().map(|g| g.n).sum();
    let mut scatter = DMatrix::zeros(d, d);
    for g in gs {
        scatter += &g.scatter;
    }
    let mean = gs.iter().fold(DVector::zeros(d), |acc, g| acc + &g.mean) / v;
    let own = (n - gs.len()) as f64;
    let weight = own + opts.pooling;
    let cov = if weight > 0.0 {
        (scatter + pooled * opts.pooling) / weight
    } else {
        pooled.clone()
    } + ridge;
    // The point's mean is itself estimated from the solvers' means, which
    // widens the density by the variance of that estimate.
    let inv_n: f64 = gs.iter().map(|g| 1.0 / g.n as f64).sum();
    let within = cov * (1.0 + inv_n / (v * v));
    let nu_within = (weight - d as f64 + 1.0).max(1.0);
    let (scale, nu) = match between {
        Some((b, nu_b)) if b.trace() > 0.0 => {
            let b_part = b * (1.0 + 1.0 / v);
            let (tw, tb) = (within.trace(), b_part.trace());
            // Welch-Satterthwaite on the traces: the t's tails are as heavy
            // as the less certain of the two parts makes them.
            let nu = (tw + tb).powi(2) / (tw * tw / nu_within + tb * tb / nu_b);
            (within + b_part, nu.max(1.0))
        }
        _ => (within, nu_within),
    };
    let chol = scale.cholesky()?;
    let l = chol.l();
    let log_det = 2.0 * l.diagonal().iter().map(|v| v.ln()).sum::<f64>();
    Some(PointDensity {
        mean,
        chol_l: l,
        log_det,
        nu,
    })
}

/// The posterior model of a grid: one predictive density per grid point
/// with at least one trial summary.
#[derive(Clone, Debug)]
pub struct GridPosterior {
    points: Vec<Option<PointDensity>>,
    dim: usize,
}

/// Out-of-model test of one subject.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct OutOfModel {
    /// Whether the subject is implausible under every grid point.
    pub flagged: bool,
    /// Smallest squared Mahalanobis distance to a grid point's density.
    pub statistic: f64,
    /// Largest tail probability over the grid points: P(F(d, nu) > delta^2 / d).
    pub p_value: f64,
    /// The flag is raised when `p_value` is below this.
    pub threshold: f64,
    /// What put the subject out of model, when one feature alone does: for
    /// a posterior that uses the absolute duration, a stand-up slower or
    /// faster than anything the grid produces (docs/science.md#timing).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

/// The smallest highest-probability set holding at least a given mass.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct CredibleSet {
    /// Indices of its members, in index order.
    pub indices: Vec<usize>,
    /// The mass they hold.
    pub mass: f64,
    /// The mass the set was asked to hold.
    pub level: f64,
}

/// The smallest set of indices whose probabilities add up to at least
/// `level`: indices are taken by decreasing probability, and equal
/// probabilities by increasing index (docs/inference.md#credible-sets).
/// Zero-probability entries are never taken. Empty if all are zero.
pub fn highest_probability_set(probs: &[f64], level: f64) -> CredibleSet {
    let mut order: Vec<usize> = (0..probs.len()).filter(|&i| probs[i] > 0.0).collect();
    order.sort_by(|&a, &b| probs[b].total_cmp(&probs[a]).then(a.cmp(&b)));
    let mut mass = 0.0;
    let mut indices = Vec::new();
    for i in order {
        // A rounding margin, so that a set that holds the level exactly in
        // real arithmetic is not extended by one more point.
        if mass >= level - 1e-12 {
            break;
        }
        mass += probs[i];
        indices.push(i);
    }
    indices.sort_unstable();
    CredibleSet {
        indices,
        mass: mass.min(1.0),
        level,
    }
}

/// The credible set over one ordered parameter: the shortest run of
/// neighbours in `order` (indices sorted by the parameter's value) whose
/// probabilities add up to at least `level`; among runs of the same
/// length the one holding more mass, then the lower one
/// (docs/inference.md#credible-sets). A set with holes in w1 reads as
/// noise, so the interval may hold a point of low probability between two
/// likely ones. Empty if all probabilities are zero.
pub fn shortest_interval_set(probs: &[f64], order: &[usize], level: f64) -> CredibleSet {
    let p = |k: usize| probs.get(order[k]).copied().unwrap_or(0.0).max(0.0);
    let n = order.len();
    let mut best: Option<(usize, usize, f64)> = None;
    for start in 0..n {
        let mut mass = 0.0;
        for end in start..n {
            mass += p(end);
            // The same rounding margin as the highest-probability set.
            if mass >= level - 1e-12 {
                let len = end - start + 1;
                let better = match best {
                    None => true,
                    Some((s, e, m)) => len < e - s + 1 || (len == e - s + 1 && mass > m + 1e-15),
                };
                if better {
                    best = Some((start, end, mass));
                }
                break;
            }
        }
    }
    match best {
        Some((s, e, mass)) if probs.iter().any(|&v| v > 0.0) => {
            let mut indices: Vec<usize> = order[s..=e].to_vec();
            indices.sort_unstable();
            CredibleSet {
                indices,
                mass: mass.min(1.0),
                level,
            }
        }
        _ => CredibleSet {
            indices: Vec::new(),
            mass: 0.0,
            level,
        },
    }
}

/// Prior weights over grid points with `values` (aligned), normalized over
/// the points marked `available`. For [`Prior::LogCell`] a point's weight is
/// the width in log value of its cell: half-way in log to each neighbour,
/// the cell of an end point reaching as far outwards as inwards. Values
/// that are not positive cannot be logged: then the prior is uniform.
pub fn prior_weights(values: &[f64], available: &[bool], prior: Prior) -> Vec<f64> {
    let n = values.len();
    let avail: Vec<usize> = (0..n).filter(|&i| available[i]).collect();
    let mut w = vec![0.0; n];
    if avail.is_empty() {
        return w;
    }
    let uniform = |w: &mut Vec<f64>| {
        for &i in &avail {
            w[i] = 1.0 / avail.len() as f64;
        }
    };
    if prior == Prior::Uniform || avail.len() == 1 || avail.iter().any(|&i| values[i] <= 0.0) {
        uniform(&mut w);
        return w;
    }
    let mut sorted = avail.clone();
    sorted.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
    let logs: Vec<f64> = sorted.iter().map(|&i| values[i].ln()).collect();
    let m = logs.len();
    for (k, &i) in sorted.iter().enumerate() {
        let width = if k == 0 {
            logs[1] - logs[0]
        } else if k == m - 1 {
            logs[m - 1] - logs[m - 2]
        } else {
            0.5 * (logs[k + 1] - logs[k - 1])
        };
        w[i] = width.max(0.0);
    }
    let total: f64 = w.iter().sum();
    if total > 0.0 && total.is_finite() {
        w.iter_mut().for_each(|v| *v /= total);
    } else {
        // Every available value is the same: no cells to weigh.
        uniform(&mut w);
    }
    w
}

/// One subject's posterior over the grid.
#[derive(Clone, Debug, PartialEq)]
pub struct PosteriorScore {
    /// log predictive density per grid point; `None` where the point has no
    /// density.
    pub log_likelihood: Vec<Option<f64>>,
    /// Posterior probabilities per grid point (0 where no density).
    pub probabilities: Vec<f64>,
    /// Index of the most probable point (lowest index on ties).
    pub map: Option<usize>,
    /// The credible set.
    pub credible: CredibleSet,
    /// The out-of-model test.
    pub out_of_model: OutOfModel,
}

impl GridPosterior {
    /// Fits the model from per-point lists of trial summaries (each of
    /// length `opts.dim()`), all from one solver. A point with no summary
    /// gets no density.
    pub fn fit(points: &[Vec<Vec<f64>>], opts: &PosteriorOptions) -> Result<Self, PosteriorError> {
        let tagged: Vec<Vec<(usize, Vec<f64>)>> = points
            .iter()
            .map(|ys| ys.iter().map(|y| (0, y.clone())).collect())
            .collect();
        Self::fit_solvers(&tagged, opts)
    }

    /// Fits the model from per-point lists of `(solver, summary)` pairs,
    /// accounting for the spread *between* solvers as well as between the
    /// trials of one (docs/inference.md#solver-spread). With one solver it
    /// is exactly [`GridPosterior::fit`].
    ///
    /// At point w, solver v has n_wv trials with mean m_wv and scatter
    /// S_wv. The within-solver covariance W is pooled over every (w, v)
    /// group and shrunk toward per point as in the one-solver model; the
    /// between-solver covariance B is the scatter of the solver means about
    /// their point's mean, pooled over points, less the part the trials'
    /// own noise explains (method of moments, clipped to be positive
    /// semi-definite). A new path from a solver the grid has not seen is
    /// predicted around the mean of the solver means with covariance
    /// `W_w (1 + sum_v 1/n_wv / V^2) + B (1 + 1/V)`, as a Student t whose
    /// degrees of freedom combine those of W and B (Welch-Satterthwaite).
    pub fn fit_solvers(
        points: &[Vec<(usize, Vec<f64>)>],
        opts: &PosteriorOptions,
    ) -> Result<Self, PosteriorError> {
        let d = opts.dim();
        for (_, s) in points.iter().flatten() {
            if s.len() != d {
                return Err(PosteriorError::Dimension {
                    expected: d,
                    found: s.len(),
                });
            }
        }
        let groups: Vec<Vec<SolverStats>> = points.iter().map(|ys| solver_groups(ys, d)).collect();
        let within_dof: usize = groups.iter().flatten().map(|g| g.n - 1).sum();
        if within_dof == 0 {
            return Err(PosteriorError::NoReplicates);
        }
        let mut pooled = DMatrix::zeros(d, d);
        for g in groups.iter().flatten() {
            pooled += &g.scatter;
        }
        pooled /= within_dof as f64;
        let trace = pooled.trace();
        if !(trace.is_finite() && trace > 0.0) {
            return Err(PosteriorError::ZeroSpread);
        }
        // A ridge far below any real spread keeps a covariance with an
        // exactly collinear pair of coordinates invertible.
        let ridge = DMatrix::identity(d, d) * (1e-9 * trace / d as f64);
        let between = between_solver_covariance(&groups, &pooled, d, opts.solver_spread_floor);
        let densities = groups
            .iter()
            .map(|gs| point_density(gs, &pooled, between.as_ref(), &ridge, opts))
            .collect();
        Ok(Self {
            points: densities,
            dim: d,
        })
    }

    /// The largest, over the grid points, tail probability of coordinate
    /// `index` of `y` alone under the point's marginal density (a Student
    /// t with the point's degrees of freedom): P(F(1, nu) > delta_i^2).
    /// 0 when no point has a density or `index` is out of range.
    pub fn marginal_tail(&self, y: &[f64], index: usize) -> f64 {
        let Some(&yi) = y.get(index) else {
            return 0.0;
        };
        self.points
            .iter()
            .flatten()
            .filter(|p| index < p.mean.len())
            .map(|p| {
                let row = p.chol_l.row(index);
                let scale: f64 = row.iter().map(|v| v * v).sum();
                let delta2 = (yi - p.mean[index]).powi(2) / scale;
                f_upper_tail(delta2, 1.0, p.nu)
            })
            .fold(0.0, f64::max)
    }

    /// Whether each grid point has a density.
    pub fn available(&self) -> Vec<bool> {
        self.points.iter().map(Option::is_some).collect()
    }

    /// Scores one subject summary against the grid with prior weights
    /// `prior` (aligned with the points; see [`prior_weights`]).
    pub fn score(
        &self,
        y: &[f64],
        prior: &[f64],
        opts: &PosteriorOptions,
    ) -> Result<PosteriorScore, PosteriorError> {
        if y.len() != self.dim {
            return Err(PosteriorError::Dimension {
                expected: self.dim,
                found: y.len(),
            });
        }
        let y = DVector::from_column_slice(y);
        let d = self.dim as f64;
        let mut log_likelihood = Vec::with_capacity(self.points.len());
        let mut best_p = 0.0_f64;
        let mut min_delta2 = f64::INFINITY;
        for p in &self.points {
            match p {
                Some(p) => {
                    let (ll, delta2) = p.log_density(&y);
                    min_delta2 = min_delta2.min(delta2);
                    best_p = best_p.max(f_upper_tail(delta2 / d, d, p.nu));
                    log_likelihood.push(Some(ll).filter(|v| v.is_finite()));
                }
                None => log_likelihood.push(None),
            }
        }
        // log-sum-exp over points with a prior weight and a finite density.
        let terms: Vec<Option<f64>> = log_likelihood
            .iter()
            .zip(prior)
            .map(|(ll, &w)| match ll {
                Some(ll) if w > 0.0 => Some(ll + w.ln()),
                _ => None,
            })
            .collect();
        let max = terms
            .iter()
            .flatten()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        let mut probabilities: Vec<f64> = terms
            .iter()
            .map(|t| t.map_or(0.0, |t| (t - max).exp()))
            .collect();
        let total: f64 = probabilities.iter().sum();
        if total > 0.0 && total.is_finite() {
            probabilities.iter_mut().for_each(|v| *v /= total);
        } else {
            probabilities.iter_mut().for_each(|v| *v = 0.0);
        }
        let map = super::costs::argmax_first(&probabilities).filter(|&i| probabilities[i] > 0.0);
        let min_delta2 = if min_delta2.is_finite() {
            min_delta2
        } else {
            f64::MAX
        };
        Ok(PosteriorScore {
            credible: highest_probability_set(&probabilities, opts.credible_mass),
            log_likelihood,
            probabilities,
            map,
            out_of_model: OutOfModel {
                flagged: best_p < opts.out_of_model_p,
                statistic: min_delta2,
                p_value: best_p,
                threshold: opts.out_of_model_p,
                reason: None,
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::observables::path_summary;
    use super::*;

    fn opts(components: usize, pooling: f64) -> PosteriorOptions {
        PosteriorOptions {
            components,
            pooling,
            observables: Observables::Shape,
            ..PosteriorOptions::default()
        }
    }

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol * (1.0 + b.abs())
    }

    /// One-dimensional Student-t log density, written out from its
    /// textbook formula (independent of the matrix code).
    fn t_logpdf_1d(y: f64, mu: f64, scale2: f64, nu: f64) -> f64 {
        ln_gamma((nu + 1.0) / 2.0)
            - ln_gamma(nu / 2.0)
            - 0.5 * (nu * std::f64::consts::PI * scale2).ln()
            - 0.5 * (nu + 1.0) * (1.0 + (y - mu).powi(2) / (nu * scale2)).ln()
    }

    #[test]
    fn two_points_one_dimension_match_hand_computed_student_t() {
        // Point A: 0, 1, 2 (mean 1, scatter 2); point B: 4, 6 (mean 5,
        // scatter 2). Pooled variance 4 / 3. With pooling 2:
        // A: var (2 + 2 * 4/3) / (2 + 2) = 7/6, scale 7/6 * 4/3, nu = 4.
        // B: var (2 + 8/3) / (1 + 2) = 14/9, scale 14/9 * 3/2, nu = 3.
        let points = vec![
            vec![vec![0.0], vec![1.0], vec![2.0]],
            vec![vec![4.0], vec![6.0]],
        ];
        let o = opts(0, 2.0);
        let g = GridPosterior::fit(&points, &o).unwrap();
        let s = g.score(&[3.0], &[0.5, 0.5], &o).unwrap();
        let la = t_logpdf_1d(3.0, 1.0, 7.0 / 6.0 * 4.0 / 3.0, 4.0);
        let lb = t_logpdf_1d(3.0, 5.0, 14.0 / 9.0 * 1.5, 3.0);
        assert!(close(s.log_likelihood[0].unwrap(), la, 1e-6), "{s:?} {la}");
        assert!(close(s.log_likelihood[1].unwrap(), lb, 1e-6), "{s:?} {lb}");
        let pa = 1.0 / (1.0 + (lb - la).exp());
        assert!(close(s.probabilities[0], pa, 1e-9));
        assert!(close(s.probabilities[0] + s.probabilities[1], 1.0, 1e-12));
        // The prior multiplies in: 3:1 for A shifts the odds by 3.
        let s3 = g.score(&[3.0], &[0.75, 0.25], &o).unwrap();
        let odds = s3.probabilities[0] / s3.probabilities[1];
        assert!(close(odds, 3.0 * (la - lb).exp(), 1e-9));
    }

    #[test]
    fn single_trial_point_uses_the_pooled_covariance() {
        // Point B has one trial: its variance is the pooled one (1), scale
        // 1 * (1 + 1/1) = 2, nu = pooling = 3.
        let points = vec![
            vec![vec![-1.0], vec![1.0], vec![-1.0], vec![1.0]],
            vec![vec![10.0]],
        ];
        let o = opts(0, 3.0);
        let g = GridPosterior::fit(&points, &o).unwrap();
        let s = g.score(&[10.5], &[0.5, 0.5], &o).unwrap();
        // pooled = scatter 4 / dof 3
        let pooled = 4.0 / 3.0;
        let lb = t_logpdf_1d(10.5, 10.0, pooled * 2.0, 3.0);
        assert!(close(s.log_likelihood[1].unwrap(), lb, 1e-7));
        assert_eq!(s.map, Some(1));
    }

    #[test]
    fn no_replicates_and_zero_spread_are_typed_errors() {
        let o = opts(0, 2.0);
        let single = vec![vec![vec![1.0]], vec![vec![2.0]]];
        assert_eq!(
            GridPosterior::fit(&single, &o).unwrap_err(),
            PosteriorError::NoReplicates
        );
        let same = vec![vec![vec![1.0], vec![1.0]], vec![vec![2.0], vec![2.0]]];
        assert_eq!(
            GridPosterior::fit(&same, &o).unwrap_err(),
            PosteriorError::ZeroSpread
        );
    }

    #[test]
    fn identical_trials_at_one_point_borrow_spread_and_stay_finite() {
        let points = vec![
            vec![vec![1.0, 0.0], vec![1.0, 0.0], vec![1.0, 0.0]],
            vec![vec![2.0, 0.5], vec![2.2, 0.4], vec![1.8, 0.6]],
        ];
        let o = opts(1, 2.0);
        let g = GridPosterior::fit(&points, &o).unwrap();
        let s = g.score(&[1.0, 0.0], &[0.5, 0.5], &o).unwrap();
        assert!(s.probabilities.iter().all(|p| p.is_finite()));
        assert!(s.probabilities[0] > 0.99, "{s:?}");
    }

    #[test]
    fn collinear_summaries_are_kept_invertible_by_the_ridge() {
        // Second coordinate is exactly twice the first.
        let points = vec![
            vec![vec![1.0, 2.0], vec![2.0, 4.0], vec![3.0, 6.0]],
            vec![vec![5.0, 10.0], vec![6.0, 12.0]],
        ];
        let o = opts(1, 1.0);
        let g = GridPosterior::fit(&points, &o).unwrap();
        let s = g.score(&[2.0, 4.0], &[0.5, 0.5], &o).unwrap();
        assert!(s.probabilities.iter().all(|p| p.is_finite()));
        assert_eq!(s.map, Some(0));
    }

    #[test]
    fn far_away_subject_is_out_of_model_and_a_typical_one_is_not() {
        let points = vec![
            vec![vec![0.0], vec![1.0], vec![2.0], vec![1.0]],
            vec![vec![5.0], vec![6.0], vec![4.0], vec![5.0]],
        ];
        let o = opts(0, 2.0);
        let g = GridPosterior::fit(&points, &o).unwrap();
        let far = g.score(&[100.0], &[0.5, 0.5], &o).unwrap();
        assert!(far.out_of_model.flagged);
        assert!(far.out_of_model.p_value < 1e-3);
        assert!(far.probabilities.iter().all(|p| p.is_finite()));
        let near = g.score(&[1.2], &[0.5, 0.5], &o).unwrap();
        assert!(!near.out_of_model.flagged);
        assert!(near.out_of_model.p_value > 0.5);
    }

    #[test]
    fn f_tail_matches_closed_forms() {
        // F(2, nu) has the closed-form tail (1 + 2 f / nu)^(-nu / 2).
        for (f, nu) in [(0.5_f64, 3.0_f64), (2.0, 7.0), (10.0, 12.0)] {
            let want = (1.0 + 2.0 * f / nu).powf(-nu / 2.0);
            assert!(close(f_upper_tail(f, 2.0, nu), want, 1e-10));
        }
        // F(1, 1) tail = 1 - (2 / pi) atan(sqrt f).
        let want = 1.0 - 2.0 / std::f64::consts::PI * 3.0_f64.sqrt().atan();
        assert!(close(f_upper_tail(3.0, 1.0, 1.0), want, 1e-10));
        assert_eq!(f_upper_tail(0.0, 2.0, 3.0), 1.0);
        assert_eq!(f_upper_tail(f64::INFINITY, 2.0, 3.0), 0.0);
    }

    #[test]
    fn highest_probability_set_is_smallest_and_breaks_ties_by_index() {
        let s = highest_probability_set(&[0.1, 0.5, 0.3, 0.1], 0.9);
        assert_eq!(s.indices, vec![0, 1, 2]);
        assert!(close(s.mass, 0.9, 1e-12));
        let s = highest_probability_set(&[0.25, 0.25, 0.25, 0.25], 0.5);
        assert_eq!(s.indices, vec![0, 1]);
        let s = highest_probability_set(&[0.0, 1.0, 0.0], 0.9);
        assert_eq!(s.indices, vec![1]);
        assert!(highest_probability_set(&[0.0, 0.0], 0.9).indices.is_empty());
    }

    #[test]
    fn shortest_interval_fills_holes_and_prefers_fewer_points_then_more_mass() {
        // Mass at both ends of a gap: the highest-probability set skips the
        // middle, the interval holds it.
        let probs = [0.45, 0.05, 0.45, 0.05];
        let order = [0, 1, 2, 3];
        assert_eq!(highest_probability_set(&probs, 0.9).indices, vec![0, 2]);
        let s = shortest_interval_set(&probs, &order, 0.9);
        assert_eq!(s.indices, vec![0, 1, 2]);
        assert!(close(s.mass, 0.95, 1e-12));
        // Two runs of two points reach 0.5; the one with more mass wins.
        let s = shortest_interval_set(&[0.3, 0.25, 0.35, 0.1], &order, 0.5);
        assert_eq!(s.indices, vec![1, 2]);
        // The order is the parameter's, not the index order.
        let s = shortest_interval_set(&[0.5, 0.0, 0.5], &[1, 0, 2], 0.9);
        assert_eq!(s.indices, vec![0, 2]);
        assert!(shortest_interval_set(&[0.0, 0.0], &[0, 1], 0.9)
            .indices
            .is_empty());
    }

    #[test]
    fn one_solver_fit_equals_the_tagged_fit_and_a_second_solver_widens() {
        let a = vec![vec![0.0], vec![1.0], vec![2.0]];
        let b = vec![vec![4.0], vec![5.0], vec![6.0]];
        let o = opts(0, 2.0);
        let one = GridPosterior::fit(&[a.clone(), b.clone()], &o).unwrap();
        let tag = |ys: &[Vec<f64>], v: usize| -> Vec<(usize, Vec<f64>)> {
            ys.iter().map(|y| (v, y.clone())).collect()
        };
        let tagged = GridPosterior::fit_solvers(&[tag(&a, 3), tag(&b, 3)], &o).unwrap();
        let (s1, s2) = (
            one.score(&[3.0], &[0.5, 0.5], &o).unwrap(),
            tagged.score(&[3.0], &[0.5, 0.5], &o).unwrap(),
        );
        assert_eq!(s1, s2);
        // A second solver whose trials sit 2 higher at both points: the
        // point mean moves half-way, and the density widens by the spread
        // between solvers.
        let shift =
            |ys: &[Vec<f64>]| -> Vec<Vec<f64>> { ys.iter().map(|y| vec![y[0] + 2.0]).collect() };
        let mut pa = tag(&a, 0);
        pa.extend(tag(&shift(&a), 1));
        let mut pb = tag(&b, 0);
        pb.extend(tag(&shift(&b), 1));
        let two = GridPosterior::fit_solvers(&[pa, pb], &o).unwrap();
        // Within scatter per solver 2 at each of 4 groups: W = 8 / 8 = 1.
        // Solver means 1, 3 and 5, 7: scatter 2 + 2 over 2 dof = 2, less
        // W * mean(1/3) -> B = 2 - 1/3 = 5/3.
        // Point A: own dof 4, cov (4 + 2 W) / 6 = 1, times (1 + (2/3)/4)
        // = 7/6; plus B (1 + 1/2) = 5/2: scale 7/6 + 5/2 = 11/3, centre 2.
        let p = two.points[0].as_ref().unwrap();
        assert!(close(p.mean[0], 2.0, 1e-12));
        let scale = (p.chol_l[(0, 0)]).powi(2);
        assert!(close(scale, 11.0 / 3.0, 1e-8), "{scale}");
        // nu: within 4 + 2 = 6; between dof 2 -> 2; Welch-Satterthwaite.
        let (tw, tb) = (7.0 / 6.0, 5.0 / 2.0);
        let nu = (tw + tb) * (tw + tb) / (tw * tw / 6.0 + tb * tb / 2.0);
        assert!(close(p.nu, nu, 1e-8), "{} {nu}", p.nu);
    }

    #[test]
    fn spread_floor_raises_the_between_part_to_a_multiple_of_within() {
        let m = |r: &[f64]| DMatrix::from_row_slice(2, 2, r);
        let max_diff = |a: &DMatrix<f64>, b: &DMatrix<f64>| (a - b).abs().max();
        // Solvers that agree (raw B zero) under a correlated W: B = floor W.
        let w = m(&[2.0, 1.0, 1.0, 2.0]);
        let b = floored(&DMatrix::zeros(2, 2), &w, 0.5);
        assert!(max_diff(&b, &(&w * 0.5)) < 1e-12, "{b}");
        // Where the estimate is larger it is kept: raw diag(5, 0) against
        // W = diag(1, 4) and floor 0.5 gives diag(5, 2).
        let b = floored(&m(&[5.0, 0.0, 0.0, 0.0]), &m(&[1.0, 0.0, 0.0, 4.0]), 0.5);
        assert!(max_diff(&b, &m(&[5.0, 0.0, 0.0, 2.0])) < 1e-12, "{b}");
        // Floor 0 is the plain clip to positive semi-definite.
        let b = floored(&m(&[1.0, 0.0, 0.0, -3.0]), &w, 0.0);
        assert!(max_diff(&b, &m(&[1.0, 0.0, 0.0, 0.0])) < 1e-12, "{b}");
        // In a fit: two solvers that agree exactly give B = 0 without a
        // floor, and B = floor W with one (scale W_w (1 + ...) + floor W
        // (1 + 1/V)).
        let a = [vec![0.0], vec![1.0], vec![2.0]];
        let tagged: Vec<(usize, Vec<f64>)> = (0..2)
            .flat_map(|v| a.iter().map(move |y| (v, y.clone())))
            .collect();
        let fit = |floor: f64| {
            let o = PosteriorOptions {
                solver_spread_floor: floor,
                ..opts(0, 0.0)
            };
            let p = GridPosterior::fit_solvers(std::slice::from_ref(&tagged), &o).unwrap();
            p.points[0].as_ref().unwrap().chol_l[(0, 0)].powi(2)
        };
        // W = 4 / 4 = 1 (two groups of scatter 2, 2 dof each); the point's
        // own covariance 1 times (1 + (2/3)/4) = 7/6.
        assert!(close(fit(0.0), 7.0 / 6.0, 1e-8), "{}", fit(0.0));
        assert!(close(fit(2.0), 7.0 / 6.0 + 2.0 * 1.5, 1e-8), "{}", fit(2.0));
    }

    #[test]
    fn stored_options_without_a_floor_read_as_none_and_new_ones_get_the_default() {
        let old: PosteriorOptions = serde_json::from_str(r#"{"components": 2}"#).unwrap();
        assert_eq!(old.solver_spread_floor, 0.0);
        assert_eq!(
            PosteriorOptions::default().solver_spread_floor,
            DEFAULT_SOLVER_SPREAD_FLOOR
        );
        let bad = PosteriorOptions {
            solver_spread_floor: -1.0,
            ..PosteriorOptions::default()
        };
        assert!(bad.validate().is_err());
    }

    #[test]
    fn log_cell_prior_weighs_cells_in_log_space() {
        // 1, 2, 4, 8 are even in log: uniform.
        let w = prior_weights(&[1.0, 2.0, 4.0, 8.0], &[true; 4], Prior::LogCell);
        assert!(w.iter().all(|v| close(*v, 0.25, 1e-12)), "{w:?}");
        // Adding sqrt(2) between 1 and 2 halves the cells there.
        let v = [1.0, 2f64.sqrt(), 2.0, 4.0];
        let w = prior_weights(&v, &[true; 4], Prior::LogCell);
        let l2 = 2f64.ln();
        let raw = [l2 / 2.0, l2 / 2.0, 0.75 * l2, l2];
        let total: f64 = raw.iter().sum();
        for (a, b) in w.iter().zip(raw) {
            assert!(close(*a, b / total, 1e-12), "{w:?}");
        }
        // Unavailable points get nothing; non-positive values fall back to
        // uniform.
        let w = prior_weights(&[1.0, 2.0, 4.0], &[true, false, true], Prior::Uniform);
        assert_eq!(w, vec![0.5, 0.0, 0.5]);
        let w = prior_weights(&[0.0, 1.0], &[true, true], Prior::LogCell);
        assert_eq!(w, vec![0.5, 0.5]);
    }

    #[test]
    fn the_default_prior_is_log_cell_and_ignores_refinement_density() {
        assert_eq!(PosteriorOptions::default().prior, Prior::LogCell);
        assert_eq!(Prior::default(), Prior::LogCell);
        // The paper's grid: 0.1 and 0.5 sit in wider log cells.
        let paper = [0.1, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0];
        let w = prior_weights(&paper, &[true; 7], Prior::default());
        let (l5, l2) = (5f64.ln(), 2f64.ln());
        let raw = [l5, 0.5 * (l5 + l2), l2, l2, l2, l2, l2];
        let total: f64 = raw.iter().sum();
        for (a, b) in w.iter().zip(raw) {
            assert!(close(*a, b / total, 1e-12), "{w:?}");
        }
        // Refining between 4 and 8 adds mass to that interval only as its
        // log width, not per added point: [4, 8] keeps the same share.
        let coarse = prior_weights(&[1.0, 2.0, 4.0, 8.0, 16.0], &[true; 5], Prior::LogCell);
        let fine_v = [
            1.0,
            2.0,
            4.0,
            4.0 * 2f64.powf(0.25),
            4.0 * 2f64.sqrt(),
            8.0,
            16.0,
        ];
        let fine = prior_weights(&fine_v, &[true; 7], Prior::LogCell);
        let mass = |w: &[f64], idx: &[usize]| idx.iter().map(|&i| w[i]).sum::<f64>();
        // Mass of the points outside (4, 8) is unchanged but for the half
        // cells of 4 and 8 themselves.
        assert!(close(mass(&coarse, &[0, 1]), mass(&fine, &[0, 1]), 1e-12));
        assert!(close(coarse[4], fine[6], 1e-12));
    }

    #[test]
    fn sine_summary_recovers_planted_coefficients() {
        let n = 60;
        let x: Vec<f64> = (0..n)
            .map(|i| {
                let u = i as f64 / (n - 1) as f64;
                0.3 * (std::f64::consts::PI * u).sin()
                    - 0.1 * (2.0 * std::f64::consts::PI * u).sin()
            })
            .collect();
        let s = path_summary(&x, 0.07, 3).unwrap();
        assert_eq!(s[0], 0.07);
        assert!(close(s[1], 0.3, 1e-3), "{s:?}");
        assert!(close(s[2], -0.1, 1e-3), "{s:?}");
        assert!(s[3].abs() < 1e-3, "{s:?}");
        assert!(path_summary(&[0.0, f64::NAN], 0.0, 1).is_none());
    }

    #[test]
    fn options_validate_ranges() {
        assert!(PosteriorOptions::default().validate().is_ok());
        for bad in [
            PosteriorOptions {
                components: 9,
                ..Default::default()
            },
            PosteriorOptions {
                pooling: -1.0,
                ..Default::default()
            },
            PosteriorOptions {
                credible_mass: 1.0,
                ..Default::default()
            },
            PosteriorOptions {
                out_of_model_p: 0.0,
                ..Default::default()
            },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }
}
