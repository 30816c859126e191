//! The one write path of the store: a writer task that owns the one
//! read-write sqlx connection and commits in groups. It takes every
//! operation waiting in its queue (up to [`MAX_BATCH`]), runs each inside a
//! savepoint of one `BEGIN IMMEDIATE` transaction (a failed operation rolls
//! back alone), commits once, and only then answers. One transaction per
//! operation managed 700 lease+complete cycles/s on 2 cores; a group
//! commits as often as the disk allows however many operations wait
//! (docs/performance.md#queue-overhead has the bench figures). It is the
//! only connection that writes, so its transactions never wait on another
//! writer's lock.

use std::collections::VecDeque;

use futures_util::future::BoxFuture;
use futures_util::FutureExt;
use sqlx::SqliteConnection;
use tokio::sync::{mpsc, oneshot};

use super::error::{StoreError, StoreResult};

/// Most operations committed together.
pub const MAX_BATCH: usize = 128;

/// How an operation's group ended.
enum Outcome<'a> {
    /// Committed: the operation's own answer stands.
    Committed,
    /// Begin or commit failed with this error; nothing of the group is kept.
    Failed(&'a sqlx::Error),
    /// SQLite rolled the group's transaction back after another operation's
    /// storage error; nothing of the group is kept.
    RolledBack,
}

