//! Solver variants in a grid (docs/inference.md#solver-spread): which
//! solver produced a trial, and how good each solver was at each grid
//! point, measured against the trajectory optimizer's best return there.
//!
//! A subject is not a PPO run. Under a reward that is nearly flat in path
//! shape, two good solvers of the same task move in visibly different ways
//! at the same w1, so the grid can hold trials of several solvers (PPO at
//! different budgets or settings, the trajectory optimizer) and the
//! posterior models the spread between them.

use serde::{Deserialize, Serialize};

use super::stats::mean;

/// What kind of solver produced a trial.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default, Hash)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(rename_all = "snake_case")]
pub enum SolverKind {
    /// A PPO policy, sampled from noisy starts (docs/science.md#sampling).
    #[default]
    Ppo,
    /// The open-loop trajectory optimizer from the noise-free squat
    /// (docs/science.md#optimal-reference).
    Optimizer,
}

impl SolverKind {
    /// The spelling in documents and requests.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Ppo => "ppo",
            Self::Optimizer => "optimizer",
        }
    }
}

/// The solver variant a trial belongs to: its name within the search and
/// its kind. Trials of searches without variants are the one variant
/// `ppo`.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct SolverTag {
    /// Name of the variant, unique within a search.
    pub name: String,
    /// Its kind.
    #[serde(default)]
    pub kind: SolverKind,
}

/// Name of the one solver of a search that names none.
pub const DEFAULT_SOLVER: &str = "ppo";

impl Default for SolverTag {
    fn default() -> Self {
        Self {
            name: DEFAULT_SOLVER.to_string(),
            kind: SolverKind::Ppo,
        }
    }
}

/// One solver variant at one grid point: what its usable trials reached
/// (each trial by its highest-return kept episode, the path the posterior
/// uses) and, for a PPO variant, how far that is below the optimum.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct SolverAtPoint {
    /// The variant.
    pub solver: SolverTag,
    /// Its usable trials at this point.
    pub trials_used: u32,
    /// Mean over those trials of the best kept episode's return.
    pub best_return_mean: Option<f64>,
    /// Highest best-episode return of any of its trials.
    pub best_return_max: Option<f64>,
    /// Mean duration of those episodes (s): the stand-up's time.
    pub duration_mean: Option<f64>,
    /// Mean trajectory area of those episodes.
    pub area_mean: Option<f64>,
    /// PPO variants: `100 (optimum - best_return_mean) / |optimum|`, the
    /// solver's gap to the optimizer's best return at this point, in %
    /// (negative when PPO did better); `null` without an optimizer.
    pub gap_pct: Option<f64>,
}

/// The best movement any optimizer variant found at a grid point.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct OptimumAtPoint {
    /// The optimizer variant that found it.
    pub solver: String,
    /// Its return (from the noise-free squat).
    pub best_return: f64,
    /// Its duration (s).
    pub duration: Option<f64>,
    /// Its trajectory area.
    pub area: Option<f64>,
}

/// One trial's contribution to the per-point solver table: its variant's
/// index, and its best kept episode's return, duration and area.
pub(crate) struct TrialBest {
    pub(crate) solver: usize,
    pub(crate) ret: f64,
    pub(crate) duration: Option<f64>,
    pub(crate) area: f64,
}

/// The per-point solver table and the optimum (see [`SolverAtPoint`]) from
/// the usable trials' best episodes; `solvers` are the grid's variants in
/// order, and each one that has a usable trial here gets a row.
pub(crate) fn solver_table(
    solvers: &[SolverTag],
    trials: &[TrialBest],
) -> (Vec<SolverAtPoint>, Option<OptimumAtPoint>) {
    let optimum = trials
        .iter()
        .filter(|t| solvers[t.solver].kind == SolverKind::Optimizer && t.ret.is_finite())
        .max_by(|a, b| a.ret.total_cmp(&b.ret))
        .map(|t| OptimumAtPoint {
            solver: solvers[t.solver].name.clone(),
            best_return: t.ret,
            duration: t.duration,
            area: Some(t.area).filter(|a| a.is_finite()),
        });
    let rows = solvers
        .iter()
        .enumerate()
        .filter_map(|(v, tag)| {
            let mine: Vec<&TrialBest> = trials.iter().filter(|t| t.solver == v).collect();
            if mine.is_empty() {
                return None;
            }
            let rets: Vec<f64> = mine
                .iter()
                .map(|t| t.ret)
                .filter(|r| r.is_finite())
                .collect();
            let durations: Vec<f64> = mine.iter().filter_map(|t| t.duration).collect();
            let areas: Vec<f64> = mine
                .iter()
                .map(|t| t.area)
                .filter(|a| a.is_finite())
                .collect();
            let best_return_mean = mean(&rets);
            let gap_pct = match (&optimum, best_return_mean, tag.kind) {
                (Some(o), Some(m), SolverKind::Ppo) if o.best_return != 0.0 => {
                    Some(100.0 * (o.best_return - m) / o.best_return.abs())
                }
                _ => None,
            };
            Some(SolverAtPoint {
                solver: tag.clone(),
                trials_used: u32::try_from(mine.len()).unwrap_or(u32::MAX),
                best_return_mean,
                best_return_max: rets.iter().copied().reduce(f64::max),
                duration_mean: mean(&durations),
                area_mean: mean(&areas),
                gap_pct,
            })
        })
        .collect();
    (rows, optimum)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn best(solver: usize, ret: f64, area: f64) -> TrialBest {
        TrialBest {
            solver,
            ret,
            duration: Some(0.3),
            area,
        }
    }

    #[test]
    fn gap_is_measured_against_the_best_optimizer_trial() {
        let solvers = vec![
            SolverTag::default(),
            SolverTag {
                name: "cem".into(),
                kind: SolverKind::Optimizer,
            },
            SolverTag {
                name: "ppo-short".into(),
                kind: SolverKind::Ppo,
            },
        ];
        let trials = [
            best(0, 990.0, 0.04),
            best(0, 970.0, 0.06),
            best(1, 995.0, 0.05),
            best(1, 1000.0, 0.03),
        ];
        let (rows, opt) = solver_table(&solvers, &trials);
        let opt = opt.unwrap();
        assert_eq!((opt.solver.as_str(), opt.best_return), ("cem", 1000.0));
        assert_eq!(opt.area, Some(0.03));
        // ppo: mean 980, 2 % below 1000; the optimizer has no gap; the
        // third variant has no trial here and no row.
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0].best_return_mean, Some(980.0));
        assert!((rows[0].gap_pct.unwrap() - 2.0).abs() < 1e-12);
        assert!((rows[0].area_mean.unwrap() - 0.05).abs() < 1e-12);
        assert_eq!(rows[1].gap_pct, None);
        assert_eq!(rows[1].best_return_max, Some(1000.0));
        // Without an optimizer there is no optimum and no gap.
        let (rows, opt) = solver_table(&solvers[..1], &trials[..2]);
        assert!(opt.is_none() && rows[0].gap_pct.is_none());
    }

    #[test]
    fn a_trial_without_a_variant_reads_as_the_default_ppo() {
        let t: SolverTag = serde_json::from_str(r#"{"name":"ppo"}"#).unwrap();
        assert_eq!(t, SolverTag::default());
        assert_eq!(SolverKind::Optimizer.as_str(), "optimizer");
    }
}
