//! `irlgrid simulate`: open-loop runs of the body model from a CSV of
//! normalized actions (a fixed interface that other programs rely on).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Result;
use shared::env::{EnvConfig, Episode, Outcome, Task};

use super::InputError;

#[derive(clap::Args, Debug)]
pub struct SimulateArgs {
    /// CSV with header `a1,a2,a3`, one row of normalized actions per control step.
    #[arg(long)]
    actions: PathBuf,
    /// Initial state `q1,q2,q3,dq1,dq2,dq3` (rad, rad/s); default: the squat.
    #[arg(long, allow_hyphen_values = true)]
    initial: Option<String>,
    /// Backward-pull gain k (N s/m); default 200.
    #[arg(long, allow_negative_numbers = true)]
    perturbation_gain: Option<f64>,
    /// Run every action row even past a terminal state.
    #[arg(long)]
    no_termination: bool,
    /// Torque weight used for the episode return printed on stderr.
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    w1: f64,
}

pub fn run(args: SimulateArgs) -> Result<()> {
    let actions = read_actions(&args.actions)?;
    let mut cfg = EnvConfig::with_w1(args.w1);
    if let Some(k) = args.perturbation_gain {
        cfg.sim.perturbation_gain = k;
    }
    let task = Task::new(&cfg).map_err(|e| InputError(e.to_string()))?;
    let state = match &args.initial {
        Some(text) => parse_initial(text)?,
        None => {
            let s = &cfg.sim;
            [s.q0[0], s.q0[1], s.q0[2], s.qd0[0], s.qd0[1], s.qd0[2]]
        }
    };
    let (csv, end) = simulate(&task, state, &actions, !args.no_termination);
    print!("{csv}");
    if let Some((outcome, ret, steps)) = end {
        eprintln!(
            "outcome: {} after {steps} steps, return {ret} (w1 = {})",
            outcome.as_str(),
            args.w1
        );
    }
    Ok(())
}

/// Runs the actions from `state`; returns the CSV and, when stopping at a
/// terminal state, the outcome, episode return and step count.
fn simulate(
    task: &Task,
    state: shared::sim::State,
    actions: &[[f64; 3]],
    terminate: bool,
) -> (String, Option<(Outcome, f64, u32)>) {
    let model = task.model();
    let dt = task.config().sim.control_dt();
    let mut out = String::from("t,q1,q2,q3,dq1,dq2,dq3,x_com,z_com\n");
    let mut row = |t: u32, s: &shared::sim::State| {
        let c = model.com(s);
        // `{}` prints the shortest representation that round-trips an f64.
        let _ = write!(out, "{}", f64::from(t) * dt);
        for v in s.iter().chain([c.x, c.z].iter()) {
            let _ = write!(out, ",{v}");
        }
        out.push('\n');
    };
    let mut ep = Episode::new(state);
    row(0, &ep.state);
    let mut end = None;
    for a in actions {
        let info = task.step(&mut ep, a, |_| {});
        row(ep.t, &ep.state);
        if terminate && info.outcome.is_done() {
            end = Some((info.outcome, info.episode_return, ep.t));
            break;
        }
    }
    if terminate && end.is_none() {
        // Fewer action rows than the time limit: report where the run stands.
        end = Some((Outcome::Running, ep.ret, ep.t));
    }
    (out, end)
}

fn parse_initial(text: &str) -> Result<shared::sim::State> {
    let values: Vec<&str> = text.split(',').collect();
    if values.len() != 6 {
        return Err(InputError(format!(
            "--initial: expected 6 comma-separated values q1,q2,q3,dq1,dq2,dq3, got {}",
            values.len()
        ))
        .into());
    }
    let mut s = [0.0; 6];
    for (slot, v) in s.iter_mut().zip(values) {
        *slot = parse_finite(v)
            .ok_or_else(|| InputError(format!("--initial: {v:?} is not a finite number")))?;
    }
    Ok(s)
}

fn parse_finite(v: &str) -> Option<f64> {
    v.trim().parse::<f64>().ok().filter(|x| x.is_finite())
}

/// Reads an actions CSV, naming the file and line of the first problem.
fn read_actions(path: &Path) -> Result<Vec<[f64; 3]>> {
    let name = path.display();
    let text = std::fs::read_to_string(path)
        .map_err(|e| InputError(format!("{name}: cannot read: {e}")))?;
    let mut lines = text.lines().enumerate();
    let header = lines.next().map(|(_, l)| l.trim()).unwrap_or("");
    if header != "a1,a2,a3" {
        return Err(InputError(format!(
            "{name}:1: expected the header `a1,a2,a3`, found `{header}`"
        ))
        .into());
    }
    let mut rows = Vec::new();
    for (i, line) in lines {
        let line_no = i + 1;
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let cells: Vec<&str> = line.split(',').collect();
        if cells.len() != 3 {
            return Err(InputError(format!(
                "{name}:{line_no}: expected 3 columns, found {}",
                cells.len()
            ))
            .into());
        }
        let mut a = [0.0; 3];
        for (k, cell) in cells.iter().enumerate() {
            a[k] = parse_finite(cell).ok_or_else(|| {
                InputError(format!(
                    "{name}:{line_no}: column a{} is not a finite number: {:?}",
                    k + 1,
                    cell.trim()
                ))
            })?;
        }
        rows.push(a);
    }
    Ok(rows)
}
