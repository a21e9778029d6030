//! The report's section on the non-geometric terms (docs/method.md §10): what was asked for and
//! which model was handed over, the before / geometric / extended comparison per set, the terms
//! with value ± σ and status (a held term with its reason), and the torque model's inputs
//! (gravity, masses). Every number is tagged with its JSON pointer.

use std::fmt::Write;

use super::page::{
    cell, header_row, json_attrs, json_cell, json_shown, json_text, missing, num_cell,
};
use crate::calibrate::identify_json::{MassJson, ParamStatus};
use crate::calibrate::{IdentifyReport, KeptModel, TermJson};
use crate::report::extended::{change_percent, term_unit, term_value, Extended};
use crate::units::human::{fmt_fixed, fmt_mm};

/// The comparison's rows: label and the metric's JSON key.
const ROWS: [(&str, &str); 3] = [
    ("mean ‖e‖ (mm)", "position_mean_mm"),
    ("rms ‖e‖ (mm)", "position_rms_mm"),
    ("max ‖e‖ (mm)", "position_max_mm"),
];

/// The section's HTML for result `r`.
pub fn section(r: &IdentifyReport) -> String {
    let Some(x) = Extended::of(r) else {
        return missing(
            "A geometric identification: no non-geometric terms were asked for \
             (`identify --nongeometric compliance,harmonics`, `[campaign] nongeometric`).",
        );
    };
    render(&x)
}

/// The section of the non-geometric part `x`.
pub fn render(x: &Extended) -> String {
    let families: Vec<&str> = x.families.iter().map(|f| f.name()).collect();
    let kept = match x.kept {
        KeptModel::Extended => {
            "the <b>extended</b> model (geometric + terms) was handed over: the corrected model \
             file carries the terms, and <code>metrics</code> describe it"
        }
        KeptModel::Geometric => {
            "the <b>geometric</b> model was handed over (<code>nongeometric_keep = \
             \"better\"</code>: the terms did not verify better); the corrected model file \
             carries no terms"
        }
    };
    let mut s = format!(
        "<p>Terms asked for: {}. The link of joint <i>j</i> turns by q<sub>j</sub> + \
         Δθ<sub>j</sub>(q), Δθ<sub>j</sub> = c<sub>j</sub>·τ<sub>j</sub>(q) + harmonics of \
         q<sub>j</sub> (docs/method.md §10); {kept}.</p>\n",
        families.join(", ")
    );
    s.push_str(&comparison(x));
    s.push_str(&terms(x.terms));
    s.push_str(&torque_model(x));
    s
}

/// Before / geometric / extended, mean, rms and max of ‖e‖ per set, and the extended model's
/// change against the geometric one.
fn comparison(x: &Extended) -> String {
    let columns = x.columns();
    let mut s = String::from(
        "<h3 id=\"nongeometric-comparison\">Before, geometric, extended</h3>\n<p>Position error \
         ‖e‖ (mm) of each set under the nominal model (before), the geometric model fitted to \
         the same data, and the geometric model with the terms (extended); the verification \
         set judges out of sample.</p>\n<table>\n",
    );
    s.push_str(&header_row(&[
        "set",
        "",
        "before",
        "geometric",
        "extended",
        "extended vs geometric",
    ]));
    for (set, name) in [("ident", "identification"), ("verify", "verification")] {
        if columns.iter().any(|c| c.of(set).is_none()) {
            continue;
        }
        for (label, key) in ROWS {
            let _ = write!(s, "<tr>{}{}", cell(name), cell(label));
            let mut values = Vec::new();
            for c in &columns {
                let m = c
                    .of(set)
                    .map(|m| serde_json::to_value(m).unwrap_or_default());
                let v = m
                    .as_ref()
                    .and_then(|m| m.get(key))
                    .and_then(serde_json::Value::as_f64);
                values.push(v);
                let pointer = format!("{}/{set}/{}/{key}", c.pointer, c.state);
                s.push_str(&json_cell(&pointer, v, &v.map(fmt_mm).unwrap_or_default()));
            }
            let change = match (values[1], values[2]) {
                (Some(g), Some(e)) => change_percent(g, e),
                _ => None,
            };
            s.push_str(&num_cell(&change.map_or_else(
                || "—".to_owned(),
                |c| format!("{} %", fmt_fixed(c, 1)),
            )));
            s.push_str("</tr>\n");
        }
    }
    s.push_str("</table>\n");
    s
}

