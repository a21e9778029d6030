//! Zaber ASCII protocol codec: command formatting/parsing, reply/info/alert parsing, LRC checksum.
//!
//! All functions are pure and never panic on arbitrary input.

use std::fmt;

/// Longest accepted message line (terminator excluded).
pub const MAX_LINE: usize = 256;

/// Typed codec error.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CodecError {
    /// Empty line.
    #[error("empty line")]
    Empty,
    /// Line longer than [`MAX_LINE`].
    #[error("line too long ({0} bytes)")]
    TooLong(usize),
    /// Non-ASCII or control character.
    #[error("non-printable character in line")]
    NotAscii,
    /// First character is not a known message type.
    #[error("unknown message type {0:?}")]
    BadType(char),
    /// The `:XX` checksum does not match.
    #[error("checksum mismatch: got {got:02X}, computed {computed:02X}")]
    Checksum {
        /// Checksum on the line.
        got: u8,
        /// Checksum computed from the line.
        computed: u8,
    },
    /// A field is missing or malformed.
    #[error("bad field {what}: {field:?}")]
    BadField {
        /// Field name.
        what: &'static str,
        /// Field text.
        field: String,
    },
}

/// LRC checksum: sum of `bytes` mod 256, two's complement.
pub fn lrc(bytes: &[u8]) -> u8 {
    let sum = bytes.iter().fold(0u8, |a, b| a.wrapping_add(*b));
    sum.wrapping_neg()
}

/// Append `:XX` (LRC of everything after the type character) to a message without terminator.
pub fn append_checksum(msg: &str) -> String {
    let body = msg.get(1..).unwrap_or("");
    format!("{msg}:{:02X}", lrc(body.as_bytes()))
}

/// Split off and verify a trailing `:XX` checksum. Returns the message without it and whether
/// one was present.
pub fn verify_checksum(line: &str) -> Result<(&str, bool), CodecError> {
    let bytes = line.as_bytes();
    let n = bytes.len();
    if n >= 4
        && bytes[n - 3] == b':'
        && bytes[n - 2].is_ascii_hexdigit()
        && bytes[n - 1].is_ascii_hexdigit()
    {
        let msg = &line[..n - 3];
        let got = u8::from_str_radix(&line[n - 2..], 16).map_err(|_| CodecError::BadField {
            what: "checksum",
            field: line[n - 2..].to_string(),
        })?;
        let computed = lrc(msg.get(1..).unwrap_or("").as_bytes());
        if got != computed {
            return Err(CodecError::Checksum { got, computed });
        }
        Ok((msg, true))
    } else {
        Ok((line, false))
    }
}

fn clean(raw: &str) -> Result<&str, CodecError> {
    let s = raw.trim_end_matches(['\r', '\n']);
    if s.len() > MAX_LINE {
        return Err(CodecError::TooLong(s.len()));
    }
    if !s.bytes().all(|b| (0x20..0x7f).contains(&b)) {
        return Err(CodecError::NotAscii);
    }
    if s.trim().is_empty() {
        return Err(CodecError::Empty);
    }
    Ok(s)
}

/// A host → device command.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Command {
    /// Device address (0 = all devices).
    pub device: u8,
    /// Axis (0 = all axes / device scope).
    pub axis: u8,
    /// Optional message id 0..=99.
    pub id: Option<u8>,
    /// Command words and data, e.g. `move abs 12345`; empty = status poll.
    pub text: String,
}

/// Format a command line (`/dev axis [id] command[:CS]\n`).
pub fn format_command(cmd: &Command, checksum: bool) -> String {
    let mut s = format!("/{} {}", cmd.device, cmd.axis);
    if let Some(id) = cmd.id {
        s.push_str(&format!(" {id}"));
    }
    let text = cmd.text.split_whitespace().collect::<Vec<_>>().join(" ");
    if !text.is_empty() {
        s.push(' ');
        s.push_str(&text);
    }
    if checksum {
        s = append_checksum(&s);
    }
    s.push('\n');
    s
}

fn num_u8(what: &'static str, t: &str) -> Result<u8, CodecError> {
    if t.is_empty() || t.len() > 3 || !t.bytes().all(|b| b.is_ascii_digit()) {
        return Err(CodecError::BadField {
            what,
            field: t.to_string(),
        });
    }
    t.parse::<u8>().map_err(|_| CodecError::BadField {
        what,
        field: t.to_string(),
    })
}

