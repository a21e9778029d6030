//! A schema-driven fuzz of every route of `cellcal serve`: the test reads the daemon's own
//! OpenAPI document (`GET /api/openapi.json`) and, for every path and method in it, sends bad
//! ids, bad query and header values, bodies built from the request schema and then broken
//! (required fields missing, wrong types, unknown fields, huge numbers, not JSON, not UTF-8,
//! oversized, deeply nested, wrong or missing content type), wrong methods and missing or
//! unknown tokens, plus a seeded stream of random combinations. Every answer must be below 500,
//! every error answer `application/json` with a string `"error"`, and the daemon must still
//! answer (and still run) afterwards. Deterministic (ChaCha8, fixed seed); bounded (a fixed
//! number of requests, a short read timeout; a few seconds on an idle machine).

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{json, Map, Value};

use super::serve::{fast_config, get, post, start, Server};

/// What a request got back.
#[derive(Debug)]
struct Answer {
    status: u16,
    content_type: String,
    body: Vec<u8>,
}

/// One HTTP/1.1 request on a fresh connection (`connection: close`); an event stream's body is
/// not read.
fn send(s: &Server, method: &str, target: &str, headers: &[(&str, &str)], body: &[u8]) -> Answer {
    let addr = s.base.strip_prefix("http://").expect("plain http");
    let mut c = TcpStream::connect(addr).expect("connect");
    c.set_read_timeout(Some(Duration::from_secs(20)))
        .expect("timeout");
    let mut head = format!("{method} {target} HTTP/1.1\r\nhost: {addr}\r\nconnection: close\r\n");
    if !body.is_empty() || method == "POST" {
        head.push_str(&format!("content-length: {}\r\n", body.len()));
    }
    for (k, v) in headers {
        head.push_str(&format!("{k}: {v}\r\n"));
    }
    head.push_str("\r\n");
    // the server may answer (413) and close before it has read all of a large body
    let _ = c.write_all(head.as_bytes()).and_then(|_| c.write_all(body));
    let mut raw = Vec::new();
    let mut buf = [0u8; 8192];
    let split = loop {
        if let Some(i) = raw.windows(4).position(|w| w == b"\r\n\r\n") {
            break i;
        }
        let n = c.read(&mut buf).unwrap_or_else(|e| {
            panic!(
                "{method} {target}: no answer ({e}); got {:?}",
                String::from_utf8_lossy(&raw)
            )
        });
        assert!(
            n > 0,
            "{method} {target}: connection closed without an answer"
        );
        raw.extend_from_slice(&buf[..n]);
    };
    let head = String::from_utf8_lossy(&raw[..split]).to_ascii_lowercase();
    let status = head
        .split(' ')
        .nth(1)
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("{method} {target}: status line of {head}"));
    let header = |name: &str| {
        head.lines()
            .find_map(|l| l.strip_prefix(&format!("{name}: ")))
            .unwrap_or("")
            .to_owned()
    };
    let content_type = header("content-type");
    let mut body = raw[split + 4..].to_vec();
    if !content_type.starts_with("text/event-stream") {
        let _ = c.read_to_end(&mut body);
        if header("transfer-encoding") == "chunked" {
            body = dechunk(&body);
        }
    }
    Answer {
        status,
        content_type,
        body,
    }
}

/// The payload of a chunked body.
fn dechunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    while let Some(i) = b.windows(2).position(|w| w == b"\r\n") {
        let size = usize::from_str_radix(String::from_utf8_lossy(&b[..i]).trim(), 16).unwrap_or(0);
        if size == 0 || b.len() < i + 2 + size {
            break;
        }
        out.extend_from_slice(&b[i + 2..i + 2 + size]);
        b = &b[(i + 4 + size).min(b.len())..];
    }
    out
}

/// The fuzzer: the daemon, its OpenAPI document, the seeded generator, the tally.
struct Fuzz<'a> {
    s: &'a Server,
    doc: Value,
    rng: ChaCha8Rng,
    sent: usize,
    by_status: std::collections::BTreeMap<u16, usize>,
}

