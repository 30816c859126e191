//! Natural cubic interpolating spline of one variable (the building block of
//! the parametric resampling of docs/science.md#resampling). Same curve as SciPy's
//! `CubicSpline(t, y, bc_type="natural")`, including its extrapolation with
//! the end pieces.

use super::AnalysisError;

/// Natural cubic spline through `(t_i, y_i)`: twice continuously
/// differentiable, cubic between knots, second derivative zero at both ends
/// (docs/science.md#resampling). Stored as knots, values and the second derivatives at the knots.
#[derive(Clone, Debug, PartialEq)]
pub struct NaturalCubicSpline {
    t: Vec<f64>,
    y: Vec<f64>,
    /// Second derivative at each knot; 0 at both ends by construction.
    m: Vec<f64>,
}

impl NaturalCubicSpline {
    /// Fits the spline in O(n) with the Thomas algorithm. The system is
    /// strictly diagonally dominant, so no pivoting is needed.
    ///
    /// Needs at least 2 knots (2 give the straight line), finite values and
    /// strictly increasing knots.
    pub fn new(t: &[f64], y: &[f64]) -> Result<Self, AnalysisError> {
        let n = t.len();
        if y.len() != n {
            return Err(AnalysisError::LengthMismatch {
                what: "spline values",
                expected: n,
                found: y.len(),
            });
        }
        if n < 2 {
            return Err(AnalysisError::TooFewPoints { n, min: 2 });
        }
        if let Some(index) = t
            .iter()
            .zip(y)
            .position(|(a, b)| !a.is_finite() || !b.is_finite())
        {
            return Err(AnalysisError::NonFinite { index });
        }
        if let Some(index) = (1..n).find(|&i| t[i] <= t[i - 1]) {
            return Err(AnalysisError::KnotsNotIncreasing { index });
        }

        let h: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
        let slope: Vec<f64> = (0..n - 1).map(|i| (y[i + 1] - y[i]) / h[i]).collect();
        let mut m = vec![0.0; n];
        // Interior unknowns m[1..n-1]:
        // h[i-1] m[i-1] + 2 (h[i-1] + h[i]) m[i] + h[i] m[i+1] = 6 (slope[i] - slope[i-1]).
        if n > 2 {
            let k = n - 2;
            let mut c_prime = vec![0.0; k];
            let mut d_prime = vec![0.0; k];
            for j in 0..k {
                let i = j + 1;
                let sub = h[i - 1];
                let diag = 2.0 * (h[i - 1] + h[i]);
                let sup = h[i];
                let rhs = 6.0 * (slope[i] - slope[i - 1]);
                let (w, prev_d) = if j == 0 {
                    (diag, 0.0)
                } else {
                    (diag - sub * c_prime[j - 1], d_prime[j - 1])
                };
                c_prime[j] = sup / w;
                d_prime[j] = (rhs - sub * prev_d) / w;
            }
            m[k] = d_prime[k - 1];
            for j in (0..k - 1).rev() {
                m[j + 1] = d_prime[j] - c_prime[j] * m[j + 2];
            }
        }
        if h.iter().chain(&slope).chain(&m).any(|v| !v.is_finite()) {
            return Err(AnalysisError::Overflow);
        }
        Ok(Self {
            t: t.to_vec(),
            y: y.to_vec(),
            m,
        })
    }

    /// Value at `x`. Outside the knot range the first or last cubic piece is
    /// continued (as SciPy does by default). A NaN argument gives NaN.
    pub fn eval(&self, x: f64) -> f64 {
        let n = self.t.len();
        // Interval i with t[i] <= x < t[i+1], clamped to the end pieces.
        let i = self
            .t
            .partition_point(|&k| k <= x)
            .saturating_sub(1)
            .min(n - 2);
        let (t0, t1) = (self.t[i], self.t[i + 1]);
        let h = t1 - t0;
        let a = (t1 - x) / h;
        let b = (x - t0) / h;
        a * self.y[i]
            + b * self.y[i + 1]
            + ((a * a * a - a) * self.m[i] + (b * b * b - b) * self.m[i + 1]) * (h * h / 6.0)
    }

