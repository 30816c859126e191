//! Subject costs of docs/science.md#paper-metrics: area difference and clipped Pearson correlation
//! between a subject's resampled path and each reward value's mean path, the
//! softmax rankings over the grid, and the inferred grid index.

use super::preprocess::RESAMPLE_POINTS;
use super::AnalysisError;

/// Softmax gain of the area-difference ranking (docs/science.md#rankings).
pub const K_AREA: f64 = 30.0;
/// Softmax gain of the correlation ranking (docs/science.md#rankings).
pub const K_CORR: f64 = 100.0;
/// First 0-based index of the correlation window (point n = 11, docs/science.md#correlation).
pub const CORR_FIRST: usize = 10;
/// Last 0-based index of the correlation window (point n = 50, docs/science.md#correlation).
pub const CORR_LAST: usize = 49;

/// A series whose standard deviation is below this times max(1, max |value|)
/// counts as constant. Resampled paths have unit rise, so this is rounding
/// noise (a straight path's x is ~1e-17, not 0) and must not yield a
/// meaningful-looking correlation.
const CONSTANT_SD_REL: f64 = 1e-12;

/// Area difference `D = sum_n |x_s(n) - x_w(n)|` (docs/science.md#area-difference) of two equally
/// long series.
pub fn area_difference(xs: &[f64], xw: &[f64]) -> Result<f64, AnalysisError> {
    if xw.len() != xs.len() {
        return Err(AnalysisError::LengthMismatch {
            what: "weight path",
            expected: xs.len(),
            found: xw.len(),
        });
    }
    Ok(xs.iter().zip(xw).map(|(a, b)| (a - b).abs()).sum())
}

