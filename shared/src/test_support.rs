//! Synthetic fixtures for the tests and benches of every crate of the
//! workspace (cargo feature `test-support`, which their dev-dependencies
//! turn on; `shared`'s own unit tests see it too). Not part of the
//! science: nothing in a build of the binaries uses it.

use std::f64::consts::PI;

use std::collections::BTreeMap;

use crate::analysis::{EpisodeRecord, SolverKind, SolverTag, SubjectPath, TrialInput, WeightInput};

/// The synthetic "bulging stand-up" the tests and benches build episodes
/// and subjects from: over `samples` evenly spaced `s` in [0, 1] the COM
/// rises as `z = z0 + rise s` while it bulges forward as
/// `x = bulge sin(pi s) + wobble sin(2 pi s)`, at times `t = duration s`.
/// A larger bulge gives a larger path area, so a grid of bulges stands in
/// for a grid of reward values.
///
/// `StandUp::new(bulge)` is a 40-sample, 0.8 s rise from 0.6 m to 1.0 m
/// without wobble, return 900, torque usage 100 N m s, 16 control steps;
/// each builder method changes one of those.
#[derive(Clone, Debug, PartialEq)]
pub struct StandUp {
    /// Peak forward displacement of the first harmonic (m).
    pub bulge: f64,
    /// Amplitude of the second harmonic (m), which skews the bulge.
    pub wobble: f64,
    /// Samples of the path, both ends included (at least 2).
    pub samples: usize,
    /// Time of the last sample (s).
    pub duration: f64,
    /// Starting COM height (m).
    pub z0: f64,
    /// Rise of the COM from start to end (m).
    pub rise: f64,
    /// Episode return.
    pub ret: f64,
    /// Torque usage (N m s).
    pub torque_usage: f64,
    /// Control steps.
    pub steps: u32,
}

impl StandUp {
    /// The default stand-up (see the type's docs) bulging by `bulge`.
    pub fn new(bulge: f64) -> Self {
        Self {
            bulge,
            wobble: 0.0,
            samples: 40,
            duration: 0.8,
            z0: 0.6,
            rise: 0.4,
            ret: 900.0,
            torque_usage: 100.0,
            steps: 16,
        }
    }

    /// A stand-up shaped like a real job's kept episode: 7 control steps of
    /// 10 RK4 sub-steps (70 samples over 0.35 s) rising 0.38 m, return 930,
    /// torque usage 90 N m s.
    pub fn real_sized(bulge: f64) -> Self {
        Self::new(bulge)
            .sampled(70, 0.35)
            .rising(0.6, 0.38)
            .ret(930.0)
            .torque_usage(90.0)
            .steps(7)
    }

    /// With a second harmonic of amplitude `wobble`.
    pub fn wobble(self, wobble: f64) -> Self {
        Self { wobble, ..self }
    }

    /// With `samples` samples over `duration` seconds.
    pub fn sampled(self, samples: usize, duration: f64) -> Self {
        Self {
            samples,
            duration,
            ..self
        }
    }

    /// Rising from `z0` by `rise`.
    pub fn rising(self, z0: f64, rise: f64) -> Self {
        Self { z0, rise, ..self }
    }

    /// With episode return `ret`.
    pub fn ret(self, ret: f64) -> Self {
        Self { ret, ..self }
    }

    /// With torque usage `torque_usage`.
    pub fn torque_usage(self, torque_usage: f64) -> Self {
        Self {
            torque_usage,
            ..self
        }
    }

    /// With `steps` control steps.
    pub fn steps(self, steps: u32) -> Self {
        Self { steps, ..self }
    }

    /// The path parameter `s` of each sample: `k / (samples - 1)`.
    pub fn s(&self) -> Vec<f64> {
        let last = (self.samples - 1) as f64;
        (0..self.samples).map(|k| k as f64 / last).collect()
    }

    /// Sample times (s).
    pub fn com_t(&self) -> Vec<f64> {
        self.s().iter().map(|v| v * self.duration).collect()
    }

    /// Forward COM coordinate (m).
    pub fn com_x(&self) -> Vec<f64> {
        self.s()
            .iter()
            .map(|v| {
                let x = self.bulge * (PI * v).sin();
                if self.wobble == 0.0 {
                    x
                } else {
                    x + self.wobble * (2.0 * PI * v).sin()
                }
            })
            .collect()
    }

    /// Vertical COM coordinate (m).
    pub fn com_z(&self) -> Vec<f64> {
        self.s().iter().map(|v| self.z0 + self.rise * v).collect()
    }

    /// One kept episode along this path.
    pub fn episode(&self) -> EpisodeRecord {
        EpisodeRecord {
            com_t: self.com_t(),
            com_x: self.com_x(),
            com_z: self.com_z(),
            ret: self.ret,
            torque_usage: self.torque_usage,
            steps: self.steps,
        }
    }

    /// A subject named `name` who moved along this path.
    pub fn subject(&self, name: &str) -> SubjectPath {
        SubjectPath {
            subject: name.to_string(),
            t: self.com_t(),
            x: self.com_x(),
            z: self.com_z(),
        }
    }
}

