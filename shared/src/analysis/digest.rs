//! A trial's digest (docs/science.md#aggregation): what the result
//! document needs of one uploaded output, computed once per output. The
//! digest holds the 60-point means of the trial's resampled episodes, its
//! area, torque usage and counts, and its top episode (return, resampled
//! path, duration and timing); the posterior's summary vector is cut from
//! that top path when a document is built (its length depends on the
//! report's options). Aggregating digests gives the same document as
//! aggregating the raw episodes, at a cost that does not grow with the
//! trajectories' length: the coordinator stores one per accepted upload
//! and builds every document from them.

use std::collections::BTreeMap;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::inputs::{EpisodeRecord, TrialInput, WeightInput};
use super::preprocess::{resample_path, ResampledPath};
use super::solvers::SolverTag;
use super::stats::{mean, pointwise_mean};
use super::timing::{stand_up_timing, Timing};

/// The highest-return resampled episode of a trial.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct TopEpisode {
    /// Its return (finite).
    pub ret: f64,
    /// Its resampled path.
    pub path: ResampledPath,
    /// Its duration (s): the last sample time, if finite.
    pub duration: Option<f64>,
    /// Its timing (docs/science.md#timing), or why it has none.
    pub timing: Result<Timing, String>,
}

/// What aggregation needs of one output (see the module header). Notes are
/// kept without the point and trial they belong to; the document adds them.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct TrialDigest {
    /// Final training success rate; `None` if not finite.
    pub final_success_rate: Option<f64>,
    /// Mean area over the resampled episodes; `None` if none.
    pub area: Option<f64>,
    /// Mean torque usage over the kept episodes with a finite one.
    pub torque_usage: Option<f64>,
    /// Successful episodes found while sampling.
    pub successes_found: u32,
    /// Successful episodes wanted.
    pub successes_wanted: u32,
    /// Kept episodes received.
    pub episodes: u32,
    /// Kept episodes whose path could be resampled.
    pub episodes_resampled: u32,
    /// Pointwise mean x of the resampled episodes (empty if none).
    pub mean_x: Vec<f64>,
    /// Pointwise mean z of the resampled episodes (empty if none).
    pub mean_z: Vec<f64>,
    /// The resampled episode with the highest finite return, if any.
    pub top: Option<TopEpisode>,
    /// What went wrong with the output's data, in order.
    pub notes: Vec<String>,
}

fn count(n: usize) -> u32 {
    u32::try_from(n).unwrap_or(u32::MAX)
}

impl TrialDigest {
    /// The digest of one output: resamples each kept episode once.
    pub fn of(
        episodes: &[EpisodeRecord],
        final_success_rate: f64,
        successes_found: u32,
        successes_wanted: u32,
    ) -> Self {
        let mut notes = Vec::new();
        let mut paths: Vec<(f64, ResampledPath, usize)> = Vec::new();
        for (e, ep) in episodes.iter().enumerate() {
            match resample_path(&ep.com_x, &ep.com_z) {
                Ok(p) => paths.push((ep.ret, p, e)),
                Err(err) => notes.push(format!("episode {e} not resampled: {err}")),
            }
        }
        let torques: Vec<f64> = episodes
            .iter()
            .map(|ep| ep.torque_usage)
            .filter(|v| v.is_finite())
            .collect();
        if torques.len() < episodes.len() {
            notes.push(format!(
                "{} episode(s) with non-finite torque usage left out",
                episodes.len() - torques.len()
            ));
        }
        let rate = Some(final_success_rate).filter(|v| v.is_finite());
        if rate.is_none() {
            notes.push("final success rate is not finite".to_string());
        }
        let areas: Vec<f64> = paths.iter().map(|(_, p, _)| p.area).collect();
        let xs: Vec<&[f64]> = paths.iter().map(|(_, p, _)| p.x.as_slice()).collect();
        let zs: Vec<&[f64]> = paths.iter().map(|(_, p, _)| p.z.as_slice()).collect();
        // Resampled paths all have RESAMPLE_POINTS points, so only "no paths" can fail.
        let mean_x = pointwise_mean(&xs).unwrap_or_default();
        let mean_z = pointwise_mean(&zs).unwrap_or_default();
        let mut top: Option<(f64, ResampledPath, usize)> = None;
        for (ret, p, e) in paths {
            if ret.is_finite() && top.as_ref().is_none_or(|(best, _, _)| ret > *best) {
                top = Some((ret, p, e));
            }
        }
        let top = top.map(|(ret, path, e)| {
            let ep = &episodes[e];
            TopEpisode {
                ret,
                path,
                duration: ep.com_t.last().copied().filter(|t| t.is_finite()),
                timing: stand_up_timing(&ep.com_t, &ep.com_x, &ep.com_z)
                    .map_err(|err| err.to_string()),
            }
        });
        Self {
            final_success_rate: rate,
            area: mean(&areas).filter(|v| v.is_finite()),
            torque_usage: mean(&torques).filter(|v| v.is_finite()),
            successes_found,
            successes_wanted,
            episodes: count(episodes.len()),
            episodes_resampled: count(areas.len()),
            mean_x,
            mean_z,
            top,
            notes,
        }
    }
}

