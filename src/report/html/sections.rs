//! The report's sections, in page order. Each returns its HTML; a section whose data is missing
//! says so (and why) instead of disappearing.

use std::fmt::Write;

use super::page::{
    cell, esc, figure, fixed, header_row, json_attrs, json_cell, json_num, json_shown, json_text,
    missing, num_cell, section,
};
use super::plots::{self, BeforeAfter};
use super::{CampaignFacts, ReportInput, SetErrors, SIGNIFICANCE_SAMPLES};
use crate::analysis::metrics::Metrics;
use crate::analysis::significance::Significance;
use crate::calibrate::identify_json::{
    BeforeAfter as MetricsPair, IdentifyReport, NotIdentifiable, ParamStatus, ParameterJson,
};
use crate::calibrate::{BaseResult, ToolFrameResult};
use crate::report::summary::campaign_time_rows;
use crate::units::human::{fmt_deg, fmt_mm, fmt_mm3, fmt_mrad, fmt_sig, fmt_time_in, TimeZone};

/// `(id, heading)` of every section, in order (the table of contents).
const SECTIONS: [(&str, &str); 13] = [
    ("verdict", "Verdict and warnings"),
    ("accuracy", "Accuracy before and after"),
    ("per-pose", "Per-pose position errors"),
    ("histograms", "Error histograms"),
    ("attitude", "Attitude errors"),
    ("parameters", "Identified parameters"),
    ("nongeometric", "Non-geometric terms"),
    ("correlation", "Parameter correlations"),
    ("significance", "Significance indices"),
    ("setup", "Cell setup"),
    ("drift", "Drift checks and faults"),
    ("devices", "Devices"),
    ("provenance", "Provenance"),
];

/// Every section with the table of contents first.
pub fn all(input: &ReportInput) -> String {
    let mut out = toc();
    for note in &input.notes {
        let _ = writeln!(out, "<p class=\"note\">{}</p>", esc(note));
    }
    let bodies = [
        verdict(&input.result),
        accuracy(&input.result),
        per_pose(input),
        histograms(input),
        attitude(input),
        parameters(&input.result),
        super::nongeometric::section(&input.result),
        correlation(&input.result),
        significance(input),
        setup(input),
        drift(input.campaign.as_ref(), &input.provenance.time_zone),
        devices(input.campaign.as_ref()),
        provenance(input),
    ];
    for ((id, heading), body) in SECTIONS.iter().zip(bodies) {
        out.push_str(&section(id, heading, &body));
    }
    out
}

fn toc() -> String {
    let items: String = SECTIONS
        .iter()
        .map(|(id, h)| format!("<li><a href=\"#{id}\">{}</a></li>", esc(h)))
        .collect();
    format!("<nav><ol>{items}</ol></nav>\n")
}

fn verdict(r: &IdentifyReport) -> String {
    let q = r.quality.as_str();
    let mut s = format!(
        "<p>The verdict is <b class=\"sev-{q}\">{}</b>: the worst of the findings below \
         (none: nothing argues against using the result).</p>\n",
        json_text("/quality", q)
    );
    if r.warnings.is_empty() {
        s.push_str("<p>No warnings.</p>\n");
        return s;
    }
    s.push_str("<table>\n");
    s.push_str(&header_row(&["severity", "code", "finding"]));
    for (i, w) in r.warnings.iter().enumerate() {
        let sev = w.severity.as_str();
        let _ = writeln!(
            s,
            "<tr><td class=\"sev-{sev}\">{}</td><td><code>{}</code></td><td>{}</td></tr>",
            json_text(&format!("/warnings/{i}/severity"), sev),
            json_text(&format!("/warnings/{i}/code"), &w.code),
            json_text(&format!("/warnings/{i}/message"), &w.message)
        );
    }
    s.push_str("</table>\n");
    s
}

/// How a metric is shown.
#[derive(Clone, Copy, PartialEq)]
enum Shown {
    /// mm, 3 decimals.
    Mm,
    /// rad shown as mrad, 3 decimals.
    Mrad,
    /// A count.
    Count,
}

