use super::*;
use crate::analysis::significance::significance;
use crate::calibrate::calibrate;
use crate::dataset::Observation;
use crate::identify::Identification;
use crate::identify::{IdentifyOptions, ObsConfig, ObsModel};
use crate::model::tx60;
use crate::simulate::{simulate, truth, SimConfig};

/// A small simulated OP identification: its rows, result and identification.
fn small_op() -> (Vec<Observation>, IdentifyReport, Identification) {
    let nominal = tx60();
    let truth = truth::apply_errors(&nominal, &truth::paper_errors()).expect("paper errors");
    let cfg = SimConfig {
        poses: 90,
        ident: 50,
        ..SimConfig::default()
    };
    let rows = simulate(&nominal, &truth, &cfg)
        .expect("sampled")
        .observations;
    let opts = IdentifyOptions::new(ObsConfig::new(ObsModel::Op, 10.0));
    let (report, id) = calibrate(&nominal, &rows, &opts, 10.0).expect("identified");
    (rows, report, id)
}

fn input(rows: &[Observation], report: IdentifyReport, id: &Identification) -> ReportInput {
    ReportInput {
        title: "t".into(),
        source: "s".into(),
        result: report,
        poses: PoseErrors::compute(id, rows, 10.0).map_err(|e| e.to_string()),
        significance: significance(&tx60(), SIGNIFICANCE_SAMPLES, SIGNIFICANCE_SEED),
        campaign: None,
        provenance: Provenance::of_this_build(0, Vec::new()),
        notes: Vec::new(),
    }
}

fn mean_norm(e: &[PoseError]) -> f64 {
    e.iter().map(PoseError::norm_mm).sum::<f64>() / e.len() as f64
}

#[test]
fn per_pose_errors_are_the_ones_behind_the_metrics() {
    let (rows, report, id) = small_op();
    let p = PoseErrors::compute(&id, &rows, 10.0).expect("errors");
    let v = p.verify.as_ref().expect("verify set");
    assert_eq!((p.ident.ids.len(), v.ids.len()), (50, 40));
    let m = &report.metrics;
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * b.abs().max(1.0);
    assert!(close(
        mean_norm(&p.ident.before),
        m.ident.before.position_mean_mm
    ));
    assert!(close(
        mean_norm(&p.ident.after),
        m.ident.after.position_mean_mm
    ));
    let verify = m.verify.as_ref().expect("verify metrics");
    assert!(close(mean_norm(&v.before), verify.before.position_mean_mm));
    assert!(close(mean_norm(&v.after), verify.after.position_mean_mm));
    assert!(
        v.after.iter().all(|e| e.attitude_rad.is_some()),
        "OP measures the stage axis"
    );
}

#[test]
fn every_text_from_the_input_is_escaped() {
    let (rows, mut report, id) = small_op();
    report.warnings.push(crate::calibrate::QualityWarning {
        code: "x<y".into(),
        severity: crate::calibrate::Quality::Warning,
        message: "<script>alert(1)</script> & \"quoted\"".into(),
    });
    let mut inp = input(&rows, report, &id);
    inp.title = "<b>bold</b>".into();
    inp.notes.push("<img src=x onerror=alert(1)>".into());
    let html = render(&inp);
    assert!(!html.contains("<script>"), "a script tag got through");
    assert!(!html.contains("<img"), "an img tag got through");
    assert!(!html.contains("<b>bold</b>"));
    assert!(html.contains("&lt;script&gt;alert(1)&lt;/script&gt; &amp; &quot;quoted&quot;"));
    assert!(html.contains(
        "<code><span data-json=\"/warnings/0/code\" data-value=\"x&lt;y\">x&lt;y</span></code>"
    ));
}

#[test]
fn without_a_store_the_campaign_sections_say_so() {
    let (rows, report, id) = small_op();
    let html = render(&input(&rows, report, &id));
    for what in [
        "not come from a campaign store: the tool-frame",
        "not come from a campaign store: no journal",
        "not come from a campaign store: which devices",
    ] {
        assert!(html.contains(what), "missing: {what}");
    }
    assert!(!html.contains("plot not drawn"), "a plot failed");
    // 4 per-pose + 2 histograms per set, attitude per set, heat map, 4 significance charts
    assert_eq!(html.matches("<svg").count(), 2 * 4 + 2 * 2 + 2 + 1 + 4);
}

#[test]
fn missing_per_pose_errors_are_reported_with_the_reason() {
    let (rows, report, id) = small_op();
    let mut inp = input(&rows, report, &id);
    inp.poses = Err("the robot file no longer parses".into());
    let html = render(&inp);
    assert!(html.contains("Per-pose errors are not available: the robot file no longer parses."));
    // the heat map and the significance charts remain
    assert_eq!(html.matches("<svg").count(), 1 + 4);
}

