//! Device simulators (server side): a Zaber ASCII stage and a generic RS-232 gauge, each served
//! over any async byte stream, with deterministic one-shot fault injection.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt, BufReader};
use tracing::debug;

use crate::ascii::{
    format_reply, parse_command, parse_steps, CodecError, Reply, ReplyFlag, Status, Warning,
    WarningClass,
};
use crate::lineio::{ascii_lines, gauge_lines, read_line, LineRead};
use crate::product::SIM_PRODUCT;

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

fn take(c: &mut u32) -> bool {
    if *c > 0 {
        *c -= 1;
        true
    } else {
        false
    }
}

// ------------------------------------------------------------------------------------------------
// Stage

/// Simulated stage parameters.
#[derive(Debug, Clone)]
pub struct StageSimConfig {
    /// Device address.
    pub device: u8,
    /// Axis number.
    pub axis: u8,
    /// `device.id` the device reports (default: [`SIM_PRODUCT`]).
    pub device_id: u32,
    /// `peripheral.id` the axis reports (default: [`SIM_PRODUCT`]).
    pub peripheral_id: u32,
    /// `system.serial` the device reports.
    pub serial: u32,
    /// `version` the device reports (`major.minor`).
    pub version: String,
    /// `version.build` the device reports.
    pub build: u32,
    /// `resolution`: microsteps per full step (X-series default 64).
    pub resolution: u32,
    /// Travel limits in microsteps (inclusive).
    pub limit_min: i64,
    /// Travel limits in microsteps (inclusive).
    pub limit_max: i64,
    /// Speed in microsteps per second.
    pub speed_steps_s: f64,
    /// Whether the stage starts homed.
    pub homed: bool,
    /// Add `:XX` checksums to replies.
    pub checksum_replies: bool,
    /// Fixed time added to every move (start-up and settling; a move stays BUSY at least this
    /// long). Zero makes a move at infinite speed end at once.
    pub move_overhead: Duration,
}

impl Default for StageSimConfig {
    fn default() -> Self {
        Self {
            device: 1,
            axis: 1,
            device_id: SIM_PRODUCT.device_id,
            peripheral_id: SIM_PRODUCT.peripheral_id,
            serial: 123_456,
            version: "7.38".into(),
            build: 18_000,
            resolution: 64,
            limit_min: 0,
            limit_max: 2_100_000,
            speed_steps_s: 20_000_000.0,
            homed: false,
            checksum_replies: true,
            move_overhead: Duration::from_millis(5),
        }
    }
}

/// Stage fault injection (one-shot counters).
#[derive(Debug, Clone)]
pub struct StageFaults {
    /// Reject the next N motion commands (`move`, `home`) with `reject_reason`.
    pub reject: u32,
    /// Reason used by `reject` (`BADCOMMAND`, `BADDATA`, ...).
    pub reject_reason: String,
    /// The next N moves never finish (BUSY until `stop`).
    pub stall: u32,
    /// The next N moves end in a fault: axis stops, flag `fault_flag` latched until `warnings clear`.
    pub fault: u32,
    /// Fault flag used by `fault` (e.g. `FF`, `FZ`, `FS`).
    pub fault_flag: String,
    /// Mark the stage not homed at the next command (WR; moves rejected until homed).
    pub lose_home: u32,
    /// The next N moves are interrupted half-way (NI latched until `warnings clear`).
    pub interrupt: u32,
    /// The next N moves stop two thirds of the way on a limit sensor (WL, unexpected limit
    /// trigger, latched until `warnings clear`).
    pub limit_hit: u32,
    /// At the next N commands that find the axis stationary, it is first pushed
    /// `displace_steps` off its position (WM, displaced when stationary, latched until
    /// `warnings clear`).
    pub displace: u32,
    /// Offset applied by `displace`, microsteps.
    pub displace_steps: i64,
    /// The next N moves end `overshoot_steps` off target (read-back ≠ target).
    pub overshoot: u32,
    /// Offset applied by `overshoot`, microsteps.
    pub overshoot_steps: i64,
    /// Corrupt the checksum of the next N replies.
    pub bad_checksum: u32,
    /// Replace the next N replies by a garbage line.
    pub garbage: u32,
    /// Send only the first half of the next N replies (no terminator).
    pub partial: u32,
    /// Send nothing for the next N commands.
    pub silence: u32,
}

