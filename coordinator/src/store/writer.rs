//! The one write path of the store: a dedicated writer thread that owns its
//! own `rusqlite` connection and commits in groups: it takes every operation waiting in its queue (up to
//! [`MAX_BATCH`]), runs each inside a savepoint of one transaction (a failed
//! operation rolls back alone), commits once, and only then answers. sqlx
//! would run each statement as a round trip to its connection thread and
//! commit each operation separately; under load this cuts both the thread
//! hops and the commits by the batch size. It is the only connection that
//! writes, so its transactions never wait on another writer's lock (the
//! docs/performance.md#queue-overhead has the bench figures behind this choice).

use std::collections::VecDeque;
use std::path::Path;
use std::sync::mpsc;

use rusqlite::Transaction;

use super::error::{StoreError, StoreResult};

/// Most operations committed together.
pub const MAX_BATCH: usize = 128;

/// How an operation's group ended.
enum Outcome<'a> {
    /// Committed: the operation's own answer stands.
    Committed,
    /// Begin or commit failed with this error; nothing of the group is kept.
    Failed(&'a rusqlite::Error),
    /// SQLite rolled the group's transaction back after another operation's
    /// storage error; nothing of the group is kept.
    RolledBack,
}

/// Answers an operation once its group has ended.
type Deliver = Box<dyn FnOnce(Outcome<'_>) + Send>;
/// Runs an operation in the group's transaction, or answers at once with the
/// error that kept the transaction (or the operation's savepoint) from
/// starting.
type Op = Box<dyn FnOnce(Result<&Transaction<'_>, &rusqlite::Error>) -> Deliver + Send>;

enum Msg {
    Op(Op),
    /// A pragma to run between groups, outside any transaction.
    Pragma(
        WriterPragma,
        tokio::sync::oneshot::Sender<StoreResult<Option<i64>>>,
    ),
    Close(std::sync::mpsc::Sender<()>),
}

/// The pragmas that may be run on the writer's connection from outside
/// (the storage fault tests pin it read-only or full with them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WriterPragma {
    /// `query_only`: refuse every write (as a read-only file system does).
    QueryOnly(bool),
    /// `max_page_count`: with `true`, pin the file at the pages it has
    /// (SQLite never sets the cap below the file's size, so a cap of 1 pins
    /// it there), as a full disk does; with `false`, lift the cap. The
    /// answer is the cap SQLite applied.
    Full(bool),
    /// `page_count`: the file's pages now.
    PageCount,
}

/// Handle of the writer thread.
#[derive(Debug, Clone)]
pub struct Writer {
    tx: mpsc::Sender<Msg>,
}

impl std::fmt::Debug for Msg {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Msg")
    }
}

impl Writer {
    /// Opens `path` (already migrated) on a new writer thread.
    pub fn start(path: &Path) -> anyhow::Result<Self> {
        let conn = rusqlite::Connection::open(path)?;
        conn.busy_timeout(std::time::Duration::from_secs(10))?;
        conn.pragma_update(None, "synchronous", "NORMAL")?;
        conn.pragma_update(None, "foreign_keys", "ON")?;
        conn.set_prepared_statement_cache_capacity(32);
        let (tx, rx) = mpsc::channel::<Msg>();
        std::thread::Builder::new()
            .name("irlgrid-writer".into())
            .spawn(move || run(conn, rx))?;
        Ok(Self { tx })
    }

    /// Runs one pragma on the writer's connection between two groups.
    pub async fn pragma(&self, p: WriterPragma) -> StoreResult<Option<i64>> {
        let (reply, answer) = tokio::sync::oneshot::channel();
        self.tx
            .send(Msg::Pragma(p, reply))
            .map_err(|_| StoreError::internal("database writer has stopped"))?;
        answer
            .await
            .map_err(|_| StoreError::internal("database writer dropped a pragma"))?
    }

    /// Stops the thread and closes its connection (pending operations are
    /// finished first).
    pub fn close(&self) {
        let (done, wait) = mpsc::channel();
        if self.tx.send(Msg::Close(done)).is_ok() {
            let _ = wait.recv();
        }
    }
}

