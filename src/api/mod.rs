//! The REST API of `cellcal serve` over [`crate::daemon::Daemon`] (axum). Every body is JSON
//! (`Content-Type: application/json`, at most 64 KiB); every error is `{"error": "..."}` with a
//! 4xx/5xx status. [`guard`] checks `Host`, `Origin` and the bearer token of every request
//! before routing; the routes check the caller's [`crate::auth::Role`] for what it asks.
//! [`serve`] runs the router over plain HTTP or TLS ([`tls`]).
//!
//! | method and path | what |
//! |---|---|
//! | `GET /api/health` | `{"ok": true, "version"}` |
//! | `GET /api/campaigns` | every stored campaign (`CampaignView`) |
//! | `POST /api/campaigns` | plan and store a new campaign; body `{poses?, ident?, seed?, model?}` (may be empty) → 201 + `CampaignView` |
//! | `GET /api/campaigns/{id}` | one campaign: state, poses done/total, open question |
//! | `POST /api/campaigns/{id}/commands` | `{"command": "arm"\|"disarm"\|"start"\|"pause"\|"resume"\|"reregister"\|"abort"}` (`reregister`: resume, and re-register a tracker frame found moved; operator) or `{"command": "answer", "seq", "value_mm"?, "abort"?}` |
//! | `GET /api/campaigns/{id}/events` | the stored event journal: `[{seq, at_ms, kind, event}]` |
//! | `GET /api/campaigns/{id}/stream` | events, Server-Sent Events (`id:` = journal `seq`, `event:` = kind, `data:` = JSON); resumes after `Last-Event-ID` (header, or `?last_event_id=`); ends after the run's final state |
//! | `GET /api/campaigns/{id}/result` | the `cellcal identify` JSON contract, 404 until identified |

pub mod guard;
pub mod tls;

use std::convert::Infallible;
use std::sync::Arc;
use std::time::Duration;

use axum::body::Bytes;
use axum::extract::rejection::QueryRejection;
use axum::extract::{DefaultBodyLimit, FromRequestParts, Path, Query, State};
use axum::http::request::Parts;
use axum::http::{HeaderMap, StatusCode};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use tokio_stream::wrappers::ReceiverStream;
use tokio_stream::{Stream, StreamExt};

pub use guard::{Gate, Scheme};

use crate::auth::{Action, Principal};
use crate::daemon::{CampaignOverrides, ClientCommand, Daemon, DaemonError, Followed};

/// Largest accepted request body (bytes); larger ones get 413.
pub const MAX_BODY_BYTES: usize = 64 * 1024;

/// An API error: status and message.
#[derive(Debug)]
pub struct ApiError(StatusCode, String);

impl From<DaemonError> for ApiError {
    fn from(e: DaemonError) -> ApiError {
        let status = match &e {
            DaemonError::BadRequest(_) => StatusCode::BAD_REQUEST,
            DaemonError::NotFound(_) => StatusCode::NOT_FOUND,
            DaemonError::Conflict(_) => StatusCode::CONFLICT,
            DaemonError::Session(_) | DaemonError::Store(_) | DaemonError::Task(_) => {
                StatusCode::INTERNAL_SERVER_ERROR
            }
        };
        ApiError(status, e.to_string())
    }
}

/// A JSON body (the gate has checked its content type); errors name the field.
fn parse_body<T: serde::de::DeserializeOwned>(body: &[u8]) -> Result<T, ApiError> {
    let mut de = serde_json::Deserializer::from_slice(body);
    serde_path_to_error::deserialize(&mut de)
        .map_err(|e| ApiError(StatusCode::BAD_REQUEST, format!("request body: {e}")))
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        (self.0, Json(serde_json::json!({ "error": self.1 }))).into_response()
    }
}

/// The caller the gate authenticated; `may` refuses with 403 naming role and action.
struct Caller(Principal);

impl<S: Send + Sync> FromRequestParts<S> for Caller {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, ApiError> {
        parts
            .extensions
            .get::<Principal>()
            .cloned()
            .map(Caller)
            .ok_or_else(|| ApiError(StatusCode::UNAUTHORIZED, "not authenticated".into()))
    }
}

impl Caller {
    /// `Ok` when the caller's role allows `action`, else 403.
    fn may(&self, action: Action) -> Result<(), ApiError> {
        self.0
            .check(action)
            .map_err(|m| ApiError(StatusCode::FORBIDDEN, m))
    }
}

/// The permission a client command needs.
fn action_of(cmd: &ClientCommand) -> Action {
    match cmd {
        ClientCommand::Arm => Action::Arm,
        ClientCommand::Disarm => Action::Disarm,
        ClientCommand::Start => Action::Start,
        ClientCommand::Pause => Action::Pause,
        ClientCommand::Resume | ClientCommand::Reregister => Action::Resume,
        ClientCommand::Abort => Action::Abort,
        ClientCommand::Answer { .. } => Action::Answer,
    }
}

/// A campaign id from the path; anything but a whole number is a JSON 400.
struct CampaignId(i64);

impl<S: Send + Sync> FromRequestParts<S> for CampaignId {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, ApiError> {
        let Path(raw) = Path::<String>::from_request_parts(parts, state)
            .await
            .map_err(|e| ApiError(StatusCode::BAD_REQUEST, e.body_text()))?;
        raw.parse().map(CampaignId).map_err(|_| {
            ApiError(
                StatusCode::BAD_REQUEST,
                format!("campaign id `{raw}` is not a whole number"),
            )
        })
    }
}

