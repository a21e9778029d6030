use super::*;
use crate::analysis::significance::significance;
use crate::calibrate::calibrate;
use crate::dataset::Observation;
use crate::identify::Identification;
use crate::identify::{IdentifyOptions, ObsConfig, ObsModel, PracticalBounds};
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
    let opts = IdentifyOptions {
        obs: ObsConfig::new(ObsModel::Op, 10.0),
        identify_base: false,
        identify_tool: false,
        registered_base: false,
        robust: None,
        point_weights: None,
        solver: Default::default(),
        practical: PracticalBounds::default(),
        nongeometric: Default::default(),
    };
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

#[test]
fn the_nongeometric_section_shows_terms_torque_model_and_comparison_each_number_the_json_s() {
    use crate::calibrate::identify_json::ParamStatus;
    use crate::model::TermFamily;
    use crate::report::extended::{Extended, KeptModel, MassJson, TermJson};
    let (_, report, _) = small_op();
    let term =
        |name: &str, joint, kind: &str, value, sigma, unit: &str, reason: Option<&str>| TermJson {
            name: name.into(),
            joint,
            kind: kind.into(),
            value,
            sigma,
            unit: unit.into(),
            status: if sigma.is_some() {
                ParamStatus::Identified
            } else {
                ParamStatus::NotIdentified
            },
            reason: reason.map(Into::into),
        };
    let terms = vec![
        term(
            "compliance2",
            2,
            "compliance",
            2.5e-6,
            Some(1.5e-8),
            "rad/(N·m)",
            None,
        ),
        term("sin_q3", 3, "sin_q", -1.5e-4, Some(2e-6), "rad", None),
        term(
            "sin_q6",
            6,
            "sin_q",
            0.0,
            None,
            "rad",
            Some("not observable: the tool is on axis 6"),
        ),
    ];
    let mut geometric = report.metrics.clone();
    let v = geometric.verify.as_mut().expect("verify");
    v.after.position_mean_mm *= 1.25;
    let masses = vec![MassJson {
        frame: 2,
        at_mm: [-150.0, 0.0, 120.5],
        kg: 8.4,
    }];
    let x = Extended {
        families: &[TermFamily::Compliance, TermFamily::Harmonics],
        terms: &terms,
        metrics: &report.metrics,
        geometric: &geometric,
        extended_not_kept: None,
        kept: KeptModel::Extended,
        gravity: Some([0.0, 0.0, -1.0]),
        masses: &masses,
    };
    let html = super::nongeometric::render(&x);
    let mut json = serde_json::to_value(&report).expect("JSON");
    json["metrics_geometric"] = serde_json::to_value(&geometric).expect("JSON");
    json["gravity"] = serde_json::json!([0.0, 0.0, -1.0]);
    json["masses"] = serde_json::json!([{"frame": 2, "at_mm": [-150.0, 0.0, 120.5], "kg": 8.4}]);
    json["nongeometric_terms"] = serde_json::Value::Array(
        terms
            .iter()
            .map(|t| {
                serde_json::json!({"name": t.name, "joint": t.joint, "kind": t.kind,
                    "value": t.value, "sigma": t.sigma, "unit": t.unit,
                    "status": t.status.name(), "reason": t.reason})
            })
            .collect(),
    );
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
    let seen = |p: &str| pairs.iter().any(|(q, _)| q == p);
    for p in [
        "/metrics/verify/before/position_mean_mm",
        "/metrics_geometric/verify/after/position_rms_mm",
        "/metrics/verify/after/position_max_mm",
        "/metrics/ident/after/position_mean_mm",
        "/nongeometric_terms/0/value",
        "/nongeometric_terms/0/sigma",
        "/nongeometric_terms/2/reason",
        "/nongeometric_terms/2/status",
        "/gravity/2",
        "/masses/0/at_mm/2",
        "/masses/0/kg",
        "/masses/0/frame",
    ] {
        assert!(seen(p), "{p} not shown");
    }
    // units for people: compliance in µrad/(N·m), harmonics in mrad; the change vs geometric
    assert!(
        html.contains(">2.500</td>") && html.contains("± 0.015"),
        "{html}"
    );
    assert!(html.contains(">-0.150</td>"), "{html}");
    assert!(
        html.contains("-20.0 %"),
        "verification mean −20 % vs geometric: {html}"
    );
    assert!(html.contains("held at zero"), "{html}");

    // the printed summary shows the same
    let mut text = String::new();
    super::super::summary::tests_support::extended_lines(&mut text, &x);
    assert!(
        text.contains(
            "compliance2  joint 2  compliance         2.500 ± 0.015 µrad/(N·m)  identified"
        ),
        "{text}"
    );
    assert!(
        text.contains("held at zero: not observable: the tool is on axis 6"),
        "{text}"
    );
    assert!(
        text.contains("masses: frame 2 at (-150.000, 0.000, 120.500) mm 8.400 kg"),
        "{text}"
    );
    assert!(text.contains("-20.0 %"), "{text}");
}
