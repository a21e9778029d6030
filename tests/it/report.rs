//! The calibration report (`cellcal report`, `identify --report`, `GET /api/campaigns/{id}/report`):
//! it parses as HTML with a real parser (html5ever through `scraper`), holds one SVG per plot and
//! each parses as XML on its own, loads nothing from anywhere, and every number it tags with a
//! JSON pointer equals the identify JSON's value there.

use std::path::Path;
use std::process::Command as StdCommand;

use scraper::{Html, Selector};
use serde_json::Value;

use super::cli::{cellcal, identify_json, simulate_poses};
use super::serve::{agent, fast_config, start};

fn select<'a>(doc: &'a Html, css: &str) -> Vec<scraper::ElementRef<'a>> {
    let sel = Selector::parse(css).expect("selector");
    doc.select(&sel).collect()
}

/// Every `<svg>…</svg>` of the page's source, as written.
fn svg_sources(html: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let mut rest = html;
    while let Some(start) = rest.find("<svg") {
        let end = rest[start..].find("</svg>").expect("closed svg") + start + "</svg>".len();
        out.push(&rest[start..end]);
        rest = &rest[end..];
    }
    out
}

/// The page parses without an error, holds `svgs` plots (each a standalone XML document with a
/// title) and references nothing outside itself. Returns the parsed document.
fn check_structure(html: &str, svgs: usize) -> Html {
    let doc = Html::parse_document(html);
    assert!(doc.errors.is_empty(), "HTML parse errors: {:?}", doc.errors);
    assert_eq!(select(&doc, "svg").len(), svgs, "plots in the DOM");
    let sources = svg_sources(html);
    assert_eq!(sources.len(), svgs, "plots in the source");
    for svg in sources {
        let xml = roxmltree::Document::parse(svg).unwrap_or_else(|e| panic!("{e}: {svg:.300}"));
        let root = xml.root_element();
        assert_eq!(root.tag_name().name(), "svg");
        assert!(
            root.children().any(|c| c.has_tag_name("title")),
            "an SVG without a title"
        );
    }
    assert!(
        select(&doc, "figure p.missing").is_empty(),
        "a plot was not drawn"
    );
    // self-contained: no script, no loaded resource, links only within the page
    for tag in ["script", "link", "img", "iframe", "object", "embed", "base"] {
        assert!(select(&doc, tag).is_empty(), "a <{tag}> element");
    }
    assert!(select(&doc, "[src]").is_empty(), "an element with src=");
    for a in select(&doc, "[href], [xlink\\:href]") {
        let href = a.value().attr("href").unwrap_or("");
        assert!(href.starts_with('#'), "an external link: {href}");
    }
    let outside_namespaces = html.replace("xmlns=\"http://www.w3.org/2000/svg\"", "");
    for needle in ["http:", "https:", "url(", "@import", "//"] {
        assert!(
            !outside_namespaces.contains(needle),
            "`{needle}` in the page"
        );
    }
    doc
}

/// `a` equals the JSON's `b` (a JSON number may be read back one unit in the last place off).
fn same_number(a: f64, b: f64) -> bool {
    a == b || (a - b).abs() <= 2.0 * f64::EPSILON * b.abs()
}

/// Every value tagged `data-json` equals the JSON's at that pointer; the pointers checked.
fn check_numbers(doc: &Html, json: &Value) -> Vec<String> {
    let mut seen = Vec::new();
    for el in select(doc, "[data-json]") {
        let pointer = el.value().attr("data-json").expect("pointer");
        let shown = el
            .value()
            .attr("data-value")
            .expect("data-value beside data-json");
        let want = json
            .pointer(pointer)
            .unwrap_or_else(|| panic!("{pointer} is not in the JSON"));
        match want {
            Value::Number(n) => {
                let got: f64 = shown.parse().expect("a number");
                let want = n.as_f64().expect("f64");
                assert!(same_number(got, want), "{pointer}: page {got}, JSON {want}");
            }
            Value::String(s) => assert_eq!(shown, s, "{pointer}"),
            other => panic!("{pointer}: unexpected JSON value {other}"),
        }
        seen.push(pointer.to_owned());
    }
    seen
}