impl Default for StageFaults {
    fn default() -> Self {
        Self {
            reject: 0,
            reject_reason: "BADCOMMAND".into(),
            stall: 0,
            fault: 0,
            fault_flag: "FF".into(),
            lose_home: 0,
            interrupt: 0,
            limit_hit: 0,
            displace: 0,
            displace_steps: 200,
            overshoot: 0,
            overshoot_steps: 50,
            bad_checksum: 0,
            garbage: 0,
            partial: 0,
            silence: 0,
        }
    }
}

#[derive(Debug)]
struct Move {
    from: i64,
    to: i64,
    start: Instant,
    duration: Duration,
    /// Flag to latch when the move ends (NI / WL / fault).
    end_flag: Option<Warning>,
    stall: bool,
}

#[derive(Debug)]
struct StageState {
    pos: i64,
    homed: bool,
    mv: Option<Move>,
    /// Latched warning flags in the order they were raised (WR while not homed).
    flags: Vec<Warning>,
}

/// Severity rank of a flag: faults over warnings over notices.
fn severity(w: Warning) -> u8 {
    match w.class() {
        WarningClass::Fault => 3,
        WarningClass::Warning => 2,
        WarningClass::Notice => 1,
        WarningClass::None | WarningClass::Other => 0,
    }
}

/// The flag a reply shows: the most severe latched one (the earliest among equals).
fn top_flag(flags: &[Warning]) -> Warning {
    flags.iter().fold(Warning::NONE, |best, w| {
        if severity(*w) > severity(best) {
            *w
        } else {
            best
        }
    })
}

fn latch(flags: &mut Vec<Warning>, w: Warning) {
    if !flags.contains(&w) {
        flags.push(w);
    }
}

/// `warnings` data: two-digit count, then the flags (`00`, `02 WR NI`).
fn warnings_data(flags: &[Warning]) -> String {
    let mut s = format!("{:02}", flags.len());
    for f in flags {
        s.push(' ');
        s.push_str(f.as_str());
    }
    s
}

/// Whether a setting belongs to the device (read at axis 0) or to an axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scope {
    Device,
    Axis,
}

/// Simulated stage; cheap to clone (shared state). The handle gives the integrator the position.
#[derive(Debug, Clone)]
pub struct StageSim {
    cfg: StageSimConfig,
    st: Arc<Mutex<StageState>>,
    faults: Arc<Mutex<StageFaults>>,
}

impl StageSim {
    /// New simulated stage at position 0.
    pub fn new(cfg: StageSimConfig) -> Self {
        let st = StageState {
            pos: 0,
            homed: cfg.homed,
            mv: None,
            flags: if cfg.homed {
                Vec::new()
            } else {
                vec![Warning::WR]
            },
        };
        Self {
            cfg,
            st: Arc::new(Mutex::new(st)),
            faults: Arc::new(Mutex::new(StageFaults::default())),
        }
    }

    /// The configuration.
    pub fn config(&self) -> &StageSimConfig {
        &self.cfg
    }