/// Path ids that are not a campaign's.
const BAD_IDS: [&str; 11] = [
    "abc",
    "-1",
    "0",
    "99999",
    "1.5",
    "99999999999999999999999",
    "%00",
    "%ff%fe",
    "1%20OR%201=1",
    "%2e%2e%2fetc",
    "",
];

/// Values of the wrong type (or out of range) for any field, as JSON text.
const WRONG_VALUES: [&str; 14] = [
    "null",
    "true",
    "\"text\"",
    "1.5",
    "-1",
    "0",
    "1e308",
    "-1e308",
    "18446744073709551616",
    "9223372036854775807",
    "[]",
    "{}",
    "[1,2,3]",
    "{\"a\":{\"b\":[null]}}",
];

/// Bodies that are not a JSON object of the schema at all.
fn broken_bodies() -> Vec<Vec<u8>> {
    let mut v: Vec<Vec<u8>> = [
        "",
        "{",
        "}",
        "[]",
        "null",
        "123",
        "\"s\"",
        "{\"a\":}",
        "{'a': 1}",
        "NaN",
        "{\"x\": NaN}",
        "{\"x\": Infinity}",
        "\u{feff}{}",
    ]
    .iter()
    .map(|b| b.as_bytes().to_vec())
    .collect();
    v.push(vec![0xff, 0xfe, 0x00, 0x7b]);
    v.push(b"{\"command\": \"\xff\"}".to_vec());
    v.push(format!("{}{}", "[".repeat(5000), "]".repeat(5000)).into_bytes());
    v.push(format!("{{\"x\": \"{}\"}}", "a".repeat(70 * 1024)).into_bytes());
    v.push(vec![b' '; 65 * 1024]);
    v
}

