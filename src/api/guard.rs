//! The API's door, run before any route: the `Host` header must name this daemon (421: stops
//! DNS rebinding), a browser's `Origin` must be this daemon's own (403), every route but
//! `GET /api/health`, `GET /api/openapi.json` and the web page's assets ([`super::web::PUBLIC_PATHS`]) needs a known
//! bearer token (401), and a request body must be declared
//! `application/json` (415: a cross-origin `text/plain` form post never reaches a route). The
//! authenticated [`Principal`] is left in the request's extensions for the routes' role checks.
//! [`json_errors`] turns every error response that is not yet JSON (axum's own 405, 413, …)
//! into `{"error": …}`.

use std::net::SocketAddr;
use std::sync::Arc;

use axum::body::Body;
use axum::extract::{Request, State};
use axum::http::header::{
    ALLOW, AUTHORIZATION, CONTENT_LENGTH, CONTENT_TYPE, HOST, ORIGIN, WWW_AUTHENTICATE,
};
use axum::http::{HeaderMap, HeaderValue, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use super::ApiError;
use crate::auth::{Principal, TokenTable};

/// Largest error text of an inner response that [`json_errors`] reads back (bytes).
const MAX_ERROR_TEXT: usize = 16 * 1024;

/// `http` or `https`: how the daemon is served (same-origin checks compare it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scheme {
    /// Plain HTTP.
    Http,
    /// HTTP over TLS.
    Https,
}

impl Scheme {
    /// `http` or `https`.
    pub fn as_str(self) -> &'static str {
        match self {
            Scheme::Http => "http",
            Scheme::Https => "https",
        }
    }

    /// The port a URL of this scheme means when it names none.
    fn default_port(self) -> u16 {
        match self {
            Scheme::Http => 80,
            Scheme::Https => 443,
        }
    }
}

/// What the door admits: accepted tokens, the `Host` values and the origins this daemon is.
#[derive(Debug)]
pub struct Gate {
    tokens: TokenTable,
    scheme: Scheme,
    /// Lowercase `host:port` authorities.
    hosts: Vec<String>,
    /// Lowercase `scheme://host:port` origins.
    origins: Vec<String>,
}

impl Gate {
    /// The gate of a daemon serving `scheme` on `served`, accepting `tokens`; `extra_hosts`
    /// (`name` or `name:port`) and `extra_origins` (`scheme://host[:port]`) come from `[api]`.
    pub fn new(
        tokens: TokenTable,
        scheme: Scheme,
        served: SocketAddr,
        extra_hosts: &[String],
        extra_origins: &[String],
    ) -> Gate {
        let port = served.port();
        let mut hosts: Vec<String> = vec![
            served.to_string(),
            format!("localhost:{port}"),
            format!("127.0.0.1:{port}"),
            format!("[::1]:{port}"),
        ];
        hosts.extend(
            extra_hosts
                .iter()
                .map(|h| with_port(&h.to_ascii_lowercase(), port)),
        );
        hosts.dedup();
        let mut origins: Vec<String> = hosts
            .iter()
            .map(|h| format!("{}://{h}", scheme.as_str()))
            .collect();
        origins.extend(extra_origins.iter().filter_map(|o| normal_origin(o)));
        Gate {
            tokens,
            scheme,
            hosts,
            origins,
        }
    }

    /// Whether a `Host` value (or HTTP/2 authority) names this daemon.
    fn host_ok(&self, host: &str) -> bool {
        let full = with_port(&host.to_ascii_lowercase(), self.scheme.default_port());
        self.hosts.contains(&full)
    }

    /// Whether a browser's `Origin` is this daemon (or a configured extra origin).
    fn origin_ok(&self, origin: &str) -> bool {
        normal_origin(origin).is_some_and(|o| self.origins.contains(&o))
    }

