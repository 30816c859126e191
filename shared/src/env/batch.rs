//! N independent environments stepped together over contiguous buffers, for
//! the trainer and the sampler. Each environment has its own seeded RNG for
//! the initial-state noise and resets itself when its episode ends.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::task::{Episode, Outcome, StepInfo, Task};
use super::{EnvConfig, EnvError};
use crate::sim::{Block, BlockStepper, F64s, LANES};

/// A centre-of-mass path sampled at every RK4 sub-step (docs/science.md#sampling), including
/// the initial state.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ComPath {
    /// Time since the episode start (s).
    pub t: Vec<f64>,
    /// COM x (m, forward).
    pub x: Vec<f64>,
    /// COM z (m, up).
    pub z: Vec<f64>,
}

impl ComPath {
    fn clear(&mut self) {
        self.t.clear();
        self.x.clear();
        self.z.clear();
    }

    fn push(&mut self, t: f64, x: f64, z: f64) {
        self.t.push(t);
        self.x.push(x);
        self.z.push(z);
    }
}

/// A batch of environments with row-major observation buffers.
#[derive(Debug)]
pub struct BatchEnv {
    task: Task,
    stepper: BlockStepper,
    obs_dim: usize,
    episodes: Vec<Episode>,
    rngs: Vec<ChaCha8Rng>,
    obs: Vec<f64>,
    final_obs: Vec<f64>,
    infos: Vec<StepInfo>,
    /// COM recording (off unless asked for: the trainer does not need it).
    record_com: bool,
    paths: Vec<ComPath>,
    finished_paths: Vec<ComPath>,
    /// COM (x, z) of a block after each sub-step, while recording.
    com_buf: Vec<[F64s; 2]>,
}

impl BatchEnv {
    /// Number of action components.
    pub const ACT_DIM: usize = 3;

    /// `n` environments; environment i draws its initial noise from a ChaCha8
    /// stream i of `seed`, so a batch is reproducible and its members independent.
    pub fn new(cfg: &EnvConfig, n: usize, seed: u64) -> Result<Self, EnvError> {
        if n == 0 {
            return Err(EnvError::InvalidConfig(
                "a batch needs at least one environment".into(),
            ));
        }
        let task = Task::new(cfg)?;
        let obs_dim = cfg.obs_dim();
        let mut rngs: Vec<ChaCha8Rng> = (0..n)
            .map(|i| {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                rng.set_stream(i as u64);
                rng
            })
            .collect();
        let episodes = rngs
            .iter_mut()
            .map(|rng| Episode::new(task.initial_state(rng)))
            .collect();
        let blank = StepInfo {
            reward: 0.0,
            outcome: Outcome::Running,
            episode_return: 0.0,
            episode_len: 0,
            episode_torque_usage: 0.0,
        };
        let substeps = task.config().sim.substeps as usize;
        let mut env = Self {
            stepper: task.model().block_stepper(),
            com_buf: vec![[F64s::splat(0.0); 2]; substeps],
            task,
            obs_dim,
            episodes,
            rngs,
            obs: vec![0.0; n * obs_dim],
            final_obs: vec![0.0; n * obs_dim],
            infos: vec![blank; n],
            record_com: false,
            paths: vec![ComPath::default(); n],
            finished_paths: vec![ComPath::default(); n],
        };
        for i in 0..n {
            env.write_obs(i);
        }
        Ok(env)
    }

    /// Number of environments.
    pub fn len(&self) -> usize {
        self.episodes.len()
    }

    /// Always false: a batch has at least one environment.
    pub fn is_empty(&self) -> bool {
        self.episodes.is_empty()
    }