/// The accuracy table's rows: label, the metric's JSON key (a pointer below the metrics
/// object) and how it is shown.
const METRIC_ROWS: [(&str, &str, Shown); 14] = [
    ("mean ‖e‖ (mm)", "position_mean_mm", Shown::Mm),
    ("rms ‖e‖ (mm)", "position_rms_mm", Shown::Mm),
    ("p95 ‖e‖ (mm)", "position_p95_mm", Shown::Mm),
    ("max ‖e‖ (mm)", "position_max_mm", Shown::Mm),
    ("mean |e_x| (mm)", "position_axial_mean_mm/0", Shown::Mm),
    ("mean |e_y| (mm)", "position_axial_mean_mm/1", Shown::Mm),
    ("mean |e_z| (mm)", "position_axial_mean_mm/2", Shown::Mm),
    ("max |e_x| (mm)", "position_axial_max_mm/0", Shown::Mm),
    ("max |e_y| (mm)", "position_axial_max_mm/1", Shown::Mm),
    ("max |e_z| (mm)", "position_axial_max_mm/2", Shown::Mm),
    ("mean attitude (mrad)", "attitude_mean_rad", Shown::Mrad),
    ("rms attitude (mrad)", "attitude_rms_rad", Shown::Mrad),
    ("max attitude (mrad)", "attitude_max_rad", Shown::Mrad),
    ("poses", "poses", Shown::Count),
];

/// The cell of metric `key` of `m` (its JSON form), tagged with `pointer/key`.
fn metric_cell(pointer: &str, key: &str, shown: Shown, m: &serde_json::Value) -> String {
    let v = m
        .pointer(&format!("/{key}"))
        .and_then(serde_json::Value::as_f64);
    let text = match (v, shown) {
        (Some(v), Shown::Count) => format!("{v:.0}"),
        (Some(v), Shown::Mrad) => fmt_mrad(v),
        (Some(v), Shown::Mm) => fmt_mm(v),
        (None, _) => "—".to_owned(),
    };
    json_cell(&format!("{pointer}/{key}"), v, &text)
}

fn accuracy(r: &IdentifyReport) -> String {
    let mut sets: Vec<(&str, &MetricsPair)> = vec![("ident", &r.metrics.ident)];
    if let Some(v) = &r.metrics.verify {
        sets.push(("verify", v));
    }
    let base = match r.before_base {
        Some(b) => format!(
            "{} (<code>before_base</code> = {})",
            esc(b.describe()),
            json_text("/before_base", b.name())
        ),
        None => "a base the result does not name (stored before it was named)".to_owned(),
    };
    let mut s = format!(
        "<p>Position error <i>e</i> = measured P1 − model (mm, measurement frame), docs/method.md §6; \
         before = nominal model with the setup's tool and <span id=\"before-base\">{base}</span>, \
         after = identified model. Attitude: the angle between the measured and the modelled \
         stage axis (NP/OP), or of the rotation error (full).</p>\n<table>\n<tr><th></th>",
    );
    for (name, _) in &sets {
        let _ = write!(s, "<th>{name} before</th><th>{name} after</th>");
    }
    s.push_str("</tr>\n");
    let json = |m: &Metrics| serde_json::to_value(m).unwrap_or_default();
    let sets: Vec<_> = sets
        .into_iter()
        .map(|(name, p)| (name, json(&p.before), json(&p.after)))
        .collect();
    for (label, key, shown) in METRIC_ROWS {
        let _ = write!(s, "<tr><th>{}</th>", esc(label));
        for (name, before, after) in &sets {
            s.push_str(&metric_cell(
                &format!("/metrics/{name}/before"),
                key,
                shown,
                before,
            ));
            s.push_str(&metric_cell(
                &format!("/metrics/{name}/after"),
                key,
                shown,
                after,
            ));
        }
        s.push_str("</tr>\n");
    }
    s.push_str("</table>\n");
    s
}

/// The sets with per-pose errors: `(name, errors)`.
fn error_sets(input: &ReportInput) -> Result<Vec<(&'static str, &SetErrors)>, String> {
    let p = input.poses.as_ref().map_err(Clone::clone)?;
    let mut v = vec![("identification", &p.ident)];
    if let Some(ver) = &p.verify {
        v.push(("verification", ver));
    }
    Ok(v)
}