    /// Admit `req` (leaving its [`Principal`] in the extensions) or answer it with the refusal.
    fn admit(&self, req: &mut Request) -> Result<(), Refusal> {
        let host = req
            .headers()
            .get(HOST)
            .and_then(|v| v.to_str().ok())
            .map(str::to_owned)
            .or_else(|| req.uri().authority().map(|a| a.to_string()));
        match host {
            Some(h) if self.host_ok(&h) => {}
            Some(h) => {
                return Err(refuse(
                    StatusCode::MISDIRECTED_REQUEST,
                    format!("Host `{h}` is not this daemon"),
                ))
            }
            None => {
                return Err(refuse(
                    StatusCode::MISDIRECTED_REQUEST,
                    "no Host header".into(),
                ))
            }
        }
        if let Some(origin) = req.headers().get(ORIGIN) {
            let origin = origin.to_str().unwrap_or("(not text)");
            if !self.origin_ok(origin) {
                return Err(refuse(
                    StatusCode::FORBIDDEN,
                    format!("cross-origin request from `{origin}` refused"),
                ));
            }
        }
        if req.method() == Method::GET && is_public(req.uri().path()) {
            return Ok(());
        }
        let principal = self.authenticate(req.headers())?;
        if let Some(connection) = req.extensions().get::<super::conns::Connection>() {
            connection.authenticated();
        }
        if matches!(*req.method(), Method::POST | Method::PUT | Method::PATCH) {
            check_json_body(req.headers())?;
        }
        req.extensions_mut().insert(principal);
        Ok(())
    }

    /// The principal of the request's bearer token, or the 401 answer.
    fn authenticate(&self, headers: &HeaderMap) -> Result<Principal, Refusal> {
        let Some(value) = headers.get(AUTHORIZATION) else {
            return Err(unauthorized(
                "missing `Authorization: Bearer <token>`",
                false,
            ));
        };
        let token = value
            .to_str()
            .ok()
            .and_then(|v| v.split_once(' '))
            .filter(|(scheme, _)| scheme.eq_ignore_ascii_case("bearer"))
            .map(|(_, t)| t.trim());
        let Some(token) = token else {
            return Err(unauthorized(
                "the Authorization header must be `Bearer <token>`",
                false,
            ));
        };
        self.tokens
            .authenticate(token)
            .cloned()
            .ok_or_else(|| unauthorized("unknown token", true))
    }
}

/// Whether a GET of `path` needs no token: the health check and the web page's assets.
fn is_public(path: &str) -> bool {
    path == "/api/health" || path == "/api/openapi.json" || super::web::PUBLIC_PATHS.contains(&path)
}

/// `name:port` stays; a bare `name` gets `port`.
fn with_port(host: &str, port: u16) -> String {
    if has_port(host) {
        host.to_owned()
    } else {
        format!("{host}:{port}")
    }
}

/// Whether an authority ends in `:digits` (a bracketed IPv6 address's colons do not count).
fn has_port(authority: &str) -> bool {
    let tail = authority.rsplit(']').next().unwrap_or(authority);
    tail.rsplit_once(':')
        .is_some_and(|(_, p)| !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()))
}

/// An origin as `scheme://host:port`, lowercase, the scheme's default port made explicit;
/// `None` unless the scheme is `http` or `https`.
fn normal_origin(origin: &str) -> Option<String> {
    let origin = origin.trim_end_matches('/').to_ascii_lowercase();
    let (scheme, authority) = origin.split_once("://")?;
    let scheme = match scheme {
        "http" => Scheme::Http,
        "https" => Scheme::Https,
        _ => return None,
    };
    Some(format!(
        "{}://{}",
        scheme.as_str(),
        with_port(authority, scheme.default_port())
    ))
}

/// 415 unless the body is declared `application/json` (parameters such as `charset` allowed).
fn check_json_body(headers: &HeaderMap) -> Result<(), Refusal> {
    let declared = headers.get(CONTENT_TYPE).and_then(|v| v.to_str().ok());
    let mime = declared.map(|v| v.split(';').next().unwrap_or("").trim());
    if mime.is_some_and(|m| m.eq_ignore_ascii_case("application/json")) {
        return Ok(());
    }
    Err(refuse(
        StatusCode::UNSUPPORTED_MEDIA_TYPE,
        format!(
            "request body: Content-Type must be application/json (got {})",
            declared.map_or("none".to_owned(), |d| format!("`{d}`"))
        ),
    ))
}

/// Why the gate turned a request away; answered as a JSON error.
#[derive(Debug)]
struct Refusal {
    status: StatusCode,
    message: String,
    /// The `WWW-Authenticate` challenge of a 401.
    challenge: Option<&'static str>,
}

impl IntoResponse for Refusal {
    fn into_response(self) -> Response {
        let mut r = ApiError(self.status, self.message).into_response();
        if let Some(c) = self.challenge {
            r.headers_mut()
                .insert(WWW_AUTHENTICATE, HeaderValue::from_static(c));
        }
        r
    }
}

/// A refusal with `status` and `message`.
fn refuse(status: StatusCode, message: String) -> Refusal {
    Refusal {
        status,
        message,
        challenge: None,
    }
}