    /// Lock the fault configuration to arm faults.
    pub fn faults(&self) -> std::sync::MutexGuard<'_, StageFaults> {
        lock(&self.faults)
    }

    fn update(&self, st: &mut StageState) {
        let now = Instant::now();
        let Some(m) = &st.mv else { return };
        if m.stall {
            let t = (now - m.start).as_secs_f64() / m.duration.as_secs_f64().max(1e-9);
            st.pos = m.from + ((m.to - m.from) as f64 * t.min(0.5)) as i64;
            return;
        }
        if now >= m.start + m.duration {
            st.pos = m.to;
            if let Some(f) = m.end_flag {
                latch(&mut st.flags, f);
            }
            st.mv = None;
        } else {
            let t = (now - m.start).as_secs_f64() / m.duration.as_secs_f64().max(1e-9);
            st.pos = m.from + ((m.to - m.from) as f64 * t) as i64;
        }
    }

    /// Current position in microsteps (for the simulated world).
    pub fn position_steps(&self) -> i64 {
        let mut st = lock(&self.st);
        self.update(&mut st);
        st.pos
    }

    /// True while a move is in progress.
    pub fn is_busy(&self) -> bool {
        let mut st = lock(&self.st);
        self.update(&mut st);
        st.mv.is_some()
    }

    /// True once homed.
    pub fn is_homed(&self) -> bool {
        lock(&self.st).homed
    }

    /// The latched warning flags, in the order they were raised.
    pub fn warning_flags(&self) -> Vec<Warning> {
        let mut st = lock(&self.st);
        self.update(&mut st);
        st.flags.clone()
    }

    /// A reply on `axis` (0 for a device-scope command) with the current status and flag.
    fn reply(&self, axis: u8, id: Option<u8>, flag: ReplyFlag, data: String) -> Reply {
        let mut st = lock(&self.st);
        self.update(&mut st);
        Reply {
            device: self.cfg.device,
            axis,
            id,
            flag,
            status: if st.mv.is_some() {
                Status::Busy
            } else {
                Status::Idle
            },
            warning: top_flag(&st.flags),
            data,
        }
    }

    fn start_move(&self, to: i64) {
        let mut f = lock(&self.faults);
        let mut st = lock(&self.st);
        self.update(&mut st);
        // Like a real Zaber device, a new move while busy retargets from the current position.
        let mut to = to;
        let mut end_flag = None;
        if take(&mut f.interrupt) {
            to = st.pos + (to - st.pos) / 2;
            end_flag = Some(Warning::NI);
        }
        if take(&mut f.limit_hit) {
            to = st.pos + (to - st.pos) * 2 / 3;
            end_flag = Some(Warning::WL);
        }
        if take(&mut f.fault) {
            to = st.pos + (to - st.pos) / 3;
            end_flag = Some(Warning::parse(&f.fault_flag).unwrap_or(Warning::FF));
        }
        if take(&mut f.overshoot) {
            to += f.overshoot_steps;
        }
        let stall = take(&mut f.stall);
        let dist = (to - st.pos).abs() as f64;
        let duration = Duration::from_secs_f64((dist / self.cfg.speed_steps_s).min(3600.0))
            + self.cfg.move_overhead;
        st.mv = Some(Move {
            from: st.pos,
            to,
            start: Instant::now(),
            duration,
            end_flag,
            stall,
        });
    }

    /// Apply the one-shot faults that act before a command: lost home, displacement.
    fn pre_command_faults(&self) {
        let mut f = lock(&self.faults);
        let mut st = lock(&self.st);
        self.update(&mut st);
        if take(&mut f.lose_home) {
            st.homed = false;
            latch(&mut st.flags, Warning::WR);
        }
        if st.mv.is_none() && take(&mut f.displace) {
            st.pos += f.displace_steps;
            latch(&mut st.flags, Warning::WM);
        }
    }

    /// Value and scope of a readable setting (`None`: no such setting).
    fn setting(&self, name: &str) -> Option<(Scope, String)> {
        let c = &self.cfg;
        let dev = |v: String| Some((Scope::Device, v));
        let axis = |v: String| Some((Scope::Axis, v));
        match name {
            "device.id" | "deviceid" => dev(c.device_id.to_string()),
            "system.serial" => dev(c.serial.to_string()),
            "version" => dev(c.version.clone()),
            "version.build" => dev(c.build.to_string()),
            "comm.packet.size.max" => dev("80".into()),
            "system.axiscount" => dev("1".into()),
            "pos" => axis(self.position_steps().to_string()),
            "resolution" => axis(c.resolution.to_string()),
            "peripheral.id" | "peripheralid" => axis(c.peripheral_id.to_string()),
            "limit.min" => axis(c.limit_min.to_string()),
            "limit.max" => axis(c.limit_max.to_string()),
            // ASCII velocity unit: microsteps per 1/1.6384 s.
            "maxspeed" => axis(format!("{:.0}", c.speed_steps_s * 1.6384)),
            _ => None,
        }
    }

    /// `get <name>` on `axis`: device settings at axis 0 only; axis settings at axis 0 answer
    /// for every axis (one here).
    fn get(&self, axis: u8, id: Option<u8>, name: &str) -> Reply {
        match self.setting(name) {
            None => self.reply(axis, id, ReplyFlag::Rejected, "BADCOMMAND".into()),
            Some((Scope::Device, _)) if axis != 0 => {
                self.reply(axis, id, ReplyFlag::Rejected, "BADAXIS".into())
            }
            Some((_, v)) => self.reply(axis, id, ReplyFlag::Ok, v),
        }
    }

    /// Execute one parsed command and return the reply (None = not addressed to us). Replies
    /// carry the command's axis: 0 for device scope, like a real X-series device.
    fn execute(&self, dev: u8, axis: u8, id: Option<u8>, text: &str) -> Option<Reply> {
        if dev != 0 && dev != self.cfg.device {
            return None;
        }
        if axis != 0 && axis != self.cfg.axis {
            return Some(self.reply(axis, id, ReplyFlag::Rejected, "BADAXIS".into()));
        }
        self.pre_command_faults();
        let words: Vec<&str> = text.split_whitespace().collect();
        let is_motion = matches!(words.first(), Some(&"move") | Some(&"home"));
        if is_motion {
            let mut f = lock(&self.faults);
            if take(&mut f.reject) {
                let reason = f.reject_reason.clone();
                drop(f);
                return Some(self.reply(axis, id, ReplyFlag::Rejected, reason));
            }
        }
        let ok = |data: &str| Some(self.reply(axis, id, ReplyFlag::Ok, data.into()));
        let rejected = |why: &str| Some(self.reply(axis, id, ReplyFlag::Rejected, why.into()));
        match words.as_slice() {
            [] => ok("0"),
            ["home"] => {
                {
                    let mut st = lock(&self.st);
                    st.homed = true;
                    st.flags.retain(|w| *w != Warning::WR);
                }
                self.start_move(0);
                ok("0")
            }
            ["move", "abs", n] => {
                let Ok(to) = parse_steps(n) else {
                    return rejected("BADDATA");
                };
                if !lock(&self.st).homed {
                    return rejected("BADCOMMAND");
                }
                if to < self.cfg.limit_min || to > self.cfg.limit_max {
                    return rejected("BADDATA");
                }
                self.start_move(to);
                ok("0")
            }
            ["stop"] => {
                let mut st = lock(&self.st);
                self.update(&mut st);
                if st.mv.take().is_some() {
                    latch(&mut st.flags, Warning::NI);
                }
                drop(st);
                ok("0")
            }
            ["get", name] => Some(self.get(axis, id, name)),
            ["warnings"] => {
                let data = warnings_data(&self.warning_flags());
                ok(&data)
            }
            ["warnings", "clear"] => {
                // Replies with the flags it clears; WR persists until homed.
                let r = ok(&warnings_data(&self.warning_flags()));
                let mut st = lock(&self.st);
                let homed = st.homed;
                st.flags.retain(|w| *w == Warning::WR && !homed);
                r
            }
            _ => rejected("BADCOMMAND"),
        }
    }
}

