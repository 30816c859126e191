//! What a domain call fails with: the request is invalid, names nothing
//! known, or conflicts with the current state, or the store failed.

use crate::store::StoreError;

/// A refused or failed domain call.
#[derive(Debug, thiserror::Error)]
pub enum DomainError {
    /// Invalid input; the message names the field and the problem.
    #[error("{0}")]
    Invalid(String),
    /// Unknown search or job.
    #[error("{0}")]
    NotFound(String),
    /// The request conflicts with the current state (lost lease, job
    /// already done, search cancelled or completed).
    #[error("{0}")]
    Conflict(String),
    /// The store failed (database unavailable, or internal).
    #[error(transparent)]
    Store(StoreError),
    /// Anything else.
    #[error(transparent)]
    Internal(anyhow::Error),
}

/// The result of a domain call.
pub type DomainResult<T> = Result<T, DomainError>;

impl DomainError {
    /// An internal error with a message.
    pub fn internal(msg: impl std::fmt::Display) -> Self {
        Self::Internal(anyhow::anyhow!("{msg}"))
    }
}

/// The store's refusals are the domain's; its failures pass through.
impl From<StoreError> for DomainError {
    fn from(e: StoreError) -> Self {
        match e {
            StoreError::NotFound(m) => Self::NotFound(m),
            StoreError::Conflict(m) => Self::Conflict(m),
            StoreError::Invalid(m) => Self::Invalid(m),
            other => Self::Store(other),
        }
    }
}

/// Reads that return `anyhow` fail as the store does: unavailable when a
/// storage fault is in the chain.
impl From<anyhow::Error> for DomainError {
    fn from(e: anyhow::Error) -> Self {
        Self::Store(StoreError::from(e))
    }
}
