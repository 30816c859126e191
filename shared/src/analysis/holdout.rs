//! Leave-one-trial-out recovery: how well a finished grid identifies the
//! reward value of a policy it has not seen. An extension beyond the paper's metrics
//! (docs/science.md#paper-metrics),
//! built only from its pieces.
//!
//! Each usable trial in turn plays a synthetic subject: its highest-return
//! kept episode (a raw COM path, exactly as a subject CSV would carry it) is
//! scored with the paper's costs against the weight means of the grid
//! rebuilt *without that trial*, through [`build_report`] itself. The value
//! inferred by each metric is compared with the trial's own. A synthetic
//! subject made by `irlgrid synth-subjects` is one more policy trained at a
//! planted value; here every trial of the grid is such a case, so a grid of
//! 7 values x 10 trials gives 70 recovery cases without training a single
//! extra policy.

use serde::{Deserialize, Serialize};

use super::report::{build_report, ReportOptions, WeightInput};
use super::subjects::SubjectPath;

/// One held-out trial.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct HoldOutCase {
    /// The trial's own label value (e.g. its w1).
    pub value: f64,
    /// Trial number within its grid point.
    pub trial: u32,
    /// Training seed.
    pub seed: u64,
    /// Label value inferred by area difference; `null` if none could be.
    pub inferred_area: Option<f64>,
    /// Label value inferred by correlation; `null` if none could be.
    pub inferred_corr: Option<f64>,
    /// Grid steps between the inferred and the true value (area metric):
    /// 0 is exact, 1 a grid neighbour. `null` when nothing was inferred.
    pub area_steps: Option<u32>,
    /// The same for the correlation metric.
    pub corr_steps: Option<u32>,
}

/// Tally of one metric over all cases.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct HoldOutTally {
    /// Cases whose inferred value is the true one.
    pub exact: u32,
    /// Cases whose inferred value is the true one or a grid neighbour.
    pub within_one: u32,
    /// `confusion[i][j]`: cases of grid value `values[i]` inferred as
    /// `values[j]` (rows true, columns inferred; a case with nothing
    /// inferred is in no column).
    pub confusion: Vec<Vec<u32>>,
}

/// Per grid value: how its own trials were recovered.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct HoldOutRow {
    /// The grid value.
    pub value: f64,
    /// Its held-out cases.
    pub cases: u32,
    /// Of those, inferred within one grid step by area difference.
    pub area_within_one: u32,
    /// Of those, inferred within one grid step by correlation.
    pub corr_within_one: u32,
}

/// The leave-one-trial-out result.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct HoldOutReport {
    /// The grid's label values in increasing order: grid steps count here.
    pub values: Vec<f64>,
    /// Cases scored.
    pub cases: u32,
    /// Area-difference metric (docs/science.md#area-difference, smallest `D`).
    pub area: HoldOutTally,
    /// Correlation metric (docs/science.md#correlation, largest `rho`).
    pub corr: HoldOutTally,
    /// One row per grid value, in `values` order (index i is `values[i]`).
    pub per_value: Vec<HoldOutRow>,
    /// Every case, grid value by grid value.
    pub case_list: Vec<HoldOutCase>,
    /// Trials or grid points that could not be held out, and why.
    pub notes: Vec<String>,
}

