//! Adaptive refinement of a one-parameter grid toward each subject's value
//! (docs/science.md#refinement). After a grid has finished, every subject's
//! answer is read as a pair of neighbouring grid values that bracket it:
//! its most likely point and the more likely of that point's two
//! neighbours in the sorted values (by posterior probability, or by area
//! difference before the grid has a posterior). When the pair is wider
//! than the target ratio and, under the posterior, holds enough of the
//! subject's posterior mass to say that the subject lies between them, its
//! geometric midpoint is the next point to train. Points wanted by several
//! subjects are trained once. A flat posterior asks for nothing: more
//! points cannot sharpen an answer the grid does not resolve.
//!
//! Pure functions of a [`ResultDocument`]: the coordinator calls them when
//! a refining search completes and stores what they answered.

use serde::{Deserialize, Serialize};

use super::{Method, ResultDocument, SubjectSummary};

/// Default rounds of refinement.
pub const DEFAULT_ROUNDS: u32 = 3;
/// Default neighbour ratio below which a subject needs no more points.
pub const DEFAULT_TARGET_RATIO: f64 = 1.2;
/// Smallest target ratio accepted: a midpoint must stay distinguishable
/// from its neighbours at [`MIDPOINT_DIGITS`] significant digits.
pub const MIN_TARGET_RATIO: f64 = 1.01;
/// Default posterior mass the bracketing pair must hold for the subject
/// to ask for its midpoint.
pub const DEFAULT_MIN_PAIR_MASS: f64 = 0.5;
/// Significant digits a midpoint is rounded to (readable labels; far finer
/// than any grid step refinement reaches).
pub const MIDPOINT_DIGITS: i32 = 4;

/// One subject's reading of the grid in a refinement round.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct SubjectRefinement {
    /// Subject label.
    pub subject: String,
    /// Which score chose the pair: `posterior`, or `area` while the grid
    /// has too few trials for a posterior; `null` if neither answered.
    pub method: Option<Method>,
    /// The subject's estimate: the most likely grid value.
    pub estimate: Option<f64>,
    /// Lower value of the bracketing pair of neighbours.
    pub lo: Option<f64>,
    /// Upper value of the bracketing pair.
    pub hi: Option<f64>,
    /// `hi / lo` (infinite when `lo` is 0).
    pub ratio: Option<f64>,
    /// Posterior mass on `lo` and `hi` together (posterior only).
    pub pair_mass: Option<f64>,
    /// The point this subject asks for, if its pair is not yet narrow enough.
    pub midpoint: Option<f64>,
    /// Why the subject asks for nothing (narrow enough, no answer, ...).
    pub reason: Option<String>,
}

/// When a subject asks for a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefineRule {
    /// A pair narrower than this ratio is settled.
    pub target_ratio: f64,
    /// Under the posterior, the pair must hold at least this mass.
    pub min_pair_mass: f64,
}

impl Default for RefineRule {
    fn default() -> Self {
        Self {
            target_ratio: DEFAULT_TARGET_RATIO,
            min_pair_mass: DEFAULT_MIN_PAIR_MASS,
        }
    }
}

/// Reads every subject of `doc` against its grid and says which points to
/// add. `doc.weights` must be a one-parameter grid in increasing value
/// order (as the coordinator and `irlgrid analyze` build it).
pub fn evaluate(doc: &ResultDocument, rule: RefineRule) -> Vec<SubjectRefinement> {
    let values: Vec<f64> = doc.weights.iter().map(|w| w.value).collect();
    doc.subjects
        .iter()
        .map(|s| evaluate_subject(s, &values, rule))
        .collect()
}

/// The distinct points the subjects ask for, in increasing order.
pub fn midpoints(subjects: &[SubjectRefinement]) -> Vec<f64> {
    let mut out: Vec<f64> = subjects.iter().filter_map(|s| s.midpoint).collect();
    out.sort_by(f64::total_cmp);
    out.dedup();
    out
}

