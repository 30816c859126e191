//! Request intake: strict parsing and validation of what clients and
//! workers send, before anything is stored. A search request becomes a
//! resolved, reproducible configuration and the rows to insert; heartbeats
//! and uploaded job outputs are checked against their search. Every
//! rejection names the offending field.

use std::collections::BTreeMap;

use serde::de::DeserializeOwned;
use serde::Serialize;
use shared::analysis::SolverKind;
use shared::analysis::{
    parse_subjects_csv, refine, subjects_to_csv, EpisodeRecord, ReportOptions, SubjectPath,
};
use shared::api::{
    ExtendRequest, Heartbeat, JobOutput, Partial, RefineRequest, RefineSpec, ResolvedConfig,
    SearchRequest, SolverRequest, SolverSpec, DEFAULT_CONVERGENCE_THRESHOLD, DEFAULT_MAX_ATTEMPTS,
};
use shared::env::EnvConfig;
use shared::optimize::OptimizeConfig;
use shared::ppo::PpoConfig;
use shared::sample::SamplingConfig;

use crate::domain::DomainError;
use crate::store::queue::{ExtensionPlan, GridNow, NewSearch};

/// Most reward parameters a grid may vary.
pub const MAX_GRID_PARAMS: usize = 4;
/// Most values per grid parameter.
pub const MAX_VALUES_PER_PARAM: usize = 64;
/// Most grid points (product of the value lists).
pub const MAX_POINTS: usize = 256;
/// Most trials per point.
pub const MAX_TRIALS: u32 = 100;
/// Most jobs a search may ever enqueue (points x trial cap).
pub const MAX_JOBS: u64 = 10_000;
/// Largest training budget per job (environment steps).
pub const MAX_ENV_STEPS: u64 = 100_000_000;
/// Most successful episodes a job may be asked to sample.
pub const MAX_SUCCESSFUL_EPISODES: u32 = 100_000;
/// Most episodes a job may roll out while sampling.
pub const MAX_SAMPLING_ATTEMPTS: u32 = 10_000_000;
/// Most leases a job may lose before failing.
pub const MAX_ATTEMPTS: u32 = 20;
/// Most subjects in `subjects_csv`.
pub const MAX_SUBJECTS: usize = 1_000;
/// Longest search name.
pub const MAX_NAME_CHARS: usize = 200;
/// Most samples in one uploaded episode path (60 s at 200 Hz is 12,000).
pub const MAX_EPISODE_POINTS: usize = 100_000;
/// Most progress points in one heartbeat.
pub const MAX_HEARTBEAT_POINTS: usize = 1_000;
/// Longest lease token accepted (ours are 32 hex characters).
pub const MAX_TOKEN_CHARS: usize = 128;
/// Most solver variants in one search.
pub const MAX_SOLVERS: usize = 8;
/// Longest solver variant name.
pub const MAX_SOLVER_NAME_CHARS: usize = 40;
/// Most candidate evaluations one optimizer job may spend on its own w1
/// (population x iterations x (restarts + stretch_rounds); the w1 = 0 start
/// adds at most as many again): about a PPO job's budget in rollouts.
pub const MAX_OPTIMIZER_EVALUATIONS: u64 = 2_000_000;

fn bad(msg: impl Into<String>) -> DomainError {
    DomainError::Invalid(msg.into())
}

/// Resolves an optional partial configuration over `base` (the type's
/// defaults, or a preset) strictly: unknown or ill-typed fields are errors
/// naming their path inside `field`.
fn resolve<T: Serialize + DeserializeOwned>(
    field: &str,
    base: &T,
    patches: &[Option<&Partial<T>>],
) -> Result<T, DomainError> {
    Partial::resolve_all(base, patches.iter().flatten().copied()).map_err(|e| bad(e.under(field)))
}

/// Parses subject CSV sent to the API, with the same line-precise 400
/// errors at submission and when scoring subjects later.
pub fn parse_subjects(text: &str) -> Result<Vec<SubjectPath>, DomainError> {
    let subjects = parse_subjects_csv(text).map_err(|e| bad(format!("subjects_csv: {e}")))?;
    if subjects.len() > MAX_SUBJECTS {
        return Err(bad(format!(
            "subjects_csv: {} subjects exceed the limit {MAX_SUBJECTS}",
            subjects.len()
        )));
    }
    Ok(subjects)
}

