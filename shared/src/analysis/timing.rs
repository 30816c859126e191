//! The timing of a stand-up (docs/science.md#timing): when the movement
//! starts, when the body reaches standing height, and how the vertical
//! speed is spread over that interval. Computed the same way for a
//! simulated episode (`com_t`, `com_x`, `com_z`) and for a subject's path
//! (`time`, `x`, `z`), from the preprocessed path, so that the rise is
//! measured along the same start-to-end direction as the shape.
//!
//! - **Onset**: the first time the normalized height reaches
//!   [`ONSET_FRACTION`] of the rise (linear interpolation between samples).
//!   A quiet period before the movement, or a small sway, does not count.
//! - **Standing**: the first time it reaches [`STANDING_FRACTION`] of the
//!   rise; the final settling (the simulated task ends only once the body
//!   is nearly still, a recording may go on after it) does not count.
//! - **Duration**: standing minus onset, in the path's time unit (s).
//! - **Speed profile**: the normalized height over normalized time
//!   `tau = (t - onset) / duration` runs from 0 to 1; its vertical speed
//!   `v(tau) = 1 + sum_j a_j cos(j pi tau)` (1 is the constant speed) is
//!   summarised by its first [`PROFILE_COMPONENTS`] cosine coefficients
//!   `a_j`. They do not change when the time axis is stretched: a slowed
//!   copy of a path has the same profile and a longer duration.

use serde::{Deserialize, Serialize};

use super::preprocess::preprocess;
use super::AnalysisError;

/// Fraction of the rise that marks the movement's onset.
pub const ONSET_FRACTION: f64 = 0.05;

/// Fraction of the rise that counts as standing height.
pub const STANDING_FRACTION: f64 = 0.95;

/// Cosine coefficients of the speed profile kept as features: one (a_1,
/// fast start or fast finish). With two, the 7 x 8 `power` grid's
/// leave-one-solver-out coverage at 90 % fell from 0.84 to 0.68 for
/// `timing` at the same recovery, on 62 trials
/// (docs/inference.md#observables-measured):
/// a second coefficient is estimated too poorly from 8 trials per point.
pub const PROFILE_COMPONENTS: usize = 1;

/// Points of normalized time at which the height is read for the profile.
const PROFILE_POINTS: usize = 60;

/// The timing of one path.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct Timing {
    /// Time of movement onset, in the path's time unit.
    pub onset: f64,
    /// Time standing height is reached.
    pub standing: f64,
    /// `standing - onset`.
    pub duration: f64,
    /// Cosine coefficients `a_1 .. a_k` of the time-normalized vertical
    /// speed profile.
    pub profile: Vec<f64>,
}

/// The first time `z` reaches `level`, by linear interpolation between the
/// sample before and the sample at which it first does. `z` starts below
/// `level` and ends above it, so the crossing exists.
fn first_crossing(t: &[f64], z: &[f64], level: f64) -> f64 {
    let k = z.iter().position(|&v| v >= level).unwrap_or(z.len() - 1);
    if k == 0 {
        return t[0];
    }
    let (z0, z1) = (z[k - 1], z[k]);
    let f = if z1 > z0 {
        (level - z0) / (z1 - z0)
    } else {
        1.0
    };
    t[k - 1] + f * (t[k] - t[k - 1])
}

/// Linear interpolation of the samples `(t, z)` at time `s` (clamped to
/// the samples' span); `hint` is the index to search from, advanced as `s`
/// grows.
fn interpolate(t: &[f64], z: &[f64], s: f64, hint: &mut usize) -> f64 {
    let n = t.len();
    while *hint + 2 < n && t[*hint + 1] < s {
        *hint += 1;
    }
    let (t0, t1) = (t[*hint], t[*hint + 1]);
    let f = ((s - t0) / (t1 - t0)).clamp(0.0, 1.0);
    z[*hint] + f * (z[*hint + 1] - z[*hint])
}