fn is_num(t: &str) -> bool {
    !t.is_empty() && t.len() <= 3 && t.bytes().all(|b| b.is_ascii_digit())
}

/// Parse a command line (device side). Leading numeric tokens are device, axis, id in order.
pub fn parse_command(raw: &str) -> Result<(Command, bool), CodecError> {
    let line = clean(raw)?;
    let Some(rest) = line.strip_prefix('/') else {
        return Err(CodecError::BadType(line.chars().next().unwrap_or(' ')));
    };
    let (rest, had_cs) = verify_checksum_cmd(rest)?;
    let toks: Vec<&str> = rest.split_whitespace().collect();
    let mut i = 0;
    let mut nums = Vec::new();
    while i < toks.len() && nums.len() < 3 && is_num(toks[i]) {
        nums.push(num_u8("address", toks[i])?);
        i += 1;
    }
    let id = nums.get(2).copied();
    if let Some(id) = id {
        if id > 99 {
            return Err(CodecError::BadField {
                what: "message id",
                field: id.to_string(),
            });
        }
    }
    Ok((
        Command {
            device: nums.first().copied().unwrap_or(0),
            axis: nums.get(1).copied().unwrap_or(0),
            id,
            text: toks[i..].join(" "),
        },
        had_cs,
    ))
}

fn verify_checksum_cmd(rest: &str) -> Result<(&str, bool), CodecError> {
    // The checksum covers the bytes after '/', which is exactly `rest` minus the suffix.
    let b = rest.as_bytes();
    let n = b.len();
    if n >= 3 && b[n - 3] == b':' && b[n - 2].is_ascii_hexdigit() && b[n - 1].is_ascii_hexdigit() {
        let msg = &rest[..n - 3];
        let got = u8::from_str_radix(&rest[n - 2..], 16).unwrap_or(0);
        let computed = lrc(msg.as_bytes());
        if got != computed {
            return Err(CodecError::Checksum { got, computed });
        }
        Ok((msg, true))
    } else {
        Ok((rest, false))
    }
}

/// Reply flag.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReplyFlag {
    /// `OK`: command accepted.
    Ok,
    /// `RJ`: command rejected.
    Rejected,
}

/// Axis status.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Status {
    /// `IDLE`.
    Idle,
    /// `BUSY`.
    Busy,
}

/// Two-character warning flag (`--`, `FF`, `WR`, `NI`, ...).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Warning(pub [u8; 2]);

/// Class of a warning flag.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WarningClass {
    /// `--`: no warning.
    None,
    /// `F*`: fault.
    Fault,
    /// `W*`: warning.
    Warning,
    /// `N*`: notice.
    Notice,
    /// Anything else.
    Other,
}

impl Warning {
    /// No warning (`--`).
    pub const NONE: Warning = Warning(*b"--");
    /// Fault, stalled (`FF`/`FS` family); `FF` here.
    pub const FF: Warning = Warning(*b"FF");
    /// No reference position (home first).
    pub const WR: Warning = Warning(*b"WR");
    /// Movement interrupted.
    pub const NI: Warning = Warning(*b"NI");
    /// Unexpected limit trigger: a move stopped on a limit sensor it did not expect.
    pub const WL: Warning = Warning(*b"WL");
    /// Displaced when stationary: the idle axis was pushed off its position.
    pub const WM: Warning = Warning(*b"WM");

    /// Parse two characters.
    pub fn parse(t: &str) -> Result<Self, CodecError> {
        let b = t.as_bytes();
        if b.len() == 2 && b.iter().all(|c| c.is_ascii_uppercase() || *c == b'-') {
            Ok(Warning([b[0], b[1]]))
        } else {
            Err(CodecError::BadField {
                what: "warning flag",
                field: t.to_string(),
            })
        }
    }

    /// Classify the flag by its first character.
    pub fn class(&self) -> WarningClass {
        match self.0[0] {
            b'-' if self.0[1] == b'-' => WarningClass::None,
            b'F' => WarningClass::Fault,
            b'W' => WarningClass::Warning,
            b'N' => WarningClass::Notice,
            _ => WarningClass::Other,
        }
    }

