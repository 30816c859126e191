//! `irlgrid analyze`: aggregates saved training/sampling runs into the same
//! result document the coordinator serves (docs/science.md#aggregation), locally.
//!
//! A run directory is what `irlgrid train` writes: `policy.json` (its reward
//! parameters and seed) and `samples.json` (the kept trajectories). A trial's
//! final success rate is the success fraction of its sampling rollouts
//! (successes found / episodes tried, at least 1000 episodes by default),
//! exactly as the coordinator computes it for uploaded jobs.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use shared::analysis::{
    build_report, parse_subjects_csv, report_to_csv, SubjectPath, TrialInput, WeightInput,
};
use shared::ppo::TrainedPolicy;
use shared::sample::SampleOutput;

use super::InputError;

/// The saved grid to read: shared by `analyze` and `holdout`.
#[derive(clap::Args, Debug)]
#[group(id = "grid_source", required = true, multiple = false, args = ["runs", "outputs"])]
pub struct GridArgs {
    /// Run directories (each with policy.json and samples.json), or parents
    /// whose immediate subdirectories are run directories.
    #[arg(long, num_args = 1..)]
    runs: Vec<PathBuf>,
    /// Instead of runs: a search's aggregation input as the coordinator
    /// serves it (`GET /api/v1/searches/{id}/outputs`, saved to a file),
    /// every done trial with its solver variant and convergence.
    #[arg(long)]
    outputs: Option<PathBuf>,
    /// Trials whose final success rate is below this are kept but left out
    /// of the means (not converged).
    #[arg(long, default_value_t = 0.5)]
    converged_threshold: f64,
}

impl GridArgs {
    /// Every run directory under `--runs`, grouped into grid points.
    pub fn load(&self) -> Result<Vec<WeightInput>> {
        if !(0.0..=1.0).contains(&self.converged_threshold) {
            return Err(InputError(format!(
                "--converged-threshold must be in [0, 1], got {}",
                self.converged_threshold
            ))
            .into());
        }
        if let Some(path) = &self.outputs {
            return read_json(path);
        }
        let mut dirs = Vec::new();
        for root in &self.runs {
            find_runs(root, &mut dirs)?;
        }
        if dirs.is_empty() {
            return Err(InputError(
                "no run directories (with samples.json) found under --runs".into(),
            )
            .into());
        }
        load_runs(&dirs, self.converged_threshold)
    }
}

#[derive(clap::Args, Debug)]
pub struct AnalyzeArgs {
    #[command(flatten)]
    grid: GridArgs,
    /// Subject CSV (`subject,time,x,z`) to score against the grid.
    #[arg(long)]
    subjects: Option<PathBuf>,
    /// Write the JSON document here instead of stdout.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also write the tidy CSV form of the document here.
    #[arg(long)]
    csv: Option<PathBuf>,
    #[command(flatten)]
    posterior: super::posterior_args::PosteriorArgs,
}

pub fn run(args: AnalyzeArgs) -> Result<()> {
    let opts = args.posterior.options()?;
    let weights = args.grid.load()?;
    let subjects = match &args.subjects {
        Some(path) => read_subjects(path)?,
        None => Vec::new(),
    };
    let doc = build_report(&weights, &subjects, &opts);
    let json = serde_json::to_string_pretty(&doc)?;
    match &args.out {
        Some(path) => {
            std::fs::write(path, json).with_context(|| format!("writing {}", path.display()))?
        }
        None => println!("{json}"),
    }
    if let Some(path) = &args.csv {
        std::fs::write(path, report_to_csv(&doc))
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

fn find_runs(root: &Path, out: &mut Vec<PathBuf>) -> Result<()> {
    if root.join("samples.json").is_file() {
        out.push(root.to_path_buf());
        return Ok(());
    }
    let entries = std::fs::read_dir(root)
        .map_err(|e| InputError(format!("{}: cannot read directory: {e}", root.display())))?;
    let mut found: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("samples.json").is_file())
        .collect();
    if found.is_empty() {
        return Err(InputError(format!(
            "{}: neither a run directory (samples.json) nor a parent of run directories",
            root.display()
        ))
        .into());
    }
    found.sort();
    out.extend(found);
    Ok(())
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| InputError(format!("{}: cannot read: {e}", path.display())))?;
    serde_json::from_str(&text).map_err(|e| InputError(format!("{}: {e}", path.display())).into())
}

/// Groups runs by reward point and numbers the trials of a point by seed.
fn load_runs(dirs: &[PathBuf], threshold: f64) -> Result<Vec<WeightInput>> {
    // Keyed by the point's parameters in a stable, exact textual form.
    let mut points: BTreeMap<String, WeightInput> = BTreeMap::new();
    for dir in dirs {
        let policy_path = dir.join("policy.json");
        let text = std::fs::read_to_string(&policy_path)
            .map_err(|e| InputError(format!("{}: cannot read: {e}", policy_path.display())))?;
        let policy = TrainedPolicy::from_json(&text)
            .map_err(|e| InputError(format!("{}: {e}", policy_path.display())))?;
        let samples: SampleOutput = read_json(&dir.join("samples.json"))?;
        let params = BTreeMap::from([("w1".to_string(), policy.env.reward.w1)]);
        let key = format!("{params:?}");
        let success = samples.success_rate();
        let point = points.entry(key).or_insert_with(|| WeightInput {
            params,
            trials: Vec::new(),
        });
        point.trials.push(TrialInput {
            trial: 0,
            seed: policy.seed,
            final_success_rate: success,
            converged: success >= threshold,
            episodes: samples.episodes,
            successes_found: samples.successes_found,
            successes_wanted: samples.successes_wanted,
            solver: Default::default(),
        });
    }
    let mut weights: Vec<WeightInput> = points.into_values().collect();
    weights.sort_by(|a, b| a.params["w1"].total_cmp(&b.params["w1"]));
    for w in &mut weights {
        w.trials.sort_by_key(|t| t.seed);
        for (i, t) in w.trials.iter_mut().enumerate() {
            t.trial = i as u32;
        }
    }
    Ok(weights)
}

fn read_subjects(path: &Path) -> Result<Vec<SubjectPath>> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| InputError(format!("{}: cannot read: {e}", path.display())))?;
    parse_subjects_csv(&text).map_err(|e| InputError(format!("{}: {e}", path.display())).into())
}