fn unavailable(why: &str) -> String {
    missing(&format!("Per-pose errors are not available: {why}."))
}

fn per_pose(input: &ReportInput) -> String {
    let sets = match error_sets(input) {
        Ok(s) => s,
        Err(why) => return unavailable(&why),
    };
    let mut s = String::from(
        "<p>Each pose's position error before (nominal model) and after (identified model): \
         axial components x, y, z and the comprehensive error ‖e‖, as in the paper's \
         Figs. 8–13.</p>\n",
    );
    for (name, set) in sets {
        let _ = writeln!(
            s,
            "<h3>{} set ({} poses)</h3>\n<div class=\"plots\">",
            esc(name),
            set.ids.len()
        );
        for (axis, label) in ["x", "y", "z", "‖e‖"]
            .iter()
            .enumerate()
            .map(|(k, l)| (k, *l))
        {
            let pick = |e: &super::PoseError| {
                if axis < 3 {
                    e.position_mm[axis]
                } else {
                    e.norm_mm()
                }
            };
            let before: Vec<f64> = set.before.iter().map(pick).collect();
            let after: Vec<f64> = set.after.iter().map(pick).collect();
            let title = format!("{name}: position error {label}");
            let y = if axis < 3 {
                format!("e_{label} (mm)")
            } else {
                "‖e‖ (mm)".to_owned()
            };
            let svg = plots::per_pose(
                &title,
                &y,
                &BeforeAfter {
                    before: &before,
                    after: &after,
                },
            );
            s.push_str(&figure(svg, &title));
        }
        s.push_str("</div>\n");
    }
    s
}

fn histograms(input: &ReportInput) -> String {
    let sets = match error_sets(input) {
        Ok(s) => s,
        Err(why) => return unavailable(&why),
    };
    let mut s = String::from(
        "<p>Distribution of the comprehensive position error ‖e‖ over the poses, before and \
         after (each on its own scale).</p>\n<div class=\"plots\">\n",
    );
    for (name, set) in sets {
        for (state, errors, after) in [("before", &set.before, false), ("after", &set.after, true)]
        {
            let v: Vec<f64> = errors.iter().map(super::PoseError::norm_mm).collect();
            let title = format!("{name} set, {state}: ‖e‖");
            s.push_str(&figure(
                plots::histogram(&title, "‖e‖ (mm)", &v, after),
                &title,
            ));
        }
    }
    s.push_str("</div>\n");
    s
}

fn attitude(input: &ReportInput) -> String {
    let what = match input.result.model.as_str() {
        "position" => {
            return missing(
                "The position model measures no attitude (one point per pose): no attitude errors.",
            )
        }
        "full" => "the angle of the rotation error R_meas·R_modelᵀ (full pose)",
        _ => "the angle between the measured stage direction (P2 − P1) and the modelled stage axis",
    };
    let sets = match error_sets(input) {
        Ok(s) => s,
        Err(why) => return unavailable(&why),
    };
    let mut s = format!(
        "<p>Attitude error per pose: {} (mrad).</p>\n<div class=\"plots\">\n",
        esc(what)
    );
    for (name, set) in sets {
        let mrad = |e: &[super::PoseError]| -> Option<Vec<f64>> {
            e.iter().map(|p| p.attitude_rad.map(|a| a * 1e3)).collect()
        };
        let title = format!("{name}: attitude error");
        match (mrad(&set.before), mrad(&set.after)) {
            (Some(b), Some(a)) => {
                let svg = plots::per_pose(
                    &title,
                    "mrad",
                    &BeforeAfter {
                        before: &b,
                        after: &a,
                    },
                );
                s.push_str(&figure(svg, &title));
            }
            _ => s.push_str(&missing(&format!(
                "{name}: some poses carry no attitude measurement"
            ))),
        }
    }
    s.push_str("</div>\n");
    s
}

/// A parameter error or σ `v` of `p` with its unit: mm, or mrad for an angle (a small angle).
fn error_text(p: &ParameterJson, v: f64) -> String {
    if p.unit == "rad" {
        format!("{} mrad", fmt_mrad(v))
    } else {
        format!("{} mm", fmt_mm(v))
    }
}