    /// Flag as text.
    pub fn as_str(&self) -> &str {
        std::str::from_utf8(&self.0).unwrap_or("??")
    }
}

impl fmt::Display for Warning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A `@` reply.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Reply {
    /// Device address.
    pub device: u8,
    /// Axis.
    pub axis: u8,
    /// Message id, if the command carried one.
    pub id: Option<u8>,
    /// OK or RJ.
    pub flag: ReplyFlag,
    /// IDLE or BUSY.
    pub status: Status,
    /// Highest-priority warning flag.
    pub warning: Warning,
    /// Data (rest of the line, single-space joined); for RJ the reason.
    pub data: String,
}

/// Any message a device sends.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Message {
    /// `@` reply.
    Reply(Reply),
    /// `#` info line.
    Info {
        /// Device address.
        device: u8,
        /// Axis.
        axis: u8,
        /// Text after the address fields.
        text: String,
    },
    /// `!` alert (unsolicited).
    Alert {
        /// Device address.
        device: u8,
        /// Axis.
        axis: u8,
        /// Status.
        status: Status,
        /// Warning flag.
        warning: Warning,
    },
}

fn status(t: &str) -> Result<Status, CodecError> {
    match t {
        "IDLE" => Ok(Status::Idle),
        "BUSY" => Ok(Status::Busy),
        o => Err(CodecError::BadField {
            what: "status",
            field: o.to_string(),
        }),
    }
}

fn tok<'a>(toks: &[&'a str], i: usize, what: &'static str) -> Result<&'a str, CodecError> {
    toks.get(i).copied().ok_or(CodecError::BadField {
        what,
        field: String::new(),
    })
}

/// Parse a device message line (`@`, `#` or `!`), verifying an optional checksum.
pub fn parse_message(raw: &str) -> Result<Message, CodecError> {
    let line = clean(raw)?;
    let (line, _) = verify_checksum(line)?;
    let mut chars = line.chars();
    let ty = chars.next().ok_or(CodecError::Empty)?;
    let toks: Vec<&str> = chars.as_str().split_whitespace().collect();
    match ty {
        '@' => {
            let device = num_u8("device", tok(&toks, 0, "device")?)?;
            let axis = num_u8("axis", tok(&toks, 1, "axis")?)?;
            let mut i = 2;
            let mut id = None;
            let t = tok(&toks, i, "flag")?;
            if is_num(t) {
                id = Some(num_u8("message id", t)?);
                i += 1;
            }
            let flag = match tok(&toks, i, "flag")? {
                "OK" => ReplyFlag::Ok,
                "RJ" => ReplyFlag::Rejected,
                o => {
                    return Err(CodecError::BadField {
                        what: "flag",
                        field: o.to_string(),
                    })
                }
            };
            let st = status(tok(&toks, i + 1, "status")?)?;
            let warning = Warning::parse(tok(&toks, i + 2, "warning")?)?;
            let data = toks.get(i + 3..).unwrap_or(&[]).join(" ");
            Ok(Message::Reply(Reply {
                device,
                axis,
                id,
                flag,
                status: st,
                warning,
                data,
            }))
        }
        '#' => {
            let device = num_u8("device", tok(&toks, 0, "device")?)?;
            let axis = num_u8("axis", tok(&toks, 1, "axis")?)?;
            let mut i = 2;
            if toks.get(2).is_some_and(|t| is_num(t)) {
                i = 3;
            }
            Ok(Message::Info {
                device,
                axis,
                text: toks.get(i..).unwrap_or(&[]).join(" "),
            })
        }
        '!' => {
            let device = num_u8("device", tok(&toks, 0, "device")?)?;
            let axis = num_u8("axis", tok(&toks, 1, "axis")?)?;
            let st = status(tok(&toks, 2, "status")?)?;
            let warning = Warning::parse(tok(&toks, 3, "warning")?)?;
            Ok(Message::Alert {
                device,
                axis,
                status: st,
                warning,
            })
        }
        other => Err(CodecError::BadType(other)),
    }
}

