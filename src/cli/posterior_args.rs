//! The posterior's knobs shared by `irlgrid analyze`, `holdout` and
//! `score` (docs/inference.md): summary components, pooling, prior and the
//! observable set.

use anyhow::Result;
use shared::analysis::{Observables, ReportOptions};

use super::InputError;

/// Posterior knobs (docs/inference.md); the defaults are the measured ones.
#[derive(clap::Args, Debug)]
pub struct PosteriorArgs {
    /// Sine-series coefficients of x in the posterior's summary, beside the area.
    #[arg(long)]
    posterior_components: Option<usize>,
    /// Strength of the pooled covariance, in pseudo-trials.
    #[arg(long)]
    posterior_pooling: Option<f64>,
    /// Prior over the grid points: `log-cell` (the default: uniform in log
    /// w1) or `uniform` (every point alike, the default before extensions).
    #[arg(long, value_enum)]
    posterior_prior: Option<PriorArg>,
    /// Least spread between solver variants, as a multiple of the spread
    /// between one variant's trials (docs/inference.md#solver-spread).
    #[arg(long)]
    solver_spread_floor: Option<f64>,
    /// The evidence the posterior uses: `shape`, `timing`,
    /// `relative_timing`, `shape+timing` or `shape+relative_timing`; default
    /// `shape` (docs/inference.md#observables).
    #[arg(long, value_parser = parse_observables)]
    observables: Option<Observables>,
}

/// `--observables`: one of the set names.
pub fn parse_observables(s: &str) -> Result<Observables, String> {
    Observables::parse(s).ok_or_else(|| {
        format!(
            "{s:?} is none of {}",
            Observables::ALL.map(|o| o.key()).join(", ")
        )
    })
}

/// `--posterior-prior`.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum PriorArg {
    /// Uniform in log of the label value (each point weighted by its log cell).
    LogCell,
    /// Every grid point equally probable.
    Uniform,
}

impl PosteriorArgs {
    /// The report options with these knobs applied, validated.
    pub fn options(&self) -> Result<ReportOptions> {
        let mut opts = ReportOptions::default();
        if let Some(c) = self.posterior_components {
            opts.posterior.components = c;
        }
        if let Some(k) = self.posterior_pooling {
            opts.posterior.pooling = k;
        }
        if let Some(p) = self.posterior_prior {
            opts.posterior.prior = match p {
                PriorArg::LogCell => shared::analysis::Prior::LogCell,
                PriorArg::Uniform => shared::analysis::Prior::Uniform,
            };
        }
        if let Some(f) = self.solver_spread_floor {
            opts.posterior.solver_spread_floor = f;
        }
        if let Some(o) = self.observables {
            opts.posterior.observables = o;
        }
        opts.validate().map_err(|e| InputError(e.to_string()))?;
        Ok(opts)
    }
}
