//! Runs the emScon simulator with a fixed-point backend.
//!
//! Usage: `cargo run --example simulator -- [ADDR] [SECONDS]` (default 127.0.0.1:7000, 60 s).

use std::sync::Arc;
use std::time::Duration;

use emscon::{serve, FaultConfig, SimpleBackend};

#[tokio::main(flavor = "current_thread")]
async fn main() -> std::io::Result<()> {
    let mut args = std::env::args().skip(1);
    let addr = args.next().unwrap_or_else(|| "127.0.0.1:7000".into());
    let secs: u64 = args.next().and_then(|s| s.parse().ok()).unwrap_or(60);
    let listener = tokio::net::TcpListener::bind(&addr).await?;
    println!(
        "emscon simulator on {} for {secs} s",
        listener.local_addr()?
    );
    serve(
        listener,
        Arc::new(SimpleBackend::default()),
        FaultConfig::shared(),
        tokio::time::sleep(Duration::from_secs(secs)),
    )
    .await
}
