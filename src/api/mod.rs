//! The REST API of `cellcal serve` over [`crate::daemon::Daemon`] (axum). Every body is one
//! JSON value and nothing after it (`Content-Type: application/json`, at most 64 KiB); every
//! error is `{"error": "..."}` with a 4xx/5xx status. [`guard`] checks `Host`, `Origin` and the
//! bearer token of every request before routing; the routes check the caller's
//! [`crate::auth::Role`] for what it asks. [`serve`] runs the router over plain HTTP or TLS
//! ([`tls`]) within [`conns`]' limits. Every handler is cancel-safe: a
//! dropped request only stops its own reads or waits (a command is applied before its reply
//! waits for the engine; a creation or load runs in its own task).
//!
//! | method and path | what |
//! |---|---|
//! | `GET /`, `/index.html`, `/app.js`, `/human.js`, `/app.css` | the cockpit web page ([`web`]; no token needed) |
//! | `GET /api/health` | `{"ok": true, "version"}` |
//! | `GET /api/openapi.json` | the OpenAPI 3.1 description of these routes ([`openapi`]; no token needed) |
//! | `GET /api/whoami` | the caller: `{name, role, may: [action…]}` |
//! | `GET /api/campaigns` | every stored campaign (`CampaignView`) |
//! | `POST /api/campaigns` | plan and store a new campaign; body `{poses?, ident?, seed?, model?}` (may be empty) → 201 + `CampaignView` |
//! | `GET /api/campaigns/{id}` | one campaign: state, poses done/total, open question |
//! | `POST /api/campaigns/{id}/commands` | `{"command": "arm"\|"disarm"\|"start"\|"pause"\|"resume"\|"reregister"\|"abort"}` (`reregister`: resume, and re-register a tracker frame found moved; operator; `disarm` stops the robot and the stage and pauses; `resume` of an aborted, failed or interrupted campaign, once armed, resumes it; a command that cannot act in the campaign's state is a 409 with the reason, never a 200 that does nothing; `pause` answers at once, `pausing` until it takes effect) or `{"command": "answer", "seq", "value_mm"?, "abort"?}` or `{"command": "confirm_clear", "seq"}` (the only answer to a `confirm_clear` question) |
//! | `GET /api/campaigns/{id}/events` | the stored event journal: `[{seq, at_ms, kind, event}]` |
//! | `GET /api/campaigns/{id}/stream` | events, Server-Sent Events (`id:` = journal `seq`, `event:` = kind, `data:` = JSON); resumes after `Last-Event-ID` (header, or `?last_event_id=`); ends after the run's final state |
//! | `GET /api/campaigns/{id}/prompt` | the open technician question (`PromptView`), 204 when none |
//! | `GET /api/campaigns/{id}/result` | the `cellcal identify` JSON contract, 404 until identified; saved as `campaign-{id}-result.json` (`Content-Disposition`, as model and report) |
//! | `GET /api/campaigns/{id}/model` | the corrected model: a robot TOML (`text/plain`) that `--robot` loads, 404 until identified; `campaign-{id}-model.toml` |
//! | `GET /api/campaigns/{id}/measurements` | the measured poses (`[MeasurementRow]`); `?format=csv`: the identify CSV `cellcal export` writes |
//! | `GET /api/campaigns/{id}/plan` | the stored plan (`PlanView`): poses in move order, set, joints (rad), done marks |
//! | `GET /api/devices` | tracker, robot, stage: kind, address, simulated, connected, last fault (`DevicesView`) |
//! | `POST /api/cell/stop` | stop the cell (any role): abort the loaded campaign and stop the robot and the stage → `CellStopView` (what each device answered) |
//! | `GET /metrics` | Prometheus metrics, OpenMetrics text ([`crate::metrics`]); a token of any role |
//! | `GET /api/campaigns/{id}/report` | the calibration report, one self-contained HTML page (`text/html`, no script), 404 (JSON) until identified; `campaign-{id}-report.html` |

pub mod conns;
pub mod guard;
mod observe;
pub mod openapi;
pub mod tls;
pub mod web;