/// The numbers the brief names are all there: verify mean before/after, every parameter's
/// value and σ, and the verdict; and the headline shows the verify mean as the JSON rounds.
fn check_named_numbers(doc: &Html, json: &Value, seen: &[String]) {
    let must = |p: &str| assert!(seen.iter().any(|s| s == p), "{p} not in the page");
    must("/quality");
    must("/metrics/verify/before/position_mean_mm");
    must("/metrics/verify/after/position_mean_mm");
    must("/metrics/ident/after/position_mean_mm");
    for (i, p) in json["parameters"]
        .as_array()
        .expect("parameters")
        .iter()
        .enumerate()
    {
        must(&format!("/parameters/{i}/nominal"));
        must(&format!("/parameters/{i}/error"));
        if p["std"].is_number() {
            must(&format!("/parameters/{i}/std"));
        }
    }
    for (i, _) in json["not_identifiable"]
        .as_array()
        .expect("list")
        .iter()
        .enumerate()
    {
        must(&format!("/not_identifiable/{i}/reason"));
    }
    let after = json["metrics"]["verify"]["after"]["position_mean_mm"]
        .as_f64()
        .expect("verify after");
    let headline = select(
        doc,
        "header [data-json=\"/metrics/verify/after/position_mean_mm\"]",
    );
    let text: String = headline.first().expect("headline").text().collect();
    assert_eq!(
        text,
        cellcal::units::human::fmt_mm(after),
        "mm with 3 decimals"
    );
    let badge = select(doc, "header .badge");
    let q = json["quality"].as_str().expect("quality");
    assert_eq!(badge[0].value().attr("data-value"), Some(q));
}

/// The identify JSON and the report page written to `json` and `html`.
fn read_outputs(json: &Path, html: &Path) -> (Value, String) {
    let text = std::fs::read_to_string(json).expect("JSON written");
    let page = std::fs::read_to_string(html).expect("report written");
    (serde_json::from_str(&text).expect("JSON"), page)
}

/// Plots of a page with both sets and attitude: 4 per-pose and 2 histograms per set, one
/// attitude plot per set, the heat map and four significance charts.
const PLOTS: usize = 2 * 4 + 2 * 2 + 2 + 1 + 4;

#[test]
fn identify_writes_a_report_whose_numbers_are_the_json_s() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = simulate_poses(dir.path(), 90, 40, &[]);
    let json_path = dir.path().join("r.json");
    let html_path = dir.path().join("r.html");
    identify_json(&data, "op", &json_path)
        .arg("--report")
        .arg(&html_path)
        .assert()
        .success();
    let (json, html) = read_outputs(&json_path, &html_path);
    let doc = check_structure(&html, PLOTS);
    let seen = check_numbers(&doc, &json);
    check_named_numbers(&doc, &json, &seen);
    // no store behind a CSV: those sections say so; the inputs are named with their digests
    assert!(html.contains("did not come from a campaign store"));
    let digest = |p: &Path| {
        use sha2::Digest;
        let d = sha2::Sha256::digest(std::fs::read(p).expect("read"));
        d.iter().map(|b| format!("{b:02x}")).collect::<String>()
    };
    assert!(html.contains(&digest(&data)), "the CSV's SHA-256");
    assert!(
        html.contains(&digest(&super::cli::robot())),
        "the robot file's SHA-256"
    );
}

/// Run a small campaign on the simulated cell with `cellcal run` into `dir/c.db`.
fn run_small_campaign(dir: &Path) -> (std::path::PathBuf, std::path::PathBuf, Value) {
    let cfg = fast_config(dir, "serial", 60, 30);
    let store = dir.join("c.db");
    let json = dir.join("result.json");
    let out = StdCommand::new(assert_cmd::cargo::cargo_bin("cellcal"))
        .args(["run", "--quiet", "--arm", "--on-fault", "fail", "--config"])
        .arg(&cfg)
        .arg("--store")
        .arg(&store)
        .arg("--json")
        .arg(&json)
        .stdin(std::process::Stdio::null())
        .output()
        .expect("cellcal run");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // README command 1's summary: values ± σ in mm and mrad, no e-notation
    let text = String::from_utf8(out.stdout).expect("UTF-8");
    assert!(text.contains("Δθ (mrad)") && text.contains(" ± "), "{text}");
    assert!(!super::cli::has_e_notation(&text), "e-notation in:\n{text}");
    let v = serde_json::from_str(&std::fs::read_to_string(&json).expect("JSON written"));
    (cfg, store, v.expect("JSON"))
}

