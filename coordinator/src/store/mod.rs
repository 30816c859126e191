//! The store: every SQL statement of the coordinator, over one SQLite file
//! in WAL mode. One write path: every write is an operation of the
//! group-committing writer thread ([`writer`]), with one lease check, one
//! job insert and one attempts rule ([`queue`]). Reads go through a pool
//! of sqlx reader connections (WAL readers do not block the writer).
//! Migrations run once at start-up, before the writer starts.
//!
//! - [`queue`]: searches and jobs, their state changes and status reads;
//! - [`reads`]: the dashboard's paged lists and the few lookups the routes
//!   and start-up need;
//! - [`backup`]: consistent online copies;
//! - [`codec`]: how an accepted output is stored;
//! - [`states`]: the stored states as Rust reads them;
//! - [`backfill`]: summaries and compact outputs for rows stored before them;
//! - [`error`]: what a store call fails with ([`StoreError`]), and the one
//!   classification of the drivers' errors.

pub mod backfill;
pub mod backup;
pub mod codec;
pub mod error;
pub mod queue;
pub mod reads;
pub mod states;
pub(crate) mod writer;

#[cfg(test)]
mod error_tests;

use std::path::Path;
use std::str::FromStr;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use anyhow::Context;
use sqlx::sqlite::{SqliteConnectOptions, SqliteJournalMode, SqlitePoolOptions, SqliteSynchronous};
use sqlx::SqlitePool;

pub use error::{StoreError, StoreResult};
pub use writer::WriterPragma;

/// The embedded migrations (`migrations/` at the workspace root).
pub static MIGRATOR: sqlx::migrate::Migrator = sqlx::migrate!("../migrations");

/// The store over one database file.
#[derive(Debug, Clone)]
pub struct Db {
    /// Read-only queries.
    pub read: SqlitePool,
    /// The one writer: a thread with its own connection that commits
    /// operations in groups.
    pub(crate) writer: writer::Writer,
}

impl Db {
    /// Opens (creating if needed) and migrates the database at `path`.
    pub async fn open(path: &Path) -> anyhow::Result<Self> {
        let opts = SqliteConnectOptions::from_str("sqlite:")
            .context("sqlite options")?
            .filename(path)
            .create_if_missing(true)
            .journal_mode(SqliteJournalMode::Wal)
            // In WAL mode NORMAL loses nothing when the process dies; only
            // an OS crash or power loss can drop the last commits.
            .synchronous(SqliteSynchronous::Normal)
            .busy_timeout(Duration::from_secs(10))
            .foreign_keys(true)
            .pragma("temp_store", "memory")
            .pragma("cache_size", "-16000");
        // Migrations need sqlx's migrator. Its connection stays open until
        // the writer thread holds its own (a read-only reader cannot open a
        // WAL database whose last connection has just removed the WAL
        // files), then closes: from then on the writer is alone.
        let migrate = SqlitePoolOptions::new()
            .max_connections(1)
            .connect_with(opts.clone())
            .await
            .with_context(|| format!("opening database {}", path.display()))?;
        MIGRATOR
            .run(&migrate)
            .await
            .with_context(|| format!("migrating database {}", path.display()))?;
        let writer = writer::Writer::start(path)
            .with_context(|| format!("starting the writer for {}", path.display()))?;
        migrate.close().await;
        let read = SqlitePoolOptions::new()
            .max_connections(4)
            .test_before_acquire(false)
            .acquire_timeout(Duration::from_secs(30))
            .connect_with(opts.read_only(true))
            .await
            .with_context(|| format!("opening database {} for reading", path.display()))?;
        let db = Self { read, writer };
        let n = backfill::run(&db)
            .await
            .with_context(|| format!("summarising the stored outputs of {}", path.display()))?;
        if n > 0 {
            tracing::info!(outputs = n, "stored outputs summarised and compressed");
        }
        Ok(db)
    }

    /// Runs one pragma on the writer's connection, outside any transaction,
    /// and returns its value if it has one. For the storage fault tests,
    /// which pin the writer read-only or full.
    pub async fn writer_pragma(&self, p: WriterPragma) -> StoreResult<Option<i64>> {
        self.writer.pragma(p).await
    }

    /// Closes the readers, then stops the writer (finishing its queued
    /// operations). The writer goes last: only a read-write connection can
    /// checkpoint the WAL into the file when the last connection closes.
    pub async fn close(&self) {
        self.read.close().await;
        self.writer.close();
    }
}

/// Milliseconds since the Unix epoch.
pub fn now_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_millis() as i64)
        .unwrap_or(0)
}

/// RFC 3339 UTC text of a Unix time in milliseconds (civil-from-days,
/// H. Hinnant's algorithm).
pub fn rfc3339(ms: i64) -> String {
    let secs = ms.div_euclid(1000);
    let millis = ms.rem_euclid(1000);
    let days = secs.div_euclid(86_400);
    let sod = secs.rem_euclid(86_400);
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}.{millis:03}Z",
        sod / 3600,
        sod / 60 % 60,
        sod % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rfc3339_formats_known_instants() {
        assert_eq!(rfc3339(0), "1970-01-01T00:00:00.000Z");
        assert_eq!(rfc3339(951_782_400_123), "2000-02-29T00:00:00.123Z");
        assert_eq!(rfc3339(1_700_000_000_000), "2023-11-14T22:13:20.000Z");
    }

    #[tokio::test]
    async fn open_creates_schema_in_wal_mode_and_reopens() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.db");
        let db = Db::open(&path).await.unwrap();
        let mode: String = sqlx::query_scalar("pragma journal_mode")
            .fetch_one(&db.read)
            .await
            .unwrap();
        assert_eq!(mode, "wal");
        let n: i64 = sqlx::query_scalar("select count(*) from jobs")
            .fetch_one(&db.read)
            .await
            .unwrap();
        assert_eq!(n, 0);
        db.close().await;
        let db = Db::open(&path).await.unwrap();
        db.close().await;
    }
}
