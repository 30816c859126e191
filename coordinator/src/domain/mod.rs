//! The domain layer: the queue and search rules between the HTTP handlers
//! and the store. Its functions take parsed requests and the shared state,
//! call the store, keep the in-memory caches, and answer with wire types or
//! a [`DomainError`]; they know nothing of HTTP (the handlers map the
//! error at the edge, `crate::error`).

pub mod doc_cache;
mod error;
pub mod leasing;
pub mod results;
pub mod scoring;
pub mod searches;

use std::sync::Arc;

pub use error::{DomainError, DomainResult};

use crate::state::AppState;
use crate::store::queue::SearchInfo;

/// The immutable facts of a search (cached by the state), or not found.
pub(crate) async fn search_info(s: &AppState, id: &str) -> DomainResult<Arc<SearchInfo>> {
    Ok(s.search_info(id).await?)
}