use std::convert::Infallible;
use std::sync::Arc;
use std::time::Duration;

use axum::body::Bytes;
use axum::extract::rejection::QueryRejection;
use axum::extract::{DefaultBodyLimit, FromRequestParts, Path, Query, State};
use axum::http::header::{CONTENT_DISPOSITION, CONTENT_TYPE};
use axum::http::request::Parts;
use axum::http::{HeaderMap, StatusCode};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use tokio_stream::wrappers::ReceiverStream;
use tokio_stream::{Stream, StreamExt};

pub use conns::ServeLimits;
pub use guard::{Gate, Scheme};

use crate::auth::{Action, Principal};
use crate::daemon::{
    CampaignOverrides, CampaignView, CellStopView, ClientCommand, Daemon, DaemonError, DevicesView,
    Followed, MeasurementRow, PlanView, PromptView,
};

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
            DaemonError::Session(_)
            | DaemonError::Store(_)
            | DaemonError::Task(_)
            | DaemonError::Stored(_) => StatusCode::INTERNAL_SERVER_ERROR,
        };
        ApiError(status, e.to_string())
    }
}

/// A JSON body (the gate has checked its content type): exactly one JSON value, whitespace
/// around it allowed, anything after it refused; errors name the field.
fn parse_body<T: serde::de::DeserializeOwned>(body: &[u8]) -> Result<T, ApiError> {
    let bad =
        |e: &dyn std::fmt::Display| ApiError(StatusCode::BAD_REQUEST, format!("request body: {e}"));
    let mut de = serde_json::Deserializer::from_slice(body);
    let value = serde_path_to_error::deserialize(&mut de).map_err(|e| bad(&e))?;
    de.end()
        .map_err(|e| bad(&format_args!("{e} after the JSON value")))?;
    Ok(value)
}

/// The body of every error response.
#[derive(Debug, serde::Serialize, utoipa::ToSchema)]
pub struct ErrorBody {
    /// What went wrong, for a person to read.
    pub error: String,
}

/// The message of an error response, left in its extensions for the request log.
#[derive(Debug, Clone)]
pub(crate) struct ErrorText(pub(crate) String);

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let text = ErrorText(self.1.clone());
        let mut r = (self.0, Json(ErrorBody { error: self.1 })).into_response();
        r.extensions_mut().insert(text);
        r
    }
}

/// The caller the gate authenticated; `may` refuses with 403 naming role and action.
struct Caller(Principal);

impl<S: Send + Sync> FromRequestParts<S> for Caller {
    type Rejection = ApiError;

    /// Cancel-safe: it only reads the request.
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
        ClientCommand::Answer { .. } | ClientCommand::ConfirmClear { .. } => Action::Answer,
    }
}

/// A campaign id from the path; anything but a whole number is a JSON 400.
struct CampaignId(i64);

impl<S: Send + Sync> FromRequestParts<S> for CampaignId {
    type Rejection = ApiError;

    /// Cancel-safe: it only reads the request.
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
    let metrics = Arc::clone(daemon.metrics());
    Router::new()
        .merge(web::routes())
        .route("/api/health", get(health))
        .route("/api/openapi.json", get(openapi::serve_document))
        .route("/api/whoami", get(whoami))
        .route("/api/campaigns", get(list).post(create))
        .route("/api/campaigns/{id}", get(one))
        .route("/api/campaigns/{id}/commands", post(command))
        .route("/api/campaigns/{id}/events", get(journal))
        .route("/api/campaigns/{id}/stream", get(stream))
        .route("/api/campaigns/{id}/result", get(result))
        .route("/api/campaigns/{id}/model", get(model))
        .route("/api/campaigns/{id}/report", get(report))
        .route("/api/campaigns/{id}/prompt", get(prompt))
        .route("/api/campaigns/{id}/measurements", get(measurements))
        .route("/api/campaigns/{id}/plan", get(plan))
        .route("/api/devices", get(devices))
        .route("/api/cell/stop", post(cell_stop))
        .route("/metrics", get(prometheus_metrics))
        .fallback(|| async { ApiError(StatusCode::NOT_FOUND, "no such endpoint".into()) })
        .layer(DefaultBodyLimit::max(MAX_BODY_BYTES))
        .layer(axum::middleware::from_fn_with_state(gate, guard::guard))
        .layer(axum::middleware::from_fn(guard::json_errors))
        .layer(axum::middleware::from_fn_with_state(
            metrics,
            observe::observe,
        ))
        .with_state(daemon)
}

