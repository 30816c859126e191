//! JSON wire types of the coordinator's REST API (`/api/v1`), shared by the
//! coordinator, the worker and the CLI, plus the documented derivation of a
//! job's seed from its search's base seed. Plain serde types: no I/O.
//!
//! Science configurations (`training` = `ppo::PpoConfig`, `sampling` =
//! `sample::SamplingConfig`, `env` = `env::EnvConfig`) travel as JSON objects
//! in exactly those types' serde form. A search request carries them as
//! [`Partial`] configurations (resolved strictly over the defaults or a
//! preset at intake, errors naming the field); the coordinator stores the resolved
//! [`ResolvedConfig`] with every default filled in, so a job's configuration
//! is complete and reproducible even if a later release changes a default,
//! and leases carry it typed in [`JobSpec`].

use std::borrow::Cow;
use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

mod partial;
pub mod routes;
pub use partial::{Partial, PartialError};

/// A grid point's text form, owned by the analysis ([`crate::analysis::points`]).
pub use crate::analysis::{point_label, point_label_with};
use crate::analysis::{
    EpisodeRecord, ReportOptions, ResultDocument, SolverKind, SolverTag, SubjectSummary,
    DEFAULT_SOLVER,
};
use crate::env::EnvConfig;
use crate::optimize::OptimizeConfig;
use crate::ppo::PpoConfig;
use crate::sample::SamplingConfig;

/// Default final success rate a trial needs to count as converged.
pub const DEFAULT_CONVERGENCE_THRESHOLD: f64 = 0.5;
/// Default number of leases a job may lose (expiry or worker failure) before
/// it is marked failed.
pub const DEFAULT_MAX_ATTEMPTS: u32 = 3;

/// The full configuration a search's jobs run with, every default filled
/// in; stored with the search, and its first three parts are sent with
/// every lease ([`JobSpec`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResolvedConfig {
    /// Trainer.
    pub training: PpoConfig,
    /// Sampler.
    pub sampling: SamplingConfig,
    /// Task before the grid point's reward parameters are applied.
    pub env: EnvConfig,
    /// Aggregation options.
    pub report: ReportOptions,
    /// The search's solver variants, in order (docs/inference.md#solver-spread);
    /// empty for a search of the one PPO solver that `training` configures.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub solvers: Vec<SolverSpec>,
}

impl ResolvedConfig {
    /// The search's solver variants: the stored list, or the one PPO
    /// variant of a search that names none.
    pub fn solver_specs(&self) -> Vec<SolverSpec> {
        if self.solvers.is_empty() {
            vec![SolverSpec::Ppo {
                name: DEFAULT_SOLVER.to_string(),
                training: self.training.clone(),
            }]
        } else {
            self.solvers.clone()
        }
    }
}

/// One solver variant of a search request (the `solvers` list): every
/// (point, trial, variant) is one job. Omitted settings take the search's
/// (`training`) or the optimizer's defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct SolverRequest {
    /// Name, unique within the search (1-40 letters, digits, `-`, `_` or `.`).
    pub name: String,
    /// `ppo` or `optimizer`.
    pub kind: SolverKind,
    /// PPO only: trainer settings (`ppo::PpoConfig` fields), partial, over
    /// the search's `training`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub training: Option<Partial<PpoConfig>>,
    /// Optimizer only: cross-entropy settings (`optimize::OptimizeConfig`
    /// fields, e.g. `restarts`, `iterations`, `population`), partial; the
    /// job's seed replaces `seed`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub optimizer: Option<Partial<OptimizeConfig>>,
}

/// A solver variant with every setting resolved, as stored with the search
/// and sent with each of its jobs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum SolverSpec {
    /// PPO with its own trainer settings; the job trains a policy and
    /// samples its best kept episodes.
    Ppo {
        /// Variant name.
        name: String,
        /// Trainer.
        training: PpoConfig,
    },
    /// The trajectory optimizer from the noise-free squat
    /// (docs/science.md#optimal-reference); the job uploads its best path.
    Optimizer {
        /// Variant name.
        name: String,
        /// Cross-entropy settings (the job's seed replaces `seed`).
        optimizer: OptimizeConfig,
    },
}