impl Fuzz<'_> {
    /// A fuzzer of `s` (its OpenAPI document read), seeded with `seed`.
    fn of(s: &Server, seed: u64) -> Fuzz<'_> {
        let (code, doc) = get(s, "/api/openapi.json");
        assert_eq!(code, 200);
        Fuzz {
            s,
            doc,
            rng: ChaCha8Rng::seed_from_u64(seed),
            sent: 0,
            by_status: Default::default(),
        }
    }

    /// Send, tally, and check the answer: below 500; an error is JSON `{"error": "…"}`.
    fn check(&mut self, method: &str, target: &str, headers: &[(&str, &str)], body: &[u8]) -> u16 {
        let a = send(self.s, method, target, headers, body);
        self.sent += 1;
        *self.by_status.entry(a.status).or_default() += 1;
        let what = format!(
            "{method} {target} {headers:?} body {:?}",
            String::from_utf8_lossy(&body[..body.len().min(200)])
        );
        assert!(
            a.status < 500,
            "{what}: {} {:?}",
            a.status,
            String::from_utf8_lossy(&a.body)
        );
        if a.status >= 400 {
            assert!(
                a.content_type.starts_with("application/json"),
                "{what}: {} with content type `{}`",
                a.status,
                a.content_type
            );
            let v: Value = serde_json::from_slice(&a.body)
                .unwrap_or_else(|e| panic!("{what}: {e}: {:?}", String::from_utf8_lossy(&a.body)));
            assert!(v["error"].is_string(), "{what}: {v}");
            assert_eq!(v.as_object().map(Map::len), Some(1), "{what}: {v}");
        }
        a.status
    }

    /// A request with the token (and a JSON content type when there is a body).
    fn authed(&mut self, method: &str, target: &str, body: &[u8]) -> u16 {
        let auth = format!("Bearer {}", self.s.token);
        let mut h = vec![("authorization", auth.as_str())];
        if matches!(method, "POST" | "PUT" | "PATCH") {
            h.push(("content-type", "application/json"));
        }
        self.check(method, target, &h, body)
    }

    /// `$ref` resolved against the document's components.
    fn resolve<'s>(&'s self, schema: &'s Value) -> &'s Value {
        match schema["$ref"].as_str() {
            Some(r) => {
                let name = r.rsplit('/').next().unwrap_or("");
                &self.doc["components"]["schemas"][name]
            }
            None => schema,
        }
    }

    /// A value of `schema`, small numbers only (a body that is valid creates at most a small
    /// campaign).
    fn instance(&mut self, schema: &Value, depth: usize) -> Value {
        let schema = self.resolve(schema).clone();
        if depth > 6 {
            return Value::Null;
        }
        for key in ["oneOf", "anyOf"] {
            if let Some(alts) = schema[key].as_array().filter(|a| !a.is_empty()) {
                let k = self.rng.random_range(0..alts.len());
                return self.instance(&alts[k], depth + 1);
            }
        }
        if let Some(e) = schema["enum"].as_array().filter(|e| !e.is_empty()) {
            return e[self.rng.random_range(0..e.len())].clone();
        }
        let ty = match &schema["type"] {
            Value::String(t) => t.clone(),
            Value::Array(ts) => ts
                .iter()
                .filter_map(Value::as_str)
                .find(|t| *t != "null")
                .unwrap_or("null")
                .to_owned(),
            _ => "null".to_owned(),
        };
        match ty.as_str() {
            "object" => {
                let required: Vec<String> = schema["required"]
                    .as_array()
                    .map(|r| {
                        r.iter()
                            .filter_map(|v| v.as_str().map(String::from))
                            .collect()
                    })
                    .unwrap_or_default();
                let mut out = Map::new();
                if let Some(props) = schema["properties"].as_object() {
                    for (k, p) in props {
                        if required.contains(k) || self.rng.random_bool(0.5) {
                            let v = self.instance(p, depth + 1);
                            out.insert(k.clone(), v);
                        }
                    }
                }
                Value::Object(out)
            }
            "array" => {
                let items = schema["items"].clone();
                Value::Array(vec![self.instance(&items, depth + 1)])
            }
            "string" => json!("x"),
            "integer" => json!(self.rng.random_range(0..4)),
            "number" => json!(1.5),
            "boolean" => json!(self.rng.random_bool(0.5)),
            _ => Value::Null,
        }
    }

    /// `body` with the value at `key` replaced by the JSON text `raw` (as text, so that numbers
    /// JSON can hold but `Value` cannot stay as they are).
    fn with_raw(body: &Value, key: &str, raw: &str) -> Vec<u8> {
        let mut v = body.clone();
        v[key] = json!("\u{1}MARK\u{1}");
        v.to_string()
            .replace("\"\\u0001MARK\\u0001\"", raw)
            .into_bytes()
    }

    /// Every broken body of one operation's schema.
    fn body_cases(&mut self, schema: &Value) -> Vec<Vec<u8>> {
        let mut cases = Vec::new();
        for _ in 0..4 {
            let valid = self.instance(schema, 0);
            cases.push(valid.to_string().into_bytes());
            if let Some(obj) = valid.as_object() {
                for key in obj.keys() {
                    let mut missing = valid.clone();
                    missing.as_object_mut().map(|o| o.remove(key));
                    cases.push(missing.to_string().into_bytes());
                    let raw = WRONG_VALUES[self.rng.random_range(0..WRONG_VALUES.len())];
                    cases.push(Self::with_raw(&valid, key, raw));
                }
                cases.push(Self::with_raw(&valid, "unknown_field", "1"));
                cases.push(Self::with_raw(&valid, "command", "\"fly\""));
                cases.push(Self::with_raw(&valid, "model", "\"xyz\""));
            }
        }
        cases.extend(broken_bodies());
        cases
    }

    /// The concrete targets of a path template: valid ids and bad ones.
    fn targets(&self, template: &str, id: i64) -> Vec<String> {
        if !template.contains("{id}") {
            return vec![template.to_owned()];
        }
        let mut t = vec![template.replace("{id}", &id.to_string())];
        t.extend(BAD_IDS.iter().map(|b| template.replace("{id}", b)));
        t.push(template.replace("{id}", &"9".repeat(3000)));
        t
    }

    /// Fuzz one operation (`method` on `template`).
    fn operation(&mut self, template: &str, method: &str, op: &Value, id: i64) {
        let upper = method.to_ascii_uppercase();
        let schema = op["requestBody"]["content"]["application/json"]["schema"].clone();
        let valid_body = if schema.is_null() {
            Vec::new()
        } else {
            self.instance(&schema, 0).to_string().into_bytes()
        };
        for target in self.targets(template, id) {
            self.authed(&upper, &target, &valid_body);
        }
        let good = template.replace("{id}", &id.to_string());
        // query and header parameters with bad values, and an unknown query parameter
        let params = op["parameters"].as_array().cloned().unwrap_or_default();
        let bad_values = [
            "",
            "x",
            "-1",
            "1e99",
            "%ff",
            "%00",
            "99999999999999999999999",
        ];
        for p in &params {
            let name = p["name"].as_str().unwrap_or("");
            match p["in"].as_str() {
                Some("query") => {
                    for v in bad_values {
                        self.authed(&upper, &format!("{good}?{name}={v}"), &valid_body);
                    }
                    let long = "a".repeat(10_000);
                    self.authed(&upper, &format!("{good}?{name}={long}"), &valid_body);
                }
                Some("header") => {
                    let auth = format!("Bearer {}", self.s.token);
                    for v in ["x", "-5", "1.5", "99999999999999999999999", " "] {
                        self.check(
                            &upper,
                            &good,
                            &[("authorization", &auth), (name, v)],
                            &valid_body,
                        );
                    }
                }
                _ => {}
            }
        }
        self.authed(&upper, &format!("{good}?bogus=1&&=&%zz"), &valid_body);
        // bodies
        if !schema.is_null() {
            for body in self.body_cases(&schema) {
                self.authed(&upper, &good, &body);
            }
            let auth = format!("Bearer {}", self.s.token);
            for ctype in [
                None,
                Some("text/plain"),
                Some("application/x-www-form-urlencoded"),
            ] {
                let mut h = vec![("authorization", auth.as_str())];
                if let Some(c) = ctype {
                    h.push(("content-type", c));
                }
                assert_eq!(self.check(&upper, &good, &h, &valid_body), 415, "{ctype:?}");
            }
        }
        // no token, an unknown token, a malformed header (public routes answer anyway)
        let public = op["security"]
            .as_array()
            .is_some_and(|s| s.iter().any(|r| r.as_object().is_some_and(Map::is_empty)));
        for h in [
            vec![],
            vec![("authorization", "Bearer 00")],
            vec![("authorization", "Basic Og==")],
        ] {
            let code = self.check(&upper, &good, &h, &valid_body);
            if !public {
                assert_eq!(code, 401, "{upper} {good} {h:?}");
            }
        }
    }

    /// Methods a path does not have: 405 (JSON, naming the allowed ones).
    fn wrong_methods(&mut self, template: &str, item: &Value, id: i64) {
        let good = template.replace("{id}", &id.to_string());
        for m in ["get", "post", "put", "delete", "patch"] {
            if item.get(m).is_none() {
                let code = self.authed(&m.to_ascii_uppercase(), &good, b"{}");
                assert_eq!(code, 405, "{m} {good}");
            }
        }
        self.check("TRACE", &good, &[], b"");
        self.check("BREW", &good, &[], b"");
    }

    /// The daemon still answers.
    fn alive(&mut self) {
        let (code, v) = get(self.s, "/api/health");
        assert_eq!((code, &v["ok"]), (200, &Value::Bool(true)), "{v}");
    }
}

