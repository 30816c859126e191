-- trial_summaries: the digest of each accepted output (json
-- shared::analysis::TrialDigest: the 60-point mean paths, area, torque
-- usage, counts, the top episode's path, return and timing), written in
-- the transaction that accepts the output. Result documents, partial
-- documents, dashboard pages and subject scoring are built from these
-- rows alone; only /outputs reads job_results.output. The job's facts are
-- copied beside the digest so that a search's digests are one index range.
create table trial_summaries (
    job_id integer primary key not null references job_results (job_id),
    search_id text not null,
    point_idx integer not null,
    variant integer not null,
    trial integer not null,
    seed integer not null,                    -- u64 stored as its i64 bit pattern
    converged integer not null,               -- 0/1, as in job_results
    digest text not null                      -- json TrialDigest
);
create index trial_summaries_by_search on trial_summaries (search_id, point_idx, variant, trial);

-- job_results.output changes encoding without a table rebuild: new rows
-- hold a blob (coordinator store::codec: "irz1" then zstd of the output's
-- fields and its XOR-delta trajectories), rows from before hold the JSON
-- text. SQLite keeps a blob as it is in a column of any declared type, so
-- `typeof(output)` tells them apart. Rows of older databases get their
-- summary and their compressed output at start-up (store::backfill), in
-- batches, before the coordinator serves.
