//! Integration tests for zaber (single test binary).

mod common;
mod corpus;
mod duplex;
mod gauge_pty;
mod identity;
mod props;
mod stage_pty;
