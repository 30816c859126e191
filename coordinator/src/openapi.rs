//! The OpenAPI 3.1 document of the API, written by hand: the wire types
//! embed `shared` science types (configs, episode records, the result
//! document) that this crate does not own and cannot annotate, and a derive
//! framework would add a proc-macro build for one static document. A test
//! checks that its paths and methods are exactly the router's
//! ([`crate::auth::ROUTES`]), and each operation states the role it needs.

use serde_json::{json, Value};

use shared::api::routes::{Access, Endpoint, ROUTES};

use shared::analysis::refine;

use crate::intake::{
    MAX_ATTEMPTS, MAX_ENV_STEPS, MAX_EPISODE_POINTS, MAX_GRID_PARAMS, MAX_HEARTBEAT_POINTS,
    MAX_NAME_CHARS, MAX_OPTIMIZER_EVALUATIONS, MAX_POINTS, MAX_REFINE_ROUNDS,
    MAX_SAMPLING_ATTEMPTS, MAX_SOLVERS, MAX_SOLVER_NAME_CHARS, MAX_SUBJECTS,
    MAX_SUCCESSFUL_EPISODES, MAX_TOKEN_CHARS, MAX_TRIALS, MAX_VALUES_PER_PARAM,
};

fn err(desc: &str) -> Value {
    json!({"description": desc, "content": {"application/json": {"schema": {"$ref": "#/components/schemas/Error"}}}})
}

fn ok(desc: &str, schema: Value) -> Value {
    json!({"description": desc, "content": {"application/json": {"schema": schema}}})
}

fn body(schema: &str) -> Value {
    json!({"required": true, "content": {"application/json": {"schema": {"$ref": format!("#/components/schemas/{schema}")}}}})
}

fn r(name: &str) -> Value {
    json!({"$ref": format!("#/components/schemas/{name}")})
}

fn id_param(desc: &str, int: bool) -> Value {
    json!([{"name": "id", "in": "path", "required": true, "description": desc,
            "schema": if int { json!({"type": "integer", "format": "int64", "examples": [1]}) } else { json!({"type": "string"}) }}])
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
    let mut doc = document_body();
    stamp_roles(&mut doc);
    doc
}