/// A nominal value with its unit: mm, or degrees for an angle (a large angle).
fn nominal_text(p: &ParameterJson) -> String {
    if p.unit == "rad" {
        format!("{}°", fmt_deg(p.nominal))
    } else {
        format!("{} mm", fmt_mm(p.nominal))
    }
}

/// The status cell of parameter `i`, tagged with its JSON value.
fn status_cell(i: usize, status: ParamStatus) -> String {
    let shown = match status {
        ParamStatus::Identified => "identified",
        ParamStatus::SetupRelative => "identified, relative to the setup",
        ParamStatus::NotIdentified => "held at nominal",
    };
    let attrs = json_attrs(&format!("/parameters/{i}/status"), status.name());
    format!("<td {attrs}>{shown}</td>")
}

fn parameter_row(i: usize, p: &ParameterJson) -> String {
    let ratio = p.std.filter(|s| *s > 0.0).map(|s| p.error.abs() / s);
    let relative = p.status == ParamStatus::SetupRelative;
    let given = if relative { " given the setup" } else { "" };
    let joint = p.joint.map(|j| j.to_string()).unwrap_or_else(|| "—".into());
    format!(
        "<tr{}><td>{}</td>{}{}{}{}{}{}{}</tr>\n",
        if p.identified { "" } else { " class=\"held\"" },
        json_text(&format!("/parameters/{i}/name"), &p.name),
        cell(&joint),
        json_cell(
            &format!("/parameters/{i}/nominal"),
            Some(p.nominal),
            &nominal_text(p)
        ),
        json_cell(
            &format!("/parameters/{i}/error"),
            Some(p.error),
            &error_text(p, p.error)
        ),
        json_cell(
            &format!("/parameters/{i}/std"),
            p.std,
            &p.std
                .map(|s| format!("± {}{given}", error_text(p, s)))
                .unwrap_or_default()
        ),
        num_cell(
            &ratio
                .map(|r| format!("{}{given}", fixed(r, 1)))
                .unwrap_or_else(|| "—".into())
        ),
        status_cell(i, p.status),
        cell(&p.kind),
    )
}

fn parameters(r: &IdentifyReport) -> String {
    let mut s = format!(
        "<p>{} of {} candidate parameters identified; error = identified − nominal, σ its \
         standard deviation (σ̂₀ = {} mm over the fit's redundancy). Lengths in mm, angle \
         errors and their σ in mrad, nominal angles in degrees.</p>\n<table>\n",
        r.identified.len(),
        r.parameters.len(),
        json_shown("/sigma0_mm", r.sigma0_mm, &fmt_mm(r.sigma0_mm)),
    );
    s.push_str(&header_row(&[
        "parameter",
        "joint",
        "nominal",
        "error",
        "± σ",
        "|error|/σ",
        "status",
        "kind",
    ]));
    for (i, p) in r.parameters.iter().enumerate() {
        s.push_str(&parameter_row(i, p));
    }
    s.push_str("</table>\n");
    s.push_str(&setup_relative(r));
    s.push_str(&tool_and_base(r));
    s.push_str(&not_identifiable(r));
    s
}

/// The identified parameters relative to the setup, and what that means for their σ.
fn setup_relative(r: &IdentifyReport) -> String {
    if r.setup_relative.is_empty() {
        return String::new();
    }
    let mut s = String::from(
        "<h3>Relative to the setup</h3>\n<p id=\"setup-relative-note\">These parameters are \
         identified relative to the setup: the measured tool and stage axis (and a registered \
         base) were held, and were they free they would take these parameters over. Their \
         values and σ hold <b>given the setup</b>; they are not the robot's own geometry to \
         that precision, and an error of the setup moves them. The corrected model predicts \
         well with this setup; its |error|/σ says nothing about the robot alone.</p>\n<table>\n",
    );
    s.push_str(&listed(
        r,
        &r.setup_relative,
        "setup_relative",
        "σ were the setup free",
    ));
    s.push_str("</table>\n");
    s
}