/// One finished trial as aggregation takes it: the job's facts and the
/// digest of its output.
#[derive(Clone, Debug, PartialEq)]
pub struct DigestedTrial {
    /// Trial number within its grid point.
    pub trial: u32,
    /// Training seed.
    pub seed: u64,
    /// Whether training met its convergence criterion.
    pub converged: bool,
    /// The solver variant that produced it.
    pub solver: SolverTag,
    /// Its output's digest (shared: a store may keep digests between builds).
    pub digest: Arc<TrialDigest>,
}

impl DigestedTrial {
    /// Digests a trial's raw input.
    pub fn of(t: &TrialInput) -> Self {
        Self {
            trial: t.trial,
            seed: t.seed,
            converged: t.converged,
            solver: t.solver.clone(),
            digest: Arc::new(TrialDigest::of(
                &t.episodes,
                t.final_success_rate,
                t.successes_found,
                t.successes_wanted,
            )),
        }
    }
}

/// All digested trials of one reward-grid point.
#[derive(Clone, Debug, PartialEq)]
pub struct PointDigests {
    /// Reward parameters of this grid point.
    pub params: BTreeMap<String, f64>,
    /// Its finished trials.
    pub trials: Vec<DigestedTrial>,
}

impl PointDigests {
    /// Digests every trial of a grid point's raw input.
    pub fn of(w: &WeightInput) -> Self {
        Self {
            params: w.params.clone(),
            trials: w.trials.iter().map(DigestedTrial::of).collect(),
        }
    }
}

/// Digests a whole grid's raw input.
pub fn digest_grid(weights: &[WeightInput]) -> Vec<PointDigests> {
    weights.iter().map(PointDigests::of).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::{
        build_report_from, build_report_with, Identifiability, Observables, ReportOptions,
    };
    use crate::test_support::{varied_grid, varied_subjects};

    /// The digests as a store keeps them: through their JSON text.
    fn stored(points: &[PointDigests]) -> Vec<PointDigests> {
        points
            .iter()
            .map(|p| PointDigests {
                params: p.params.clone(),
                trials: p
                    .trials
                    .iter()
                    .map(|t| {
                        let text = serde_json::to_string(&*t.digest).unwrap();
                        DigestedTrial {
                            digest: Arc::new(serde_json::from_str(&text).unwrap()),
                            ..t.clone()
                        }
                    })
                    .collect(),
            })
            .collect()
    }

    #[test]
    fn digests_survive_their_json_text_exactly() {
        let points = digest_grid(&varied_grid(4));
        assert_eq!(stored(&points), points);
        let t = &points[0].trials[0].digest;
        assert_eq!(t.mean_x.len(), crate::analysis::RESAMPLE_POINTS);
        assert!(t.top.as_ref().is_some_and(|t| t.timing.is_ok()));
        // The grid has what the document must note: broken episodes,
        // non-finite returns, torques and rates.
        let notes: Vec<&String> = points
            .iter()
            .flat_map(|p| &p.trials)
            .flat_map(|t| &t.digest.notes)
            .collect();
        for what in ["not resampled", "non-finite torque", "rate is not finite"] {
            assert!(notes.iter().any(|n| n.contains(what)), "{what}: {notes:?}");
        }
    }

    #[test]
    fn documents_from_stored_digests_equal_documents_from_raw_episodes() {
        let grid = varied_grid(4);
        let points = stored(&digest_grid(&grid));
        let subjects = varied_subjects();
        for obs in [Observables::Shape, Observables::ShapeTiming] {
            let mut opts = ReportOptions::default();
            opts.posterior.observables = obs;
            for when in [Identifiability::Always, Identifiability::Never] {
                let raw = build_report_with(&grid, &subjects, &opts, when);
                let digested = build_report_from(&points, &subjects, &opts, when);
                let (a, b) = (
                    serde_json::to_value(&raw).unwrap(),
                    serde_json::to_value(&digested).unwrap(),
                );
                assert!(a == b, "{obs} {when:?}: documents differ");
                assert!(!raw.notes.is_empty());
                assert_eq!(
                    when == Identifiability::Always,
                    raw.identifiability.is_some()
                );
            }
        }
    }
}
