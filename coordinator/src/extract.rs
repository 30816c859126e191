//! Request extractors whose rejections answer `{"error": "..."}` (an
//! [`ApiError`] naming the field), shared by the API routes and the
//! dashboard.

use axum::extract::{FromRequest, FromRequestParts};

use crate::error::ApiError;

/// JSON body extractor whose rejection is an [`ApiError`] naming the field.
#[derive(FromRequest)]
#[from_request(via(axum::Json), rejection(ApiError))]
pub struct ApiJson<T>(pub T);

/// Path extractor whose rejection is an [`ApiError`].
#[derive(FromRequestParts)]
#[from_request(via(axum::extract::Path), rejection(ApiError))]
pub struct ApiPath<T>(pub T);