/// Serve `app` on `listener` (TLS when `tls` is given) until `handle` shuts it down, within
/// `limits` ([`conns`]: a connection cap with room for new requests, header-read and idle
/// timeouts, failed accepts logged).
/// Cancel-safe: dropping the future stops accepting; connections already open run on until
/// they end (a graceful stop goes through `handle`).
pub async fn serve(
    listener: std::net::TcpListener,
    app: Router,
    tls: Option<axum_server::tls_rustls::RustlsConfig>,
    handle: axum_server::Handle<std::net::SocketAddr>,
    limits: ServeLimits,
) -> std::io::Result<()> {
    let service = app.into_make_service();
    let conns = Arc::new(conns::Connections::new(limits));
    let _reaper = conns::Reaper::start(Arc::clone(&conns));
    let mut server = axum_server::from_tcp(listener)?
        .handle(handle)
        .first_request_timeout(limits.header_read_timeout);
    server
        .http_builder()
        .http1()
        .timer(hyper_util::rt::TokioTimer::new())
        .header_read_timeout(limits.header_read_timeout);
    let failed = Arc::clone(&conns);
    let server = server.accept_error_handler(move |_, e| {
        failed.accept_failed(e, std::time::Instant::now());
    });
    let plain = conns::Tracking::new(axum_server::accept::DefaultAcceptor::new(), conns);
    match tls {
        None => server.acceptor(plain).serve(service).await,
        Some(config) => {
            let tls = axum_server::tls_rustls::RustlsAcceptor::new(config)
                .handshake_timeout(limits.header_read_timeout)
                .acceptor(plain);
            server.acceptor(tls).serve(service).await
        }
    }
}

/// The answer of the health check.
#[derive(Debug, serde::Serialize, utoipa::ToSchema)]
pub struct Health {
    /// Always `true` when the daemon answers.
    pub ok: bool,
    /// The daemon's version.
    pub version: &'static str,
}

/// Whether the daemon answers (no token needed).
///
/// Cancel-safe: no state.
#[utoipa::path(get, path = "/api/health", tag = "daemon", security(()),
    responses((status = 200, description = "the daemon answers", body = Health)))]
async fn health() -> Json<Health> {
    Json(Health {
        ok: true,
        version: env!("CARGO_PKG_VERSION"),
    })
}

/// The actions a client may ask for, by the names the web page uses.
const ACTIONS: [(&str, Action); 9] = [
    ("read", Action::Read),
    ("create", Action::Create),
    ("arm", Action::Arm),
    ("disarm", Action::Disarm),
    ("start", Action::Start),
    ("pause", Action::Pause),
    ("resume", Action::Resume),
    ("abort", Action::Abort),
    ("answer", Action::Answer),
];

/// Who the caller is and what its role may do (the page offers only those actions).
#[derive(Debug, serde::Serialize, utoipa::ToSchema)]
pub struct WhoAmI {
    /// The token's configured name.
    pub name: String,
    /// `viewer`, `technician` or `operator`.
    #[schema(value_type = String, example = "operator")]
    pub role: crate::auth::Role,
    /// The actions this role may ask for: `read`, `create`, `arm`, `disarm`, `start`, `pause`,
    /// `resume`, `abort`, `answer`.
    pub may: Vec<&'static str>,
}

/// The caller's name, role and allowed actions.
///
/// Cancel-safe: it only reads.
#[utoipa::path(get, path = "/api/whoami", tag = "daemon",
    responses((status = 200, description = "the caller", body = WhoAmI),
        (status = 401, description = "no or unknown token", body = ErrorBody)))]