    /// Observation length per environment.
    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }

    /// The shared task.
    pub fn task(&self) -> &Task {
        &self.task
    }

    /// Current observations, `len() * obs_dim()` row-major (after auto-reset).
    pub fn observations(&self) -> &[f64] {
        &self.obs
    }

    /// Turns recording of the COM path at every RK4 sub-step on or off. The
    /// current episodes' paths start at their present state.
    pub fn set_record_com(&mut self, on: bool) {
        self.record_com = on;
        for i in 0..self.len() {
            self.paths[i].clear();
            if on {
                self.record_start(i);
            }
        }
    }

    /// The COM path of environment `i`'s episode that ended in the last
    /// `step` (valid when its outcome was not `Running` and recording is on).
    pub fn finished_path(&self, i: usize) -> &ComPath {
        &self.finished_paths[i]
    }

    /// The observation in which environment `i`'s episode ended in the last
    /// `step` (for bootstrapping a truncated episode's value).
    pub fn final_observation(&self, i: usize) -> &[f64] {
        &self.final_obs[i * self.obs_dim..(i + 1) * self.obs_dim]
    }

    /// Steps every environment with its row of `actions` (`len() * 3`
    /// normalized actions, clipped inside); finished episodes are reset.
    ///
    /// The dynamics run in blocks of eight environments in vector registers
    /// (`sim::BlockStepper`); a last, partial block is padded with copies of
    /// its final environment, whose results are dropped. The episode logic
    /// (scoring, resets, COM paths) stays per environment.
    pub fn step(&mut self, actions: &[f64]) -> Result<&[StepInfo], EnvError> {
        let n = self.len();
        if actions.len() != n * Self::ACT_DIM {
            return Err(EnvError::ActionShape {
                expected: n * Self::ACT_DIM,
                got: actions.len(),
            });
        }
        for first in (0..n).step_by(LANES) {
            let real = (n - first).min(LANES);
            let zero = F64s::splat(0.0);
            let mut block = Block {
                q: [zero; 3],
                qd: [zero; 3],
            };
            let (mut tau, mut a) = ([zero; 3], [zero; 3]);
            let mut held = [([0.0; 3], [0.0; 3]); LANES];
            for (lane, held) in held.iter_mut().enumerate() {
                let i = first + lane.min(real - 1);
                *held = self
                    .task
                    .model()
                    .torque(&actions[i * Self::ACT_DIM..(i + 1) * Self::ACT_DIM]);
                let s = &self.episodes[i].state;
                for j in 0..3 {
                    block.q[j].0[lane] = s[j];
                    block.qd[j].0[lane] = s[3 + j];
                    tau[j].0[lane] = held.0[j];
                    a[j].0[lane] = held.1[j];
                }
            }
            let com = self.record_com.then_some(&mut self.com_buf[..]);
            let out = self.stepper.control_step(&mut block, &tau, &a, com);
            for (lane, &(tau, a)) in held.iter().enumerate().take(real) {
                let i = first + lane;
                let ep = &mut self.episodes[i];
                for j in 0..3 {
                    ep.state[j] = block.q[j].0[lane];
                    ep.state[3 + j] = block.qd[j].0[lane];
                }
                if self.record_com {
                    let dt = self.task.config().sim.dt_s;
                    let substeps = self.task.config().sim.substeps;
                    let k0 = ep.t * substeps;
                    for (k, xz) in (1..).zip(&self.com_buf) {
                        self.paths[i].push(f64::from(k0 + k) * dt, xz[0].0[lane], xz[1].0[lane]);
                    }
                }
                let effort = self.task.effort(a, out.power_sum.0[lane]);
                let info = self.task.finish_step(ep, tau, effort);
                self.infos[i] = info;
                if info.outcome.is_done() {
                    self.reset(i);
                }
                self.write_obs(i);
            }
        }
        Ok(&self.infos)
    }

    /// Keeps environment `i`'s final observation (and COM path) and starts
    /// its next episode.
    fn reset(&mut self, i: usize) {
        let d = self.obs_dim;
        self.task
            .observe(&self.episodes[i], &mut self.final_obs[i * d..(i + 1) * d]);
        self.episodes[i] = Episode::new(self.task.initial_state(&mut self.rngs[i]));
        if self.record_com {
            std::mem::swap(&mut self.paths[i], &mut self.finished_paths[i]);
            self.paths[i].clear();
            self.record_start(i);
        }
    }

    fn write_obs(&mut self, i: usize) {
        let d = self.obs_dim;
        self.task
            .observe(&self.episodes[i], &mut self.obs[i * d..(i + 1) * d]);
    }

    fn record_start(&mut self, i: usize) {
        let c = self.task.model().com(&self.episodes[i].state);
        self.paths[i].push(0.0, c.x, c.z);
    }
}