fn document_body() -> Value {
    let sid = id_param("search id", false);
    let jid = id_param("job id", true);
    let auth = json!([{"bearer": []}]);
    let observables = shared::analysis::Observables::ALL.map(|o| o.key());
    let (observables_enum, observables_or_null) = (json!(observables), {
        let mut v = json!(observables);
        v.as_array_mut().expect("array").push(Value::Null);
        v
    });
    let worker_errs = |v: &mut Value| {
        let m = v.as_object_mut().expect("object");
        m.insert(
            "400".into(),
            err("invalid body or id; the message names the field"),
        );
        m.insert("401".into(), err("missing or wrong bearer token"));
        m.insert("404".into(), err("unknown job"));
        m.insert("409".into(), err("lease token not current (expired, released, job done or cancelled); nothing changed"));
    };
    let mut hb = json!({"200": ok("lease renewed", r("HeartbeatAck"))});
    worker_errs(&mut hb);
    let mut res = json!({"200": ok("result accepted", r("ResultAck"))});
    worker_errs(&mut res);
    let mut fail = json!({"200": ok("job requeued or failed", r("JobStateAck"))});
    worker_errs(&mut fail);
    let mut rel = json!({"200": ok("job requeued", r("JobStateAck"))});
    worker_errs(&mut rel);
    let obj = json!({"type": "object"});
    // Limits the coordinator enforces (crate::intake, routes::jobs).
    let token = json!({"type": "string", "minLength": 1, "maxLength": MAX_TOKEN_CHARS, "description": "the lease's token"});
    let count = json!({"type": "integer", "minimum": 0, "maximum": u32::MAX});
    let samples = json!({"type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": MAX_EPISODE_POINTS});
    let params: Vec<&str> = shared::env::RewardConfig::PARAMS.to_vec();
    let num_opt = json!({"type": ["number", "null"]});
    // The enum lists `null` too: the type allows it, and a JSON Schema enum
    // constrains every value, null included.
    let mut preset_names: Vec<serde_json::Value> = shared::env::presets()
        .iter()
        .map(|p| json!(p.name))
        .collect();
    preset_names.push(serde_json::Value::Null);
    json!({
        "openapi": "3.1.0",
        "info": {
            "title": "irlgrid coordinator",
            "version": env!("CARGO_PKG_VERSION"),
            "description": "Reward-parameter search over a grid of (point, trial) PPO jobs leased to workers. When the coordinator has a token, every /api/v1 request but this document needs `Authorization: Bearer <token>` of a role that covers it (`x-irlgrid-role`: admin `IRLGRID_TOKEN` everything, worker `IRLGRID_WORKER_TOKEN` the worker calls, reader `IRLGRID_READ_TOKEN` the reads); no or unknown token is 401, another role 403. Errors are `{\"error\": \"...\"}`."
        },
        "components": {
            "securitySchemes": {"bearer": {"type": "http", "scheme": "bearer"}},
            "schemas": {
                "Error": {"type": "object", "required": ["error"], "properties": {"error": {"type": "string"}}},
                "SearchRequest": {"type": "object", "description": "A search: omitted fields take the `shared` defaults; the coordinator stores the request and the resolved configuration (every default filled in) and sends the resolved one with every lease.", "required": ["reward_grid", "trials"], "additionalProperties": false, "properties": {
                    "name": {"type": "string", "maxLength": MAX_NAME_CHARS, "description": "label"},
                    "reward_grid": {"type": "object", "description": format!("parameter name (w1, success_bonus, ...) -> 1..{MAX_VALUES_PER_PARAM} distinct values valid for that parameter; several parameters give their product (<= {MAX_POINTS} points)"),
                        "minProperties": 1, "maxProperties": MAX_GRID_PARAMS, "propertyNames": {"enum": params},
                        "additionalProperties": {"type": "array", "items": {"type": "number"}, "minItems": 1, "maxItems": MAX_VALUES_PER_PARAM, "uniqueItems": true}},
                    "trials": {"type": "integer", "minimum": 1, "maximum": MAX_TRIALS, "description": "converged trials wanted per point"},
                    "reward_preset": {"type": ["string", "null"], "enum": preset_names, "default": "paper", "description": "named reward preset (`irlgrid presets`): the reward starts from its values; `env.reward` fields and the grid override them. Reward parameters: w1, effort_exponent (p of ||a||^p), height_offset (running reward h_t - offset), success_step_cost, ..."},
                    "seed": {"type": "integer", "minimum": 0, "maximum": u64::MAX, "description": "base seed (u64); job seed = splitmix64 chain of (seed, point values, trial)"},
                    "training": {"type": ["object", "null"], "description": "shared::ppo::PpoConfig fields (partial; env_steps <= 100000000)"},
                    "sampling": {"type": ["object", "null"], "description": format!("shared::sample::SamplingConfig fields (partial: successful_episodes, top_k, max_attempts, n_envs; <= {MAX_SUCCESSFUL_EPISODES} successes, <= {MAX_SAMPLING_ATTEMPTS} attempts)")},
                    "env": {"type": ["object", "null"], "description": "shared::env::EnvConfig fields (partial); the point's parameters are applied on top"},
                    "subjects_csv": {"type": ["string", "null"], "description": format!("subject trajectories, CSV subject,time,x,z; parsed on submission (a bad line is a 400 naming it), <= {MAX_SUBJECTS} subjects")},
                    "convergence_threshold": {"type": ["number", "null"], "minimum": 0, "maximum": 1, "default": 0.5, "description": "final success rate a trial needs to count as converged"},
                    "replace_unconverged": {"type": "boolean", "default": false, "description": "enqueue a replacement trial (fresh seed) for every unconverged or failed trial"},
                    "max_trials_per_point": {"type": ["integer", "null"], "minimum": 1, "maximum": MAX_TRIALS * 4, "description": "cap on trials per point, replacements included: trials..=400; default 2 x trials with replacement, else trials"},
                    "max_attempts": {"type": ["integer", "null"], "minimum": 1, "maximum": MAX_ATTEMPTS, "default": 3, "description": "leases a job may lose (expiry or worker failure) before it fails"},
                    "refine": {"oneOf": [{"type": "null"}, r("RefineRequest")], "description": "refine the grid toward the subjects once it has finished (one-parameter grid with subjects only)"},
                    "observables": {"type": ["string", "null"], "enum": observables_or_null, "description": "the evidence the posterior uses (docs/inference.md#observables); omitted: relative_timing under the power preset, shape otherwise; stored in the resolved configuration, where a search stored without it reads as shape"},
                    "solvers": {"type": ["array", "null"], "items": r("SolverRequest"), "minItems": 1, "maxItems": MAX_SOLVERS, "description": "solver variants (docs/inference.md#solver-spread): every (point, trial) runs once per variant, and points x trial cap x variants must stay within the job limit; omitted: one PPO variant `ppo` configured by `training`"}
                }},
                "SolverRequest": {"type": "object", "required": ["name", "kind"], "additionalProperties": false, "properties": {
                    "name": {"type": "string", "pattern": format!("^[A-Za-z0-9._-]{{1,{MAX_SOLVER_NAME_CHARS}}}$"), "description": "unique within the search"},
                    "kind": {"enum": ["ppo", "optimizer"]},
                    "training": {"type": ["object", "null"], "description": "ppo only: shared::ppo::PpoConfig fields (partial) over the search's `training`"},
                    "optimizer": {"type": ["object", "null"], "description": format!("optimizer only: shared::optimize::OptimizeConfig fields (partial: population, iterations, restarts, stretch, stretch_rounds, ...; population x iterations x (restarts + stretch_rounds) <= {MAX_OPTIMIZER_EVALUATIONS}); the job's seed is the optimizer's")}
                }},
                "RefineRequest": {"type": "object", "additionalProperties": false, "properties": {
                    "rounds": {"type": "integer", "minimum": 1, "maximum": MAX_REFINE_ROUNDS, "default": refine::DEFAULT_ROUNDS},
                    "trials": {"type": "integer", "minimum": 1, "maximum": MAX_TRIALS, "description": "trials per added point (default: the search's trials per point)"},
                    "target_ratio": {"type": "number", "minimum": refine::MIN_TARGET_RATIO, "maximum": 100, "default": refine::DEFAULT_TARGET_RATIO, "description": "a subject is settled once the ratio of its two neighbouring candidates is below this"},
                    "min_pair_mass": {"type": "number", "minimum": 0, "maximum": 1, "default": refine::DEFAULT_MIN_PAIR_MASS, "description": "under the posterior, a subject asks for a point only when its two candidates hold at least this much of its posterior mass"}}},
                "Refinement": {"type": "object", "required": ["id", "status", "state", "rounds"], "properties": {
                    "id": {"type": "string"}, "status": {"enum": ["running", "completed", "cancelled"]},
                    "spec": {"type": ["object", "null"], "description": "rounds, trials, target_ratio, min_pair_mass, param, first_round"},
                    "state": {"enum": ["pending", "settled", "none"]},
                    "rounds": {"type": "array", "description": "one evaluation per round: round (0 = the grid as submitted), subjects (subject, method, estimate, lo, hi, ratio, pair_mass, midpoint, reason), added values, stop reason, at", "items": {"type": "object"}}}},
                "Created": {"type": "object", "required": ["id", "jobs"], "properties": {"id": {"type": "string"}, "jobs": {"type": "integer"}}},
                "ExtendRequest": {"type": "object", "additionalProperties": false, "properties": {
                    "trials": {"type": "integer", "minimum": 1, "maximum": MAX_TRIALS, "description": "new converged trials wanted per point (at least the current)"},
                    "reward_grid": {"type": "object", "maxProperties": MAX_GRID_PARAMS, "description": "values to add per parameter of the search's grid", "additionalProperties": {"type": "array", "minItems": 1, "maxItems": MAX_VALUES_PER_PARAM, "items": {"type": "number"}}}}},
                "Extended": {"type": "object", "required": ["id", "status", "trials", "points", "points_added", "jobs_added", "extension"], "properties": {
                    "id": {"type": "string"}, "status": {"enum": ["running", "completed", "cancelled"]}, "trials": {"type": "integer"}, "points": {"type": "integer"},
                    "points_added": {"type": "integer"}, "jobs_added": {"type": "integer"}, "extension": {"type": "integer", "description": "1-based number of this extension"}}},
                "JobCounts": {"type": "object", "properties": {"queued": {"type": "integer"}, "leased": {"type": "integer"}, "done": {"type": "integer"}, "failed": {"type": "integer"}, "cancelled": {"type": "integer"}, "total": {"type": "integer"}}},
                "SearchStatus": {"type": "object", "properties": {
                    "id": {"type": "string"}, "name": {"type": "string"},
                    "status": {"enum": ["running", "completed", "cancelled"]},
                    "points": {"type": "integer"}, "trials": {"type": "integer"},
                    "jobs": r("JobCounts"),
                    "trials_converged": {"type": "integer"}, "trials_not_converged": {"type": "integer"},
                    "trials_with_shortfall": {"type": "integer"}, "workers_busy": {"type": "integer"},
                    "created_at": {"type": "string", "format": "date-time"},
                    "started_at": {"type": ["string", "null"], "format": "date-time"},
                    "finished_at": {"type": ["string", "null"], "format": "date-time"},
                    "eta_secs": num_opt, "convergence_threshold": {"type": "number"}
                }},
                "ProgressPoint": {"type": "object", "required": ["env_steps", "total_env_steps"], "properties": {
                    "env_steps": {"type": "integer", "minimum": 0, "description": "at most 2 x max(total_env_steps, 1)"}, "total_env_steps": {"type": "integer", "minimum": 0},
                    "mean_return": num_opt, "success_rate": {"type": ["number", "null"], "minimum": 0, "maximum": 1}, "mean_episode_length": num_opt,
                    "policy_loss": num_opt, "value_loss": num_opt, "entropy": num_opt, "approx_kl": num_opt
                }},
                "LeaseRequest": {"type": "object", "required": ["worker"], "additionalProperties": false, "properties": {
                    "worker": {"type": "string", "minLength": 1, "maxLength": 200, "pattern": "^[^\\x00-\\x1f\\x7f-\\x9f]*\\S[^\\x00-\\x1f\\x7f-\\x9f]*$", "description": "printable, not blank"}, "wait_secs": {"type": "integer", "minimum": 0, "maximum": 30, "default": 0}
                }},
                "JobSpec": {"type": "object", "properties": {
                    "search_id": {"type": "string"}, "search_name": {"type": "string"},
                    "point_idx": {"type": "integer"}, "params": {"type": "object", "additionalProperties": {"type": "number"}},
                    "trial": {"type": "integer"}, "seed": {"type": "integer"}, "attempt": {"type": "integer"},
                    "training": obj, "sampling": obj, "env": obj, "convergence_threshold": {"type": "number"},
                    "solver": {"type": "object", "description": "the solver variant to run (kind ppo with its training, or optimizer with its settings); absent: PPO with `training`"}
                }},
                "Lease": {"type": "object", "properties": {
                    "job_id": {"type": "integer"}, "lease_token": {"type": "string"},
                    "lease_secs": {"type": "integer"}, "heartbeat_secs": {"type": "integer"}, "spec": r("JobSpec")
                }},
                "Heartbeat": {"type": "object", "required": ["lease_token"], "additionalProperties": false, "properties": {
                    "lease_token": token.clone(), "phase": {"enum": ["training", "sampling"]},
                    "progress": {"type": "array", "maxItems": MAX_HEARTBEAT_POINTS, "items": r("ProgressPoint")}
                }},
                "HeartbeatAck": {"type": "object", "properties": {"lease_secs": {"type": "integer"}}},
                "EpisodeRecord": {"type": "object", "required": ["com_t", "com_x", "com_z", "return", "torque_usage", "steps"], "properties": {
                    "com_t": {"type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": MAX_EPISODE_POINTS, "description": "non-decreasing"}, "com_x": samples.clone(),
                    "com_z": samples, "return": {"type": "number"},
                    "torque_usage": {"type": "number", "minimum": 0}, "steps": count.clone()
                }},
                "JobOutput": {"type": "object", "additionalProperties": false, "required": ["final_success_rate", "env_steps", "successes_found", "successes_wanted", "sampling_attempts", "episodes"], "properties": {
                    "final_success_rate": {"type": "number", "minimum": 0, "maximum": 1},
                    "env_steps": {"type": "integer", "minimum": 0, "maximum": MAX_ENV_STEPS * 2}, "successes_found": count.clone(),
                    "successes_wanted": count.clone(), "sampling_attempts": count,
                    "episodes": {"type": "array", "items": r("EpisodeRecord"), "description": "at most top_k and at most successes_found"},
                    "train_secs": {"type": "number", "minimum": 0}, "sample_secs": {"type": "number", "minimum": 0}
                }},
                "ResultUpload": {"type": "object", "required": ["lease_token", "output"], "additionalProperties": false, "properties": {
                    "lease_token": token.clone(), "output": r("JobOutput")
                }},
                "ResultAck": {"type": "object", "properties": {"converged": {"type": "boolean"}, "replacement_enqueued": {"type": "boolean"}}},
                "FailReport": {"type": "object", "required": ["lease_token", "error"], "additionalProperties": false, "properties": {
                    "lease_token": token.clone(), "error": {"type": "string", "description": "kept up to 4000 characters"}
                }},
                "ReleaseRequest": {"type": "object", "required": ["lease_token"], "additionalProperties": false, "properties": {"lease_token": token}},
                "JobStateAck": {"type": "object", "properties": {"status": {"enum": ["queued", "leased", "done", "failed", "cancelled"]}}},
                "JobInfo": {"type": "object", "properties": {
                    "id": {"type": "integer"}, "search_id": {"type": "string"}, "point_idx": {"type": "integer"},
                    "params": {"type": "object"}, "trial": {"type": "integer"}, "seed": {"type": "integer"},
                    "variant": {"type": "integer", "description": "index of the job's solver variant in the search's solvers (0 without variants)"},
                    "status": {"enum": ["queued", "leased", "done", "failed", "cancelled"]},
                    "worker": {"type": ["string", "null"]}, "attempts": {"type": "integer"}, "lease_count": {"type": "integer"},
                    "last_error": {"type": ["string", "null"]}, "progress": {"oneOf": [r("ProgressPoint"), {"type": "null"}]},
                    "phase": {"enum": ["training", "sampling", null]}, "final_success_rate": num_opt,
                    "converged": {"type": ["boolean", "null"]}, "successes_found": {"type": ["integer", "null"]},
                    "successes_wanted": {"type": ["integer", "null"]}, "duration_secs": num_opt
                }},
                "JobDetail": {"allOf": [r("JobInfo"), {"type": "object", "properties": {"curve": {"type": "array", "items": r("ProgressPoint")}}}]},
                "ResultDocument": {"type": "object", "description": "shared::analysis::ResultDocument (as written by irlgrid analyze) plus search_id, status, partial and jobs", "properties": {
                    "search_id": {"type": "string"}, "status": {"enum": ["running", "completed", "cancelled"]},
                    "partial": {"type": "boolean"}, "jobs": r("JobCounts"),
                    "analysis_version": {"type": "integer"},
                    "weights": {"type": "array", "items": obj}, "subjects": {"type": "array", "items": obj, "description": "per subject: x, z, area and methods {area, correlation, posterior}, each with scores, probabilities, inferred_index, inferred; the posterior also credible_set and out_of_model"},
                    "identifiability": {"description": "leave-one-trial-out recovery and calibration per method (null until every point has 3 usable trials, or the search completes)"},
                    "notes": {"type": "array", "items": {"type": "string"}}
                }},
                "WeightInput": {"type": "object", "description": "shared::analysis::WeightInput: params and done trials with their episodes"}
            }
        },
        "paths": {
            (Endpoint::Healthz.template()): {"get": {"summary": "liveness and database check (a read and a one-row write)", "responses": {"200": ok("healthy", obj.clone()), "503": err("database unavailable: disk full, read-only, I/O error or locked (Retry-After set)")}}},
            (Endpoint::Metrics.template()): {"get": {"summary": "Prometheus metrics", "responses": {"200": {"description": "text/plain exposition format", "content": {"text/plain": {"schema": {"type": "string"}}}}}}},
            (Endpoint::OpenApi.template()): {"get": {"summary": "this document", "responses": {"200": ok("OpenAPI 3.1", obj.clone())}}},
            (Endpoint::ListSearches.template()): {
                "get": {"summary": "list searches, newest first", "responses": {"200": ok("searches", json!({"type": "array", "items": r("SearchStatus")}))}},
                "post": {"summary": "submit a search", "security": auth, "requestBody": body("SearchRequest"), "responses": {
                    "201": ok("created", r("Created")), "400": err("invalid field (named)"), "401": err("missing or wrong token"), "413": err("body too large")}}
            },
            (Endpoint::SearchStatus.template()): {"get": {"summary": "status, job counts, workers busy, times, ETA", "parameters": sid, "responses": {"200": ok("status", r("SearchStatus")), "404": err("unknown search")}}},
            (Endpoint::Cancel.template()): {"post": {"summary": "cancel: queued and leased jobs become cancelled; finished ones are kept", "security": auth, "parameters": sid, "responses": {
                "200": ok("cancelled", r("SearchStatus")), "401": err("missing or wrong token"), "404": err("unknown search"), "409": err("search already completed")}}},
            (Endpoint::Extend.template()): {"post": {"summary": "extend a running or completed search: raise trials per point and/or add grid values; existing jobs and results are kept, new jobs get the seeds of their (point, trial), the search runs again and its document is partial until they finish", "security": auth, "parameters": sid, "requestBody": body("ExtendRequest"), "responses": {
                "200": ok("extended", r("Extended")), "400": err("invalid field (named), a value already in the grid, fewer trials than now, a limit exceeded, or nothing to add"), "401": err("missing or wrong token"), "404": err("unknown search"), "409": err("search cancelled"), "413": err("body too large")}}},
            (Endpoint::Refine.template()): {"post": {"summary": "refine the grid toward the search's subjects: when the search has completed (at once if it has), every subject's best grid value and its more likely neighbour are read; their geometric midpoint is added where the pair is wider than target_ratio, for up to `rounds` rounds", "security": auth, "parameters": sid, "requestBody": body("RefineRequest"), "responses": {
                "200": ok("refinement", r("Refinement")), "400": err("invalid field (named), a grid of several parameters, or no subjects"), "401": err("missing or wrong token"), "404": err("unknown search"), "409": err("search cancelled"), "413": err("body too large")}}},
            (Endpoint::Refinement.template()): {"get": {"summary": "the refinement asked for and every round so far: per subject the estimate, the bracketing pair and the point it asked for", "parameters": sid, "responses": {"200": ok("refinement", r("Refinement")), "404": err("unknown search")}}},
            (Endpoint::Results.template()): {"get": {"summary": "result document (partial while running, final when completed)", "parameters": sid, "responses": {"200": ok("document", r("ResultDocument")), "404": err("unknown search")}}},
            (Endpoint::ResultsCsv.template()): {"get": {"summary": "per-weight statistics and subject cost matrices as tidy CSV", "parameters": sid, "responses": {
                "200": {"description": "CSV with header section,subject,param_value,trial,point,quantity,value", "content": {"text/csv": {"schema": {"type": "string"}}}}, "404": err("unknown search")}}},
            (Endpoint::SearchJobs.template()): {"get": {"summary": "every job with state, owner, attempts and latest progress", "parameters": sid, "responses": {"200": ok("jobs", json!({"type": "array", "items": r("JobInfo")})), "404": err("unknown search")}}},
            (Endpoint::Outputs.template()): {"get": {"summary": "aggregation input: every done trial's output by grid point", "parameters": sid, "responses": {"200": ok("inputs", json!({"type": "array", "items": r("WeightInput")})), "404": err("unknown search")}}},
            (Endpoint::ScoreSubjects.template()): {"post": {"summary": "score new subjects against the search's finished trials without running a job (every method, as in the result document); ?save=true also adds them to the search", "security": auth, "parameters": [sid[0].clone(), {"name": "save", "in": "query", "required": false, "schema": {"type": "boolean", "default": false}}, {"name": "observables", "in": "query", "required": false, "description": "score with this observable set instead of the search's own (docs/inference.md#observables)", "schema": {"type": "string", "enum": observables_enum}}],
                "requestBody": {"required": true, "content": {"text/csv": {"schema": {"type": "string", "description": "subject,time,x,z rows"}}, "application/json": {"schema": {"type": "object", "additionalProperties": false, "required": ["subjects_csv"], "properties": {"subjects_csv": {"type": "string"}}}}}},
                "responses": {"200": ok("scored subjects", obj.clone()), "400": err("bad CSV (line-precise) or query"), "401": err("missing or wrong token"), "404": err("unknown search"), "409": err("no converged trial yet, or a subject name already stored (save)"), "413": err("body too large")}}},
            (Endpoint::JobDetail.template()): {"get": {"summary": "one job with its learning curve", "parameters": jid, "responses": {"200": ok("job", r("JobDetail")), "400": err("bad id"), "404": err("unknown job")}}},
            (Endpoint::Lease.template()): {"post": {"summary": "lease the next job (fair across running searches); long-polls up to wait_secs", "security": auth, "requestBody": body("LeaseRequest"), "responses": {
                "200": ok("leased", r("Lease")), "204": {"description": "no job queued"}, "400": err("invalid body"), "401": err("missing or wrong token")}}},
            (Endpoint::Heartbeat.template()): {"post": {"summary": "renew the lease and report progress", "security": auth, "parameters": jid, "requestBody": body("Heartbeat"), "responses": hb}},
            (Endpoint::Result.template()): {"post": {"summary": "upload the output; the first valid upload under the current lease wins", "security": auth, "parameters": jid, "requestBody": body("ResultUpload"), "responses": res}},
            (Endpoint::Fail.template()): {"post": {"summary": "report a failure; retried until max_attempts, then failed", "security": auth, "parameters": jid, "requestBody": body("FailReport"), "responses": fail}},
            (Endpoint::Release.template()): {"post": {"summary": "hand the job back unfinished without using an attempt", "security": auth, "parameters": jid, "requestBody": body("ReleaseRequest"), "responses": rel}}
        }
    })
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    use super::*;

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
