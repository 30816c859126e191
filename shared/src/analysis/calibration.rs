//! Calibration of probabilities over the grid (docs/inference.md#calibration):
//! over a set of cases whose true grid value is known, how often the
//! highest-probability set at each nominal level holds the truth, how large
//! those sets are, and how much probability the true value gets compared
//! with a uniform guess.

use serde::{Deserialize, Serialize};

use super::posterior::{highest_probability_set, shortest_interval_set, CredibleSet};

/// The nominal levels reported.
pub const COVERAGE_LEVELS: [f64; 4] = [0.5, 0.8, 0.9, 0.95];

/// Probabilities below this count as this in the log score, so that one
/// case given probability 0 scores log(1e-300) = -690.8 rather than minus
/// infinity.
pub const LOG_PROB_FLOOR: f64 = 1e-300;

/// One nominal level.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct CoverageRow {
    /// Nominal mass of the highest-probability sets.
    pub level: f64,
    /// Fraction of cases whose set held the true value.
    pub coverage: f64,
    /// Mean number of grid points in the sets.
    pub mean_set_size: f64,
}

/// The calibration of one method over a set of cases.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct Calibration {
    /// Cases scored.
    pub cases: u32,
    /// One row per level of [`COVERAGE_LEVELS`].
    pub levels: Vec<CoverageRow>,
    /// Mean over cases of log(probability of the true value), nats.
    pub mean_log_prob: f64,
    /// log(1 / number of grid values): what a uniform guess scores.
    pub uniform_log_prob: f64,
    /// `mean_log_prob - uniform_log_prob`: positive when informative.
    pub gain_nats: f64,
}

impl Calibration {
    /// The row of the nominal `level` (one of [`COVERAGE_LEVELS`]), if
    /// it was computed.
    pub fn at(&self, level: f64) -> Option<&CoverageRow> {
        self.levels.iter().find(|l| (l.level - level).abs() < 1e-9)
    }
}

/// Calibration over `cases`, each the true value's index and the
/// probabilities over `n_values` grid values (aligned by index). `None`
/// without cases or grid values. A case whose probabilities are all zero
/// (the method could not answer) has an empty set at every level and
/// scores [`LOG_PROB_FLOOR`].
pub fn calibrate(cases: &[(usize, &[f64])], n_values: usize) -> Option<Calibration> {
    calibrate_sets(cases, n_values, SetRule::HighestProbability)
}

/// How the credible sets of a calibration are formed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SetRule {
    /// The smallest set of points by decreasing probability.
    HighestProbability,
    /// The shortest interval of neighbours, the probabilities being in
    /// increasing order of the parameter (docs/inference.md#credible-sets).
    Interval,
}

impl SetRule {
    fn set(self, probs: &[f64], level: f64) -> CredibleSet {
        match self {
            Self::HighestProbability => highest_probability_set(probs, level),
            Self::Interval => {
                let order: Vec<usize> = (0..probs.len()).collect();
                shortest_interval_set(probs, &order, level)
            }
        }
    }
}

/// [`calibrate`] with the sets formed by `rule`.
pub fn calibrate_sets(
    cases: &[(usize, &[f64])],
    n_values: usize,
    rule: SetRule,
) -> Option<Calibration> {
    if cases.is_empty() || n_values == 0 {
        return None;
    }
    let n = cases.len() as f64;
    let levels = COVERAGE_LEVELS
        .iter()
        .map(|&level| {
            let (mut covered, mut size) = (0usize, 0usize);
            for (truth, probs) in cases {
                let set = rule.set(probs, level);
                covered += usize::from(set.indices.contains(truth));
                size += set.indices.len();
            }
            CoverageRow {
                level,
                coverage: covered as f64 / n,
                mean_set_size: size as f64 / n,
            }
        })
        .collect();
    let mean_log_prob = cases
        .iter()
        .map(|(truth, probs)| {
            let p = probs.get(*truth).copied().unwrap_or(0.0);
            p.max(LOG_PROB_FLOOR).ln()
        })
        .sum::<f64>()
        / n;
    let uniform_log_prob = -(n_values as f64).ln();
    Some(Calibration {
        cases: u32::try_from(cases.len()).unwrap_or(u32::MAX),
        levels,
        mean_log_prob,
        uniform_log_prob,
        gain_nats: mean_log_prob - uniform_log_prob,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coverage_set_sizes_and_log_score_of_hand_made_cases() {
        // Three grid values, four cases.
        let a = [0.7, 0.2, 0.1]; // truth 0: in every set
        let b = [0.6, 0.3, 0.1]; // truth 1: second; in the 80 % set and up
        let c = [0.1, 0.1, 0.8]; // truth 0: tie with 1 broken by index
        let d = [0.0, 0.0, 0.0]; // truth 2: no answer
        let cases: Vec<(usize, &[f64])> = vec![(0, &a), (1, &b), (0, &c), (2, &d)];
        let cal = calibrate(&cases, 3).unwrap();
        assert_eq!(cal.cases, 4);
        // 50 %: sets {0}, {0}, {2}, {} -> covered a only.
        assert_eq!(cal.levels[0].coverage, 0.25);
        assert_eq!(cal.levels[0].mean_set_size, 0.75);
        // 80 %: {0,1}, {0,1}, {2}, {} -> a and b. (0.8 for c reached by 2 alone.)
        assert_eq!(cal.levels[1].coverage, 0.5);
        assert_eq!(cal.levels[1].mean_set_size, 1.25);
        // 90 %: {0,1}, {0,1}, {0,2} (tie 0 before 1), {} -> a, b, c.
        assert_eq!(cal.levels[2].coverage, 0.75);
        assert_eq!(cal.levels[2].mean_set_size, 1.5);
        // 95 %: {0,1,2}, {0,1,2}, {0,1,2}, {} -> a, b, c.
        assert_eq!(cal.levels[3].coverage, 0.75);
        let want = (0.7f64.ln() + 0.3f64.ln() + 0.1f64.ln() + LOG_PROB_FLOOR.ln()) / 4.0;
        assert!((cal.mean_log_prob - want).abs() < 1e-12);
        assert!((cal.uniform_log_prob + 3f64.ln()).abs() < 1e-15);
        assert!((cal.gain_nats - (want + 3f64.ln())).abs() < 1e-12);
    }

    #[test]
    fn uniform_answers_score_the_baseline() {
        let u = [0.25; 4];
        let cases: Vec<(usize, &[f64])> = (0..4).map(|t| (t, &u[..])).collect();
        let cal = calibrate(&cases, 4).unwrap();
        assert!(cal.gain_nats.abs() < 1e-12);
        // The 50 % set of a tie is the two lowest indices: truths 0 and 1.
        assert_eq!(cal.levels[0].coverage, 0.5);
        assert!(calibrate(&[], 4).is_none());
    }

    #[test]
    fn interval_sets_hold_the_gap_between_two_likely_values() {
        // Truth 1 has little mass between two likely neighbours: outside
        // the highest-probability 90 % set, inside the interval.
        let a = [0.46, 0.04, 0.46, 0.04];
        let cases: Vec<(usize, &[f64])> = vec![(1, &a)];
        let hpd = calibrate(&cases, 4).unwrap();
        let int = calibrate_sets(&cases, 4, SetRule::Interval).unwrap();
        assert_eq!(hpd.levels[2].coverage, 0.0);
        assert_eq!(hpd.levels[2].mean_set_size, 2.0);
        assert_eq!(int.levels[2].coverage, 1.0);
        assert_eq!(int.levels[2].mean_set_size, 3.0);
    }
}
