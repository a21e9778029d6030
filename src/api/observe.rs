//! The request middleware outside every other layer: each request's latency into the
//! `cellcal_http_request_duration_seconds` histogram by method and route template, both from
//! fixed sets (an unknown method, a path no route matches: `other`; never a raw value, also for
//! a request the gate refused), and one structured log line per error answer (4xx `warn`, 5xx
//! `error`: method, route, path without the query, status, the error message; every value a
//! client controls cut to [`LOG_VALUE_CHARS`] characters). Headers and query strings are never
//! logged, so neither is a token.

use std::sync::Arc;
use std::time::Instant;

use axum::extract::{MatchedPath, Request, State};
use axum::middleware::Next;
use axum::response::Response;

use super::ErrorText;
use crate::metrics::{Metrics, OTHER};

/// Most characters of a client's value (method, path, error text) in a log line.
pub(crate) const LOG_VALUE_CHARS: usize = 200;

/// `text` cut to [`LOG_VALUE_CHARS`] characters (`…` and the full length in bytes appended
/// when cut).
pub(crate) fn clip(text: &str) -> std::borrow::Cow<'_, str> {
    match text.char_indices().nth(LOG_VALUE_CHARS) {
        None => text.into(),
        Some((end, _)) => format!("{}… ({} bytes)", &text[..end], text.len()).into(),
    }
}

/// Middleware: time the request, count it by route, log an error answer. Cancel-safe: a
/// dropped request is neither counted nor logged.
pub(super) async fn observe(
    State(metrics): State<Arc<Metrics>>,
    req: Request,
    next: Next,
) -> Response {
    let started = Instant::now();
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map(|p| p.as_str().to_owned());
    let method = req.method().clone();
    let path = req.uri().path().to_owned();
    let res = next.run(req).await;
    let status = res.status();
    metrics.request(
        method.as_str(),
        route.as_deref(),
        status.as_u16(),
        started.elapsed(),
    );
    if status.is_client_error() || status.is_server_error() {
        let error = res
            .extensions()
            .get::<ErrorText>()
            .map_or("", |t| t.0.as_str());
        let code = status.as_u16();
        let route = route.as_deref().unwrap_or(OTHER);
        let (method, path, error) = (clip(method.as_str()), clip(&path), clip(error));
        let (path, error) = (path.as_ref(), error.as_ref());
        if status.is_server_error() {
            tracing::error!(method = %method, route, path, status = code, error, "request failed");
        } else {
            tracing::warn!(method = %method, route, path, status = code, error, "request refused");
        }
    }
    res
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_values_are_cut_to_200_characters_on_a_char_boundary() {
        assert_eq!(clip("GET"), "GET");
        let exact = "é".repeat(LOG_VALUE_CHARS);
        assert_eq!(clip(&exact), exact);
        let long = "é".repeat(60_000);
        let cut = clip(&long);
        assert!(cut.starts_with(&"é".repeat(LOG_VALUE_CHARS)));
        assert_eq!(
            cut,
            format!("{}… (120000 bytes)", "é".repeat(LOG_VALUE_CHARS))
        );
    }
}
