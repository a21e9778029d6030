//! Serves a simulated UR controller on the standard ports of HOST (default 127.0.0.2), arm
//! powered off at q = 0, until killed. `cargo run --release -p ur --example sim_controller -- 127.0.0.3`

use std::net::IpAddr;

use ur::{ControllerConfig, ServerConfig, SimController, TrapezoidMotion, UrServers};

#[tokio::main(flavor = "current_thread")]
async fn main() -> std::io::Result<()> {
    let host: IpAddr = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "127.0.0.2".into())
        .parse()
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, format!("HOST: {e}")))?;
    let controller = SimController::new(
        ControllerConfig::default(),
        Box::new(TrapezoidMotion::new([0.0, -1.57, 1.57, -1.57, -1.57, 0.0])),
    );
    let servers = UrServers::start(controller, &ServerConfig::standard(host)).await?;
    println!(
        "robot ur {host}: dashboard {}, RTDE {}, URScript {:?}",
        servers.dashboard, servers.rtde, servers.script
    );
    std::future::pending::<()>().await;
    Ok(())
}
