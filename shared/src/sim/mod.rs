//! The 3-DOF squat-to-stand body model (docs/science.md#body-model): parameters, closed-form
//! equations of motion, and RK4 integration, for one environment and for
//! blocks of eight stepped together in vector registers. Deterministic, allocation-free
//! per step, f64 throughout.

mod block;
mod dynamics;
mod integrate;
mod lanes;
mod params;

pub use block::{Block, BlockStep, BlockStepper, Isa};
pub use dynamics::{solve_spd3, Com, Mat3, Model, State};
pub use lanes::{poly_sin_cos, F64s, LANES};
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
