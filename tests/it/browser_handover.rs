//! The page hands over a calibration and reads well on a tablet (issue 19), in a real headless
//! Chromium against the real `cellcal serve` on a simulated cell: the report, the corrected
//! model, the measurements and the result are downloaded by the page's buttons (fetched with the
//! bearer token) and equal, byte for byte, what the REST API sends; the buttons are disabled
//! with a reason until the campaign has the file. At 768×1024 (a 1024×768 tablet in portrait)
//! the document is no wider than the window and the key controls lie inside it; devices read
//! "not connected yet", not a red "NO", before the first connection; the event list's
//! numbers are inside its box; every number is formatted by the page's one formatter
//! (`web/human.js`). Screenshots of the dashboard, an open question, the result with its
//! downloads and the report's first page at 1280×800 and 768×1024 go to `target/screenshots/`
//! (their paths printed).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use fantoccini::Client;
use serde_json::{json, Value};

use super::browser::{
    arm_and_start, browser, browser_saving_to, by_id, chromedriver, click, console_errors,
    create_from_page, keys, manual_cell, screenshot, scroll_to, shown, sign_in, text, until,
    Driver, ENTER,
};
use super::serve::{agent, bearer, create, fast_config, get, post, start, Server};

/// Sizes of the screenshots and layout checks: a laptop, and a 1024×768 tablet in portrait.
const DESKTOP: (u32, u32) = (1280, 800);
const TABLET: (u32, u32) = (768, 1024);

/// One Chrome DevTools command through chromedriver (`goog/cdp/execute`): its result.
async fn cdp(c: &Client, driver: &Driver, cmd: &str, params: Value) -> Value {
    let session = c
        .session_id()
        .await
        .expect("session id")
        .expect("a session");
    let url = format!("{}/session/{session}/goog/cdp/execute", driver.url);
    let body = json!({"cmd": cmd, "params": params});
    let cmd = cmd.to_owned();
    let reply: Value = tokio::task::spawn_blocking(move || {
        agent()
            .post(&url)
            .send_json(body)
            .expect("CDP")
            .body_mut()
            .read_json()
            .expect("CDP JSON")
    })
    .await
    .expect("CDP thread");
    assert!(reply["value"]["error"].is_null(), "{cmd}: {reply}");
    reply["value"].clone()
}

/// Make the page's viewport exactly `w`×`h` CSS pixels (screenshots are that size).
async fn viewport(c: &Client, driver: &Driver, (w, h): (u32, u32)) {
    cdp(
        c,
        driver,
        "Emulation.setDeviceMetricsOverride",
        json!({"width": w, "height": h, "deviceScaleFactor": 1, "mobile": false}),
    )
    .await;
    let inner: Value = c
        .execute("return [window.innerWidth, window.innerHeight];", vec![])
        .await
        .expect("inner size");
    assert_eq!(inner, json!([w, h]), "viewport");
}

/// `name-WxH.png` of the window with `#id` at its top (the window's top when `id` is None).
async fn shot(c: &Client, id: Option<&str>, name: &str, (w, h): (u32, u32)) -> PathBuf {
    match id {
        Some(id) => scroll_to(c, id).await,
        None => {
            c.execute("window.scrollTo(0, 0);", vec![])
                .await
                .expect("scroll");
        }
    }
    screenshot(c, &format!("{name}-{w}x{h}.png")).await
}

/// At the current viewport: how far the document is wider than the window (px), and each of
/// `ids` that is not shown, or not inside the window once scrolled to.
async fn layout_faults(c: &Client, ids: &[&str]) -> (i64, Vec<String>) {
    let v: Value = c
        .execute(
            r#"
const W = document.documentElement.clientWidth, H = window.innerHeight;
const bad = [];
for (const id of arguments[0]) {
  const e = document.getElementById(id);
  if (!e || !e.getClientRects().length) { bad.push(id + ' not shown'); continue; }
  e.scrollIntoView({block: 'center', inline: 'nearest'});
  const r = e.getBoundingClientRect();
  // one taller than the window (a long table) need only fit across
  const tall = r.height > H;
  if (r.left < 0 || r.right > W + 0.5 || (!tall && (r.top < 0 || r.bottom > H + 0.5))) {
    bad.push(id + ' at ' + [r.left, r.top, r.right, r.bottom].map(Math.round).join(',')
      + ' outside ' + W + 'x' + H);
  }
}
window.scrollTo(0, 0);
return [document.documentElement.scrollWidth - W, bad];"#,
            vec![json!(ids)],
        )
        .await
        .expect("layout");
    let over = v[0].as_i64().expect("overflow");
    let bad = v[1]
        .as_array()
        .expect("faults")
        .iter()
        .map(|b| b.as_str().unwrap_or_default().to_owned())
        .collect();
    (over, bad)
}

