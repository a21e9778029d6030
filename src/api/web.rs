//! The cockpit web page (`web/` in the source tree, embedded in the binary): `/` and
//! `/index.html`, `/app.js`, `/human.js` (the page's number and time format), `/app.css`. These are the only routes the [`super::guard`] lets
//! through without a token (the page signs in with one and sends it on every API call); they
//! still pass its `Host` and `Origin` checks. Every asset is sent with a strict
//! Content-Security-Policy (same-origin scripts, styles and fetches only), no referrer (the
//! `/?token=` link must not leak), no framing and no caching.

use axum::http::header::{CACHE_CONTROL, CONTENT_TYPE, REFERRER_POLICY};
use axum::http::{HeaderName, HeaderValue};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;

/// Paths of the page and its assets: what the gate admits without a token (GET only).
pub const PUBLIC_PATHS: [&str; 5] = ["/", "/index.html", "/app.js", "/human.js", "/app.css"];

const INDEX_HTML: &str = include_str!("../../web/index.html");
const APP_JS: &str = include_str!("../../web/app.js");
const HUMAN_JS: &str = include_str!("../../web/human.js");
const APP_CSS: &str = include_str!("../../web/app.css");

/// The page's routes (state-free; merged into the API router).
pub fn routes<S: Clone + Send + Sync + 'static>() -> Router<S> {
    Router::new()
        .route("/", get(index))
        .route("/index.html", get(index))
        .route("/app.js", get(app_js))
        .route("/human.js", get(human_js))
        .route("/app.css", get(app_css))
}

/// An embedded asset with its content type and the page's security headers.
fn asset(content_type: &'static str, body: &'static str) -> Response {
    let headers = [
        (CONTENT_TYPE, HeaderValue::from_static(content_type)),
        (CACHE_CONTROL, HeaderValue::from_static("no-store")),
        (REFERRER_POLICY, HeaderValue::from_static("no-referrer")),
        (
            HeaderName::from_static("content-security-policy"),
            HeaderValue::from_static(
                "default-src 'none'; script-src 'self'; style-src 'self'; connect-src 'self'; \
                 img-src 'self' blob: data:; base-uri 'none'; form-action 'none'; frame-ancestors 'none'",
            ),
        ),
        (
            HeaderName::from_static("x-content-type-options"),
            HeaderValue::from_static("nosniff"),
        ),
        (
            HeaderName::from_static("x-frame-options"),
            HeaderValue::from_static("DENY"),
        ),
    ];
    (headers, body).into_response()
}

/// A calibration report page ([`crate::report::html`]): no script may run and nothing may load
/// (its style and SVG plots are inline); not cached (it holds a campaign's results).
pub fn report_page(html: String) -> Response {
    let headers = [
        (
            CONTENT_TYPE,
            HeaderValue::from_static("text/html; charset=utf-8"),
        ),
        (CACHE_CONTROL, HeaderValue::from_static("no-store")),
        (REFERRER_POLICY, HeaderValue::from_static("no-referrer")),
        (
            HeaderName::from_static("content-security-policy"),
            HeaderValue::from_static(
                "default-src 'none'; style-src 'unsafe-inline'; img-src data:; base-uri 'none'; \
                 form-action 'none'; frame-ancestors 'none'",
            ),
        ),
        (
            HeaderName::from_static("x-content-type-options"),
            HeaderValue::from_static("nosniff"),
        ),
    ];
    (headers, html).into_response()
}

/// The cockpit page (no token needed; it signs in with `?token=` or a typed token).
///
/// Cancel-safe: no state.
#[utoipa::path(get, path = "/", tag = "web", security(()),
    responses((status = 200, description = "the page (also at `/index.html`)", body = String, content_type = "text/html")))]
pub(super) async fn index() -> Response {
    asset("text/html; charset=utf-8", INDEX_HTML)
}

/// The page's script.
///
/// Cancel-safe: no state.
#[utoipa::path(get, path = "/app.js", tag = "web", security(()),
    responses((status = 200, description = "the page's script", body = String, content_type = "text/javascript")))]
pub(super) async fn app_js() -> Response {
    asset("text/javascript; charset=utf-8", APP_JS)
}

/// The page's number and time format (lengths mm, small angles mrad, joint angles degrees,
/// local ISO 8601 times, durations), loaded before its script.
///
/// Cancel-safe: no state.
#[utoipa::path(get, path = "/human.js", tag = "web", security(()),
    responses((status = 200, description = "the page's number and time format", body = String, content_type = "text/javascript")))]
pub(super) async fn human_js() -> Response {
    asset("text/javascript; charset=utf-8", HUMAN_JS)
}

/// The page's style sheet.
///
/// Cancel-safe: no state.
#[utoipa::path(get, path = "/app.css", tag = "web", security(()),
    responses((status = 200, description = "the page's style sheet", body = String, content_type = "text/css")))]
pub(super) async fn app_css() -> Response {
    asset("text/css; charset=utf-8", APP_CSS)
}
