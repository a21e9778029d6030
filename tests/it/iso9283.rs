//! ISO 9283 pose accuracy and repeatability campaigns on the simulated cell (the real
//! protocols, the world's hidden truth): the uncompensated robot's AP is its error, RP is the
//! cell's jitter and noise, targets compensated by a calibration's corrected model bring AP
//! down; `cellcal iso9283` recomputes the stored figures from the store alone. The
//! hand-computed case is the unit test `iso9283::tests::hand_computed_case`.

use std::path::Path;
use std::sync::Arc;

use cellcal::campaign::stored::stored_model_toml;
use cellcal::campaign::Outcome;
use cellcal::cell::ScriptedPrompter;
use cellcal::iso9283::{format_table, IsoReport};
use cellcal::store::Store;

use crate::campaign::{config_text, run_in_process, run_with};
use crate::cli::cellcal;

/// The `[iso9283]` table of these tests: 3 cycles on a cube the TX60 reaches with one
/// orientation.
fn iso_table(compensated: Option<&Path>) -> String {
    let mut t = "\n[iso9283]\ncycles = 3\ncube_center_mm = [400.0, 0.0, 400.0]\n\
                 cube_edge_mm = 200.0\napproach_mm = 20.0\n"
        .to_owned();
    if let Some(p) = compensated {
        t.push_str(&format!("compensated_model = \"{}\"\n", p.display()));
    }
    t
}

/// Run the ISO campaign of `text` in a fresh folder; its report and store.
fn run_iso(rt: &tokio::runtime::Runtime, text: &str) -> (IsoReport, std::path::PathBuf, i64) {
    let dir = tempfile::tempdir().expect("tempdir").keep();
    let (ctx, sim, outcome) =
        rt.block_on(run_with(&dir, text, Arc::new(ScriptedPrompter::exact())));
    if let Some(sim) = sim {
        rt.block_on(sim.stop());
    }
    let Outcome::Iso(report) = outcome else {
        panic!("the ISO campaign did not finish: {outcome:?}");
    };
    (*report, dir.join("c.db"), ctx.campaign_id)
}

fn max_of(r: &IsoReport, f: impl Fn(&cellcal::iso9283::PoseFigures) -> f64) -> f64 {
    r.poses.iter().map(f).fold(0.0, f64::max)
}

