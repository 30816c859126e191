//! The SQLite database: WAL mode, a busy timeout, migrations at start-up,
//! two writers and a pool of readers. The lease cycle (claim, upload,
//! failure, expiry sweep) writes through the group-committing rusqlite
//! thread (`queue::writer`); the rarer writes go through one sqlx
//! connection. The two take SQLite's write lock up front (`begin
//! immediate`), so they queue on its busy timeout rather than fail.

use std::path::Path;
use std::str::FromStr;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use anyhow::Context;
use sqlx::sqlite::{SqliteConnectOptions, SqliteJournalMode, SqlitePoolOptions, SqliteSynchronous};
use sqlx::SqlitePool;

/// The embedded migrations (`migrations/` at the workspace root).
pub static MIGRATOR: sqlx::migrate::Migrator = sqlx::migrate!("../migrations");

/// Connection pools over one database file.
#[derive(Debug, Clone)]
pub struct Db {
    /// The sqlx connection for the writes outside the lease cycle
    /// (submissions, heartbeats, releases, cancels, cached documents); each
    /// is one transaction on it.
    pub write: SqlitePool,
    /// Read-only queries (WAL readers do not block the writer).
    pub read: SqlitePool,
    /// The group-committing writer thread of the lease cycle
    /// (`queue::writer`).
    pub(crate) writer: crate::queue::writer::Writer,
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
        let write = SqlitePoolOptions::new()
            .max_connections(1)
            .min_connections(1)
            // Keep the one writer connection for the life of the pool.
            .max_lifetime(None)
            .idle_timeout(None)
            // A ping per acquire is a round trip to the connection thread.
            .test_before_acquire(false)
            // SQLite rolls a transaction back by itself on some errors
            // (SQLITE_FULL, SQLITE_IOERR, ...); sqlx's own rollback then
            // fails and the connection believes it is still in a
            // transaction, refusing every later `begin` ("non-zero
            // transaction depth"). Replace such a connection, so writes work
            // again once the disk has space.
            .before_acquire(|conn, _meta| {
                Box::pin(async move {
                    use sqlx::Connection;
                    if !conn.is_in_transaction() {
                        return Ok(true);
                    }
                    // Let the rollback queued by a dropped transaction run.
                    conn.ping().await?;
                    if conn.is_in_transaction() {
                        tracing::warn!(
                            "database writer connection stuck in a transaction SQLite rolled back; reopening it"
                        );
                        return Ok(false);
                    }
                    Ok(true)
                })
            })
            .acquire_timeout(Duration::from_secs(30))
            .connect_with(opts.clone())
            .await
            .with_context(|| format!("opening database {}", path.display()))?;
        MIGRATOR
            .run(&write)
            .await
            .with_context(|| format!("migrating database {}", path.display()))?;
        let read = SqlitePoolOptions::new()
            .max_connections(4)
            .test_before_acquire(false)
            .acquire_timeout(Duration::from_secs(30))
            .connect_with(opts.read_only(true))
            .await
            .with_context(|| format!("opening database {} for reading", path.display()))?;
        Ok(Self {
            write,
            read,
            writer: crate::queue::writer::Writer::start(path)
                .with_context(|| format!("starting the writer for {}", path.display()))?,
        })
    }

    /// Closes both pools (checkpointing the WAL when the last connection
    /// goes).
    pub async fn close(&self) {
        self.writer.close();
        self.read.close().await;
        self.write.close().await;
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
            .fetch_one(&db.write)
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