/// The table of `list` (`/{key}/i/…` in the JSON): name, kind, a predicted σ headed `sigma`
/// (— when unbounded) and the reason.
fn listed(r: &IdentifyReport, list: &[NotIdentifiable], key: &str, sigma: &str) -> String {
    let mut s = header_row(&["parameter", "kind", sigma, "reason"]);
    for (i, d) in list.iter().enumerate() {
        let angle = r
            .parameters
            .iter()
            .any(|p| p.name == d.name && p.unit == "rad");
        let sigma = d.predicted_sigma.map(|v| {
            if angle {
                format!("{} mrad", fmt_mrad(v))
            } else {
                format!("{} mm", fmt_mm(v))
            }
        });
        let _ = writeln!(
            s,
            "<tr><td>{}</td><td>{}</td>{}<td>{}</td></tr>",
            json_text(&format!("/{key}/{i}/name"), &d.name),
            json_text(&format!("/{key}/{i}/kind"), &d.kind),
            json_cell(
                &format!("/{key}/{i}/predicted_sigma"),
                d.predicted_sigma,
                &sigma.unwrap_or_default()
            ),
            json_text(&format!("/{key}/{i}/reason"), &d.reason),
        );
    }
    s
}

fn vec3(pointer: &str, v: &[f64; 3], decimals: usize) -> String {
    vec3_shown(pointer, v, |x| fixed(x, decimals))
}

/// The three values at `pointer`, each shown by `show` and tagged with its JSON value.
fn vec3_shown(pointer: &str, v: &[f64; 3], show: impl Fn(f64) -> String) -> String {
    let parts: Vec<String> = (0..3)
        .map(|k| json_shown(&format!("{pointer}/{k}"), v[k], &show(v[k])))
        .collect();
    format!("({})", parts.join(", "))
}

fn tool_and_base(r: &IdentifyReport) -> String {
    format!(
        "<h3>Base and tool after identification</h3>\n<table>\n\
         <tr><th>base translation (mm)</th><td class=\"num\">{}</td></tr>\n\
         <tr><th>base rotation vector (deg)</th><td class=\"num\">{}</td></tr>\n\
         <tr><th>tool: ball in the flange frame (mm)</th><td class=\"num\">{}</td></tr>\n</table>\n",
        vec3_shown("/base/translation_mm", &r.base.translation_mm, fmt_mm),
        vec3_shown("/base/rotation_vector_rad", &r.base.rotation_vector_rad, fmt_deg),
        vec3_shown("/tool/translation_mm", &r.tool.translation_mm, fmt_mm),
    )
}

fn not_identifiable(r: &IdentifyReport) -> String {
    let mut s = String::from("<h3>Not identifiable: held at nominal</h3>\n");
    if r.not_identifiable.is_empty() {
        s.push_str("<p>None: every candidate parameter was identified.</p>\n");
        return s;
    }
    s.push_str(
        "<p><i>structural</i>: no pose set can tell it from the others (the Jacobian's rank); \
         <i>dependent</i> / <i>poorly_determined</i>: these poses do not determine it within the \
         σ bound (predicted σ given).</p>\n<table>\n",
    );
    s.push_str(&listed(
        r,
        &r.not_identifiable,
        "not_identifiable",
        "predicted σ",
    ));
    s.push_str("</table>\n");
    s
}

/// Correlations this strong are listed by name.
const STRONG_CORRELATION: f64 = 0.9;

fn correlation(r: &IdentifyReport) -> String {
    let c = &r.correlation;
    let mut s = format!(
        "<p>Correlation of the identified parameters' estimates (σ̂₀²(JᵀJ)⁻¹ normalised); \
         condition number of the scaled Jacobian {}.</p>\n",
        json_num("/condition_number", r.condition_number, 1)
    );
    if c.names.is_empty() {
        s.push_str(&missing("No parameter was identified: no correlations."));
        return s;
    }
    s.push_str(&figure(
        plots::heat_map("correlation of the estimates", &c.names, &c.matrix),
        "correlation matrix: red +1, white 0, blue −1 (grey: undetermined)",
    ));
    let mut strong = Vec::new();
    for (i, row) in c.matrix.iter().enumerate() {
        for (j, rho) in row.iter().enumerate().skip(i + 1) {
            if rho.abs() >= STRONG_CORRELATION {
                strong.push((i, j, *rho));
            }
        }
    }
    strong.sort_by(|a, b| b.2.abs().total_cmp(&a.2.abs()));
    if strong.is_empty() {
        let _ = writeln!(
            s,
            "<p>No pair correlates at |ρ| ≥ {STRONG_CORRELATION}.</p>"
        );
        return s;
    }
    let _ = writeln!(s, "<h3>Pairs with |ρ| ≥ {STRONG_CORRELATION}</h3>\n<table>");
    s.push_str(&header_row(&["parameter", "parameter", "ρ"]));
    for (i, j, rho) in strong {
        let _ = writeln!(
            s,
            "<tr>{}{}{}</tr>",
            cell(&c.names[i]),
            cell(&c.names[j]),
            json_cell(
                &format!("/correlation/matrix/{i}/{j}"),
                Some(rho),
                &fixed(rho, 4)
            )
        );
    }
    s.push_str("</table>\n");
    s
}

