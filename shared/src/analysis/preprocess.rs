//! Preprocessing and resampling of one centre-of-mass path
//! (docs/science.md#preprocessing, docs/science.md#resampling):
//! translate, rotate and scale to unit rise, fit a chord-length parametric
//! natural cubic spline, evaluate it at [`RESAMPLE_POINTS`] parameter values,
//! and compute the trajectory area.

use serde::{Deserialize, Serialize};

use super::spline::NaturalCubicSpline;
use super::AnalysisError;

/// Number of resampled points per path (docs/science.md#resampling).
pub const RESAMPLE_POINTS: usize = 60;

/// Fewest (distinct) points accepted for a path. A natural spline would fit
/// through two, but a recorded trajectory with fewer than four samples has no
/// shape worth comparing.
pub const MIN_POINTS: usize = 4;

/// A start-to-end distance below this fraction of the path's extent counts as
/// zero rise: normalizing by it would blow rounding noise up to the path's
/// size.
const ZERO_RISE_REL: f64 = 1e-12;

/// A path after preprocessing steps 1-3 (docs/science.md#preprocessing): starts at (0, 0), ends at
/// exactly (0, 1).
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct PreprocessedPath {
    /// Forward coordinate, in units of the rise.
    pub x: Vec<f64>,
    /// Vertical coordinate, 0 at the start and 1 at the end.
    pub z: Vec<f64>,
    /// Start-to-end distance in input units (the scale that was divided out).
    pub rise: f64,
}

/// A path resampled to [`RESAMPLE_POINTS`] points (docs/science.md#resampling).
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct ResampledPath {
    /// Forward coordinate at each resampled point, in units of the rise.
    pub x: Vec<f64>,
    /// Vertical coordinate at each resampled point, 0 to 1.
    pub z: Vec<f64>,
    /// Signed area between path and chord, see [`path_area`].
    pub area: f64,
}

/// Checks what every path needs: equal lengths, at least [`MIN_POINTS`]
/// samples, all finite.
fn check_input(x: &[f64], z: &[f64]) -> Result<(), AnalysisError> {
    if z.len() != x.len() {
        return Err(AnalysisError::LengthMismatch {
            what: "path z coordinates",
            expected: x.len(),
            found: z.len(),
        });
    }
    if x.len() < MIN_POINTS {
        return Err(AnalysisError::TooFewPoints {
            n: x.len(),
            min: MIN_POINTS,
        });
    }
    if let Some(index) = x
        .iter()
        .zip(z)
        .position(|(a, b)| !a.is_finite() || !b.is_finite())
    {
        return Err(AnalysisError::NonFinite { index });
    }
    Ok(())
}

/// Preprocessing steps 1-3 (docs/science.md#preprocessing) on checked input
/// (finite, at least 2 points).
fn normalize(x: &[f64], z: &[f64]) -> Result<PreprocessedPath, AnalysisError> {
    let (x0, z0) = (x[0], z[0]);
    let dx: Vec<f64> = x.iter().map(|v| v - x0).collect();
    let dz: Vec<f64> = z.iter().map(|v| v - z0).collect();
    // Divide by the extent first so that the rise test below is relative and
    // the squares cannot overflow or underflow.
    let extent = dx.iter().chain(&dz).fold(0.0_f64, |m, v| m.max(v.abs()));
    if !extent.is_finite() {
        return Err(AnalysisError::Overflow);
    }
    if extent == 0.0 {
        return Err(AnalysisError::ZeroRise { rise: 0.0 });
    }
    let n = x.len();
    let (ex, ez) = (dx[n - 1] / extent, dz[n - 1] / extent);
    let r = ex.hypot(ez);
    if r < ZERO_RISE_REL {
        return Err(AnalysisError::ZeroRise { rise: r * extent });
    }
    // Rotation taking the unit end direction (s, c) to (0, 1), then scaling by
    // 1 / rise: one similarity transform.
    let (s, c) = (ex / r, ez / r);
    let mut px: Vec<f64> = Vec::with_capacity(n);
    let mut pz: Vec<f64> = Vec::with_capacity(n);
    for (a, b) in dx.iter().zip(&dz) {
        let (a, b) = (a / extent, b / extent);
        px.push((c * a - s * b) / r);
        pz.push((s * a + c * b) / r);
    }
    // The end lands on (0, 1) up to rounding; pin it so every path ends on
    // exactly the same point.
    px[n - 1] = 0.0;
    pz[n - 1] = 1.0;
    Ok(PreprocessedPath {
        x: px,
        z: pz,
        rise: r * extent,
    })
}

