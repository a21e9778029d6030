//! The non-geometric part of a result as the views show it (docs/method.md §10): the terms with
//! their values, σ and status, the torque model's inputs and the before / geometric / extended
//! comparison per set, each number with the JSON pointer it comes from.

use crate::calibrate::identify_json::{BeforeAfter, MassJson, MetricsJson, ParamStatus};
use crate::calibrate::{IdentifyReport, KeptModel, TermJson};
use crate::model::TermFamily;
use crate::units::human::{fmt_fixed, fmt_mrad};

/// The non-geometric part of one result.
#[derive(Debug, Clone, Copy)]
pub struct Extended<'a> {
    /// The families asked for (`compliance`, `harmonics`).
    pub families: &'a [TermFamily],
    /// Every candidate term (`/nongeometric_terms`).
    pub terms: &'a [TermJson],
    /// Before and after of the model handed over (`/metrics`).
    pub metrics: &'a MetricsJson,
    /// The geometric model fitted to the same data (`/metrics_geometric`).
    pub geometric: &'a MetricsJson,
    /// The extended model's metrics when the geometric one was kept (`/metrics_extended`).
    pub extended_not_kept: Option<&'a MetricsJson>,
    /// Which model was handed over.
    pub kept: KeptModel,
    /// Direction of gravity in the robot base frame (`/gravity`).
    pub gravity: Option<[f64; 3]>,
    /// The masses of the torque model (`/masses`).
    pub masses: &'a [MassJson],
}

/// One model's column of the comparison: its JSON pointer (below which `/{set}/…` follows)
/// and its metrics.
#[derive(Debug, Clone, Copy)]
pub struct Column<'a> {
    /// `before`, `geometric` or `extended`.
    pub label: &'static str,
    /// The pointer of the set's pair, `/metrics` or `/metrics_geometric` …
    pub pointer: &'static str,
    /// `before` or `after` within the pair.
    pub state: &'static str,
    /// The pair of metrics of each set.
    pub metrics: &'a MetricsJson,
}

impl<'a> Column<'a> {
    /// The pair of set `set` (`ident`, `verify`), if the result has that set.
    pub fn pair(&self, set: &str) -> Option<&'a BeforeAfter> {
        match set {
            "ident" => Some(&self.metrics.ident),
            _ => self.metrics.verify.as_ref(),
        }
    }

    /// The metrics of set `set` in this column.
    pub fn of(&self, set: &str) -> Option<&'a crate::analysis::metrics::Metrics> {
        self.pair(set).map(|p| {
            if self.state == "before" {
                &p.before
            } else {
                &p.after
            }
        })
    }
}

impl<'a> Extended<'a> {
    /// The non-geometric part of `r`, `None` for a geometric identification (or a result that
    /// lacks the geometric fit's metrics or the model handed over).
    pub fn of(r: &'a IdentifyReport) -> Option<Extended<'a>> {
        if r.nongeometric.is_empty() {
            return None;
        }
        Some(Extended {
            families: &r.nongeometric,
            terms: &r.nongeometric_terms,
            metrics: &r.metrics,
            geometric: r.metrics_geometric.as_ref()?,
            extended_not_kept: r.metrics_extended.as_ref(),
            kept: r.nongeometric_kept?,
            gravity: r.gravity,
            masses: &r.masses,
        })
    }

    /// The three columns of the comparison: before (the nominal model), geometric and extended
    /// (after), each pointing where the JSON holds it.
    pub fn columns(&self) -> [Column<'a>; 3] {
        let (ext_pointer, ext) = match (self.kept, self.extended_not_kept) {
            (KeptModel::Geometric, Some(m)) => ("/metrics_extended", m),
            _ => ("/metrics", self.metrics),
        };
        let (geo_pointer, geo) = match self.kept {
            KeptModel::Extended => ("/metrics_geometric", self.geometric),
            // the model handed over is the geometric one: `metrics` holds it
            KeptModel::Geometric => ("/metrics", self.metrics),
        };
        [
            Column {
                label: "before",
                pointer: "/metrics",
                state: "before",
                metrics: self.metrics,
            },
            Column {
                label: "geometric",
                pointer: geo_pointer,
                state: "after",
                metrics: geo,
            },
            Column {
                label: "extended",
                pointer: ext_pointer,
                state: "after",
                metrics: ext,
            },
        ]
    }
}

/// A term's value (or σ) for people: compliance in µrad/(N·m), a harmonic in mrad, 3 decimals.
pub fn term_value(t: &TermJson, v: f64) -> String {
    if t.kind == "compliance" {
        fmt_fixed(v * 1e6, 3)
    } else {
        fmt_mrad(v)
    }
}

/// The unit [`term_value`] writes for `t`.
pub fn term_unit(t: &TermJson) -> &'static str {
    if t.kind == "compliance" {
        "µrad/(N·m)"
    } else {
        "mrad"
    }
}

/// `value ± σ unit`, or why the term has none (`held at zero: reason`).
pub fn term_value_sigma(t: &TermJson) -> String {
    match (t.status, t.sigma) {
        (ParamStatus::NotIdentified, _) | (_, None) => "held at zero".to_owned(),
        (_, Some(s)) => format!(
            "{} ± {} {}",
            term_value(t, t.value),
            term_value(t, s),
            term_unit(t)
        ),
    }
}

/// Relative change of the extended model's figure against the geometric one's (%, signed).
pub fn change_percent(geometric: f64, extended: f64) -> Option<f64> {
    (geometric > 0.0 && geometric.is_finite() && extended.is_finite())
        .then(|| 100.0 * (extended - geometric) / geometric)
}
