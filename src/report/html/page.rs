//! The page around the sections: head, inline style sheet (screen and print), header, table of
//! contents; and the HTML helpers every section writes with (escaping, numbers tagged with the
//! JSON pointer they come from).

use std::fmt::Write;

use super::sections;
use super::ReportInput;
use crate::units::human::{fmt_mm, fmt_time_in};

/// The report as one HTML document.
pub fn render(input: &ReportInput) -> String {
    let body = sections::all(input);
    let mut out = String::with_capacity(body.len() + 8 * 1024);
    let _ = write!(
        out,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n\
         <meta name=\"generator\" content=\"cellcal {}\">\n<title>{}</title>\n<style>\n{STYLE}</style>\n</head>\n<body>\n",
        esc(&input.provenance.software_version),
        esc(&input.title)
    );
    out.push_str(&header(input));
    out.push_str(&body);
    let _ = write!(
        out,
        "<footer>cellcal {} · generated {}</footer>\n</body>\n</html>\n",
        esc(&input.provenance.software_version),
        esc(&generated(input))
    );
    out
}

/// When the report was generated, in the provenance's time zone.
fn generated(input: &ReportInput) -> String {
    let p = &input.provenance;
    fmt_time_in(p.generated_at_ms, &p.time_zone)
}

/// Title, verdict badge and the headline numbers.
fn header(input: &ReportInput) -> String {
    let r = &input.result;
    let q = r.quality.as_str();
    let mut h = format!(
        "<header>\n<h1>{}</h1>\n<p class=\"source\">{} · model <b>{}</b> · generated {}</p>\n\
         <p class=\"headline\"><span class=\"badge q-{q}\" data-json=\"/quality\" data-value=\"{q}\">quality: {}</span>",
        esc(&input.title),
        esc(&input.source),
        esc(&r.model),
        esc(&generated(input)),
        q.to_uppercase()
    );
    let (set, ba) = match &r.metrics.verify {
        Some(v) => ("verify", v),
        None => ("ident", &r.metrics.ident),
    };
    let p = format!("/metrics/{set}");
    let _ = write!(
        h,
        " <span class=\"kpi\">{set} mean position error {} mm → <b>{} mm</b> ({} poses)</span></p>\n</header>\n",
        json_shown(
            &format!("{p}/before/position_mean_mm"),
            ba.before.position_mean_mm,
            &fmt_mm(ba.before.position_mean_mm)
        ),
        json_shown(
            &format!("{p}/after/position_mean_mm"),
            ba.after.position_mean_mm,
            &fmt_mm(ba.after.position_mean_mm)
        ),
        ba.after.poses
    );
    h
}

/// `s` with `& < > " '` escaped: safe as element text and as a quoted attribute value.
pub fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// `v` with `decimals` decimals, or `—` when it is not finite.
pub fn fixed(v: f64, decimals: usize) -> String {
    if v.is_finite() {
        format!("{v:.decimals$}")
    } else {
        "—".to_owned()
    }
}

/// The attributes that tie a shown value to the JSON: its pointer and its exact value (shortest
/// round-trip form).
pub fn json_attrs(pointer: &str, exact: &str) -> String {
    format!(
        "data-json=\"{}\" data-value=\"{}\"",
        esc(pointer),
        esc(exact)
    )
}

/// A `<span>` showing `v` with `decimals` decimals, tagged with its JSON pointer.
pub fn json_num(pointer: &str, v: f64, decimals: usize) -> String {
    json_shown(pointer, v, &fixed(v, decimals))
}

/// A `<span>` showing `shown` for the JSON value `v` at `pointer`.
pub fn json_shown(pointer: &str, v: f64, shown: &str) -> String {
    if v.is_finite() {
        format!(
            "<span {}>{}</span>",
            json_attrs(pointer, &v.to_string()),
            esc(shown)
        )
    } else {
        esc(shown)
    }
}

/// A `<span>` showing the JSON string at `pointer`.
pub fn json_text(pointer: &str, s: &str) -> String {
    format!("<span {}>{}</span>", json_attrs(pointer, s), esc(s))
}

/// A numeric table cell showing `shown` for the JSON value `v` at `pointer` (`None`: no value).
pub fn json_cell(pointer: &str, v: Option<f64>, shown: &str) -> String {
    match v.filter(|v| v.is_finite()) {
        Some(v) => format!(
            "<td class=\"num\" {}>{}</td>",
            json_attrs(pointer, &v.to_string()),
            esc(shown)
        ),
        None => "<td class=\"num\">—</td>".to_owned(),
    }
}