/// Preprocessing (docs/science.md#preprocessing): translate the first point to the origin, rotate
/// about it so the last point is straight above, scale by 1 / rise so `z`
/// runs from 0 to 1. Keeps every input point (repeats included).
pub fn preprocess(x: &[f64], z: &[f64]) -> Result<PreprocessedPath, AnalysisError> {
    check_input(x, z)?;
    normalize(x, z)
}

/// Preprocesses and resamples a path (docs/science.md#resampling): parametric natural cubic
/// spline `(x(u), z(u))` with `u` the normalized cumulative chord length of
/// the preprocessed points, evaluated at [`RESAMPLE_POINTS`] equally spaced
/// `u` in [0, 1] (both ends included).
///
/// Consecutive exact repeats of a sample (a recorder that did not move)
/// would give zero-length chords and a non-increasing parameter, so they are
/// dropped before fitting; so is a point whose chord is below f64 resolution
/// of the running length. At least [`MIN_POINTS`] distinct points must remain.
///
/// Errors, in the order checked: `LengthMismatch`, `TooFewPoints` (fewer
/// than 4 samples), `NonFinite`, `ZeroRise` (end coincides with start, e.g.
/// all points equal), `RepeatedPoints` (fewer than 4 distinct points),
/// `Overflow`.
pub fn resample_path(x: &[f64], z: &[f64]) -> Result<ResampledPath, AnalysisError> {
    check_input(x, z)?;
    let total = x.len();
    let mut ux: Vec<f64> = Vec::with_capacity(total);
    let mut uz: Vec<f64> = Vec::with_capacity(total);
    for (&a, &b) in x.iter().zip(z) {
        if ux.last() != Some(&a) || uz.last() != Some(&b) {
            ux.push(a);
            uz.push(b);
        }
    }
    let p = normalize(&ux, &uz)?;
    let too_few = |distinct| AnalysisError::RepeatedPoints { distinct, total };
    if p.x.len() < MIN_POINTS {
        return Err(too_few(p.x.len()));
    }

    // Cumulative chord length; a point that does not advance it (rounding
    // after the transform) is dropped, except that the pinned end point
    // replaces its predecessor so the path still ends on (0, 1).
    let mut kx = vec![p.x[0]];
    let mut kz = vec![p.z[0]];
    let mut s = vec![0.0];
    let (mut lx, mut lz, mut ls) = (p.x[0], p.z[0], 0.0);
    let last = p.x.len() - 1;
    for i in 1..=last {
        let next = ls + (p.x[i] - lx).hypot(p.z[i] - lz);
        if next > ls {
            kx.push(p.x[i]);
            kz.push(p.z[i]);
            s.push(next);
            (lx, lz, ls) = (p.x[i], p.z[i], next);
        } else if i == last && kx.len() > 1 {
            let j = kx.len() - 1;
            kx[j] = p.x[i];
            kz[j] = p.z[i];
        }
    }
    if kx.len() < MIN_POINTS {
        return Err(too_few(kx.len()));
    }
    let length = s[s.len() - 1];
    let u: Vec<f64> = s.iter().map(|v| v / length).collect();
    let sx = NaturalCubicSpline::new(&u, &kx)?;
    let sz = NaturalCubicSpline::new(&u, &kz)?;

    let denom = (RESAMPLE_POINTS - 1) as f64;
    let (rx, rz): (Vec<f64>, Vec<f64>) = (0..RESAMPLE_POINTS)
        .map(|k| {
            let uk = k as f64 / denom;
            (sx.eval(uk), sz.eval(uk))
        })
        .unzip();
    let area = path_area(&rx, &rz)?;
    if !area.is_finite() || rx.iter().chain(&rz).any(|v| !v.is_finite()) {
        return Err(AnalysisError::Overflow);
    }
    Ok(ResampledPath { x: rx, z: rz, area })
}

