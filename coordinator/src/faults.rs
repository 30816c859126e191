//! Crash points for the reliability tests: `IRLGRID_FAULT=<point>` in the
//! coordinator's environment kills the process with SIGKILL when it
//! reaches that point (no destructor, no commit, no flush runs, as when
//! the machine's OOM killer or an operator's `kill -9` strikes there).
//! Unset, each check is one load of a value read once.

use std::sync::OnceLock;

/// A place where a test may kill the coordinator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Point {
    /// Inside the transaction that accepts an output: after the output's
    /// row is written, before its trial summary is.
    BetweenResultAndSummary,
}

impl Point {
    /// The value of `IRLGRID_FAULT` that arms this point.
    pub fn key(self) -> &'static str {
        match self {
            Self::BetweenResultAndSummary => "between-result-and-summary",
        }
    }
}

fn armed() -> Option<&'static str> {
    static ARMED: OnceLock<Option<String>> = OnceLock::new();
    ARMED
        .get_or_init(|| {
            std::env::var("IRLGRID_FAULT")
                .ok()
                .filter(|v| !v.is_empty())
        })
        .as_deref()
}

/// Kills the process here if `IRLGRID_FAULT` names `p`.
pub fn hit(p: Point) {
    if armed() != Some(p.key()) {
        return;
    }
    tracing::warn!(point = p.key(), "fault point reached: killing the process");
    let _ = std::process::Command::new("kill")
        .args(["-KILL", &std::process::id().to_string()])
        .status();
    // `kill` missing or refused: die without unwinding all the same.
    std::process::abort();
}