/// A numeric table cell without a JSON counterpart.
pub fn num_cell(shown: &str) -> String {
    format!("<td class=\"num\">{}</td>", esc(shown))
}

/// A text table cell.
pub fn cell(text: &str) -> String {
    format!("<td>{}</td>", esc(text))
}

/// `<tr>` of header cells.
pub fn header_row(names: &[&str]) -> String {
    let cells: String = names
        .iter()
        .map(|n| format!("<th>{}</th>", esc(n)))
        .collect();
    format!("<tr>{cells}</tr>\n")
}

/// A `<section>` with an id, a heading and its content.
pub fn section(id: &str, heading: &str, content: &str) -> String {
    format!(
        "<section id=\"{}\">\n<h2>{}</h2>\n{content}</section>\n",
        esc(id),
        esc(heading)
    )
}

/// A paragraph saying why something is missing.
pub fn missing(text: &str) -> String {
    format!("<p class=\"missing\">{}</p>\n", esc(text))
}

/// A `<figure>` around an SVG (or the reason it could not be drawn) with a caption.
pub fn figure(svg: Result<String, super::plots::PlotError>, caption: &str) -> String {
    let inner = match svg {
        Ok(s) => s,
        Err(e) => missing(&format!("plot not drawn: {e}")),
    };
    format!(
        "<figure>\n{inner}<figcaption>{}</figcaption>\n</figure>\n",
        esc(caption)
    )
}

const STYLE: &str = r#":root { --before: #d6604d; --after: #2166ac; --ok: #1b7837; --warning: #b35806; --poor: #b2182b; }
* { box-sizing: border-box; -webkit-print-color-adjust: exact; print-color-adjust: exact; }
body { font: 14px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; color: #222; max-width: 1180px; margin: 0 auto; padding: 16px 24px 40px; }
h1 { font-size: 1.6em; margin: 0.2em 0; }
h2 { font-size: 1.25em; border-bottom: 2px solid #ddd; padding-bottom: 4px; margin-top: 1.8em; }
h3 { font-size: 1.05em; margin: 1.2em 0 0.4em; }
header .source { color: #555; margin: 0; }
.headline { font-size: 1.1em; }
.badge { display: inline-block; padding: 2px 10px; border-radius: 4px; color: #fff; font-weight: 700; margin-right: 12px; }
.q-ok { background: var(--ok); } .q-warning { background: var(--warning); } .q-poor { background: var(--poor); }
.sev-ok { color: var(--ok); } .sev-warning { color: var(--warning); font-weight: 600; } .sev-poor { color: var(--poor); font-weight: 700; }
nav ol { columns: 3; margin: 0.5em 0; }
nav a { color: #2166ac; text-decoration: none; }
table { border-collapse: collapse; margin: 0.5em 0 1em; font-size: 0.92em; }
th, td { border: 1px solid #d8d8d8; padding: 3px 8px; vertical-align: top; }
th { background: #f3f3f3; text-align: left; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
tr.held td { color: #777; }
.plots { display: grid; grid-template-columns: repeat(auto-fill, minmax(420px, 1fr)); gap: 8px 16px; }
.plots.wide { grid-template-columns: 1fr; max-width: 820px; }
figure { margin: 0.4em 0; }
figcaption { font-size: 0.85em; color: #555; }
svg.plot { max-width: 100%; height: auto; display: block; }
.missing { color: #777; font-style: italic; }
.note { background: #fff8e1; border-left: 4px solid #f0b400; padding: 4px 10px; }
code, .mono { font-family: ui-monospace, "DejaVu Sans Mono", monospace; font-size: 0.92em; overflow-wrap: break-word; }
footer { margin-top: 3em; color: #777; font-size: 0.85em; border-top: 1px solid #ddd; padding-top: 6px; }
@page { size: A4; margin: 14mm 12mm; }
@media print {
  body { font-size: 10.5pt; max-width: none; padding: 0; }
  nav { display: none; }
  h2 { break-after: avoid; }
  figure, tr, .note { break-inside: avoid; }
  .plots { grid-template-columns: 1fr 1fr; }
  .plots.wide { grid-template-columns: 1fr; }
  #parameters, #correlation, #significance { break-before: page; }
  a { color: inherit; text-decoration: none; }
}
"#;