fn significance(input: &ReportInput) -> String {
    let sig = &input.significance;
    if sig.is_empty() {
        return missing("Significance indices were not computed.");
    }
    let labels: Vec<String> = sig.iter().map(|x| x.name.clone()).collect();
    let mut s = format!(
        "<p>How much each MDH parameter moves the flange (paper §2.2, Fig. 3): the mean \
         projection of the pose error a perturbation causes (0.1 mm on lengths, 0.1 rad on \
         angles) over {} random joint configurations of the nominal model. ē_p is position \
         (mm); ē_n, ē_o, ē_a are the flange x, y, z axes (unit-vector change).</p>\n<div class=\"plots wide\">\n",
        SIGNIFICANCE_SAMPLES
    );
    let column = |get: fn(&Significance) -> f64| sig.iter().map(get).collect::<Vec<f64>>();
    let series = [
        ("ē_p: position", "mm", column(|x| x.e_p_mm)),
        ("ē_n: flange x axis", "", column(|x| x.e_n)),
        ("ē_o: flange y axis", "", column(|x| x.e_o)),
        ("ē_a: flange z axis", "", column(|x| x.e_a)),
    ];
    for (title, unit, values) in series {
        s.push_str(&figure(plots::bars(title, unit, &labels, &values), title));
    }
    s.push_str("</div>\n");
    s
}

fn stage_axis(r: &IdentifyReport) -> String {
    let mut s = format!(
        "<table>\n<tr><th>stage axis in use (flange frame)</th><td class=\"num\">{}</td></tr>\n",
        vec3("/stage_axis", &r.stage_axis, 5)
    );
    if let (Some(m), Some(a)) = (&r.stage_axis_measured, r.stage_axis_angle_rad) {
        let _ = write!(
            s,
            "<tr><th>mean measured P2 − P1 direction (flange frame)</th><td class=\"num\">{}</td></tr>\n\
             <tr><th>angle between them</th><td class=\"num\">{}</td></tr>\n",
            vec3("/stage_axis_measured", m, 5),
            json_shown("/stage_axis_angle_rad", a, &format!("{} mrad", fmt_mrad(a)))
        );
    }
    s.push_str("</table>\n");
    s
}

fn setup(input: &ReportInput) -> String {
    let mut s = String::from("<h3>Stage axis</h3>\n");
    s.push_str(&stage_axis(&input.result));
    let Some(c) = &input.campaign else {
        s.push_str(&missing(
            "The data did not come from a campaign store: the tool-frame and base-registration \
             results of the cell setup are not known here.",
        ));
        return s;
    };
    match &c.setup {
        None => s.push_str(&missing(
            "The campaign stored no setup result (the setup was not configured, or has not run).",
        )),
        Some(setup) => {
            match &setup.tool_frame {
                Some(t) => s.push_str(&tool_frame(t)),
                None => s.push_str(&missing("The tool-frame procedure was not run.")),
            }
            match &setup.base {
                Some(b) => s.push_str(&base_registration(b)),
                None => s.push_str(&missing("The base registration was not run.")),
            }
        }
    }
    s
}

fn plain3(v: &[f64; 3], decimals: usize) -> String {
    format!(
        "({}, {}, {})",
        fixed(v[0], decimals),
        fixed(v[1], decimals),
        fixed(v[2], decimals)
    )
}

