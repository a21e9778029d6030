//! Device simulators (server side): a Zaber ASCII stage and a generic RS-232 gauge, each served
//! over any async byte stream, with deterministic one-shot fault injection.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt, BufReader};
use tracing::debug;

use crate::ascii::{
    format_reply, parse_command, parse_steps, CodecError, Reply, ReplyFlag, Status, Warning,
};
use crate::lineio::{read_line_until, LineRead};

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
    /// Final flag to latch when the move ends (NI / fault).
    end_flag: Option<Warning>,
    stall: bool,
}

#[derive(Debug)]
struct StageState {
    pos: i64,
    homed: bool,
    mv: Option<Move>,
    flag: Warning,
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
            flag: if cfg.homed {
                Warning::NONE
            } else {
                Warning::WR
            },
        };
        Self {
            cfg,
            st: Arc::new(Mutex::new(st)),
            faults: Arc::new(Mutex::new(StageFaults::default())),
        }
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
                st.flag = f;
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

    fn reply(&self, id: Option<u8>, flag: ReplyFlag, data: String) -> Reply {
        let mut st = lock(&self.st);
        self.update(&mut st);
        Reply {
            device: self.cfg.device,
            axis: self.cfg.axis,
            id,
            flag,
            status: if st.mv.is_some() {
                Status::Busy
            } else {
                Status::Idle
            },
            warning: st.flag,
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

    /// Execute one parsed command and return the reply (None = not addressed to us).
    fn execute(&self, dev: u8, axis: u8, id: Option<u8>, text: &str) -> Option<Reply> {
        if dev != 0 && dev != self.cfg.device {
            return None;
        }
        if axis != 0 && axis != self.cfg.axis {
            return Some(self.reply(id, ReplyFlag::Rejected, "BADAXIS".into()));
        }
        {
            let mut f = lock(&self.faults);
            if take(&mut f.lose_home) {
                let mut st = lock(&self.st);
                st.homed = false;
                st.flag = Warning::WR;
            }
        }
        let words: Vec<&str> = text.split_whitespace().collect();
        let is_motion = matches!(words.first(), Some(&"move") | Some(&"home"));
        if is_motion {
            let mut f = lock(&self.faults);
            if take(&mut f.reject) {
                let reason = f.reject_reason.clone();
                drop(f);
                return Some(self.reply(id, ReplyFlag::Rejected, reason));
            }
        }
        match words.as_slice() {
            [] => Some(self.reply(id, ReplyFlag::Ok, "0".into())),
            ["home"] => {
                {
                    let mut st = lock(&self.st);
                    st.homed = true;
                    if st.flag == Warning::WR {
                        st.flag = Warning::NONE;
                    }
                }
                self.start_move(0);
                Some(self.reply(id, ReplyFlag::Ok, "0".into()))
            }
            ["move", "abs", n] => {
                let Ok(to) = parse_steps(n) else {
                    return Some(self.reply(id, ReplyFlag::Rejected, "BADDATA".into()));
                };
                if !lock(&self.st).homed {
                    return Some(self.reply(id, ReplyFlag::Rejected, "BADCOMMAND".into()));
                }
                if to < self.cfg.limit_min || to > self.cfg.limit_max {
                    return Some(self.reply(id, ReplyFlag::Rejected, "BADDATA".into()));
                }
                self.start_move(to);
                Some(self.reply(id, ReplyFlag::Ok, "0".into()))
            }
            ["stop"] => {
                let mut st = lock(&self.st);
                self.update(&mut st);
                if st.mv.take().is_some() {
                    st.flag = Warning::NI;
                }
                drop(st);
                Some(self.reply(id, ReplyFlag::Ok, "0".into()))
            }
            ["get", "pos"] => {
                let p = self.position_steps();
                Some(self.reply(id, ReplyFlag::Ok, p.to_string()))
            }
            ["warnings"] => {
                let w = lock(&self.st).flag;
                let data = if w == Warning::NONE {
                    "00".to_string()
                } else {
                    format!("01 {w}")
                };
                Some(self.reply(id, ReplyFlag::Ok, data))
            }
            ["warnings", "clear"] => {
                let r = self.reply(id, ReplyFlag::Ok, "0".into());
                let mut st = lock(&self.st);
                // WR persists until homed.
                st.flag = if st.homed { Warning::NONE } else { Warning::WR };
                Some(r)
            }
            _ => Some(self.reply(id, ReplyFlag::Rejected, "BADCOMMAND".into())),
        }
    }
}

/// Serve the simulated stage on `stream` until EOF or an I/O error.
pub async fn serve_stage<S>(stream: S, sim: StageSim) -> std::io::Result<()>
where
    S: AsyncRead + AsyncWrite + Unpin + Send,
{
    let mut io = BufReader::new(stream);
    loop {
        let line = match read_line_until(&mut io, 256, b"\n").await? {
            LineRead::Eof => return Ok(()),
            LineRead::Bad(why) => {
                debug!(why, "stage sim: bad line ignored");
                continue;
            }
            LineRead::Line(l) => l,
        };
        let (cmd, _) = match parse_command(&line) {
            Ok(c) => c,
            Err(CodecError::Checksum { .. }) => {
                // Real devices reply RJ with BADDATA? They drop the command; reply a rejection.
                let r = sim.reply(None, ReplyFlag::Rejected, "BADDATA".into());
                io.get_mut()
                    .write_all(format_reply(&r, sim.cfg.checksum_replies).as_bytes())
                    .await?;
                io.get_mut().flush().await?;
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
        io.get_mut().write_all(out.as_bytes()).await?;
        io.get_mut().flush().await?;
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
pub async fn serve_gauge<S>(stream: S, sim: GaugeSim) -> std::io::Result<()>
where
    S: AsyncRead + AsyncWrite + Unpin + Send,
{
    let mut io = BufReader::new(stream);
    loop {
        let line = match read_line_until(&mut io, 64, b"\r\n").await? {
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
        io.get_mut().write_all(out.as_bytes()).await?;
        io.get_mut().flush().await?;
    }
}
