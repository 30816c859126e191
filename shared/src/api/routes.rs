//! The route table: every endpoint of the coordinator's HTTP API with its
//! method, path template and the role it needs. It is the one place a URL
//! of the API is spelled: the coordinator builds its router, its role
//! check and the OpenAPI paths from it, and the typed client
//! (`irlgrid_client`) and the dashboard's links fill in its templates.

use std::fmt;

/// The prefix of every route that needs a token (all but `/healthz` and
/// `/metrics`); the token guard covers what lies under it.
pub const API_PREFIX: &str = "/api/v1";

/// An HTTP method the API uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// A read.
    Get,
    /// A write (or a worker call).
    Post,
}

impl Method {
    /// The method's name (`GET`, `POST`).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Get => "GET",
            Self::Post => "POST",
        }
    }
}

/// What a route needs from the caller's bearer token.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// No token ever (health, metrics, the OpenAPI document).
    Open,
    /// A read of search or job data: reader or admin.
    Read,
    /// A worker call (lease, heartbeat, result, fail, release): worker or
    /// admin.
    Worker,
    /// A write (submit, cancel, extend, refine, score subjects): admin only.
    Admin,
}

impl Access {
    /// The name stated in the OpenAPI document (`x-irlgrid-role`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Open => "open",
            Self::Read => "reader",
            Self::Worker => "worker",
            Self::Admin => "admin",
        }
    }
}

/// Every endpoint of the API, by what it does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Endpoint {
    /// `GET /healthz`.
    Healthz,
    /// `GET /metrics`.
    Metrics,
    /// `GET /api/v1/openapi.json`.
    OpenApi,
    /// `GET /api/v1/searches`.
    ListSearches,
    /// `POST /api/v1/searches`.
    Submit,
    /// `GET /api/v1/searches/{id}`.
    SearchStatus,
    /// `POST /api/v1/searches/{id}/cancel`.
    Cancel,
    /// `POST /api/v1/searches/{id}/extend`.
    Extend,
    /// `POST /api/v1/searches/{id}/refine`.
    Refine,
    /// `GET /api/v1/searches/{id}/refinement`.
    Refinement,
    /// `GET /api/v1/searches/{id}/results`.
    Results,
    /// `GET /api/v1/searches/{id}/results.csv`.
    ResultsCsv,
    /// `GET /api/v1/searches/{id}/jobs`.
    SearchJobs,
    /// `GET /api/v1/searches/{id}/outputs`.
    Outputs,
    /// `POST /api/v1/searches/{id}/subjects`.
    ScoreSubjects,
    /// `GET /api/v1/jobs/{id}`.
    JobDetail,
    /// `POST /api/v1/leases`.
    Lease,
    /// `POST /api/v1/jobs/{id}/heartbeat`.
    Heartbeat,
    /// `POST /api/v1/jobs/{id}/result`.
    Result,
    /// `POST /api/v1/jobs/{id}/fail`.
    Fail,
    /// `POST /api/v1/jobs/{id}/release`.
    Release,
}

/// One row of the route table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Route {
    /// The endpoint.
    pub endpoint: Endpoint,
    /// Its method.
    pub method: Method,
    /// Its path template; `{id}` stands for a search or job id.
    pub path: &'static str,
    /// The role it needs.
    pub access: Access,
}

const fn route(endpoint: Endpoint, method: Method, path: &'static str, access: Access) -> Route {
    Route {
        endpoint,
        method,
        path,
        access,
    }
}