/// At 768×1024 the document is no wider than the window and every one of `ids` is shown inside
/// it.
async fn fits_a_tablet(c: &Client, driver: &Driver, ids: &[&str], when: &str) {
    viewport(c, driver, TABLET).await;
    let (over, bad) = layout_faults(c, ids).await;
    assert!(
        over <= 0,
        "{when}: the page is {over} px wider than a 768 px tablet"
    );
    assert!(bad.is_empty(), "{when}: {bad:?}");
}

/// The campaign's file as the API sends it with the token: its bytes and `Content-Disposition`.
fn rest_file(s: &Server, path: &str) -> (Vec<u8>, String) {
    let mut r = agent()
        .get(&format!("{}{path}", s.base))
        .header("authorization", &bearer(&s.token))
        .call()
        .expect("GET");
    assert_eq!(r.status().as_u16(), 200, "{path}");
    let disposition = r
        .headers()
        .get("content-disposition")
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
        .to_owned();
    let body = r.body_mut().read_to_vec().expect("body");
    (body, disposition)
}

/// The file `name` in `dir` once the browser has finished saving it (at most 20 s).
async fn downloaded(dir: &Path, name: &str) -> Vec<u8> {
    let path = dir.join(name);
    let partial = dir.join(format!("{name}.crdownload"));
    until(&format!("{name} downloaded"), 20, || {
        let (path, partial) = (path.clone(), partial.clone());
        async move { (path.is_file() && !partial.exists()).then_some(()) }
    })
    .await;
    std::fs::read(&path).expect("downloaded file")
}

/// The title (tooltip) of `#id` and whether it is enabled.
async fn button_state(c: &Client, id: &str) -> (bool, String) {
    let e = by_id(c, id).await;
    let enabled = e.is_enabled().await.expect("enabled");
    let title = e.attr("title").await.expect("title").unwrap_or_default();
    (enabled, title)
}

/// The page's downloads: button, route, file suffix.
const DOWNLOADS: [(&str, &str, &str); 4] = [
    ("download-report", "report", "report.html"),
    ("download-model", "model", "model.toml"),
    (
        "download-csv",
        "measurements?format=csv",
        "measurements.csv",
    ),
    ("download-result", "result", "result.json"),
];

