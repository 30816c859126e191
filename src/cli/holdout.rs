//! `irlgrid holdout`: leave-one-trial-out recovery over saved runs. Every
//! converged trial in turn is scored as a synthetic subject against the grid
//! means rebuilt without it (`shared::analysis::holdout`), which measures how
//! well the grid identifies w1 with as many cases as it has trials.

use std::path::PathBuf;

use anyhow::{Context, Result};
use shared::analysis::{hold_out_recovery, hold_out_table, ReportOptions};

use super::analyze::GridArgs;
use super::InputError;

#[derive(clap::Args, Debug)]
pub struct HoldOutArgs {
    #[command(flatten)]
    grid: GridArgs,
    /// Also write the full report (every case, both confusion matrices) as JSON.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Exit with status 1 unless at least this fraction of cases is
    /// inferred within one grid step by area difference.
    #[arg(long)]
    require_within_one: Option<f64>,
}

pub fn run(args: HoldOutArgs) -> Result<()> {
    if let Some(f) = args.require_within_one.filter(|f| !(0.0..=1.0).contains(f)) {
        return Err(InputError(format!("--require-within-one must be in [0, 1], got {f}")).into());
    }
    let weights = args.grid.load()?;
    let opts = ReportOptions::default();
    let report = hold_out_recovery(&weights, &opts);
    print!("{}", hold_out_table(&report, &opts.label_param));
    if let Some(path) = &args.out {
        std::fs::write(path, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(need) = args.require_within_one {
        let got = if report.cases == 0 {
            0.0
        } else {
            f64::from(report.area.within_one) / f64::from(report.cases)
        };
        if got < need {
            anyhow::bail!(
                "{} of {} held-out trials ({:.0} %) inferred within one grid step by area; \
                 --require-within-one asks for {:.0} %",
                report.area.within_one,
                report.cases,
                100.0 * got,
                100.0 * need
            );
        }
    }
    Ok(())
}