fn evaluate_subject(s: &SubjectSummary, values: &[f64], rule: RefineRule) -> SubjectRefinement {
    let target = rule.target_ratio;
    let mut r = SubjectRefinement {
        subject: s.subject.clone(),
        method: None,
        estimate: None,
        lo: None,
        hi: None,
        ratio: None,
        pair_mass: None,
        midpoint: None,
        reason: None,
    };
    let Some((method, goodness)) = scores(s, values.len()) else {
        r.reason = Some(
            s.error
                .clone()
                .unwrap_or_else(|| "no method answered for this subject".to_string()),
        );
        return r;
    };
    r.method = Some(method);
    let Some(best) = best_index(&goodness) else {
        r.reason = Some("no grid point has a score".to_string());
        return r;
    };
    r.estimate = Some(values[best]);
    let neighbour = [
        best.checked_sub(1),
        Some(best + 1).filter(|&i| i < values.len()),
    ]
    .into_iter()
    .flatten()
    .filter(|&i| goodness[i].is_some())
    // The more likely neighbour; on a tie the lower one.
    .fold(None, |acc: Option<usize>, i| match acc {
        Some(a) if goodness[a] >= goodness[i] => Some(a),
        _ => Some(i),
    });
    let Some(nb) = neighbour else {
        r.reason = Some("no neighbouring grid point has a score".to_string());
        return r;
    };
    let (lo, hi) = (values[best.min(nb)], values[best.max(nb)]);
    let ratio = if lo > 0.0 { hi / lo } else { f64::INFINITY };
    (r.lo, r.hi, r.ratio) = (Some(lo), Some(hi), Some(ratio));
    if ratio < target {
        r.reason = Some(format!(
            "neighbours {lo} and {hi} are within the target ratio {target}"
        ));
        return r;
    }
    if method == Method::Posterior {
        let mass = goodness[best].map_or(0.0, |g| g.0) + goodness[nb].map_or(0.0, |g| g.0);
        r.pair_mass = Some(mass);
        if mass < rule.min_pair_mass {
            r.reason = Some(format!(
                "the posterior does not straddle two neighbours: {lo} and {hi} hold {:.0} % of \
                 it (at least {:.0} % needed); the grid does not resolve this subject here, and \
                 more points would not sharpen its answer",
                mass * 100.0,
                rule.min_pair_mass * 100.0
            ));
            return r;
        }
    }
    let mid = round_significant(midpoint(lo, hi), MIDPOINT_DIGITS);
    if mid <= lo || mid >= hi {
        r.reason = Some(format!(
            "{lo} and {hi} have no distinct midpoint at {MIDPOINT_DIGITS} significant digits"
        ));
        return r;
    }
    r.midpoint = Some(mid);
    r
}

/// Higher is better, one entry per grid point (`None`: no score there):
/// the posterior's probability when it answered, else minus the area
/// difference. Posterior probabilities that underflow to the same value
/// (two neighbours far from a sharp peak) are told apart by the log
/// predictive density, the posterior's score.
fn scores(s: &SubjectSummary, n: usize) -> Option<(Method, Vec<Option<Goodness>>)> {
    if let Some(p) = s.method(Method::Posterior) {
        if p.inferred_index.is_some() && p.probabilities.len() == n && p.scores.len() == n {
            let g = p
                .probabilities
                .iter()
                .zip(&p.scores)
                .map(|(&pr, sc)| sc.map(|sc| Goodness(pr, sc)))
                .collect();
            return Some((Method::Posterior, g));
        }
    }
    let a = s.method(Method::Area)?;
    if a.inferred_index.is_none() || a.scores.len() != n {
        return None;
    }
    Some((
        Method::Area,
        a.scores
            .iter()
            .map(|d| d.map(|d| Goodness(-d, 0.0)))
            .collect(),
    ))
}

/// A grid point's goodness for a subject: compared by the first number,
/// then by the second.
#[derive(Clone, Copy, Debug, PartialEq, PartialOrd)]
struct Goodness(f64, f64);

/// Index of the largest score; the first on a tie.
fn best_index<T: PartialOrd + Copy>(goodness: &[Option<T>]) -> Option<usize> {
    let mut best: Option<(usize, T)> = None;
    for (i, g) in goodness.iter().enumerate() {
        if let Some(g) = *g {
            if best.is_none_or(|(_, b)| g > b) {
                best = Some((i, g));
            }
        }
    }
    best.map(|(i, _)| i)
}

/// The geometric midpoint of a positive pair (the grid is read in log w1);
/// the arithmetic one when the lower value is 0 or below.
pub fn midpoint(lo: f64, hi: f64) -> f64 {
    if lo > 0.0 {
        (lo * hi).sqrt()
    } else {
        0.5 * (lo + hi)
    }
}