/// Checks a search request and turns it into the rows to insert.
pub fn prepare_search(req: &SearchRequest, id: String) -> Result<NewSearch, DomainError> {
    // The limit counts the name as sent (as the OpenAPI `maxLength` does).
    if req.name.chars().count() > MAX_NAME_CHARS {
        return Err(bad(format!(
            "name: longer than {MAX_NAME_CHARS} characters"
        )));
    }
    let name = req.name.trim();
    let name = if name.is_empty() { "search" } else { name };
    if name.chars().any(char::is_control) {
        return Err(bad("name: contains control characters"));
    }

    let training: PpoConfig = resolve("training", &PpoConfig::default(), &[req.training.as_ref()])?;
    training
        .validate()
        .map_err(|e| bad(format!("training: {e}")))?;
    if training.env_steps > MAX_ENV_STEPS {
        return Err(bad(format!(
            "training.env_steps: {} exceeds the per-job budget limit {MAX_ENV_STEPS}",
            training.env_steps
        )));
    }
    let sampling: SamplingConfig = resolve(
        "sampling",
        &SamplingConfig::default(),
        &[req.sampling.as_ref()],
    )?;
    sampling
        .validate()
        .map_err(|e| bad(format!("sampling: {e}")))?;
    if sampling.successful_episodes > MAX_SUCCESSFUL_EPISODES {
        return Err(bad(format!(
            "sampling.successful_episodes: {} exceeds the limit {MAX_SUCCESSFUL_EPISODES}",
            sampling.successful_episodes
        )));
    }
    if sampling.max_attempts > MAX_SAMPLING_ATTEMPTS {
        return Err(bad(format!(
            "sampling.max_attempts: {} exceeds the limit {MAX_SAMPLING_ATTEMPTS}",
            sampling.max_attempts
        )));
    }
    let preset_name = req
        .reward_preset
        .as_deref()
        .unwrap_or(shared::env::DEFAULT_PRESET);
    let base = EnvConfig {
        reward: shared::env::preset(preset_name)
            .and_then(|p| p.reward())
            .map_err(|e| bad(format!("reward_preset: {e}")))?,
        ..EnvConfig::default()
    };
    let env: EnvConfig = resolve("env", &base, &[req.env.as_ref()])?;
    env.validate().map_err(|e| bad(format!("env: {e}")))?;

    let points = grid_points(&req.reward_grid, &env)?;

    if req.trials == 0 || req.trials > MAX_TRIALS {
        return Err(bad(format!(
            "trials: must be in 1..={MAX_TRIALS}, got {}",
            req.trials
        )));
    }
    let threshold = req
        .convergence_threshold
        .unwrap_or(DEFAULT_CONVERGENCE_THRESHOLD);
    if !(threshold.is_finite() && (0.0..=1.0).contains(&threshold)) {
        return Err(bad(format!(
            "convergence_threshold: must be a number in [0, 1], got {threshold}"
        )));
    }
    let default_cap = if req.replace_unconverged {
        req.trials.saturating_mul(2)
    } else {
        req.trials
    };
    let cap = req.max_trials_per_point.unwrap_or(default_cap);
    if cap < req.trials || cap > MAX_TRIALS.saturating_mul(4) {
        return Err(bad(format!(
            "max_trials_per_point: must be in trials..={} (trials = {}), got {cap}",
            MAX_TRIALS * 4,
            req.trials
        )));
    }
    let solvers = resolve_solvers(req.solvers.as_deref(), req.training.as_ref())?;
    let variants = solvers.len().max(1) as u64;
    let max_jobs = points.len() as u64 * u64::from(cap) * variants;
    if max_jobs > MAX_JOBS {
        return Err(bad(format!(
            "reward_grid x max_trials_per_point x solvers: {} points x {cap} trials x \
             {variants} solver(s) = {max_jobs} jobs exceeds the limit {MAX_JOBS}",
            points.len()
        )));
    }
    let max_attempts = req.max_attempts.unwrap_or(DEFAULT_MAX_ATTEMPTS);
    if max_attempts == 0 || max_attempts > MAX_ATTEMPTS {
        return Err(bad(format!(
            "max_attempts: must be in 1..={MAX_ATTEMPTS}, got {max_attempts}"
        )));
    }
    let subjects_csv = match &req.subjects_csv {
        None => None,
        Some(text) if text.trim().is_empty() => None,
        // Stored as the parser's own CSV form of what it read, so that the
        // stored text reads back to exactly these subjects.
        Some(text) => Some(subjects_to_csv(&parse_subjects(text)?)),
    };
    let refine = match &req.refine {
        None => None,
        Some(r) => {
            if subjects_csv.is_none() {
                return Err(bad(
                    "refine: needs subjects (subjects_csv) to refine the grid toward",
                ));
            }
            Some(resolve_refine(r, &req.reward_grid, req.trials, 0)?)
        }
    };
    let label_param = if req.reward_grid.contains_key("w1") {
        "w1".to_string()
    } else {
        req.reward_grid.keys().next().cloned().unwrap_or_default()
    };
    let resolved = ResolvedConfig {
        training,
        sampling,
        env,
        report: {
            let mut report = ReportOptions {
                label_param,
                ..ReportOptions::default()
            };
            report.posterior.observables = req.observables.unwrap_or_else(|| {
                shared::analysis::Observables::default_for_preset(req.reward_preset.as_deref())
            });
            report
        },
        solvers,
    };
    Ok(NewSearch {
        id,
        name: name.to_string(),
        request: serde_json::to_string(req).map_err(|e| DomainError::Internal(e.into()))?,
        config: serde_json::to_string(&resolved).map_err(|e| DomainError::Internal(e.into()))?,
        trials: req.trials,
        base_seed: req.seed,
        threshold,
        replace_unconverged: req.replace_unconverged,
        max_trials_per_point: cap,
        max_attempts,
        subjects_csv,
        points,
        refine,
        variants: variants as u32,
    })
}

