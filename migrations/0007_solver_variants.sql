-- solver variants (docs/inference.md#solver-spread): every (point, trial,
-- variant) is one job. sqlite cannot change a table's unique constraint in
-- place, so jobs is rebuilt. The migration runs in one transaction with
-- foreign keys enforced, where the parent of job_results and job_progress
-- cannot be dropped while they hold rows: their rows wait in holding
-- tables while jobs is swapped, then go back (every id is kept, so every
-- reference holds again). Existing jobs are variant 0, the one solver of a
-- search that names none.
create table job_results_keep as select * from job_results;
create table job_progress_keep as select * from job_progress;
delete from job_results;
delete from job_progress;
create table jobs_new (
    id integer primary key autoincrement,
    search_id text not null references searches (id),
    point_idx integer not null,
    variant integer not null default 0,       -- index into the search's solver variants
    trial integer not null,                   -- 0-based within (point, variant); replacements continue it
    seed integer not null,                    -- derived from (base seed, point, trial, variant); u64 as i64
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
    unique (search_id, point_idx, variant, trial)
);
insert into jobs_new (id, search_id, point_idx, variant, trial, seed, status, worker_id,
    lease_token, lease_expires_at, attempts, max_attempts, lease_count, last_error, progress,
    phase, queued_at, leased_at, finished_at)
select id, search_id, point_idx, 0, trial, seed, status, worker_id, lease_token,
    lease_expires_at, attempts, max_attempts, lease_count, last_error, progress, phase,
    queued_at, leased_at, finished_at
from jobs;
drop table jobs;
alter table jobs_new rename to jobs;
create index jobs_by_search_status_attempts on jobs (search_id, status, attempts);
create index jobs_by_status_expiry on jobs (status, lease_expires_at);
insert into job_results select * from job_results_keep;
insert into job_progress select * from job_progress_keep;
drop table job_results_keep;
drop table job_progress_keep;
-- the autoincrement counter follows the copied ids, so a job id is never
-- reused.

-- searches: how many solver variants each (point, trial) runs as.
alter table searches add column variants integer not null default 1;