/// Pearson correlation of two equally long series. Defined as 0 when either
/// series is constant (zero variance, or fewer than 2 values): no linear
/// relation is measurable, and 0 ranks such a match below any positively
/// correlated one without producing NaN. Clamped to [-1, 1] against rounding.
pub fn pearson(a: &[f64], b: &[f64]) -> Result<f64, AnalysisError> {
    if b.len() != a.len() {
        return Err(AnalysisError::LengthMismatch {
            what: "correlated series",
            expected: a.len(),
            found: b.len(),
        });
    }
    let n = a.len() as f64;
    let (Some(ma), Some(mb)) = (super::stats::mean(a), super::stats::mean(b)) else {
        return Ok(0.0);
    };
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        let (dx, dy) = (x - ma, y - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    let constant = |ss: f64, v: &[f64]| {
        let scale = v.iter().fold(1.0_f64, |m, x| m.max(x.abs()));
        (ss / n).sqrt() <= CONSTANT_SD_REL * scale
    };
    if constant(saa, a) || constant(sbb, b) {
        return Ok(0.0);
    }
    Ok((sab / (saa.sqrt() * sbb.sqrt())).clamp(-1.0, 1.0))
}

/// Correlation `rho` (docs/science.md#correlation): Pearson correlation of two resampled x
/// series over points n = 11..50 (0-based [`CORR_FIRST`]..=[`CORR_LAST`]).
/// Both series must have [`RESAMPLE_POINTS`] values.
pub fn correlation(xs: &[f64], xw: &[f64]) -> Result<f64, AnalysisError> {
    for (what, v) in [("subject path", xs), ("weight path", xw)] {
        if v.len() != RESAMPLE_POINTS {
            return Err(AnalysisError::LengthMismatch {
                what,
                expected: RESAMPLE_POINTS,
                found: v.len(),
            });
        }
    }
    pearson(&xs[CORR_FIRST..=CORR_LAST], &xw[CORR_FIRST..=CORR_LAST])
}

/// Numerically stable softmax (the maximum is subtracted before `exp`).
/// Empty in, empty out. Limits instead of NaN for non-finite scores: NaN gets
/// probability 0; any `+inf` scores share all the mass; `-inf` gets 0; if no
/// score is finite or `+inf`, the `-inf` scores share it equally; all NaN
/// gives all zeros.
pub fn softmax(scores: &[f64]) -> Vec<f64> {
    let share = |pick: &dyn Fn(f64) -> bool| {
        let k = scores.iter().filter(|&&s| pick(s)).count() as f64;
        scores
            .iter()
            .map(|&s| if pick(s) { 1.0 / k } else { 0.0 })
            .collect::<Vec<f64>>()
    };
    if scores.contains(&f64::INFINITY) {
        return share(&|s| s == f64::INFINITY);
    }
    let max = scores
        .iter()
        .copied()
        .filter(|s| s.is_finite())
        .fold(f64::NEG_INFINITY, f64::max);
    if max == f64::NEG_INFINITY {
        if scores.contains(&f64::NEG_INFINITY) {
            return share(&|s| s == f64::NEG_INFINITY);
        }
        return vec![0.0; scores.len()];
    }
    let e: Vec<f64> = scores
        .iter()
        .map(|&s| if s.is_finite() { (s - max).exp() } else { 0.0 })
        .collect();
    // The maximum contributes exp(0) = 1, so the sum is >= 1.
    let total: f64 = e.iter().sum();
    e.iter().map(|v| v / total).collect()
}

/// Index of the smallest value, first on ties, NaN ignored; `None` if there is
/// no comparable value.
pub fn argmin_first(xs: &[f64]) -> Option<usize> {
    let mut best: Option<(usize, f64)> = None;
    for (i, &v) in xs.iter().enumerate() {
        if !v.is_nan() && best.is_none_or(|(_, b)| v < b) {
            best = Some((i, v));
        }
    }
    best.map(|(i, _)| i)
}

/// Index of the largest value, first on ties, NaN ignored; `None` if there is
/// no comparable value.
pub fn argmax_first(xs: &[f64]) -> Option<usize> {
    let neg: Vec<f64> = xs.iter().map(|v| -v).collect();
    argmin_first(&neg)
}

/// One subject's costs against a list of weight mean paths (docs/science.md#paper-metrics).
#[derive(Clone, Debug, PartialEq)]
pub struct SubjectCosts {
    /// `D[s, w]` per weight.
    pub area_difference: Vec<f64>,
    /// `rho[s, w]` per weight.
    pub correlation: Vec<f64>,
    /// `softmax(-k_area * D[s, .])`.
    pub ranking_area: Vec<f64>,
    /// `softmax(k_corr * rho[s, .])`.
    pub ranking_corr: Vec<f64>,
    /// Index of the smallest `D` (first on ties); `None` for no weights.
    pub best_area: Option<usize>,
    /// Index of the largest `rho` (first on ties); `None` for no weights.
    pub best_corr: Option<usize>,
}

/// Costs, rankings and inferred indices of one subject x series against each
/// weight mean x series (all [`RESAMPLE_POINTS`] long), docs/science.md#paper-metrics.
pub fn subject_costs<P: AsRef<[f64]>>(
    subject_x: &[f64],
    weight_x: &[P],
    k_area: f64,
    k_corr: f64,
) -> Result<SubjectCosts, AnalysisError> {
    let mut d = Vec::with_capacity(weight_x.len());
    let mut rho = Vec::with_capacity(weight_x.len());
    for w in weight_x {
        rho.push(correlation(subject_x, w.as_ref())?);
        d.push(area_difference(subject_x, w.as_ref())?);
    }
    let neg_d: Vec<f64> = d.iter().map(|v| -k_area * v).collect();
    let pos_rho: Vec<f64> = rho.iter().map(|v| k_corr * v).collect();
    Ok(SubjectCosts {
        ranking_area: softmax(&neg_d),
        ranking_corr: softmax(&pos_rho),
        best_area: argmin_first(&d),
        best_corr: argmax_first(&rho),
        area_difference: d,
        correlation: rho,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn area_difference_is_sum_of_absolute_differences() {
        assert_eq!(
            area_difference(&[1.0, -2.0, 0.5], &[0.0, 1.0, 0.5]).unwrap(),
            4.0
        );
        assert!(area_difference(&[1.0], &[1.0, 2.0]).is_err());
    }

    #[test]
    fn pearson_matches_hand_computation() {
        // a: mean 2, devs -1 0 1; b: mean 3, devs -2 -1 3 -> sab 5, saa 2, sbb 14.
        let r = pearson(&[1.0, 2.0, 3.0], &[1.0, 2.0, 6.0]).unwrap();
        assert!(close(r, 5.0 / (2.0_f64 * 14.0).sqrt(), 1e-15));
        assert!(close(
            pearson(&[1.0, 2.0, 3.0], &[-2.0, -4.0, -6.0]).unwrap(),
            -1.0,
            1e-15
        ));
    }

    #[test]
    fn zero_variance_correlation_is_zero() {
        assert_eq!(pearson(&[1.0, 1.0, 1.0], &[1.0, 2.0, 3.0]).unwrap(), 0.0);
        assert_eq!(pearson(&[1.0, 2.0, 3.0], &[0.0; 3]).unwrap(), 0.0);
        assert_eq!(pearson(&[], &[]).unwrap(), 0.0);
        assert_eq!(pearson(&[1.0], &[2.0]).unwrap(), 0.0);
        // Rounding noise on a straight path is still "constant".
        let noise: Vec<f64> = (0..40).map(|k| 1e-17 * f64::from(k % 3)).collect();
        let line: Vec<f64> = (0..40).map(f64::from).collect();
        assert_eq!(pearson(&noise, &line).unwrap(), 0.0);
    }

    #[test]
    fn correlation_uses_only_points_11_to_50() {
        let mut s: Vec<f64> = (0..60).map(|k| f64::from(k).sin()).collect();
        let w = s.clone();
        // Wreck the clipped ends: rho must not notice.
        for k in (0..10).chain(50..60) {
            s[k] = -100.0 * w[k] + 7.0;
        }
        assert!(close(correlation(&s, &w).unwrap(), 1.0, 1e-12));
        assert!(correlation(&s[..59], &w).is_err());
    }

    #[test]
    fn softmax_matches_hand_computation_and_sums_to_one() {
        let p = softmax(&[0.0, 2.0_f64.ln(), 0.0]);
        assert!(close(p[0], 0.25, 1e-15) && close(p[1], 0.5, 1e-15) && close(p[2], 0.25, 1e-15));
        // Stable for huge scores that would overflow exp directly.
        let q = softmax(&[1000.0, 1000.0 + 3.0_f64.ln(), -1e300]);
        assert!(close(q[0], 0.25, 1e-12) && close(q[1], 0.75, 1e-12) && q[2] == 0.0);
        for v in [p, q] {
            assert!(close(v.iter().sum::<f64>(), 1.0, 1e-15));
        }
        assert!(softmax(&[]).is_empty());
    }

    #[test]
    fn softmax_of_non_finite_scores_takes_limits_not_nan() {
        assert_eq!(
            softmax(&[1.0, f64::INFINITY, f64::NAN]),
            vec![0.0, 1.0, 0.0]
        );
        assert_eq!(softmax(&[f64::NEG_INFINITY, 0.0]), vec![0.0, 1.0]);
        assert_eq!(softmax(&[f64::NEG_INFINITY; 2]), vec![0.5, 0.5]);
        assert_eq!(softmax(&[f64::NAN]), vec![0.0]);
    }

    #[test]
    fn argmin_and_argmax_take_first_on_ties() {
        assert_eq!(argmin_first(&[3.0, 1.0, 1.0, 2.0]), Some(1));
        assert_eq!(argmax_first(&[3.0, 1.0, 3.0]), Some(0));
        assert_eq!(argmin_first(&[f64::NAN, 2.0]), Some(1));
        assert_eq!(argmin_first(&[]), None);
        assert_eq!(argmax_first(&[f64::NAN]), None);
    }

    #[test]
    fn subject_costs_rank_and_infer_as_hand_computed() {
        let subject: Vec<f64> = (0..60).map(|k| 0.01 * f64::from(k)).collect();
        // Weight 0: subject + 0.01 everywhere (D = 0.6, rho = 1).
        // Weight 1: subject + 0.005 (D = 0.3, rho = 1) -> area prefers 1;
        // correlation ties up to rounding between 0 and 1.
        // Weight 2: reversed (D large, rho = -1).
        let w0: Vec<f64> = subject.iter().map(|v| v + 0.01).collect();
        let w1: Vec<f64> = subject.iter().map(|v| v + 0.005).collect();
        let w2: Vec<f64> = subject.iter().rev().copied().collect();
        let c = subject_costs(&subject, &[w0, w1, w2], K_AREA, K_CORR).unwrap();
        assert!(close(c.area_difference[0], 0.6, 1e-12));
        assert!(close(c.area_difference[1], 0.3, 1e-12));
        assert!(close(c.correlation[0], 1.0, 1e-12) && close(c.correlation[2], -1.0, 1e-12));
        assert_eq!(c.best_area, Some(1));
        assert!(matches!(c.best_corr, Some(0 | 1)));
        let d2 = c.area_difference[2];
        let e = [
            (-30.0 * 0.6_f64).exp(),
            (-30.0 * 0.3_f64).exp(),
            (-30.0 * d2).exp(),
        ];
        let sum: f64 = e.iter().sum();
        for (p, ek) in c.ranking_area.iter().zip(e) {
            assert!(close(*p, ek / sum, 1e-12));
        }
        assert!(close(c.ranking_corr[0], 0.5, 1e-12) && close(c.ranking_corr[1], 0.5, 1e-12));
        assert!(close(c.ranking_corr.iter().sum::<f64>(), 1.0, 1e-15));
    }
}