impl SolverSpec {
    /// The variant's name.
    pub fn name(&self) -> &str {
        match self {
            Self::Ppo { name, .. } | Self::Optimizer { name, .. } => name,
        }
    }

    /// The variant's kind.
    pub fn kind(&self) -> SolverKind {
        match self {
            Self::Ppo { .. } => SolverKind::Ppo,
            Self::Optimizer { .. } => SolverKind::Optimizer,
        }
    }

    /// The tag its trials carry in the analysis.
    pub fn tag(&self) -> SolverTag {
        SolverTag {
            name: self.name().to_string(),
            kind: self.kind(),
        }
    }
}

/// `POST /api/v1/searches` body. Omitted fields take the `shared` defaults.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct SearchRequest {
    /// Free-form label shown in listings (1-200 characters).
    #[serde(default)]
    pub name: String,
    /// Reward parameter name -> values; several parameters give their
    /// cartesian product (the paper's grid is `{"w1": [0.1, ..., 16]}`).
    pub reward_grid: BTreeMap<String, Vec<f64>>,
    /// Converged trials wanted per grid point.
    pub trials: u32,
    /// Named reward preset (`env::presets`, default `paper`) the task's reward
    /// starts from; `env.reward` fields and the grid override its values.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reward_preset: Option<String>,
    /// Base seed; each job's seed is [`job_seed`] of it.
    #[serde(default)]
    pub seed: u64,
    /// Trainer configuration (`ppo::PpoConfig` fields), partial.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub training: Option<Partial<PpoConfig>>,
    /// Sampler configuration (`sample::SamplingConfig` fields), partial.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sampling: Option<Partial<SamplingConfig>>,
    /// Environment configuration (`env::EnvConfig` fields), partial, over
    /// the reward preset; the grid point's reward parameters are applied on
    /// top of it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub env: Option<Partial<EnvConfig>>,
    /// Subject trajectories, CSV `subject,time,x,z` (docs/science.md#subject-data).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub subjects_csv: Option<String>,
    /// Final success rate a trial needs to count as converged (default 0.5).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub convergence_threshold: Option<f64>,
    /// Enqueue a replacement trial (fresh seed) for every trial that does not
    /// converge or fails, until each point has `trials` converged trials or
    /// `max_trials_per_point` trials in all.
    #[serde(default)]
    pub replace_unconverged: bool,
    /// Cap on trials per point, replacements included (default 2 x trials).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_trials_per_point: Option<u32>,
    /// Leases a job may lose before it fails (default 3).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_attempts: Option<u32>,
    /// Refine the grid toward the subjects once it has finished (a
    /// one-parameter grid with subjects only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refine: Option<RefineRequest>,
    /// Solver variants (docs/inference.md#solver-spread): each (point,
    /// trial) runs once per variant. Omitted: one PPO variant, `ppo`,
    /// configured by `training`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub solvers: Option<Vec<SolverRequest>>,
    /// The evidence the posterior uses (docs/inference.md#observables):
    /// `shape`, `timing`, `relative_timing`, `shape+timing` or
    /// `shape+relative_timing`. Omitted: the measured default of the
    /// reward preset (`relative_timing` under `power`, `shape` otherwise);
    /// stored in the resolved configuration (`report.posterior.observables`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub observables: Option<crate::analysis::Observables>,
}

