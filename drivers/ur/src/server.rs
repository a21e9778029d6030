//! The simulated controller's servers: Dashboard (29999), RTDE (30004) and the URScript
//! client interfaces (30001-30003), on one address so several controllers can coexist on
//! 127.0.0.x.

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::time::Duration;

use lineio::{LineRead, LineReader, Overlong};
use tokio::io::{AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinSet;
use tracing::{debug, info, warn};

use crate::client::{DASHBOARD_PORT, PRIMARY_PORT, REALTIME_PORT, RTDE_PORT, SECONDARY_PORT};
use crate::rtde::{
    decode_values, encode_values, ClientPackage, FrameDecoder, MessageLevel, RtdeType,
    ServerPackage, TextMessage, PROTOCOL_VERSION,
};
use crate::sim::SimController;
use crate::vars;

/// Where the servers listen.
#[derive(Debug, Clone)]
pub struct ServerConfig {
    /// The controller's address (e.g. 127.0.0.2).
    pub host: IpAddr,
    /// Dashboard port (29999; 0: any free port).
    pub dashboard_port: u16,
    /// RTDE port (30004; 0: any free port).
    pub rtde_port: u16,
    /// URScript client interface ports (30001, 30002, 30003; 0: any free port).
    pub script_ports: Vec<u16>,
}

impl ServerConfig {
    /// The standard ports on `host`.
    pub fn standard(host: IpAddr) -> Self {
        ServerConfig {
            host,
            dashboard_port: DASHBOARD_PORT,
            rtde_port: RTDE_PORT,
            script_ports: vec![PRIMARY_PORT, SECONDARY_PORT, REALTIME_PORT],
        }
    }

    /// Free ports chosen by the system on `host` (tests).
    pub fn ephemeral(host: IpAddr) -> Self {
        ServerConfig {
            host,
            dashboard_port: 0,
            rtde_port: 0,
            script_ports: vec![0, 0],
        }
    }
}

/// Running servers; dropping it stops them and closes every connection.
pub struct UrServers {
    /// Dashboard address.
    pub dashboard: SocketAddr,
    /// RTDE address.
    pub rtde: SocketAddr,
    /// URScript addresses, in the order of [`ServerConfig::script_ports`].
    pub script: Vec<SocketAddr>,
    tasks: JoinSet<()>,
}

impl Drop for UrServers {
    fn drop(&mut self) {
        self.tasks.abort_all();
    }
}

impl UrServers {
    /// Binds every listener of `config` (all or none) and serves `controller` on the current
    /// tokio runtime until dropped.
    /// Cancel-safe: a drop before it returns closes the listeners bound so far.
    pub async fn start(controller: SimController, config: &ServerConfig) -> std::io::Result<Self> {
        let bind = |port: u16| TcpListener::bind(SocketAddr::new(config.host, port));
        let dash = bind(config.dashboard_port).await?;
        let rtde = bind(config.rtde_port).await?;
        let mut scripts = Vec::new();
        for p in &config.script_ports {
            scripts.push(bind(*p).await?);
        }
        let mut servers = UrServers {
            dashboard: dash.local_addr()?,
            rtde: rtde.local_addr()?,
            script: scripts
                .iter()
                .map(TcpListener::local_addr)
                .collect::<Result<_, _>>()?,
            tasks: JoinSet::new(),
        };
        servers
            .tasks
            .spawn(accept_loop(dash, controller.clone(), Kind::Dashboard));
        servers
            .tasks
            .spawn(accept_loop(rtde, controller.clone(), Kind::Rtde));
        for l in scripts {
            servers
                .tasks
                .spawn(accept_loop(l, controller.clone(), Kind::Script));
        }
        // programs advance even when no RTDE client samples the controller
        let c = controller.clone();
        servers.tasks.spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_millis(4));
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
            loop {
                tick.tick().await;
                c.snapshot();
            }
        });
        info!(
            "simulated UR controller: dashboard {}, RTDE {}, URScript {:?}",
            servers.dashboard, servers.rtde, servers.script
        );
        Ok(servers)
    }
}

#[derive(Debug, Clone, Copy)]
enum Kind {
    Dashboard,
    Rtde,
    Script,
}

