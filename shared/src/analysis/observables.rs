//! Which evidence the posterior uses (docs/inference.md#observables): the
//! path's shape (time normalized away, the paper's view), its timing, or
//! both. A path's features are computed once ([`PathFeatures`]); the
//! summary vector of an observable set is cut from them.

use serde::{Deserialize, Serialize};

use super::preprocess::ResampledPath;
use super::timing::{Timing, PROFILE_COMPONENTS};

/// The summary of one resampled path: `[area, b_1, ..., b_k]` with
/// `b_j = 2 * integral_0^1 x(u) sin(j pi u) du` over the resampling parameter
/// `u` (trapezoid rule on the resampled points). `None` if any input is not
/// finite or there are fewer than two points.
pub fn path_summary(x: &[f64], area: f64, components: usize) -> Option<Vec<f64>> {
    let n = x.len();
    if n < 2 || !area.is_finite() || x.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let h = 1.0 / (n - 1) as f64;
    let mut out = Vec::with_capacity(1 + components);
    out.push(area);
    for j in 1..=components {
        let f = |i: usize| x[i] * (j as f64 * std::f64::consts::PI * i as f64 * h).sin();
        let inner: f64 = (1..n - 1).map(f).sum();
        out.push(2.0 * h * (inner + 0.5 * (f(0) + f(n - 1))));
    }
    Some(out)
}

/// An observable set: the evidence the posterior's summary vector holds.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub enum Observables {
    /// The path's shape: area and sine coefficients of the resampled x
    /// (docs/inference.md#summary). Searches stored before observables
    /// could be chosen read as this.
    #[serde(rename = "shape")]
    Shape,
    /// The stand-up's timing: log duration and the speed profile
    /// (docs/science.md#timing).
    #[serde(rename = "timing")]
    Timing,
    /// The speed profile only, without the absolute duration: unchanged
    /// when a movement is slowed down as a whole.
    #[serde(rename = "relative_timing")]
    RelativeTiming,
    /// Shape and timing.
    #[serde(rename = "shape+timing")]
    ShapeTiming,
    /// Shape and the speed profile.
    #[serde(rename = "shape+relative_timing")]
    ShapeRelativeTiming,
}

impl Default for Observables {
    /// The default of the local commands and of a search under the paper's
    /// reward: the shape, the paper's evidence and the best measured set
    /// there (docs/inference.md#observables-measured).
    fn default() -> Self {
        Self::Shape
    }
}

impl Observables {
    /// The default of a new search under the reward preset `preset`, chosen
    /// by measurement (docs/inference.md#observables-measured): under
    /// `power` the effort weight moves the stand-up's timing more than its
    /// shape, and the relative speed profile carries that without the
    /// absolute duration, which is not a person's; under the paper's reward
    /// the timing is flat and the shape is the evidence.
    pub fn default_for_preset(preset: Option<&str>) -> Self {
        match preset {
            Some("power") => Self::RelativeTiming,
            _ => Self::default(),
        }
    }

    /// Every set, in display order.
    pub const ALL: [Observables; 5] = [
        Self::Shape,
        Self::Timing,
        Self::RelativeTiming,
        Self::ShapeTiming,
        Self::ShapeRelativeTiming,
    ];

    /// What a stored configuration without the field means: the shape
    /// summary, the only one before observables could be chosen.
    pub fn legacy() -> Self {
        Self::Shape
    }

    /// The name in requests, documents and on the command line.
    pub fn key(self) -> &'static str {
        match self {
            Self::Shape => "shape",
            Self::Timing => "timing",
            Self::RelativeTiming => "relative_timing",
            Self::ShapeTiming => "shape+timing",
            Self::ShapeRelativeTiming => "shape+relative_timing",
        }
    }

    /// Parses [`Observables::key`].
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|o| o.key() == s)
    }

    /// Whether the set holds the shape summary.
    pub fn has_shape(self) -> bool {
        matches!(
            self,
            Self::Shape | Self::ShapeTiming | Self::ShapeRelativeTiming
        )
    }

    /// Whether the set holds the absolute (log) duration.
    pub fn has_duration(self) -> bool {
        matches!(self, Self::Timing | Self::ShapeTiming)
    }

    /// Whether the set holds the speed profile.
    pub fn has_profile(self) -> bool {
        self != Self::Shape
    }

    /// Length of the summary vector with `components` shape coefficients.
    pub fn dim(self, components: usize) -> usize {
        let shape = if self.has_shape() { 1 + components } else { 0 };
        let duration = usize::from(self.has_duration());
        let profile = if self.has_profile() {
            PROFILE_COMPONENTS
        } else {
            0
        };
        shape + duration + profile
    }

    /// Index of the log duration in the summary vector, if the set holds it.
    pub fn duration_index(self, components: usize) -> Option<usize> {
        self.has_duration()
            .then_some(if self.has_shape() { 1 + components } else { 0 })
    }
}