/// Resolves a request's solver variants (docs/inference.md#solver-spread):
/// names unique and plain, each PPO variant's trainer settings over the
/// search's (`search_training_patch` is the request's partial `training`,
/// so a variant changes only what it names), each optimizer's settings
/// over the optimizer's defaults. `None` resolves to no list: the search's
/// one PPO solver.
fn resolve_solvers(
    req: Option<&[SolverRequest]>,
    search_training_patch: Option<&Partial<PpoConfig>>,
) -> Result<Vec<SolverSpec>, DomainError> {
    let Some(list) = req else {
        return Ok(Vec::new());
    };
    if list.is_empty() || list.len() > MAX_SOLVERS {
        return Err(bad(format!(
            "solvers: must hold 1..={MAX_SOLVERS} variants, got {}",
            list.len()
        )));
    }
    let mut out: Vec<SolverSpec> = Vec::with_capacity(list.len());
    for (i, s) in list.iter().enumerate() {
        let field = format!("solvers[{i}]");
        let name_ok = !s.name.is_empty()
            && s.name.chars().count() <= MAX_SOLVER_NAME_CHARS
            && s.name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'));
        if !name_ok {
            return Err(bad(format!(
                "{field}.name: must be 1..={MAX_SOLVER_NAME_CHARS} letters, digits, '-', '_' or \
                 '.', got {:?}",
                s.name
            )));
        }
        if out.iter().any(|o| o.name() == s.name) {
            return Err(bad(format!(
                "{field}.name: {:?} names two variants",
                s.name
            )));
        }
        let spec = match s.kind {
            SolverKind::Ppo => {
                if s.optimizer.is_some() {
                    return Err(bad(format!(
                        "{field}.optimizer: a ppo variant takes \"training\", not \"optimizer\""
                    )));
                }
                // The search's own patch first, then the variant's, over
                // the defaults: a variant differs only where it says so.
                let t: PpoConfig = resolve(
                    &format!("{field}.training"),
                    &PpoConfig::default(),
                    &[search_training_patch, s.training.as_ref()],
                )?;
                t.validate()
                    .map_err(|e| bad(format!("{field}.training: {e}")))?;
                if t.env_steps > MAX_ENV_STEPS {
                    return Err(bad(format!(
                        "{field}.training.env_steps: {} exceeds the per-job budget limit \
                         {MAX_ENV_STEPS}",
                        t.env_steps
                    )));
                }
                SolverSpec::Ppo {
                    name: s.name.clone(),
                    training: t,
                }
            }
            SolverKind::Optimizer => {
                if s.training.is_some() {
                    return Err(bad(format!(
                        "{field}.training: an optimizer variant takes \"optimizer\", not \"training\""
                    )));
                }
                let mut o: OptimizeConfig = resolve(
                    &format!("{field}.optimizer"),
                    &OptimizeConfig::default(),
                    &[s.optimizer.as_ref()],
                )?;
                // The job's seed is the optimizer's seed; one thread per job,
                // since a worker runs one job per core (the result does not
                // depend on the thread count).
                o.seed = 0;
                o.threads = 1;
                o.validate()
                    .map_err(|e| bad(format!("{field}.optimizer: {e}")))?;
                let evaluations = o.evaluations_per_value();
                if evaluations > MAX_OPTIMIZER_EVALUATIONS {
                    return Err(bad(format!(
                        "{field}.optimizer: population x iterations x (restarts + stretch_rounds) \
                         = {evaluations} exceeds the limit {MAX_OPTIMIZER_EVALUATIONS}"
                    )));
                }
                SolverSpec::Optimizer {
                    name: s.name.clone(),
                    optimizer: o,
                }
            }
        };
        out.push(spec);
    }
    Ok(out)
}

/// Most rounds of refinement one request may ask for.
pub const MAX_REFINE_ROUNDS: u32 = 10;

/// Checks a refinement request against the search's grid and fills in
/// the defaults: 1..=MAX_REFINE_ROUNDS rounds, 1..=MAX_TRIALS trials per
/// added point (default `search_trials`), a target ratio in
/// [MIN_TARGET_RATIO, 100], a pair mass in [0, 1], and a grid that varies
/// exactly one parameter.
pub fn resolve_refine(
    req: &RefineRequest,
    grid: &BTreeMap<String, Vec<f64>>,
    search_trials: u32,
    first_round: u32,
) -> Result<RefineSpec, DomainError> {
    let rounds = req.rounds.unwrap_or(refine::DEFAULT_ROUNDS);
    if rounds == 0 || rounds > MAX_REFINE_ROUNDS {
        return Err(bad(format!(
            "refine.rounds: must be in 1..={MAX_REFINE_ROUNDS}, got {rounds}"
        )));
    }
    let trials = req.trials.unwrap_or(search_trials);
    if trials == 0 || trials > MAX_TRIALS {
        return Err(bad(format!(
            "refine.trials: must be in 1..={MAX_TRIALS}, got {trials}"
        )));
    }
    let target_ratio = req.target_ratio.unwrap_or(refine::DEFAULT_TARGET_RATIO);
    if !(target_ratio.is_finite() && (refine::MIN_TARGET_RATIO..=100.0).contains(&target_ratio)) {
        return Err(bad(format!(
            "refine.target_ratio: must be a number in [{}, 100], got {target_ratio}",
            refine::MIN_TARGET_RATIO
        )));
    }
    let min_pair_mass = req.min_pair_mass.unwrap_or(refine::DEFAULT_MIN_PAIR_MASS);
    if !(min_pair_mass.is_finite() && (0.0..=1.0).contains(&min_pair_mass)) {
        return Err(bad(format!(
            "refine.min_pair_mass: must be a number in [0, 1], got {min_pair_mass}"
        )));
    }
    let varied: Vec<&String> = grid.keys().collect();
    let [param] = varied[..] else {
        return Err(bad(format!(
            "refine: refines a grid of one parameter; this one varies {} ({})",
            varied.len(),
            varied
                .iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        )));
    };
    Ok(RefineSpec {
        rounds,
        trials,
        target_ratio,
        min_pair_mass,
        param: param.clone(),
        first_round,
    })
}