/// `x` rounded to `digits` significant digits.
pub fn round_significant(x: f64, digits: i32) -> f64 {
    if x == 0.0 || !x.is_finite() {
        return x;
    }
    let scale = 10f64.powi(digits - 1 - x.abs().log10().floor() as i32);
    (x * scale).round() / scale
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::{build_report, MethodResult};

    /// A document with grid `values` and one subject per probability row
    /// (posterior), scored by area as minus the probability when `area`.
    fn doc(values: &[f64], rows: &[&[f64]], area: bool) -> ResultDocument {
        let mut d = build_report(&[], &[], &Default::default());
        let template = build_report(
            &[crate::analysis::WeightInput {
                params: [("w1".to_string(), 1.0)].into(),
                trials: vec![],
            }],
            &[],
            &Default::default(),
        )
        .weights
        .remove(0);
        d.weights = values
            .iter()
            .map(|&v| {
                let mut w = template.clone();
                w.value = v;
                w.params = [("w1".to_string(), v)].into();
                w
            })
            .collect();
        d.subjects = rows
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let best = best_index(&p.iter().map(|&x| Some(x)).collect::<Vec<_>>());
                let result = MethodResult {
                    scores: p
                        .iter()
                        .map(|&x| Some(if area { 1.0 - x } else { x.ln() }))
                        .collect(),
                    probabilities: p.to_vec(),
                    inferred_index: best,
                    inferred: best.map(|i| values[i]),
                    credible_set: None,
                    out_of_model: None,
                    unavailable: None,
                };
                let method = if area {
                    Method::Area
                } else {
                    Method::Posterior
                };
                SubjectSummary {
                    subject: format!("s{k}"),
                    x: None,
                    z: None,
                    area: None,
                    methods: [(method, result)].into(),
                    error: None,
                }
            })
            .collect();
        d
    }

    const PAPER: [f64; 7] = [0.1, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0];

    fn rule(target_ratio: f64) -> RefineRule {
        RefineRule {
            target_ratio,
            ..RefineRule::default()
        }
    }

    #[test]
    fn the_pair_is_the_best_point_and_its_more_likely_neighbour() {
        // Mass at 4 with more on 8 than on 2: the pair is (4, 8).
        let d = doc(&PAPER, &[&[0.0, 0.0, 0.0, 0.1, 0.6, 0.3, 0.0]], false);
        let r = evaluate(&d, rule(1.2));
        assert_eq!(r[0].method, Some(Method::Posterior));
        assert_eq!(
            (r[0].lo, r[0].hi, r[0].estimate),
            (Some(4.0), Some(8.0), Some(4.0))
        );
        assert_eq!(r[0].ratio, Some(2.0));
        // sqrt(32) = 5.65685... at 4 significant digits.
        assert_eq!(r[0].midpoint, Some(5.657));
        // At the end of the grid the only neighbour is used.
        let d = doc(&PAPER, &[&[0.0, 0.0, 0.0, 0.0, 0.0, 0.2, 0.8]], false);
        let r = evaluate(&d, rule(1.2));
        assert_eq!((r[0].lo, r[0].hi), (Some(8.0), Some(16.0)));
        assert_eq!(r[0].midpoint, Some(11.31));
    }

    #[test]
    fn subjects_asking_for_the_same_point_share_it_and_narrow_pairs_ask_for_none() {
        let d = doc(
            &PAPER,
            &[
                &[0.0, 0.0, 0.0, 0.1, 0.6, 0.3, 0.0],
                &[0.0, 0.0, 0.0, 0.0, 0.3, 0.7, 0.0],
                &[0.5, 0.4, 0.1, 0.0, 0.0, 0.0, 0.0],
            ],
            false,
        );
        let r = evaluate(&d, rule(1.2));
        assert_eq!(r[0].midpoint, r[1].midpoint);
        // sqrt(0.05) = 0.22360...
        assert_eq!(midpoints(&r), vec![0.2236, 5.657]);
        // A ratio below the target asks for nothing, with the reason.
        let d = doc(&[4.0, 4.757, 5.657], &[&[0.1, 0.5, 0.4]], false);
        let r = evaluate(&d, rule(1.2));
        assert_eq!(r[0].midpoint, None);
        assert!(r[0].ratio.unwrap() < 1.2);
        assert!(r[0]
            .reason
            .as_deref()
            .unwrap()
            .contains("within the target"));
        // The same pair asks for its midpoint under a stricter target.
        let r = evaluate(&d, rule(1.1));
        assert_eq!(r[0].midpoint, Some(5.188));
    }

    #[test]
    fn three_rounds_of_halving_log_steps_reach_a_planted_value_from_the_paper_grid() {
        // A subject whose true value is 5.7, read by a posterior that puts
        // its mass on the grid point nearest in log w1 and the next nearest:
        // each round halves the log step around it.
        let truth: f64 = 5.7;
        let mut grid = PAPER.to_vec();
        let mut added = 0;
        let mut rounds = 0;
        loop {
            let d: Vec<f64> = grid.iter().map(|v| (v.ln() - truth.ln()).abs()).collect();
            let p: Vec<f64> = d.iter().map(|x| (-x * 8.0).exp()).collect();
            let total: f64 = p.iter().sum();
            let p: Vec<f64> = p.iter().map(|x| x / total).collect();
            let doc = doc(&grid, &[&p], false);
            let r = evaluate(&doc, rule(1.2));
            let est = r[0].estimate.unwrap();
            let Some(m) = r[0].midpoint else {
                assert!((est / truth - 1.0).abs() < 0.15, "{est}");
                break;
            };
            grid.push(m);
            grid.sort_by(f64::total_cmp);
            added += 1;
            rounds += 1;
            assert!(rounds <= 3, "{grid:?}");
        }
        assert_eq!((rounds, added), (2, 2), "{grid:?}");
    }

    #[test]
    fn neighbours_whose_probabilities_underflow_are_told_apart_by_their_density() {
        // A sharp peak at 4: both neighbours have probability 0, but 8 has
        // the higher log predictive density.
        let mut d = doc(&PAPER, &[&[0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0]], false);
        let post = d.subjects[0].methods.get_mut(&Method::Posterior).unwrap();
        post.scores = [-900.0, -800.0, -700.0, -600.0, -1.0, -500.0, -650.0]
            .map(Some)
            .to_vec();
        let r = evaluate(&d, rule(1.2));
        assert_eq!((r[0].lo, r[0].hi), (Some(4.0), Some(8.0)));
    }

    #[test]
    fn a_flat_posterior_asks_for_no_point_and_says_the_grid_does_not_resolve_it() {
        // MAP 0.1 with 0.5 next to it, but the pair holds 35 % of the mass.
        let d = doc(&PAPER, &[&[0.2, 0.15, 0.14, 0.13, 0.13, 0.13, 0.12]], false);
        let r = evaluate(&d, rule(1.2));
        assert_eq!((r[0].lo, r[0].hi), (Some(0.1), Some(0.5)));
        assert!((r[0].pair_mass.unwrap() - 0.35).abs() < 1e-12);
        assert_eq!(r[0].midpoint, None);
        assert!(r[0]
            .reason
            .as_deref()
            .unwrap()
            .contains("does not straddle"));
        // A looser rule refines it anyway; the area difference has no mass.
        let loose = RefineRule {
            min_pair_mass: 0.3,
            ..rule(1.2)
        };
        assert_eq!(evaluate(&d, loose)[0].midpoint, Some(0.2236));
        let d = doc(&PAPER, &[&[0.2, 0.15, 0.14, 0.13, 0.13, 0.13, 0.12]], true);
        assert_eq!(evaluate(&d, rule(1.2))[0].midpoint, Some(0.2236));
    }

    #[test]
    fn the_area_difference_answers_while_the_grid_has_no_posterior() {
        let d = doc(&PAPER, &[&[0.0, 0.1, 0.5, 0.3, 0.0, 0.0, 0.0]], true);
        let r = evaluate(&d, rule(1.2));
        assert_eq!(r[0].method, Some(Method::Area));
        assert_eq!((r[0].lo, r[0].hi), (Some(1.0), Some(2.0)));
        assert_eq!(r[0].midpoint, Some(1.414));
    }

    #[test]
    fn a_subject_without_an_answer_asks_for_nothing_and_says_why() {
        let mut d = doc(&PAPER, &[&[0.0; 7]], false);
        d.subjects[0].methods.clear();
        d.subjects[0].error = Some("too few samples".into());
        let r = evaluate(&d, rule(1.2));
        assert_eq!(r[0].midpoint, None);
        assert_eq!(r[0].reason.as_deref(), Some("too few samples"));
    }

    #[test]
    fn midpoints_are_geometric_and_rounded_to_four_significant_digits() {
        assert_eq!(midpoint(4.0, 16.0), 8.0);
        assert_eq!(midpoint(0.0, 1.0), 0.5);
        assert_eq!(round_significant(5.656854, 4), 5.657);
        assert_eq!(round_significant(0.0223606, 4), 0.02236);
        assert_eq!(round_significant(1131.37, 4), 1131.0);
    }
}
