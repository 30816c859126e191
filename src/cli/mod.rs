//! Subcommands of the `irlgrid` binary, one module each.

pub mod analyze;
pub mod client;
pub mod coordinator;
pub mod evaluate;
pub mod holdout;
pub mod ops;
pub mod resample;
pub mod run;
pub mod sample;
pub mod simulate;
pub mod synth_subjects;
pub mod train;
pub mod worker;

/// An error caused by the user's input (file, flag or value): exit status 2.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct InputError(pub String);

/// Prints `err` as one line on stderr and returns the exit status: 2 for bad
/// input, 1 for anything else.
pub fn report_error(err: &anyhow::Error) -> i32 {
    eprintln!("error: {err:#}");
    if err.downcast_ref::<InputError>().is_some() {
        2
    } else {
        1
    }
}