#[test]
fn every_route_survives_a_schema_driven_fuzz() {
    let started = Instant::now();
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = fast_config(dir.path(), "serial", 20, 14);
    let mut s = start(&cfg, &dir.path().join("c.db"));
    let (code, v) = post(&s, "/api/campaigns", "{}");
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_i64().expect("id");
    let mut f = Fuzz::of(&s, 0x00ce_11ca_1f22);
    let paths: Vec<(String, Value)> = f.doc["paths"]
        .as_object()
        .expect("paths")
        .iter()
        .map(|(k, v)| (k.clone(), v.clone()))
        .collect();
    assert!(paths.len() >= 15, "{} paths in the document", paths.len());
    let mut operations = Vec::new();
    for (template, item) in &paths {
        for (method, op) in item.as_object().expect("path item") {
            if ["get", "post", "put", "delete", "patch"].contains(&method.as_str()) {
                operations.push((template.clone(), method.clone(), op.clone()));
            }
        }
        f.wrong_methods(template, item, id);
    }
    for (template, method, op) in &operations {
        f.operation(template, method, op, id);
        f.alive();
    }
    // random combinations: any operation, any id, a generated or broken body
    let broken = broken_bodies();
    for _ in 0..1500 {
        let (template, method, op) = &operations[f.rng.random_range(0..operations.len())];
        let target = {
            let t = f.targets(template, id);
            t[f.rng.random_range(0..t.len())].clone()
        };
        let schema = op["requestBody"]["content"]["application/json"]["schema"].clone();
        let body = match (schema.is_null(), f.rng.random_range(0..3)) {
            (true, _) => Vec::new(),
            (false, 0) => broken[f.rng.random_range(0..broken.len())].clone(),
            (false, _) => f.instance(&schema, 0).to_string().into_bytes(),
        };
        f.authed(&method.to_ascii_uppercase(), &target, &body);
    }
    f.alive();
    let (sent, by_status) = (f.sent, f.by_status.clone());
    assert!(s.alive(), "the daemon exited");
    eprintln!(
        "fuzz: {sent} requests, {} operations, statuses {by_status:?}, {:.1} s",
        operations.len(),
        started.elapsed().as_secs_f64()
    );
    // the tally shows the fuzz reached the routes, not only the door
    assert!(by_status.contains_key(&200) && by_status.contains_key(&400));
    assert!(by_status.contains_key(&404) && by_status.contains_key(&405));
}