fn kv_table(rows: &[(&str, String)]) -> String {
    let mut s = String::from("<table>\n");
    for (k, v) in rows {
        let _ = writeln!(
            s,
            "<tr><th>{}</th><td class=\"num\">{}</td></tr>",
            esc(k),
            esc(v)
        );
    }
    s.push_str("</table>\n");
    s
}

fn tool_frame(t: &ToolFrameResult) -> String {
    let mut s = String::from(
        "<h3>Tool frame (docs/method.md §4: jogs along flange x and y, sphere fit of rotations)</h3>\n",
    );
    s.push_str(&kv_table(&[
        ("ball in the flange frame (mm)", fmt_mm3(&t.tool_mm)),
        ("stage axis (flange frame)", plain3(&t.stage_axis, 5)),
        ("sphere radius = |tool| (mm)", fmt_mm(t.sphere_radius_mm)),
        ("sphere fit rms (mm)", fmt_mm(t.sphere_rms_mm)),
        (
            "angle between the jog axes (deg)",
            fixed(t.jog_axes_angle_deg, 3),
        ),
        (
            "measured stage travel (mm)",
            fmt_mm(t.stage_travel_measured_mm),
        ),
        (
            "flange origin, tracker frame (mm)",
            fmt_mm3(&t.flange_origin_tracker_mm),
        ),
        ("targets measured", t.targets.to_string()),
    ]));
    s
}

fn base_registration(b: &BaseResult) -> String {
    let mut s = String::from("<h3>Base registration (tracker ← robot base, nominal model)</h3>\n");
    s.push_str(&kv_table(&[
        ("translation (mm)", fmt_mm3(&b.translation_mm)),
        (
            "rotation vector (deg)",
            format!(
                "({}, {}, {})",
                fmt_deg(b.rotation_vector_rad[0]),
                fmt_deg(b.rotation_vector_rad[1]),
                fmt_deg(b.rotation_vector_rad[2])
            ),
        ),
        ("residual rms (mm)", fmt_mm(b.rms_mm)),
        ("residual max (mm)", fmt_mm(b.max_mm)),
        (
            "tracker position in the base frame (mm)",
            fmt_mm3(&b.tracker_in_base_mm),
        ),
        ("poses used", b.poses.to_string()),
    ]));
    s
}

fn no_store() -> String {
    missing("The data did not come from a campaign store: no journal to report from.")
}

fn drift(c: Option<&CampaignFacts>, tz: &TimeZone) -> String {
    let Some(c) = c else {
        return no_store();
    };
    let mut s = String::new();
    if c.drift.is_empty() {
        s.push_str(&missing("The journal holds no drift check."));
    } else {
        let worst = c.drift.iter().map(|d| d.drift_mm).fold(0.0, f64::max);
        let over = c.drift.iter().filter(|d| d.drift_mm > d.max_mm).count();
        let _ = writeln!(
            s,
            "<p>{} drift checks at the reference pose; largest {} mm; {} over the threshold.</p>\n<table>",
            c.drift.len(),
            fmt_mm(worst),
            over
        );
        s.push_str(&header_row(&[
            "#",
            "time",
            "drift (mm)",
            "threshold (mm)",
            "result",
        ]));
        for (i, d) in c.drift.iter().enumerate() {
            let _ = writeln!(
                s,
                "<tr>{}{}{}{}{}</tr>",
                num_cell(&(i + 1).to_string()),
                cell(&fmt_time_in(d.at_ms, tz)),
                num_cell(&fmt_mm(d.drift_mm)),
                num_cell(&fmt_mm(d.max_mm)),
                cell(if d.drift_mm > d.max_mm { "over" } else { "ok" })
            );
        }
        s.push_str("</table>\n");
    }
    s.push_str("<h3>Device faults</h3>\n");
    if c.faults.is_empty() {
        s.push_str("<p>None journalled.</p>\n");
        return s;
    }
    s.push_str("<table>\n");
    s.push_str(&header_row(&[
        "time", "device", "kind", "action", "message",
    ]));
    for f in &c.faults {
        let _ = writeln!(
            s,
            "<tr>{}{}{}{}{}</tr>",
            cell(&fmt_time_in(f.at_ms, tz)),
            cell(&f.device),
            cell(&f.kind),
            cell(&f.action),
            cell(&f.message)
        );
    }
    s.push_str("</table>\n");
    s
}