/// Accepts connections forever, one task each; they end with the listener's task.
/// Cancel-safe: a drop aborts every connection task (their sockets close).
async fn accept_loop(listener: TcpListener, controller: SimController, kind: Kind) {
    let mut conns = JoinSet::new();
    loop {
        tokio::select! {
            res = listener.accept() => match res {
                Ok((stream, peer)) => {
                    debug!("simulated UR {kind:?}: connection from {peer}");
                    let _ = stream.set_nodelay(true);
                    let c = controller.clone();
                    conns.spawn(async move {
                        let mut drop_signal = c.disconnect_signal();
                        drop_signal.mark_unchanged();
                        let run = async {
                            match kind {
                                Kind::Dashboard => dashboard_conn(stream, &c).await,
                                Kind::Rtde => rtde_conn(stream, &c).await,
                                Kind::Script => script_conn(stream, &c).await,
                            }
                        };
                        tokio::select! {
                            biased;
                            _ = drop_signal.changed() => {
                                info!("simulated UR {kind:?}: connection dropped (fault)");
                            }
                            r = run => if let Err(e) = r {
                                debug!("simulated UR {kind:?}: connection ended: {e}");
                            },
                        }
                    });
                }
                Err(e) => {
                    warn!("simulated UR {kind:?}: accept failed: {e}");
                    tokio::time::sleep(Duration::from_millis(10)).await;
                }
            },
            Some(_) = conns.join_next(), if !conns.is_empty() => {}
        }
    }
}

/// One Dashboard connection: banner, then one reply line per command line.
/// Cancel-safe: a drop closes the connection.
async fn dashboard_conn(stream: TcpStream, c: &SimController) -> std::io::Result<()> {
    let (r, mut w) = stream.into_split();
    let mut lines = LineReader::new(BufReader::new(r), 4096).overlong(Overlong::Skip);
    w.write_all(format!("{}\n", crate::dashboard::BANNER).as_bytes())
        .await?;
    loop {
        let line = match lines.next_line().await? {
            LineRead::Line(l) => l,
            LineRead::Eof => return Ok(()),
            LineRead::Bad(why) => {
                w.write_all(format!("could not understand: '{why}'\n").as_bytes())
                    .await?;
                continue;
            }
        };
        if line.trim().is_empty() {
            continue;
        }
        let (reply, close) = c.dashboard(&line);
        debug!("simulated UR dashboard {line:?} -> {reply:?}");
        w.write_all(format!("{reply}\n").as_bytes()).await?;
        if close {
            return Ok(());
        }
    }
}

/// Longest program the URScript receiver keeps.
const MAX_PROGRAM: usize = 1 << 20;

/// One URScript connection: each complete program (a `def`/`sec` ... `end` block, or one
/// line outside a block) runs as soon as it is received. A block cut by the end of the
/// connection does not run.
/// Cancel-safe: a drop closes the connection; a partial program never runs.
async fn script_conn(stream: TcpStream, c: &SimController) -> std::io::Result<()> {
    let (r, _w) = stream.into_split();
    let mut lines = LineReader::new(BufReader::new(r), 64 * 1024).overlong(Overlong::Skip);
    let mut block: Option<String> = None;
    loop {
        let line = match lines.next_line().await? {
            LineRead::Line(l) => l,
            LineRead::Eof => return Ok(()),
            LineRead::Bad(why) => {
                warn!("simulated UR URScript: bad line ({why}); program dropped");
                block = None;
                continue;
            }
        };
        let t = line.split('#').next().unwrap_or("").trim();
        match block.as_mut() {
            Some(b) => {
                b.push_str(&line);
                b.push('\n');
                if b.len() > MAX_PROGRAM {
                    warn!("simulated UR URScript: program over {MAX_PROGRAM} bytes dropped");
                    block = None;
                } else if t == "end" {
                    let text = block.take().unwrap_or_default();
                    let _ = c.run_script(&text);
                }
            }
            None if t.is_empty() => {}
            None if t.starts_with("def ") || t.starts_with("sec ") => {
                block = Some(format!("{line}\n"));
            }
            None => {
                let _ = c.run_script(&line);
            }
        }
    }
}

struct Recipe {
    names: Vec<String>,
    types: Vec<RtdeType>,
    valid: bool,
    period: Duration,
}

fn text(message: impl Into<String>, level: MessageLevel) -> ServerPackage {
    ServerPackage::Text(TextMessage {
        message: message.into(),
        source: "RTDE".into(),
        level,
    })
}

/// Writes `p`.
/// Not cancel-safe: a drop may leave a partial package; the connection is then dropped too.
async fn send(w: &mut TcpStream, p: &ServerPackage) -> std::io::Result<()> {
    let bytes = p
        .encode()
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))?;
    w.write_all(&bytes).await
}

