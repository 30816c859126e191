-- The queue leases, within a search, the queued job with the fewest lost
-- attempts first, then the lowest id. This index serves that order (the
-- rowid id is its implicit last column) and every lookup by (search_id,
-- status) that the old index served.
drop index jobs_by_search_status;
create index jobs_by_search_status_attempts on jobs (search_id, status, attempts);