async fn whoami(caller: Caller) -> Json<WhoAmI> {
    let may = ACTIONS
        .iter()
        .filter(|(_, a)| caller.0.role.may(*a))
        .map(|(n, _)| *n)
        .collect();
    Json(WhoAmI {
        name: caller.0.name.clone(),
        role: caller.0.role,
        may,
    })
}

/// Every stored campaign.
///
/// Cancel-safe: it only reads.
#[utoipa::path(get, path = "/api/campaigns", tag = "campaigns",
    responses((status = 200, description = "every stored campaign", body = Vec<CampaignView>),
        (status = 401, description = "no or unknown token", body = ErrorBody)))]
async fn list(State(d): State<Shared>) -> Result<Response, ApiError> {
    Ok(Json(d.list().await?).into_response())
}

/// Plan and store a new campaign and load it (nothing moves yet).
///
/// Cancel-safe: the creation runs in its own task, so a dropped request (client gone) still creates
/// and loads the campaign, or fails, as a whole.
#[utoipa::path(post, path = "/api/campaigns", tag = "campaigns",
    request_body(content = Option<CampaignOverrides>, content_type = "application/json",
        description = "overrides of the configuration's `[campaign]`; may be empty"),
    responses((status = 201, description = "created and loaded", body = CampaignView),
        (status = 400, description = "a bad override, or a campaign that cannot run", body = ErrorBody),
        (status = 401, description = "no or unknown token", body = ErrorBody),
        (status = 403, description = "the role may not create", body = ErrorBody),
        (status = 409, description = "a campaign is loaded, or another process commands the cell", body = ErrorBody),
        (status = 413, description = "body over 64 KiB", body = ErrorBody),
        (status = 415, description = "body not declared application/json", body = ErrorBody)))]
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

/// One campaign: state, progress, open question.
///
/// Cancel-safe: it only reads.
#[utoipa::path(get, path = "/api/campaigns/{id}", tag = "campaigns",
    params(("id" = i64, Path, description = "campaign id")),
    responses((status = 200, description = "the campaign", body = CampaignView),
        (status = 400, description = "the id is not a number", body = ErrorBody),
        (status = 401, description = "no or unknown token", body = ErrorBody),
        (status = 404, description = "no such campaign", body = ErrorBody)))]
async fn one(State(d): State<Shared>, CampaignId(id): CampaignId) -> Result<Response, ApiError> {
    Ok(Json(d.get(id).await?).into_response())
}

/// A command to a campaign; answers with the campaign after it.
///
/// Cancel-safe: the command is applied before any wait, so a dropped request (client gone) still
/// applies it; only the reply is lost.
#[utoipa::path(post, path = "/api/campaigns/{id}/commands", tag = "campaigns",
    params(("id" = i64, Path, description = "campaign id")),
    request_body(content = ClientCommand, content_type = "application/json"),
    responses((status = 200, description = "the campaign after the command: in, or going to, the state the command asks for (`pausing`: a pause waits for the current pose or open question)", body = CampaignView),
        (status = 400, description = "a bad command or value", body = ErrorBody),
        (status = 401, description = "no or unknown token", body = ErrorBody),
        (status = 403, description = "the role may not do that", body = ErrorBody),
        (status = 404, description = "no such campaign", body = ErrorBody),
        (status = 409, description = "conflicts with the cell's current use (not armed, a stale question number, a command the campaign's state has nothing for — a pause or resume before the start, a start while paused, anything but a stop while identifying —, a campaign that is not loaded — only arm, start and resume load one —, another process commanding the cell, …)", body = ErrorBody),
        (status = 413, description = "body over 64 KiB", body = ErrorBody),
        (status = 415, description = "body not declared application/json", body = ErrorBody)))]
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

/// The stored event journal.
///
/// Cancel-safe: it only reads.
#[utoipa::path(get, path = "/api/campaigns/{id}/events", tag = "events",
    params(("id" = i64, Path, description = "campaign id")),
    responses((status = 200, description = "`[{seq, at_ms, kind, event}]` in sequence order", body = Vec<serde_json::Value>),
        (status = 400, description = "the id is not a number", body = ErrorBody),
        (status = 401, description = "no or unknown token", body = ErrorBody),
        (status = 404, description = "no such campaign", body = ErrorBody)))]
