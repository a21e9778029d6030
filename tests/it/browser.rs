//! The cockpit web page in a real headless Chromium driven over WebDriver (fantoccini, Debian's
//! `chromedriver`) against the real `cellcal serve` binary on a simulated cell: the printed token
//! link signs in, a campaign is created with overrides, armed (confirmed), started, every
//! technician question answered by typing a reading and Enter (with its context: pose n of N,
//! P1 or P2, robot stopped; an out-of-tolerance reading explained), the dashboard's device
//! panel, drift checks and deviation plot filled, and the verdict shown; the same from the
//! keyboard alone (Tab, Enter, Escape); what a viewer and a technician are offered; the page's
//! Abort stops a running campaign. Screenshots go to `target/screenshots/`.
//!
//! Without `chromedriver` the tests skip with a loud message, unless `CELLCAL_REQUIRE_BROWSER=1`
//! (set by `.ci/run`), where they fail.

use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use fantoccini::actions::{InputSource, KeyAction, KeyActions};
use fantoccini::elements::Element;
use fantoccini::{Client, ClientBuilder, Locator};
use serde_json::{json, Value};

use super::campaign::write_config;
use super::serve::{fast_config, get, post_as, role_tokens, start, start_as_operator, Server};

/// Env var: `1` makes a missing chromedriver a failure instead of a skip.
const REQUIRE_ENV: &str = "CELLCAL_REQUIRE_BROWSER";
/// WebDriver's key codes of Enter, Tab and Escape.
pub(super) const ENTER: char = '\u{E007}';
const TAB: char = '\u{E004}';
const ESCAPE: char = '\u{E00C}';

/// A running chromedriver, killed on drop.
pub(super) struct Driver {
    child: Child,
    pub(super) url: String,
}

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The first `name` on `PATH`.
fn on_path(name: &str) -> Option<PathBuf> {
    std::env::var_os("PATH")
        .map(|p| {
            std::env::split_paths(&p)
                .map(|d| d.join(name))
                .collect::<Vec<_>>()
        })
        .unwrap_or_default()
        .into_iter()
        .find(|p| p.is_file())
}

/// chromedriver on a free loopback port, or `None` (with a loud message) when it is not
/// installed and the browser is not required.
pub(super) fn chromedriver() -> Option<Driver> {
    let Some(path) = on_path("chromedriver") else {
        let required = std::env::var(REQUIRE_ENV).is_ok_and(|v| v == "1");
        assert!(
            !required,
            "{REQUIRE_ENV}=1 but chromedriver is not on PATH: apt-get install chromium chromium-driver"
        );
        eprintln!(
            "\n*** SKIPPED: browser test needs chromedriver (apt-get install chromium chromium-driver); \
             set {REQUIRE_ENV}=1 to make this a failure ***\n"
        );
        return None;
    };
    let port = TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("free port")
        .port();
    let child = Command::new(path)
        .arg(format!("--port={port}"))
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn chromedriver");
    let deadline = Instant::now() + Duration::from_secs(20);
    while TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(Instant::now() < deadline, "chromedriver never listened");
        std::thread::sleep(Duration::from_millis(50));
    }
    Some(Driver {
        child,
        url: format!("http://127.0.0.1:{port}"),
    })
}

/// A headless Chromium session on `driver`.
pub(super) async fn browser(driver: &Driver) -> Client {
    browser_saving_to(driver, None).await
}

/// A headless Chromium session on `driver` that saves downloads in `downloads`, when given,
/// without asking.
pub(super) async fn browser_saving_to(driver: &Driver, downloads: Option<&Path>) -> Client {
    let mut options = json!({
        "args": ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                 "--window-size=1280,1800"]
    });
    if let Some(dir) = downloads {
        options["prefs"] = json!({
            "download.default_directory": dir,
            "download.prompt_for_download": false,
            "download.directory_upgrade": true,
        });
    }
    if Path::new("/usr/bin/chromium").is_file() {
        options["binary"] = json!("/usr/bin/chromium");
    }
    let mut caps = serde_json::Map::new();
    caps.insert("goog:chromeOptions".into(), options);
    // the console's entries, for [`console_errors`]
    caps.insert("goog:loggingPrefs".into(), json!({"browser": "ALL"}));
    ClientBuilder::new(hyper_util::client::legacy::connect::HttpConnector::new())
        .capabilities(caps)
        .connect(&driver.url)
        .await
        .expect("WebDriver session")
}