/// Runs the leave-one-trial-out recovery over `weights` (see the module
/// docs). A trial is held out when it entered its grid point's means
/// (converged, with a resampleable episode) and its grid point keeps at
/// least one other usable trial, so that the value stays on the grid.
/// Grid points without the label param are skipped with a note; never
/// fails.
pub fn hold_out_recovery(weights: &[WeightInput], opts: &ReportOptions) -> HoldOutReport {
    let full = build_report(weights, &[], opts);
    let mut notes = Vec::new();
    // Grid order: indices of the labelled points by increasing value.
    let mut order: Vec<usize> = (0..weights.len())
        .filter(|&i| {
            let has = full.weights[i].params.contains_key(&opts.label_param);
            if !has {
                notes.push(format!(
                    "grid point #{i} has no parameter {:?}; not held out",
                    opts.label_param
                ));
            }
            has
        })
        .collect();
    order.sort_by(|&a, &b| full.weights[a].value.total_cmp(&full.weights[b].value));
    let values: Vec<f64> = order.iter().map(|&i| full.weights[i].value).collect();
    let grid_index = |v: f64| values.iter().position(|&g| g == v);
    let n = values.len();
    // Confusion matrices, true grid index x inferred; the tallies and the
    // per-value rows are derived from them (and the case counts) below.
    let (mut area, mut corr) = (vec![vec![0u32; n]; n], vec![vec![0u32; n]; n]);
    let mut cases_per_row = vec![0u32; n];
    let mut case_list = Vec::new();
    // One copy of the grid; each held-out trial is taken out and put back.
    let mut reduced = weights.to_vec();
    for (row, &wi) in order.iter().enumerate() {
        let summary = &full.weights[wi];
        let usable: Vec<usize> = (0..summary.trials.len())
            .filter(|&t| summary.trials[t].used)
            .collect();
        if usable.len() < 2 {
            notes.push(format!(
                "{} = {}: {} usable trial(s); holding one out would take the value off the grid",
                opts.label_param,
                summary.value,
                usable.len()
            ));
            continue;
        }
        for &t in &usable {
            let held = reduced[wi].trials.remove(t);
            let scored = top_episode_subject(&held, summary.value)
                .map(|subject| build_report(&reduced, &[subject], opts));
            let (trial, seed) = (held.trial, held.seed);
            reduced[wi].trials.insert(t, held);
            let Some(doc) = scored else {
                notes.push(format!(
                    "{} = {}, trial {trial}: no kept episode has a finite return; not held out",
                    opts.label_param, summary.value
                ));
                continue;
            };
            let s = &doc.subjects[0];
            let steps = |inferred: Option<f64>| {
                inferred
                    .and_then(grid_index)
                    .map(|j| (j, u32::try_from(j.abs_diff(row)).unwrap_or(u32::MAX)))
            };
            let (a, c) = (steps(s.inferred_area), steps(s.inferred_corr));
            if let Some((j, _)) = a {
                area[row][j] += 1;
            }
            if let Some((j, _)) = c {
                corr[row][j] += 1;
            }
            cases_per_row[row] += 1;
            case_list.push(HoldOutCase {
                value: summary.value,
                trial,
                seed,
                inferred_area: s.inferred_area,
                inferred_corr: s.inferred_corr,
                area_steps: a.map(|(_, d)| d),
                corr_steps: c.map(|(_, d)| d),
            });
        }
    }
    // Cases of row i inferred within one grid step of i.
    let band = |m: &[Vec<u32>], i: usize| -> u32 {
        (i.saturating_sub(1)..(i + 2).min(n)).map(|j| m[i][j]).sum()
    };
    let per_value = (0..n)
        .map(|i| HoldOutRow {
            value: values[i],
            cases: cases_per_row[i],
            area_within_one: band(&area, i),
            corr_within_one: band(&corr, i),
        })
        .collect();
    let tally = |m: Vec<Vec<u32>>| HoldOutTally {
        exact: (0..n).map(|i| m[i][i]).sum(),
        within_one: (0..n).map(|i| band(&m, i)).sum(),
        confusion: m,
    };
    HoldOutReport {
        values,
        cases: u32::try_from(case_list.len()).unwrap_or(u32::MAX),
        area: tally(area),
        corr: tally(corr),
        per_value,
        case_list,
        notes,
    }
}

/// The trial's highest-return kept episode as a subject path (ties: the
/// first). `None` when no episode has a finite return.
fn top_episode_subject(trial: &super::report::TrialInput, value: f64) -> Option<SubjectPath> {
    // `reduce` keeps the earlier of equal returns.
    let best = trial
        .episodes
        .iter()
        .filter(|e| e.ret.is_finite())
        .reduce(|best, e| if e.ret > best.ret { e } else { best })?;
    Some(SubjectPath {
        subject: format!("held-out value {value} trial {}", trial.trial),
        t: best.com_t.clone(),
        x: best.com_x.clone(),
        z: best.com_z.clone(),
    })
}

