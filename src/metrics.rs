//! The daemon's Prometheus metrics, kept with `prometheus-client` (the Prometheus project's own
//! Rust client: typed metric families, no global registry, OpenMetrics text out) and served by
//! `GET /metrics`. The campaign side is fed from the journalled events (see
//! [`crate::daemon`]), the HTTP side by the API's request middleware.
//!
//! | metric | type | labels |
//! |---|---|---|
//! | `cellcal_poses_measured_total` | counter | (poses committed while this daemon ran) |
//! | `cellcal_faults_total` | counter | `device`, `kind`, `action` |
//! | `cellcal_retries_total` | counter | `device`, `kind` (faults the engine retried: relock, reconnect, …) |
//! | `cellcal_campaign_state` | gauge, 1 for the current state | `state` (`none` before any campaign) |
//! | `cellcal_campaign_poses_done`, `cellcal_campaign_poses_planned` | gauge | (the loaded campaign) |
//! | `cellcal_http_request_duration_seconds` | histogram | `method` (one of [`HTTP_METHODS`], else `other`), `route` (the route template, `other` when none matched), `status` |
//!
//! Every label value comes from a fixed set (the engine's device, fault and action names, the
//! router's templates, [`HTTP_METHODS`], status codes), never from a client's raw text, so the
//! text stays bounded whatever clients send.

use std::time::Duration;

use crate::campaign::events::fault_kind_name;
use crate::campaign::CampaignEvent;

use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{exponential_buckets, Histogram};
use prometheus_client::registry::{Registry, Unit};

/// The `Content-Type` of [`Metrics::encode`]'s text.
pub const CONTENT_TYPE: &str = "application/openmetrics-text; version=1.0.0; charset=utf-8";

