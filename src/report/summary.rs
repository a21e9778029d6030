//! The printed summary of an identification: the verdict and its warnings first, then the
//! parameter-error table (like the paper's Tables 3–5) and the before/after accuracy table.

use std::fmt::Write;
use std::time::Duration;

use crate::analysis::metrics::Metrics;
use crate::calibrate::identify_json::ParameterJson;
use crate::calibrate::KeptModel;
use crate::calibrate::{CampaignTime, IdentifyReport, ParamStatus, Quality, SetupResult};
use crate::identify::DropKind;
use crate::report::extended::{change_percent, term_value_sigma, Extended};
use crate::units::human::{
    fmt_deg, fmt_duration, fmt_fixed, fmt_mm, fmt_mm3, fmt_mrad, fmt_sig, NO_NUMBER,
};

/// A parameter's value in its unit for people: mm, or mrad for an angle error.
fn shown(p: &ParameterJson, v: f64) -> String {
    if p.unit == "rad" {
        fmt_mrad(v)
    } else {
        fmt_mm(v)
    }
}

/// The unit [`shown`] writes for `p`.
fn shown_unit(p: &ParameterJson) -> &'static str {
    if p.unit == "rad" {
        "mrad"
    } else {
        "mm"
    }
}

/// `value ± σ` of a parameter (`*` when relative to the setup), or why it has none: `not
/// identifiable` (structural), `held` (not determined by these poses, held at nominal).
fn value_sigma(r: &IdentifyReport, p: &ParameterJson) -> String {
    if !p.identified {
        let structural = r
            .not_identifiable
            .iter()
            .any(|d| d.name == p.name && d.kind == DropKind::Structural.name());
        return if structural {
            "not identifiable"
        } else {
            "held"
        }
        .to_owned();
    }
    let sigma = p.std.map_or_else(|| NO_NUMBER.to_owned(), |s| shown(p, s));
    let mark = if p.status == ParamStatus::SetupRelative {
        "*"
    } else {
        ""
    };
    format!("{} ± {sigma}{mark}", shown(p, p.error))
}

fn cell(r: &IdentifyReport, name: &str) -> String {
    r.parameters
        .iter()
        .find(|p| p.name == name)
        .map_or_else(String::new, |p| {
            // the `*` of a value relative to the setup stands in its own column
            let v = value_sigma(r, p);
            if v.ends_with('*') {
                v
            } else {
                v + " "
            }
        })
}

fn metric_line(out: &mut String, set: &str, state: &str, m: &Metrics) {
    let att = |v: Option<f64>| v.map_or_else(|| NO_NUMBER.to_owned(), fmt_mrad);
    let _ = writeln!(
        out,
        "{set:<7} {state:<7} {:>5} {:>9} {:>9} {:>9} {:>9}  {:>23} {:>9} {:>9}",
        m.poses,
        fmt_mm(m.position_mean_mm),
        fmt_mm(m.position_max_mm),
        fmt_mm(m.position_rms_mm),
        fmt_mm(m.position_p95_mm),
        format!(
            "{}/{}/{}",
            fmt_mm(m.position_axial_mean_mm[0]),
            fmt_mm(m.position_axial_mean_mm[1]),
            fmt_mm(m.position_axial_mean_mm[2])
        ),
        att(m.attitude_mean_rad),
        att(m.attitude_max_rad),
    );
}

/// The verdict line and one line per warning.
fn verdict_lines(out: &mut String, r: &IdentifyReport) {
    let what = match r.quality {
        Quality::Ok => "ok",
        Quality::Warning => "WARNING (usable; read the warnings)",
        Quality::Poor => "POOR (do not load these parameters; see why below)",
    };
    let _ = writeln!(out, "quality: {what}");
    for w in &r.warnings {
        let _ = writeln!(
            out,
            "  {:<7} {}: {}",
            w.severity.as_str(),
            w.code,
            w.message
        );
    }
}