/// The status cell of term `i`, tagged with its JSON value.
fn status_cell(i: usize, t: &TermJson) -> String {
    let shown = match t.status {
        ParamStatus::Identified => "identified",
        ParamStatus::SetupRelative => "identified, relative to the setup",
        ParamStatus::NotIdentified => "held at zero",
    };
    let attrs = json_attrs(&format!("/nongeometric_terms/{i}/status"), t.status.name());
    format!("<td {attrs}>{shown}</td>")
}

/// Every candidate term: name, joint, kind, value ± σ, unit, status and why a held one is held.
fn terms(list: &[TermJson]) -> String {
    let mut s = String::from(
        "<h3 id=\"nongeometric-terms\">Terms</h3>\n<p>Compliance in µrad/(N·m), harmonics in \
         mrad; a term these poses do not determine is held at zero (its reason given).</p>\n\
         <table>\n",
    );
    s.push_str(&header_row(&[
        "term", "joint", "kind", "value", "± σ", "unit", "status", "reason",
    ]));
    for (i, t) in list.iter().enumerate() {
        let p = |k: &str| format!("/nongeometric_terms/{i}/{k}");
        let held = t.status == ParamStatus::NotIdentified;
        let _ = writeln!(
            s,
            "<tr{}><td>{}</td>{}<td>{}</td>{}{}<td>{} <span class=\"mono\">({})</span></td>{}<td>{}</td></tr>",
            if held { " class=\"held\"" } else { "" },
            json_text(&p("name"), &t.name),
            json_cell(&p("joint"), Some(t.joint as f64), &t.joint.to_string()),
            json_text(&p("kind"), &t.kind),
            json_cell(&p("value"), Some(t.value), &term_value(t, t.value)),
            json_cell(
                &p("sigma"),
                t.sigma,
                &t.sigma.map(|v| format!("± {}", term_value(t, v))).unwrap_or_default()
            ),
            term_unit(t),
            json_text(&p("unit"), &t.unit),
            status_cell(i, t),
            t.reason
                .as_deref()
                .map(|r| json_text(&p("reason"), r))
                .unwrap_or_default(),
        );
    }
    s.push_str("</table>\n");
    s
}

/// The inputs of the gravity torques: the direction of gravity and the masses.
fn torque_model(x: &Extended) -> String {
    let mut s = String::from(
        "<h3 id=\"torque-model\">Torque model</h3>\n<p>The static gravity torque τ<sub>j</sub>(q) \
         about each joint comes from these lumped masses, each fixed in an MDH frame, and the \
         direction of gravity in the robot base frame (robot model file: <code>gravity</code>, \
         <code>[[masses]]</code>), on the nominal MDH chain the identification started from: \
         the identified geometry does not move the levers, and the corrected model keeps that \
         chain (<code>[[torque_chain]]</code>).</p>\n",
    );
    match x.gravity {
        Some(g) => {
            let parts: Vec<String> = (0..3)
                .map(|k| json_shown(&format!("/gravity/{k}"), g[k], &fmt_fixed(g[k], 4)))
                .collect();
            let _ = writeln!(
                s,
                "<p>gravity (unit vector, robot base frame): ({})</p>",
                parts.join(", ")
            );
        }
        None => s.push_str(&missing(
            "The result does not name the direction of gravity.",
        )),
    }
    if x.masses.is_empty() {
        s.push_str(&missing(
            "No masses: the robot model has no gravity torques, so no compliance was identified.",
        ));
        return s;
    }
    s.push_str("<table>\n");
    s.push_str(&header_row(&[
        "mass",
        "frame",
        "centre of mass in the frame (mm)",
        "kg",
    ]));
    for (i, m) in x.masses.iter().enumerate() {
        s.push_str(&mass_row(i, m));
    }
    s.push_str("</table>\n");
    s
}

fn mass_row(i: usize, m: &MassJson) -> String {
    let p = |k: &str| format!("/masses/{i}/{k}");
    let at: Vec<String> = (0..3)
        .map(|k| json_shown(&p(&format!("at_mm/{k}")), m.at_mm[k], &fmt_mm(m.at_mm[k])))
        .collect();
    format!(
        "<tr>{}{}<td class=\"num\">({})</td>{}</tr>\n",
        num_cell(&(i + 1).to_string()),
        json_cell(&p("frame"), Some(m.frame as f64), &m.frame.to_string()),
        at.join(", "),
        json_cell(&p("kg"), Some(m.kg), &fmt_fixed(m.kg, 3)),
    )
}