async fn journal(
    State(d): State<Shared>,
    CampaignId(id): CampaignId,
) -> Result<Response, ApiError> {
    Ok(Json(d.journal(id).await?).into_response())
}

/// The `cellcal identify` JSON of a campaign, rendered from its stored typed result.
///
/// Cancel-safe: it only reads.
#[utoipa::path(get, path = "/api/campaigns/{id}/result", tag = "campaigns",
    params(("id" = i64, Path, description = "campaign id")),
    responses((status = 200, description = "the `cellcal identify` JSON contract (see docs/data-formats.md), rendered from the stored result; an ISO 9283 campaign's stored figures", body = serde_json::Value,
            headers(("content-disposition" = String, description = "`attachment; filename=\"campaign-{id}-result.json\"`"))),
        (status = 400, description = "the id is not a number", body = ErrorBody),
        (status = 401, description = "no or unknown token", body = ErrorBody),
        (status = 404, description = "no such campaign, or no result yet", body = ErrorBody),
        (status = 500, description = "the stored result cannot be read", body = ErrorBody)))]
async fn result(State(d): State<Shared>, CampaignId(id): CampaignId) -> Result<Response, ApiError> {
    match d.result(id).await? {
        Some(v) => Ok(attachment(Json(v).into_response(), id, "result.json")),
        None => Err(no_result_yet(id)),
    }
}

/// `r` with `Content-Disposition: attachment; filename="campaign-{id}-{what}"`: the name a
/// saved copy gets (the page's downloads and `curl -OJ` use it).
fn attachment(mut r: Response, id: i64, what: &str) -> Response {
    let value = format!("attachment; filename=\"campaign-{id}-{what}\"");
    if let Ok(v) = axum::http::HeaderValue::from_str(&value) {
        r.headers_mut().insert(CONTENT_DISPOSITION, v);
    }
    r
}

/// 404 for a campaign that has not been identified (its result, model and report).
fn no_result_yet(id: i64) -> ApiError {
    ApiError(
        StatusCode::NOT_FOUND,
        format!("campaign {id} has no result yet"),
    )
}

/// The corrected model of a campaign: the robot TOML `cellcal run --model-out` writes.
///
/// Cancel-safe: it only reads.
#[utoipa::path(get, path = "/api/campaigns/{id}/model", tag = "campaigns",
    params(("id" = i64, Path, description = "campaign id")),
    responses((status = 200, description = "a robot model file (TOML) with the identified absolute MDH values, base and tool, the nominal joint limits and a provenance header; every command loads it as `--robot`", body = String, content_type = "text/plain; charset=utf-8",
            headers(("content-disposition" = String, description = "`attachment; filename=\"campaign-{id}-model.toml\"`"))),
        (status = 400, description = "the id is not a number", body = ErrorBody),
        (status = 401, description = "no or unknown token", body = ErrorBody),
        (status = 404, description = "no such campaign, or no result yet", body = ErrorBody),
        (status = 500, description = "the stored campaign cannot be rebuilt", body = ErrorBody)))]
async fn model(State(d): State<Shared>, CampaignId(id): CampaignId) -> Result<Response, ApiError> {
    match d.model(id).await? {
        Some(text) => Ok(attachment(
            ([(CONTENT_TYPE, "text/plain; charset=utf-8")], text).into_response(),
            id,
            "model.toml",
        )),
        None => Err(no_result_yet(id)),
    }
}

/// The calibration report of a campaign: one self-contained HTML page.
///
/// Cancel-safe: it only reads.
#[utoipa::path(get, path = "/api/campaigns/{id}/report", tag = "campaigns",
    params(("id" = i64, Path, description = "campaign id")),
    responses((status = 200, description = "the calibration report: one self-contained HTML page (inline CSS and SVG plots, no script, no external reference; see docs/report.md)", body = String, content_type = "text/html",
            headers(("content-disposition" = String, description = "`attachment; filename=\"campaign-{id}-report.html\"`"))),
        (status = 400, description = "the id is not a number", body = ErrorBody),
        (status = 401, description = "no or unknown token", body = ErrorBody),
        (status = 404, description = "no such campaign, or no result yet", body = ErrorBody),
        (status = 409, description = "an ISO 9283 campaign: no calibration report (its figures are the result)", body = ErrorBody)))]