/// The parameters held at nominal: structurally not identifiable, then those these poses do not
/// determine (with their predicted σ in the reason).
fn not_identified_lines(out: &mut String, r: &IdentifyReport) {
    let (structural, practical): (Vec<_>, Vec<_>) = r
        .not_identifiable
        .iter()
        .partition(|d| d.kind == DropKind::Structural.name());
    for (title, list) in [
        ("Not identifiable", structural),
        ("Held at nominal: not determined by these poses", practical),
    ] {
        if list.is_empty() {
            continue;
        }
        let _ = writeln!(out, "\n{title}:");
        for d in list {
            let _ = writeln!(out, "  {:<10} {}", d.name, d.reason);
        }
    }
}

/// The identified parameters relative to the setup (the `*` of the table), with why.
fn setup_relative_lines(out: &mut String, r: &IdentifyReport) {
    if r.setup_relative.is_empty() {
        return;
    }
    let _ = writeln!(
        out,
        "\n* Relative to the setup: identified given the quantities the setup fixed (named in \
         each line); were those free they would take these parameters over, so their values \
         and σ hold only given the setup, not as the robot's own geometry:"
    );
    for d in &r.setup_relative {
        let std = r
            .parameters
            .iter()
            .find(|p| p.name == d.name)
            .and_then(|p| {
                p.std
                    .map(|s| format!(" (σ {} {} given the setup)", shown(p, s), shown_unit(p)))
            })
            .unwrap_or_default();
        let _ = writeln!(out, "  {:<10} {}{std}", d.name, d.reason);
    }
}

/// The base of the "before" rows, when the result names it.
fn before_line(out: &mut String, r: &IdentifyReport) {
    if let Some(b) = r.before_base {
        let _ = writeln!(
            out,
            "before = the nominal model with the tool in use and {} (before_base: {})",
            b.describe(),
            b.name()
        );
    }
}

/// The non-geometric terms (§10): families, each term's value ± σ or why it is held, the torque
/// model's inputs; nothing for a geometric identification.
fn terms_lines(out: &mut String, x: &Extended) {
    let families: Vec<&str> = x.families.iter().map(|f| f.name()).collect();
    let _ = writeln!(
        out,
        "\nNon-geometric terms ({}; docs/method.md §10): compliance µrad/(N·m), harmonics mrad; \
         handed over: the {} model",
        families.join(", "),
        match x.kept {
            KeptModel::Extended => "extended (geometric + terms)",
            KeptModel::Geometric => "geometric (the terms did not verify better)",
        }
    );
    for t in x.terms {
        let status = match (&t.reason, t.status) {
            (Some(r), ParamStatus::NotIdentified) => format!("held at zero: {r}"),
            (_, st) => st.name().to_owned(),
        };
        let _ = writeln!(
            out,
            "  {:<12} joint {:<2} {:<10} {:>32}  {status}",
            t.name,
            t.joint,
            t.kind,
            term_value_sigma(t),
        );
    }
    if let Some(g) = x.gravity {
        let masses: Vec<String> = x
            .masses
            .iter()
            .map(|m| {
                format!(
                    "frame {} at {} mm {} kg",
                    m.frame,
                    fmt_mm3(&m.at_mm),
                    fmt_fixed(m.kg, 3)
                )
            })
            .collect();
        let _ = writeln!(
            out,
            "torque model: gravity ({}, {}, {}) in the robot base frame; {}; on the nominal chain",
            fmt_fixed(g[0], 4),
            fmt_fixed(g[1], 4),
            fmt_fixed(g[2], 4),
            if masses.is_empty() {
                "no masses".to_owned()
            } else {
                format!("masses: {}", masses.join("; "))
            }
        );
    }
}

/// Before / geometric / extended mean, rms and max position error per set (§10).
fn comparison_lines(out: &mut String, x: &Extended) {
    let _ = writeln!(
        out,
        "\nBefore / geometric / extended (position mm; change = extended vs geometric)"
    );
    let _ = writeln!(
        out,
        "{:<7} {:<10} {:>9} {:>9} {:>9} {:>8}",
        "set", "model", "mean", "rms", "max", "change"
    );
    let columns = x.columns();
    for set in ["ident", "verify"] {
        let Some(geometric) = columns[1].of(set) else {
            continue;
        };
        for c in &columns {
            let Some(m) = c.of(set) else { continue };
            let change = (c.label == "extended")
                .then(|| change_percent(geometric.position_mean_mm, m.position_mean_mm))
                .flatten()
                .map_or_else(String::new, |p| format!("{} %", fmt_fixed(p, 1)));
            let _ = writeln!(
                out,
                "{set:<7} {:<10} {:>9} {:>9} {:>9} {change:>8}",
                c.label,
                fmt_mm(m.position_mean_mm),
                fmt_mm(m.position_rms_mm),
                fmt_mm(m.position_max_mm),
            );
        }
    }
}

