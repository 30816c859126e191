//! irlgrid worker: leases (reward point, trial) jobs from a
//! coordinator, trains a PPO policy and samples its trajectories on blocking
//! threads, reports progress by heartbeat, and uploads the results.

pub mod backoff;
pub mod config;
pub mod job;
pub mod run;

pub use config::WorkerConfig;
pub use job::{run_job, JobBody, JobError, JobHooks};
pub use run::{run, run_with, RunStats};
