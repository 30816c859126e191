//! `irlgrid submit`, `irlgrid status`, `irlgrid results`, `irlgrid score`,
//! `irlgrid extend`:
//! small clients of the coordinator's REST API.

use std::io::Read;
use std::path::PathBuf;

use anyhow::Context;
use irlgrid_client::{Body, CallError, Client};
use shared::api::routes::Endpoint;
use shared::api::{ExtendRequest, RefineRequest, Refinement, SearchStatus};

use super::coordinator::runtime;
use super::InputError;

#[derive(clap::Args, Debug, Clone)]
pub struct Remote {
    /// Coordinator base URL.
    #[arg(
        long,
        env = "IRLGRID_COORDINATOR",
        default_value = "http://127.0.0.1:8080"
    )]
    pub coordinator: String,
    /// Bearer token of the coordinator, sent on every request: the admin
    /// token to submit or score, the admin or reader token to read.
    #[arg(long, env = "IRLGRID_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// File holding the bearer token (instead of --token).
    #[arg(long, env = "IRLGRID_TOKEN_FILE")]
    pub token_file: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
pub struct SubmitArgs {
    /// Search request JSON (`-` reads standard input).
    pub file: PathBuf,
    #[command(flatten)]
    pub remote: Remote,
}

#[derive(clap::Args, Debug)]
pub struct StatusArgs {
    /// Search id (omit to list all searches).
    pub id: Option<String>,
    /// Print the raw JSON.
    #[arg(long, env = "IRLGRID_JSON")]
    pub json: bool,
    #[command(flatten)]
    pub remote: Remote,
}

#[derive(clap::Args, Debug)]
pub struct ResultsArgs {
    /// Search id.
    pub id: String,
    /// The tidy CSV instead of the JSON document.
    #[arg(long, env = "IRLGRID_CSV")]
    pub csv: bool,
    #[command(flatten)]
    pub remote: Remote,
}

#[derive(clap::Args, Debug)]
pub struct ScoreArgs {
    /// Search id.
    pub id: String,
    /// Subject CSV (header subject,time,x,z; `-` reads standard input).
    pub subjects: PathBuf,
    /// Also add the subjects to the search, so that its document and
    /// dashboard show them.
    #[arg(long)]
    pub save: bool,
    /// Print the raw JSON answer instead of the table.
    #[arg(long, env = "IRLGRID_JSON")]
    pub json: bool,
    /// Score with this observable set instead of the search's own
    /// (docs/inference.md#observables).
    #[arg(long, value_parser = super::posterior_args::parse_observables)]
    pub observables: Option<shared::analysis::Observables>,
    #[command(flatten)]
    pub remote: Remote,
}

#[derive(clap::Args, Debug)]
pub struct ExtendArgs {
    /// Search id.
    pub id: String,
    /// New number of converged trials wanted per point (at least the
    /// current one).
    #[arg(long)]
    pub trials: Option<u32>,
    /// Grid values to add, `NAME=V1,V2,...` (e.g. `w1=5.66,11.3`);
    /// repeat for several parameters.
    #[arg(long = "add", value_name = "NAME=VALUES")]
    pub add: Vec<String>,
    /// Print the raw JSON answer.
    #[arg(long, env = "IRLGRID_JSON")]
    pub json: bool,
    #[command(flatten)]
    pub remote: Remote,
}

/// The body of `irlgrid extend`'s request from its flags.
pub fn extend_request(trials: Option<u32>, add: &[String]) -> Result<ExtendRequest, InputError> {
    let mut req = ExtendRequest {
        trials,
        ..ExtendRequest::default()
    };
    for a in add {
        let (name, values) = a
            .split_once('=')
            .ok_or_else(|| InputError(format!("--add {a}: expected NAME=V1,V2,...")))?;
        let name = name.trim();
        if name.is_empty() {
            return Err(InputError(format!(
                "--add {a}: the parameter name is empty"
            )));
        }
        let list = req.reward_grid.entry(name.to_string()).or_default();
        for v in values.split(',') {
            let x: f64 = v
                .trim()
                .parse()
                .map_err(|_| InputError(format!("--add {a}: {v:?} is not a number")))?;
            list.push(x);
        }
    }
    if req.trials.is_none() && req.reward_grid.is_empty() {
        return Err(InputError(
            "extend needs --trials N and/or --add NAME=VALUES".into(),
        ));
    }
    Ok(req)
}

/// Extends a search (`irlgrid extend`).
pub fn extend(args: ExtendArgs) -> anyhow::Result<()> {
    let body = extend_request(args.trials, &args.add)?;
    let client = args.remote.client()?;
    runtime()?.block_on(async {
        if args.json {
            let text = client
                .call(Endpoint::Extend, Some(&args.id), &[], Body::json(&body))
                .await;
            return print_pretty(text.map_err(refused)?);
        }
        let e = client.extend(&args.id, &body).await.map_err(refused)?;
        println!(
            "{}  {}  extension {}: {} jobs queued, {} points added; now {} points x {} trials",
            e.id,
            e.status.as_str(),
            e.extension,
            e.jobs_added,
            e.points_added,
            e.points,
            e.trials
        );
        Ok(())
    })
}

