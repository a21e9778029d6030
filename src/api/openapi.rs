//! The OpenAPI 3.1 description of the API, generated from the routes' `#[utoipa::path]`
//! annotations and the bodies' `ToSchema` derives, served at `GET /api/openapi.json` (no token
//! needed). `tests/snapshots/openapi.json` holds the committed copy; a test compares them, so
//! an API change shows in review.

use axum::Json;
use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
use utoipa::{Modify, OpenApi};

/// The API's OpenAPI document (see [`document`]).
#[derive(OpenApi)]
#[openapi(
    info(
        title = "cellcal",
        description = "The REST API of `cellcal serve`: one calibration cell, one loaded campaign at a time. \
            Every body is JSON (at most 64 KiB); every error is `{\"error\": \"…\"}`. Requests must name this \
            daemon in `Host` (else 421) and come from its own `Origin` when a browser sends one (else 403)."
    ),
    paths(
        super::health,
        serve_document,
        super::whoami,
        super::list,
        super::create,
        super::one,
        super::command,
        super::journal,
        super::stream,
        super::result,
        super::model,
        super::report,
        super::prompt,
        super::measurements,
        super::plan,
        super::devices,
        super::cell_stop,
        super::prometheus_metrics,
        super::web::index,
        super::web::app_js,
        super::web::human_js,
        super::web::app_css,
    ),
    modifiers(&BearerScheme),
    security(("bearer" = [])),
    tags(
        (name = "daemon", description = "health, identity, devices, metrics, this description"),
        (name = "campaigns", description = "campaigns and their commands"),
        (name = "events", description = "the event journal and the live stream"),
        (name = "web", description = "the cockpit web page"),
    )
)]
pub struct ApiDoc;

/// Adds the `bearer` security scheme (`Authorization: Bearer TOKEN`).
struct BearerScheme;

impl Modify for BearerScheme {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        let components = openapi.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(
                HttpBuilder::new()
                    .scheme(HttpAuthScheme::Bearer)
                    .description(Some(
                        "a token from `cellcal token`, or the one-time token `cellcal serve` prints",
                    ))
                    .build(),
            ),
        );
    }
}

/// The OpenAPI document as pretty JSON (what the snapshot test compares).
pub fn document() -> String {
    let mut doc = ApiDoc::openapi();
    doc.info.version = env!("CARGO_PKG_VERSION").to_owned();
    doc.to_pretty_json()
        .unwrap_or_else(|e| format!("{{\"error\": \"openapi: {e}\"}}"))
}

/// This description of the API (no token needed).
///
/// Cancel-safe: no state.
#[utoipa::path(get, path = "/api/openapi.json", tag = "daemon", security(()),
    responses((status = 200, description = "the OpenAPI 3.1 document", body = serde_json::Value)))]
pub(super) async fn serve_document() -> Json<serde_json::Value> {
    Json(ApiDoc::openapi_json())
}

impl ApiDoc {
    /// The document as a JSON value (version = the crate's).
    fn openapi_json() -> serde_json::Value {
        serde_json::from_str(&document()).unwrap_or_default()
    }
}