/// Adaptive refinement of a finished one-parameter grid toward its
/// subjects (docs/science.md#refinement): the `refine` field of a search
/// request, and the body of `POST /api/v1/searches/{id}/refine`. Omitted
/// fields take the defaults.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct RefineRequest {
    /// Most rounds of added midpoints (default 3).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rounds: Option<u32>,
    /// Trials per added point (default: the search's trials per point).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trials: Option<u32>,
    /// A subject needs no more points once the ratio of its two
    /// neighbouring candidates is below this (default 1.2).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_ratio: Option<f64>,
    /// Under the posterior, a subject asks for a point only when its two
    /// candidates hold at least this much of its posterior mass (default
    /// 0.5): a flat posterior is not sharpened by more points.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_pair_mass: Option<f64>,
}

/// A [`RefineRequest`] with every default filled in, as stored with the
/// search.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct RefineSpec {
    /// Most rounds of added midpoints.
    pub rounds: u32,
    /// Trials per added point.
    pub trials: u32,
    /// Neighbour ratio at which a subject is settled.
    pub target_ratio: f64,
    /// Posterior mass the two candidates must hold for a subject to ask
    /// for their midpoint.
    #[serde(default = "default_min_pair_mass")]
    pub min_pair_mass: f64,
    /// The grid parameter refined (the search's only one).
    pub param: String,
    /// Number of the first evaluation of this refinement (0 for one asked
    /// for at submission; later for `POST .../refine` on a finished search).
    pub first_round: u32,
}

fn default_min_pair_mass() -> f64 {
    crate::analysis::refine::DEFAULT_MIN_PAIR_MASS
}

impl RefineSpec {
    /// The rule a round applies.
    pub fn rule(&self) -> crate::analysis::refine::RefineRule {
        crate::analysis::refine::RefineRule {
            target_ratio: self.target_ratio,
            min_pair_mass: self.min_pair_mass,
        }
    }
}

/// One evaluation of a refining search's grid: round 0 reads the grid as
/// submitted, round r the grid after r rounds of added midpoints.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct RefineRound {
    /// Evaluation number.
    pub round: u32,
    /// Every subject's reading of the grid at that point.
    pub subjects: Vec<crate::analysis::SubjectRefinement>,
    /// Points this round added (the subjects' distinct midpoints).
    pub added: Vec<f64>,
    /// Why refinement ended with this round, if it did.
    pub stop: Option<String>,
    /// When it was evaluated (RFC 3339, UTC).
    pub at: String,
}

/// `GET /api/v1/searches/{id}/refinement`, and the answer to `POST
/// .../refine`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct Refinement {
    /// The search's id.
    pub id: String,
    /// The search's state.
    pub status: SearchState,
    /// The refinement asked for, if any.
    pub spec: Option<RefineSpec>,
    /// `pending` (rounds to come), `settled` (ended), or `none`.
    pub state: String,
    /// Every evaluation so far, in order.
    pub rounds: Vec<RefineRound>,
}

/// `201` answer to a submission.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct Created {
    /// The new search's id.
    pub id: String,
    /// Jobs enqueued.
    pub jobs: u64,
}

/// `POST /api/v1/searches/{id}/extend` body: more trials per point, more
/// grid values, or both. Jobs already in the search are kept as they are;
/// the new ones get the seeds [`job_seed`] gives their (point, trial).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct ExtendRequest {
    /// The new number of converged trials wanted per point (at least the
    /// current one); every point, old and new, gets trials `0..trials`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trials: Option<u32>,
    /// Values to add per grid parameter (parameters of the search's grid
    /// only); the grid becomes the product of the extended value lists.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub reward_grid: BTreeMap<String, Vec<f64>>,
}

/// `200` answer to an extension.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct Extended {
    /// The search's id.
    pub id: String,
    /// Search state after the extension (`running` when jobs were added).
    pub status: SearchState,
    /// Converged trials wanted per point now.
    pub trials: u32,
    /// Grid points now.
    pub points: u64,
    /// Grid points added by this extension.
    pub points_added: u64,
    /// Jobs enqueued by this extension.
    pub jobs_added: u64,
    /// 1-based number of this extension of the search.
    pub extension: u32,
}