fn run(mut conn: rusqlite::Connection, rx: mpsc::Receiver<Msg>) {
    let mut close: Option<mpsc::Sender<()>> = None;
    // Operations of a group that SQLite rolled back before they ran.
    let mut carry: VecDeque<Op> = VecDeque::new();
    while close.is_none() || !carry.is_empty() {
        let mut ops = std::mem::take(&mut carry);
        if ops.is_empty() {
            let Ok(first) = rx.recv() else { return };
            match first {
                Msg::Op(op) => ops.push_back(op),
                Msg::Pragma(p, reply) => {
                    let _ = reply.send(run_pragma(&conn, &p));
                }
                Msg::Close(c) => close = Some(c),
            }
        }
        while close.is_none() && ops.len() < MAX_BATCH {
            match rx.try_recv() {
                Ok(Msg::Op(op)) => ops.push_back(op),
                Ok(Msg::Pragma(p, reply)) => {
                    let _ = reply.send(run_pragma(&conn, &p));
                }
                Ok(Msg::Close(c)) => close = Some(c),
                Err(_) => break,
            }
        }
        if ops.is_empty() {
            continue;
        }
        let tx = match conn.transaction_with_behavior(rusqlite::TransactionBehavior::Immediate) {
            Ok(tx) => tx,
            Err(e) => {
                // Each operation answers with the error (503 for a full,
                // read-only or failing disk, a lock held too long).
                tracing::error!(error = %e, "writer: begin failed");
                for op in ops {
                    op(Err(&e))(Outcome::Failed(&e));
                }
                continue;
            }
        };
        let mut delivers = Vec::with_capacity(ops.len());
        let mut rolled_back = false;
        while let Some(op) = ops.pop_front() {
            if let Err(e) = tx.execute_batch("savepoint op") {
                delivers.push(op(Err(&e)));
            } else {
                // A panicking operation answers with an error (its reply is
                // dropped) and is rolled back; the thread lives on.
                match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| op(Ok(&tx)))) {
                    Ok(d) => delivers.push(d),
                    Err(_) => {
                        tracing::error!("writer: operation panicked; rolled back");
                        let _ = tx.execute_batch("rollback to op; release op");
                    }
                }
            }
            // SQLite rolls the whole transaction back itself on some errors
            // (SQLITE_FULL, SQLITE_IOERR, ...). The group's earlier changes
            // are gone, and a later operation would run outside any
            // transaction: stop here, answer the group, and run the rest in
            // a fresh transaction.
            if tx.is_autocommit() {
                rolled_back = true;
                break;
            }
        }
        if rolled_back {
            tracing::error!(
                answered = delivers.len(),
                carried = ops.len(),
                "writer: a storage error rolled back the group's transaction"
            );
            drop(tx);
            for d in delivers {
                d(Outcome::RolledBack);
            }
            carry = ops;
            continue;
        }
        let failed = match tx.commit() {
            Ok(()) => None,
            Err(e) => {
                // The transaction is rolled back when `tx` drops: none of
                // the group's changes is kept, and each operation says so.
                tracing::error!(error = %e, "writer: commit failed");
                Some(e)
            }
        };
        for d in delivers {
            match &failed {
                None => d(Outcome::Committed),
                Some(e) => d(Outcome::Failed(e)),
            }
        }
    }
    drop(conn);
    if let Some(c) = close {
        let _ = c.send(());
    }
}

/// Sets or reads one pragma of the writer's connection.
fn run_pragma(conn: &rusqlite::Connection, p: &WriterPragma) -> StoreResult<Option<i64>> {
    match *p {
        WriterPragma::QueryOnly(on) => conn.pragma_update(None, "query_only", on).map(|_| None),
        WriterPragma::Full(full) => {
            let cap: i64 = if full { 1 } else { 1_073_741_823 };
            conn.pragma_update_and_check(None, "max_page_count", cap, |r| r.get(0))
                .map(Some)
        }
        WriterPragma::PageCount => conn
            .pragma_query_value(None, "page_count", |r| r.get(0))
            .map(Some),
    }
    .map_err(db_err)
}

/// A database error of the writer's connection: unavailable for a storage
/// fault (full, read-only, I/O, busy), internal otherwise.
pub(crate) fn db_err(e: rusqlite::Error) -> StoreError {
    StoreError::from(&e)
}

/// Runs `f` as one operation of the writer thread's next group commit;
/// answers after the commit. An `Err` from `f` rolls back `f`'s changes
/// only. The error is the store's, or the caller's own where `f` runs a
/// caller's rule (an extension's plan) that may refuse.
pub(crate) async fn with_tx<T: Send + 'static, E: From<StoreError> + Send + 'static>(
    writer: &Writer,
    f: impl FnOnce(&Transaction<'_>) -> Result<T, E> + Send + 'static,
) -> Result<T, E> {
    let (reply, answer) = tokio::sync::oneshot::channel::<Result<T, E>>();
    let op: Op = Box::new(move |tx| {
        let tx = match tx {
            Ok(tx) => tx,
            Err(e) => {
                let _ = reply.send(Err(StoreError::from(e).into()));
                return Box::new(|_| {});
            }
        };
        let out = f(tx);
        let undo = if out.is_ok() {
            tx.execute_batch("release op")
        } else {
            tx.execute_batch("rollback to op; release op")
        };
        let out = match (out, undo) {
            (Ok(_), Err(e)) => Err(db_err(e).into()),
            (out, _) => out,
        };
        Box::new(move |outcome| {
            let out = match (out, outcome) {
                (Ok(_), Outcome::Failed(e)) => Err(StoreError::from(e).into()),
                (Ok(_), Outcome::RolledBack) => Err(StoreError::Unavailable(
                    "database unavailable: a storage error rolled back the write; retry later"
                        .into(),
                )
                .into()),
                (out, _) => out,
            };
            let _ = reply.send(out);
        })
    });
    writer
        .tx
        .send(Msg::Op(op))
        .map_err(|_| StoreError::internal("database writer has stopped"))?;
    answer
        .await
        .map_err(|_| StoreError::internal("database writer dropped an operation"))?
}
