//! The OpenAPI 3.1 document of the API. Its paths come from the route
//! table ([`ROUTES`]: a test checks that they and their methods are
//! exactly the router's), each operation states the role it needs, and its
//! component schemas are derived from the wire types of [`shared::api`]
//! and the science types they carry (schemars, `shared`'s `openapi`
//! feature), so a field added to a type is in the document without an edit
//! here. What the types cannot say, the limits the coordinator enforces at
//! intake and the defaults it fills in, is laid over the derived schemas by
//! [`constrain_limits`], naming the intake constants.

use std::sync::OnceLock;

use schemars::generate::SchemaSettings;
use schemars::{JsonSchema, SchemaGenerator};
use serde_json::{json, Map, Value};

use shared::analysis::{refine, WeightInput};
use shared::api::routes::{Access, Endpoint, ROUTES};
use shared::api::{
    Created, ErrorBody, ExtendRequest, Extended, FailReport, Heartbeat, HeartbeatAck, JobDetail,
    JobInfo, JobStateAck, Lease, LeaseRequest, PageQuery, RefineRequest, Refinement,
    ReleaseRequest, ResultAck, ResultUpload, ResultsView, ScoreQuery, ScoredSubjects,
    SearchRequest, SearchStatus, SubjectsBody, DEFAULT_CONVERGENCE_THRESHOLD, DEFAULT_MAX_ATTEMPTS,
};

use crate::intake::{
    MAX_ATTEMPTS, MAX_ENV_STEPS, MAX_EPISODE_POINTS, MAX_GRID_PARAMS, MAX_HEARTBEAT_POINTS,
    MAX_NAME_CHARS, MAX_OPTIMIZER_EVALUATIONS, MAX_POINTS, MAX_REFINE_ROUNDS,
    MAX_SAMPLING_ATTEMPTS, MAX_SOLVERS, MAX_SOLVER_NAME_CHARS, MAX_SUBJECTS,
    MAX_SUCCESSFUL_EPISODES, MAX_TOKEN_CHARS, MAX_TRIALS, MAX_VALUES_PER_PARAM,
};

/// An error answer (the `Error` schema, [`ErrorBody`]).
fn err(desc: &str) -> Value {
    json!({"description": desc, "content": {"application/json": {"schema": {"$ref": "#/components/schemas/Error"}}}})
}

/// The document served at `GET /api/v1/openapi.json` by a coordinator
/// with a token (`auth_required`) or without one, with reads open
/// (`public_reads`) or not. Operations that need no `Authorization` here
/// get an empty `security` list, to describe this coordinator truthfully;
/// every operation keeps its `x-irlgrid-role`.
pub fn document_for(auth_required: bool, public_reads: bool) -> Value {
    let mut doc = document();
    if !auth_required {
        doc["info"]["description"] = json!("Reward-parameter search over a grid of (point, trial) PPO jobs leased to workers. This coordinator has no token: requests need no Authorization. Errors are `{\"error\": \"...\"}`.");
    }
    for route in ROUTES {
        let open = !auth_required || (public_reads && route.access == Access::Read);
        let op = &mut doc["paths"][route.path][route.method.as_str().to_lowercase()];
        if open && op.get("security").is_some() {
            op["security"] = json!([]);
        }
    }
    doc
}

/// States each operation's role (`x-irlgrid-role`, see [`crate::auth`]),
/// its bearer requirement and its 401/403 answers.
fn stamp_roles(doc: &mut Value) {
    for route in ROUTES {
        let access = route.access;
        let op = &mut doc["paths"][route.path][route.method.as_str().to_lowercase()];
        op["x-irlgrid-role"] = json!(access.name());
        if access == Access::Open {
            continue;
        }
        op["security"] = json!([{"bearer": []}]);
        let who = match access {
            Access::Read => "a reader or admin token",
            Access::Worker => "a worker or admin token",
            _ => "the admin token",
        };
        op["responses"]["401"] = err("missing or unknown bearer token");
        op["responses"]["403"] = err(&format!("this route needs {who}"));
    }
}

/// The full document (every `/api/v1` route but this document needs a
/// bearer token of its role), as served by a coordinator with a token.
pub fn document() -> Value {
    static DOCUMENT: OnceLock<Value> = OnceLock::new();
    DOCUMENT
        .get_or_init(|| {
            let mut doc = document_body();
            stamp_roles(&mut doc);
            doc
        })
        .clone()
}

