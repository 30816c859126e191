//! `irlgrid holdout`: leave-one-trial-out recovery over saved runs. Every
//! converged trial in turn is scored as a synthetic subject against the grid
//! means rebuilt without it (`shared::analysis::holdout`), which measures how
//! well the grid identifies w1 with as many cases as it has trials.

use std::path::PathBuf;

use anyhow::{Context, Result};
use shared::analysis::{hold_out_recovery, hold_out_table, Method};

use super::analyze::GridArgs;
use super::posterior_args::PosteriorArgs;
use super::InputError;

#[derive(clap::Args, Debug)]
pub struct HoldOutArgs {
    #[command(flatten)]
    grid: GridArgs,
    /// Also write the full report as JSON: every case with each method's
    /// probabilities over the grid, the confusion matrices and the coverage
    /// table.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Exit with status 1 unless at least this fraction of cases is
    /// inferred within one grid step by `--method`.
    #[arg(long)]
    require_within_one: Option<f64>,
    /// The method `--require-within-one` checks.
    #[arg(long, value_enum, default_value = "area")]
    method: MethodArg,
    #[command(flatten)]
    posterior: PosteriorArgs,
}

/// The inference methods, as named on the command line.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum MethodArg {
    /// Area difference (the paper's).
    Area,
    /// Correlation (the paper's).
    Correlation,
    /// The posterior over the grid.
    Posterior,
}

impl From<MethodArg> for Method {
    fn from(m: MethodArg) -> Self {
        match m {
            MethodArg::Area => Method::Area,
            MethodArg::Correlation => Method::Correlation,
            MethodArg::Posterior => Method::Posterior,
        }
    }
}

pub fn run(args: HoldOutArgs) -> Result<()> {
    if let Some(f) = args.require_within_one.filter(|f| !(0.0..=1.0).contains(f)) {
        return Err(InputError(format!("--require-within-one must be in [0, 1], got {f}")).into());
    }
    let opts = args.posterior.options()?;
    let weights = args.grid.load()?;
    let report = hold_out_recovery(&weights, &opts);
    print!("{}", hold_out_table(&report, &opts.label_param));
    if let Some(path) = &args.out {
        std::fs::write(path, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(need) = args.require_within_one {
        let method = Method::from(args.method);
        let within = report.tally(method).map_or(0, |t| t.within_one);
        let got = if report.cases == 0 {
            0.0
        } else {
            f64::from(within) / f64::from(report.cases)
        };
        if got < need {
            anyhow::bail!(
                "{} of {} held-out trials ({:.0} %) inferred within one grid step by {}; \
                 --require-within-one asks for {:.0} %",
                within,
                report.cases,
                100.0 * got,
                method.title(),
                100.0 * need
            );
        }
    }
    Ok(())
}
