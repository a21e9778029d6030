//! Integration tests for robotlink (single test binary).

mod abort;
mod common;
mod corpus;
mod faults;
mod props;
mod session;