/// One gridded parameter's values, as submitted or added by an extension:
/// 1..=MAX_VALUES_PER_PARAM of them, each valid for the parameter and none
/// given twice. 400 naming the field otherwise.
fn check_grid_values(name: &str, values: &[f64], env: &EnvConfig) -> Result<(), DomainError> {
    if values.is_empty() || values.len() > MAX_VALUES_PER_PARAM {
        return Err(bad(format!(
            "reward_grid.{name}: needs 1..={MAX_VALUES_PER_PARAM} values, got {}",
            values.len()
        )));
    }
    for (i, &v) in values.iter().enumerate() {
        let mut reward = env.reward.clone();
        reward
            .set_param(name, v)
            .map_err(|e| bad(format!("reward_grid.{name}[{i}]: {e}")))?;
        if values[..i].contains(&v) {
            return Err(bad(format!("reward_grid.{name}[{i}]: duplicate value {v}")));
        }
    }
    Ok(())
}

/// The cartesian product of the grid (first parameter in name order varies
/// slowest), each value checked by applying it to the task's reward.
fn grid_points(
    grid: &BTreeMap<String, Vec<f64>>,
    env: &EnvConfig,
) -> Result<Vec<BTreeMap<String, f64>>, DomainError> {
    if grid.is_empty() {
        return Err(bad(
            "reward_grid: needs at least one parameter, e.g. {\"w1\": [1.0]}",
        ));
    }
    if grid.len() > MAX_GRID_PARAMS {
        return Err(bad(format!(
            "reward_grid: {} parameters exceed the limit {MAX_GRID_PARAMS}",
            grid.len()
        )));
    }
    let mut total = 1usize;
    for (name, values) in grid {
        check_grid_values(name, values, env)?;
        total = total.saturating_mul(values.len());
    }
    if total > MAX_POINTS {
        return Err(bad(format!(
            "reward_grid: {total} points exceed the limit {MAX_POINTS}"
        )));
    }
    Ok(cartesian(grid))
}

/// Every point of the grid: the cartesian product of its parameters'
/// values, the first parameter in name order varying slowest.
fn cartesian(grid: &BTreeMap<String, Vec<f64>>) -> Vec<BTreeMap<String, f64>> {
    let mut points = vec![BTreeMap::new()];
    for (name, values) in grid {
        points = points
            .into_iter()
            .flat_map(|p| {
                values.iter().map(move |&v| {
                    let mut p = p.clone();
                    p.insert(name.clone(), v);
                    p
                })
            })
            .collect();
    }
    points
}

/// Checks what an extension request says on its own, before the search's
/// state is read: `trials` in range, every added value valid for the
/// search's reward (`env`) and none given twice, something asked for.
pub fn check_extension(req: &ExtendRequest, env: &EnvConfig) -> Result<(), DomainError> {
    if let Some(t) = req.trials {
        if t == 0 || t > MAX_TRIALS {
            return Err(bad(format!("trials: must be in 1..={MAX_TRIALS}, got {t}")));
        }
    }
    if req.trials.is_none() && req.reward_grid.is_empty() {
        return Err(bad(
            "body: an extension needs \"trials\" or \"reward_grid\" (or both)",
        ));
    }
    for (name, values) in &req.reward_grid {
        check_grid_values(name, values, env)?;
    }
    Ok(())
}

/// Plans an extension against the search as it is now (run inside the
/// extension's write transaction, so concurrent extensions each see what
/// the one before did). The grid becomes the product of each parameter's
/// values with the new ones added, under the submission limits; trials can
/// only grow. The cap on trials per point (replacements included) grows in
/// proportion to trials, as at submission where it defaults to 2 x trials
/// with replacement.
pub fn plan_extension(req: &ExtendRequest, now: &GridNow) -> Result<ExtensionPlan, DomainError> {
    let trials = req.trials.unwrap_or(now.trials);
    if trials == 0 || trials > MAX_TRIALS {
        return Err(bad(format!(
            "trials: must be in 1..={MAX_TRIALS}, got {trials}"
        )));
    }
    if trials < now.trials {
        return Err(bad(format!(
            "trials: the search already has {} trials per point; an extension can only raise \
             it, got {trials}",
            now.trials
        )));
    }
    // The grid's parameters and their values, from its points.
    let mut grid: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    for p in &now.points {
        for (name, &v) in p {
            let vals = grid.entry(name.clone()).or_default();
            if !vals.contains(&v) {
                vals.push(v);
            }
        }
    }
    for (name, values) in &req.reward_grid {
        let Some(vals) = grid.get_mut(name) else {
            return Err(bad(format!(
                "reward_grid.{name}: not a parameter of this search's grid (it varies {})",
                now.points
                    .first()
                    .map(|p| p.keys().cloned().collect::<Vec<_>>().join(", "))
                    .unwrap_or_default()
            )));
        };
        for (i, &v) in values.iter().enumerate() {
            if vals.contains(&v) {
                return Err(bad(format!(
                    "reward_grid.{name}[{i}]: {v} is already in the grid"
                )));
            }
        }
        vals.extend(values);
        if vals.len() > MAX_VALUES_PER_PARAM {
            return Err(bad(format!(
                "reward_grid.{name}: {} values with the new ones exceed the limit \
                 {MAX_VALUES_PER_PARAM}",
                vals.len()
            )));
        }
    }
    let total = grid.values().fold(1usize, |n, v| n.saturating_mul(v.len()));
    if total > MAX_POINTS {
        return Err(bad(format!(
            "reward_grid: {total} points with the new values exceed the limit {MAX_POINTS}"
        )));
    }
    let new_points: Vec<BTreeMap<String, f64>> = cartesian(&grid)
        .into_iter()
        .filter(|p| !now.points.contains(p))
        .collect();
    let scaled = (u64::from(now.max_trials_per_point) * u64::from(trials))
        .div_ceil(u64::from(now.trials.max(1)));
    let cap = u32::try_from(scaled)
        .unwrap_or(u32::MAX)
        .clamp(trials, MAX_TRIALS.saturating_mul(4).max(trials));
    let max_jobs = total as u64 * u64::from(cap) * u64::from(now.variants.max(1));
    if max_jobs > MAX_JOBS {
        return Err(bad(format!(
            "reward_grid x max_trials_per_point x solvers: {total} points x {cap} trials x {} \
             solver(s) = {max_jobs} jobs exceeds the limit {MAX_JOBS}",
            now.variants.max(1)
        )));
    }
    if trials == now.trials && new_points.is_empty() {
        return Err(bad(format!(
            "trials: the search already has {trials} trials per point and no new grid value was \
             given; nothing to extend"
        )));
    }
    Ok(ExtensionPlan {
        trials,
        max_trials_per_point: cap,
        new_points,
        new_point_trials: None,
    })
}