async fn report(State(d): State<Shared>, CampaignId(id): CampaignId) -> Result<Response, ApiError> {
    match d.report_html(id).await? {
        Some(html) => Ok(attachment(web::report_page(html), id, "report.html")),
        None => Err(no_result_yet(id)),
    }
}

/// The question waiting for the technician; 204 when none.
///
/// Cancel-safe: it only reads.
#[utoipa::path(get, path = "/api/campaigns/{id}/prompt", tag = "campaigns",
    params(("id" = i64, Path, description = "campaign id")),
    responses((status = 200, description = "the open question", body = PromptView),
        (status = 204, description = "no question is open"),
        (status = 400, description = "the id is not a number", body = ErrorBody),
        (status = 401, description = "no or unknown token", body = ErrorBody),
        (status = 404, description = "no such campaign", body = ErrorBody)))]
async fn prompt(State(d): State<Shared>, CampaignId(id): CampaignId) -> Result<Response, ApiError> {
    Ok(match d.get(id).await?.prompt {
        Some(p) => Json(p).into_response(),
        None => StatusCode::NO_CONTENT.into_response(),
    })
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
            .event(e.event.kind())
            .data(serde_json::to_string(&e.event).unwrap_or_default()),
        Followed::Replayed { count } => {
            Event::default().comment(format!("replayed {count} events from the journal"))
        }
    }
}

/// Live events as Server-Sent Events.
///
/// Cancel-safe: a dropped stream ends its follower task; nothing else changes.
#[utoipa::path(get, path = "/api/campaigns/{id}/stream", tag = "events",
    params(("id" = i64, Path, description = "campaign id"),
        ("Last-Event-ID" = Option<i64>, Header, description = "resume after this journal sequence number"),
        ("last_event_id" = Option<i64>, Query, description = "the same, for clients that cannot set headers")),
    responses((status = 200, description = "`id:` = journal seq, `event:` = kind (`state`, `measured`, `fault`, `drift`, `setup`, `prompt`, `note`, `result`), `data:` = the event JSON; ends after the run's final state",
            body = String, content_type = "text/event-stream"),
        (status = 400, description = "a bad id or last event id", body = ErrorBody),
        (status = 401, description = "no or unknown token", body = ErrorBody),
        (status = 404, description = "no such campaign", body = ErrorBody)))]
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

/// `?format=` of the measurements.
#[derive(Debug, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct MeasurementsQuery {
    format: Option<String>,
}

/// A campaign's measured poses: JSON rows, or the identify CSV of `cellcal export`.
///
/// Cancel-safe: it only reads.
#[utoipa::path(get, path = "/api/campaigns/{id}/measurements", tag = "campaigns",
    params(("id" = i64, Path, description = "campaign id"),
        ("format" = Option<String>, Query, description = "`json` (default) or `csv`: the identify CSV with its setup header, exactly as `cellcal export` writes it")),
    responses((status = 200, description = "the measured poses in plan order (P1/P2 in the campaign's first tracker frame)", body = Vec<MeasurementRow>),
        (status = 400, description = "a bad id or format", body = ErrorBody),
        (status = 401, description = "no or unknown token", body = ErrorBody),
        (status = 404, description = "no such campaign", body = ErrorBody),
        (status = 409, description = "the campaign cannot be rebuilt for the CSV (an import without its robot model)", body = ErrorBody)))]
async fn measurements(
    State(d): State<Shared>,
    CampaignId(id): CampaignId,
    query: Result<Query<MeasurementsQuery>, QueryRejection>,
) -> Result<Response, ApiError> {
    let query = query.map_err(|e| ApiError(StatusCode::BAD_REQUEST, e.body_text()))?;
    match query.0.format.as_deref() {
        None | Some("json") => Ok(Json(d.measurements(id).await?).into_response()),
        Some("csv") => {
            let csv = d.measurements_csv(id).await?;
            let disposition = format!("attachment; filename=\"campaign-{id}-measurements.csv\"");
            Ok((
                [
                    (CONTENT_TYPE, "text/csv; charset=utf-8".to_owned()),
                    (CONTENT_DISPOSITION, disposition),
                ],
                csv,
            )
                .into_response())
        }
        Some(f) => Err(ApiError(
            StatusCode::BAD_REQUEST,
            format!("format: `{f}` is neither `json` nor `csv`"),
        )),
    }
}