fn devices(c: Option<&CampaignFacts>) -> String {
    let Some(c) = c else {
        return missing(
            "The data did not come from a campaign store: which devices measured it is not known here.",
        );
    };
    let mut s = String::from("<table>\n");
    s.push_str(&header_row(&["device", "configured as", "identity"]));
    for d in &c.devices {
        let _ = writeln!(
            s,
            "<tr>{}{}{}</tr>",
            cell(&d.device),
            cell(&d.configured),
            cell(
                d.identity
                    .as_deref()
                    .unwrap_or("unknown: not recorded by this campaign")
            )
        );
    }
    s.push_str("</table>\n");
    s
}

fn provenance(input: &ReportInput) -> String {
    let p = &input.provenance;
    let r = &input.result;
    let time = |ms: i64| fmt_time_in(ms, &p.time_zone);
    let mut rows: Vec<(&str, String)> = vec![
        ("software", format!("cellcal {}", p.software_version)),
        (
            "git commit",
            p.git_hash
                .clone()
                .unwrap_or_else(|| "unknown (not built from a git checkout)".into()),
        ),
        ("report generated", time(p.generated_at_ms)),
        ("data", input.source.clone()),
    ];
    if let Some(c) = &input.campaign {
        rows.push((
            "campaign",
            format!("{} \"{}\" (state {})", c.id, c.name, c.state),
        ));
        rows.push(("campaign created", time(c.created_at_ms)));
        if let Some((a, b)) = c.journal_span_ms {
            rows.push((
                "journal",
                format!("{} entries, {} … {}", c.journal_entries, time(a), time(b)),
            ));
        }
        rows.push((
            "poses measured / planned",
            format!("{} / {}", c.poses_done, c.poses_total),
        ));
        rows.push(("plan seed", c.seed.to_string()));
        if let Some(t) = &c.time {
            for (what, text) in campaign_time_rows(t) {
                let label = match what {
                    "planned" => "campaign time planned",
                    "measuring" => "campaign time measuring (pauses excluded)",
                    _ => "campaign time paused",
                };
                rows.push((label, text));
            }
        }
    }
    let mut s = kv_table(&rows);
    s.push_str("<h3>Inputs</h3>\n");
    if p.inputs.is_empty() {
        s.push_str(&missing("No input digests were recorded."));
    } else {
        s.push_str("<table>\n");
        s.push_str(&header_row(&["input", "name", "SHA-256"]));
        for i in &p.inputs {
            let _ = writeln!(
                s,
                "<tr>{}{}<td class=\"mono\">{}</td></tr>",
                cell(&i.what),
                cell(&i.name),
                esc(&i.sha256)
            );
        }
        s.push_str("</table>\n");
    }
    s.push_str("<h3>Identification</h3>\n");
    s.push_str(&solver_table(r));
    s
}

fn solver_table(r: &IdentifyReport) -> String {
    let rejected = if r.rejected_poses.is_empty() {
        "none".to_owned()
    } else {
        r.rejected_poses.join(", ")
    };
    format!(
        "<table>\n<tr><th>observation model</th><td>{}</td></tr>\n\
         <tr><th>direction weight (mm)</th><td class=\"num\">{}</td></tr>\n\
         <tr><th>solver</th><td>{} iterations, {}, final cost {} mm²</td></tr>\n\
         <tr><th>converged</th><td>{}</td></tr>\n\
         <tr><th>poses rejected as outliers</th><td>{}</td></tr>\n</table>\n",
        json_text("/model", &r.model),
        json_num("/direction_weight_mm", r.direction_weight_mm, 3),
        json_shown(
            "/solver/iterations",
            r.solver.iterations as f64,
            &r.solver.iterations.to_string()
        ),
        json_text("/solver/termination", &r.solver.termination),
        json_shown(
            "/solver/final_cost",
            r.solver.final_cost,
            &fmt_sig(r.solver.final_cost, 4)
        ),
        if r.solver.converged { "yes" } else { "NO" },
        esc(&rejected),
    )
}