/// The extension a refinement round asks for (`queue::refine_round` runs it
/// against the grid `now` inside the round's write): the `added` values of
/// `param` that are not on the grid yet, `trials` each, refused when the
/// grid would exceed [`MAX_VALUES_PER_PARAM`] values or [`MAX_JOBS`] jobs.
pub fn plan_refine_round(
    now: &GridNow,
    param: &str,
    added: &[f64],
    trials: u32,
) -> Result<ExtensionPlan, DomainError> {
    let new_points: Vec<BTreeMap<String, f64>> = added
        .iter()
        .map(|&v| BTreeMap::from([(param.to_string(), v)]))
        .filter(|p| !now.points.contains(p))
        .collect();
    let total = now.points.len() + new_points.len();
    let jobs = total as u64
        * u64::from(now.max_trials_per_point.max(trials))
        * u64::from(now.variants.max(1));
    if total > MAX_VALUES_PER_PARAM || jobs > MAX_JOBS {
        return Err(DomainError::Invalid(format!(
            "refine: {total} grid values ({jobs} jobs at most) would exceed the \
             limits ({MAX_VALUES_PER_PARAM} values, {MAX_JOBS} jobs)"
        )));
    }
    Ok(ExtensionPlan {
        trials: now.trials,
        max_trials_per_point: now.max_trials_per_point,
        new_points,
        new_point_trials: (trials != now.trials).then_some(trials),
    })
}

fn check_token(token: &str) -> Result<(), DomainError> {
    if token.is_empty() || token.len() > MAX_TOKEN_CHARS {
        return Err(bad(format!(
            "lease_token: must be 1..={MAX_TOKEN_CHARS} characters"
        )));
    }
    Ok(())
}

/// Checks a heartbeat's fields.
pub fn validate_heartbeat(hb: &Heartbeat) -> Result<(), DomainError> {
    check_token(&hb.lease_token)?;
    if hb.progress.len() > MAX_HEARTBEAT_POINTS {
        return Err(bad(format!(
            "progress: {} points exceed the limit {MAX_HEARTBEAT_POINTS} per heartbeat",
            hb.progress.len()
        )));
    }
    for (i, p) in hb.progress.iter().enumerate() {
        let fields = [
            ("mean_return", p.mean_return),
            ("success_rate", p.success_rate),
            ("mean_episode_length", p.mean_episode_length),
            ("policy_loss", p.policy_loss),
            ("value_loss", p.value_loss),
            ("entropy", p.entropy),
            ("approx_kl", p.approx_kl),
        ];
        for (name, v) in fields {
            if let Some(v) = v {
                if !v.is_finite() {
                    return Err(bad(format!("progress[{i}].{name}: not finite")));
                }
            }
        }
        if let Some(s) = p.success_rate {
            if !(0.0..=1.0).contains(&s) {
                return Err(bad(format!(
                    "progress[{i}].success_rate: must be in [0, 1], got {s}"
                )));
            }
        }
        if p.env_steps > p.total_env_steps.max(1).saturating_mul(2) {
            return Err(bad(format!(
                "progress[{i}].env_steps: {} is beyond total_env_steps {}",
                p.env_steps, p.total_env_steps
            )));
        }
    }
    Ok(())
}

/// Checks a lease token field on its own (fail, release).
pub fn validate_token(token: &str) -> Result<(), DomainError> {
    check_token(token)
}

fn check_episode(i: usize, e: &EpisodeRecord) -> Result<(), DomainError> {
    let n = e.com_t.len();
    if !(2..=MAX_EPISODE_POINTS).contains(&n) {
        return Err(bad(format!(
            "output.episodes[{i}].com_t: needs 2..={MAX_EPISODE_POINTS} samples, got {n}"
        )));
    }
    for (name, v) in [("com_x", &e.com_x), ("com_z", &e.com_z)] {
        if v.len() != n {
            return Err(bad(format!(
                "output.episodes[{i}].{name}: {} samples, but com_t has {n}",
                v.len()
            )));
        }
    }
    for (name, v) in [
        ("com_t", &e.com_t),
        ("com_x", &e.com_x),
        ("com_z", &e.com_z),
    ] {
        if let Some(k) = v.iter().position(|x| !x.is_finite()) {
            return Err(bad(format!("output.episodes[{i}].{name}[{k}]: not finite")));
        }
    }
    if let Some(k) = e.com_t.windows(2).position(|w| w[1] < w[0]) {
        return Err(bad(format!(
            "output.episodes[{i}].com_t[{}]: time goes backwards",
            k + 1
        )));
    }
    if !e.ret.is_finite() {
        return Err(bad(format!("output.episodes[{i}].return: not finite")));
    }
    if !(e.torque_usage.is_finite() && e.torque_usage >= 0.0) {
        return Err(bad(format!(
            "output.episodes[{i}].torque_usage: must be finite and >= 0, got {}",
            e.torque_usage
        )));
    }
    Ok(())
}