/// The browser console's SEVERE entries (errors, failed loads) since the session began or the
/// last call, from chromedriver's log endpoint.
pub(super) async fn console_errors(c: &Client, driver: &Driver) -> Vec<Value> {
    let session = c
        .session_id()
        .await
        .expect("session id")
        .expect("a session");
    let url = format!("{}/session/{session}/se/log", driver.url);
    let log: Value = tokio::task::spawn_blocking(move || {
        super::serve::agent()
            .post(&url)
            .send_json(json!({"type": "browser"}))
            .expect("console log")
            .body_mut()
            .read_json()
            .expect("console log JSON")
    })
    .await
    .expect("console log thread");
    let entries = log["value"].as_array().expect("console entries").clone();
    entries
        .into_iter()
        .filter(|e| e["level"] == "SEVERE")
        .collect()
}

/// Poll `probe` every 50 ms until it gives `Some`, at most `secs` seconds.
pub(super) async fn until<T, F, Fut>(what: &str, secs: u64, mut probe: F) -> T
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = Option<T>>,
{
    let deadline = Instant::now() + Duration::from_secs(secs);
    loop {
        if let Some(v) = probe().await {
            return v;
        }
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

pub(super) async fn by_id(c: &Client, id: &str) -> Element {
    c.find(Locator::Id(id))
        .await
        .unwrap_or_else(|e| panic!("#{id}: {e}"))
}

/// The visible text of `#id` ("" when hidden).
pub(super) async fn text(c: &Client, id: &str) -> String {
    by_id(c, id).await.text().await.unwrap_or_default()
}

/// Wait until `#id` shows `want`.
pub(super) async fn until_text(c: &Client, id: &str, want: &str, secs: u64) {
    until(&format!("#{id} = {want}"), secs, || async move {
        (text(c, id).await == want).then_some(())
    })
    .await;
}

/// Click `#id` once it is shown and enabled.
pub(super) async fn click(c: &Client, id: &str) {
    let e = until(&format!("#{id} clickable"), 20, || async move {
        let e = by_id(c, id).await;
        let ready =
            e.is_displayed().await.unwrap_or(false) && e.is_enabled().await.unwrap_or(false);
        ready.then_some(e)
    })
    .await;
    // in the middle of the window: never under the sticky header
    let at = serde_json::to_value(&e).expect("element reference");
    c.execute("arguments[0].scrollIntoView({block: 'center'});", vec![at])
        .await
        .expect("scroll");
    e.click()
        .await
        .unwrap_or_else(|err| panic!("click #{id}: {err}"));
}

/// Where the screenshots go: `target/screenshots/` of this checkout.
fn screenshot_dir() -> PathBuf {
    let d = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/screenshots");
    std::fs::create_dir_all(&d).expect("screenshot dir");
    d
}

/// Save a PNG screenshot as `target/screenshots/<name>`.
pub(super) fn save_png(png: Vec<u8>, name: &str) -> PathBuf {
    assert!(png.starts_with(b"\x89PNG"), "a PNG");
    let p = screenshot_dir().join(name);
    std::fs::write(&p, png).expect("write screenshot");
    eprintln!("screenshot: {}", p.display());
    p
}

/// The whole window.
pub(super) async fn screenshot(c: &Client, name: &str) -> PathBuf {
    save_png(c.screenshot().await.expect("screenshot"), name)
}

/// Scroll `#id` to the top of the window (below the sticky header).
pub(super) async fn scroll_to(c: &Client, id: &str) {
    c.execute(
        "document.getElementById(arguments[0]).scrollIntoView({block: 'start'});",
        vec![json!(id)],
    )
    .await
    .expect("scroll");
}

/// One element (`#id`) of the page.
async fn screenshot_of(c: &Client, id: &str, name: &str) -> PathBuf {
    scroll_to(c, id).await;
    let png = by_id(c, id).await.screenshot().await.expect("screenshot");
    save_png(png, name)
}

/// The window with `#id` at its top.
pub(super) async fn screenshot_from(c: &Client, id: &str, name: &str) -> PathBuf {
    scroll_to(c, id).await;
    screenshot(c, name).await
}

/// Press the keys of `text` (WebDriver key codes included) on whatever has the focus: the
/// keyboard, not an element.
pub(super) async fn keys(c: &Client, text: &str) {
    let mut k = KeyActions::new("keyboard".into());
    for ch in text.chars() {
        k = k
            .then(KeyAction::Down { value: ch })
            .then(KeyAction::Up { value: ch });
    }
    c.perform_actions(k).await.expect("keys");
}

/// The id of the focused element (`None` for an element without one, e.g. the body).
pub(super) async fn focused_id(c: &Client) -> Option<String> {
    let e = c.active_element().await.ok()?;
    e.attr("id")
        .await
        .ok()
        .flatten()
        .filter(|id| !id.is_empty())
}

/// Press Tab until `#id` has the focus (at most 80 times).
async fn tab_to(c: &Client, id: &str) {
    for _ in 0..80 {
        if focused_id(c).await.as_deref() == Some(id) {
            return;
        }
        keys(c, &TAB.to_string()).await;
    }
    panic!("Tab never reached #{id}");
}

/// Wait until `#id` is shown and enabled.
pub(super) async fn until_usable(c: &Client, id: &str) {
    until(&format!("#{id} usable"), 20, || async move {
        let e = by_id(c, id).await;
        let ready =
            e.is_displayed().await.unwrap_or(false) && e.is_enabled().await.unwrap_or(false);
        ready.then_some(())
    })
    .await;
}

/// Whether `#id` is shown.
pub(super) async fn shown(c: &Client, id: &str) -> bool {
    by_id(c, id).await.is_displayed().await.unwrap_or(false)
}

/// A manual-stage simulated cell (the technician sets and reads a micrometer) whose base is
/// registered (so every measured pose has a deviation from the nominal model), without the
/// tool-frame step; `extra` is appended to the configuration.
pub(super) fn manual_cell(dir: &Path, extra: &str) -> PathBuf {
    let cfg = fast_config(dir, "manual", 300, 100);
    let text = std::fs::read_to_string(&cfg)
        .expect("config")
        .replace("stage_mode = \"zaber\"", "stage_mode = \"manual\"")
        .replace("tool_frame = true", "tool_frame = false")
        + extra;
    write_config(dir, &text)
}

/// Open the `/?token=` link of `token`: the page signs in as `who` and the token leaves the
/// address bar.
async fn sign_in_as(c: &Client, s: &Server, token: &str, who: &str) {
    c.goto(&format!("{}/?token={token}", s.base))
        .await
        .expect("open the link");
    until(&format!("signed in as {who}"), 20, || async move {
        (text(c, "who").await == who).then_some(())
    })
    .await;
    let url = c.current_url().await.expect("url");
    assert!(!url.as_str().contains("token"), "{url}");
    let stored: Value = c
        .execute("return sessionStorage.getItem('cellcal.token');", vec![])
        .await
        .expect("sessionStorage");
    assert_eq!(stored, Value::String(token.to_owned()));
}

/// Open the printed `/?token=` link (the one-time operator token).
pub(super) async fn sign_in(c: &Client, s: &Server) {
    sign_in_as(c, s, &s.token, "one-time (operator)").await;
}

/// The newest campaign's id, once there is one whose progress the page shows as `0 / poses`.
pub(super) async fn created(c: &Client, s: &Server, poses: usize) -> i64 {
    let id = until("the campaign is created", 30, || async move {
        let (_, list) = get(s, "/api/campaigns");
        list.as_array()
            .and_then(|l| l.last())
            .and_then(|v| v["id"].as_i64())
    })
    .await;
    until_text(c, "progress", &format!("0 / {poses}"), 20).await;
    id
}

/// Create a campaign from the page's form with `poses` and `ident`: its id.
pub(super) async fn create_from_page(c: &Client, s: &Server, poses: usize, ident: usize) -> i64 {
    by_id(c, "create-poses")
        .await
        .send_keys(&poses.to_string())
        .await
        .expect("poses");
    by_id(c, "create-ident")
        .await
        .send_keys(&ident.to_string())
        .await
        .expect("ident");
    click(c, "create").await;
    created(c, s, poses).await
}

/// Arm through the confirmation dialog, then start.
pub(super) async fn arm_and_start(c: &Client) {
    click(c, "cmd-arm").await;
    click(c, "arm-confirm").await;
    until_armed(c).await;
    click(c, "cmd-start").await;
}

pub(super) async fn until_armed(c: &Client) {
    until("armed", 20, || async move {
        text(c, "armed-flag").await.contains("ARMED").then_some(())
    })
    .await;
}

/// How [`answer_all`] answers, beyond typing the expected reading and Enter.
#[derive(Default)]
struct Answering {
    /// Once, at a question about P2: first a reading 0.5 mm off (the re-ask must explain it),
    /// and a screenshot of the prompt panel with the explanation.
    off_once: bool,
    /// Once, at the first reading: Escape (the abort question opens), then Enter on its
    /// focused "No, go back" (the question is still there, the field focused).
    escape_once: bool,
    /// Once `dashboard_after` poses are measured: a screenshot of the whole page.
    dashboard_after: Option<usize>,
}

/// The open question the page shows, once it is shown and is the one the API has open (a new
/// one, not `last`): its API view. `None` when the campaign is done.
async fn next_question(c: &Client, s: &Server, id: i64, last: &Option<String>) -> Option<Value> {
    let started = Instant::now();
    loop {
        if text(c, "campaign-state").await == "done" {
            return None;
        }
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "no question for 60 s"
        );
        let panel = by_id(c, "prompt-panel").await;
        let seq = panel.attr("data-seq").await.expect("data-seq");
        if panel.is_displayed().await.unwrap_or(false) && seq.is_some() && seq != *last {
            let (_, v) = get(s, &format!("/api/campaigns/{id}"));
            if v["prompt"]["seq"].as_u64().map(|n| n.to_string()) == seq {
                return Some(v);
            }
        }
        tokio::time::sleep(Duration::from_millis(30)).await;
    }
}

/// The question's context as the page shows it agrees with the engine's: pose n of N, P1 or
/// P2, and "robot stopped — safe to approach" exactly when the engine says so.
async fn check_context(c: &Client, q: &Value) {
    let context = text(c, "prompt-context").await;
    if let (Some(n), Some(total)) = (q["pose"].as_u64(), q["poses_total"].as_u64()) {
        assert!(
            context.contains(&format!("Pose {n} of {total}")),
            "{context} / {q}"
        );
    }
    if let Some(p) = q["position"].as_str() {
        assert!(context.contains(p), "{context} / {q}");
    }
    let safe = text(c, "prompt-safe").await;
    assert_eq!(
        safe.contains("Robot stopped — safe to approach"),
        q["robot_stopped"] == Value::Bool(true),
        "{safe} / {q}"
    );
}

/// Answer every question of campaign `id` from the keyboard (the focused field, the reading,
/// Enter; a decimal comma every other time) until the page shows `done`; returns how many
/// questions were answered, checking each one's context (see [`check_context`]).
async fn answer_all(c: &Client, s: &Server, id: i64, how: Answering) -> usize {
    let started = Instant::now();
    let (mut answered, mut off_done, mut escape_done, mut shot) = (0usize, false, false, false);
    let (mut clear_checked, mut cleared) = (false, 0usize);
    let mut last_seq = None;
    let mut contexts = Vec::new();
    while let Some(v) = next_question(c, s, id, &last_seq).await {
        assert!(
            started.elapsed() < Duration::from_secs(150),
            "campaign stuck"
        );
        let q = &v["prompt"];
        last_seq = q["seq"].as_u64().map(|n| n.to_string());
        check_context(c, q).await;
        assert_eq!(q["robot_stopped"], Value::Bool(true), "{q}");
        // the visual cue: the tab's title says a question is open
        let title = c.title().await.expect("title");
        assert!(title.contains("Question"), "{title}");
        contexts.push((q["pose"].clone(), q["position"].clone()));
        if let (Some(after), false) = (how.dashboard_after, shot) {
            if v["poses_done"].as_u64().unwrap_or(0) >= after as u64 {
                shot = true;
                dashboard_is_filled(c, s).await;
                c.execute("window.scrollTo(0, 0);", vec![])
                    .await
                    .expect("scroll");
                screenshot(c, "dashboard.png").await;
            }
        }
        let focus = focused_id(c).await;
        if q["id"] == "confirm_clear" {
            confirm_clear_on_page(c, s, id, q, focus.as_deref(), !clear_checked).await;
            clear_checked = true;
            cleared += 1;
            answered += 1;
            continue;
        }
        let Some(expected) = q["expected_mm"].as_f64() else {
            // a confirmation: Enter on the focused Confirm button
            assert_eq!(focus.as_deref(), Some("prompt-confirm"), "{v}");
            keys(c, &ENTER.to_string()).await;
            answered += 1;
            continue;
        };
        let prompt = text(c, "prompt-text").await;
        assert!(prompt.contains("micrometer"), "{prompt}");
        assert_eq!(
            focus.as_deref(),
            Some("prompt-value"),
            "the field has the focus"
        );
        if how.escape_once && !escape_done {
            escape_done = true;
            keys(c, &ESCAPE.to_string()).await;
            until("the abort question", 10, || async move {
                (focused_id(c).await.as_deref() == Some("abort-cancel")).then_some(())
            })
            .await;
            assert!(shown(c, "abort-dialog").await, "Escape asks to abort");
            keys(c, &ENTER.to_string()).await;
            until("back at the reading", 10, || async move {
                (focused_id(c).await.as_deref() == Some("prompt-value")).then_some(())
            })
            .await;
            assert!(!shown(c, "abort-dialog").await);
        }
        let mut reading = format!("{expected:.3}");
        if how.off_once && !off_done && q["position"] == "P2" {
            off_done = true;
            reading = format!("{:.3}", expected + 0.5);
            keys(c, &format!("{reading}{ENTER}")).await;
            answered += 1;
            let v = next_question(c, s, id, &last_seq)
                .await
                .expect("the reading is asked again");
            last_seq = v["prompt"]["seq"].as_u64().map(|n| n.to_string());
            let why = text(c, "prompt-retry").await;
            assert!(
                why.contains(&format!(
                    "The reading {reading} mm, 0.500 mm from the requested {expected:.3} mm"
                )),
                "{why}"
            );
            assert!(
                !text(c, "prompt-text").await.contains("from the requested"),
                "the reason is shown once, apart from the request"
            );
            check_context(c, &v["prompt"]).await;
            screenshot_of(c, "prompt-panel", "prompt.png").await;
            reading = format!("{expected:.3}");
        }
        if answered % 2 == 1 {
            reading = reading.replace('.', ",");
        }
        keys(c, &format!("{reading}{ENTER}")).await;
        answered += 1;
    }
    // before every move after the first pose's answers the cell was confirmed clear
    assert!(cleared >= POSES - 1, "{cleared} confirm_clear questions");
    // the context named every pose and both stage positions
    let poses: std::collections::HashSet<u64> =
        contexts.iter().filter_map(|(p, _)| p.as_u64()).collect();
    assert!(poses.len() >= 2, "{contexts:?}");
    for p in ["P1", "P2"] {
        assert!(contexts.iter().any(|(_, at)| at == p), "{p}: {contexts:?}");
    }
    answered
}

/// A `confirm_clear` question (after a manual stage answer, before the robot moves): the page
/// offers only its own button `prompt-clear`, never focused, and no reading field or Confirm;
/// with `try_enter`, Enter first, which must leave the question open and the robot where it
/// is; then the button releases it.
async fn confirm_clear_on_page(
    c: &Client,
    s: &Server,
    id: i64,
    q: &Value,
    focus: Option<&str>,
    try_enter: bool,
) {
    assert!(shown(c, "prompt-clear").await, "the clear button: {q}");
    assert!(!shown(c, "prompt-confirm").await, "no Confirm: {q}");
    assert!(!shown(c, "prompt-value").await, "no reading: {q}");
    assert_ne!(
        focus,
        Some("prompt-clear"),
        "the clear button is never focused"
    );
    let seq = q["seq"].as_u64().expect("seq");
    if try_enter {
        let done = |v: &Value| v["poses_done"].as_u64();
        let (_, before) = get(s, &format!("/api/campaigns/{id}"));
        keys(c, &ENTER.to_string()).await;
        tokio::time::sleep(Duration::from_millis(400)).await;
        let (_, after) = get(s, &format!("/api/campaigns/{id}"));
        assert_eq!(after["prompt"]["seq"].as_u64(), Some(seq), "Enter: {after}");
        assert_eq!(done(&after), done(&before), "Enter moved nothing: {after}");
        assert!(shown(c, "prompt-clear").await, "still asked after Enter");
        screenshot_of(c, "prompt-panel", "prompt-clear.png").await;
    }
    click(c, "prompt-clear").await;
    until("the cell confirmed clear", 30, || async move {
        let (_, v) = get(s, &format!("/api/campaigns/{id}"));
        (v["prompt"]["seq"].as_u64() != Some(seq)).then_some(())
    })
    .await;
}

/// The dashboard panels while poses are measured: device status as `GET /api/devices` says
/// (its `connection`), the drift reference, the deviation plot with a point
/// per measured pose (matching the API's deviations).
async fn dashboard_is_filled(c: &Client, s: &Server) {
    let (code, devices) = get(s, "/api/devices");
    for name in ["tracker", "robot", "stage"] {
        let row = text(c, &format!("device-{name}")).await;
        let want = match (code, devices[name]["connection"].as_str()) {
            (200, Some("connected")) => "yes",
            (200, Some("fault")) => "NO",
            (200, Some("not_connected_yet")) => "not connected yet",
            (200, Some("closed")) => "closed",
            (200, Some("no_connection")) => "no connection",
            _ => "unknown",
        };
        assert!(row.contains(want), "{name}: {row} (API {code}: {devices})");
        if let Some(identity) = devices[name]["identity"].as_str() {
            assert!(
                row.contains(identity),
                "{name}: {row} (API {code}: {devices})"
            );
        }
    }
    let drift = text(c, "drift-checks").await;
    assert!(drift.contains("reference"), "{drift}");
    let page = c;
    let points = until("points in the deviation plot", 10, || async move {
        let p = by_id(page, "deviation-plot")
            .await
            .attr("data-points")
            .await
            .ok()??;
        let n: usize = p.parse().ok()?;
        (n >= 2).then_some(n)
    })
    .await;
    let circles = c
        .find_all(Locator::Css("#deviation-plot circle"))
        .await
        .expect("circles");
    assert_eq!(circles.len(), points);
    let summary = text(c, "deviation-summary").await;
    assert!(
        summary.contains("mean") && summary.contains("max"),
        "{summary}"
    );
}

/// The verdict and the verify mean after on the page agree with the API's result.
async fn verdict_is_shown(c: &Client, s: &Server, id: i64, poses: usize) {
    until_text(c, "progress", &format!("{poses} / {poses}"), 10).await;
    let quality = until("the verdict", 30, || async move {
        let q = text(c, "quality").await;
        (!q.is_empty() && q != "—").then_some(q)
    })
    .await;
    let after: f64 = text(c, "result-verify-after")
        .await
        .parse()
        .expect("verify mean after is a number");
    let (_, result) = get(s, &format!("/api/campaigns/{id}/result"));
    let want = result["metrics"]["verify"]["after"]["position_mean_mm"]
        .as_f64()
        .expect("verify after");
    // the page shows mm with 3 decimals
    assert!(
        (after - want).abs() <= 5e-4 + 1e-12,
        "page {after}, API {want}"
    );
    // one before: the page names the result's before base, the live deviation's
    assert_eq!(result["before_base"], "setup_registration", "{result}");
    let base = text(c, "result-before-base").await;
    assert!(
        base.contains("the setup's base registration (as the live deviation above)"),
        "{base}"
    );
    match result["quality"].as_str() {
        Some(q) => assert_eq!(quality, q),
        None => assert_eq!(quality, "not given"),
    }
}

/// Every stored `measured` event carries the pose's deviation from the nominal model (the base
/// is registered), and it is |deviation_xyz_mm|.
fn deviations_are_journalled(s: &Server, id: i64, poses: usize) {
    let (_, events) = get(s, &format!("/api/campaigns/{id}/events"));
    let measured: Vec<&Value> = events
        .as_array()
        .expect("events")
        .iter()
        .filter(|e| e["kind"] == "measured")
        .map(|e| &e["event"])
        .collect();
    assert_eq!(measured.len(), poses);
    for m in measured {
        let d = m["deviation_mm"].as_f64().expect("deviation_mm");
        let xyz: Vec<f64> = m["deviation_xyz_mm"]
            .as_array()
            .expect("deviation_xyz_mm")
            .iter()
            .map(|v| v.as_f64().expect("number"))
            .collect();
        let norm = xyz.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!((d - norm).abs() < 1e-9 && d.is_finite(), "{m}");
        // the simulated robot differs from its nominal model by a few tenths of a mm to mm
        assert!(d > 1e-4 && d < 20.0, "{m}");
    }
}

/// 20 poses, 14 for identification: 14 × 6 equations ≥ 3 × 28 parameters (OP with base), the
/// fewest a campaign accepts; 40 stage questions and a few more.
const POSES: usize = 20;
const IDENT: usize = 14;

/// `serve` on a manual-stage cell in a new directory and a browser signed in with the
/// printed link (the directory lives as long as the server).
async fn signed_in_on_a_manual_cell(driver: &Driver) -> (tempfile::TempDir, Server, Client) {
    let dir = tempfile::tempdir().expect("tempdir");
    let s = start(&manual_cell(dir.path(), ""), &dir.path().join("c.db"));
    let c = browser(driver).await;
    sign_in(&c, &s).await;
    (dir, s, c)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_runs_a_manual_campaign_with_its_dashboard() {
    let Some(driver) = chromedriver() else { return };
    let (_dir, s, c) = signed_in_on_a_manual_cell(&driver).await;
    let id = create_from_page(&c, &s, POSES, IDENT).await;
    // the audible cue on: a beep for every question
    click(&c, "sound-toggle").await;
    arm_and_start(&c).await;
    let how = Answering {
        off_once: true,
        dashboard_after: Some(6),
        ..Answering::default()
    };
    let answered = answer_all(&c, &s, id, how).await;
    assert!(answered > 2 * POSES, "{answered} questions answered");
    verdict_is_shown(&c, &s, id, POSES).await;
    deviations_are_journalled(&s, id, POSES);
    let beeps: usize = by_id(&c, "prompt-panel")
        .await
        .attr("data-beeps")
        .await
        .expect("attr")
        .and_then(|n| n.parse().ok())
        .unwrap_or(0);
    assert!(beeps >= 2 * POSES, "{beeps} beeps for {answered} questions");
    // tall enough for the whole result view
    c.set_window_size(1280, 2600).await.expect("window size");
    screenshot_from(&c, "result-view", "result.png").await;
    // the whole campaign without a console error (the page's icon asks for nothing)
    let errors = console_errors(&c, &driver).await;
    assert!(errors.is_empty(), "console errors: {errors:#?}");
    c.close().await.expect("close");
}

/// The create form chooses the campaign's non-geometric terms: they are its own, stored with
/// its configuration (what `identify --store`, the report and a resume read).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_creates_a_campaign_with_the_terms_chosen() {
    let Some(driver) = chromedriver() else { return };
    let (dir, s, c) = signed_in_on_a_manual_cell(&driver).await;
    let stored_terms = |id: i64| {
        let row = cellcal::store::Store::open_reader(&dir.path().join("c.db"))
            .expect("store")
            .campaign(id)
            .expect("row");
        let cfg = cellcal::config::parse_cell_config(&row.config_toml, Path::new("stored"))
            .expect("the stored configuration parses");
        cfg.campaign.nongeometric
    };
    use cellcal::model::TermFamily::{Compliance, Harmonics};
    for (field, n) in [("create-poses", POSES), ("create-ident", IDENT)] {
        by_id(&c, field)
            .await
            .send_keys(&n.to_string())
            .await
            .expect("count");
    }
    screenshot_from(&c, "create-form", "create-form.png").await;
    for (choice, want) in [
        ("compliance,harmonics", vec![Compliance, Harmonics]),
        ("harmonics", vec![Harmonics]),
    ] {
        by_id(&c, "create-nongeometric")
            .await
            .select_by_value(choice)
            .await
            .expect("terms");
        let before = get(&s, "/api/campaigns").1.as_array().map_or(0, Vec::len);
        click(&c, "create").await;
        let server = &s;
        let id = until("the campaign is created", 30, || async move {
            let (_, list) = get(server, "/api/campaigns");
            let list = list.as_array()?;
            (list.len() > before).then(|| list.last()?["id"].as_i64())?
        })
        .await;
        assert_eq!(stored_terms(id), want, "{choice}");
        // one campaign on the cell at a time: this one ends (once loaded) before the next
        let commands = format!("/api/campaigns/{id}/commands");
        let (server, commands) = (&s, &commands);
        until("the campaign aborted", 30, || async move {
            let (code, _) = super::serve::post(server, commands, r#"{"command": "abort"}"#);
            (code == 200).then_some(())
        })
        .await;
    }
    c.close().await.expect("close");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_is_usable_with_the_keyboard_alone() {
    let Some(driver) = chromedriver() else { return };
    let (_dir, s, c) = signed_in_on_a_manual_cell(&driver).await;
    // create: Tab to the fields, type, Enter submits the form
    tab_to(&c, "create-poses").await;
    keys(&c, &POSES.to_string()).await;
    tab_to(&c, "create-ident").await;
    keys(&c, &format!("{IDENT}{ENTER}")).await;
    let id = created(&c, &s, POSES).await;
    // arm: Enter opens the confirmation with "Cancel" focused; Escape closes it unarmed
    until_usable(&c, "cmd-arm").await;
    tab_to(&c, "cmd-arm").await;
    keys(&c, &ENTER.to_string()).await;
    let page = &c;
    until("the arm question", 10, || async move {
        (focused_id(page).await.as_deref() == Some("arm-cancel")).then_some(())
    })
    .await;
    keys(&c, &ESCAPE.to_string()).await;
    until("the arm question closed", 10, || async move {
        (!shown(page, "arm-dialog").await).then_some(())
    })
    .await;
    let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
    assert_eq!(v["armed"], Value::Bool(false), "Escape did not arm: {v}");
    // again, and this time Tab to "Yes, arm" and Enter
    tab_to(&c, "cmd-arm").await;
    keys(&c, &ENTER.to_string()).await;
    tab_to(&c, "arm-confirm").await;
    keys(&c, &ENTER.to_string()).await;
    until_armed(&c).await;
    until_usable(&c, "cmd-start").await;
    tab_to(&c, "cmd-start").await;
    keys(&c, &ENTER.to_string()).await;
    let how = Answering {
        escape_once: true,
        ..Answering::default()
    };
    let answered = answer_all(&c, &s, id, how).await;
    assert!(answered >= 2 * POSES, "{answered} questions answered");
    verdict_is_shown(&c, &s, id, POSES).await;
    c.close().await.expect("close");
}

/// Which of the page's controls are offered (shown) now.
async fn offered(c: &Client) -> Vec<&'static str> {
    let mut on = Vec::new();
    for id in [
        "create-form",
        "cmd-arm",
        "cmd-disarm",
        "cmd-start",
        "cmd-pause",
        "cmd-resume",
        "prompt-value",
        "prompt-confirm",
        "prompt-clear",
        "prompt-abort",
        "abort",
    ] {
        if shown(c, id).await {
            on.push(id);
        }
    }
    on
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_offers_each_role_only_what_it_may_do() {
    let Some(driver) = chromedriver() else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = manual_cell(dir.path(), &role_tokens());
    let s = start_as_operator(&cfg, &dir.path().join("c.db"));
    // the operator creates, arms and starts over REST; the first question opens
    let (code, v) = post_as(
        &s,
        "operator-token",
        "/api/campaigns",
        &format!(r#"{{"poses": {POSES}, "ident": {IDENT}}}"#),
    );
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_i64().expect("id");
    let path = format!("/api/campaigns/{id}/commands");
    for cmd in ["arm", "start"] {
        let (code, v) = post_as(
            &s,
            "operator-token",
            &path,
            &format!(r#"{{"command": "{cmd}"}}"#),
        );
        assert_eq!(code, 200, "{cmd}: {v}");
    }
    let server = &s;
    until("the first question", 60, || async move {
        let (_, v) = get(server, &format!("/api/campaigns/{id}"));
        v["prompt"]["seq"].as_u64()
    })
    .await;
    let c = browser(&driver).await;

    // a viewer sees the question and its context, and may only abort
    sign_in_as(&c, &s, "viewer-token", "viewer one (viewer)").await;
    let page = &c;
    until("the question on the viewer's page", 20, || async move {
        shown(page, "prompt-panel").await.then_some(())
    })
    .await;
    assert!(text(&c, "prompt-context").await.contains("question"));
    assert_eq!(offered(&c).await, ["prompt-abort", "abort"], "viewer");
    screenshot(&c, "viewer.png").await;

    // a technician may answer (and pause, resume), not create, arm or start
    c.execute("sessionStorage.clear();", vec![])
        .await
        .expect("sign out");
    sign_in_as(&c, &s, "technician-token", "technician one (technician)").await;
    until("the question on the technician's page", 20, || async move {
        shown(page, "prompt-value").await.then_some(())
    })
    .await;
    let on = offered(&c).await;
    for id in [
        "prompt-value",
        "prompt-confirm",
        "prompt-abort",
        "abort",
        "cmd-pause",
    ] {
        assert!(on.contains(&id), "technician offered {id}: {on:?}");
    }
    for id in ["create-form", "cmd-arm", "cmd-disarm", "cmd-start"] {
        assert!(!on.contains(&id), "technician not offered {id}: {on:?}");
    }
    // and the answer goes through: the technician's typed reading moves the campaign on
    let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
    let seq = v["prompt"]["seq"].as_u64().expect("seq");
    let expected = v["prompt"]["expected_mm"].as_f64().expect("a reading");
    assert_eq!(focused_id(&c).await.as_deref(), Some("prompt-value"));
    keys(&c, &format!("{expected:.3}{ENTER}")).await;
    until("the answer taken", 30, || async move {
        let (_, v) = get(server, &format!("/api/campaigns/{id}"));
        (v["prompt"]["seq"].as_u64() != Some(seq)).then_some(())
    })
    .await;
    let (code, _) = post_as(&s, "operator-token", &path, r#"{"command": "abort"}"#);
    assert_eq!(code, 200);
    c.close().await.expect("close");
}

/// A Zaber-stage campaign (it runs without questions) created, armed and started from the
/// page of an operator, once 3 poses are measured; then `button` is clicked and the page must
/// show `state`. The directory, the daemon, the page, the campaign id and the poses measured
/// (the same 800 ms later: nothing measured after the click).
async fn click_while_running(
    driver: &Driver,
    button: &str,
    state: &str,
) -> (tempfile::TempDir, Server, Client, i64, u64) {
    let dir = tempfile::tempdir().expect("tempdir");
    let s = start(
        &fast_config(dir.path(), "serial", 300, 100),
        &dir.path().join("c.db"),
    );
    let c = browser(driver).await;
    sign_in(&c, &s).await;
    let id = create_from_page(&c, &s, 300, 100).await;
    arm_and_start(&c).await;
    let server = &s;
    until("poses measured", 60, || async move {
        let (_, v) = get(server, &format!("/api/campaigns/{id}"));
        (v["poses_done"].as_u64().unwrap_or(0) >= 3).then_some(())
    })
    .await;
    click(&c, button).await;
    until_text(&c, "campaign-state", state, 20).await;
    let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
    let done = v["poses_done"].as_u64().expect("poses done");
    assert!(done < 300, "stopped before the end: {v}");
    tokio::time::sleep(Duration::from_millis(800)).await;
    let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
    assert_eq!(
        v["poses_done"].as_u64(),
        Some(done),
        "nothing measured after {button}: {v}"
    );
    assert_eq!(v["state"], state, "{v}");
    (dir, s, c, id, done)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_abort_stops_a_running_campaign() {
    let Some(driver) = chromedriver() else { return };
    let (_dir, _s, c, _, _) = click_while_running(&driver, "abort", "aborted").await;
    c.close().await.expect("close");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_disarm_stops_and_pauses_a_running_campaign() {
    let Some(driver) = chromedriver() else { return };
    let (_dir, s, c, id, _) = click_while_running(&driver, "cmd-disarm", "paused").await;
    let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
    assert_eq!(v["armed"], Value::Bool(false), "{v}");
    // the engine told the robot and the stage to stop
    let (_, journal) = get(&s, &format!("/api/campaigns/{id}/events"));
    let stopped = journal
        .as_array()
        .expect("journal")
        .iter()
        .any(|e| e["kind"] == "stopped" && e["event"]["reason"] == "disarm");
    assert!(stopped, "a `stopped` event for the disarm");
    // resuming is not offered while disarmed
    assert!(!by_id(&c, "cmd-resume")
        .await
        .is_enabled()
        .await
        .expect("enabled"));
    c.close().await.expect("close");
}
