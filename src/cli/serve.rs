//! `cellcal serve`: the campaign daemon of one cell and its REST API.

use std::net::{SocketAddr, ToSocketAddrs};
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{anyhow, Context};

use cellcal::api::{self, Scheme};
use cellcal::config::load_cell_config;
use cellcal::daemon::Daemon;

use super::{access, input, other, runtime, Failure};
use crate::signals::StopSignals;

/// Arguments of `cellcal serve`.
#[derive(clap::Args)]
pub struct ServeArgs {
    /// Cell configuration file (TOML).
    #[arg(long, default_value = "config/cell.sim.toml")]
    config: PathBuf,
    /// Address to listen on: `IP:PORT` or `HOST:PORT` (`localhost:8080`; a name is resolved,
    /// its first IPv4 address taken, else its first; a loopback address needs no token).
    /// `127.0.0.1:0` picks a free port; the line `listening on http://ADDR` tells which.
    #[arg(long, default_value = "127.0.0.1:8080")]
    listen: String,
    /// Store file (default: `store` of the configuration).
    #[arg(long)]
    store: Option<PathBuf>,
    /// Log lines on stderr: `text` (human) or `json` (one object a line). Level from
    /// `RUST_LOG` (default `info`): campaign loads and state changes, device faults, every
    /// request answered 4xx/5xx; never a token.
    #[arg(long, value_parser = ["text", "json"], default_value = "text")]
    pub log_format: String,
}

/// The address `--listen` names, and its host name when it gave one: `IP:PORT`, or
/// `HOST:PORT` resolved (of several addresses the first IPv4 one, else the first; `localhost`
/// is the loopback address). The exposure rules ([`access::check_exposure`]) are judged on
/// the address bound, so a name that resolves to a public address needs tokens like the
/// address itself.
fn listen_addr(listen: &str) -> Result<(SocketAddr, Option<String>), Failure> {
    if let Ok(addr) = listen.parse() {
        return Ok((addr, None));
    }
    let bad = |why: String| {
        input(anyhow!(
            "--listen `{listen}`: {why}; give IP:PORT or HOST:PORT (e.g. 127.0.0.1:8080, \
             localhost:8080, 0.0.0.0:8080)"
        ))
    };
    let Some((host, port)) = listen.rsplit_once(':') else {
        return Err(bad("no port".into()));
    };
    if port.parse::<u16>().is_err() {
        return Err(bad(format!("`{port}` is not a port number (0 to 65535)")));
    }
    let addrs: Vec<SocketAddr> = listen
        .to_socket_addrs()
        .map_err(|e| bad(format!("cannot resolve `{host}`: {e}")))?
        .collect();
    let addr = addrs
        .iter()
        .find(|a| a.is_ipv4())
        .or(addrs.first())
        .copied()
        .ok_or_else(|| bad(format!("`{host}` resolves to no address")))?;
    Ok((addr, Some(host.to_ascii_lowercase())))
}

/// `cellcal serve`: the campaign daemon and its REST API until Ctrl-C / SIGTERM.
pub fn run(a: ServeArgs) -> Result<(), Failure> {
    let ServeArgs {
        config,
        listen,
        store,
        log_format: _,
    } = a;
    let (config, listen) = (config.as_path(), listen.as_str());
    let cfg = load_cell_config(config).map_err(input)?;
    // the controller's secret is checked now, not at the first campaign (a 5xx then)
    drop(cellcal::cell::controller_secret(&cfg.robot_controller).map_err(input)?);
    let (addr, host) = listen_addr(listen)?;
    let mut api_cfg = cfg.api.clone();
    // the name it was told to listen on is a Host the page may be opened with
    api_cfg.allowed_hosts.extend(host);
    access::check_exposure(addr, &api_cfg)?;
    let tls = match &api_cfg.tls {
        Some((cert, key)) => Some(api::tls::server_config(cert, key).map_err(input)?),
        None => None,
    };
    let scheme = if tls.is_some() {
        Scheme::Https
    } else {
        Scheme::Http
    };
    let store_path = store.unwrap_or_else(|| cfg.store.clone());
    let rt = runtime()?;
    rt.block_on(async move {
        let daemon = Arc::new(Daemon::new(cfg, &store_path).map_err(input)?);
        let listener = api::conns::listen(addr)
            .with_context(|| format!("cannot listen on {addr}"))
            .map_err(other)?;
        let bound = listener.local_addr().map_err(other)?;
        let (tokens, one_time) = access::accepted_tokens(&api_cfg)?;
        println!("listening on {}://{bound}", scheme.as_str());
        if let Some(token) = one_time {
            println!("open {}://{bound}/?token={token}", scheme.as_str());
        }
        tracing::info!(store = %store_path.display(), "campaign store");
        let mut signals = StopSignals::install().map_err(other)?;
        let app = api::router(
            Arc::clone(&daemon),
            access::gate(tokens, scheme, bound, &api_cfg),
        );
        let descriptors = api::conns::raise_descriptor_limit().map_err(other)?;
        let limits = api::ServeLimits::from_env(descriptors).map_err(input)?;
        tracing::info!(
            descriptors,
            max_connections = limits.max_connections,
            header_read_timeout_s = limits.header_read_timeout.as_secs_f64(),
            idle_timeout_s = limits.idle_timeout.as_secs_f64(),
            "connection limits"
        );
        let handle = axum_server::Handle::new();
        let server = api::serve(listener, app, tls, handle.clone(), limits);
        tokio::pin!(server);
        tokio::select! {
            r = &mut server => r.map_err(other)?,
            _ = signals.next() => {
                tracing::info!("stopping: aborting the loaded campaign");
                daemon.shutdown().await;
                handle.graceful_shutdown(Some(std::time::Duration::from_secs(5)));
                let _ = tokio::time::timeout(std::time::Duration::from_secs(6), server).await;
            }
        }
        Ok(())
    })
}