/// Checks an uploaded output against its search's sampling configuration.
pub fn validate_output(
    o: &JobOutput,
    cfg: &ResolvedConfig,
    variant: u32,
) -> Result<(), DomainError> {
    let kind = cfg
        .solver_specs()
        .get(variant as usize)
        .map(SolverSpec::kind)
        .ok_or_else(|| {
            DomainError::Internal(anyhow::anyhow!(
                "job of solver variant #{variant}, which its search does not have"
            ))
        })?;
    // An optimizer job rolls out one noise-free movement (its best) and
    // keeps it if it stands up.
    let (wanted, top_k) = match kind {
        SolverKind::Ppo => (
            cfg.sampling.successful_episodes,
            cfg.sampling.top_k as usize,
        ),
        SolverKind::Optimizer => (1, 1),
    };
    if !(o.final_success_rate.is_finite() && (0.0..=1.0).contains(&o.final_success_rate)) {
        return Err(bad(format!(
            "output.final_success_rate: must be in [0, 1], got {}",
            o.final_success_rate
        )));
    }
    if o.successes_found > o.successes_wanted {
        return Err(bad(format!(
            "output.successes_found: {} is more than successes_wanted {}",
            o.successes_found, o.successes_wanted
        )));
    }
    if o.successes_wanted != wanted {
        return Err(bad(format!(
            "output.successes_wanted: {} but the search asks for {wanted}",
            o.successes_wanted
        )));
    }
    if o.successes_found > o.sampling_attempts {
        return Err(bad(format!(
            "output.successes_found: {} is more than sampling_attempts {}",
            o.successes_found, o.sampling_attempts
        )));
    }
    if o.episodes.len() > top_k || o.episodes.len() > o.successes_found as usize {
        return Err(bad(format!(
            "output.episodes: {} episodes, but at most top_k = {top_k} and at most \
             successes_found = {} may be kept",
            o.episodes.len(),
            o.successes_found
        )));
    }
    if o.env_steps > MAX_ENV_STEPS.saturating_mul(2) {
        return Err(bad(format!(
            "output.env_steps: {} is implausibly large",
            o.env_steps
        )));
    }
    for (name, v) in [("train_secs", o.train_secs), ("sample_secs", o.sample_secs)] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(bad(format!(
                "output.{name}: must be finite and >= 0, got {v}"
            )));
        }
    }
    for (i, e) in o.episodes.iter().enumerate() {
        check_episode(i, e)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn req(grid: &[(&str, &[f64])]) -> SearchRequest {
        SearchRequest {
            name: "t".into(),
            reward_grid: grid
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_vec()))
                .collect(),
            trials: 2,
            ..SearchRequest::default()
        }
    }

    /// A partial configuration from its JSON form.
    fn partial<T>(v: serde_json::Value) -> shared::api::Partial<T> {
        shared::api::Partial::from_value(v).unwrap()
    }

    #[test]
    fn observables_are_stored_in_the_resolved_config_and_default_when_omitted() {
        use shared::analysis::Observables;
        let resolved = |r: &SearchRequest| -> ResolvedConfig {
            serde_json::from_str(&prepare_search(r, "x".into()).unwrap().config).unwrap()
        };
        let mut r = req(&[("w1", &[1.0, 2.0])]);
        assert_eq!(
            resolved(&r).report.posterior.observables,
            Observables::default()
        );
        assert_eq!(
            resolved(&r).report.posterior.observables,
            Observables::Shape
        );
        r.reward_preset = Some("power".into());
        assert_eq!(
            resolved(&r).report.posterior.observables,
            Observables::RelativeTiming
        );
        r.observables = Some(Observables::Timing);
        assert_eq!(
            resolved(&r).report.posterior.observables,
            Observables::Timing
        );
        // An unknown set is refused when the request is read.
        let bad = serde_json::from_value::<SearchRequest>(serde_json::json!({
            "reward_grid": {"w1": [1.0]}, "trials": 1, "observables": "speed"
        }));
        assert!(bad.unwrap_err().to_string().contains("unknown variant"));
    }

    #[test]
    fn a_reward_preset_sets_the_reward_and_explicit_fields_override_it() {
        let resolved = |r: &SearchRequest| -> ResolvedConfig {
            serde_json::from_str(&prepare_search(r, "x".into()).unwrap().config).unwrap()
        };
        let paper = resolved(&req(&[("w1", &[1.0])]));
        assert_eq!(paper.env.reward, shared::env::RewardConfig::default());

        let mut r = req(&[("w1", &[0.3])]);
        r.reward_preset = Some("power".into());
        let power = resolved(&r).env.reward;
        assert_eq!(
            power,
            shared::env::preset("power").unwrap().reward().unwrap()
        );
        assert_eq!(power.effort_term, shared::env::EffortTerm::Power);

        r.env = Some(partial(
            serde_json::json!({"reward": {"success_step_cost": 4.0}, "max_steps": 50}),
        ));
        let c = resolved(&r);
        assert_eq!(c.env.reward.success_step_cost, 4.0);
        assert_eq!(c.env.reward.height_offset, power.height_offset);
        assert_eq!(c.env.max_steps, 50);

        r.env = Some(partial(
            serde_json::json!({"reward": {"effort_exponnent": 2.0}}),
        ));
        let e = prepare_search(&r, "x".into()).unwrap_err().to_string();
        assert!(e.contains("env.reward"), "{e}");

        r.env = None;
        r.reward_preset = Some("fast".into());
        let e = prepare_search(&r, "x".into()).unwrap_err().to_string();
        assert!(e.contains("reward_preset") && e.contains("power"), "{e}");
    }

    #[test]
    fn solver_variants_resolve_over_the_search_and_bad_ones_name_their_field() {
        let resolved = |r: &SearchRequest| -> (ResolvedConfig, u32) {
            let s = prepare_search(r, "x".into()).unwrap();
            (serde_json::from_str(&s.config).unwrap(), s.variants)
        };
        let mut r = req(&[("w1", &[1.0, 2.0])]);
        // No variants: one PPO solver, nothing stored.
        let (c, v) = resolved(&r);
        assert!(c.solvers.is_empty());
        assert_eq!(v, 1);
        r.training = Some(partial(
            serde_json::json!({"env_steps": 300000, "learning_rate": 0.001}),
        ));
        let solver = |v: serde_json::Value| -> SolverRequest { serde_json::from_value(v).unwrap() };
        r.solvers = Some(vec![
            solver(serde_json::json!({"name": "ppo", "kind": "ppo"})),
            solver(
                serde_json::json!({"name": "short", "kind": "ppo", "training": {"env_steps": 100000}}),
            ),
            solver(
                serde_json::json!({"name": "cem", "kind": "optimizer", "optimizer": {"restarts": 2}}),
            ),
        ]);
        let (c, v) = resolved(&r);
        assert_eq!(v, 3);
        let SolverSpec::Ppo {
            training: short, ..
        } = &c.solvers[1]
        else {
            panic!("{:?}", c.solvers[1])
        };
        // The variant changes its budget; the search's learning rate stays.
        assert_eq!((short.env_steps, short.learning_rate), (100000, 0.001));
        assert_eq!(
            c.solvers[0],
            SolverSpec::Ppo {
                name: "ppo".into(),
                training: c.training.clone()
            }
        );
        let SolverSpec::Optimizer { optimizer, .. } = &c.solvers[2] else {
            panic!("{:?}", c.solvers[2])
        };
        assert_eq!((optimizer.restarts, optimizer.threads), (2, 1));
        // Jobs count every variant.
        assert_eq!(prepare_search(&r, "x".into()).unwrap().points.len() * 3, 6);
        for (bad, field) in [
            (
                serde_json::json!([{"name": "a", "kind": "ppo"}, {"name": "a", "kind": "ppo"}]),
                "solvers[1].name",
            ),
            (
                serde_json::json!([{"name": "a b", "kind": "ppo"}]),
                "solvers[0].name",
            ),
            (
                serde_json::json!([{"name": "o", "kind": "optimizer", "training": {}}]),
                "solvers[0].training",
            ),
            (
                serde_json::json!([{"name": "o", "kind": "optimizer", "optimizer": {"populaton": 9}}]),
                "solvers[0].optimizer",
            ),
            (
                serde_json::json!([{"name": "o", "kind": "optimizer", "optimizer": {"population": 100000, "iterations": 1000}}]),
                "solvers[0].optimizer",
            ),
            (
                // 256 x 1000 x (4 + 4) = 2.05 M: the stretched searches count.
                serde_json::json!([{"name": "o", "kind": "optimizer", "optimizer": {"iterations": 1000, "stretch_rounds": 4}}]),
                "solvers[0].optimizer",
            ),
            (
                serde_json::json!([{"name": "o", "kind": "optimizer", "optimizer": {"stretch": [1.5, 9.0]}}]),
                "solvers[0].optimizer",
            ),
            (
                serde_json::json!([{"name": "p", "kind": "ppo", "training": {"env_steps": 0}}]),
                "solvers[0].training",
            ),
            (serde_json::json!([]), "solvers"),
        ] {
            r.solvers = Some(serde_json::from_value(bad.clone()).unwrap());
            let e = prepare_search(&r, "x".into()).unwrap_err().to_string();
            assert!(e.starts_with(field), "{bad}: {e}");
        }
        // The job limit counts variants: 2 points x 2 trials fits, x 3000 does not.
        r.solvers = Some(vec![solver(
            serde_json::json!({"name": "a", "kind": "ppo"}),
        )]);
        r.trials = 100;
        r.max_trials_per_point = Some(400);
        r.reward_grid = BTreeMap::from([("w1".to_string(), (1..=20).map(f64::from).collect())]);
        assert!(prepare_search(&r, "x".into()).is_ok());
        r.solvers = Some(
            (0..3)
                .map(|i| solver(serde_json::json!({"name": format!("v{i}"), "kind": "ppo"})))
                .collect(),
        );
        let e = prepare_search(&r, "x".into()).unwrap_err().to_string();
        assert!(e.contains("solver(s)"), "{e}");
    }

    #[test]
    fn grid_product_has_every_combination_in_name_order() {
        let s = prepare_search(
            &req(&[("w1", &[1.0, 2.0]), ("tall_reward", &[0.5, 1.0, 2.0])]),
            "x".into(),
        )
        .unwrap();
        assert_eq!(s.points.len(), 6);
        assert_eq!(s.points[0]["tall_reward"], 0.5);
        assert_eq!(s.points[0]["w1"], 1.0);
        assert_eq!(s.points[1]["w1"], 2.0);
        assert_eq!(s.max_trials_per_point, 2);
    }

    #[test]
    fn bad_grid_values_name_the_field() {
        let e = prepare_search(&req(&[("w1", &[1.0, -1.0])]), "x".into()).unwrap_err();
        assert!(e.to_string().contains("reward_grid.w1[1]"), "{e}");
        let e = prepare_search(&req(&[("w9", &[1.0])]), "x".into()).unwrap_err();
        assert!(e.to_string().contains("reward_grid.w9[0]"), "{e}");
        let e = prepare_search(&req(&[("w1", &[1.0, 1.0])]), "x".into()).unwrap_err();
        assert!(e.to_string().contains("duplicate"), "{e}");
        let e = prepare_search(&req(&[]), "x".into()).unwrap_err();
        assert!(e.to_string().contains("reward_grid"), "{e}");
    }

    #[test]
    fn unknown_config_fields_are_rejected_with_their_path() {
        let mut r = req(&[("w1", &[1.0])]);
        r.training = Some(partial(serde_json::json!({"env_steps": 1000, "bogus": 1})));
        let e = prepare_search(&r, "x".into()).unwrap_err();
        assert!(e.to_string().starts_with("training"), "{e}");
        assert!(e.to_string().contains("bogus"), "{e}");
        let mut r = req(&[("w1", &[1.0])]);
        r.env = Some(partial(serde_json::json!({"reward": {"w1": "x"}})));
        let e = prepare_search(&r, "x".into()).unwrap_err();
        assert!(e.to_string().contains("env.reward.w1"), "{e}");
    }

    fn grid_now(grid: &[(&str, &[f64])], trials: u32, cap: u32) -> GridNow {
        GridNow {
            variants: 1,
            status: shared::api::SearchState::Completed,
            trials,
            max_trials_per_point: cap,
            points: prepare_search(&req(grid), "x".into()).unwrap().points,
        }
    }

    fn ext(trials: Option<u32>, grid: &[(&str, &[f64])]) -> ExtendRequest {
        ExtendRequest {
            trials,
            reward_grid: grid
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_vec()))
                .collect(),
        }
    }

    #[test]
    fn an_extension_adds_the_missing_products_and_scales_the_cap() {
        let now = grid_now(&[("w1", &[1.0, 2.0]), ("tall_reward", &[0.5, 1.0])], 2, 4);
        let p = plan_extension(&ext(None, &[("w1", &[4.0])]), &now).unwrap();
        assert_eq!(p.trials, 2);
        assert_eq!(p.max_trials_per_point, 4);
        let added: Vec<(f64, f64)> = p
            .new_points
            .iter()
            .map(|q| (q["tall_reward"], q["w1"]))
            .collect();
        assert_eq!(added, vec![(0.5, 4.0), (1.0, 4.0)]);
        let p = plan_extension(&ext(Some(5), &[]), &now).unwrap();
        assert!(p.new_points.is_empty());
        assert_eq!((p.trials, p.max_trials_per_point), (5, 10));
    }

    #[test]
    fn bad_extensions_name_the_field() {
        let env = EnvConfig::default();
        let now = grid_now(&[("w1", &[1.0, 2.0])], 2, 2);
        let cases: Vec<(ExtendRequest, &str)> = vec![
            (ext(Some(1), &[]), "trials: the search already has 2"),
            (
                ext(Some(2), &[]),
                "trials: the search already has 2 trials per point and no new",
            ),
            (ext(Some(101), &[]), "trials: must be in 1..=100"),
            (
                ext(None, &[("w1", &[3.0, 2.0])]),
                "reward_grid.w1[1]: 2 is already in the grid",
            ),
            (
                ext(None, &[("w9", &[3.0])]),
                "reward_grid.w9: not a parameter",
            ),
        ];
        for (r, want) in cases {
            let e = plan_extension(&r, &now).unwrap_err().to_string();
            assert!(e.starts_with(want), "{r:?}: {e}");
        }
        let many: Vec<f64> = (0..63).map(|i| 10.0 + i as f64).collect();
        let e = plan_extension(&ext(None, &[("w1", &many)]), &now)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("reward_grid.w1: 65 values"), "{e}");
        let replacing = grid_now(&[("w1", &[1.0, 2.0])], 2, 4);
        let e = plan_extension(&ext(Some(100), &[("w1", &many[..60])]), &replacing)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("reward_grid x max_trials_per_point"), "{e}");
        for (r, want) in [
            (ext(None, &[]), "body: an extension needs"),
            (ext(Some(0), &[]), "trials: must be in"),
            (ext(None, &[("w1", &[-1.0])]), "reward_grid.w1[0]"),
            (
                ext(None, &[("w1", &[3.0, 3.0])]),
                "reward_grid.w1[1]: duplicate",
            ),
            (ext(None, &[("w1", &[])]), "reward_grid.w1: needs"),
        ] {
            let e = check_extension(&r, &env).unwrap_err().to_string();
            assert!(e.starts_with(want), "{r:?}: {e}");
        }
        assert!(check_extension(&ext(Some(3), &[("w1", &[5.66, 11.3])]), &env).is_ok());
    }

    #[test]
    fn budget_and_counts_are_bounded() {
        let mut r = req(&[("w1", &[1.0])]);
        r.training = Some(partial(serde_json::json!({"env_steps": MAX_ENV_STEPS + 1})));
        assert!(prepare_search(&r, "x".into()).is_err());
        let mut r = req(&[("w1", &[1.0])]);
        r.trials = 0;
        assert!(prepare_search(&r, "x".into()).is_err());
        let mut r = req(&[("w1", &[1.0])]);
        r.convergence_threshold = Some(1.5);
        assert!(prepare_search(&r, "x".into()).is_err());
        let mut r = req(&[("w1", &[1.0])]);
        r.replace_unconverged = true;
        assert_eq!(
            prepare_search(&r, "x".into()).unwrap().max_trials_per_point,
            4
        );
    }
}
