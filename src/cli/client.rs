//! `irlgrid submit`, `irlgrid status`, `irlgrid results`, `irlgrid score`:
//! small clients of the coordinator's REST API.

use std::io::Read;
use std::path::PathBuf;

use anyhow::Context;
use shared::api::{Created, ErrorBody, SearchStatus};

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
    #[command(flatten)]
    pub remote: Remote,
}

impl Remote {
    fn url(&self, path: &str) -> String {
        format!("{}{path}", self.coordinator.trim_end_matches('/'))
    }

    async fn send(&self, req: reqwest::RequestBuilder) -> anyhow::Result<reqwest::Response> {
        let token = super::resolve_token(self.token.as_deref(), self.token_file.as_deref())?;
        let req = match token {
            Some(t) => req.bearer_auth(t),
            None => req,
        };
        let resp = req
            .send()
            .await
            .with_context(|| format!("cannot reach the coordinator at {}", self.coordinator))?;
        let status = resp.status();
        if status.is_success() {
            return Ok(resp);
        }
        let text = resp.text().await.unwrap_or_default();
        let msg = serde_json::from_str::<ErrorBody>(&text)
            .map(|e| e.error)
            .unwrap_or(text);
        if status.is_client_error() {
            Err(InputError(format!("coordinator refused ({status}): {msg}")).into())
        } else {
            anyhow::bail!("coordinator error ({status}): {msg}")
        }
    }
}

/// Submits a request body; returns the answer.
pub async fn submit_body(remote: &Remote, body: &serde_json::Value) -> anyhow::Result<Created> {
    let client = reqwest::Client::new();
    let resp = remote
        .send(client.post(remote.url("/api/v1/searches")).json(body))
        .await?;
    resp.json()
        .await
        .context("reading the coordinator's answer")
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
    let body: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| InputError(format!("{} is not valid JSON: {e}", args.file.display())))?;
    let created = runtime()?.block_on(submit_body(&args.remote, &body))?;
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
    runtime()?.block_on(async {
        let client = reqwest::Client::new();
        let path = match &args.id {
            Some(id) => format!("/api/v1/searches/{id}"),
            None => "/api/v1/searches".to_string(),
        };
        let v: serde_json::Value = args
            .remote
            .send(client.get(args.remote.url(&path)))
            .await?
            .json()
            .await
            .context("reading status")?;
        if args.json {
            println!("{}", serde_json::to_string_pretty(&v)?);
        } else if args.id.is_some() {
            println!("{}", describe(&serde_json::from_value(v)?));
        } else {
            for s in serde_json::from_value::<Vec<SearchStatus>>(v)? {
                println!("{}", describe(&s));
            }
        }
        Ok(())
    })
}

/// Scores a subject CSV against a finished search without running a job.
pub fn score(args: ScoreArgs) -> anyhow::Result<()> {
    let csv = read_input(&args.subjects)?;
    runtime()?.block_on(async {
        let client = reqwest::Client::new();
        let path = format!(
            "/api/v1/searches/{}/subjects{}",
            args.id,
            if args.save { "?save=true" } else { "" }
        );
        let req = client
            .post(args.remote.url(&path))
            .header(reqwest::header::CONTENT_TYPE, "text/csv")
            .body(csv);
        let text = args
            .remote
            .send(req)
            .await?
            .text()
            .await
            .context("reading the coordinator's answer")?;
        let v: serde_json::Value = serde_json::from_str(&text)?;
        if args.json {
            println!("{}", serde_json::to_string_pretty(&v)?);
            return Ok(());
        }
        let doc = shared::analysis::ResultDocument {
            analysis_version: shared::analysis::ANALYSIS_VERSION,
            weights: Vec::new(),
            subjects: serde_json::from_value(v["subjects"].clone())
                .context("reading the scored subjects")?,
            identifiability: None,
            notes: serde_json::from_value(v["notes"].clone()).unwrap_or_default(),
        };
        print!("{}", super::run::subject_table(&doc));
        if args.save {
            eprintln!("saved: the search's document and dashboard now show these subjects");
        }
        Ok(())
    })
}

pub fn results(args: ResultsArgs) -> anyhow::Result<()> {
    runtime()?.block_on(async {
        let client = reqwest::Client::new();
        let path = if args.csv {
            format!("/api/v1/searches/{}/results.csv", args.id)
        } else {
            format!("/api/v1/searches/{}/results", args.id)
        };
        let resp = args.remote.send(client.get(args.remote.url(&path))).await?;
        let text = resp.text().await.context("reading results")?;
        if args.csv {
            print!("{text}");
        } else {
            let v: serde_json::Value = serde_json::from_str(&text)?;
            println!("{}", serde_json::to_string_pretty(&v)?);
        }
        Ok(())
    })
}