impl std::fmt::Display for Observables {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.key())
    }
}

/// What the posterior can use of one path: its shape summary and, when the
/// path carried usable times, its timing.
#[derive(Clone, Debug, PartialEq)]
pub struct PathFeatures {
    /// `[area, b_1, .., b_k]` (see [`path_summary`]).
    pub shape: Vec<f64>,
    /// The timing, `None` when the times were missing or unusable.
    pub timing: Option<Timing>,
}

impl PathFeatures {
    /// The features of a resampled path with its timing; `None` when the
    /// shape summary is not finite.
    pub fn new(path: &ResampledPath, timing: Option<Timing>, components: usize) -> Option<Self> {
        Some(Self {
            shape: path_summary(&path.x, path.area, components)?,
            timing: timing.filter(|t| {
                t.duration.is_finite()
                    && t.duration > 0.0
                    && t.profile.iter().all(|v| v.is_finite())
            }),
        })
    }

    /// The summary vector of `obs`: shape, then log duration, then the
    /// speed profile, as far as the set holds them. `None` when the set
    /// needs the timing and the path has none.
    pub fn summary(&self, obs: Observables) -> Option<Vec<f64>> {
        let mut y = Vec::with_capacity(self.shape.len() + 1 + PROFILE_COMPONENTS);
        if obs.has_shape() {
            y.extend_from_slice(&self.shape);
        }
        if obs.has_duration() || obs.has_profile() {
            let t = self.timing.as_ref()?;
            if obs.has_duration() {
                y.push(t.duration.ln());
            }
            y.extend_from_slice(&t.profile);
        }
        Some(y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_round_trip_and_old_configs_read_as_shape() {
        for o in Observables::ALL {
            assert_eq!(Observables::parse(o.key()), Some(o));
            assert_eq!(
                serde_json::to_string(&o).unwrap(),
                format!("\"{}\"", o.key())
            );
        }
        assert_eq!(Observables::legacy(), Observables::Shape);
        assert_eq!(Observables::parse("time"), None);
    }

    #[test]
    fn summary_vectors_are_cut_in_a_fixed_order() {
        let f = PathFeatures {
            shape: vec![0.05, 0.1, 0.2],
            timing: Some(Timing {
                onset: 0.0,
                standing: 0.5,
                duration: 0.5,
                profile: vec![0.3],
            }),
        };
        let l = 0.5f64.ln();
        assert_eq!(f.summary(Observables::Shape).unwrap(), vec![0.05, 0.1, 0.2]);
        assert_eq!(f.summary(Observables::Timing).unwrap(), vec![l, 0.3]);
        assert_eq!(f.summary(Observables::RelativeTiming).unwrap(), vec![0.3]);
        assert_eq!(
            f.summary(Observables::ShapeTiming).unwrap(),
            vec![0.05, 0.1, 0.2, l, 0.3]
        );
        assert_eq!(
            f.summary(Observables::ShapeRelativeTiming).unwrap(),
            vec![0.05, 0.1, 0.2, 0.3]
        );
        for o in Observables::ALL {
            assert_eq!(f.summary(o).unwrap().len(), o.dim(2), "{o}");
        }
        assert_eq!(Observables::ShapeTiming.duration_index(2), Some(3));
        assert_eq!(Observables::Timing.duration_index(2), Some(0));
        assert_eq!(Observables::RelativeTiming.duration_index(2), None);
        let untimed = PathFeatures { timing: None, ..f };
        assert!(untimed.summary(Observables::Timing).is_none());
        assert!(untimed.summary(Observables::Shape).is_some());
    }
}
