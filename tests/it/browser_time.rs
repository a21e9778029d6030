//! The page says how long a campaign takes (issue 20 item 1), in a real headless Chromium
//! against the real `cellcal serve` on a simulated cell: before arming `#campaign-estimate`
//! shows the stored estimate's summary exactly as the REST view carries it; while the campaign
//! runs (here: paused by the page) `#campaign-time` shows the measuring time against the
//! planned one with the plan's time left and the paused time; once done, planned against actual
//! with their ratio, as the REST view's numbers formatted by the page's one formatter.
//! Screenshots of the dashboard before arming, paused and done go to `target/screenshots/`.

use std::time::Duration;

use cellcal::units::human::fmt_duration;
use serde_json::Value;

use super::browser::{
    arm_and_start, browser, chromedriver, click, console_errors, create_from_page, screenshot_from,
    sign_in, text, until, until_text,
};
use super::serve::{fast_config, get, start};

/// `fmt_duration` of `s` seconds: the rule `human.duration` of the page follows.
fn duration(s: f64) -> String {
    fmt_duration(Duration::from_secs_f64(s))
}

fn seconds(v: &Value, key: &str) -> f64 {
    v[key].as_f64().unwrap_or_else(|| panic!("{key} in {v}"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_shows_the_estimate_before_arming_and_planned_against_actual_after() {
    let Some(driver) = chromedriver() else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let s = start(
        &fast_config(dir.path(), "serial", 300, 100),
        &dir.path().join("c.db"),
    );
    let c = browser(&driver).await;
    sign_in(&c, &s).await;
    let (poses, ident) = (40, 20);
    let id = create_from_page(&c, &s, poses, ident).await;
    let (_, view) = get(&s, &format!("/api/campaigns/{id}"));
    let estimate = view["estimate"].clone();
    let summary = estimate["summary"]
        .as_str()
        .expect("an estimate")
        .to_owned();
    assert!(
        summary.starts_with(&format!("{poses} poses, ")),
        "{summary}"
    );
    // before arming: the summary, nothing measured yet
    assert_eq!(view["armed"], Value::Bool(false), "{view}");
    until_text(&c, "campaign-estimate", &summary, 10).await;
    assert_eq!(text(&c, "campaign-time").await, "");
    screenshot_from(&c, "dashboard", "time-before-arming-1280x1800.png").await;

    // while it runs: paused by the page after a few poses
    arm_and_start(&c).await;
    let server = &s;
    until("poses measured", 60, || async move {
        let (_, v) = get(server, &format!("/api/campaigns/{id}"));
        (v["poses_done"].as_u64().unwrap_or(0) >= 3).then_some(())
    })
    .await;
    click(&c, "cmd-pause").await;
    until_text(&c, "campaign-state", "paused", 20).await;
    let total = seconds(&estimate, "total_s");
    let running = until("the time while paused", 10, || async {
        let t = text(&c, "campaign-time").await;
        t.contains("paused").then_some(t)
    })
    .await;
    let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
    let measured = seconds(&v, "measuring_s");
    assert!(measured > 0.0, "{v}");
    let want = format!(
        "measuring {} of about {} planned · about ",
        duration(measured),
        duration(total)
    );
    assert!(running.starts_with(&want), "{running:?}, want {want:?}…");
    assert!(running.contains(" left by the plan · paused "), "{running}");
    assert_eq!(text(&c, "campaign-estimate").await, summary);
    screenshot_from(&c, "dashboard", "time-paused-1280x1800.png").await;

    // after: planned against actual, as the REST view says
    click(&c, "cmd-resume").await;
    until_text(&c, "campaign-state", "done", 120).await;
    // the page's line and the REST view, read together until they agree: the page may show
    // "done" a moment before the view's final times, or the other way round
    let page = &c;
    let want = until(
        "planned against actual, as the REST view says",
        10,
        || async move {
            let (_, done) = get(server, &format!("/api/campaigns/{id}"));
            let (measuring, paused) = (seconds(&done, "measuring_s"), seconds(&done, "paused_s"));
            let want = format!(
                "planned {}, took {} measuring ({:.2} × planned) · paused {}",
                duration(total),
                duration(measuring),
                measuring / total,
                duration(paused)
            );
            (text(page, "campaign-time").await == want).then_some(want)
        },
    )
    .await;
    assert_eq!(text(&c, "campaign-estimate").await, summary);
    screenshot_from(&c, "dashboard", "time-done-1280x1800.png").await;
    eprintln!("page: {summary}; {want}");
    let errors = console_errors(&c, &driver).await;
    assert!(errors.is_empty(), "console errors: {errors:#?}");
    c.close().await.expect("close");
}
