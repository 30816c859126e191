//! `irlgrid`: the one command-line entry point. Parses arguments, starts
//! tracing, and hands over to the library crates.

mod cli;

use clap::{Parser, Subcommand};

/// Infer the cost function behind human movement by reward-parameter search.
#[derive(Parser)]
#[command(name = "irlgrid", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the 3-DOF body model open-loop on a CSV of normalized actions.
    Simulate(cli::simulate::SimulateArgs),
    /// Train a PPO policy for one (w1, seed) into a run directory.
    Train(cli::train::TrainArgs),
    /// Evaluate a saved policy with stochastic episodes.
    Evaluate(cli::evaluate::EvaluateArgs),
    /// Sample trajectories (top successful episodes, docs/science.md#sampling) from a saved policy.
    Sample(cli::sample::SampleArgs),
    /// Preprocess and resample subject COM paths (subject CSV) to 60 points, as JSON.
    Resample(cli::resample::ResampleArgs),
    /// Generate clearly labelled synthetic subjects with planted w1 values.
    SynthSubjects(cli::synth_subjects::SynthSubjectsArgs),
    /// Aggregate saved runs (and subjects) into the result document.
    Analyze(cli::analyze::AnalyzeArgs),
    /// Leave-one-trial-out recovery: score every trial as a subject against the rest of the grid.
    Holdout(cli::holdout::HoldOutArgs),
    /// Find the best open-loop movement a reward allows (a learner-free reference).
    Optimize(cli::optimize::OptimizeArgs),
    /// Print every reward preset as JSON.
    Presets,
    /// Run the coordinator service (job queue, leases, REST API).
    Coordinator(cli::coordinator::CoordinatorArgs),
    /// Run a worker: lease jobs from a coordinator, train, sample, upload.
    Worker(cli::worker::WorkerArgs),
    /// Submit a search (JSON file) to a coordinator; prints its id.
    Submit(cli::client::SubmitArgs),
    /// Show a search's status (or list all searches).
    Status(cli::client::StatusArgs),
    /// Fetch a search's result document (or its CSV).
    Results(cli::client::ResultsArgs),
    /// Score new subjects against a finished search, without retraining.
    Score(cli::client::ScoreArgs),
    /// Extend a search: more trials per point and/or new grid values.
    Extend(cli::client::ExtendArgs),
    /// Refine a search's grid toward its subjects: add the midpoints of
    /// each subject's bracketing pair, round after round.
    Refine(cli::client::RefineArgs),
    /// Run a whole search locally: coordinator, workers, progress, results.
    Run(cli::run::RunArgs),
    /// Probe a coordinator's health URL (exit 0 on HTTP 200): for container health checks.
    Health(cli::ops::HealthArgs),
    /// Write a consistent copy of the coordinator's database while it runs.
    Backup(cli::ops::BackupArgs),
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Simulate(args) => cli::simulate::run(args),
        Command::Train(args) => cli::train::run(args),
        Command::Evaluate(args) => cli::evaluate::run(args),
        Command::Sample(args) => cli::sample::run(args),
        Command::Resample(args) => cli::resample::run(args),
        Command::SynthSubjects(args) => cli::synth_subjects::run(args),
        Command::Analyze(args) => cli::analyze::run(args),
        Command::Holdout(args) => cli::holdout::run(args),
        Command::Optimize(args) => cli::optimize::run(args),
        Command::Presets => cli::optimize::list_presets(),
        Command::Coordinator(args) => cli::coordinator::run(args),
        Command::Worker(args) => cli::worker::run(args),
        Command::Submit(args) => cli::client::submit(args),
        Command::Status(args) => cli::client::status(args),
        Command::Results(args) => cli::client::results(args),
        Command::Score(args) => cli::client::score(args),
        Command::Extend(args) => cli::client::extend(args),
        Command::Refine(args) => cli::client::refine(args),
        Command::Run(args) => cli::run::run(args),
        Command::Health(args) => cli::ops::health(args),
        Command::Backup(args) => cli::ops::backup(args),
    };
    if let Err(err) = result {
        std::process::exit(cli::report_error(&err));
    }
}
