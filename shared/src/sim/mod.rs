//! The 3-DOF squat-to-stand body model (docs/science.md#body-model): parameters, closed-form
//! equations of motion, and RK4 integration. Deterministic, allocation-free
//! per step, f64 throughout.

mod dynamics;
mod integrate;
mod params;

pub use dynamics::{solve_spd3, Com, Mat3, Model, State};
pub use params::{Segment, SimConfig};

/// Errors of the simulator.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SimError {
    /// A parameter is out of its meaningful range.
    #[error("invalid simulator configuration: {0}")]
    InvalidConfig(String),
}

#[cfg(test)]
mod tests;
