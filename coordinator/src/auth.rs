//! Who may call what: the three token roles, each route's needed role
//! looked up in the route table (`shared::api::routes`), and the one
//! constant-time token compare.
//!
//! With no token configured everything is open (a loopback coordinator).
//! With any token configured every `/api/v1` route except the OpenAPI
//! document needs a token whose role covers it; a missing or unknown token
//! is 401, a known token of the wrong role 403. `public_reads` opens reads
//! (and the dashboard) again, for a trusted network only.

use subtle::ConstantTimeEq;

use crate::config::CoordinatorConfig;

pub use shared::api::routes::{Access, ROUTES};

/// What a route needs, by method and path template (`HEAD` as `GET`),
/// from the route table ([`ROUTES`]).
pub fn access_of(method: &str, path: &str) -> Option<Access> {
    shared::api::routes::lookup(method, path).map(|r| r.access)
}

/// The role a presented token proves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// `IRLGRID_TOKEN`: everything.
    Admin,
    /// `IRLGRID_WORKER_TOKEN`: the worker calls.
    Worker,
    /// `IRLGRID_READ_TOKEN`: reads and the dashboard.
    Reader,
}

impl Role {
    /// Whether this role may call a route needing `access`.
    pub fn may(self, access: Access) -> bool {
        matches!(
            (self, access),
            (_, Access::Open)
                | (Role::Admin, _)
                | (Role::Worker, Access::Worker)
                | (Role::Reader, Access::Read)
        )
    }
}

/// Whether two secrets are equal, in time independent of where they first
/// differ (`subtle`), so that response times do not leak how much of a
/// guessed token is right. The one compare of bearer, dashboard and lease
/// tokens.
pub fn ct_eq(a: &str, b: &str) -> bool {
    bool::from(a.as_bytes().ct_eq(b.as_bytes()))
}

/// The configured tokens of one coordinator.
#[derive(Clone, Copy)]
pub struct Tokens<'a> {
    admin: Option<&'a str>,
    worker: Option<&'a str>,
    reader: Option<&'a str>,
    public_reads: bool,
}

impl<'a> Tokens<'a> {
    /// The tokens of a configuration.
    pub fn of(cfg: &'a CoordinatorConfig) -> Self {
        Self {
            admin: cfg.token.as_deref(),
            worker: cfg.worker_token.as_deref(),
            reader: cfg.read_token.as_deref(),
            public_reads: cfg.public_reads,
        }
    }

    /// Whether any token is configured (else everything is open).
    pub fn any(&self) -> bool {
        self.admin.is_some() || self.worker.is_some() || self.reader.is_some()
    }

    /// The role `given` proves, if any. Every configured token is compared
    /// (no early exit), so timing does not tell which role was close.
    pub fn role_of(&self, given: &str) -> Option<Role> {
        let mut found = None;
        for (tok, role) in [
            (self.admin, Role::Admin),
            (self.worker, Role::Worker),
            (self.reader, Role::Reader),
        ] {
            if let Some(t) = tok {
                if ct_eq(given, t) && found.is_none() {
                    found = Some(role);
                }
            }
        }
        found
    }

    /// The tokens that open the dashboard: admin and reader.
    pub fn dashboard_tokens(&self) -> Vec<&'a str> {
        [self.admin, self.reader].into_iter().flatten().collect()
    }

    /// Whether reads (API and dashboard) need no token here.
    pub fn reads_open(&self) -> bool {
        self.public_reads || !self.any()
    }

    /// Whether a request to a route needing `access` with bearer token
    /// `given` (if any) may proceed: `Ok`, or the refusal's status (401 no
    /// or unknown token, 403 a known token of another role).
    pub fn check(&self, access: Access, given: Option<&str>) -> Result<(), Refusal> {
        if access == Access::Open || !self.any() {
            return Ok(());
        }
        if access == Access::Read && self.public_reads {
            return Ok(());
        }
        match given.and_then(|g| self.role_of(g)) {
            None => Err(Refusal::Unauthorized),
            Some(role) if role.may(access) => Ok(()),
            Some(_) => Err(Refusal::Forbidden),
        }
    }
}

/// Why a request was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// No token, or not one of the configured tokens (401).
    Unauthorized,
    /// A configured token whose role does not cover the route (403).
    Forbidden,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> CoordinatorConfig {
        let mut c = CoordinatorConfig::new("127.0.0.1:0".parse().unwrap(), "x.db");
        c.token = Some("adm".into());
        c.worker_token = Some("wrk".into());
        c.read_token = Some("rd".into());
        c
    }

    #[test]
    fn each_role_reaches_only_its_routes() {
        let c = cfg();
        let t = Tokens::of(&c);
        use Refusal::*;
        assert_eq!(t.check(Access::Read, Some("rd")), Ok(()));
        assert_eq!(t.check(Access::Read, Some("wrk")), Err(Forbidden));
        assert_eq!(t.check(Access::Worker, Some("rd")), Err(Forbidden));
        assert_eq!(t.check(Access::Admin, Some("wrk")), Err(Forbidden));
        assert_eq!(t.check(Access::Admin, Some("adm")), Ok(()));
        assert_eq!(t.check(Access::Worker, Some("adm")), Ok(()));
        assert_eq!(t.check(Access::Read, None), Err(Unauthorized));
        assert_eq!(t.check(Access::Read, Some("nope")), Err(Unauthorized));
        assert_eq!(t.check(Access::Open, None), Ok(()));
    }

    #[test]
    fn public_reads_open_reads_only_and_no_token_opens_all() {
        let mut c = cfg();
        c.public_reads = true;
        let t = Tokens::of(&c);
        assert_eq!(t.check(Access::Read, None), Ok(()));
        assert_eq!(t.check(Access::Admin, None), Err(Refusal::Unauthorized));
        let open = CoordinatorConfig::new("127.0.0.1:0".parse().unwrap(), "x.db");
        assert_eq!(Tokens::of(&open).check(Access::Admin, None), Ok(()));
    }

    #[test]
    fn compare_needs_every_byte() {
        assert!(ct_eq("x1", "x1") && !ct_eq("x1", "x2") && !ct_eq("x1", "x1 "));
    }

    #[test]
    fn head_is_looked_up_as_get() {
        let searches = shared::api::routes::Endpoint::ListSearches.path();
        assert_eq!(access_of("HEAD", searches), Some(Access::Read));
        assert_eq!(access_of("PUT", searches), None);
    }
}