/// Cosine coefficients of the speed of `u(tau) = tau + r(tau)` with `r`
/// vanishing at both ends: `r = sum_j b_j sin(j pi tau)`, so the speed is
/// `1 + sum_j j pi b_j cos(j pi tau)`; `b_j = 2 * integral r sin(j pi tau)`
/// by the trapezoid rule on equally spaced samples of `r`.
pub(crate) fn sine_coefficients(r: &[f64], components: usize) -> Vec<f64> {
    let n = r.len();
    let h = 1.0 / (n - 1) as f64;
    (1..=components)
        .map(|j| {
            let f = |i: usize| r[i] * (j as f64 * std::f64::consts::PI * i as f64 * h).sin();
            let inner: f64 = (1..n - 1).map(f).sum();
            2.0 * h * (inner + 0.5 * (f(0) + f(n - 1)))
        })
        .collect()
}

/// The timing of the path `(t, x, z)` (see the module docs). Errors when
/// the path cannot be preprocessed (docs/science.md#preprocessing), when
/// `t` has another length, a non-finite value or does not increase
/// strictly.
pub fn stand_up_timing(t: &[f64], x: &[f64], z: &[f64]) -> Result<Timing, AnalysisError> {
    if t.len() != x.len() {
        return Err(AnalysisError::LengthMismatch {
            what: "path times",
            expected: x.len(),
            found: t.len(),
        });
    }
    let p = preprocess(x, z)?;
    if let Some(index) = t.iter().position(|v| !v.is_finite()) {
        return Err(AnalysisError::NonFinite { index });
    }
    if let Some(index) = t.windows(2).position(|w| w[1] <= w[0]) {
        return Err(AnalysisError::KnotsNotIncreasing { index: index + 1 });
    }
    let onset = first_crossing(t, &p.z, ONSET_FRACTION);
    let standing = first_crossing(t, &p.z, STANDING_FRACTION);
    let duration = standing - onset;
    if !(duration.is_finite() && duration > 0.0) {
        return Err(AnalysisError::Overflow);
    }
    let span = STANDING_FRACTION - ONSET_FRACTION;
    let denom = (PROFILE_POINTS - 1) as f64;
    let mut hint = 0;
    let r: Vec<f64> = (0..PROFILE_POINTS)
        .map(|k| {
            let tau = k as f64 / denom;
            let s = onset + tau * duration;
            let u = (interpolate(t, &p.z, s, &mut hint) - ONSET_FRACTION) / span;
            u - tau
        })
        .collect();
    let profile = sine_coefficients(&r, PROFILE_COMPONENTS)
        .into_iter()
        .enumerate()
        .map(|(i, b)| (i + 1) as f64 * std::f64::consts::PI * b)
        .collect();
    Ok(Timing {
        onset,
        standing,
        duration,
        profile,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// A straight vertical rise from rest at `t0` to height 1 at `t0 + T`
    /// with a cosine (minimum-jerk-like) speed profile, sampled at `hz`,
    /// with `pre` s of stillness before and after.
    fn cosine_rise(t0: f64, big_t: f64, hz: f64, pre: f64) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let n = ((2.0 * pre + big_t) * hz).round() as usize + 1;
        let mut t = Vec::new();
        let mut z = Vec::new();
        for k in 0..n {
            let s = t0 - pre + k as f64 / hz;
            let f = ((s - t0) / big_t).clamp(0.0, 1.0);
            t.push(s);
            z.push(0.5 * (1.0 - (PI * f).cos()));
        }
        let x = vec![0.0; n];
        (t, x, z)
    }

    #[test]
    fn onset_and_standing_of_a_cosine_rise_match_closed_form() {
        // z = (1 - cos(pi f)) / 2 reaches level c at f = acos(1 - 2c) / pi.
        let (t0, big_t) = (0.4, 1.5);
        let (t, x, z) = cosine_rise(t0, big_t, 1000.0, 0.3);
        let tm = stand_up_timing(&t, &x, &z).unwrap();
        let at = |c: f64| t0 + big_t * (1.0 - 2.0 * c).acos() / PI;
        assert!((tm.onset - at(0.05)).abs() < 1e-4, "{tm:?}");
        assert!((tm.standing - at(0.95)).abs() < 1e-4, "{tm:?}");
        assert!((tm.duration - (at(0.95) - at(0.05))).abs() < 2e-4);
    }

    #[test]
    fn linear_rise_has_flat_speed_profile_and_known_duration() {
        // z = t on [0, 2] s, 100 Hz: onset 0.1 s, standing 1.9 s, constant
        // speed, so every profile coefficient is 0.
        let t: Vec<f64> = (0..=200).map(|k| k as f64 / 100.0).collect();
        let z: Vec<f64> = t.iter().map(|v| v / 2.0).collect();
        let x = vec![0.0; t.len()];
        let tm = stand_up_timing(&t, &x, &z).unwrap();
        assert!((tm.onset - 0.1).abs() < 1e-12);
        assert!((tm.standing - 1.9).abs() < 1e-12);
        assert!((tm.duration - 1.8).abs() < 1e-12);
        assert!(tm.profile.iter().all(|a| a.abs() < 1e-12), "{tm:?}");
    }

    #[test]
    fn planted_speed_profile_is_recovered() {
        // u(tau) = tau + b1 sin(pi tau) + b2 sin(2 pi tau) between onset and
        // standing: a_j = j pi b_j. Built on the normalized height directly,
        // 2000 samples.
        let (b1, b2) = (0.08, -0.03);
        let span = STANDING_FRACTION - ONSET_FRACTION;
        let n = 2001;
        let (t0, big_t) = (0.2, 0.6);
        let mut t = vec![0.0];
        let mut z = vec![0.0];
        for k in 0..n {
            let tau = k as f64 / (n - 1) as f64;
            let u = tau + b1 * (PI * tau).sin() + b2 * (2.0 * PI * tau).sin();
            t.push(t0 + tau * big_t);
            z.push(ONSET_FRACTION + span * u);
        }
        t.push(t0 + big_t + 0.1);
        z.push(1.0);
        // The first sample (0, 0) reaches onset height only at t0.
        let x = vec![0.0; t.len()];
        let tm = stand_up_timing(&t, &x, &z).unwrap();
        assert!((tm.onset - t0).abs() < 1e-9 && (tm.duration - big_t).abs() < 1e-9);
        assert_eq!(tm.profile.len(), PROFILE_COMPONENTS);
        assert!((tm.profile[0] - PI * b1).abs() < 1e-4, "{tm:?}");
        // The series itself recovers the second coefficient too.
        let r: Vec<f64> = (0..61)
            .map(|k| {
                let tau = f64::from(k) / 60.0;
                b1 * (PI * tau).sin() + b2 * (2.0 * PI * tau).sin()
            })
            .collect();
        let b = sine_coefficients(&r, 2);
        assert!(
            (b[0] - b1).abs() < 1e-12 && (b[1] - b2).abs() < 1e-12,
            "{b:?}"
        );
    }

    #[test]
    fn slowing_the_time_axis_scales_duration_and_keeps_the_profile() {
        let (t, x, z) = cosine_rise(0.0, 0.5, 200.0, 0.1);
        let base = stand_up_timing(&t, &x, &z).unwrap();
        let slow_t: Vec<f64> = t.iter().map(|v| 3.0 * v + 7.0).collect();
        let slow = stand_up_timing(&slow_t, &x, &z).unwrap();
        assert!((slow.duration - 3.0 * base.duration).abs() < 1e-12);
        for (a, b) in base.profile.iter().zip(&slow.profile) {
            assert!((a - b).abs() < 1e-12);
        }
        // Units and pose do not matter either: metres to millimetres, tilted.
        let (th, k) = (0.3_f64, 1000.0);
        let xr: Vec<f64> = z.iter().map(|v| k * -th.sin() * v).collect();
        let zr: Vec<f64> = z.iter().map(|v| k * th.cos() * v).collect();
        let moved = stand_up_timing(&t, &xr, &zr).unwrap();
        assert!((moved.duration - base.duration).abs() < 1e-12);
    }

    #[test]
    fn bad_times_are_typed_errors() {
        let (t, x, z) = cosine_rise(0.0, 0.5, 100.0, 0.0);
        assert!(matches!(
            stand_up_timing(&t[1..], &x, &z),
            Err(AnalysisError::LengthMismatch { .. })
        ));
        let mut flat = t.clone();
        flat[5] = flat[4];
        assert_eq!(
            stand_up_timing(&flat, &x, &z),
            Err(AnalysisError::KnotsNotIncreasing { index: 5 })
        );
        let mut nan = t.clone();
        nan[3] = f64::NAN;
        assert_eq!(
            stand_up_timing(&nan, &x, &z),
            Err(AnalysisError::NonFinite { index: 3 })
        );
    }
}