/// What is left of a received line once DEL ([`crate::stage::DISCARD_PARTIAL`]) has
/// discarded the incomplete command before it, as a device does.
fn after_discard(line: String) -> String {
    let del = char::from(crate::stage::DISCARD_PARTIAL);
    match line.rfind(del) {
        Some(i) => line.get(i + del.len_utf8()..).unwrap_or("").to_string(),
        None => line,
    }
}

/// Serve the simulated stage on `stream` until EOF or an I/O error.
/// Cancel-safe in the sense that a drop ends the simulated device (its stream is dropped); a reply
/// being written is cut short, as when a real device loses power.
pub async fn serve_stage<S>(stream: S, sim: StageSim) -> std::io::Result<()>
where
    S: AsyncRead + AsyncWrite + Unpin + Send,
{
    let mut io = ascii_lines(BufReader::new(stream), 256);
    loop {
        let line = match read_line(&mut io).await? {
            LineRead::Eof => return Ok(()),
            LineRead::Bad(why) => {
                debug!(why, "stage sim: bad line ignored");
                continue;
            }
            LineRead::Line(l) => after_discard(l),
        };
        let (cmd, _) = match parse_command(&line) {
            Ok(c) => c,
            Err(CodecError::Checksum { .. }) => {
                // Real devices reply RJ with BADDATA? They drop the command; reply a rejection.
                let r = sim.reply(0, None, ReplyFlag::Rejected, "BADDATA".into());
                io.get_mut()
                    .get_mut()
                    .write_all(format_reply(&r, sim.cfg.checksum_replies).as_bytes())
                    .await?;
                io.get_mut().get_mut().flush().await?;
                continue;
            }
            Err(e) => {
                debug!(error = %e, line, "stage sim: unparseable command ignored");
                continue;
            }
        };
        let Some(reply) = sim.execute(cmd.device, cmd.axis, cmd.id, &cmd.text) else {
            continue;
        };
        let (silence, garbage, partial, badcs) = {
            let mut f = sim.faults();
            (
                take(&mut f.silence),
                take(&mut f.garbage),
                take(&mut f.partial),
                take(&mut f.bad_checksum),
            )
        };
        if silence {
            continue;
        }
        let mut out = if garbage {
            "@@ %$ garbage ~~\r\n".to_string()
        } else {
            format_reply(&reply, sim.cfg.checksum_replies || badcs)
        };
        if badcs {
            let body = out.trim_end().to_string();
            let (msg, cs) = body.split_at(body.len() - 2);
            let v = u8::from_str_radix(cs, 16).unwrap_or(0).wrapping_add(1);
            out = format!("{msg}{v:02X}\r\n");
        }
        if partial {
            out.truncate(out.len() / 2);
        }
        io.get_mut().get_mut().write_all(out.as_bytes()).await?;
        io.get_mut().get_mut().flush().await?;
    }
}