/// What may follow a body's JSON value: nothing but whitespace.
const TRAILING: [&str; 6] = [r#"{"command":"arm"}"#, "x", ",", "[]", "\u{0}", " 1"];

#[test]
fn every_json_body_route_refuses_anything_after_the_json_value() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = fast_config(dir.path(), "serial", 20, 14);
    let s = start(&cfg, &dir.path().join("c.db"));
    let (code, v) = post(&s, "/api/campaigns", "{}");
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_i64().expect("id");
    let commands = format!("/api/campaigns/{id}/commands");
    // the issue's case: a disarm with an arm after it is refused whole, nothing applied
    let (code, v) = post(&s, &commands, r#"{"command":"disarm"}{"command":"arm"}"#);
    assert_eq!(code, 400, "{v}");
    assert!(
        v["error"].as_str().is_some_and(
            |e| e.contains("trailing characters") && e.contains("after the JSON value")
        ),
        "{v}"
    );
    let mut f = Fuzz::of(&s, 0x00b0_d1e5);
    let before = get(&s, "/api/campaigns").1;
    let mut routes = Vec::new();
    let paths = f.doc["paths"].as_object().expect("paths").clone();
    for (template, item) in &paths {
        for (method, op) in item.as_object().expect("path item") {
            let schema = &op["requestBody"]["content"]["application/json"]["schema"];
            if schema.is_null() {
                continue;
            }
            let target = template.replace("{id}", &id.to_string());
            let upper = method.to_ascii_uppercase();
            routes.push(format!("{upper} {template}"));
            for _ in 0..8 {
                let valid = f.instance(schema, 0).to_string();
                for trailing in TRAILING {
                    let body = format!("{valid}{trailing}");
                    let code = f.authed(&upper, &target, body.as_bytes());
                    assert_eq!(code, 400, "{upper} {target} {body}");
                }
            }
        }
    }
    assert!(routes.len() >= 2, "{routes:?}");
    // nothing was applied: no campaign created, armed, started or aborted
    assert_eq!(get(&s, "/api/campaigns").1, before, "{routes:?}");
    // whitespace after the value is fine
    let (code, v) = post(&s, &commands, "{\"command\": \"arm\"} \r\n\t ");
    assert_eq!(code, 200, "{v}");
    assert_eq!(v["armed"], true, "{v}");
    eprintln!("trailing data refused on {routes:?} ({} requests)", f.sent);
}
