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
    /// Bearer token required on every `/api/v1` write and worker call.
    pub token: Option<String>,
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
            insecure: false,
            body_limit: DEFAULT_BODY_LIMIT,
            sweep_interval: Duration::from_secs(1),
        }
    }

    /// Refuses settings that are unsafe or meaningless: a non-loopback bind
    /// without a token (unless `insecure`), an empty token, a zero lease.
    pub fn validate(&self) -> anyhow::Result<()> {
        if let Some(t) = &self.token {
            anyhow::ensure!(!t.trim().is_empty(), "the token must not be empty");
        }
        anyhow::ensure!(
            (1..=86_400).contains(&self.lease_secs),
            "--lease-seconds must be in 1..=86400, got {}",
            self.lease_secs
        );
        if !self.bind.ip().is_loopback() && self.token.is_none() && !self.insecure {
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
        let local = CoordinatorConfig::new("127.0.0.1:0".parse().unwrap(), "x.db");
        assert!(local.validate().is_ok());
    }
}