/// Every route, in the order the API reference lists them. The router
/// serves exactly these, the OpenAPI document lists exactly these, and the
/// auth middleware looks each request's route up here (a route missing
/// from the table is refused).
pub const ROUTES: &[Route] = {
    use Access::*;
    use Endpoint as E;
    use Method::*;
    &[
        route(E::Healthz, Get, "/healthz", Open),
        route(E::Metrics, Get, "/metrics", Open),
        route(E::OpenApi, Get, "/api/v1/openapi.json", Open),
        route(E::ListSearches, Get, "/api/v1/searches", Read),
        route(E::Submit, Post, "/api/v1/searches", Admin),
        route(E::SearchStatus, Get, "/api/v1/searches/{id}", Read),
        route(E::Cancel, Post, "/api/v1/searches/{id}/cancel", Admin),
        route(E::Extend, Post, "/api/v1/searches/{id}/extend", Admin),
        route(E::Refine, Post, "/api/v1/searches/{id}/refine", Admin),
        route(E::Refinement, Get, "/api/v1/searches/{id}/refinement", Read),
        route(E::Results, Get, "/api/v1/searches/{id}/results", Read),
        route(
            E::ResultsCsv,
            Get,
            "/api/v1/searches/{id}/results.csv",
            Read,
        ),
        route(E::SearchJobs, Get, "/api/v1/searches/{id}/jobs", Read),
        route(E::Outputs, Get, "/api/v1/searches/{id}/outputs", Read),
        route(
            E::ScoreSubjects,
            Post,
            "/api/v1/searches/{id}/subjects",
            Admin,
        ),
        route(E::JobDetail, Get, "/api/v1/jobs/{id}", Read),
        route(E::Lease, Post, "/api/v1/leases", Worker),
        route(E::Heartbeat, Post, "/api/v1/jobs/{id}/heartbeat", Worker),
        route(E::Result, Post, "/api/v1/jobs/{id}/result", Worker),
        route(E::Fail, Post, "/api/v1/jobs/{id}/fail", Worker),
        route(E::Release, Post, "/api/v1/jobs/{id}/release", Worker),
    ]
};

impl Endpoint {
    /// The endpoint's row of [`ROUTES`].
    pub fn route(self) -> &'static Route {
        ROUTES
            .iter()
            .find(|r| r.endpoint == self)
            .expect("every endpoint has a row in ROUTES (tested)")
    }

    /// Its method.
    pub fn method(self) -> Method {
        self.route().method
    }

    /// Its path template (`/api/v1/searches/{id}`).
    pub fn template(self) -> &'static str {
        self.route().path
    }

    /// The path of a route without an id (`/api/v1/searches`).
    pub fn path(self) -> &'static str {
        let p = self.template();
        debug_assert!(!p.contains('{'), "{p} needs an id: use Endpoint::path_of");
        p
    }

    /// The path with `{id}` filled in (`/api/v1/searches/abc/results`).
    /// Search ids are UUIDs and job ids integers: nothing to escape.
    pub fn path_of(self, id: impl fmt::Display) -> String {
        self.template().replace("{id}", &id.to_string())
    }
}

/// The row of a request's method and matched path template (`HEAD` is
/// looked up as `GET`).
pub fn lookup(method: &str, path: &str) -> Option<&'static Route> {
    let method = if method == "HEAD" { "GET" } else { method };
    ROUTES
        .iter()
        .find(|r| r.method.as_str() == method && r.path == path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_endpoint_has_exactly_one_row_and_no_row_repeats() {
        let mut seen = std::collections::HashSet::new();
        for r in ROUTES {
            assert!(seen.insert(r.endpoint), "{:?} twice", r.endpoint);
            assert_eq!(r.endpoint.route(), r);
            assert_eq!(
                ROUTES
                    .iter()
                    .filter(|o| o.method == r.method && o.path == r.path)
                    .count(),
                1,
                "{} {} twice",
                r.method.as_str(),
                r.path
            );
        }
    }

    #[test]
    fn guarded_routes_and_only_they_live_under_the_api_prefix() {
        for r in ROUTES {
            let under = r.path.starts_with(&format!("{API_PREFIX}/"));
            match r.access {
                Access::Open => assert!(
                    under == (r.endpoint == Endpoint::OpenApi),
                    "{}: open routes are /healthz, /metrics and the document",
                    r.path
                ),
                _ => assert!(
                    under,
                    "{} needs a token but is not under {API_PREFIX}",
                    r.path
                ),
            }
        }
    }

    #[test]
    fn templates_fill_and_look_up() {
        assert_eq!(
            Endpoint::Results.path_of("s1"),
            "/api/v1/searches/s1/results"
        );
        assert_eq!(Endpoint::Heartbeat.path_of(7), "/api/v1/jobs/7/heartbeat");
        assert_eq!(Endpoint::ListSearches.path(), "/api/v1/searches");
        let r = lookup("HEAD", "/api/v1/searches").unwrap();
        assert_eq!(
            (r.endpoint, r.access),
            (Endpoint::ListSearches, Access::Read)
        );
        assert_eq!(lookup("PUT", "/api/v1/searches"), None);
        assert_eq!(
            lookup("POST", "/api/v1/searches").map(|r| r.access),
            Some(Access::Admin)
        );
    }
}