/// The component schemas as they are built: each wire type's schema is
/// derived once by schemars (JSON Schema 2020-12, the dialect of OpenAPI
/// 3.1) under `#/components/schemas/<Type>`, and [`Schemas::of`] answers
/// the `$ref` a path uses, so a path can only name a schema that exists.
/// Schemas describe what serde reads (the request types' contract; a
/// client reads the answers with the same types).
struct Schemas(SchemaGenerator);

impl Schemas {
    fn new() -> Self {
        Self(
            SchemaSettings::draft2020_12()
                .with(|s| {
                    s.definitions_path = "/components/schemas".into();
                    s.meta_schema = None;
                })
                .into_generator(),
        )
    }

    /// The `$ref` to `T`'s schema, derived on first use.
    fn of<T: JsonSchema>(&mut self) -> Value {
        self.0.subschema_for::<T>().to_value()
    }

    /// The query parameters of a query-string type `T` (as axum's `Query`
    /// reads it): one per field, with its derived schema and description.
    fn query_params<T: JsonSchema>(&mut self) -> Vec<Value> {
        let schema = T::json_schema(&mut self.0).to_value();
        let required = schema.get("required").cloned().unwrap_or(json!([]));
        let Some(props) = schema.get("properties").and_then(Value::as_object) else {
            return Vec::new();
        };
        props
            .iter()
            .map(|(name, prop)| {
                let mut prop = prop.clone();
                let m = prop.as_object_mut().expect("a field schema");
                let description = m.remove("description").unwrap_or(Value::Null);
                // An absent parameter is the `null` of an `Option`.
                if m.get("default") == Some(&Value::Null) {
                    m.remove("default");
                }
                if let Some(Value::Array(types)) = m.get_mut("type") {
                    types.retain(|t| t != "null");
                    if types.len() == 1 {
                        let only = types[0].clone();
                        m.insert("type".into(), only);
                    }
                }
                let mut p = json!({"name": name, "in": "query",
                    "required": required.as_array().is_some_and(|r| r.contains(&json!(name))),
                    "schema": prop});
                if description.is_string() {
                    p["description"] = description;
                }
                p
            })
            .collect()
    }

    fn into_components(mut self) -> Map<String, Value> {
        self.0.take_definitions(true)
    }
}

/// Lays `extra`'s keywords over property `field` of component `schema`
/// (replacing those it names). The targets are fixed; a unit test builds
/// the document, so a renamed field fails there, not in a served request.
fn constrain(components: &mut Map<String, Value>, schema: &str, field: &str, extra: Value) {
    let slot = components
        .get_mut(schema)
        .and_then(|s| s.get_mut("properties"))
        .and_then(|p| p.get_mut(field))
        .and_then(Value::as_object_mut)
        .unwrap_or_else(|| panic!("no property {schema}.{field} to constrain"));
    for (k, v) in extra.as_object().expect("an object of keywords") {
        slot.insert(k.clone(), v.clone());
    }
}

