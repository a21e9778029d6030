//! The printed summary of an identification: the verdict and its warnings first, then the
//! parameter-error table (like the paper's Tables 3–5) and the before/after accuracy table.

use std::fmt::Write;

use crate::analysis::metrics::Metrics;
use crate::calibrate::{IdentifyReport, ParamStatus, Quality};
use crate::identify::DropKind;

fn cell(r: &IdentifyReport, name: &str) -> String {
    match r.parameters.iter().find(|p| p.name == name) {
        Some(p) if p.status == ParamStatus::SetupRelative => format!("{:+.6e}*", p.error),
        Some(p) if p.identified => format!("{:+.6e}", p.error),
        Some(_) => "—".to_owned(),
        None => String::new(),
    }
}

fn metric_line(out: &mut String, set: &str, state: &str, m: &Metrics) {
    let att = |v: Option<f64>| v.map_or("—".to_owned(), |x| format!("{x:.6}"));
    let _ = writeln!(
        out,
        "{set:<7} {state:<7} {:>5} {:>10.4} {:>10.4} {:>10.4} {:>10.4}  {:>7.4}/{:>7.4}/{:>7.4} {:>12} {:>12}",
        m.poses,
        m.position_mean_mm,
        m.position_max_mm,
        m.position_rms_mm,
        m.position_p95_mm,
        m.position_axial_mean_mm[0],
        m.position_axial_mean_mm[1],
        m.position_axial_mean_mm[2],
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
                    .map(|s| format!(" (σ {s:.2e} {} given the setup)", p.unit))
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

/// Human summary of an identify report.
pub fn summary_text(r: &IdentifyReport) -> String {
    let mut out = String::new();
    verdict_lines(&mut out, r);
    let _ = writeln!(
        out,
        "model {}: {} parameters identified, condition number {:.1}, σ0 = {:.4} mm",
        r.model,
        r.identified.len(),
        r.condition_number,
        r.sigma0_mm
    );
    let _ = writeln!(
        out,
        "solver: {} iterations, {} ({}), final cost {:.6e} mm²",
        r.solver.iterations,
        if r.solver.converged {
            "converged"
        } else {
            "NOT converged"
        },
        r.solver.termination,
        r.solver.final_cost
    );
    let _ = writeln!(
        out,
        "\nParameter errors (identified − nominal; — = not identifiable; * = relative to the setup)"
    );
    let _ = writeln!(
        out,
        "{:<5} {:>14} {:>14} {:>14} {:>14} {:>14}",
        "joint", "Δθ (rad)", "Δd (mm)", "Δa (mm)", "Δα (rad)", "Δβ (rad)"
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
            "{:<5} {:>14} {:>14} {:>14} {:>14} {:>14}",
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
            "{:<12} {:+.6e} {} (± {:.2e})",
            p.name,
            p.error,
            p.unit,
            p.std.unwrap_or(f64::NAN)
        );
    }
    setup_relative_lines(&mut out, r);
    not_identified_lines(&mut out, r);
    if let (Some(m), Some(a)) = (r.stage_axis_measured, r.stage_axis_angle_rad) {
        let _ = writeln!(
            out,
            "stage axis in use ({:.4}, {:.4}, {:.4}); measured P2 − P1 in the flange frame ({:.4}, {:.4}, {:.4}), {:.2}° apart",
            r.stage_axis[0], r.stage_axis[1], r.stage_axis[2], m[0], m[1], m[2], a.to_degrees()
        );
    }
    if !r.rejected_poses.is_empty() {
        let _ = writeln!(
            out,
            "\nRejected as outliers (--robust): {}",
            r.rejected_poses.join(", ")
        );
    }
    let _ = writeln!(out, "\nAccuracy (position mm, attitude rad)");
    before_line(&mut out, r);
    let _ = writeln!(
        out,
        "{:<7} {:<7} {:>5} {:>10} {:>10} {:>10} {:>10}  {:>23} {:>12} {:>12}",
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
    out
}