/// The text the page shows for the JSON value at `pointer` (the first element tagged with it).
fn shown_at(html: &str, pointer: &str) -> String {
    let tag = format!("data-json=\"{pointer}\" data-value=\"");
    let at = html
        .find(&tag)
        .unwrap_or_else(|| panic!("{pointer} not in the page"));
    let rest = &html[at..];
    let start = rest.find('>').expect("element") + 1;
    let end = rest[start..].find('<').expect("closed") + start;
    rest[start..end].to_owned()
}

#[test]
fn the_parameter_table_shows_mm_mrad_and_degrees_with_three_decimals_and_sigma_beside() {
    use crate::units::human::{fmt_deg, fmt_mm, fmt_mrad};
    let (rows, report, id) = small_op();
    let html = render(&input(&rows, report.clone(), &id));
    let mut angles = 0;
    for (i, p) in report.parameters.iter().enumerate() {
        let nominal = shown_at(&html, &format!("/parameters/{i}/nominal"));
        let error = shown_at(&html, &format!("/parameters/{i}/error"));
        let (want_nominal, want_error) = match p.unit.as_str() {
            "rad" => {
                angles += 1;
                (
                    format!("{}°", fmt_deg(p.nominal)),
                    format!("{} mrad", fmt_mrad(p.error)),
                )
            }
            "mm" => (
                format!("{} mm", fmt_mm(p.nominal)),
                format!("{} mm", fmt_mm(p.error)),
            ),
            u => panic!("{}: unit {u}", p.name),
        };
        assert_eq!(nominal, want_nominal, "{}", p.name);
        assert_eq!(error, want_error, "{}", p.name);
        let decimals = |t: &str| {
            let number = t
                .split([' ', '°'])
                .find(|w| w.contains('.'))
                .expect("a number");
            number.split('.').nth(1).map(str::len)
        };
        assert_eq!(decimals(&nominal), Some(3), "{nominal}");
        assert_eq!(decimals(&error), Some(3), "{error}");
        if let Some(s) = p.std {
            let sigma = shown_at(&html, &format!("/parameters/{i}/std"));
            let unit = if p.unit == "rad" { "mrad" } else { "mm" };
            let value = if p.unit == "rad" {
                fmt_mrad(s)
            } else {
                fmt_mm(s)
            };
            assert!(
                sigma.starts_with(&format!("± {value} {unit}")),
                "{}: σ `{sigma}`",
                p.name
            );
        }
    }
    assert!(angles > 0, "the fixture has angles");
    // the table's header: σ beside the error
    assert!(
        html.contains("<th>error</th><th>± σ</th>"),
        "σ column beside the error"
    );
    // no e-notation in any table of the page (the SVG plots aside)
    let tables: String = html
        .split("<table>")
        .skip(1)
        .map(|t| t.split("</table>").next().unwrap_or(""))
        .collect();
    // a number token in e-notation (a build's git hash, hex, is not a number even when it
    // holds digits around an `e`)
    for token in tables.split(|c: char| !(c.is_ascii_alphanumeric() || "._+-".contains(c))) {
        let hex_id = token.len() >= 7 && token.chars().all(|c| c.is_ascii_hexdigit());
        assert!(
            hex_id || !(token.contains(['e', 'E']) && token.parse::<f64>().is_ok()),
            "e-notation: `{token}`"
        );
    }
}

/// Every `(data-json, data-value)` pair of a page fragment (values unescaped).
fn tagged(html: &str) -> Vec<(String, String)> {
    let doc = scraper::Html::parse_fragment(html);
    let sel = scraper::Selector::parse("[data-json]").expect("selector");
    doc.select(&sel)
        .map(|e| {
            let a = |k| e.value().attr(k).expect("attribute").to_owned();
            (a("data-json"), a("data-value"))
        })
        .collect()
}

/// An OP identification with both families of terms of simulated data whose true robot has the
/// typical terms (seed 1): its result.
fn small_op_with_terms() -> IdentifyReport {
    let nominal = tx60();
    let truth = truth::apply_terms(
        &truth::apply_errors(&nominal, &truth::paper_errors()).expect("paper errors"),
        &truth::TermErrors {
            typical_seed: Some(1),
            ..Default::default()
        },
    )
    .expect("typical terms");
    let cfg = SimConfig {
        poses: 300,
        ident: 200,
        ..SimConfig::default()
    };
    let rows = simulate(&nominal, &truth, &cfg)
        .expect("sampled")
        .observations;
    let opts = IdentifyOptions {
        nongeometric: crate::identify::Nongeometric::of(&crate::model::TermFamily::ALL),
        ..IdentifyOptions::new(ObsConfig::new(ObsModel::Op, 10.0))
    };
    calibrate(&nominal, &rows, &opts, 10.0)
        .expect("identified")
        .0
}

