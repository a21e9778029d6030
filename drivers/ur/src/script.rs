//! URScript for the client interfaces (primary 30001, secondary 30002, real-time 30003):
//! the text this crate sends (`movej`, `stopj` wrapped in a `def ...(): ... end` program, as
//! python-urx and ur_rtde's script client send programs) and the subset the simulated
//! controller runs.
//!
//! A controller compiles a received program as a whole: one statement it does not know and
//! nothing of the program runs. The simulator does the same with [`parse_program`].

use thiserror::Error;

/// URScript `movej` default joint acceleration, rad/s² (URScript manual).
pub const MOVEJ_DEFAULT_A: f64 = 1.4;
/// URScript `movej` default joint speed, rad/s (URScript manual).
pub const MOVEJ_DEFAULT_V: f64 = 1.05;

/// One statement of the subset.
#[derive(Debug, Clone, PartialEq)]
pub enum Statement {
    /// `movej(q, a=, v=, t=, r=)` with joint positions in rad.
    MoveJ {
        /// Target joint positions, rad.
        q: [f64; 6],
        /// Leading-axis acceleration, rad/s².
        a: f64,
        /// Leading-axis speed, rad/s.
        v: f64,
        /// Time for the move, s (0: from `a` and `v`).
        t: f64,
        /// Blend radius, m.
        r: f64,
    },
    /// `stopj(a)`: decelerate every joint to rest at `a` rad/s².
    StopJ {
        /// Deceleration, rad/s².
        a: f64,
    },
    /// `sleep(t)`, s.
    Sleep(f64),
}

/// A program text that does not compile in the subset (or bad values to format).
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error("URScript line {line}: {why}")]
pub struct ScriptError {
    /// 1-based line of the program (0: not tied to a line).
    pub line: usize,
    /// What is wrong.
    pub why: String,
}

fn err(line: usize, why: impl Into<String>) -> ScriptError {
    ScriptError {
        line,
        why: why.into(),
    }
}

fn check_finite(what: &str, x: f64) -> Result<f64, ScriptError> {
    if x.is_finite() {
        Ok(x)
    } else {
        Err(err(0, format!("{what} is not a finite number ({x})")))
    }
}

/// `movej([q1, ..., q6], a=A, v=V)` (joint positions in rad, `a` rad/s², `v` rad/s).
/// Refuses non-finite values and non-positive `a`/`v`.
pub fn movej(q: &[f64; 6], a: f64, v: f64) -> Result<String, ScriptError> {
    for (i, x) in q.iter().enumerate() {
        check_finite(&format!("q{}", i + 1), *x)?;
    }
    for (name, x) in [("a", a), ("v", v)] {
        if check_finite(name, x)? <= 0.0 {
            return Err(err(0, format!("{name} must be positive, got {x}")));
        }
    }
    let q: Vec<String> = q.iter().map(|x| format!("{x}")).collect();
    Ok(format!("movej([{}], a={a}, v={v})", q.join(", ")))
}

/// `stopj(A)`, `a` rad/s² (positive, finite).
pub fn stopj(a: f64) -> Result<String, ScriptError> {
    if check_finite("a", a)? <= 0.0 {
        return Err(err(0, format!("a must be positive, got {a}")));
    }
    Ok(format!("stopj({a})"))
}

/// A program `def name():` + the statements, indented + `end`, newline-terminated.
/// `name` must be a URScript identifier.
pub fn program(name: &str, statements: &[String]) -> Result<String, ScriptError> {
    if !is_ident(name) {
        return Err(err(0, format!("{name:?} is not a URScript identifier")));
    }
    let mut out = format!("def {name}():\n");
    for s in statements {
        if s.contains('\n') {
            return Err(err(0, "a statement spans lines"));
        }
        out.push_str("  ");
        out.push_str(s);
        out.push('\n');
    }
    out.push_str("end\n");
    Ok(out)
}

fn is_ident(s: &str) -> bool {
    let mut c = s.chars();
    c.next()
        .is_some_and(|f| f.is_ascii_alphabetic() || f == '_')
        && c.all(|x| x.is_ascii_alphanumeric() || x == '_')
}

/// A parsed argument: a number or a list of numbers, maybe named.
#[derive(Debug)]
enum Arg {
    Num(f64),
    List(Vec<f64>),
}

fn parse_number(s: &str, line: usize) -> Result<f64, ScriptError> {
    let s = s.trim();
    let ok = !s.is_empty()
        && s.bytes()
            .all(|b| b.is_ascii_digit() || matches!(b, b'.' | b'e' | b'E' | b'+' | b'-'))
        && s.bytes().any(|b| b.is_ascii_digit());
    match s.parse::<f64>() {
        Ok(x) if ok && x.is_finite() => Ok(x),
        _ => Err(err(line, format!("{s:?} is not a number"))),
    }
}

fn parse_arg(s: &str, line: usize) -> Result<Arg, ScriptError> {
    let s = s.trim();
    if let Some(inner) = s.strip_prefix('[') {
        let inner = inner
            .strip_suffix(']')
            .ok_or_else(|| err(line, "unclosed list"))?;
        let v = inner
            .split(',')
            .map(|x| parse_number(x, line))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Arg::List(v))
    } else if s.starts_with("p[") {
        Err(err(line, "poses (p[...]) are not in the simulated subset"))
    } else {
        parse_number(s, line).map(Arg::Num)
    }
}