/// The summary's non-geometric blocks alone, for the report's tests.
#[cfg(test)]
pub(crate) mod tests_support {
    /// The terms block and the comparison of `x`.
    pub fn extended_lines(out: &mut String, x: &super::Extended) {
        super::terms_lines(out, x);
        super::comparison_lines(out, x);
    }
}

/// Human summary of an identify report.
pub fn summary_text(r: &IdentifyReport) -> String {
    let mut out = String::new();
    verdict_lines(&mut out, r);
    let _ = writeln!(
        out,
        "model {}: {} parameters identified, condition number {:.1}, σ0 = {} mm",
        r.model,
        r.identified.len(),
        r.condition_number,
        fmt_mm(r.sigma0_mm)
    );
    let _ = writeln!(
        out,
        "solver: {} iterations, {} ({}), final cost {} mm²",
        r.solver.iterations,
        if r.solver.converged {
            "converged"
        } else {
            "NOT converged"
        },
        r.solver.termination,
        fmt_sig(r.solver.final_cost, 4)
    );
    let _ = writeln!(
        out,
        "\nParameter errors: identified − nominal ± σ (lengths mm, angles mrad; held = not \
         determined by these poses, kept at nominal; * = relative to the setup)"
    );
    let _ = writeln!(
        out,
        "{:<5} {:>19} {:>19} {:>19} {:>19} {:>19}",
        "joint", "Δθ (mrad)", "Δd (mm)", "Δa (mm)", "Δα (mrad)", "Δβ (mrad)"
    );
    let dof = r
        .parameters
        .iter()
        .filter_map(|p| p.joint)
        .max()
        .unwrap_or(0);
    for j in 1..=dof {
        let _ = writeln!(
            out,
            "{:<5} {:>19} {:>19} {:>19} {:>19} {:>19}",
            j,
            cell(r, &format!("theta{j}")),
            cell(r, &format!("d{j}")),
            cell(r, &format!("a{j}")),
            cell(r, &format!("alpha{j}")),
            cell(r, &format!("beta{j}")),
        );
    }
    for p in r
        .parameters
        .iter()
        .filter(|p| p.joint.is_none() && p.identified)
    {
        let _ = writeln!(
            out,
            "{:<12} {} {}",
            p.name,
            value_sigma(r, p),
            shown_unit(p)
        );
    }
    setup_relative_lines(&mut out, r);
    not_identified_lines(&mut out, r);
    let extended = Extended::of(r);
    if let Some(x) = &extended {
        terms_lines(&mut out, x);
    }
    if let (Some(m), Some(a)) = (r.stage_axis_measured, r.stage_axis_angle_rad) {
        let _ = writeln!(
            out,
            "stage axis in use ({:.4}, {:.4}, {:.4}); measured P2 − P1 in the flange frame ({:.4}, {:.4}, {:.4}), {}° apart",
            r.stage_axis[0], r.stage_axis[1], r.stage_axis[2], m[0], m[1], m[2], fmt_deg(a)
        );
    }
    if !r.rejected_poses.is_empty() {
        let _ = writeln!(
            out,
            "\nRejected as outliers (--robust): {}",
            r.rejected_poses.join(", ")
        );
    }
    let _ = writeln!(out, "\nAccuracy (position mm, attitude mrad)");
    before_line(&mut out, r);
    let _ = writeln!(
        out,
        "{:<7} {:<7} {:>5} {:>9} {:>9} {:>9} {:>9}  {:>23} {:>9} {:>9}",
        "set",
        "state",
        "poses",
        "mean",
        "max",
        "rms",
        "p95",
        "axial mean x/y/z",
        "att mean",
        "att max"
    );
    metric_line(&mut out, "ident", "before", &r.metrics.ident.before);
    metric_line(&mut out, "ident", "after", &r.metrics.ident.after);
    if let Some(v) = &r.metrics.verify {
        metric_line(&mut out, "verify", "before", &v.before);
        metric_line(&mut out, "verify", "after", &v.after);
    }
    if let Some(x) = &extended {
        comparison_lines(&mut out, x);
    }
    out
}