/// Lifecycle of a search.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(rename_all = "snake_case")]
pub enum SearchState {
    /// Jobs are queued or leased.
    Running,
    /// Every job is done or failed; the result document is final.
    Completed,
    /// Cancelled by a user; finished jobs are kept.
    Cancelled,
}

impl SearchState {
    /// Every state, in lifecycle order.
    pub const ALL: [SearchState; 3] = [Self::Running, Self::Completed, Self::Cancelled];

    /// The database spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Running => "running",
            Self::Completed => "completed",
            Self::Cancelled => "cancelled",
        }
    }

    /// Parses the database spelling.
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|st| st.as_str() == s)
    }
}

/// Lifecycle of a job: queued -> leased -> done | failed, or cancelled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(rename_all = "snake_case")]
pub enum JobState {
    /// Waiting for a worker.
    Queued,
    /// Leased to a worker.
    Leased,
    /// Result accepted.
    Done,
    /// Lost or failed `max_attempts` leases.
    Failed,
    /// Its search was cancelled before it finished.
    Cancelled,
}

impl JobState {
    /// Every state, in lifecycle order.
    pub const ALL: [JobState; 5] = [
        Self::Queued,
        Self::Leased,
        Self::Done,
        Self::Failed,
        Self::Cancelled,
    ];

    /// The database spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Queued => "queued",
            Self::Leased => "leased",
            Self::Done => "done",
            Self::Failed => "failed",
            Self::Cancelled => "cancelled",
        }
    }

    /// Parses the database spelling.
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|st| st.as_str() == s)
    }
}

/// Job counts by state.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct JobCounts {
    /// Waiting for a worker.
    pub queued: u64,
    /// Leased now.
    pub leased: u64,
    /// Result accepted.
    pub done: u64,
    /// Failed after `max_attempts`.
    pub failed: u64,
    /// Cancelled.
    pub cancelled: u64,
    /// All jobs, replacements included.
    pub total: u64,
}

/// `GET /api/v1/searches/{id}` (and each entry of the listing).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct SearchStatus {
    /// Search id.
    pub id: String,
    /// Label.
    pub name: String,
    /// Lifecycle state.
    pub status: SearchState,
    /// Grid points.
    pub points: u64,
    /// Converged trials wanted per point.
    pub trials: u32,
    /// Jobs by state.
    pub jobs: JobCounts,
    /// Done trials at or above the convergence threshold.
    pub trials_converged: u64,
    /// Done trials below it (kept, shown, left out of the means).
    pub trials_not_converged: u64,
    /// Done trials whose sampling found fewer successful episodes than asked.
    pub trials_with_shortfall: u64,
    /// Distinct workers holding a lease of this search now.
    pub workers_busy: u64,
    /// Submission time (RFC 3339, UTC).
    pub created_at: String,
    /// First lease (RFC 3339), if any.
    pub started_at: Option<String>,
    /// Completion or cancellation (RFC 3339), if any.
    pub finished_at: Option<String>,
    /// Rough seconds to completion from the mean job duration so far.
    pub eta_secs: Option<f64>,
    /// Final success rate needed to count as converged.
    pub convergence_threshold: f64,
}

/// Progress of a job as reported by its worker's heartbeats. Values that are
/// undefined so far (no finished episode yet) are `null`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct ProgressPoint {
    /// Environment steps trained so far.
    pub env_steps: u64,
    /// Training budget in environment steps.
    pub total_env_steps: u64,
    /// Mean return of the episodes finished in the last update.
    #[serde(default)]
    pub mean_return: Option<f64>,
    /// Success rate of the episodes finished in the last update.
    #[serde(default)]
    pub success_rate: Option<f64>,
    /// Mean episode length (control steps).
    #[serde(default)]
    pub mean_episode_length: Option<f64>,
    /// PPO policy loss.
    #[serde(default)]
    pub policy_loss: Option<f64>,
    /// PPO value loss.
    #[serde(default)]
    pub value_loss: Option<f64>,
    /// Policy entropy.
    #[serde(default)]
    pub entropy: Option<f64>,
    /// Approximate KL divergence of the update.
    #[serde(default)]
    pub approx_kl: Option<f64>,
}

