//! The cockpit's HTTP side without a browser: the page and its assets reachable without a token
//! (behind the `Host` check), `GET /api/whoami`, and the OpenAPI document (served, complete, and
//! equal to the committed snapshot `tests/snapshots/openapi.json`; regenerate it with
//! `CELLCAL_UPDATE_SNAPSHOTS=1 cargo test --test it cockpit::`).

use serde_json::Value;
use std::path::Path;

use super::serve::{agent, fast_config, get, start, Server};

/// Env var: `1` rewrites the snapshot instead of comparing with it.
const UPDATE_ENV: &str = "CELLCAL_UPDATE_SNAPSHOTS";

/// A GET without a token: status, content type, body text.
fn get_anonymous(s: &Server, path: &str) -> (u16, String, String) {
    super::serve::get_text(s, path, None)
}

#[test]
fn the_page_needs_no_token_but_the_api_does() {
    let dir = tempfile::tempdir().expect("tempdir");
    let s = start(
        &fast_config(dir.path(), "serial", 300, 100),
        &dir.path().join("c.db"),
    );
    for (path, ct) in [
        ("/", "text/html"),
        ("/index.html", "text/html"),
        ("/?token=abc", "text/html"),
        ("/app.js", "text/javascript"),
        ("/human.js", "text/javascript"),
        ("/app.css", "text/css"),
    ] {
        let (code, got, body) = get_anonymous(&s, path);
        assert_eq!(code, 200, "{path}: {body}");
        assert!(got.starts_with(ct), "{path}: {got}");
        assert!(!body.is_empty());
    }
    let (_, _, page) = get_anonymous(&s, "/");
    for id in [
        "campaign-state",
        "progress",
        "prompt-text",
        "prompt-value",
        "prompt-confirm",
        "prompt-abort",
        "abort",
        "quality",
    ] {
        assert!(page.contains(&format!("id=\"{id}\"")), "#{id} missing");
    }
    // the API itself still needs the token; a foreign Host is refused for the page too
    let (code, _, body) = get_anonymous(&s, "/api/campaigns");
    assert_eq!(code, 401, "{body}");
    let (code, _, body) = get_anonymous(&s, "/api/whoami");
    assert_eq!(code, 401, "{body}");
    let addr = s.base.strip_prefix("http://").expect("http");
    let mut r = agent()
        .get(&format!("{}/", s.base))
        .header(
            "host",
            &format!("evil.example:{}", addr.rsplit(':').next().expect("port")),
        )
        .call()
        .expect("GET");
    assert_eq!(r.status().as_u16(), 421);
    let v: Value = r.body_mut().read_json().expect("JSON error");
    assert!(
        v["error"].as_str().expect("error").contains("evil.example"),
        "{v}"
    );

    let (code, me) = get(&s, "/api/whoami");
    assert_eq!(code, 200, "{me}");
    assert_eq!(me["role"], "operator");
    assert_eq!(me["name"], "one-time");
    assert!(me["may"]
        .as_array()
        .expect("may")
        .contains(&Value::from("arm")));

    // no campaign question open: 204; a campaign that does not exist: 404
    let (code, v) = super::serve::post(&s, "/api/campaigns", "{}");
    assert_eq!(code, 201, "{v}");
    let r = agent()
        .get(&format!("{}/api/campaigns/{}/prompt", s.base, v["id"]))
        .header("authorization", &format!("Bearer {}", s.token))
        .call()
        .expect("GET prompt");
    assert_eq!(r.status().as_u16(), 204);
    assert_eq!(get(&s, "/api/campaigns/99/prompt").0, 404);

    // the served description is the generated one
    let (code, ct, body) = get_anonymous(&s, "/api/openapi.json");
    assert_eq!(code, 200, "{body}");
    assert!(ct.starts_with("application/json"), "{ct}");
    let served: Value = serde_json::from_str(&body).expect("JSON");
    let generated: Value =
        serde_json::from_str(&cellcal::api::openapi::document()).expect("document");
    assert_eq!(served, generated);
}

#[test]
fn the_openapi_document_describes_every_route_error_and_the_bearer_scheme() {
    let doc: Value = serde_json::from_str(&cellcal::api::openapi::document()).expect("JSON");
    assert!(
        doc["openapi"].as_str().expect("version").starts_with("3.1"),
        "{}",
        doc["openapi"]
    );
    let scheme = &doc["components"]["securitySchemes"]["bearer"];
    assert_eq!(
        (scheme["type"].as_str(), scheme["scheme"].as_str()),
        (Some("http"), Some("bearer"))
    );
    let paths = doc["paths"].as_object().expect("paths");
    for (path, method) in [
        ("/", "get"),
        ("/app.js", "get"),
        ("/human.js", "get"),
        ("/app.css", "get"),
        ("/api/health", "get"),
        ("/api/openapi.json", "get"),
        ("/api/whoami", "get"),
        ("/api/campaigns", "get"),
        ("/api/campaigns", "post"),
        ("/api/campaigns/{id}", "get"),
        ("/api/campaigns/{id}/commands", "post"),
        ("/api/campaigns/{id}/events", "get"),
        ("/api/campaigns/{id}/stream", "get"),
        ("/api/campaigns/{id}/result", "get"),
        ("/api/campaigns/{id}/model", "get"),
        ("/api/campaigns/{id}/report", "get"),
        ("/api/campaigns/{id}/prompt", "get"),
        ("/api/campaigns/{id}/measurements", "get"),
        ("/api/campaigns/{id}/plan", "get"),
        ("/api/devices", "get"),
        ("/api/cell/stop", "post"),
        ("/metrics", "get"),
    ] {
        let op = &paths
            .get(path)
            .unwrap_or_else(|| panic!("{path} undocumented"))[method];
        assert!(op.is_object(), "{method} {path} undocumented");
        let responses = op["responses"].as_object().expect("responses");
        for (status, r) in responses {
            if status.starts_with('4') || status.starts_with('5') {
                let schema = &r["content"]["application/json"]["schema"]["$ref"];
                assert_eq!(
                    schema.as_str(),
                    Some("#/components/schemas/ErrorBody"),
                    "{method} {path} {status}"
                );
            }
        }
        let public = op["security"].as_array().is_some_and(|s| {
            s.iter()
                .all(|r| r.as_object().is_some_and(|o| o.is_empty()))
        });
        if !public {
            assert!(responses.contains_key("401"), "{method} {path}: no 401");
        }
    }
    assert!(
        paths.len() == 21,
        "documented paths: {:?}",
        paths.keys().collect::<Vec<_>>()
    );
}

#[test]
fn the_openapi_document_matches_its_snapshot() {
    let doc = cellcal::api::openapi::document();
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/snapshots/openapi.json");
    if std::env::var(UPDATE_ENV).is_ok_and(|v| v == "1") {
        std::fs::create_dir_all(path.parent().expect("dir")).expect("mkdir");
        std::fs::write(&path, format!("{doc}\n")).expect("write snapshot");
        return;
    }
    let want = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{}: {e}; create it with {UPDATE_ENV}=1", path.display()));
    assert!(
        doc.trim_end() == want.trim_end(),
        "the API description changed: review it, then regenerate {} with {UPDATE_ENV}=1 \
         cargo test --test it cockpit::",
        path.display()
    );
}
