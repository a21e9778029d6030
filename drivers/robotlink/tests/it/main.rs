//! Integration tests for robotlink (single test binary).

mod abort;
mod auth;
mod common;
mod corpus;
mod faults;
mod props;
mod session;
