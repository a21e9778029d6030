//! Integration tests for the ur crate (one binary, several modules).

mod common;
mod corpus;
mod golden;
mod props;
mod session;
mod ur_rtde;