/// 401 with `WWW-Authenticate: Bearer` (and `error="invalid_token"` for a wrong token).
fn unauthorized(message: &str, invalid_token: bool) -> Refusal {
    Refusal {
        status: StatusCode::UNAUTHORIZED,
        message: message.to_owned(),
        challenge: Some(if invalid_token {
            r#"Bearer realm="cellcal", error="invalid_token""#
        } else {
            r#"Bearer realm="cellcal""#
        }),
    }
}

/// Middleware: [`Gate::admit`] every request before routing.
/// Cancel-safe: admission has no await; a drop only drops the inner handler (see each handler).
pub async fn guard(State(gate): State<Arc<Gate>>, mut req: Request, next: Next) -> Response {
    match gate.admit(&mut req) {
        Ok(()) => next.run(req).await,
        Err(refusal) => refusal.into_response(),
    }
}

/// Middleware: an error response that is not JSON (axum's rejections: 405, 413, a path that
/// does not parse, …) becomes `{"error": its text}` with the same status and headers.
/// Cancel-safe: it only rewrites the response; a drop only drops the inner handler.
pub async fn json_errors(req: Request, next: Next) -> Response {
    let method = req.method().clone();
    let res = next.run(req).await;
    let status = res.status();
    let is_json = res
        .headers()
        .get(CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    if !(status.is_client_error() || status.is_server_error()) || is_json {
        return res;
    }
    let (mut parts, body) = res.into_parts();
    let text = axum::body::to_bytes(body, MAX_ERROR_TEXT)
        .await
        .map(|b| String::from_utf8_lossy(&b).trim().to_owned())
        .unwrap_or_default();
    let message = match status {
        StatusCode::METHOD_NOT_ALLOWED => {
            match parts.headers.get(ALLOW).and_then(|v| v.to_str().ok()) {
                Some(allowed) => format!("method {method} not allowed here (allowed: {allowed})"),
                None => format!("method {method} not allowed here"),
            }
        }
        StatusCode::PAYLOAD_TOO_LARGE => format!(
            "request body: larger than {} KiB",
            super::MAX_BODY_BYTES / 1024
        ),
        _ if text.is_empty() => status
            .canonical_reason()
            .unwrap_or("error")
            .to_ascii_lowercase(),
        _ => text,
    };
    parts.headers.remove(CONTENT_LENGTH);
    parts
        .headers
        .insert(CONTENT_TYPE, HeaderValue::from_static("application/json"));
    let body = serde_json::json!({ "error": message }).to_string();
    parts.extensions.insert(super::ErrorText(message));
    Response::from_parts(parts, Body::from(body))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gate(scheme: Scheme, served: &str) -> Gate {
        Gate::new(
            TokenTable::default(),
            scheme,
            served.parse().unwrap(),
            &["cell.lan".into(), "Cell-Alias:9000".into()],
            &["https://panel.example/".into()],
        )
    }

    #[test]
    fn hosts_are_the_served_names_only() {
        let g = gate(Scheme::Http, "127.0.0.1:8080");
        for ok in [
            "127.0.0.1:8080",
            "localhost:8080",
            "LOCALHOST:8080",
            "[::1]:8080",
            "cell.lan:8080",
            "cell-alias:9000",
        ] {
            assert!(g.host_ok(ok), "{ok}");
        }
        for bad in [
            "evil.example:8080",
            "localhost:8081",
            "localhost",
            "127.0.0.1",
            "cell.lan:9000",
            "",
        ] {
            assert!(!g.host_ok(bad), "{bad}");
        }
        // a bare name means the scheme's default port
        let g = gate(Scheme::Https, "[::1]:443");
        assert!(g.host_ok("localhost") && g.host_ok("[::1]") && g.host_ok("cell.lan"));
        assert!(!g.host_ok("[::2]"));
    }

    #[test]
    fn origins_are_same_origin_or_configured() {
        let g = gate(Scheme::Http, "127.0.0.1:8080");
        for ok in [
            "http://127.0.0.1:8080",
            "http://localhost:8080",
            "http://cell.lan:8080",
            "https://panel.example",
            "https://panel.example:443",
        ] {
            assert!(g.origin_ok(ok), "{ok}");
        }
        for bad in [
            "http://evil.example",
            "https://127.0.0.1:8080",
            "http://localhost:8081",
            "null",
            "http://localhost",
        ] {
            assert!(!g.origin_ok(bad), "{bad}");
        }
    }

    #[test]
    fn ports_are_found_after_ipv6_brackets() {
        assert!(has_port("[::1]:80") && has_port("a:1"));
        assert!(!has_port("[::1]") && !has_port("a") && !has_port("a:"));
    }
}