/// The cell setup's result for people: the tool frame (ball in the flange, stage axis, sphere
/// fit) and the base registration, one line each (`run` prints them when the setup ends).
pub fn setup_summary_lines(r: &SetupResult) -> Vec<String> {
    let mut lines = Vec::new();
    if let Some(t) = &r.tool_frame {
        lines.push(format!(
            "tool frame: ball {} mm in the flange, stage axis ({:.4}, {:.4}, {:.4}), sphere fit RMS {} mm",
            fmt_mm3(&t.tool_mm),
            t.stage_axis[0],
            t.stage_axis[1],
            t.stage_axis[2],
            fmt_mm(t.sphere_rms_mm)
        ));
    }
    if let Some(b) = &r.base {
        lines.push(format!(
            "base registration: RMS {} mm over {} poses, tracker at {} mm in the robot base frame",
            fmt_mm(b.rms_mm),
            b.poses,
            fmt_mm3(&b.tracker_in_base_mm)
        ));
    }
    lines
}

/// Planned against actual time of a campaign, one `(what, text)` row each for people:
/// `planned` (the estimate's summary), `measuring` (with its ratio to the plan), `paused`.
pub fn campaign_time_rows(t: &CampaignTime) -> [(&'static str, String); 3] {
    let duration = |s: f64| fmt_duration(Duration::from_secs_f64(s.max(0.0)));
    let planned = match (&t.planned_summary, t.planned_s) {
        (Some(summary), Some(s)) => format!("{summary} ({})", duration(s)),
        _ => "not estimated (the campaign was created without an estimate)".to_owned(),
    };
    let measuring = match t.ratio {
        Some(r) => format!(
            "{} ({} × planned)",
            duration(t.measuring_s),
            fmt_fixed(r, 2)
        ),
        None => duration(t.measuring_s),
    };
    [
        ("planned", planned),
        ("measuring", measuring),
        ("paused", duration(t.paused_s)),
    ]
}

/// The campaign time block of `cellcal run`'s summary ([`campaign_time_rows`]).
pub fn campaign_time_text(t: &CampaignTime) -> String {
    let mut s = String::from("Campaign time (measuring excludes pauses):\n");
    for (what, text) in campaign_time_rows(t) {
        let _ = writeln!(s, "  {what:<10} {text}");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::{BaseResult, ToolFrameResult};

    #[test]
    fn the_setup_summary_shows_millimetres_with_three_decimals() {
        let r = SetupResult {
            tool_frame: Some(ToolFrameResult {
                tool_mm: [0.3195619813344486, -0.0000001, 95.49951],
                stage_axis: [0.0, 1.0, 0.0],
                flange_origin_tracker_mm: [0.0; 3],
                flange_axes_tracker: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                sphere_radius_mm: 95.5,
                sphere_rms_mm: 0.00123,
                jog_axes_angle_deg: 90.0,
                stage_travel_measured_mm: 10.0,
                targets: 12,
            }),
            base: Some(BaseResult {
                translation_mm: [1.0, 2.0, 3.0],
                rotation_vector_rad: [0.0; 3],
                rms_mm: 0.0214,
                max_mm: 0.05,
                tracker_in_base_mm: [2500.04, -12.0, 300.0],
                poses: 8,
            }),
        };
        let lines = setup_summary_lines(&r);
        assert_eq!(
            lines,
            [
                "tool frame: ball (0.320, 0.000, 95.500) mm in the flange, stage axis (0.0000, \
                 1.0000, 0.0000), sphere fit RMS 0.001 mm",
                "base registration: RMS 0.021 mm over 8 poses, tracker at (2500.040, -12.000, \
                 300.000) mm in the robot base frame",
            ]
        );
    }
}
