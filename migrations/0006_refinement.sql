-- Adaptive refinement (`"refine"` in a search request, `POST
-- /api/v1/searches/{id}/refine`): when a refining search completes, the
-- coordinator reads every subject against the grid and adds the
-- midpoints they ask for, as an extension of the search.

-- The refinement asked for (shared::api::RefineSpec as json), null if none.
alter table searches add column refine text;
-- 'pending' while rounds may follow, 'settled' once refinement ended,
-- null if none was asked for.
alter table searches add column refine_state text;

-- Trials wanted at a point when it differs from the search's (points
-- added by refinement with their own trial count); null: the search's.
alter table points add column trials integer;

-- One row per evaluation of a refining search's grid, written in the same
-- transaction as the extension it caused (or the settling it decided).
create table refine_rounds (
    search_id text not null references searches (id),
    round integer not null,                   -- 0 = the grid as submitted
    subjects text not null,                   -- json [SubjectRefinement]
    added text not null,                      -- json [f64]: points added
    extension integer,                        -- search_extensions.seq, null if none
    stop text,                                -- why refinement ended here
    created_at integer not null,              -- unix ms
    primary key (search_id, round)
);