/// What a worker is doing with its job.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(rename_all = "snake_case")]
pub enum JobPhase {
    /// Training the policy (PPO).
    #[default]
    Training,
    /// Rolling out the trained policy for trajectories.
    Sampling,
}

/// `POST /api/v1/leases` body: ask for one job.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct LeaseRequest {
    /// Worker identity recorded as the lease owner (1-200 characters).
    pub worker: String,
    /// Wait up to this many seconds (0-30) for a job before answering 204.
    #[serde(default)]
    pub wait_secs: u32,
}

/// `200` answer to a lease request: the job and its lease.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct Lease {
    /// Job id, used in the job endpoints' paths.
    pub job_id: i64,
    /// Random lease token; every job call must carry it.
    pub lease_token: String,
    /// Lease length; a heartbeat renews it for as long again.
    pub lease_secs: u64,
    /// Suggested heartbeat period (a third of the lease).
    pub heartbeat_secs: u64,
    /// What to compute.
    pub spec: JobSpec,
}

/// Everything a worker needs to run one (point, trial) job.
///
/// Strict both ways: an unknown field here or in the three configurations
/// (all `deny_unknown_fields`) is refused, so a worker never silently runs
/// a job without a setting that a newer coordinator sent.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct JobSpec {
    /// Search id.
    pub search_id: String,
    /// Search label.
    pub search_name: String,
    /// Index of the grid point.
    pub point_idx: u32,
    /// Reward parameters of the point (applied with `RewardConfig::set_param`).
    pub params: BTreeMap<String, f64>,
    /// Trial number within the point (0-based; replacements continue it).
    pub trial: u32,
    /// Seed of this job ([`job_seed`]).
    pub seed: u64,
    /// 1-based lease number of this job (retries after lost leases count).
    pub attempt: u32,
    /// Resolved trainer configuration.
    pub training: PpoConfig,
    /// Resolved sampler configuration.
    pub sampling: SamplingConfig,
    /// Resolved task before the point's parameters are applied.
    pub env: EnvConfig,
    /// Final success rate needed to count as converged.
    pub convergence_threshold: f64,
    /// The solver variant to run, for a search with variants; absent: PPO
    /// with `training`. A PPO variant's settings are also in `training`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub solver: Option<SolverSpec>,
}

/// `POST /api/v1/jobs/{id}/heartbeat` body.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct Heartbeat {
    /// The lease's token.
    pub lease_token: String,
    /// Current phase.
    #[serde(default)]
    pub phase: JobPhase,
    /// Progress points since the last heartbeat, oldest first (at most 1000).
    #[serde(default)]
    pub progress: Vec<ProgressPoint>,
}

/// `200` answer to a heartbeat.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct HeartbeatAck {
    /// Seconds until the renewed lease expires.
    pub lease_secs: u64,
}

/// The output of one job: what the sampler kept plus the numbers the
/// aggregation needs (docs/science.md#sampling).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct JobOutput {
    /// Final success rate of the trained policy (successes / attempts of the
    /// sampling rollouts unless the trainer reports one), in [0, 1].
    pub final_success_rate: f64,
    /// Environment steps the trainer used.
    pub env_steps: u64,
    /// Successful episodes the sampler found.
    pub successes_found: u32,
    /// Successful episodes it was asked for (shortfall = wanted - found).
    pub successes_wanted: u32,
    /// Episodes the sampler rolled out.
    pub sampling_attempts: u32,
    /// The kept episodes (top-k successful by return).
    pub episodes: Vec<EpisodeRecord>,
    /// Wall-clock seconds spent training.
    #[serde(default)]
    pub train_secs: f64,
    /// Wall-clock seconds spent sampling.
    #[serde(default)]
    pub sample_secs: f64,
}