    /// The knots `t`.
    pub fn knots(&self) -> &[f64] {
        &self.t
    }

    /// The interpolated values `y`.
    pub fn values(&self) -> &[f64] {
        &self.y
    }

    /// Second derivatives at the knots (zero at both ends).
    pub fn second_derivatives(&self) -> &[f64] {
        &self.m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[derive(Deserialize)]
    struct Case {
        name: String,
        t: Vec<f64>,
        y: Vec<f64>,
        t_eval: Vec<f64>,
        y_eval: Vec<f64>,
    }

    #[test]
    fn spline_matches_scipy_natural_cubic_spline_to_1e9() {
        let cases: Vec<Case> =
            serde_json::from_str(include_str!("../../tests/fixtures/spline_natural.json"))
                .expect("fixture parses");
        assert!(cases.len() >= 3);
        for case in &cases {
            let s = NaturalCubicSpline::new(&case.t, &case.y).expect("fixture fits");
            assert_eq!(case.t_eval.len(), case.y_eval.len());
            for (&x, &want) in case.t_eval.iter().zip(&case.y_eval) {
                let got = s.eval(x);
                assert!(
                    (got - want).abs() <= 1e-9,
                    "{}: at t = {x} got {got}, SciPy {want}",
                    case.name
                );
            }
        }
    }

    #[test]
    fn spline_through_straight_line_is_that_line() {
        let t = [0.0, 0.1, 0.5, 0.7, 2.0];
        let y: Vec<f64> = t.iter().map(|v| 3.0 * v - 1.0).collect();
        let s = NaturalCubicSpline::new(&t, &y).unwrap();
        for &m in s.second_derivatives() {
            assert!(m.abs() < 1e-12);
        }
        for k in 0..=40 {
            let x = -0.5 + 3.0 * f64::from(k) / 40.0;
            assert!((s.eval(x) - (3.0 * x - 1.0)).abs() < 1e-12);
        }
    }

    #[test]
    fn spline_interpolates_knots_and_has_zero_end_curvature() {
        let t = [0.0, 0.3, 0.4, 1.0, 1.7];
        let y = [1.0, -2.0, 0.5, 0.25, 3.0];
        let s = NaturalCubicSpline::new(&t, &y).unwrap();
        for (&a, &b) in t.iter().zip(&y) {
            assert!((s.eval(a) - b).abs() < 1e-12);
        }
        let m = s.second_derivatives();
        assert_eq!((m[0], m[4]), (0.0, 0.0));
    }

    #[test]
    fn two_knot_spline_is_linear() {
        let s = NaturalCubicSpline::new(&[1.0, 3.0], &[2.0, 6.0]).unwrap();
        assert!((s.eval(2.0) - 4.0).abs() < 1e-15);
        assert!((s.eval(4.0) - 8.0).abs() < 1e-15);
    }

    #[test]
    fn spline_rejects_bad_knots() {
        assert_eq!(
            NaturalCubicSpline::new(&[0.0], &[1.0]),
            Err(AnalysisError::TooFewPoints { n: 1, min: 2 })
        );
        assert_eq!(
            NaturalCubicSpline::new(&[0.0, 1.0, 1.0], &[1.0, 2.0, 3.0]),
            Err(AnalysisError::KnotsNotIncreasing { index: 2 })
        );
        assert_eq!(
            NaturalCubicSpline::new(&[0.0, 1.0, 2.0], &[1.0, f64::NAN, 3.0]),
            Err(AnalysisError::NonFinite { index: 1 })
        );
        assert!(matches!(
            NaturalCubicSpline::new(&[0.0, 1.0], &[1.0]),
            Err(AnalysisError::LengthMismatch { .. })
        ));
    }
}
