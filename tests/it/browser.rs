//! The cockpit web page in a real headless Chromium driven over WebDriver (fantoccini, Debian's
//! `chromedriver`) against the real `cellcal serve` binary on a simulated cell: the printed token
//! link signs in, a campaign is created with overrides, armed (confirmed), started, every
//! technician question answered from the keyboard alone, and the verdict shown; the page's
//! Abort stops a running campaign. Screenshots go to `target/screenshots/`.
//!
//! Without `chromedriver` the tests skip with a loud message, unless `CELLCAL_REQUIRE_BROWSER=1`
//! (set by `.ci/run`), where they fail.

use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use fantoccini::elements::Element;
use fantoccini::{Client, ClientBuilder, Locator};
use serde_json::{json, Value};

use super::campaign::write_config;
use super::serve::{fast_config, get, start, Server};

/// Env var: `1` makes a missing chromedriver a failure instead of a skip.
const REQUIRE_ENV: &str = "CELLCAL_REQUIRE_BROWSER";
/// WebDriver's key code of Enter.
const ENTER: &str = "\u{E007}";

/// A running chromedriver, killed on drop.
struct Driver {
    child: Child,
    url: String,
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
fn chromedriver() -> Option<Driver> {
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
async fn browser(driver: &Driver) -> Client {
    let mut options = json!({
        "args": ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                 "--window-size=1280,1100"]
    });
    if Path::new("/usr/bin/chromium").is_file() {
        options["binary"] = json!("/usr/bin/chromium");
    }
    let mut caps = serde_json::Map::new();
    caps.insert("goog:chromeOptions".into(), options);
    ClientBuilder::new(hyper_util::client::legacy::connect::HttpConnector::new())
        .capabilities(caps)
        .connect(&driver.url)
        .await
        .expect("WebDriver session")
}

/// Poll `probe` every 50 ms until it gives `Some`, at most `secs` seconds.
async fn until<T, F, Fut>(what: &str, secs: u64, mut probe: F) -> T
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

async fn by_id(c: &Client, id: &str) -> Element {
    c.find(Locator::Id(id))
        .await
        .unwrap_or_else(|e| panic!("#{id}: {e}"))
}

/// The visible text of `#id` ("" when hidden).
async fn text(c: &Client, id: &str) -> String {
    by_id(c, id).await.text().await.unwrap_or_default()
}

/// Wait until `#id` shows `want`.
async fn until_text(c: &Client, id: &str, want: &str, secs: u64) {
    until(&format!("#{id} = {want}"), secs, || async move {
        (text(c, id).await == want).then_some(())
    })
    .await;
}

/// Click `#id` once it is shown and enabled.
async fn click(c: &Client, id: &str) {
    let e = until(&format!("#{id} clickable"), 20, || async move {
        let e = by_id(c, id).await;
        let ready =
            e.is_displayed().await.unwrap_or(false) && e.is_enabled().await.unwrap_or(false);
        ready.then_some(e)
    })
    .await;
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

async fn screenshot(c: &Client, name: &str) -> PathBuf {
    let png = c.screenshot().await.expect("screenshot");
    assert!(png.starts_with(b"\x89PNG"), "a PNG");
    let p = screenshot_dir().join(name);
    std::fs::write(&p, png).expect("write screenshot");
    eprintln!("screenshot: {}", p.display());
    p
}

/// A manual-stage simulated cell (the technician sets and reads a micrometer), no setup step.
fn manual_cell(dir: &Path) -> PathBuf {
    let cfg = fast_config(dir, "manual", 300, 100);
    let text = std::fs::read_to_string(&cfg)
        .expect("config")
        .replace("stage_mode = \"zaber\"", "stage_mode = \"manual\"")
        .replace("tool_frame = true", "tool_frame = false")
        .replace("base_registration = true", "base_registration = false");
    write_config(dir, &text)
}

/// Open the printed `/?token=` link: the page signs in and the token leaves the address bar.
async fn sign_in(c: &Client, s: &Server) {
    c.goto(&format!("{}/?token={}", s.base, s.token))
        .await
        .expect("open the link");
    until("signed in", 20, || async move {
        (!text(c, "who").await.is_empty()).then_some(())
    })
    .await;
    assert_eq!(text(c, "who").await, "one-time (operator)");
    let url = c.current_url().await.expect("url");
    assert!(!url.as_str().contains("token"), "{url}");
    let stored: Value = c
        .execute("return sessionStorage.getItem('cellcal.token');", vec![])
        .await
        .expect("sessionStorage");
    assert_eq!(stored, Value::String(s.token.clone()));
}

/// Create a campaign from the page's form with `poses` and `ident`: its id.
async fn create_from_page(c: &Client, s: &Server, poses: usize, ident: usize) -> i64 {
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

/// Arm through the confirmation dialog, then start.
async fn arm_and_start(c: &Client) {
    click(c, "cmd-arm").await;
    click(c, "arm-confirm").await;
    until("armed", 20, || async move {
        text(c, "armed-flag").await.contains("ARMED").then_some(())
    })
    .await;
    click(c, "cmd-start").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_runs_a_manual_campaign_from_the_keyboard() {
    let Some(driver) = chromedriver() else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let s = start(&manual_cell(dir.path()), &dir.path().join("c.db"));
    let c = browser(&driver).await;
    sign_in(&c, &s).await;
    let (poses, ident) = (20, 14);
    let id = create_from_page(&c, &s, poses, ident).await;
    screenshot(&c, "dashboard.png").await;
    arm_and_start(&c).await;

    // every question: the reading typed into the focused field, Enter; commas every other time
    let started = Instant::now();
    let mut answered = 0usize;
    let mut last_seq = None;
    loop {
        if text(&c, "campaign-state").await == "done" {
            break;
        }
        assert!(
            started.elapsed() < Duration::from_secs(120),
            "campaign stuck"
        );
        let panel = by_id(&c, "prompt-panel").await;
        let seq = panel.attr("data-seq").await.expect("data-seq");
        if !panel.is_displayed().await.unwrap_or(false) || seq.is_none() || seq == last_seq {
            tokio::time::sleep(Duration::from_millis(30)).await;
            continue;
        }
        let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
        if v["prompt"]["seq"].as_u64().map(|n| n.to_string()) != seq {
            tokio::time::sleep(Duration::from_millis(30)).await;
            continue;
        }
        let context = text(&c, "prompt-context").await;
        assert!(context.contains(&format!("of {poses}")), "{context}");
        let focused = c.active_element().await.expect("focused element");
        let focus = focused.attr("id").await.expect("id");
        let Some(expected) = v["prompt"]["expected_mm"].as_f64() else {
            // a confirmation: Enter on the focused Confirm button
            assert_eq!(focus.as_deref(), Some("prompt-confirm"), "{v}");
            focused.send_keys(ENTER).await.expect("confirm");
            answered += 1;
            last_seq = seq;
            continue;
        };
        let prompt = text(&c, "prompt-text").await;
        assert!(prompt.contains("micrometer"), "{prompt}");
        assert_eq!(
            focus.as_deref(),
            Some("prompt-value"),
            "the field has the focus"
        );
        if answered == 0 {
            screenshot(&c, "prompt.png").await;
        }
        let mut reading = format!("{expected:.3}");
        if answered % 2 == 1 {
            reading = reading.replace('.', ",");
        }
        focused
            .send_keys(&format!("{reading}{ENTER}"))
            .await
            .expect("type the reading");
        answered += 1;
        last_seq = seq;
    }
    assert!(answered >= 2 * poses, "{answered} questions answered");
    until_text(&c, "progress", &format!("{poses} / {poses}"), 10).await;
    let page = &c;
    let quality = until("the verdict", 30, || async move {
        let q = text(page, "quality").await;
        (!q.is_empty() && q != "—").then_some(q)
    })
    .await;
    let after: f64 = text(&c, "result-verify-after")
        .await
        .parse()
        .expect("verify mean after is a number");
    let (_, result) = get(&s, &format!("/api/campaigns/{id}/result"));
    let want = result["metrics"]["verify"]["after"]["position_mean_mm"]
        .as_f64()
        .expect("verify after");
    assert!((after - want).abs() < 1e-4, "page {after}, API {want}");
    match result["quality"].as_str() {
        Some(q) => assert_eq!(quality, q),
        None => assert_eq!(quality, "not given"),
    }
    c.find(Locator::Id("result-view"))
        .await
        .expect("result view")
        .click()
        .await
        .ok();
    screenshot(&c, "result.png").await;
    c.close().await.expect("close");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_abort_stops_a_running_campaign() {
    let Some(driver) = chromedriver() else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    // the Zaber stage: the campaign runs without questions until aborted
    let s = start(
        &fast_config(dir.path(), "serial", 300, 100),
        &dir.path().join("c.db"),
    );
    let c = browser(&driver).await;
    sign_in(&c, &s).await;
    let id = create_from_page(&c, &s, 300, 100).await;
    arm_and_start(&c).await;
    let server = &s;
    until("poses measured", 60, || async move {
        let (_, v) = get(server, &format!("/api/campaigns/{id}"));
        (v["poses_done"].as_u64().unwrap_or(0) >= 3).then_some(())
    })
    .await;
    click(&c, "abort").await;
    until_text(&c, "campaign-state", "aborted", 20).await;
    let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
    let done = v["poses_done"].as_u64().expect("poses done");
    assert!(done < 300, "aborted before the end: {v}");
    tokio::time::sleep(Duration::from_millis(800)).await;
    let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
    assert_eq!(
        v["poses_done"].as_u64(),
        Some(done),
        "nothing measured after the abort"
    );
    assert_eq!(v["state"], "aborted");
    c.close().await.expect("close");
}
