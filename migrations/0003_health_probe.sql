-- One row that GET /healthz rewrites: a health check proves the database
-- still commits a write (a full disk, a read-only file or file system, an
-- I/O error answer 503), not only that it can be read.
create table health_probe (
    id integer primary key check (id = 1),
    checked_at integer not null
);