#[test]
fn the_nongeometric_section_shows_terms_torque_model_and_comparison_each_number_the_json_s() {
    use crate::calibrate::identify_json::ParamStatus;
    use crate::report::extended::{term_value, Extended};
    let report = small_op_with_terms();
    let x = Extended::of(&report).expect("a result with terms");
    let html = super::nongeometric::section(&report);
    let json = serde_json::to_value(&report).expect("JSON");
    let pairs = tagged(&html);
    for (pointer, shown) in &pairs {
        let want = json
            .pointer(pointer)
            .unwrap_or_else(|| panic!("{pointer} not in the JSON"));
        match want {
            serde_json::Value::Number(n) => {
                assert_eq!(shown.parse::<f64>().ok(), n.as_f64(), "{pointer}")
            }
            serde_json::Value::String(s) => assert_eq!(shown, s, "{pointer}"),
            other => panic!("{pointer}: {other}"),
        }
    }
    let index = |name: &str| {
        (report.nongeometric_terms.iter())
            .position(|t| t.name == name)
            .unwrap_or_else(|| panic!("{name} listed"))
    };
    let identified = |i: usize| report.nongeometric_terms[i].status == ParamStatus::Identified;
    // an identified compliance and an identified harmonic (terms within 3 σ of zero are held)
    let first = |kind: &str| {
        (0..report.nongeometric_terms.len())
            .find(|&i| identified(i) && report.nongeometric_terms[i].kind.starts_with(kind))
            .unwrap_or_else(|| panic!("an identified {kind}"))
    };
    let (c2, c1, s3) = (first("compliance"), index("compliance1"), first("sin_q"));
    assert!(!identified(c1));
    let seen = |p: &str| pairs.iter().any(|(q, _)| q == p);
    let masses = report.masses.len();
    assert_eq!(masses, tx60().masses.len(), "the robot file's masses");
    for p in [
        "/metrics/verify/before/position_mean_mm".to_owned(),
        "/metrics_geometric/verify/after/position_rms_mm".to_owned(),
        "/metrics/verify/after/position_max_mm".to_owned(),
        "/metrics/ident/after/position_mean_mm".to_owned(),
        format!("/nongeometric_terms/{c2}/value"),
        format!("/nongeometric_terms/{c2}/sigma"),
        format!("/nongeometric_terms/{s3}/value"),
        format!("/nongeometric_terms/{c1}/reason"),
        format!("/nongeometric_terms/{c1}/status"),
        "/gravity/2".to_owned(),
        format!("/masses/{}/at_mm/2", masses - 1),
        format!("/masses/{}/kg", masses - 1),
        "/masses/0/frame".to_owned(),
    ] {
        assert!(seen(&p), "{p} not shown");
    }
    // units for people: compliance in µrad/(N·m), harmonics in mrad; the change vs geometric
    let (t2, t3) = (
        &report.nongeometric_terms[c2],
        &report.nongeometric_terms[s3],
    );
    for t in [t2, t3] {
        let shown = format!(">{}</td>", term_value(t, t.value));
        assert!(html.contains(&shown), "{shown}: {html}");
    }
    assert!(
        html.contains("µrad/(N·m)") && html.contains("held at zero"),
        "{html}"
    );
    let verify = |m: &crate::calibrate::identify_json::MetricsJson| {
        m.verify.as_ref().expect("verify").after.position_mean_mm
    };
    let change = crate::report::extended::change_percent(
        verify(report.metrics_geometric.as_ref().expect("geometric")),
        verify(&report.metrics),
    )
    .expect("a change");
    assert!(
        change < -20.0,
        "the extended model verifies better: {change} %"
    );
    let change = format!("{} %", crate::units::human::fmt_fixed(change, 1));
    assert!(html.contains(&change), "{change}: {html}");

    // the printed summary shows the same
    let text = crate::report::summary_text(&report);
    let mut lines = String::new();
    super::super::summary::tests_support::extended_lines(&mut lines, &x);
    assert!(text.contains(&lines[..lines.find("\nBefore").unwrap_or(lines.len())]));
    assert!(
        text.contains("compliance2  joint 2  compliance ") && text.contains("identified"),
        "{text}"
    );
    assert!(text.contains("held at zero: "), "{text}");
    assert!(text.contains("masses: frame 1 at ("), "{text}");
    assert!(lines.contains(&change), "{lines}");
}