#[derive(clap::Args, Debug)]
pub struct RefineArgs {
    /// Search id.
    pub id: String,
    /// Most rounds of added midpoints.
    #[arg(long)]
    pub rounds: Option<u32>,
    /// Trials per added point (default: the search's trials per point).
    #[arg(long)]
    pub trials: Option<u32>,
    /// Stop once each subject's two neighbouring candidates are within this
    /// ratio.
    #[arg(long)]
    pub target_ratio: Option<f64>,
    /// Posterior mass a subject's two candidates must hold for it to ask
    /// for their midpoint.
    #[arg(long)]
    pub min_pair_mass: Option<f64>,
    /// Only show the refinement so far (`GET .../refinement`); ask for none.
    #[arg(long)]
    pub show: bool,
    /// Print the raw JSON answer.
    #[arg(long, env = "IRLGRID_JSON")]
    pub json: bool,
    #[command(flatten)]
    pub remote: Remote,
}

/// Refines a search toward its subjects (`irlgrid refine`), or shows its
/// refinement (`--show`).
pub fn refine(args: RefineArgs) -> anyhow::Result<()> {
    let body = RefineRequest {
        rounds: args.rounds,
        trials: args.trials,
        target_ratio: args.target_ratio,
        min_pair_mass: args.min_pair_mass,
    };
    let client = args.remote.client()?;
    runtime()?.block_on(async {
        let (endpoint, req) = if args.show {
            (Endpoint::Refinement, Body::Empty)
        } else {
            (Endpoint::Refine, Body::json(&body))
        };
        let text = client
            .call(endpoint, Some(&args.id), &[], req)
            .await
            .map_err(refused)?;
        if args.json {
            return print_pretty(text);
        }
        let r: Refinement =
            serde_json::from_str(&text.unwrap_or_default()).context("reading the refinement")?;
        print!("{}", refinement_text(&r));
        Ok(())
    })
}

/// The refinement as lines of text: what was asked for, then per round
/// each subject's estimate, bracketing pair and the point it asked for.
pub fn refinement_text(r: &Refinement) -> String {
    let mut out = String::new();
    let Some(spec) = &r.spec else {
        return format!("{}  {}  no refinement asked for\n", r.id, r.status.as_str());
    };
    out.push_str(&format!(
        "{}  {}  refinement {}: up to {} rounds, {} trials per added point, target ratio {}\n",
        r.id,
        r.status.as_str(),
        r.state,
        spec.rounds,
        spec.trials,
        spec.target_ratio
    ));
    if r.rounds.is_empty() {
        out.push_str("  the first round is decided when the grid has finished\n");
    }
    for round in &r.rounds {
        out.push_str(&format!("  round {}:\n", round.round));
        for s in &round.subjects {
            let fmt = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v}"));
            out.push_str(&format!(
                "    {}: {} {} in [{}, {}]{}\n",
                s.subject,
                s.method.map_or("-", |m| m.key()),
                fmt(s.estimate),
                fmt(s.lo),
                fmt(s.hi),
                s.midpoint
                    .map(|m| format!(", asks for {}={m}", spec.param))
                    .unwrap_or_else(|| s
                        .reason
                        .as_ref()
                        .map(|r| format!(" ({r})"))
                        .unwrap_or_default())
            ));
        }
        if !round.added.is_empty() {
            let added: Vec<String> = round.added.iter().map(|v| v.to_string()).collect();
            out.push_str(&format!("    added {}={}\n", spec.param, added.join(",")));
        }
        if let Some(stop) = &round.stop {
            out.push_str(&format!("    settled: {stop}\n"));
        }
    }
    out
}

impl Remote {
    /// The typed client of this coordinator, with the token resolved
    /// (`--token` or `--token-file`): the one HTTP client of a command.
    pub fn client(&self) -> anyhow::Result<Client> {
        let token = super::resolve_token(self.token.as_deref(), self.token_file.as_deref())?;
        Client::new(&self.coordinator, token).context("building the HTTP client")
    }
}

/// A failed call as the CLI reports it: a refusal (4xx) is the user's
/// input error (exit status 2), anything else the coordinator's.
pub fn refused(e: CallError) -> anyhow::Error {
    match e.refusal_status() {
        Some(status) => {
            let status = reqwest::StatusCode::from_u16(status)
                .map_or_else(|_| status.to_string(), |s| s.to_string());
            InputError(format!("coordinator refused ({status}): {}", e.message())).into()
        }
        None => anyhow::anyhow!("{e}"),
    }
}

/// Prints an answer's JSON pretty.
fn print_pretty(text: Option<String>) -> anyhow::Result<()> {
    let v: serde_json::Value = serde_json::from_str(&text.unwrap_or_default())
        .context("reading the coordinator's answer")?;
    println!("{}", serde_json::to_string_pretty(&v)?);
    Ok(())
}