#[test]
fn iso_campaigns_on_the_simulated_cell_uncompensated_and_compensated() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    let base = config_text("", "", "");

    // uncompensated: AP is the robot's (and the design tool's) error, RP the cell's noise
    let (plain, store, id) = run_iso(&rt, &format!("{base}{}", iso_table(None)));
    print!("uncompensated\n{}", format_table(&plain));
    assert_eq!(plain.kind, "iso9283");
    assert_eq!((plain.cycles_complete, plain.partial), (3, false));
    assert_eq!(plain.poses.len(), 5);
    assert!(plain
        .poses
        .iter()
        .all(|p| p.n == 3 && p.ap_dir_deg.is_some()));
    let ap_plain = max_of(&plain, |p| p.ap_p_mm);
    assert!(
        (0.2..3.0).contains(&ap_plain),
        "uncompensated AP_P up to {ap_plain} mm"
    );
    let rp = max_of(&plain, |p| p.rp_l_mm);
    assert!(rp < 0.1, "RP_l up to {rp} mm");
    assert!(plain.frame.contains("base registration"), "{}", plain.frame);

    // the stored result, recomputed by `cellcal iso9283` from the store alone (same text)
    let stored = Store::open(&store)
        .unwrap()
        .latest_result(id)
        .unwrap()
        .expect("stored result");
    assert_eq!(stored, serde_json::to_string_pretty(&plain).unwrap());
    let json = store.with_file_name("iso.json");
    let out = cellcal()
        .args(["iso9283", "--store"])
        .arg(&store)
        .args(["--campaign", &id.to_string(), "--json"])
        .arg(&json)
        .output()
        .unwrap();
    assert!(out.status.success(), "{out:?}");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("AP_P mm") && text.contains("P5"), "{text}");
    // people's units: mm and mrad with 3 decimals (the JSON keeps mm and deg)
    assert!(text.contains("AP_dir mrad RP_dir mrad"), "{text}");
    let p1 = text.lines().find(|l| l.starts_with("P1 ")).expect("P1 row");
    let ap_p = p1.split_whitespace().nth(2).expect("AP_P");
    assert_eq!(ap_p.split_once('.').map(|(_, d)| d.len()), Some(3), "{p1}");
    assert_eq!(std::fs::read_to_string(&json).unwrap(), stored);
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    for key in [
        "ap_p_mm",
        "ap_x_mm",
        "rp_l_mm",
        "l_mean_mm",
        "s_l_mm",
        "ap_dir_deg",
        "n",
    ] {
        assert!(v["poses"][0].get(key).is_some(), "{key}: {v}");
    }

    // an ISO campaign is not a calibration: no report, no identification, no corrected model
    // (exit 2, saying where its figures are); `run` on it (done) prints the stored figures
    let refused = |args: &[&str]| {
        let out = cellcal().args(args).output().unwrap();
        assert_eq!(out.status.code(), Some(2), "{args:?}: {out:?}");
        let e = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(e.contains("is an ISO 9283 campaign"), "{args:?}: {e}");
        assert!(e.contains("cellcal iso9283"), "{args:?}: {e}");
    };
    let (db, n) = (store.to_str().unwrap(), id.to_string());
    let html = store.with_file_name("iso.html");
    refused(&[
        "report",
        "--store",
        db,
        "--campaign",
        &n,
        "--out",
        html.to_str().unwrap(),
    ]);
    assert!(!html.exists());
    refused(&["identify", "--store", db, "--campaign", &n]);
    let cfg = store.with_file_name("cell.toml");
    let out = cellcal()
        .args([
            "run",
            "--config",
            cfg.to_str().unwrap(),
            "--store",
            db,
            "--campaign",
            &n,
        ])
        .arg("--json")
        .arg(store.with_file_name("again.json"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{out:?}");
    assert_eq!(String::from_utf8_lossy(&out.stdout), format_table(&plain));
    assert_eq!(
        std::fs::read_to_string(store.with_file_name("again.json")).unwrap(),
        stored
    );

    // a calibration campaign: its corrected model, and `cellcal iso9283` refuses it (exit 2)
    let text = base.replace("poses = 300", "poses = 160");
    let f = rt.block_on(run_in_process(&text));
    let out = cellcal()
        .args(["iso9283", "--store"])
        .arg(&f.store)
        .args(["--campaign", &f.id.to_string()])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2), "{out:?}");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("not an ISO 9283 campaign"),
        "{out:?}"
    );
    let model = stored_model_toml(&Store::open(&f.store).unwrap(), f.id)
        .unwrap()
        .expect("a corrected model");
    let model_path = f.store.with_file_name("identified.toml");
    std::fs::write(&model_path, model).unwrap();

    // compensated by it: AP drops to the calibration's accuracy
    let (comp, _, _) = run_iso(&rt, &format!("{base}{}", iso_table(Some(&model_path))));
    print!("compensated\n{}", format_table(&comp));
    assert!(comp.compensated && comp.frame.contains("compensated model"));
    let ap_comp = max_of(&comp, |p| p.ap_p_mm);
    assert!(
        ap_comp < 0.15 && ap_comp < 0.3 * ap_plain,
        "compensated AP_P up to {ap_comp} mm (uncompensated {ap_plain} mm)"
    );
    let rp = max_of(&comp, |p| p.rp_l_mm);
    assert!(rp < 0.1, "compensated RP_l up to {rp} mm");
}

/// A fresh ISO campaign has no figures (exit 2); aborted after 12 of 15 visits it is computed
/// over its 2 complete cycles and says so; every visit was approached through its pre-pose (at
/// least two robot moves per visit); resumed by `cellcal run`, it ends with all 3 cycles.
#[test]
fn an_iso_campaign_aborted_and_resumed_counts_complete_cycles() {
    use cellcal::campaign::{CampaignCommand, CampaignEvent};
    use std::sync::Mutex;

    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    let text = format!("{}{}", config_text("", "", ""), iso_table(None));

    // created, nothing measured: no figures
    let dir = tempfile::tempdir().expect("tempdir").keep();
    let session = rt.block_on(crate::campaign::sim_session(&dir, &text));
    let id = session.ctx.campaign_id;
    let plan_len = session.ctx.plan.poses.len();
    assert_eq!((plan_len, session.ctx.plan.approach.len()), (15, 15));
    drop(session.lock);
    if let Some(sim) = session.sim {
        rt.block_on(sim.stop());
    }
    let out = cellcal()
        .args(["iso9283", "--store"])
        .arg(dir.join("c.db"))
        .args(["--campaign", &id.to_string()])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2), "{out:?}");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("0 complete cycle(s)"),
        "{out:?}"
    );

    // measured in part
    let moves: Arc<Mutex<Vec<u64>>> = Arc::default();
    let seen = Arc::clone(&moves);
    let (outcome, store, id) = rt.block_on(crate::campaign::run_steered(
        &text,
        move |e, cell, control| {
            if let CampaignEvent::Measured { done, .. } = e {
                let n = cellcal::sim::lock_world(&cell.world).moves();
                seen.lock().unwrap().push(n);
                if *done == 12 {
                    control.apply(&CampaignCommand::Abort);
                }
            }
        },
    ));
    assert!(matches!(outcome, Outcome::Aborted), "{outcome:?}");
    // the robot's move count read at each visit's event (the reading may lag by the next
    // visit's moves, at most 2, at either end): visits 2–12 took at least 2 moves each
    let moves = moves.lock().unwrap().clone();
    assert_eq!(moves.len(), 12);
    assert!(
        moves[11] - moves[0] >= 2 * 11 - 2,
        "visits without their pre-pose: robot moves at each visit {moves:?}"
    );
    let out = cellcal()
        .args(["iso9283", "--store"])
        .arg(&store)
        .args(["--campaign", &id.to_string()])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{out:?}");
    assert!(
        stdout.contains("2 of 3 cycles, PARTIAL")
            && stdout.contains("measured in part: the figures use its 2 complete cycles of 3"),
        "{stdout}"
    );

    // resumed to the end by the binary: the table, all three cycles
    let out = cellcal()
        .args([
            "run",
            "--quiet",
            "--arm",
            "--campaign",
            &id.to_string(),
            "--config",
        ])
        .arg(store.with_file_name("cell.toml"))
        .arg("--store")
        .arg(&store)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{out:?}");
    assert!(
        stdout.contains("(3 of 3 cycles; robot base frame"),
        "{stdout}"
    );
    let s = Store::open(&store).unwrap();
    assert_eq!(s.done_poses(id).unwrap().len(), 15, "every visit once");
    let r: IsoReport = serde_json::from_str(&s.latest_result(id).unwrap().unwrap()).unwrap();
    assert!(!r.partial && r.poses.iter().all(|p| p.n == 3), "{r:?}");
}