/// `POST /api/v1/jobs/{id}/result` body.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct ResultUpload {
    /// The lease's token.
    pub lease_token: String,
    /// The job's output.
    pub output: JobOutput,
}

/// `200` answer to an accepted result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct ResultAck {
    /// Whether the trial reached the convergence threshold.
    pub converged: bool,
    /// Whether a replacement trial was enqueued for it.
    pub replacement_enqueued: bool,
}

/// `POST /api/v1/jobs/{id}/fail` body.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct FailReport {
    /// The lease's token.
    pub lease_token: String,
    /// What went wrong (kept as the job's last error; at most 4000 characters).
    pub error: String,
}

/// `POST /api/v1/jobs/{id}/release` body.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct ReleaseRequest {
    /// The lease's token.
    pub lease_token: String,
}

/// Answer of the fail and release endpoints.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct JobStateAck {
    /// The job's state afterwards.
    pub status: JobState,
}

/// One job as listed by `GET /api/v1/searches/{id}/jobs` and
/// `GET /api/v1/jobs/{id}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct JobInfo {
    /// Job id.
    pub id: i64,
    /// Search id.
    pub search_id: String,
    /// Grid point index.
    pub point_idx: u32,
    /// Point's reward parameters.
    pub params: BTreeMap<String, f64>,
    /// Trial number.
    pub trial: u32,
    /// Index of the job's solver variant in the search's `solvers` (0 in
    /// a search without variants).
    #[serde(default)]
    pub variant: u32,
    /// Seed.
    pub seed: u64,
    /// State.
    pub status: JobState,
    /// Owner of the current or last lease.
    pub worker: Option<String>,
    /// Leases lost or failed so far.
    pub attempts: u32,
    /// Leases granted so far.
    pub lease_count: u32,
    /// Last failure or expiry message.
    pub last_error: Option<String>,
    /// Latest progress.
    pub progress: Option<ProgressPoint>,
    /// Phase reported with the latest heartbeat.
    pub phase: Option<JobPhase>,
    /// Final success rate, once done.
    pub final_success_rate: Option<f64>,
    /// Converged, once done.
    pub converged: Option<bool>,
    /// Successful episodes found / wanted, once done.
    pub successes_found: Option<u32>,
    /// Successful episodes wanted, once done.
    pub successes_wanted: Option<u32>,
    /// Seconds from lease to result, once done.
    pub duration_secs: Option<f64>,
}

/// `GET /api/v1/jobs/{id}`: a job with its learning curve.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct JobDetail {
    /// The job.
    #[serde(flatten)]
    pub job: JobInfo,
    /// Learning curve of the current or last attempt (bounded, thinned).
    pub curve: Vec<ProgressPoint>,
}

/// `GET /api/v1/searches/{id}/results`: the result document (the same
/// shape as `irlgrid analyze` writes) plus the search's state. Borrowed
/// where the coordinator writes it, owned where a client reads it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[cfg_attr(feature = "openapi", schemars(rename = "ResultDocument"))]
pub struct ResultsView<'a> {
    /// Search id.
    pub search_id: Cow<'a, str>,
    /// Search state.
    pub status: SearchState,
    /// True until the search has completed and the document is final.
    pub partial: bool,
    /// Jobs by state when the document was built.
    pub jobs: Cow<'a, JobCounts>,
    /// The document.
    #[serde(flatten)]
    pub document: Cow<'a, ResultDocument>,
}

/// `POST /api/v1/searches/{id}/subjects[?save=true]` body, as JSON (the
/// endpoint also takes the CSV itself as `text/csv`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct SubjectsBody {
    /// Subject trajectories, CSV `subject,time,x,z`.
    pub subjects_csv: String,
}