/// Trajectory area (docs/science.md#area, the paper's "fatness"): the integral of `x dz`
/// along the points by the trapezoid rule. For a path from (0, 0) to (0, 1)
/// this is the signed area between path and chord, positive when the path
/// bulges forward (+x).
pub fn path_area(x: &[f64], z: &[f64]) -> Result<f64, AnalysisError> {
    if z.len() != x.len() {
        return Err(AnalysisError::LengthMismatch {
            what: "path z coordinates",
            expected: x.len(),
            found: z.len(),
        });
    }
    Ok(x.windows(2)
        .zip(z.windows(2))
        .map(|(a, b)| 0.5 * (a[0] + a[1]) * (b[1] - b[0]))
        .sum())
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;
    use std::f64::consts::PI;

    fn semicircle(n: usize) -> (Vec<f64>, Vec<f64>) {
        (0..n)
            .map(|k| {
                let s = k as f64 / (n - 1) as f64;
                (0.5 * (PI * s).sin(), 0.5 * (1.0 - (PI * s).cos()))
            })
            .unzip()
    }

    #[derive(Deserialize)]
    struct Case {
        name: String,
        x: Vec<f64>,
        z: Vec<f64>,
        out_x: Vec<f64>,
        out_z: Vec<f64>,
        area: f64,
    }

    #[test]
    fn resample_path_matches_independent_scipy_pipeline_to_1e9() {
        let cases: Vec<Case> =
            serde_json::from_str(include_str!("../../tests/fixtures/resample_path.json"))
                .expect("fixture parses");
        assert!(cases.len() >= 3);
        for case in &cases {
            let got = resample_path(&case.x, &case.z).expect("fixture resamples");
            assert_eq!(got.x.len(), RESAMPLE_POINTS);
            for k in 0..RESAMPLE_POINTS {
                assert!(
                    (got.x[k] - case.out_x[k]).abs() <= 1e-9
                        && (got.z[k] - case.out_z[k]).abs() <= 1e-9,
                    "{} point {k}: got ({}, {}), SciPy ({}, {})",
                    case.name,
                    got.x[k],
                    got.z[k],
                    case.out_x[k],
                    case.out_z[k]
                );
            }
            assert!((got.area - case.area).abs() <= 1e-9, "{}", case.name);
        }
    }

    #[test]
    fn preprocess_puts_start_at_origin_and_end_at_unit_height() {
        let x = [2.0, 3.0, 5.0, 4.0];
        let z = [1.0, 2.0, 2.0, 1.0];
        let p = preprocess(&x, &z).unwrap();
        assert_eq!((p.x[0], p.z[0]), (0.0, 0.0));
        assert_eq!((p.x[3], p.z[3]), (0.0, 1.0));
        assert!((p.rise - 2.0).abs() < 1e-15);
        // End direction +x becomes +z; (3, 2) - (2, 1) = (1, 1) -> (-1, 1) / 2.
        assert!((p.x[1] + 0.5).abs() < 1e-15 && (p.z[1] - 0.5).abs() < 1e-15);
    }

    #[test]
    fn resampled_path_has_60_points_and_pinned_ends() {
        let (x, z) = semicircle(50);
        let p = resample_path(&x, &z).unwrap();
        assert_eq!(p.x.len(), RESAMPLE_POINTS);
        assert_eq!(p.z.len(), RESAMPLE_POINTS);
        assert!(p.x[0].abs() < 1e-15 && p.z[0].abs() < 1e-15);
        assert!(p.x[59].abs() < 1e-15 && (p.z[59] - 1.0).abs() < 1e-15);
    }

    #[test]
    fn straight_path_has_zero_area() {
        let x: Vec<f64> = (0..17)
            .map(|k| 1.0 + 0.3 * f64::from(k).powf(1.3))
            .collect();
        let z: Vec<f64> = x.iter().map(|v| -2.0 * v + 7.0).collect();
        let p = resample_path(&x, &z).unwrap();
        assert!(p.area.abs() < 1e-12, "area {}", p.area);
        for (a, b) in p.x.iter().zip(&p.z) {
            assert!(a.abs() < 1e-12);
            assert!((-1e-12..=1.0 + 1e-12).contains(b));
        }
    }

    #[test]
    fn forward_semicircle_area_is_pi_over_8() {
        let (x, z) = semicircle(100);
        let p = resample_path(&x, &z).unwrap();
        assert!(p.area > 0.0);
        assert!((p.area - PI / 8.0).abs() < 1e-3, "area {}", p.area);
        // Mirrored backwards: same size, negative.
        let xm: Vec<f64> = x.iter().map(|v| -v).collect();
        let q = resample_path(&xm, &z).unwrap();
        assert!((q.area + p.area).abs() < 1e-12);
    }

    #[test]
    fn rotated_scaled_translated_copy_resamples_identically() {
        let (x, z): (Vec<f64>, Vec<f64>) = (0..37)
            .map(|k| {
                let s = f64::from(k) / 36.0;
                let s = s * s * (3.0 - 2.0 * s); // uneven sampling
                (
                    0.2 * (PI * s).sin() + 0.05 * (3.0 * PI * s).sin(),
                    s + 0.1 * s * s,
                )
            })
            .unzip();
        let base = resample_path(&x, &z).unwrap();
        let (th, k, tx, tz) = (2.1_f64, 37.5, -4.0, 123.0);
        let xr: Vec<f64> = x
            .iter()
            .zip(&z)
            .map(|(a, b)| k * (th.cos() * a - th.sin() * b) + tx)
            .collect();
        let zr: Vec<f64> = x
            .iter()
            .zip(&z)
            .map(|(a, b)| k * (th.sin() * a + th.cos() * b) + tz)
            .collect();
        let moved = resample_path(&xr, &zr).unwrap();
        for i in 0..RESAMPLE_POINTS {
            assert!((base.x[i] - moved.x[i]).abs() < 1e-9);
            assert!((base.z[i] - moved.z[i]).abs() < 1e-9);
        }
        assert!((base.area - moved.area).abs() < 1e-9);
    }

    #[test]
    fn consecutive_repeats_are_dropped_before_fitting() {
        let (x, z) = semicircle(30);
        let base = resample_path(&x, &z).unwrap();
        let mut xr = Vec::new();
        let mut zr = Vec::new();
        for i in 0..x.len() {
            let copies = if i % 7 == 0 { 3 } else { 1 };
            for _ in 0..copies {
                xr.push(x[i]);
                zr.push(z[i]);
            }
        }
        assert_eq!(resample_path(&xr, &zr).unwrap(), base);
    }

    #[test]
    fn fewer_than_four_points_is_too_few_points() {
        assert_eq!(
            resample_path(&[0.0, 0.1, 0.0], &[0.0, 0.5, 1.0]),
            Err(AnalysisError::TooFewPoints { n: 3, min: 4 })
        );
        assert_eq!(
            resample_path(&[], &[]),
            Err(AnalysisError::TooFewPoints { n: 0, min: 4 })
        );
    }

    #[test]
    fn path_ending_where_it_started_is_zero_rise() {
        let loop_x = [0.0, 1.0, 1.0, 0.0, 0.0];
        let loop_z = [0.0, 0.0, 1.0, 1.0, 0.0];
        assert_eq!(
            resample_path(&loop_x, &loop_z),
            Err(AnalysisError::ZeroRise { rise: 0.0 })
        );
        assert_eq!(
            resample_path(&[2.0; 6], &[3.0; 6]),
            Err(AnalysisError::ZeroRise { rise: 0.0 })
        );
        assert!(matches!(
            resample_path(&[0.0, 1.0, 2.0, 1e-14], &[0.0, 1.0, 0.0, 0.0]),
            Err(AnalysisError::ZeroRise { .. })
        ));
    }

    #[test]
    fn mostly_repeated_points_are_repeated_points() {
        let x = [0.0, 0.0, 0.0, 0.3, 0.3, 0.0];
        let z = [0.0, 0.0, 0.0, 0.5, 0.5, 1.0];
        assert_eq!(
            resample_path(&x, &z),
            Err(AnalysisError::RepeatedPoints {
                distinct: 3,
                total: 6
            })
        );
    }

    #[test]
    fn non_finite_sample_is_reported_by_index() {
        let x = [0.0, 0.1, f64::NAN, 0.1, 0.0];
        let z = [0.0, 0.2, 0.4, 0.6, 1.0];
        assert_eq!(
            resample_path(&x, &z),
            Err(AnalysisError::NonFinite { index: 2 })
        );
        let z_inf = [0.0, 0.2, 0.4, f64::INFINITY, 1.0];
        assert_eq!(
            resample_path(&[0.0; 5], &z_inf),
            Err(AnalysisError::NonFinite { index: 3 })
        );
    }

    #[test]
    fn mismatched_lengths_are_rejected() {
        assert!(matches!(
            resample_path(&[0.0; 5], &[0.0; 4]),
            Err(AnalysisError::LengthMismatch {
                expected: 5,
                found: 4,
                ..
            })
        ));
    }
}