// ------------------------------------------------------------------------------------------------
// Gauge

/// Source of the true gauge value in mm (hook into the simulated world).
pub type ValueSource = Arc<dyn Fn() -> f64 + Send + Sync>;

/// Gauge fault injection (one-shot counters).
#[derive(Debug, Clone, Default)]
pub struct GaugeFaults {
    /// Ignore the next N requests.
    pub no_reply: u32,
    /// Answer the next N requests with a status line (`91 ...`).
    pub status: u32,
    /// Answer the next N requests in inches.
    pub inch: u32,
    /// Answer the next N requests with an out-of-range value (`+999.9999`).
    pub out_of_range: u32,
}

/// Simulated gauge: answers `request` (terminated by `\r` or `\n`) with `+dd.dddd mm\r\n`.
#[derive(Clone)]
pub struct GaugeSim {
    /// The request the gauge answers (without terminator), e.g. `?`.
    pub request: String,
    /// Where the value comes from.
    pub value: ValueSource,
    /// Faults.
    pub faults: Arc<Mutex<GaugeFaults>>,
}

impl std::fmt::Debug for GaugeSim {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GaugeSim")
            .field("request", &self.request)
            .finish_non_exhaustive()
    }
}

impl GaugeSim {
    /// Gauge answering `?` with the value from `value`.
    pub fn new(value: ValueSource) -> Self {
        Self {
            request: "?".into(),
            value,
            faults: Arc::new(Mutex::new(GaugeFaults::default())),
        }
    }

    /// Lock the fault configuration.
    pub fn faults(&self) -> std::sync::MutexGuard<'_, GaugeFaults> {
        lock(&self.faults)
    }
}

/// Serve the simulated gauge on `stream` until EOF.
/// Cancel-safe in the sense that a drop ends the simulated gauge (its stream is dropped); a reading
/// being written is cut short.
pub async fn serve_gauge<S>(stream: S, sim: GaugeSim) -> std::io::Result<()>
where
    S: AsyncRead + AsyncWrite + Unpin + Send,
{
    let mut io = gauge_lines(BufReader::new(stream), 64);
    loop {
        let line = match read_line(&mut io).await? {
            LineRead::Eof => return Ok(()),
            LineRead::Bad(_) => continue,
            LineRead::Line(l) => l,
        };
        if line.trim().is_empty() || line.trim() != sim.request {
            continue;
        }
        let (no_reply, status, inch, oor) = {
            let mut f = sim.faults();
            (
                take(&mut f.no_reply),
                take(&mut f.status),
                take(&mut f.inch),
                take(&mut f.out_of_range),
            )
        };
        if no_reply {
            continue;
        }
        let v = (sim.value)();
        let out = if status {
            "91 ERR\r\n".to_string()
        } else if inch {
            format!("{:+.5} in\r\n", v / 25.4)
        } else if oor {
            "+999.9999 mm\r\n".to_string()
        } else {
            format!("{v:+.4} mm\r\n")
        };
        io.get_mut().get_mut().write_all(out.as_bytes()).await?;
        io.get_mut().get_mut().flush().await?;
    }
}