/// The daemon runs ISO campaigns from the same `[iso9283]` table: the result is the figures,
/// the calibration report is refused (409, saying where the figures are), and a cube the robot
/// cannot reach under the planning checks is the client's request to fix (400, not 500).
#[test]
fn the_daemon_runs_iso_campaigns_and_refuses_what_does_not_apply() {
    use crate::serve::{arm_and_start, create, get, get_text, post, start, wait_for_state};
    let dir = tempfile::tempdir().expect("tempdir");
    let base = config_text("", "", "");
    let cfg = crate::campaign::write_config(dir.path(), &format!("{base}{}", iso_table(None)));
    let s = start(&cfg, &dir.path().join("c.db"));
    let id = create(&s, "{}");
    arm_and_start(&s, id);
    wait_for_state(&s, id, "done");
    let (code, r) = get(&s, &format!("/api/campaigns/{id}/result"));
    assert_eq!((code, r["kind"].as_str()), (200, Some("iso9283")), "{r}");
    assert_eq!(r["poses"].as_array().map(Vec::len), Some(5), "{r}");
    let (code, _, body) = get_text(&s, &format!("/api/campaigns/{id}/report"), Some(&s.token));
    assert_eq!(code, 409, "{body}");
    assert!(body.contains("is an ISO 9283 campaign"), "{body}");
    drop(s);

    let far = dir.path().join("far");
    std::fs::create_dir_all(&far).unwrap();
    let table = iso_table(None).replace("cube_edge_mm = 200.0", "cube_edge_mm = 1600.0");
    let cfg = crate::campaign::write_config(&far, &format!("{base}{table}"));
    let s = start(&cfg, &far.join("c.db"));
    let (code, e) = post(&s, "/api/campaigns", "{}");
    assert_eq!(code, 400, "{e}");
    assert!(e["error"].as_str().unwrap_or("").contains("ISO"), "{e}");
}

/// `measure_axis = false` measures P1 only (no direction figures, no P2 of a visit), and
/// `speed_pct` is the speed the run prepares the robot with.
#[test]
fn position_only_iso_campaign_at_its_own_speed() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    let table = format!(
        "{}measure_axis = false\nspeed_pct = 35.0\n",
        iso_table(None)
    );
    let text = format!("{}{table}", config_text("", "", ""));
    let dir = tempfile::tempdir().expect("tempdir").keep();
    let (ctx, sim, outcome) =
        rt.block_on(run_with(&dir, &text, Arc::new(ScriptedPrompter::exact())));
    if let Some(sim) = sim {
        rt.block_on(sim.stop());
    }
    let Outcome::Iso(report) = outcome else {
        panic!("the ISO campaign did not finish: {outcome:?}");
    };
    assert_eq!(ctx.cfg.robot_controller.speed_pct, 35.0);
    assert!(
        report
            .poses
            .iter()
            .all(|p| p.n == 3 && p.ap_dir_deg.is_none() && p.rp_dir_deg.is_none()),
        "{}",
        format_table(&report)
    );
    assert!(max_of(&report, |p| p.ap_p_mm) > 0.2);
}