/// The limits the coordinator enforces at intake ([`crate::intake`],
/// `domain::leasing`) and the defaults it fills in, which the Rust types do
/// not carry; everything else in the components is derived.
fn constrain_limits(c: &mut Map<String, Value>) {
    let token = json!({"minLength": 1, "maxLength": MAX_TOKEN_CHARS});
    let count = json!({"maximum": u32::MAX});
    let params: Vec<&str> = shared::env::RewardConfig::PARAMS.to_vec();
    // The enum lists `null` too: the type allows it, and a JSON Schema enum
    // constrains every value, null included.
    let mut presets: Vec<Value> = shared::env::presets()
        .iter()
        .map(|p| json!(p.name))
        .collect();
    presets.push(Value::Null);
    let grid_values = json!({"type": "array", "items": {"type": "number"}, "minItems": 1,
        "maxItems": MAX_VALUES_PER_PARAM, "uniqueItems": true});

    let s = "SearchRequest";
    constrain(c, s, "name", json!({"maxLength": MAX_NAME_CHARS}));
    constrain(
        c,
        s,
        "reward_grid",
        json!({
        "description": format!("parameter name (w1, success_bonus, ...) -> 1..{MAX_VALUES_PER_PARAM} distinct values valid for that parameter; several parameters give their product (<= {MAX_POINTS} points)"),
        "minProperties": 1, "maxProperties": MAX_GRID_PARAMS, "propertyNames": {"enum": params},
        "additionalProperties": grid_values}),
    );
    constrain(c, s, "trials", json!({"minimum": 1, "maximum": MAX_TRIALS}));
    constrain(
        c,
        s,
        "reward_preset",
        json!({"enum": presets, "default": "paper"}),
    );
    constrain(c, s, "seed", json!({"maximum": u64::MAX}));
    constrain(
        c,
        s,
        "training",
        json!({"description": format!("trainer configuration (`PpoConfig` fields), partial; env_steps <= {MAX_ENV_STEPS}")}),
    );
    constrain(
        c,
        s,
        "sampling",
        json!({"description": format!("sampler configuration (`SamplingConfig` fields), partial; <= {MAX_SUCCESSFUL_EPISODES} successful episodes, <= {MAX_SAMPLING_ATTEMPTS} attempts")}),
    );
    constrain(
        c,
        s,
        "subjects_csv",
        json!({"description": format!("subject trajectories, CSV subject,time,x,z (docs/science.md#subject-data); parsed on submission (a bad line is a 400 naming it), <= {MAX_SUBJECTS} subjects")}),
    );
    constrain(
        c,
        s,
        "convergence_threshold",
        json!({"minimum": 0, "maximum": 1, "default": DEFAULT_CONVERGENCE_THRESHOLD}),
    );
    constrain(
        c,
        s,
        "max_trials_per_point",
        json!({"minimum": 1, "maximum": MAX_TRIALS * 4}),
    );
    constrain(
        c,
        s,
        "max_attempts",
        json!({"minimum": 1, "maximum": MAX_ATTEMPTS, "default": DEFAULT_MAX_ATTEMPTS}),
    );
    constrain(
        c,
        s,
        "solvers",
        json!({"minItems": 1, "maxItems": MAX_SOLVERS,
        "description": "solver variants (docs/inference.md#solver-spread): every (point, trial) runs once per variant, and points x trial cap x variants must stay within the job limit; omitted: one PPO variant `ppo` configured by `training`"}),
    );

    let s = "SolverRequest";
    constrain(
        c,
        s,
        "name",
        json!({"pattern": format!("^[A-Za-z0-9._-]{{1,{MAX_SOLVER_NAME_CHARS}}}$")}),
    );
    constrain(
        c,
        s,
        "optimizer",
        json!({"description": format!("optimizer only: cross-entropy settings (`OptimizeConfig` fields), partial; population x iterations x (restarts + stretch_rounds) <= {MAX_OPTIMIZER_EVALUATIONS}; the job's seed is the optimizer's")}),
    );

    let s = "RefineRequest";
    constrain(
        c,
        s,
        "rounds",
        json!({"minimum": 1, "maximum": MAX_REFINE_ROUNDS, "default": refine::DEFAULT_ROUNDS}),
    );
    constrain(c, s, "trials", json!({"minimum": 1, "maximum": MAX_TRIALS}));
    constrain(
        c,
        s,
        "target_ratio",
        json!({"minimum": refine::MIN_TARGET_RATIO, "maximum": 100, "default": refine::DEFAULT_TARGET_RATIO}),
    );
    constrain(
        c,
        s,
        "min_pair_mass",
        json!({"minimum": 0, "maximum": 1, "default": refine::DEFAULT_MIN_PAIR_MASS}),
    );

    let s = "ExtendRequest";
    constrain(c, s, "trials", json!({"minimum": 1, "maximum": MAX_TRIALS}));
    constrain(
        c,
        s,
        "reward_grid",
        json!({"maxProperties": MAX_GRID_PARAMS,
        "additionalProperties": {"type": "array", "items": {"type": "number"}, "minItems": 1, "maxItems": MAX_VALUES_PER_PARAM}}),
    );

    constrain(
        c,
        "Refinement",
        "state",
        json!({"enum": ["pending", "settled", "none"]}),
    );
    for f in ["created_at", "started_at", "finished_at"] {
        constrain(c, "SearchStatus", f, json!({"format": "date-time"}));
    }

    // domain::leasing: 1..=200 printable characters, at most 30 s of waiting.
    constrain(
        c,
        "LeaseRequest",
        "worker",
        json!({"minLength": 1, "maxLength": 200,
        "pattern": "^[^\\x00-\\x1f\\x7f-\\x9f]*\\S[^\\x00-\\x1f\\x7f-\\x9f]*$"}),
    );
    constrain(c, "LeaseRequest", "wait_secs", json!({"maximum": 30}));
    constrain(c, "Heartbeat", "lease_token", token.clone());
    constrain(
        c,
        "Heartbeat",
        "progress",
        json!({"maxItems": MAX_HEARTBEAT_POINTS}),
    );
    constrain(
        c,
        "ProgressPoint",
        "env_steps",
        json!({"description": "environment steps trained so far; at most 2 x max(total_env_steps, 1)"}),
    );
    constrain(
        c,
        "ProgressPoint",
        "success_rate",
        json!({"minimum": 0, "maximum": 1}),
    );

    let samples = json!({"minItems": 2, "maxItems": MAX_EPISODE_POINTS});
    constrain(c, "EpisodeRecord", "com_t", samples.clone());
    constrain(c, "EpisodeRecord", "com_x", samples.clone());
    constrain(c, "EpisodeRecord", "com_z", samples);
    constrain(c, "EpisodeRecord", "torque_usage", json!({"minimum": 0}));
    constrain(c, "EpisodeRecord", "steps", count.clone());
    let s = "JobOutput";
    constrain(
        c,
        s,
        "final_success_rate",
        json!({"minimum": 0, "maximum": 1}),
    );
    constrain(c, s, "env_steps", json!({"maximum": MAX_ENV_STEPS * 2}));
    for f in ["successes_found", "successes_wanted", "sampling_attempts"] {
        constrain(c, s, f, count.clone());
    }
    constrain(c, s, "train_secs", json!({"minimum": 0}));
    constrain(c, s, "sample_secs", json!({"minimum": 0}));
    constrain(c, "ResultUpload", "lease_token", token.clone());
    constrain(c, "FailReport", "lease_token", token.clone());
    constrain(c, "ReleaseRequest", "lease_token", token);
}

