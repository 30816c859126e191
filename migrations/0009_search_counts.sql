-- search_counts: a search's jobs by state and its results' tallies, kept
-- by triggers in the transaction of every change they count, so that a
-- search's status is one row read whatever its size. The queries they
-- replace counted every job and every result of the search on each status
-- read (every API status, result document and dashboard page asks for it).
-- Jobs and results are never deleted while the service runs; the delete
-- triggers keep the counts right if a later migration does.
create table search_counts (
    search_id text primary key not null references searches (id),
    queued integer not null default 0,
    leased integer not null default 0,
    done integer not null default 0,
    failed integer not null default 0,
    cancelled integer not null default 0,
    done_ms_sum integer not null default 0,   -- sum of finished_at - leased_at over done jobs with both
    done_ms_n integer not null default 0,     -- how many done jobs have both
    results integer not null default 0,       -- accepted outputs (job_results rows)
    converged integer not null default 0,     -- of which converged
    shortfall integer not null default 0      -- of which found fewer successes than wanted
);

insert into search_counts (search_id, queued, leased, done, failed, cancelled, done_ms_sum,
    done_ms_n, results, converged, shortfall)
select s.id,
    (select count(*) from jobs j where j.search_id = s.id and j.status = 'queued'),
    (select count(*) from jobs j where j.search_id = s.id and j.status = 'leased'),
    (select count(*) from jobs j where j.search_id = s.id and j.status = 'done'),
    (select count(*) from jobs j where j.search_id = s.id and j.status = 'failed'),
    (select count(*) from jobs j where j.search_id = s.id and j.status = 'cancelled'),
    (select coalesce(sum(j.finished_at - j.leased_at), 0) from jobs j
      where j.search_id = s.id and j.status = 'done'),
    (select count(j.finished_at - j.leased_at) from jobs j
      where j.search_id = s.id and j.status = 'done'),
    (select count(*) from job_results r join jobs j on j.id = r.job_id where j.search_id = s.id),
    (select coalesce(sum(r.converged), 0) from job_results r
      join jobs j on j.id = r.job_id where j.search_id = s.id),
    (select count(*) from job_results r join jobs j on j.id = r.job_id
      where j.search_id = s.id and r.successes_found < r.successes_wanted)
from searches s;

create trigger search_counts_new_search after insert on searches begin
    insert into search_counts (search_id) values (new.id);
end;

create trigger search_counts_new_job after insert on jobs begin
    update search_counts set
        queued = queued + (new.status = 'queued'),
        leased = leased + (new.status = 'leased'),
        done = done + (new.status = 'done'),
        failed = failed + (new.status = 'failed'),
        cancelled = cancelled + (new.status = 'cancelled'),
        done_ms_sum = done_ms_sum + (case when new.status = 'done'
            then coalesce(new.finished_at - new.leased_at, 0) else 0 end),
        done_ms_n = done_ms_n + (new.status = 'done'
            and new.finished_at is not null and new.leased_at is not null)
    where search_id = new.search_id;
end;

-- Fires only when a counted column changes (a heartbeat changes none).
create trigger search_counts_job_changed after update of status, leased_at, finished_at on jobs
begin
    update search_counts set
        queued = queued - (old.status = 'queued') + (new.status = 'queued'),
        leased = leased - (old.status = 'leased') + (new.status = 'leased'),
        done = done - (old.status = 'done') + (new.status = 'done'),
        failed = failed - (old.status = 'failed') + (new.status = 'failed'),
        cancelled = cancelled - (old.status = 'cancelled') + (new.status = 'cancelled'),
        done_ms_sum = done_ms_sum
            - (case when old.status = 'done' then coalesce(old.finished_at - old.leased_at, 0)
                else 0 end)
            + (case when new.status = 'done' then coalesce(new.finished_at - new.leased_at, 0)
                else 0 end),
        done_ms_n = done_ms_n
            - (old.status = 'done' and old.finished_at is not null and old.leased_at is not null)
            + (new.status = 'done' and new.finished_at is not null and new.leased_at is not null)
    where search_id = new.search_id;
end;

create trigger search_counts_job_deleted after delete on jobs begin
    update search_counts set
        queued = queued - (old.status = 'queued'),
        leased = leased - (old.status = 'leased'),
        done = done - (old.status = 'done'),
        failed = failed - (old.status = 'failed'),
        cancelled = cancelled - (old.status = 'cancelled'),
        done_ms_sum = done_ms_sum - (case when old.status = 'done'
            then coalesce(old.finished_at - old.leased_at, 0) else 0 end),
        done_ms_n = done_ms_n - (old.status = 'done'
            and old.finished_at is not null and old.leased_at is not null)
    where search_id = old.search_id;
end;

create trigger search_counts_new_result after insert on job_results begin
    update search_counts set
        results = results + 1,
        converged = converged + new.converged,
        shortfall = shortfall + (new.successes_found < new.successes_wanted)
    where search_id = (select search_id from jobs where id = new.job_id);
end;

create trigger search_counts_result_deleted after delete on job_results begin
    update search_counts set
        results = results - 1,
        converged = converged - old.converged,
        shortfall = shortfall - (old.successes_found < old.successes_wanted)
    where search_id = (select search_id from jobs where id = old.job_id);
end;