/// Splits `a, [b, c], d=e` at top-level commas.
fn split_args(s: &str, line: usize) -> Result<Vec<&str>, ScriptError> {
    let mut out = Vec::new();
    let (mut depth, mut from) = (0i32, 0);
    for (i, ch) in s.char_indices() {
        match ch {
            '[' | '(' => depth += 1,
            ']' | ')' => depth -= 1,
            ',' if depth == 0 => {
                out.push(&s[from..i]);
                from = i + 1;
            }
            _ => {}
        }
        if depth < 0 {
            return Err(err(line, "unbalanced brackets"));
        }
    }
    if depth != 0 {
        return Err(err(line, "unbalanced brackets"));
    }
    if !s[from..].trim().is_empty() || !out.is_empty() {
        out.push(&s[from..]);
    }
    Ok(out)
}

/// Binds positional and named arguments to `params`; missing ones are `None`.
fn bind(args: &str, params: &[&str], line: usize) -> Result<Vec<Option<Arg>>, ScriptError> {
    let mut bound: Vec<Option<Arg>> = params.iter().map(|_| None).collect();
    let mut named = false;
    for (i, a) in split_args(args, line)?.into_iter().enumerate() {
        let eq = a.find('=').filter(|&k| !a[..k].contains('['));
        let (slot, value) = match eq {
            Some(k) => {
                named = true;
                let name = a[..k].trim();
                let slot = params
                    .iter()
                    .position(|p| *p == name)
                    .ok_or_else(|| err(line, format!("unknown argument {name:?}")))?;
                (slot, &a[k + 1..])
            }
            None if named => return Err(err(line, "positional argument after a named one")),
            None if i < params.len() => (i, a),
            None => return Err(err(line, "too many arguments")),
        };
        if bound[slot].is_some() {
            return Err(err(line, format!("argument {} given twice", params[slot])));
        }
        bound[slot] = Some(parse_arg(value, line)?);
    }
    Ok(bound)
}

fn num(a: Option<Arg>, name: &str, default: Option<f64>, line: usize) -> Result<f64, ScriptError> {
    match a {
        Some(Arg::Num(x)) => Ok(x),
        Some(Arg::List(_)) => Err(err(line, format!("{name} must be a number"))),
        None => default.ok_or_else(|| err(line, format!("missing argument {name}"))),
    }
}

fn statement(text: &str, line: usize) -> Result<Statement, ScriptError> {
    let open = text
        .find('(')
        .ok_or_else(|| err(line, format!("not a function call: {text:?}")))?;
    let name = text[..open].trim();
    let args = text[open + 1..]
        .trim_end()
        .strip_suffix(')')
        .ok_or_else(|| err(line, "missing ')'"))?;
    match name {
        "movej" => {
            let mut b = bind(args, &["q", "a", "v", "t", "r"], line)?.into_iter();
            let q = match b.next().flatten() {
                Some(Arg::List(v)) if v.len() == 6 => [v[0], v[1], v[2], v[3], v[4], v[5]],
                Some(Arg::List(v)) => {
                    return Err(err(line, format!("movej needs 6 joints, got {}", v.len())))
                }
                _ => return Err(err(line, "movej needs a joint list [q1, ..., q6]")),
            };
            let a = num(b.next().flatten(), "a", Some(MOVEJ_DEFAULT_A), line)?;
            let v = num(b.next().flatten(), "v", Some(MOVEJ_DEFAULT_V), line)?;
            let t = num(b.next().flatten(), "t", Some(0.0), line)?;
            let r = num(b.next().flatten(), "r", Some(0.0), line)?;
            if a <= 0.0 || v <= 0.0 || t < 0.0 || r < 0.0 {
                return Err(err(
                    line,
                    "movej: a and v must be positive, t and r not negative",
                ));
            }
            Ok(Statement::MoveJ { q, a, v, t, r })
        }
        "stopj" => {
            let a = num(bind(args, &["a"], line)?.pop().flatten(), "a", None, line)?;
            if a <= 0.0 {
                return Err(err(line, "stopj: a must be positive"));
            }
            Ok(Statement::StopJ { a })
        }
        "sleep" => {
            let t = num(bind(args, &["t"], line)?.pop().flatten(), "t", None, line)?;
            if t < 0.0 {
                return Err(err(line, "sleep: t must not be negative"));
            }
            Ok(Statement::Sleep(t))
        }
        other => Err(err(
            line,
            format!("{other:?} is not in the simulated URScript subset"),
        )),
    }
}

/// Parses a whole program: bare statements, or one `def name():`/`sec name():` ... `end`
/// block; `#` comments and blank lines ignored. Any unknown statement fails the program.
pub fn parse_program(text: &str) -> Result<Vec<Statement>, ScriptError> {
    let mut out = Vec::new();
    let mut open_def = false;
    let mut closed = false;
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let t = raw.split('#').next().unwrap_or("").trim();
        if t.is_empty() {
            continue;
        }
        if closed {
            return Err(err(line, "text after the program's end"));
        }
        let head = t.strip_prefix("def ").or_else(|| t.strip_prefix("sec "));
        if let Some(head) = head {
            if open_def {
                return Err(err(line, "nested def"));
            }
            let name = head
                .trim()
                .strip_suffix(':')
                .and_then(|h| h.trim().strip_suffix("()"))
                .ok_or_else(|| err(line, "def must read `def name():`"))?;
            if !is_ident(name.trim()) || !out.is_empty() {
                return Err(err(line, "bad def"));
            }
            open_def = true;
            continue;
        }
        if t == "end" {
            if !open_def {
                return Err(err(line, "`end` without `def`"));
            }
            open_def = false;
            closed = true;
            continue;
        }
        out.push(statement(t, line)?);
    }
    if open_def {
        return Err(err(0, "`def` without `end`"));
    }
    Ok(out)
}
