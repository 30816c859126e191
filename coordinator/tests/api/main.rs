//! Coordinator API tests: the real service on 127.0.0.1:0 over a temporary
//! SQLite file, driven over HTTP by simulated workers.

mod helpers;
#[path = "../support/mod.rs"]
mod support;

mod auth;
mod extend;
mod faults;
mod input;
mod leases;
mod refine;
mod scale;
mod searches;
mod security;
mod subjects;