/// A grid that touches every branch of aggregation: three values of
/// `w1`, each with `trials` PPO trials and `trials` optimizer (`cem`)
/// trials of timed, skewed stand-ups, plus at each point one unconverged
/// trial with a shortfall, one converged trial whose only episode cannot
/// be resampled, and episodes with a non-finite return or torque usage.
pub fn varied_grid(trials: u32) -> Vec<WeightInput> {
    let cem = SolverTag {
        name: "cem".into(),
        kind: SolverKind::Optimizer,
    };
    let broken = EpisodeRecord {
        com_t: vec![0.0, 0.1, 0.2],
        com_x: vec![0.0, 0.1, 0.0],
        com_z: vec![0.6, 0.8, 1.0],
        ret: 2000.0,
        torque_usage: 5.0,
        steps: 1,
    };
    [(1.0, 0.08, 0.7), (4.0, 0.12, 0.8), (16.0, 0.16, 1.0)]
        .iter()
        .map(|&(w1, bulge, duration)| {
            let mut out = Vec::new();
            for t in 0..trials {
                let f = f64::from(t);
                for (v, solver) in [SolverTag::default(), cem.clone()].into_iter().enumerate() {
                    let b = bulge + 0.003 * f + 0.01 * v as f64;
                    let eps = (0..3)
                        .map(|e| {
                            let mut ep = StandUp::new(b + 0.001 * f64::from(e))
                                .wobble(0.004 * f64::from((t + e) % 3))
                                .sampled(60 + 5 * e as usize, duration * (1.0 + 0.03 * f))
                                .ret(900.0 + 7.0 * f - f64::from(e))
                                .episode();
                            if (t + e) % 5 == 4 {
                                ep.ret = f64::NAN;
                            }
                            if (t + e) % 4 == 3 {
                                ep.torque_usage = f64::INFINITY;
                            }
                            ep
                        })
                        .chain((t % 3 == 1).then(|| broken.clone()))
                        .collect();
                    out.push(TrialInput {
                        trial: t,
                        seed: 100 * t as u64 + v as u64,
                        final_success_rate: 0.95 - 0.01 * f,
                        converged: true,
                        episodes: eps,
                        successes_found: 10,
                        successes_wanted: 10,
                        solver,
                    });
                }
            }
            out.push(TrialInput {
                trial: trials,
                seed: 7,
                final_success_rate: 0.2,
                converged: false,
                episodes: vec![StandUp::new(bulge).ret(990.0).episode()],
                successes_found: 3,
                successes_wanted: 10,
                solver: SolverTag::default(),
            });
            out.push(TrialInput {
                trial: trials + 1,
                seed: 8,
                final_success_rate: f64::NAN,
                converged: true,
                episodes: vec![broken.clone()],
                successes_found: 10,
                successes_wanted: 10,
                solver: SolverTag::default(),
            });
            WeightInput {
                params: BTreeMap::from([("w1".to_string(), w1)]),
                trials: out,
            }
        })
        .collect()
}

/// Subjects for [`varied_grid`]: one between its first two values, one
/// beyond its last, and one whose path cannot be analysed.
pub fn varied_subjects() -> Vec<SubjectPath> {
    vec![
        StandUp::new(0.1)
            .wobble(0.002)
            .sampled(80, 0.75)
            .subject("between"),
        StandUp::new(0.2).sampled(50, 1.1).subject("beyond"),
        SubjectPath {
            subject: "flat".into(),
            t: vec![0.0, 0.1, 0.2, 0.3],
            x: vec![0.0; 4],
            z: vec![0.6; 4],
        },
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_path_rises_and_bulges_as_documented() {
        let e = StandUp::new(0.1).sampled(5, 2.0).rising(0.5, 0.5).episode();
        assert_eq!(e.com_t, vec![0.0, 0.5, 1.0, 1.5, 2.0]);
        assert_eq!(e.com_z, vec![0.5, 0.625, 0.75, 0.875, 1.0]);
        assert_eq!(e.com_x[0], 0.0);
        assert!((e.com_x[2] - 0.1).abs() < 1e-15, "peak {}", e.com_x[2]);
        assert!(e.com_x[4].abs() < 1e-15, "end {}", e.com_x[4]);
        assert_eq!((e.ret, e.torque_usage, e.steps), (900.0, 100.0, 16));
        // The second harmonic skews the bulge forward without moving the peak sample.
        let w = StandUp::new(0.1).sampled(5, 2.0).wobble(0.02).com_x();
        assert!(w[1] > e.com_x[1] && w[3] < e.com_x[3]);
        assert!((w[2] - e.com_x[2]).abs() < 1e-15);
    }

    #[test]
    fn a_larger_bulge_has_a_larger_area() {
        let area = |b: f64| {
            let e = StandUp::new(b).episode();
            crate::analysis::resample_path(&e.com_x, &e.com_z)
                .unwrap()
                .area
        };
        assert!(area(0.05) < area(0.10) && area(0.10) < area(0.15));
    }
}
