-- jobs: one (point, trial) training run. a job is leased to one worker at a
-- time; the lease token is the capability every worker call must present.
create table jobs (
    id integer primary key autoincrement,
    search_id text not null references searches (id),
    point_idx integer not null,
    trial integer not null,                   -- 0-based; replacement trials continue the count
    seed integer not null,                    -- derived from (base seed, point, trial); u64 as i64
    status text not null
        check (status in ('queued', 'leased', 'done', 'failed', 'cancelled')),
    worker_id text,                           -- owner of the current or last lease
    lease_token text,                         -- random token of the current lease, null when none
    lease_expires_at integer,                 -- unix ms; extended by heartbeats
    attempts integer not null default 0,      -- leases lost (expired) or failed by the worker
    max_attempts integer not null,
    lease_count integer not null default 0,   -- leases granted in all
    last_error text,
    progress text,                            -- latest heartbeat progress point (json)
    phase text,                               -- 'training' | 'sampling', from the latest heartbeat
    queued_at integer not null,
    leased_at integer,                        -- start of the current or last lease
    finished_at integer,
    unique (search_id, point_idx, trial)
);
create index jobs_by_search_status on jobs (search_id, status);
create index jobs_by_status_expiry on jobs (status, lease_expires_at);

-- job_progress: bounded learning-curve history of a job's current attempt
-- (thinned to every other point when it grows past its cap).
create table job_progress (
    job_id integer not null references jobs (id),
    seq integer not null,                     -- increasing within the job
    progress text not null,                   -- json TrainProgress
    primary key (job_id, seq)
) without rowid;

-- job_results: the single accepted upload of a done job.
create table job_results (
    job_id integer primary key not null references jobs (id),
    worker_id text not null,
    final_success_rate real not null,
    converged integer not null,               -- 0/1: final_success_rate >= search threshold
    successes_found integer not null,
    successes_wanted integer not null,        -- shortfall = wanted - found
    env_steps integer not null,
    output text not null,                     -- json JobOutput as uploaded
    uploaded_at integer not null
);