/// A stored campaign's page: the campaign sections are filled from the store.
fn check_campaign_sections(html: &str) {
    for what in [
        "Tool frame (docs/method.md §4",
        "sphere fit rms (mm)",
        "Base registration",
        "drift checks at the reference pose",
        "emScon TPI tracker (simulated cell, in-process)",
        "robotlink controller (simulated cell, in-process)",
        "cell configuration (as stored)",
        "robot model file (as stored)",
        // what the devices said they are when the run prepared them (journalled `devices`)
        "emScon tracker serial ",
        "robotlink server ",
        "Zaber ",
    ] {
        assert!(html.contains(what), "missing: {what}");
    }
    assert!(
        !html.contains("not recorded by this campaign"),
        "a device without identity"
    );
    assert!(!html.contains("did not come from a campaign store"));
    assert!(!html.contains("Per-pose errors are not available"));
    // the rebuilt identification reproduces the stored result: no note that it differs
    assert!(!html.contains("class=\"note\""), "a note in the page");
}

#[test]
fn a_stored_campaign_reports_from_the_cli_and_the_daemon() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (cfg, store, json) = run_small_campaign(dir.path());

    let out = dir.path().join("campaign.html");
    cellcal()
        .args(["report", "--store"])
        .arg(&store)
        .args(["--campaign", "1", "--out"])
        .arg(&out)
        .assert()
        .success();
    let html = std::fs::read_to_string(&out).expect("report written");
    let doc = check_structure(&html, PLOTS);
    let seen = check_numbers(&doc, &json);
    check_named_numbers(&doc, &json, &seen);
    check_campaign_sections(&html);

    // identify --store --report: this run's result, the campaign's facts
    let (again_json, again_html) = (dir.path().join("again.json"), dir.path().join("again.html"));
    cellcal()
        .args(["identify", "--store"])
        .arg(&store)
        .arg("--json")
        .arg(&again_json)
        .arg("--report")
        .arg(&again_html)
        .assert()
        .success();
    let (again, html) = read_outputs(&again_json, &again_html);
    let doc = check_structure(&html, PLOTS);
    assert_eq!(check_numbers(&doc, &again), seen);
    check_campaign_sections(&html);

    // the daemon serves the same page for the same campaign; 404 (JSON) before a result
    let s = start(&cfg, &store);
    let get = |path: &str| {
        let mut r = agent()
            .get(&format!("{}{path}", s.base))
            .header("authorization", &format!("Bearer {}", s.token))
            .call()
            .expect("GET");
        let header = |name: &str| {
            let v = r.headers().get(name).and_then(|v| v.to_str().ok());
            v.unwrap_or("").to_owned()
        };
        let (ct, csp) = (header("content-type"), header("content-security-policy"));
        let body = r.body_mut().read_to_string().expect("body");
        (r.status().as_u16(), ct, csp, body)
    };
    let (code, ct, csp, body) = get("/api/campaigns/1/report");
    assert_eq!(code, 200, "{body:.300}");
    assert!(ct.starts_with("text/html"), "{ct}");
    assert!(csp.starts_with("default-src 'none'"), "{csp}");
    let doc = check_structure(&body, PLOTS);
    assert_eq!(check_numbers(&doc, &json), seen);
    check_campaign_sections(&body);

    let (code, v) = super::serve::post(&s, "/api/campaigns", "{}");
    assert_eq!(code, 201, "{v}");
    let (code, ct, _, body) = get(&format!("/api/campaigns/{}/report", v["id"]));
    assert_eq!(code, 404, "{body}");
    assert!(ct.starts_with("application/json"), "{ct}");
    assert!(body.contains("has no result yet"), "{body}");
    assert_eq!(get("/api/campaigns/99/report").0, 404);
}
