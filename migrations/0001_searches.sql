-- searches: one submitted reward-parameter search (a grid of points x trials)
-- with its fully resolved configuration, so every result is reproducible.
create table searches (
    id text primary key not null,             -- uuid v4, the public id
    seq integer not null unique,              -- submission order; breaks fairness ties
    name text not null,
    status text not null
        check (status in ('running', 'completed', 'cancelled')),
    request text not null,                    -- the request body as submitted (json)
    config text not null,                     -- resolved training/sampling/env/options (json)
    trials integer not null,                  -- converged trials wanted per point
    base_seed integer not null,               -- u64 stored as its i64 bit pattern
    convergence_threshold real not null,      -- final success rate needed to count as converged
    replace_unconverged integer not null,     -- 0/1: enqueue replacement trials
    max_trials_per_point integer not null,    -- cap on trials per point, replacements included
    max_attempts integer not null,            -- leases a job may lose before it fails
    subjects_csv text,                        -- validated subject trajectories, if any
    created_at integer not null,              -- unix ms
    started_at integer,                       -- first lease, unix ms
    finished_at integer,                      -- completed or cancelled, unix ms
    final_document text                       -- cached result document once completed (json)
);

-- points: the cartesian product of the reward grid, in submission order.
create table points (
    search_id text not null references searches (id),
    idx integer not null,                     -- 0-based position in the grid's product
    params text not null,                     -- json object: parameter name -> value
    primary key (search_id, idx)
);