/// The text of an input file, or of standard input for `-`.
fn read_input(path: &std::path::Path) -> anyhow::Result<String> {
    if path.as_os_str() == "-" {
        let mut s = String::new();
        std::io::stdin()
            .read_to_string(&mut s)
            .context("reading standard input")?;
        return Ok(s);
    }
    Ok(std::fs::read_to_string(path)
        .map_err(|e| InputError(format!("cannot read {}: {e}", path.display())))?)
}

pub fn submit(args: SubmitArgs) -> anyhow::Result<()> {
    let text = read_input(&args.file)?;
    // Sent as written: the coordinator checks it and names the offending
    // field, as it does for any client.
    let body: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| InputError(format!("{} is not valid JSON: {e}", args.file.display())))?;
    let client = args.remote.client()?;
    let created = runtime()?.block_on(client.submit(&body)).map_err(refused)?;
    println!("{}", created.id);
    eprintln!("{} jobs queued", created.jobs);
    Ok(())
}

fn describe(s: &SearchStatus) -> String {
    let j = &s.jobs;
    let eta = s
        .eta_secs
        .filter(|_| s.status == shared::api::SearchState::Running)
        .map(|e| format!(", eta {:.0}s", e))
        .unwrap_or_default();
    format!(
        "{}  {:<9}  {}  jobs {}/{} done, {} leased, {} queued, {} failed, {} cancelled; \
         trials converged {} / not converged {} (shortfall {}); {} workers busy{eta}",
        s.id,
        s.status.as_str(),
        s.name,
        j.done,
        j.total,
        j.leased,
        j.queued,
        j.failed,
        j.cancelled,
        s.trials_converged,
        s.trials_not_converged,
        s.trials_with_shortfall,
        s.workers_busy
    )
}

pub fn status(args: StatusArgs) -> anyhow::Result<()> {
    let client = args.remote.client()?;
    runtime()?.block_on(async {
        let endpoint = match &args.id {
            Some(_) => Endpoint::SearchStatus,
            None => Endpoint::ListSearches,
        };
        if args.json {
            let text = client.call(endpoint, args.id.as_deref(), &[], Body::Empty);
            return print_pretty(text.await.map_err(refused)?);
        }
        match &args.id {
            Some(id) => println!("{}", describe(&client.search(id).await.map_err(refused)?)),
            None => {
                for s in client.searches().await.map_err(refused)? {
                    println!("{}", describe(&s));
                }
            }
        }
        Ok(())
    })
}

/// Scores a subject CSV against a finished search without running a job.
pub fn score(args: ScoreArgs) -> anyhow::Result<()> {
    let csv = read_input(&args.subjects)?;
    let client = args.remote.client()?;
    runtime()?.block_on(async {
        let query = shared::api::ScoreQuery {
            save: args.save,
            observables: args.observables.map(|o| o.key().to_string()),
        };
        if args.json {
            let text = client.score_subjects_text(&args.id, csv, &query).await;
            return print_pretty(Some(text.map_err(refused)?));
        }
        let scored = client
            .score_subjects(&args.id, csv, &query)
            .await
            .map_err(refused)?;
        let doc = shared::analysis::ResultDocument {
            analysis_version: shared::analysis::ANALYSIS_VERSION,
            weights: Vec::new(),
            subjects: scored.subjects,
            identifiability: None,
            notes: scored.notes,
        };
        print!("{}", super::tables::subject_table(&doc));
        if args.save {
            eprintln!("saved: the search's document and dashboard now show these subjects");
        }
        Ok(())
    })
}

/// Prints a search's result document (raw JSON, pretty) or its tidy CSV.
pub fn results(args: ResultsArgs) -> anyhow::Result<()> {
    let client = args.remote.client()?;
    runtime()?.block_on(async {
        let endpoint = if args.csv {
            Endpoint::ResultsCsv
        } else {
            Endpoint::Results
        };
        let text = client
            .call(endpoint, Some(&args.id), &[], Body::Empty)
            .await
            .map_err(refused)?;
        if args.csv {
            print!("{}", text.unwrap_or_default());
            Ok(())
        } else {
            // Printed as served (not re-encoded from the typed view), so
            // that every number is the coordinator's own text.
            print_pretty(text)
        }
    })
}

#[cfg(test)]
mod tests {

    use super::*;

    #[test]
    fn extend_flags_become_the_request_body() {
        let r = extend_request(Some(20), &["w1=5.66, 11.3".into(), "w1=0.3".into()]).unwrap();
        assert_eq!(r.trials, Some(20));
        assert_eq!(r.reward_grid["w1"], vec![5.66, 11.3, 0.3]);
        assert!(extend_request(None, &[]).is_err());
        assert!(extend_request(None, &["w1".into()]).is_err());
        assert!(extend_request(None, &["w1=x".into()]).is_err());
        assert!(extend_request(None, &["=1".into()]).is_err());
        let j = serde_json::to_value(extend_request(Some(3), &[]).unwrap()).unwrap();
        assert_eq!(j, serde_json::json!({"trials": 3}));
    }
}
