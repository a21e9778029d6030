//! Integration tests for the emscon crate (one binary, several modules).

mod codec_golden;
mod codec_prop;
mod common;
mod corpus;
mod faults;
mod session;
