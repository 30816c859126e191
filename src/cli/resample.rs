//! `irlgrid resample`: subject COM paths (docs/science.md#subject-data CSV) preprocessed and
//! resampled at 60 points (docs/science.md#resampling), as a JSON array other programs read.

use std::path::PathBuf;

use anyhow::Result;
use serde::Serialize;
use shared::analysis::{parse_subjects_csv, resample_path};

use super::InputError;

#[derive(clap::Args, Debug)]
pub struct ResampleArgs {
    /// Subject CSV with header `subject,time,x,z`.
    #[arg(long)]
    input: PathBuf,
}

/// One element of the output array (a fixed shape other programs rely on).
#[derive(Serialize)]
struct Resampled<'a> {
    subject: &'a str,
    x: Vec<f64>,
    z: Vec<f64>,
    area: f64,
}

pub fn run(args: ResampleArgs) -> Result<()> {
    let name = args.input.display();
    let text = std::fs::read_to_string(&args.input)
        .map_err(|e| InputError(format!("{name}: cannot read: {e}")))?;
    let subjects = parse_subjects_csv(&text).map_err(|e| InputError(format!("{name}: {e}")))?;
    let mut out = Vec::with_capacity(subjects.len());
    for s in &subjects {
        let r = resample_path(&s.x, &s.z)
            .map_err(|e| InputError(format!("{name}: subject {:?}: {e}", s.subject)))?;
        out.push(Resampled {
            subject: &s.subject,
            x: r.x,
            z: r.z,
            area: r.area,
        });
    }
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}
