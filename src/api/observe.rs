//! The request middleware outside every other layer: each request's latency into the
//! `cellcal_http_request_duration_seconds` histogram by route template (never a raw path, so
//! the label set stays bounded), and one structured log line per error answer (4xx `warn`,
//! 5xx `error`: method, route, path without the query, status, the error message). Headers and
//! query strings are never logged, so neither is a token.

use std::sync::Arc;
use std::time::Instant;

use axum::extract::{MatchedPath, Request, State};
use axum::middleware::Next;
use axum::response::Response;

use super::ErrorText;
use crate::metrics::Metrics;

/// The label of a request no route matched.
const UNMATCHED: &str = "unmatched";

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
        .map_or(UNMATCHED, |p| p.as_str())
        .to_owned();
    let method = req.method().clone();
    let path = req.uri().path().to_owned();
    let res = next.run(req).await;
    let status = res.status();
    metrics.request(method.as_str(), &route, status.as_u16(), started.elapsed());
    if status.is_client_error() || status.is_server_error() {
        let error = res
            .extensions()
            .get::<ErrorText>()
            .map_or("", |t| t.0.as_str());
        let code = status.as_u16();
        if status.is_server_error() {
            tracing::error!(method = %method, route, path, status = code, error, "request failed");
        } else {
            tracing::warn!(method = %method, route, path, status = code, error, "request refused");
        }
    }
    res
}
