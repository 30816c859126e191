//! The text form of a grid point: its reward parameters by name, as the
//! report's notes, the CSV, the dashboard and the CLI show it. The analysis
//! owns it (a grid point is its input, [`super::WeightInput::params`]); the
//! wire module re-exports it for the coordinator and the CLI.

use std::collections::BTreeMap;

/// The one text form of a grid point's reward parameters, as notes, the
/// dashboard, the CSV and the CLI show it: `w1=0.5, w2=2` in name order.
pub fn point_label(params: &BTreeMap<String, f64>) -> String {
    point_label_with(params, |v| v.to_string())
}

/// [`point_label`] with each value written by `value` (the dashboard
/// rounds them for display).
pub fn point_label_with(params: &BTreeMap<String, f64>, value: impl Fn(f64) -> String) -> String {
    params
        .iter()
        .map(|(k, v)| format!("{k}={}", value(*v)))
        .collect::<Vec<_>>()
        .join(", ")
}