/// Format a reply line (device side), `\r\n` terminated.
pub fn format_reply(r: &Reply, checksum: bool) -> String {
    let mut s = format!("@{:02} {}", r.device, r.axis);
    if let Some(id) = r.id {
        s.push_str(&format!(" {id}"));
    }
    s.push_str(match r.flag {
        ReplyFlag::Ok => " OK",
        ReplyFlag::Rejected => " RJ",
    });
    s.push_str(match r.status {
        Status::Idle => " IDLE",
        Status::Busy => " BUSY",
    });
    s.push(' ');
    s.push_str(r.warning.as_str());
    let data = r.data.split_whitespace().collect::<Vec<_>>().join(" ");
    s.push(' ');
    s.push_str(if data.is_empty() { "0" } else { &data });
    if checksum {
        s = append_checksum(&s);
    }
    s.push_str("\r\n");
    s
}

/// Parse reply data as an integer (microsteps).
pub fn parse_steps(data: &str) -> Result<i64, CodecError> {
    let t = data.split_whitespace().next().unwrap_or("");
    let digits = t.strip_prefix(['-', '+']).unwrap_or(t);
    if digits.is_empty() || digits.len() > 15 || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return Err(CodecError::BadField {
            what: "position",
            field: data.to_string(),
        });
    }
    t.parse::<i64>().map_err(|_| CodecError::BadField {
        what: "position",
        field: data.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn examples() {
        let m = parse_message("@01 1 OK IDLE -- 12345\r\n").unwrap();
        let Message::Reply(r) = m else { panic!() };
        assert_eq!((r.device, r.axis, r.id), (1, 1, None));
        assert_eq!(r.flag, ReplyFlag::Ok);
        assert_eq!(r.status, Status::Idle);
        assert_eq!(r.warning, Warning::NONE);
        assert_eq!(parse_steps(&r.data).unwrap(), 12345);
        let Message::Reply(r) = parse_message("@01 1 12 RJ IDLE -- BADCOMMAND").unwrap() else {
            panic!()
        };
        assert_eq!(r.id, Some(12));
        assert_eq!(r.flag, ReplyFlag::Rejected);
        assert_eq!(r.data, "BADCOMMAND");
        assert!(matches!(
            parse_message("!01 1 IDLE --").unwrap(),
            Message::Alert { .. }
        ));
        assert!(matches!(
            parse_message("#01 1 Visit www.zaber.com").unwrap(),
            Message::Info { .. }
        ));
        assert_eq!(Warning::parse("FF").unwrap().class(), WarningClass::Fault);
        assert_eq!(Warning::WR.class(), WarningClass::Warning);
        assert_eq!(Warning::NI.class(), WarningClass::Notice);
    }

    #[test]
    fn checksum() {
        // Known example from the Zaber manual: "/1 1 move abs 10000:" + LRC.
        let s = append_checksum("/1 1 move abs 10000");
        let (cmd, cs) = parse_command(&s).unwrap();
        assert!(cs);
        assert_eq!(cmd.text, "move abs 10000");
        let line = format_reply(
            &Reply {
                device: 1,
                axis: 1,
                id: Some(3),
                flag: ReplyFlag::Ok,
                status: Status::Busy,
                warning: Warning::NONE,
                data: "0".into(),
            },
            true,
        );
        assert!(parse_message(&line).is_ok());
        let mut bad = line.trim_end().to_string();
        let last = bad.pop().unwrap();
        bad.push(if last == '0' { '1' } else { '0' });
        assert!(matches!(
            parse_message(&bad),
            Err(CodecError::Checksum { .. })
        ));
        assert_eq!(lrc(b""), 0);
        assert_eq!(lrc(&[1]), 0xFF);
    }

    #[test]
    fn commands() {
        let (c, _) = parse_command("/1 home\n").unwrap();
        assert_eq!(
            (c.device, c.axis, c.id, c.text.as_str()),
            (1, 0, None, "home")
        );
        let (c, _) = parse_command("/1 1\n").unwrap();
        assert_eq!((c.device, c.axis, c.text.as_str()), (1, 1, ""));
        let (c, _) = parse_command("/\n").unwrap();
        assert_eq!((c.device, c.axis), (0, 0));
        assert_eq!(
            format_command(
                &Command {
                    device: 1,
                    axis: 1,
                    id: Some(7),
                    text: "move abs 5".into()
                },
                false
            ),
            "/1 1 7 move abs 5\n"
        );
        assert!(parse_command("/1 1 100 get pos").is_err());
    }
}
