//! Integration tests for the ur crate (one binary, several modules).

mod golden;