/// Every state name the `cellcal_campaign_state` gauge carries (`none`: no campaign yet).
pub const STATES: [&str; 10] = [
    "none",
    "created",
    "idle",
    "armed",
    "running",
    "paused",
    "identifying",
    "done",
    "aborted",
    "failed",
];

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct FaultLabels {
    device: String,
    kind: String,
    action: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct RetryLabels {
    device: String,
    kind: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct StateLabels {
    state: &'static str,
}

/// The HTTP methods counted by name; any other is counted as [`OTHER`].
pub const HTTP_METHODS: [&str; 7] = ["GET", "HEAD", "POST", "PUT", "DELETE", "PATCH", "OPTIONS"];

/// The label of an HTTP method not in [`HTTP_METHODS`], or a request no route matched.
pub const OTHER: &str = "other";

/// `method`'s label: itself when in [`HTTP_METHODS`], else [`OTHER`].
pub fn method_label(method: &str) -> &'static str {
    HTTP_METHODS
        .iter()
        .find(|m| **m == method)
        .copied()
        .unwrap_or(OTHER)
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct HttpLabels {
    method: &'static str,
    route: String,
    status: u16,
}

/// Request latency buckets: 0.25 ms … ~8 s, doubling.
fn latency_histogram() -> Histogram {
    Histogram::new(exponential_buckets(0.000_25, 2.0, 16))
}

/// The daemon's metrics (cheap to update from any thread; see the module doc for names).
pub struct Metrics {
    registry: Registry,
    poses_measured: Counter,
    faults: Family<FaultLabels, Counter>,
    retries: Family<RetryLabels, Counter>,
    state: Family<StateLabels, Gauge>,
    poses_done: Gauge,
    poses_planned: Gauge,
    http: Family<HttpLabels, Histogram, fn() -> Histogram>,
}

impl Default for Metrics {
    fn default() -> Metrics {
        Metrics::new()
    }
}

/// Whether the engine's fault `action` is a retry (the campaign goes on by itself), as opposed
/// to `pause` / `abort`, which need the operator.
pub fn is_retry(action: &str) -> bool {
    !matches!(action, "pause" | "abort")
}

impl Metrics {
    /// Every metric registered, at zero; the campaign state `none`.
    pub fn new() -> Metrics {
        let mut registry = Registry::with_prefix("cellcal");
        let poses_measured = Counter::default();
        registry.register(
            "poses_measured",
            "Poses measured and committed to the store while this daemon ran",
            poses_measured.clone(),
        );
        let faults = Family::<FaultLabels, Counter>::default();
        registry.register(
            "faults",
            "Device faults journalled by the engine, by device, fault kind and action taken",
            faults.clone(),
        );
        let retries = Family::<RetryLabels, Counter>::default();
        registry.register(
            "retries",
            "Faults the engine recovered from by itself (relock, reconnect, retry, measure again, …)",
            retries.clone(),
        );
        let state = Family::<StateLabels, Gauge>::default();
        registry.register(
            "campaign_state",
            "1 for the state of the campaign loaded last (none: no campaign yet), 0 for the others",
            state.clone(),
        );
        let poses_done = Gauge::default();
        registry.register(
            "campaign_poses_done",
            "Poses measured of the campaign loaded last",
            poses_done.clone(),
        );
        let poses_planned = Gauge::default();
        registry.register(
            "campaign_poses_planned",
            "Poses planned of the campaign loaded last",
            poses_planned.clone(),
        );
        let http = Family::<HttpLabels, Histogram, fn() -> Histogram>::new_with_constructor(
            latency_histogram,
        );
        registry.register_with_unit(
            "http_request_duration",
            "Time from a request's arrival to its response head (a stream: until it opens), by route template",
            Unit::Seconds,
            http.clone(),
        );
        let m = Metrics {
            registry,
            poses_measured,
            faults,
            retries,
            state,
            poses_done,
            poses_planned,
            http,
        };
        m.set_state("none");
        m
    }

    /// Count a journalled event: a state change sets the state gauge, a measured pose the
    /// poses and the progress, a fault the faults (and retries); other events count nothing.
    pub fn event(&self, e: &CampaignEvent) {
        match e {
            CampaignEvent::State { state } => self.set_state(state.name()),
            CampaignEvent::Measured { done, total, .. } => {
                self.measured(*done as u64, *total as u64)
            }
            CampaignEvent::Fault {
                device,
                kind,
                action,
                ..
            } => self.fault(device.name(), fault_kind_name(*kind), action),
            _ => {}
        }
    }

    /// The campaign's state is now `name` (one of [`STATES`]; any other sets none).
    fn set_state(&self, name: &str) {
        for s in STATES {
            self.state
                .get_or_create(&StateLabels { state: s })
                .set(i64::from(s == name));
        }
    }

    /// A pose was measured: `done` of `total`.
    fn measured(&self, done: u64, total: u64) {
        self.poses_measured.inc();
        self.progress(done, total);
    }

    /// The loaded campaign's progress.
    pub fn progress(&self, done: u64, total: u64) {
        self.poses_done.set(i64::try_from(done).unwrap_or(i64::MAX));
        self.poses_planned
            .set(i64::try_from(total).unwrap_or(i64::MAX));
    }

    /// A device fault and the engine's action (a retry unless `pause`/`abort`).
    fn fault(&self, device: &str, kind: &str, action: &str) {
        self.faults
            .get_or_create(&FaultLabels {
                device: device.to_owned(),
                kind: kind.to_owned(),
                action: action.to_owned(),
            })
            .inc();
        if is_retry(action) {
            self.retries
                .get_or_create(&RetryLabels {
                    device: device.to_owned(),
                    kind: kind.to_owned(),
                })
                .inc();
        }
    }

    /// One HTTP request answered with `status` after `took`; `route` is the route template
    /// that matched (`None`: [`OTHER`]), `method` is counted by [`method_label`]: never a raw
    /// value as a label.
    pub fn request(&self, method: &str, route: Option<&str>, status: u16, took: Duration) {
        self.http
            .get_or_create(&HttpLabels {
                method: method_label(method),
                route: route.unwrap_or(OTHER).to_owned(),
                status,
            })
            .observe(took.as_secs_f64());
    }

    /// The OpenMetrics text of every metric (ends with `# EOF`).
    pub fn encode(&self) -> String {
        let mut out = String::new();
        // writing into a String cannot fail
        let _ = prometheus_client::encoding::text::encode(&mut out, &self.registry);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::campaign::CampaignState;
    use crate::cell::{DeviceKind, FaultKind};

    #[test]
    fn the_text_names_every_metric_and_one_state() {
        let m = Metrics::new();
        m.event(&CampaignEvent::State {
            state: CampaignState::Running,
        });
        m.event(&CampaignEvent::Measured {
            pose: 7,
            done: 3,
            total: 10,
            p1_mm: [0.0; 3],
            deviation_mm: None,
            deviation_xyz_mm: None,
        });
        m.event(&CampaignEvent::fault(
            DeviceKind::Tracker,
            FaultKind::BeamBroken,
            "lost",
            "relock",
        ));
        m.event(&CampaignEvent::fault(
            DeviceKind::Robot,
            FaultKind::EmergencyStop,
            "e-stop",
            "pause",
        ));
        m.request(
            "GET",
            Some("/api/campaigns/{id}"),
            200,
            Duration::from_millis(2),
        );
        m.request("BREW", None, 401, Duration::from_millis(1));
        m.request(
            &"X".repeat(60_000),
            Some("/api/campaigns"),
            401,
            Duration::ZERO,
        );
        let t = m.encode();
        for want in [
            "cellcal_poses_measured_total 1",
            r#"cellcal_campaign_state{state="running"} 1"#,
            r#"cellcal_campaign_state{state="none"} 0"#,
            "cellcal_campaign_poses_done 3",
            "cellcal_campaign_poses_planned 10",
            r#"cellcal_faults_total{device="tracker",kind="BeamBroken",action="relock"} 1"#,
            r#"cellcal_retries_total{device="tracker",kind="BeamBroken"} 1"#,
            r#"cellcal_http_request_duration_seconds_count{method="GET",route="/api/campaigns/{id}",status="200"} 1"#,
            r#"cellcal_http_request_duration_seconds_count{method="other",route="other",status="401"} 1"#,
            r#"cellcal_http_request_duration_seconds_count{method="other",route="/api/campaigns",status="401"} 1"#,
            "# EOF",
        ] {
            assert!(t.contains(want), "{want} missing from\n{t}");
        }
        assert!(!t.contains("BREW") && !t.contains("XXXX"), "{t}");
        // a pause is not a retry
        assert!(
            !t.contains(r#"cellcal_retries_total{device="robot""#),
            "{t}"
        );
    }
}
