-- Searches that grow: `POST /api/v1/searches/{id}/extend` adds
-- trials per point and grid points to a search after submission. The
-- submitted request stays as it was; every extension is recorded here.
create table search_extensions (
    search_id text not null references searches (id),
    seq integer not null,                     -- 1, 2, ... within the search
    request text not null,                    -- the extend request as received (json)
    trials_before integer not null,
    trials_after integer not null,
    points_added integer not null,
    jobs_added integer not null,
    created_at integer not null,              -- unix ms
    primary key (search_id, seq)
);

-- Which extension added a point (search_extensions.seq); null for the
-- points submitted with the search.
alter table points add column extension integer;

-- A grid point appears once per search, however it was added (params is
-- the canonical JSON text serde_json writes for the point's map).
create unique index points_by_params on points (search_id, params);