/// A campaign's stored plan.
///
/// Cancel-safe: it only reads.
#[utoipa::path(get, path = "/api/campaigns/{id}/plan", tag = "campaigns",
    params(("id" = i64, Path, description = "campaign id")),
    responses((status = 200, description = "every planned pose in move order with its set, joint target (rad) and done mark", body = PlanView),
        (status = 400, description = "the id is not a number", body = ErrorBody),
        (status = 401, description = "no or unknown token", body = ErrorBody),
        (status = 404, description = "no such campaign", body = ErrorBody)))]
async fn plan(State(d): State<Shared>, CampaignId(id): CampaignId) -> Result<Response, ApiError> {
    Ok(Json(d.plan(id).await?).into_response())
}

/// The cell's devices: kind, address, simulated, connected (null when unknown), last fault.
///
/// Cancel-safe: it only reads.
#[utoipa::path(get, path = "/api/devices", tag = "daemon",
    responses((status = 200, description = "tracker, robot and stage", body = DevicesView),
        (status = 401, description = "no or unknown token", body = ErrorBody)))]
async fn devices(State(d): State<Shared>, caller: Caller) -> Result<Response, ApiError> {
    caller.may(Action::Read)?;
    Ok(Json(d.devices()).into_response())
}

/// Stop the cell: abort the loaded campaign and stop every device that moves (robot, stage);
/// any role may. Answers with what was stopped and what each device said.
///
/// Cancel-safe: the abort is applied before the reply waits for the engine; a dropped request
/// only loses the reply.
#[utoipa::path(post, path = "/api/cell/stop", tag = "daemon",
    responses((status = 200, description = "the campaign that was running (now aborted) and each device's answer to the stop; nulls when no campaign was running (nothing moves then)", body = CellStopView),
        (status = 401, description = "no or unknown token", body = ErrorBody),
        (status = 403, description = "the role may not do that", body = ErrorBody)))]
async fn cell_stop(State(d): State<Shared>, caller: Caller) -> Result<Response, ApiError> {
    caller.may(Action::Abort)?;
    Ok(Json(d.cell_stop().await?).into_response())
}

/// Prometheus metrics (OpenMetrics text); any role's token (Prometheus: `bearer_token`).
///
/// Cancel-safe: it only reads.
#[utoipa::path(get, path = "/metrics", tag = "daemon",
    responses((status = 200, description = "poses measured, faults and retries by kind, campaign state, request latency by route",
            body = String, content_type = "application/openmetrics-text"),
        (status = 401, description = "no or unknown token", body = ErrorBody)))]
async fn prometheus_metrics(State(d): State<Shared>, caller: Caller) -> Result<Response, ApiError> {
    caller.may(Action::Read)?;
    Ok((
        [(CONTENT_TYPE, crate::metrics::CONTENT_TYPE)],
        d.metrics().encode(),
    )
        .into_response())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_body_is_one_json_value_and_nothing_after_it() {
        let cmd: ClientCommand =
            parse_body(b" {\"command\": \"disarm\"} \r\n\t").expect("whitespace");
        assert!(matches!(cmd, ClientCommand::Disarm));
        for trailing in [
            &br#"{"command":"disarm"}{"command":"arm"}"#[..],
            br#"{"command":"disarm"} x"#,
            br#"{"command":"disarm"},"#,
            b"{\"command\":\"disarm\"}\0",
        ] {
            let e = parse_body::<ClientCommand>(trailing).expect_err("trailing data");
            assert_eq!(e.0, StatusCode::BAD_REQUEST);
            assert!(e.1.contains("after the JSON value"), "{}", e.1);
        }
    }
}