/// The report as a plain-text table for a terminal: the confusion matrix
/// of the area metric, then per-value recovery by both metrics.
pub fn hold_out_table(r: &HoldOutReport, label: &str) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    let pct = |k: u32, n: u32| {
        if n == 0 {
            "-".to_string()
        } else {
            format!("{:.0} %", 100.0 * f64::from(k) / f64::from(n))
        }
    };
    let _ = writeln!(
        out,
        "leave-one-trial-out recovery: {} cases; by area {} exact, {} within one grid step ({}); \
         by correlation {} exact, {} within one ({})",
        r.cases,
        r.area.exact,
        r.area.within_one,
        pct(r.area.within_one, r.cases),
        r.corr.exact,
        r.corr.within_one,
        pct(r.corr.within_one, r.cases),
    );
    let _ = writeln!(
        out,
        "\narea metric, true {label} (rows) x inferred (columns):"
    );
    let _ = write!(out, "{:>8}", "");
    for v in &r.values {
        let _ = write!(out, "{v:>6}");
    }
    let _ = writeln!(out, "   within one");
    for (i, v) in r.values.iter().enumerate() {
        let _ = write!(out, "{v:>8}");
        for c in &r.area.confusion[i] {
            let _ = write!(out, "{c:>6}");
        }
        let p = &r.per_value[i];
        let _ = writeln!(out, "   {}/{}", p.area_within_one, p.cases);
    }
    let _ = writeln!(
        out,
        "\ncorrelation metric, within one grid step per {label}:"
    );
    for p in &r.per_value {
        let _ = writeln!(out, "{:>8}   {}/{}", p.value, p.corr_within_one, p.cases);
    }
    for n in &r.notes {
        let _ = writeln!(out, "note: {n}");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::report::{EpisodeRecord, TrialInput};
    use std::collections::BTreeMap;
    use std::f64::consts::PI;

    /// A bulging stand-up: x = amp sin(pi s), z = 0.6 + 0.4 s. After
    /// preprocessing its x is amp / 0.4 * sin(pi s) at the same arc-length
    /// positions up to the bulge's effect on chord length, so the area
    /// difference between two such paths grows with |amp_a - amp_b|.
    fn episode(amp: f64, ret: f64) -> EpisodeRecord {
        let n = 40;
        let s: Vec<f64> = (0..n).map(|k| f64::from(k) / f64::from(n - 1)).collect();
        EpisodeRecord {
            com_t: s.iter().map(|v| v * 0.8).collect(),
            com_x: s.iter().map(|v| amp * (PI * v).sin()).collect(),
            com_z: s.iter().map(|v| 0.6 + 0.4 * v).collect(),
            ret,
            torque_usage: 100.0,
            steps: 16,
        }
    }

    /// A converged trial whose best episode bulges by `amp` (a worse one
    /// bulges a little more, so the trial mean is not the top path).
    fn trial(n: u32, amp: f64) -> TrialInput {
        TrialInput {
            trial: n,
            seed: 1000 + u64::from(n),
            final_success_rate: 1.0,
            converged: true,
            episodes: vec![episode(amp, 900.0), episode(amp + 0.002, 800.0)],
            successes_found: 1000,
            successes_wanted: 1000,
        }
    }

    fn weight(w1: f64, amps: &[f64]) -> WeightInput {
        WeightInput {
            params: BTreeMap::from([("w1".to_string(), w1)]),
            trials: amps
                .iter()
                .enumerate()
                .map(|(i, &a)| trial(i as u32, a))
                .collect(),
        }
    }

    #[test]
    fn well_separated_grid_recovers_every_trial_exactly() {
        // Given out of order: grid steps follow the values, not the input.
        let grid = [
            weight(4.0, &[0.20, 0.21]),
            weight(1.0, &[0.05, 0.06]),
            weight(2.0, &[0.10, 0.11]),
        ];
        let r = hold_out_recovery(&grid, &ReportOptions::default());
        assert_eq!(r.values, vec![1.0, 2.0, 4.0]);
        assert_eq!(r.cases, 6);
        assert_eq!((r.area.exact, r.area.within_one), (6, 6));
        assert_eq!(
            r.area.confusion,
            vec![vec![2, 0, 0], vec![0, 2, 0], vec![0, 0, 2]]
        );
        assert!(r.case_list.iter().all(|c| c.area_steps == Some(0)));
        assert!(r.notes.is_empty(), "{:?}", r.notes);
    }

    #[test]
    fn held_out_trial_is_scored_without_itself() {
        // w1 = 2 has trials bulging 0.10 and 0.30. With its own trial in the
        // mean (0.20) the 0.10 trial would be nearest w1 = 2 or tie; held
        // out, w1 = 2's mean is 0.30 and w1 = 1's (0.09, 0.11 -> 0.10) is an
        // exact match, so it is inferred as 1: a neighbour, not exact.
        let grid = [
            weight(1.0, &[0.09, 0.11]),
            weight(2.0, &[0.10, 0.30]),
            weight(4.0, &[0.60, 0.62]),
        ];
        let r = hold_out_recovery(&grid, &ReportOptions::default());
        let case = r
            .case_list
            .iter()
            .find(|c| c.value == 2.0 && c.trial == 0)
            .unwrap();
        assert_eq!(case.inferred_area, Some(1.0));
        assert_eq!(case.area_steps, Some(1));
        // The 0.30 trial: w1 = 2's mean is then 0.10, w1 = 4's 0.61; 0.30 is
        // nearer 0.10 (0.20 away) than 0.61 (0.31 away) -> inferred 2, exact.
        let other = r
            .case_list
            .iter()
            .find(|c| c.value == 2.0 && c.trial == 1)
            .unwrap();
        assert_eq!(other.inferred_area, Some(2.0));
    }

    #[test]
    fn a_trial_two_steps_off_is_a_miss_in_the_tally() {
        // w1 = 4's third trial bulges like w1 = 1: inferred 1, two steps off.
        let grid = [
            weight(1.0, &[0.05, 0.06]),
            weight(2.0, &[0.10, 0.11]),
            weight(4.0, &[0.20, 0.21, 0.055]),
        ];
        let r = hold_out_recovery(&grid, &ReportOptions::default());
        let odd = r
            .case_list
            .iter()
            .find(|c| c.value == 4.0 && c.trial == 2)
            .unwrap();
        assert_eq!((odd.inferred_area, odd.area_steps), (Some(1.0), Some(2)));
        assert_eq!(r.area.confusion[2][0], 1);
        assert_eq!(r.cases, 7);
        assert_eq!(r.area.within_one, 6);
        let row4 = r.per_value.iter().find(|p| p.value == 4.0).unwrap();
        assert_eq!((row4.cases, row4.area_within_one), (3, 2));
        let table = hold_out_table(&r, "w1");
        assert!(table.contains("7 cases"), "{table}");
        assert!(table.contains("6 within one grid step (86 %)"), "{table}");
    }

    #[test]
    fn single_trial_points_and_unconverged_trials_are_not_held_out() {
        let mut grid = vec![weight(1.0, &[0.05]), weight(2.0, &[0.10, 0.11, 0.12])];
        grid[1].trials[2].converged = false;
        let r = hold_out_recovery(&grid, &ReportOptions::default());
        assert_eq!(r.cases, 2, "only w1 = 2's two converged trials");
        assert_eq!(r.per_value[0].cases, 0);
        assert!(r.notes.iter().any(|n| n.contains("w1 = 1: 1 usable")));
        // The single-trial point still competes as a candidate.
        assert_eq!(r.values, vec![1.0, 2.0]);
    }

    #[test]
    fn a_trial_without_a_finite_return_is_skipped_with_a_note() {
        let mut grid = vec![weight(1.0, &[0.05, 0.06, 0.07]), weight(2.0, &[0.10, 0.11])];
        for e in &mut grid[0].trials[1].episodes {
            e.ret = f64::NAN;
        }
        let r = hold_out_recovery(&grid, &ReportOptions::default());
        assert_eq!(r.cases, 4);
        assert!(
            r.notes
                .iter()
                .any(|n| n == "w1 = 1, trial 1: no kept episode has a finite return; not held out"),
            "{:?}",
            r.notes
        );
    }

    #[test]
    fn empty_grid_gives_an_empty_report() {
        let r = hold_out_recovery(&[], &ReportOptions::default());
        assert_eq!(r.cases, 0);
        assert!(r.values.is_empty());
        assert!(hold_out_table(&r, "w1").contains("0 cases"));
    }
}