/// Answers an operation once its group has ended.
type Deliver = Box<dyn FnOnce(Outcome<'_>) + Send>;

/// What running an operation in its savepoint left.
struct Ran {
    deliver: Deliver,
    /// The savepoint could not be released or rolled back: SQLite had
    /// already rolled the whole transaction back (`SQLITE_FULL`,
    /// `SQLITE_IOERR`, ...).
    lost: bool,
}

/// Runs an operation in the group's transaction (its savepoint open), or
/// answers at once with the error that kept the transaction (or the
/// savepoint) from starting.
type Op = Box<
    dyn for<'c> FnOnce(Result<&'c mut SqliteConnection, &'c sqlx::Error>) -> BoxFuture<'c, Ran>
        + Send,
>;

enum Msg {
    Op(Op),
    /// A pragma to run between groups, outside any transaction.
    Pragma(WriterPragma, oneshot::Sender<StoreResult<Option<i64>>>),
    Close(oneshot::Sender<()>),
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

/// Handle of the writer task.
#[derive(Debug, Clone)]
pub struct Writer {
    tx: mpsc::UnboundedSender<Msg>,
}

impl std::fmt::Debug for Msg {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Msg")
    }
}

impl Writer {
    /// Starts the writer task on `conn` (open read-write on a migrated
    /// database).
    pub fn start(conn: SqliteConnection) -> Self {
        let (tx, rx) = mpsc::unbounded_channel::<Msg>();
        tokio::spawn(run(conn, rx));
        Self { tx }
    }

    /// Runs one pragma on the writer's connection between two groups.
    pub async fn pragma(&self, p: WriterPragma) -> StoreResult<Option<i64>> {
        let (reply, answer) = oneshot::channel();
        self.tx
            .send(Msg::Pragma(p, reply))
            .map_err(|_| StoreError::internal("database writer has stopped"))?;
        answer
            .await
            .map_err(|_| StoreError::internal("database writer dropped a pragma"))?
    }

    /// Stops the task and closes its connection (pending operations are
    /// finished first).
    pub async fn close(&self) {
        let (done, wait) = oneshot::channel();
        if self.tx.send(Msg::Close(done)).is_ok() {
            let _ = wait.await;
        }
    }
}

/// Runs `sql` (no parameters) on the writer's connection.
async fn exec(conn: &mut SqliteConnection, sql: &'static str) -> Result<(), sqlx::Error> {
    sqlx::query(sql).execute(conn).await.map(|_| ())
}

/// Undoes the operation's changes and ends its savepoint.
async fn undo(conn: &mut SqliteConnection) -> Result<(), sqlx::Error> {
    exec(conn, "rollback to op").await?;
    exec(conn, "release op").await
}

async fn run(mut conn: SqliteConnection, mut rx: mpsc::UnboundedReceiver<Msg>) {
    let mut close: Option<oneshot::Sender<()>> = None;
    // Operations of a group that SQLite rolled back before they ran.
    let mut carry: VecDeque<Op> = VecDeque::new();
    while close.is_none() || !carry.is_empty() {
        let mut ops = std::mem::take(&mut carry);
        if ops.is_empty() {
            let Some(first) = rx.recv().await else { break };
            match first {
                Msg::Op(op) => ops.push_back(op),
                Msg::Pragma(p, reply) => {
                    let _ = reply.send(run_pragma(&mut conn, p).await);
                }
                Msg::Close(c) => close = Some(c),
            }
        }
        while close.is_none() && ops.len() < MAX_BATCH {
            match rx.try_recv() {
                Ok(Msg::Op(op)) => ops.push_back(op),
                Ok(Msg::Pragma(p, reply)) => {
                    let _ = reply.send(run_pragma(&mut conn, p).await);
                }
                Ok(Msg::Close(c)) => close = Some(c),
                Err(_) => break,
            }
        }
        if ops.is_empty() {
            continue;
        }
        if let Err(e) = exec(&mut conn, "begin immediate").await {
            // Each operation answers with the error (503 for a full,
            // read-only or failing disk, a lock held too long).
            tracing::error!(error = %e, "writer: begin failed");
            for op in ops {
                (op(Err(&e)).await.deliver)(Outcome::Failed(&e));
            }
            continue;
        }
        let mut delivers = Vec::with_capacity(ops.len());
        let mut rolled_back = false;
        while let Some(op) = ops.pop_front() {
            let ran = match exec(&mut conn, "savepoint op").await {
                Err(e) => op(Err(&e)).await,
                // A panicking operation answers with an error (its reply
                // is dropped) and is rolled back; the task lives on.
                Ok(()) => match std::panic::AssertUnwindSafe(op(Ok(&mut conn)))
                    .catch_unwind()
                    .await
                {
                    Ok(ran) => ran,
                    Err(_) => {
                        tracing::error!("writer: operation panicked; rolled back");
                        let lost = undo(&mut conn).await.is_err();
                        Ran {
                            deliver: Box::new(|_| {}),
                            lost,
                        }
                    }
                },
            };
            delivers.push(ran.deliver);
            // SQLite rolls the whole transaction back itself on some errors
            // (SQLITE_FULL, SQLITE_IOERR, ...): the savepoint is gone with
            // it. The group's earlier changes are gone, and a later
            // operation would run outside any transaction: stop here,
            // answer the group, and run the rest in a fresh transaction.
            if ran.lost {
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
            // Nothing to roll back when SQLite did; this only closes a
            // transaction a failed release left open.
            let _ = exec(&mut conn, "rollback").await;
            for d in delivers {
                d(Outcome::RolledBack);
            }
            carry = ops;
            continue;
        }
        let failed = match exec(&mut conn, "commit").await {
            Ok(()) => None,
            Err(e) => {
                // None of the group's changes is kept, and each operation
                // says so.
                tracing::error!(error = %e, "writer: commit failed");
                let _ = exec(&mut conn, "rollback").await;
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
    // Closing a read-write connection checkpoints the WAL into the file.
    if let Err(e) = sqlx::Connection::close(conn).await {
        tracing::warn!(error = %e, "writer: closing the connection");
    }
    if let Some(c) = close {
        let _ = c.send(());
    }
}

/// Sets or reads one pragma of the writer's connection.
async fn run_pragma(conn: &mut SqliteConnection, p: WriterPragma) -> StoreResult<Option<i64>> {
    Ok(match p {
        WriterPragma::QueryOnly(true) => exec(conn, "pragma query_only = 1").await.map(|_| None)?,
        WriterPragma::QueryOnly(false) => {
            exec(conn, "pragma query_only = 0").await.map(|_| None)?
        }
        WriterPragma::Full(true) => Some(
            sqlx::query_scalar::<_, i64>("pragma max_page_count = 1")
                .fetch_one(conn)
                .await?,
        ),
        WriterPragma::Full(false) => Some(
            sqlx::query_scalar::<_, i64>("pragma max_page_count = 1073741823")
                .fetch_one(conn)
                .await?,
        ),
        WriterPragma::PageCount => Some(
            sqlx::query_scalar::<_, i64>("pragma page_count")
                .fetch_one(conn)
                .await?,
        ),
    })
}

/// Runs `f` as one operation of the writer task's next group commit;
/// answers after the commit. An `Err` from `f` rolls back `f`'s changes
/// only. The error is the store's, or the caller's own where `f` runs a
/// caller's rule (an extension's plan) that may refuse.
pub(crate) async fn with_tx<T, E, F>(writer: &Writer, f: F) -> Result<T, E>
where
    T: Send + 'static,
    E: From<StoreError> + Send + 'static,
    F: for<'c> FnOnce(&'c mut SqliteConnection) -> BoxFuture<'c, Result<T, E>> + Send + 'static,
{
    let (reply, answer) = oneshot::channel::<Result<T, E>>();
    let op: Op = Box::new(move |conn| {
        Box::pin(async move {
            let conn = match conn {
                Ok(conn) => conn,
                Err(e) => {
                    let _ = reply.send(Err(StoreError::from(e).into()));
                    return Ran {
                        deliver: Box::new(|_| {}),
                        lost: false,
                    };
                }
            };
            let out = f(conn).await;
            let undo = if out.is_ok() {
                exec(conn, "release op").await
            } else {
                undo(conn).await
            };
            let lost = undo.is_err();
            let out = match (out, undo) {
                (Ok(_), Err(e)) => Err(StoreError::from(e).into()),
                (out, _) => out,
            };
            let deliver: Deliver = Box::new(move |outcome| {
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
            });
            Ran { deliver, lost }
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
