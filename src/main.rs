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
    /// Preprocess and resample subject COM paths (subject CSV) to 60 points, as JSON.
    Resample(cli::resample::ResampleArgs),
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Simulate(args) => cli::simulate::run(args),
        Command::Resample(args) => cli::resample::run(args),
    };
    if let Err(err) = result {
        std::process::exit(cli::report_error(&err));
    }
}
