//! Consistent online backups of the coordinator's database.

use std::path::Path;

use anyhow::{bail, Context};
use sqlx::Connection;

/// Writes a consistent copy of the database at `db` to `out` with SQLite's
/// `VACUUM INTO`, which reads one snapshot (WAL included) and is safe while
/// the coordinator keeps writing. Refuses to overwrite an existing file.
pub async fn backup(db: &Path, out: &Path) -> anyhow::Result<()> {
    if !db.is_file() {
        bail!("{}: no such database file", db.display());
    }
    if out.exists() {
        bail!(
            "{}: already exists (a backup never overwrites)",
            out.display()
        );
    }
    let opts = sqlx::sqlite::SqliteConnectOptions::new()
        .filename(db)
        .read_only(true)
        .busy_timeout(std::time::Duration::from_secs(30));
    let mut conn = sqlx::SqliteConnection::connect_with(&opts)
        .await
        .with_context(|| format!("opening {}", db.display()))?;
    let target = out
        .to_str()
        .with_context(|| format!("{}: path is not valid UTF-8", out.display()))?;
    sqlx::query("vacuum into ?")
        .bind(target)
        .execute(&mut conn)
        .await
        .with_context(|| format!("writing backup {}", out.display()))?;
    let (check,): (String,) = sqlx::query_as("select integrity_check from pragma_integrity_check")
        .fetch_one(
            &mut sqlx::SqliteConnection::connect_with(
                &sqlx::sqlite::SqliteConnectOptions::new()
                    .filename(out)
                    .read_only(true),
            )
            .await?,
        )
        .await
        .context("checking the backup")?;
    if check != "ok" {
        bail!(
            "backup {} failed its integrity check: {check}",
            out.display()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn backup_copies_rows_and_refuses_to_overwrite() {
        let dir = tempfile::tempdir().unwrap();
        let db = dir.path().join("live.db");
        let opts = sqlx::sqlite::SqliteConnectOptions::new()
            .filename(&db)
            .create_if_missing(true)
            .journal_mode(sqlx::sqlite::SqliteJournalMode::Wal);
        let mut conn = sqlx::SqliteConnection::connect_with(&opts).await.unwrap();
        sqlx::query("create table t (x integer)")
            .execute(&mut conn)
            .await
            .unwrap();
        sqlx::query("insert into t values (42)")
            .execute(&mut conn)
            .await
            .unwrap();
        // The writer stays open: the rows live in the WAL, as in production.
        let out = dir.path().join("copy.db");
        backup(&db, &out).await.unwrap();
        let mut copy = sqlx::SqliteConnection::connect_with(
            &sqlx::sqlite::SqliteConnectOptions::new().filename(&out),
        )
        .await
        .unwrap();
        let (x,): (i64,) = sqlx::query_as("select x from t")
            .fetch_one(&mut copy)
            .await
            .unwrap();
        assert_eq!(x, 42);
        assert!(backup(&db, &out)
            .await
            .unwrap_err()
            .to_string()
            .contains("already exists"));
        assert!(
            backup(&dir.path().join("nope.db"), &dir.path().join("b.db"))
                .await
                .is_err()
        );
    }
}
