//! Coordinator configuration: one typed struct, filled by the CLI from flags
//! or `IRLGRID_*` environment variables; defaults in code.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

/// Default lease length in seconds.
pub const DEFAULT_LEASE_SECS: u64 = 60;
/// Default request body limit (bytes): room for a result upload of ten long
/// episodes and for a large subject CSV.
pub const DEFAULT_BODY_LIMIT: usize = 16 * 1024 * 1024;

/// How the coordinator runs.
#[derive(Debug, Clone)]
pub struct CoordinatorConfig {
    /// Listen address (`127.0.0.1:0` picks a free port).
    pub bind: SocketAddr,
    /// SQLite database file (created if missing).
    pub db: PathBuf,
    /// Lease length in seconds; heartbeats renew it.
    pub lease_secs: u64,
    /// Admin bearer token (`IRLGRID_TOKEN`): every route and the dashboard.
    pub token: Option<String>,
    /// Worker bearer token (`IRLGRID_WORKER_TOKEN`): the five worker calls
    /// only.
    pub worker_token: Option<String>,
    /// Reader bearer token (`IRLGRID_READ_TOKEN`): the `GET /api/v1` reads
    /// and the dashboard only.
    pub read_token: Option<String>,
    /// Reads and dashboard pages need no token even when tokens are set
    /// (`IRLGRID_PUBLIC_READS`): for a trusted network only.
    pub public_reads: bool,
    /// Allow a non-loopback bind without a token.
    pub insecure: bool,
    /// Request body limit in bytes.
    pub body_limit: usize,
    /// How often expired leases are swept back to the queue (besides at
    /// every lease request).
    pub sweep_interval: Duration,
}

impl CoordinatorConfig {
    /// A configuration with the defaults for this address and file.
    pub fn new(bind: SocketAddr, db: impl Into<PathBuf>) -> Self {
        Self {
            bind,
            db: db.into(),
            lease_secs: DEFAULT_LEASE_SECS,
            token: None,
            worker_token: None,
            read_token: None,
            public_reads: false,
            insecure: false,
            body_limit: DEFAULT_BODY_LIMIT,
            sweep_interval: Duration::from_secs(1),
        }
    }

    /// Whether any token is configured.
    pub fn has_token(&self) -> bool {
        self.token.is_some() || self.worker_token.is_some() || self.read_token.is_some()
    }

    /// Refuses settings that are unsafe or meaningless: a non-loopback bind
    /// without a token (unless `insecure`), an empty token, two roles
    /// sharing one token, a zero lease.
    pub fn validate(&self) -> anyhow::Result<()> {
        let tokens = [
            ("IRLGRID_TOKEN", &self.token),
            ("IRLGRID_WORKER_TOKEN", &self.worker_token),
            ("IRLGRID_READ_TOKEN", &self.read_token),
        ];
        for (i, (name, t)) in tokens.iter().enumerate() {
            let Some(t) = t else { continue };
            anyhow::ensure!(!t.trim().is_empty(), "{name} must not be empty");
            for (other, u) in &tokens[i + 1..] {
                anyhow::ensure!(
                    u.as_deref() != Some(t.as_str()),
                    "{name} and {other} must differ: a token proves one role"
                );
            }
        }
        anyhow::ensure!(
            (1..=86_400).contains(&self.lease_secs),
            "--lease-seconds must be in 1..=86400, got {}",
            self.lease_secs
        );
        if !self.bind.ip().is_loopback() && !self.has_token() && !self.insecure {
            anyhow::bail!(
                "refusing to listen on non-loopback address {} without a token: \
                 set IRLGRID_TOKEN (or pass --insecure to allow anyone on the network \
                 to submit searches and upload results)",
                self.bind
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_loopback_bind_without_token_is_refused_unless_insecure() {
        let mut c = CoordinatorConfig::new("0.0.0.0:8080".parse().unwrap(), "x.db");
        assert!(c.validate().is_err());
        c.insecure = true;
        assert!(c.validate().is_ok());
        c.insecure = false;
        c.token = Some("s3cret".into());
        assert!(c.validate().is_ok());
        c.worker_token = Some("s3cret".into());
        assert!(c.validate().is_err(), "two roles share one token");
        let local = CoordinatorConfig::new("127.0.0.1:0".parse().unwrap(), "x.db");
        assert!(local.validate().is_ok());
    }
}