/// `?limit=N&offset=M` on `GET /api/v1/searches`: one page of the list,
/// newest first. The answer stays a JSON array; its `X-Total-Count`
/// header says how many searches there are in all.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PageQuery {
    /// Searches per page: [`PageQuery::DEFAULT_LIMIT`] when absent, at
    /// most [`PageQuery::MAX_LIMIT`].
    #[serde(default)]
    pub limit: Option<u32>,
    /// Searches skipped, newest first (default 0).
    #[serde(default)]
    pub offset: Option<u32>,
}

impl PageQuery {
    /// Page size when none is asked for.
    pub const DEFAULT_LIMIT: u32 = 100;
    /// Largest page served; a larger `limit` is cut to it.
    pub const MAX_LIMIT: u32 = 500;
    /// The response header holding the total count.
    pub const TOTAL_HEADER: &'static str = "x-total-count";

    /// The page size served for this query (1 to [`PageQuery::MAX_LIMIT`]).
    pub fn limit(&self) -> u32 {
        self.limit
            .unwrap_or(Self::DEFAULT_LIMIT)
            .clamp(1, Self::MAX_LIMIT)
    }

    /// Searches skipped.
    pub fn offset(&self) -> u32 {
        self.offset.unwrap_or(0)
    }
}

/// `?save=true` on `POST /api/v1/searches/{id}/subjects`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct ScoreQuery {
    /// Add the subjects to the search's stored ones.
    #[serde(default)]
    pub save: bool,
    /// Score with this observable set instead of the search's own
    /// (docs/inference.md#observables); not stored.
    #[serde(default)]
    pub observables: Option<String>,
}

/// Answer of `POST /api/v1/searches/{id}/subjects`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct ScoredSubjects {
    /// Search id.
    pub search_id: String,
    /// Whether the subjects were added to the search.
    pub saved: bool,
    /// The grid points the subjects' vectors are aligned with.
    pub points: Vec<BTreeMap<String, f64>>,
    /// One entry per subject, in the order sent (the result document's
    /// subject block: every method).
    pub subjects: Vec<SubjectSummary>,
    /// Warnings from scoring.
    pub notes: Vec<String>,
}

/// The body of every 4xx/5xx answer.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[cfg_attr(feature = "openapi", schemars(rename = "Error"))]
pub struct ErrorBody {
    /// What is wrong, naming the offending field or id.
    pub error: String,
}

/// splitmix64 (Steele, Lea & Flood 2014): the finalizer of a 64-bit
/// counter-based generator; a bijection with good avalanche.
pub fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// FNV-1a 64-bit hash of a parameter name.
fn fnv1a64(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01B3)
    })
}

/// The seed of the job for `trial` at a grid point, derived from the
/// search's base seed by a splitmix64 chain over the point's parameters
/// (by name, in name order, values as IEEE-754 bits) and the trial:
///
/// ```text
/// h = splitmix64(base)
/// for (name, value) in params (sorted by name):
///     h = splitmix64(h ^ fnv1a64(name)); h = splitmix64(h ^ value.to_bits())
/// seed = splitmix64(h ^ trial)
/// ```
///
/// It depends on the point's values, not its position, so a point keeps its
/// seeds when the grid around it changes (`-0.0` is taken as `0.0`).
pub fn job_seed(base: u64, params: &BTreeMap<String, f64>, trial: u32) -> u64 {
    let mut h = splitmix64(base);
    for (name, &value) in params {
        let value = if value == 0.0 { 0.0 } else { value };
        h = splitmix64(h ^ fnv1a64(name));
        h = splitmix64(h ^ value.to_bits());
    }
    splitmix64(h ^ u64::from(trial))
}