fn document_body() -> Value {
    let mut s = Schemas::new();
    let error = s.of::<ErrorBody>();
    let err = |desc: &str| json!({"description": desc, "content": {"application/json": {"schema": error.clone()}}});
    let ok = |desc: &str, schema: Value| json!({"description": desc, "content": {"application/json": {"schema": schema}}});
    let body = |schema: Value| json!({"required": true, "content": {"application/json": {"schema": schema}}});
    let array = |items: Value| json!({"type": "array", "items": items});
    let id_param = |desc: &str, int: bool| {
        json!([{"name": "id", "in": "path", "required": true, "description": desc,
            "schema": if int { json!({"type": "integer", "format": "int64", "examples": [1]}) } else { json!({"type": "string"}) }}])
    };
    let sid = id_param("search id", false);
    let jid = id_param("job id", true);
    let auth = json!([{"bearer": []}]);
    let obj = json!({"type": "object"});
    let observables: Vec<&str> = shared::analysis::Observables::ALL.map(|o| o.key()).to_vec();
    let mut score_params = vec![sid[0].clone()];
    score_params.extend(s.query_params::<ScoreQuery>());
    for p in &mut score_params {
        // The type reads a string; the handler accepts only these.
        if p["name"] == "observables" {
            p["schema"]["enum"] = json!(observables);
        }
    }
    let worker_errs = |mut v: Value| {
        let m = v.as_object_mut().expect("object");
        m.insert(
            "400".into(),
            err("invalid body or id; the message names the field"),
        );
        m.insert("401".into(), err("missing or wrong bearer token"));
        m.insert("404".into(), err("unknown job"));
        m.insert("409".into(), err("lease token not current (expired, released, job done or cancelled); nothing changed"));
        v
    };
    let search_request = s.of::<SearchRequest>();
    let created = s.of::<Created>();
    let search_status = s.of::<SearchStatus>();
    let extend_request = s.of::<ExtendRequest>();
    let extended = s.of::<Extended>();
    let refine_request = s.of::<RefineRequest>();
    let refinement = s.of::<Refinement>();
    let results = s.of::<ResultsView<'static>>();
    let job_info = s.of::<JobInfo>();
    let weight_input = s.of::<WeightInput>();
    let subjects_body = s.of::<SubjectsBody>();
    let scored = s.of::<ScoredSubjects>();
    let job_detail = s.of::<JobDetail>();
    let lease_request = s.of::<LeaseRequest>();
    let lease = s.of::<Lease>();
    let heartbeat = s.of::<Heartbeat>();
    let heartbeat_ack = s.of::<HeartbeatAck>();
    let result_upload = s.of::<ResultUpload>();
    let result_ack = s.of::<ResultAck>();
    let fail_report = s.of::<FailReport>();
    let release_request = s.of::<ReleaseRequest>();
    let job_state_ack = s.of::<JobStateAck>();
    let mut components = s.into_components();
    constrain_limits(&mut components);
    json!({
        "openapi": "3.1.0",
        "info": {
            "title": "irlgrid coordinator",
            "version": env!("CARGO_PKG_VERSION"),
            "description": "Reward-parameter search over a grid of (point, trial) PPO jobs leased to workers. When the coordinator has a token, every /api/v1 request but this document needs `Authorization: Bearer <token>` of a role that covers it (`x-irlgrid-role`: admin `IRLGRID_TOKEN` everything, worker `IRLGRID_WORKER_TOKEN` the worker calls, reader `IRLGRID_READ_TOKEN` the reads); no or unknown token is 401, another role 403. Errors are `{\"error\": \"...\"}`."
        },
        "components": {
            "securitySchemes": {"bearer": {"type": "http", "scheme": "bearer"}},
            "schemas": components
        },
        "paths": {
            (Endpoint::Healthz.template()): {"get": {"summary": "liveness and database check (a read and a one-row write)", "responses": {"200": ok("healthy", obj.clone()), "503": err("database unavailable: disk full, read-only, I/O error or locked (Retry-After set)")}}},
            (Endpoint::Metrics.template()): {"get": {"summary": "Prometheus metrics", "responses": {"200": {"description": "text/plain exposition format", "content": {"text/plain": {"schema": {"type": "string"}}}}}}},
            (Endpoint::OpenApi.template()): {"get": {"summary": "this document", "responses": {"200": ok("OpenAPI 3.1", obj)}}},
            (Endpoint::ListSearches.template()): {
                "get": {"summary": "one page of searches, newest first; the total count is in the X-Total-Count header", "parameters": [
                    {"name": "limit", "in": "query", "required": false, "description": format!("searches per page; cut to 1..={} (0 reads as 1)", PageQuery::MAX_LIMIT), "schema": {"type": "integer", "minimum": 0, "maximum": u32::MAX, "default": PageQuery::DEFAULT_LIMIT}},
                    {"name": "offset", "in": "query", "required": false, "description": "searches skipped, newest first", "schema": {"type": "integer", "minimum": 0, "default": 0}}],
                    "responses": {"200": ok("searches", array(search_status.clone())), "400": err("malformed limit or offset")}},
                "post": {"summary": "submit a search", "security": auth, "requestBody": body(search_request), "responses": {
                    "201": ok("created", created), "400": err("invalid field (named)"), "401": err("missing or wrong token"), "413": err("body too large")}}
            },
            (Endpoint::SearchStatus.template()): {"get": {"summary": "status, job counts, workers busy, times, ETA", "parameters": sid, "responses": {"200": ok("status", search_status.clone()), "404": err("unknown search")}}},
            (Endpoint::Cancel.template()): {"post": {"summary": "cancel: queued and leased jobs become cancelled; finished ones are kept", "security": auth, "parameters": sid, "responses": {
                "200": ok("cancelled", search_status), "401": err("missing or wrong token"), "404": err("unknown search"), "409": err("search already completed")}}},
            (Endpoint::Extend.template()): {"post": {"summary": "extend a running or completed search: raise trials per point and/or add grid values; existing jobs and results are kept, new jobs get the seeds of their (point, trial), the search runs again and its document is partial until they finish", "security": auth, "parameters": sid, "requestBody": body(extend_request), "responses": {
                "200": ok("extended", extended), "400": err("invalid field (named), a value already in the grid, fewer trials than now, a limit exceeded, or nothing to add"), "401": err("missing or wrong token"), "404": err("unknown search"), "409": err("search cancelled"), "413": err("body too large")}}},
            (Endpoint::Refine.template()): {"post": {"summary": "refine the grid toward the search's subjects: when the search has completed (at once if it has), every subject's best grid value and its more likely neighbour are read; their geometric midpoint is added where the pair is wider than target_ratio, for up to `rounds` rounds", "security": auth, "parameters": sid, "requestBody": body(refine_request), "responses": {
                "200": ok("refinement", refinement.clone()), "400": err("invalid field (named), a grid of several parameters, or no subjects"), "401": err("missing or wrong token"), "404": err("unknown search"), "409": err("search cancelled"), "413": err("body too large")}}},
            (Endpoint::Refinement.template()): {"get": {"summary": "the refinement asked for and every round so far: per subject the estimate, the bracketing pair and the point it asked for", "parameters": sid, "responses": {"200": ok("refinement", refinement), "404": err("unknown search")}}},
            (Endpoint::Results.template()): {"get": {"summary": "result document (partial while running, final when completed)", "parameters": sid, "responses": {"200": ok("document", results), "404": err("unknown search")}}},
            (Endpoint::ResultsCsv.template()): {"get": {"summary": "per-weight statistics and subject cost matrices as tidy CSV", "parameters": sid, "responses": {
                "200": {"description": "CSV with header section,subject,param_value,trial,point,quantity,value", "content": {"text/csv": {"schema": {"type": "string"}}}}, "404": err("unknown search")}}},
            (Endpoint::SearchJobs.template()): {"get": {"summary": "every job with state, owner, attempts and latest progress", "parameters": sid, "responses": {"200": ok("jobs", array(job_info)), "404": err("unknown search")}}},
            (Endpoint::Outputs.template()): {"get": {"summary": "aggregation input: every done trial's output by grid point", "parameters": sid, "responses": {"200": ok("inputs", array(weight_input)), "404": err("unknown search")}}},
            (Endpoint::ScoreSubjects.template()): {"post": {"summary": "score new subjects against the search's finished trials without running a job (every method, as in the result document); ?save=true also adds them to the search", "security": auth, "parameters": score_params,
                "requestBody": {"required": true, "content": {"text/csv": {"schema": {"type": "string", "description": "subject,time,x,z rows"}}, "application/json": {"schema": subjects_body}}},
                "responses": {"200": ok("scored subjects", scored), "400": err("bad CSV (line-precise) or query"), "401": err("missing or wrong token"), "404": err("unknown search"), "409": err("no converged trial yet, or a subject name already stored (save)"), "413": err("body too large")}}},
            (Endpoint::JobDetail.template()): {"get": {"summary": "one job with its learning curve", "parameters": jid, "responses": {"200": ok("job", job_detail), "400": err("bad id"), "404": err("unknown job")}}},
            (Endpoint::Lease.template()): {"post": {"summary": "lease the next job (fair across running searches); long-polls up to wait_secs", "security": auth, "requestBody": body(lease_request), "responses": {
                "200": ok("leased", lease), "204": {"description": "no job queued"}, "400": err("invalid body"), "401": err("missing or wrong token")}}},
            (Endpoint::Heartbeat.template()): {"post": {"summary": "renew the lease and report progress", "security": auth, "parameters": jid, "requestBody": body(heartbeat), "responses": worker_errs(json!({"200": ok("lease renewed", heartbeat_ack)}))}},
            (Endpoint::Result.template()): {"post": {"summary": "upload the output; the first valid upload under the current lease wins", "security": auth, "parameters": jid, "requestBody": body(result_upload), "responses": worker_errs(json!({"200": ok("result accepted", result_ack)}))}},
            (Endpoint::Fail.template()): {"post": {"summary": "report a failure; retried until max_attempts, then failed", "security": auth, "parameters": jid, "requestBody": body(fail_report), "responses": worker_errs(json!({"200": ok("job requeued or failed", job_state_ack.clone())}))}},
            (Endpoint::Release.template()): {"post": {"summary": "hand the job back unfinished without using an attempt", "security": auth, "parameters": jid, "requestBody": body(release_request), "responses": worker_errs(json!({"200": ok("job requeued", job_state_ack)}))}}
        }
    })
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    use super::*;

    #[test]
    fn every_schema_of_the_hand_written_document_is_derived() {
        let doc = document();
        let schemas = doc["components"]["schemas"].as_object().unwrap();
        // The names the hand-written document had (clients may link them).
        for name in [
            "Created",
            "EpisodeRecord",
            "Error",
            "ExtendRequest",
            "Extended",
            "FailReport",
            "Heartbeat",
            "HeartbeatAck",
            "JobCounts",
            "JobDetail",
            "JobInfo",
            "JobOutput",
            "JobSpec",
            "JobStateAck",
            "Lease",
            "LeaseRequest",
            "ProgressPoint",
            "RefineRequest",
            "Refinement",
            "ReleaseRequest",
            "ResultAck",
            "ResultDocument",
            "ResultUpload",
            "SearchRequest",
            "SearchStatus",
            "SolverRequest",
            "WeightInput",
        ] {
            assert!(schemas.contains_key(name), "{name} missing");
        }
        // Derived: doc comments, required fields, refused unknown fields.
        let lease = &schemas["LeaseRequest"];
        assert_eq!(lease["additionalProperties"], false);
        assert_eq!(lease["required"], json!(["worker"]));
        assert!(lease["properties"]["worker"]["description"].is_string());
        assert_eq!(schemas["JobState"]["oneOf"].as_array().unwrap().len(), 5);
    }

    #[test]
    fn intake_limits_lie_over_the_derived_schemas() {
        let doc = document();
        let s = &doc["components"]["schemas"];
        let req = &s["SearchRequest"]["properties"];
        assert_eq!(req["trials"]["maximum"], MAX_TRIALS);
        assert_eq!(req["trials"]["minimum"], 1);
        assert_eq!(req["max_attempts"]["default"], DEFAULT_MAX_ATTEMPTS);
        assert_eq!(req["reward_grid"]["maxProperties"], MAX_GRID_PARAMS);
        assert_eq!(
            s["Heartbeat"]["properties"]["lease_token"]["maxLength"],
            MAX_TOKEN_CHARS
        );
        assert_eq!(
            s["RefineRequest"]["properties"]["rounds"]["maximum"],
            MAX_REFINE_ROUNDS
        );
    }

    #[test]
    fn a_partial_configuration_requires_nothing_and_refuses_unknown_fields() {
        let doc = document();
        let partial = &doc["components"]["schemas"]["PartialEnvConfig"];
        let text = partial.to_string();
        assert!(!text.contains("\"required\""), "{text}");
        assert_eq!(partial["additionalProperties"], false);
        // Nested configurations are inlined and partial too.
        let reward = &partial["properties"]["reward"];
        assert!(reward["properties"]["w1"].is_object(), "{reward}");
    }

    #[test]
    fn document_lists_exactly_the_routes() {
        let doc = document();
        let mut documented = BTreeSet::new();
        for (path, ops) in doc["paths"].as_object().unwrap() {
            for method in ops.as_object().unwrap().keys() {
                documented.insert((method.to_uppercase(), path.clone()));
            }
        }
        let routed: BTreeSet<_> = ROUTES
            .iter()
            .map(|r| (r.method.as_str().to_string(), r.path.to_string()))
            .collect();
        assert_eq!(documented, routed);
    }

    #[test]
    fn without_a_token_no_operation_requires_it() {
        let open = document_for(false, false).to_string();
        assert!(!open.contains(r#""bearer":[]"#), "{open}");
        let full = document_for(true, false);
        assert_eq!(full, document());
        assert!(full.to_string().contains(r#""security":[{"bearer":[]}]"#));
    }

    #[test]
    fn every_operation_states_its_role_and_reads_need_the_token() {
        let doc = document();
        for r in ROUTES {
            let (method, path) = (r.method.as_str(), r.path);
            let op = &doc["paths"][path][method.to_lowercase()];
            assert_eq!(op["x-irlgrid-role"], r.access.name(), "{method} {path}");
            let secured = op["security"] == json!([{"bearer": []}]);
            assert_eq!(secured, r.access != Access::Open, "{method} {path}");
        }
        let public = document_for(true, true);
        let results = &public["paths"][Endpoint::Results.template()]["get"];
        assert_eq!(results["security"], json!([]));
        let submit = &public["paths"][Endpoint::Submit.template()]["post"];
        assert_eq!(submit["security"], json!([{"bearer": []}]));
    }

    #[test]
    fn every_schema_reference_resolves() {
        let doc = document();
        let text = doc.to_string();
        let schemas = doc["components"]["schemas"].as_object().unwrap();
        for part in text.split("#/components/schemas/").skip(1) {
            let name: String = part.chars().take_while(|c| c.is_alphanumeric()).collect();
            assert!(schemas.contains_key(&name), "dangling $ref {name}");
        }
    }
}
