//! Aggregation statistics (docs/science.md#aggregation): pointwise mean and standard deviation
//! of equally long paths, and mean, standard deviation and SEM of scalars.
//!
//! Small samples are defined rather than NaN: no items gives `None` (or
//! [`AnalysisError::Empty`] for paths), one item gives a spread of 0, which
//! means "not estimable from one sample", not "exactly known".
//! Inputs are assumed finite; the report filters non-finite values first.

use super::AnalysisError;

/// Checks that paths are non-empty and equally long; returns that length.
fn common_len<P: AsRef<[f64]>>(paths: &[P]) -> Result<usize, AnalysisError> {
    let first = paths.first().ok_or(AnalysisError::Empty)?.as_ref().len();
    for p in paths {
        let found = p.as_ref().len();
        if found != first {
            return Err(AnalysisError::LengthMismatch {
                what: "path",
                expected: first,
                found,
            });
        }
    }
    Ok(first)
}

/// Pointwise mean of equally long paths (trial and weight means, docs/science.md#aggregation).
/// `Empty` for no paths, `LengthMismatch` for ragged input.
pub fn pointwise_mean<P: AsRef<[f64]>>(paths: &[P]) -> Result<Vec<f64>, AnalysisError> {
    let len = common_len(paths)?;
    let n = paths.len() as f64;
    Ok((0..len)
        .map(|k| paths.iter().map(|p| p.as_ref()[k]).sum::<f64>() / n)
        .collect())
}

/// Pointwise sample standard deviation (divisor n - 1) of equally long paths
/// (the spread across trial means, docs/science.md#aggregation). One path gives all zeros; no paths
/// give `Empty`.
pub fn pointwise_sd<P: AsRef<[f64]>>(paths: &[P]) -> Result<Vec<f64>, AnalysisError> {
    let mean = pointwise_mean(paths)?;
    if paths.len() < 2 {
        return Ok(vec![0.0; mean.len()]);
    }
    let denom = (paths.len() - 1) as f64;
    Ok(mean
        .iter()
        .enumerate()
        .map(|(k, m)| {
            let ss: f64 = paths.iter().map(|p| (p.as_ref()[k] - m).powi(2)).sum();
            (ss / denom).sqrt()
        })
        .collect())
}

/// Arithmetic mean; `None` for no values.
pub fn mean(xs: &[f64]) -> Option<f64> {
    if xs.is_empty() {
        None
    } else {
        Some(xs.iter().sum::<f64>() / xs.len() as f64)
    }
}

/// Sample standard deviation (divisor n - 1, two-pass); `None` for no
/// values, 0 for one value.
pub fn sample_sd(xs: &[f64]) -> Option<f64> {
    let m = mean(xs)?;
    if xs.len() < 2 {
        return Some(0.0);
    }
    let ss: f64 = xs.iter().map(|v| (v - m).powi(2)).sum();
    Some((ss / (xs.len() - 1) as f64).sqrt())
}

/// Standard error of the mean, `sample_sd / sqrt(n)` (docs/science.md#aggregation); `None` for no
/// values, 0 for one value.
pub fn sem(xs: &[f64]) -> Option<f64> {
    Some(sample_sd(xs)? / (xs.len() as f64).sqrt())
}

/// Mean and SEM together; `None` for no values.
pub fn mean_sem(xs: &[f64]) -> Option<(f64, f64)> {
    Some((mean(xs)?, sem(xs)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pointwise_mean_and_sd_match_hand_computation() {
        let paths = vec![
            vec![1.0, 2.0, 3.0],
            vec![3.0, 2.0, 0.0],
            vec![2.0, 2.0, 6.0],
        ];
        let m = pointwise_mean(&paths).unwrap();
        assert_eq!(m, vec![2.0, 2.0, 3.0]);
        let sd = pointwise_sd(&paths).unwrap();
        // Point 0: deviations -1, 1, 0 -> ss 2 -> var 1. Point 2: 0, -3, 3 -> 18 / 2.
        assert!((sd[0] - 1.0).abs() < 1e-15);
        assert_eq!(sd[1], 0.0);
        assert!((sd[2] - 3.0).abs() < 1e-15);
    }

    #[test]
    fn pointwise_stats_of_no_paths_are_empty_and_of_one_path_have_zero_sd() {
        let none: Vec<Vec<f64>> = vec![];
        assert_eq!(pointwise_mean(&none), Err(AnalysisError::Empty));
        assert_eq!(pointwise_sd(&none), Err(AnalysisError::Empty));
        let one = [[4.0, 5.0]];
        assert_eq!(pointwise_mean(&one).unwrap(), vec![4.0, 5.0]);
        assert_eq!(pointwise_sd(&one).unwrap(), vec![0.0, 0.0]);
    }

    #[test]
    fn ragged_paths_are_a_length_mismatch() {
        let paths: Vec<&[f64]> = vec![&[1.0, 2.0], &[1.0]];
        assert!(matches!(
            pointwise_mean(&paths),
            Err(AnalysisError::LengthMismatch {
                expected: 2,
                found: 1,
                ..
            })
        ));
    }

    #[test]
    fn scalar_mean_sd_sem_match_hand_computation() {
        let xs = [2.0, 4.0, 4.0, 4.0, 5.0, 5.0, 7.0, 9.0];
        assert_eq!(mean(&xs), Some(5.0));
        // Sum of squared deviations 32, n - 1 = 7.
        let sd = (32.0_f64 / 7.0).sqrt();
        assert!((sample_sd(&xs).unwrap() - sd).abs() < 1e-15);
        assert!((sem(&xs).unwrap() - sd / 8.0_f64.sqrt()).abs() < 1e-15);
        let (m, s) = mean_sem(&xs).unwrap();
        assert_eq!(m, 5.0);
        assert!((s - sd / 8.0_f64.sqrt()).abs() < 1e-15);
    }

    #[test]
    fn scalar_stats_of_no_values_are_none_and_of_one_value_have_zero_spread() {
        assert_eq!(mean(&[]), None);
        assert_eq!(sample_sd(&[]), None);
        assert_eq!(sem(&[]), None);
        assert_eq!(mean_sem(&[]), None);
        assert_eq!(mean_sem(&[3.5]), Some((3.5, 0.0)));
    }
}