type Shared = Arc<Daemon>;

/// The API's routes over `daemon`, behind `gate` (see [`guard`]), errors as JSON.
pub fn router(daemon: Arc<Daemon>, gate: Arc<Gate>) -> Router {
    Router::new()
        .route("/api/health", get(health))
        .route("/api/campaigns", get(list).post(create))
        .route("/api/campaigns/{id}", get(one))
        .route("/api/campaigns/{id}/commands", post(command))
        .route("/api/campaigns/{id}/events", get(journal))
        .route("/api/campaigns/{id}/stream", get(stream))
        .route("/api/campaigns/{id}/result", get(result))
        .fallback(|| async { ApiError(StatusCode::NOT_FOUND, "no such endpoint".into()) })
        .layer(DefaultBodyLimit::max(MAX_BODY_BYTES))
        .layer(axum::middleware::from_fn_with_state(gate, guard::guard))
        .layer(axum::middleware::from_fn(guard::json_errors))
        .with_state(daemon)
}

/// Serve `app` on `listener` (TLS when `tls` is given) until `handle` shuts it down.
/// Cancel-safe: dropping the future stops accepting; connections already open run on until
/// they end (a graceful stop goes through `handle`).
pub async fn serve(
    listener: std::net::TcpListener,
    app: Router,
    tls: Option<axum_server::tls_rustls::RustlsConfig>,
    handle: axum_server::Handle<std::net::SocketAddr>,
) -> std::io::Result<()> {
    let service = app.into_make_service();
    match tls {
        None => {
            axum_server::from_tcp(listener)?
                .handle(handle)
                .serve(service)
                .await
        }
        Some(config) => {
            axum_server::from_tcp_rustls(listener, config)?
                .handle(handle)
                .serve(service)
                .await
        }
    }
}

async fn health() -> Json<serde_json::Value> {
    Json(serde_json::json!({ "ok": true, "version": env!("CARGO_PKG_VERSION") }))
}

async fn list(State(d): State<Shared>) -> Result<Response, ApiError> {
    Ok(Json(d.list().await?).into_response())
}

async fn create(
    State(d): State<Shared>,
    caller: Caller,
    body: Bytes,
) -> Result<Response, ApiError> {
    caller.may(Action::Create)?;
    // an empty body means "the configuration's defaults"
    let overrides: CampaignOverrides = if body.iter().all(u8::is_ascii_whitespace) {
        CampaignOverrides::default()
    } else {
        parse_body(&body)?
    };
    let view = d.create(&overrides).await?;
    Ok((StatusCode::CREATED, Json(view)).into_response())
}

async fn one(State(d): State<Shared>, CampaignId(id): CampaignId) -> Result<Response, ApiError> {
    Ok(Json(d.get(id).await?).into_response())
}

async fn command(
    State(d): State<Shared>,
    CampaignId(id): CampaignId,
    caller: Caller,
    body: Bytes,
) -> Result<Response, ApiError> {
    let cmd: ClientCommand = parse_body(&body)?;
    caller.may(action_of(&cmd))?;
    Ok(Json(d.command(id, cmd).await?).into_response())
}

async fn journal(
    State(d): State<Shared>,
    CampaignId(id): CampaignId,
) -> Result<Response, ApiError> {
    Ok(Json(d.journal(id).await?).into_response())
}

async fn result(State(d): State<Shared>, CampaignId(id): CampaignId) -> Result<Response, ApiError> {
    match d.result(id).await? {
        Some(v) => Ok(Json(v).into_response()),
        None => Err(ApiError(
            StatusCode::NOT_FOUND,
            format!("campaign {id} has no result yet"),
        )),
    }
}

/// The `?last_event_id=` of a stream request.
#[derive(Debug, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct StreamQuery {
    last_event_id: Option<String>,
}

/// The sequence number to resume after: the `Last-Event-ID` header, else the query.
fn last_event_id(headers: &HeaderMap, query: StreamQuery) -> Result<Option<i64>, ApiError> {
    let header = headers
        .get("last-event-id")
        .map(|v| v.to_str().unwrap_or("?").to_owned());
    match header.or(query.last_event_id) {
        None => Ok(None),
        Some(v) => match v.trim().parse::<i64>() {
            Ok(n) if n >= 0 => Ok(Some(n)),
            _ => Err(ApiError(
                StatusCode::BAD_REQUEST,
                format!("last event id: `{v}` is not a non-negative integer"),
            )),
        },
    }
}

/// The SSE form of a followed item: a journal entry, or a comment naming a replayed gap.
fn sse_event(item: Followed) -> Event {
    match item {
        Followed::Entry(e) => Event::default()
            .id(e.seq.to_string())
            .event(e.record.kind)
            .data(e.record.message),
        Followed::Replayed { count } => {
            Event::default().comment(format!("replayed {count} events from the journal"))
        }
    }
}

async fn stream(
    State(d): State<Shared>,
    CampaignId(id): CampaignId,
    headers: HeaderMap,
    query: Result<Query<StreamQuery>, QueryRejection>,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiError> {
    let query = query.map_err(|e| ApiError(StatusCode::BAD_REQUEST, e.body_text()))?;
    let after = last_event_id(&headers, query.0)?;
    let followed = d.follow(id, after).await?;
    let events = ReceiverStream::new(followed).map(|item| Ok(sse_event(item)));
    Ok(Sse::new(events).keep_alive(KeepAlive::new().interval(Duration::from_secs(15))))
}