/// One RTDE connection (protocol version 2).
/// Cancel-safe: a drop closes the connection.
async fn rtde_conn(mut stream: TcpStream, c: &SimController) -> std::io::Result<()> {
    let mut decoder = FrameDecoder::new();
    let mut output: Option<Recipe> = None;
    let mut inputs: HashMap<u8, Vec<RtdeType>> = HashMap::new();
    let mut started = false;
    let mut tick = tokio::time::interval(Duration::from_millis(8));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut buf = vec![0u8; 8192];
    loop {
        tokio::select! {
            n = stream.read(&mut buf) => {
                let n = n?;
                if n == 0 {
                    return Ok(());
                }
                decoder.push(&buf[..n]);
                loop {
                    let pkg = match decoder.next_client() {
                        Ok(Some(p)) => p,
                        Ok(None) => break,
                        Err(e) if e.is_fatal() => {
                            warn!("simulated UR RTDE: {e}; closing");
                            return Ok(());
                        }
                        Err(e) => {
                            send(&mut stream, &text(e.to_string(), MessageLevel::Error)).await?;
                            continue;
                        }
                    };
                    let reply = match pkg {
                        ClientPackage::RequestProtocolVersion(v) => {
                            Some(ServerPackage::ProtocolVersion(v == PROTOCOL_VERSION))
                        }
                        ClientPackage::GetUrcontrolVersion => {
                            let [major, minor, bugfix, build] = c.config().version;
                            Some(ServerPackage::UrcontrolVersion { major, minor, bugfix, build })
                        }
                        ClientPackage::SetupOutputs { frequency, names } => {
                            if started {
                                send(&mut stream, &text(
                                    "cannot set up outputs while synchronisation runs",
                                    MessageLevel::Error,
                                )).await?;
                            }
                            let found: Vec<Option<RtdeType>> =
                                names.iter().map(|n| vars::output_type(n)).collect();
                            let types: Vec<String> = found
                                .iter()
                                .map(|t| t.map_or("NOT_FOUND", RtdeType::name).to_owned())
                                .collect();
                            let max = c.config().max_rtde_hz;
                            let freq_ok = frequency.is_finite() && frequency > 0.0 && frequency <= max;
                            let unknown: Vec<&String> = names
                                .iter()
                                .zip(&found)
                                .filter(|(_, t)| t.is_none())
                                .map(|(n, _)| n)
                                .collect();
                            if !unknown.is_empty() {
                                warn!("simulated UR RTDE: unknown outputs {unknown:?}");
                            }
                            if !freq_ok {
                                send(&mut stream, &text(
                                    format!("output frequency {frequency} Hz outside (0, {max}]"),
                                    MessageLevel::Error,
                                )).await?;
                            }
                            let valid = unknown.is_empty() && freq_ok && !started;
                            let period = Duration::from_secs_f64(1.0 / frequency.clamp(1.0, max));
                            if !started {
                                output = Some(Recipe {
                                    names: names.clone(),
                                    types: found.iter().map(|t| t.unwrap_or(RtdeType::Uint8)).collect(),
                                    valid,
                                    period,
                                });
                            }
                            Some(ServerPackage::SetupOutputs { recipe: if started { 0 } else { 1 }, types })
                        }
                        ClientPackage::SetupInputs(names) => {
                            let found: Vec<Option<RtdeType>> =
                                names.iter().map(|n| vars::input_type(n)).collect();
                            let types = found
                                .iter()
                                .map(|t| t.map_or("NOT_FOUND", RtdeType::name).to_owned())
                                .collect();
                            let id = if found.iter().all(Option::is_some) && inputs.len() < 254 {
                                let id = inputs.len() as u8 + 1;
                                inputs.insert(id, found.into_iter().flatten().collect());
                                id
                            } else {
                                0
                            };
                            Some(ServerPackage::SetupInputs { recipe: id, types })
                        }
                        ClientPackage::Start => {
                            let ok = match &output {
                                Some(r) => r.valid,
                                None => !inputs.is_empty(),
                            };
                            if ok {
                                started = true;
                                if let Some(r) = &output {
                                    tick = tokio::time::interval(r.period);
                                    tick.set_missed_tick_behavior(
                                        tokio::time::MissedTickBehavior::Skip,
                                    );
                                }
                            }
                            Some(ServerPackage::Start(ok))
                        }
                        ClientPackage::Pause => {
                            started = false;
                            Some(ServerPackage::Pause(true))
                        }
                        ClientPackage::Data { recipe, values } => {
                            match inputs.get(&recipe) {
                                Some(types) if decode_values(types, &values).is_ok() => None,
                                _ => Some(text(
                                    format!("data package for unknown input recipe {recipe} or of the wrong size"),
                                    MessageLevel::Error,
                                )),
                            }
                        }
                        ClientPackage::Text(t) => {
                            debug!("simulated UR RTDE: message from {}: {}", t.source, t.message);
                            None
                        }
                    };
                    if let Some(r) = reply {
                        send(&mut stream, &r).await?;
                    }
                }
            }
            _ = tick.tick(), if started && output.is_some() => {
                let Some(r) = &output else { continue };
                let snap = c.snapshot();
                let values: Vec<_> = r
                    .names
                    .iter()
                    .zip(&r.types)
                    .map(|(n, t)| snap.output(n, *t))
                    .collect();
                let pkg = ServerPackage::Data { recipe: 1, values: encode_values(&values) };
                send(&mut stream, &pkg).await?;
            }
        }
    }
}