/// The seed of the job for `trial` of solver variant `variant` (its index
/// in the search's list) at a grid point: [`job_seed`] for the first
/// variant, so that a search's first variant keeps the seeds a search
/// without variants has, and one more splitmix64 step per other variant,
/// so that variants draw independent seeds:
///
/// ```text
/// seed = job_seed(base, params, trial)                     variant 0
/// seed = splitmix64(job_seed(base, params, trial) ^ v)     variant v > 0
/// ```
pub fn variant_seed(base: u64, params: &BTreeMap<String, f64>, trial: u32, variant: u32) -> u64 {
    let seed = job_seed(base, params, trial);
    if variant == 0 {
        seed
    } else {
        splitmix64(seed ^ u64::from(variant))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splitmix64_matches_reference_sequence() {
        // Reference: state 0 stepped by the golden gamma, as in Vigna's C code.
        assert_eq!(splitmix64(0), 0xE220_A839_7B1D_CDAF);
        assert_eq!(splitmix64(0x9E37_79B9_7F4A_7C15), 0x6E78_9E6A_A1B9_65F4);
    }

    #[test]
    fn job_seed_depends_on_point_values_and_trial_only() {
        let p = |w: f64| BTreeMap::from([("w1".to_string(), w)]);
        let a = job_seed(7, &p(4.0), 0);
        assert_eq!(a, job_seed(7, &p(4.0), 0));
        assert_ne!(a, job_seed(7, &p(4.0), 1));
        assert_ne!(a, job_seed(7, &p(8.0), 0));
        assert_ne!(a, job_seed(8, &p(4.0), 0));
        assert_eq!(job_seed(7, &p(0.0), 3), job_seed(7, &p(-0.0), 3));
    }

    #[test]
    fn the_first_variant_keeps_the_job_seed_and_others_differ() {
        let p = BTreeMap::from([("w1".to_string(), 2.0)]);
        assert_eq!(variant_seed(7, &p, 3, 0), job_seed(7, &p, 3));
        let seeds: Vec<u64> = (0..4).map(|v| variant_seed(7, &p, 3, v)).collect();
        for (i, a) in seeds.iter().enumerate() {
            for b in &seeds[i + 1..] {
                assert_ne!(a, b);
            }
        }
        assert_eq!(
            variant_seed(7, &p, 3, 2),
            splitmix64(job_seed(7, &p, 3) ^ 2)
        );
    }

    #[test]
    fn solver_specs_read_as_tagged_objects_and_default_to_one_ppo() {
        let s: SolverSpec =
            serde_json::from_str(r#"{"kind":"optimizer","name":"cem","optimizer":{"restarts":2}}"#)
                .unwrap();
        assert_eq!(s.name(), "cem");
        assert_eq!(s.kind(), SolverKind::Optimizer);
        let SolverSpec::Optimizer { optimizer, .. } = &s else {
            panic!("{s:?}")
        };
        assert_eq!(optimizer.restarts, 2);
        assert!(serde_json::from_str::<SolverSpec>(
            r#"{"kind":"ppo","name":"a","training":{},"x":1}"#
        )
        .is_err());
        let cfg = ResolvedConfig {
            training: PpoConfig::default(),
            sampling: SamplingConfig::default(),
            env: EnvConfig::default(),
            report: ReportOptions::default(),
            solvers: Vec::new(),
        };
        let specs = cfg.solver_specs();
        assert_eq!(specs.len(), 1);
        assert_eq!(specs[0].tag(), SolverTag::default());
        // An old stored config (no `solvers`) reads and writes unchanged.
        let text = serde_json::to_string(&cfg).unwrap();
        assert!(!text.contains("solvers"));
        assert_eq!(serde_json::from_str::<ResolvedConfig>(&text).unwrap(), cfg);
    }

    #[test]
    fn job_state_round_trips_through_its_spelling() {
        for st in JobState::ALL {
            assert_eq!(JobState::parse(st.as_str()), Some(st));
        }
        assert_eq!(JobState::parse("nope"), None);
    }
}
