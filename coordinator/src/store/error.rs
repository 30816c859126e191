//! What the store can fail with, in its own terms: the rows a call needs
//! are missing, the call conflicts with their state (a stale lease, a
//! cancelled or completed search), the data refuses it (a point already in
//! the grid, an extension that adds nothing), the database cannot serve it
//! now (busy, locked, read-only, full, failing disk), or anything else.
//!
//! The database drivers' errors are classified here, once: a storage fault
//! ([`storage_fault`]) is [`StoreError::Unavailable`], everything else
//! (constraints, corruption, misuse) [`StoreError::Internal`]. The HTTP
//! layer maps these to answers (`crate::error`).

/// A failed store call.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// Unknown search or job; the message names it.
    #[error("{0}")]
    NotFound(String),
    /// The call conflicts with the current state: a lease that is not
    /// current, a job already done, a search cancelled or completed.
    #[error("{0}")]
    Conflict(String),
    /// The stored data refuses the change (a point already in the grid, an
    /// extension that adds no job); the message names the field.
    #[error("{0}")]
    Invalid(String),
    /// The database cannot take the call now (disk full, read-only file
    /// system or file, I/O error, locked past the busy timeout, no
    /// connection free); the message says what the storage reported.
    #[error("{0}")]
    Unavailable(String),
    /// Anything else (a constraint, corruption, a stored value that no
    /// longer parses, the writer thread gone).
    #[error(transparent)]
    Internal(anyhow::Error),
}

/// The result of a store call.
pub type StoreResult<T> = Result<T, StoreError>;

impl StoreError {
    /// An internal error with a message.
    pub fn internal(msg: impl std::fmt::Display) -> Self {
        Self::Internal(anyhow::anyhow!("{msg}"))
    }
}

/// What a SQLite result code (primary or extended) says about the storage
/// when it means "the database cannot serve this now" rather than "the
/// request is wrong" or "a bug": `SQLITE_BUSY`, `SQLITE_LOCKED`,
/// `SQLITE_READONLY`, `SQLITE_IOERR`, `SQLITE_FULL`, `SQLITE_CANTOPEN`.
/// Everything else (constraints, corruption, misuse) is internal.
pub fn storage_fault(code: i32) -> Option<&'static str> {
    match code & 0xff {
        5 => Some("database is busy (SQLITE_BUSY)"),
        6 => Some("database table is locked (SQLITE_LOCKED)"),
        8 => Some("database is read-only (SQLITE_READONLY)"),
        10 => Some("disk I/O error (SQLITE_IOERR)"),
        13 => Some("database or disk is full (SQLITE_FULL)"),
        14 => Some("cannot open the database file (SQLITE_CANTOPEN)"),
        _ => None,
    }
}

fn unavailable(what: &str, detail: &str) -> StoreError {
    StoreError::Unavailable(format!(
        "database unavailable: {what}: {detail}; retry later"
    ))
}

fn sqlx_fault(e: &sqlx::Error) -> Option<StoreError> {
    match e {
        sqlx::Error::Database(d) => {
            let code = d.code().and_then(|c| c.parse::<i32>().ok());
            code.and_then(storage_fault)
                .map(|what| unavailable(what, d.message()))
        }
        sqlx::Error::Io(io) => Some(unavailable("I/O error", &io.to_string())),
        sqlx::Error::PoolTimedOut => {
            Some(unavailable("no database connection free", "pool timed out"))
        }
        _ => None,
    }
}

fn rusqlite_fault(e: &rusqlite::Error) -> Option<StoreError> {
    match e {
        rusqlite::Error::SqliteFailure(f, msg) => storage_fault(f.extended_code).map(|what| {
            let detail = msg.clone().unwrap_or_else(|| f.to_string());
            unavailable(what, &detail)
        }),
        _ => None,
    }
}

impl From<sqlx::Error> for StoreError {
    fn from(e: sqlx::Error) -> Self {
        sqlx_fault(&e).unwrap_or_else(|| Self::Internal(anyhow::Error::new(e).context("database")))
    }
}

impl From<&rusqlite::Error> for StoreError {
    fn from(e: &rusqlite::Error) -> Self {
        rusqlite_fault(e)
            .unwrap_or_else(|| Self::Internal(anyhow::anyhow!("{e}").context("database")))
    }
}

impl From<rusqlite::Error> for StoreError {
    fn from(e: rusqlite::Error) -> Self {
        Self::from(&e)
    }
}

/// An error from code that returns `anyhow` is unavailable when a database
/// storage fault is anywhere in its chain, internal otherwise.
impl From<anyhow::Error> for StoreError {
    fn from(e: anyhow::Error) -> Self {
        for cause in e.chain() {
            let fault = cause
                .downcast_ref::<sqlx::Error>()
                .and_then(sqlx_fault)
                .or_else(|| {
                    cause
                        .downcast_ref::<rusqlite::Error>()
                        .and_then(rusqlite_fault)
                });
            if let Some(fault) = fault {
                return fault;
            }
        }
        Self::Internal(e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn storage_codes_are_unavailable_and_the_rest_internal() {
        // Primary and extended codes: BUSY, LOCKED, READONLY,
        // READONLY_DBMOVED, IOERR, IOERR_WRITE, IOERR_FSYNC, FULL, CANTOPEN.
        for code in [5, 6, 8, 1032, 10, 778, 1034, 13, 14] {
            assert!(storage_fault(code).is_some(), "{code}");
        }
        // ERROR, CORRUPT, CONSTRAINT, CONSTRAINT_UNIQUE, MISUSE.
        for code in [1, 11, 19, 2067, 21] {
            assert!(storage_fault(code).is_none(), "{code}");
        }
    }
}