/// Every parameter row of the result shows its nominal value with 3 decimals (° or mm) and its
/// error with 3 decimals, σ beside it when identified, in mrad or mm; no number anywhere in
/// the result view is in e-notation. The offending cells.
async fn result_format_faults(c: &Client) -> Vec<String> {
    let v: Value = c
        .execute(
            r#"
const bad = [];
const num = '-?\\d+\\.\\d{3}';
for (const tr of document.querySelectorAll('#result-parameters tbody tr')) {
  const [name, nominal, error, identified] = [...tr.cells].map((td) => td.textContent);
  if (!new RegExp('^' + num + '(°| mm)$').test(nominal)) bad.push(name + ' nominal ' + nominal);
  const sigma = identified.startsWith('yes');
  const want = new RegExp('^' + num + (sigma ? ' ± \\d+\\.\\d{3}' : '( ± \\d+\\.\\d{3})?') + ' (mrad|mm)$');
  if (!want.test(error)) bad.push(name + ' error ' + error);
  if (nominal.endsWith('°') !== error.endsWith('mrad')) bad.push(name + ' units ' + nominal + ' / ' + error);
}
if (!document.querySelectorAll('#result-parameters tbody tr').length) bad.push('no parameter rows');
for (const td of document.querySelectorAll('#result-metrics tbody td')) {
  if (td.cellIndex > 1 && !new RegExp('^' + num + '$').test(td.textContent)) bad.push('metric ' + td.textContent);
}
const text = document.getElementById('result-view').innerText;
const e = text.match(/\d\.?\d*e[-+]?\d/i);
if (e) bad.push('e-notation: ' + e[0]);
return bad;"#,
            vec![],
        )
        .await
        .expect("result format");
    v.as_array()
        .expect("faults")
        .iter()
        .map(|b| b.to_string())
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_hands_over_report_model_csv_and_result_as_the_api_sends_them() {
    let Some(driver) = chromedriver() else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let saved = dir.path().join("downloads");
    std::fs::create_dir_all(&saved).expect("downloads dir");
    let s = start(
        &fast_config(dir.path(), "serial", 30, 20),
        &dir.path().join("c.db"),
    );
    let c = browser_saving_to(&driver, Some(&saved)).await;
    cdp(
        &c,
        &driver,
        "Browser.setDownloadBehavior",
        json!({"behavior": "allow", "downloadPath": saved}),
    )
    .await;
    sign_in(&c, &s).await;
    let id = create(&s, "{}");
    let page = &c;
    until("the campaign on the page", 20, || async move {
        text(page, "campaign-id")
            .await
            .starts_with(&format!("#{id} "))
            .then_some(())
    })
    .await;
    // nothing to hand over yet: every download disabled, saying why
    for (button, _, _) in DOWNLOADS {
        let (enabled, title) = button_state(&c, button).await;
        assert!(
            !enabled,
            "{button} enabled before the campaign has its file"
        );
        let why = if button == "download-csv" {
            "no measured pose yet"
        } else {
            "no result yet"
        };
        assert!(title.contains(why), "{button}: title `{title}`");
    }
    assert!(text(&c, "handover-note").await.contains("no result yet"));

    super::serve::arm_and_start(&s, id);
    let server = &s;
    until("the campaign done", 120, || async move {
        let (_, v) = get(server, &format!("/api/campaigns/{id}"));
        (v["state"] == "done" && v["has_result"] == true).then_some(())
    })
    .await;
    until("the result on the page", 30, || async move {
        shown(page, "result-view").await.then_some(())
    })
    .await;
    for (button, route, file) in DOWNLOADS {
        let path = format!("/api/campaigns/{id}/{route}");
        let name = format!("campaign-{id}-{file}");
        let (before, disposition) = rest_file(&s, &path);
        assert_eq!(
            disposition,
            format!("attachment; filename=\"{name}\""),
            "{path}"
        );
        click(&c, button).await;
        let got = downloaded(&saved, &name).await;
        assert!(!got.is_empty(), "{name} is empty");
        if got != before {
            // the report names the second it was generated: the click's fetch may be a second later
            let (after, _) = rest_file(&s, &path);
            assert!(
                file == "report.html" && got == after,
                "{name}: the download differs from the REST body ({} vs {} bytes)",
                got.len(),
                before.len()
            );
        }
        let (enabled, title) = button_state(&c, button).await;
        assert!(enabled && title.contains(&name), "{button}: {title}");
    }
    let faults = result_format_faults(&c).await;
    assert!(faults.is_empty(), "result format: {faults:?}");

    // the result with its downloads, then the report's first page, on a laptop and a tablet
    for size in [DESKTOP, TABLET] {
        viewport(&c, &driver, size).await;
        shot(&c, Some("handover"), "result", size).await;
    }
    fits_a_tablet(
        &c,
        &driver,
        &[
            "abort",
            "download-report",
            "download-model",
            "download-csv",
            "download-result",
            "quality",
            "result-parameters",
        ],
        "the result",
    )
    .await;
    let errors = console_errors(&c, &driver).await;
    assert!(errors.is_empty(), "console errors: {errors:#?}");
    let report = saved.join(format!("campaign-{id}-report.html"));
    c.goto(&format!("file://{}", report.display()))
        .await
        .expect("open the report");
    for size in [DESKTOP, TABLET] {
        viewport(&c, &driver, size).await;
        shot(&c, None, "report", size).await;
    }
    c.close().await.expect("close");
}

/// The device table's connection cells, tracker, robot, stage: text and class.
async fn connections(c: &Client) -> Vec<(String, String)> {
    let v: Value = c
        .execute(
            "return ['tracker', 'robot', 'stage'].map((d) => {\
               const td = document.getElementById('device-' + d).cells[3];\
               return [td.textContent, td.className]; });",
            vec![],
        )
        .await
        .expect("device cells");
    v.as_array()
        .expect("rows")
        .iter()
        .map(|r| {
            (
                r[0].as_str().unwrap_or_default().to_owned(),
                r[1].as_str().unwrap_or_default().to_owned(),
            )
        })
        .collect()
}

/// Until the page shows tracker and robot "not connected yet" (neutral, not red) and the manual
/// micrometer as having no connection; `when` names the moment.
async fn not_connected_yet(c: &Client, s: &Server, when: &str) {
    let (_, d) = get(s, "/api/devices");
    for dev in ["tracker", "robot"] {
        assert_eq!(d[dev]["connection"], "not_connected_yet", "{when}: {d}");
    }
    assert_eq!(d["stage"]["connection"], "no_connection", "{when}: {d}");
    let got = until(&format!("{when}: not connected yet"), 10, || async move {
        let rows = connections(c).await;
        (rows[0].0 == "not connected yet").then_some(rows)
    })
    .await;
    for (i, (said, class)) in got.iter().enumerate() {
        let want = if i < 2 {
            "not connected yet"
        } else {
            "no connection (manual micrometer)"
        };
        assert_eq!(said, want, "{when}: {got:?}");
        assert_ne!(class, "no", "{when}: red before any connection: {got:?}");
    }
}

/// The numbers of `human.js` for known values, as the page formats them.
async fn formats_numbers_one_way(c: &Client) {
    let v: Value = c
        .execute(
            "const t = 1795666135248;\
             return [human.mm(-0.1222478), human.mm(1e-7), human.mm(-1e-7), human.mm(12345.678901),\
               human.mrad(1.2345e-4), human.mrad(-2.5e-9), human.deg(Math.PI / 2), human.deg(-1e-9),\
               human.withSigma(human.mm(0.02514), human.mm(0.00123)), human.withSigma(human.mm(1), null),\
               human.duration(21.84), human.duration(250), human.duration(3900), human.duration(59.97),\
               human.mm(NaN), human.mm(Infinity), human.mm(null),\
               human.localTime(t), Date.parse(human.localTime(t)) === 1795666135000];",
            vec![],
        )
        .await
        .expect("human");
    let want = json!([
        "-0.122",
        "0.000",
        "0.000",
        "12345.679",
        "0.123",
        "0.000",
        "90.000",
        "0.000",
        "0.025 ± 0.001",
        "1.000",
        "21.8 s",
        "4 min 10 s",
        "1 h 05 min",
        "1 min 00 s",
        "—",
        "—",
        "—"
    ]);
    assert_eq!(
        v.as_array().expect("values")[..17],
        want.as_array().expect("want")[..]
    );
    let local = v[17].as_str().expect("local time");
    let shape = local.len() == 25
        && local.as_bytes()[10] == b'T'
        && matches!(local.as_bytes()[19], b'+' | b'-')
        && !local.contains('.');
    assert!(shape, "local ISO 8601 with offset, to the second: {local}");
    assert_eq!(v[18], true, "{local} is the same instant");
}

/// The event list: each entry starts with its journal number inside the list's box and no
/// list marker hangs outside it (where it was cut).
async fn event_numbers_are_inside(c: &Client) {
    let v: Value = c
        .execute(
            r#"
const log = document.getElementById('event-log');
log.scrollIntoView({block: 'center'});
const box = log.getBoundingClientRect();
const left = box.left + log.clientLeft;
const bad = [];
for (const li of log.children) {
  const cs = getComputedStyle(li);
  if (cs.listStyleType !== 'none' && cs.listStylePosition === 'outside') bad.push('marker outside: ' + li.textContent);
  if (!/^#\d+ /.test(li.textContent)) bad.push('no number first: ' + li.textContent);
  const r = document.createRange();
  r.setStart(li.firstChild.firstChild || li.firstChild, 0);
  r.setEnd(li.firstChild.firstChild || li.firstChild, 1);
  if (r.getBoundingClientRect().left < left) bad.push('cut: ' + li.textContent);
}
return [log.children.length, bad];"#,
            vec![],
        )
        .await
        .expect("event log");
    assert!(v[0].as_u64().unwrap_or(0) > 3, "events listed: {v}");
    assert_eq!(v[1], json!([]), "event list");
}

/// Answer the open question of campaign `id` on the page (the expected reading and Enter, the
/// clear button, or Confirm); `false` when none is open.
async fn answer_one(c: &Client, s: &Server, id: i64) -> bool {
    let (_, v) = get(s, &format!("/api/campaigns/{id}"));
    let q = &v["prompt"];
    let Some(seq) = q["seq"].as_u64() else {
        return false;
    };
    until("the question on the page", 20, || async move {
        let panel = by_id(c, "prompt-panel").await;
        let shown_seq = panel.attr("data-seq").await.ok().flatten();
        (panel.is_displayed().await.unwrap_or(false) && shown_seq == Some(seq.to_string()))
            .then_some(())
    })
    .await;
    if q["id"] == "confirm_clear" {
        click(c, "prompt-clear").await;
    } else if let Some(x) = q["expected_mm"].as_f64() {
        keys(c, &format!("{x:.3}{ENTER}")).await;
    } else {
        click(c, "prompt-confirm").await;
    }
    until("the answer taken", 30, || async move {
        let (_, v) = get(s, &format!("/api/campaigns/{id}"));
        (v["prompt"]["seq"].as_u64() != Some(seq)).then_some(())
    })
    .await;
    true
}

/// The open question of campaign `id` (the next one, waiting at most 30 s).
async fn a_question(s: &Server, id: i64) {
    until("a question", 30, || async move {
        let (_, v) = get(s, &format!("/api/campaigns/{id}"));
        v["prompt"]["seq"].as_u64().map(|_| ())
    })
    .await;
}

/// The header and campaign controls an operator has on the dashboard.
const DASHBOARD_CONTROLS: [&str; 9] = [
    "abort",
    "sign-out",
    "cmd-arm",
    "cmd-disarm",
    "cmd-start",
    "cmd-pause",
    "cmd-resume",
    "create",
    "download-report",
];

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_reads_well_on_a_tablet_in_portrait() {
    let Some(driver) = chromedriver() else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let s = start(&manual_cell(dir.path(), ""), &dir.path().join("c.db"));
    let c = browser(&driver).await;
    viewport(&c, &driver, TABLET).await;
    sign_in(&c, &s).await;
    formats_numbers_one_way(&c).await;
    // before any campaign, and with one loaded but not started: not connected yet, not red
    not_connected_yet(&c, &s, "before any campaign").await;
    fits_a_tablet(&c, &driver, &DASHBOARD_CONTROLS, "signed in").await;
    let id = create_from_page(&c, &s, 20, 14).await;
    not_connected_yet(&c, &s, "loaded, not started").await;
    fits_a_tablet(&c, &driver, &DASHBOARD_CONTROLS, "a campaign loaded").await;

    // running: answer questions until a few poses are measured, one left open
    arm_and_start(&c).await;
    let (server, page) = (&s, &c);
    let started = Instant::now();
    loop {
        a_question(&s, id).await;
        let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
        if v["poses_done"].as_u64().unwrap_or(0) >= 3 && v["prompt"]["expected_mm"].is_number() {
            break;
        }
        assert!(started.elapsed() < Duration::from_secs(120), "stuck: {v}");
        answer_one(&c, &s, id).await;
    }
    until("the question on the page", 20, || async move {
        let (_, v) = get(server, &format!("/api/campaigns/{id}"));
        let seq = v["prompt"]["seq"].as_u64()?.to_string();
        let panel = by_id(page, "prompt-panel").await;
        (panel.is_displayed().await.unwrap_or(false)
            && panel.attr("data-seq").await.ok().flatten() == Some(seq))
        .then_some(())
    })
    .await;
    // the devices answered: connected (the manual micrometer has no connection)
    until("devices connected on the page", 10, || async move {
        let rows = connections(page).await;
        (rows[0].0 == "yes" && rows[1].0 == "yes").then_some(())
    })
    .await;
    fits_a_tablet(
        &c,
        &driver,
        &[
            "abort",
            "prompt-value",
            "prompt-confirm",
            "prompt-abort",
            "cmd-pause",
            "cmd-disarm",
            "progress",
            "event-log",
        ],
        "a question open",
    )
    .await;
    event_numbers_are_inside(&c).await;
    let expected = text(&c, "prompt-context").await;
    assert!(expected.contains(" mm"), "{expected}");
    for size in [DESKTOP, TABLET] {
        viewport(&c, &driver, size).await;
        shot(&c, Some("prompt-panel"), "question", size).await;
        shot(&c, Some("dashboard"), "dashboard", size).await;
    }
    let errors = console_errors(&c, &driver).await;
    assert!(errors.is_empty(), "console errors: {errors:#?}");
    let (code, v) = post(
        &s,
        &format!("/api/campaigns/{id}/commands"),
        r#"{"command": "abort"}"#,
    );
    assert_eq!(code, 200, "{v}");
    c.close().await.expect("close");
}
