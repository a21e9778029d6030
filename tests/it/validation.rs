//! Validation before anything moves, through the real binary: a non-finite or truncated
//! safety value, or an infeasible campaign, exits 2 naming the file and the key; the store is
//! not even created (no campaign stored) and the simulated cell is never started (nothing
//! moves).

use std::path::{Path, PathBuf};
use std::process::Output;

use crate::campaign::{config_text, write_config};

use super::common::cellcal_process as cellcal;

/// A test cell folder: `cell.toml` (from `text`) and `robots/staubli_tx60.toml` with `from`
/// replaced by `to` once.
fn cell_dir(text: &str, robot_edit: (&str, &str)) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = write_config(dir.path(), text);
    let robot = dir.path().join("robots/staubli_tx60.toml");
    let original = std::fs::read_to_string(&robot).expect("robot");
    assert!(original.contains(robot_edit.0), "{}", robot_edit.0);
    std::fs::write(&robot, original.replacen(robot_edit.0, robot_edit.1, 1)).expect("write");
    (dir, cfg)
}

/// `cellcal run --arm` on the cell; asserts exit 2, no store, no simulated cell; the stderr.
fn refused_run(dir: &Path, cfg: &Path, extra: &[&str]) -> String {
    let store = dir.join("c.db");
    let out: Output = cellcal()
        .args(["run", "--arm", "--quiet", "--on-fault", "fail", "--config"])
        .arg(cfg)
        .arg("--store")
        .arg(&store)
        .args(extra)
        .output()
        .expect("runs");
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(!store.exists(), "no campaign may be stored: {err}");
    assert!(!err.contains("simulated cell"), "nothing may start: {err}");
    err
}

const NO_EDIT: (&str, &str) = ("name", "name");

/// `cellcal run --arm` on `text` (and the robot file edited by `robot_edit`) is refused with
/// a message containing `want`.
fn assert_run_refused(text: &str, robot_edit: (&str, &str), extra: &[&str], want: &str) {
    let (dir, cfg) = cell_dir(text, robot_edit);
    let err = refused_run(dir.path(), &cfg, extra);
    assert!(err.contains(want), "{want}: {err}");
}

/// `cellcal <command> --config CFG` exits 2 with a message containing `want`.
fn assert_command_refused(command: &[&str], cfg: &Path, want: &str) {
    let out = cellcal()
        .args(command)
        .arg("--config")
        .arg(cfg)
        .output()
        .expect("runs");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{command:?}: {err}");
    assert!(err.contains(want), "{command:?}: {want}: {err}");
}

#[test]
fn non_finite_or_truncated_safety_values_exit_2_naming_file_and_key() {
    let base = config_text("", "", "");
    let with = |from: &str, to: &str| {
        assert!(base.contains(from), "{from}");
        base.replacen(from, to, 1)
    };
    let extra = |line: &str| config_text("", line, "");
    for (text, want) in [
        (
            with("box_center_mm = [550.0,", "box_center_mm = [nan,"),
            "cell.toml: campaign.box_center_mm[0]: nan is not a finite number",
        ),
        (
            with(
                "box_size_mm = [1000.0, 1000.0,",
                "box_size_mm = [1000.0, inf,",
            ),
            "cell.toml: campaign.box_size_mm[1]: inf is not a finite number",
        ),
        (
            extra("floor_z_mm = nan"),
            "cell.toml: campaign.floor_z_mm: nan is not a finite number",
        ),
        (
            extra("wrist_min_deg = nan"),
            "cell.toml: campaign.wrist_min_deg: nan is not a finite number",
        ),
        (
            extra("line_of_sight_max_deg = -inf"),
            "cell.toml: campaign.line_of_sight_max_deg: -inf is not a finite number",
        ),
        (
            with("\nposition_mm = [2500.0,", "\nposition_mm = [inf,"),
            "cell.toml: tracker.position_mm[0]: inf is not a finite number",
        ),
        (
            with(
                "box_center_mm = [550.0, 0.0, 550.0]",
                "box_center_mm = [550.0, 0.0]",
            ),
            "cell.toml: campaign.box_center_mm: ",
        ),
    ] {
        assert_run_refused(&text, NO_EDIT, &[], want);
    }
    for (edit, want) in [
        (
            ("limits_deg = [-180, 180]", "limits_deg = [-180, nan]"),
            "staubli_tx60.toml: joints[1].limits_deg[1]: nan is not a finite number",
        ),
        (
            (
                "limits_deg = [-127.5, 127.5]",
                "limits_deg = [-127.5, 127.5, 130]",
            ),
            "staubli_tx60.toml: joints[2].limits_deg: has 3 values; it takes exactly 2",
        ),
        (
            ("a_mm = 290", "a_mm = inf"),
            "staubli_tx60.toml: joints[2].a_mm: inf is not a finite number",
        ),
    ] {
        assert_run_refused(&base, edit, &[], want);
    }
}

#[test]
fn every_command_that_loads_the_file_refuses_it() {
    let text = config_text("", "floor_z_mm = nan", "");
    let (dir, cfg) = cell_dir(&text, NO_EDIT);
    let want = "cell.toml: campaign.floor_z_mm: nan is not a finite number";
    assert_command_refused(&["serve", "--listen", "127.0.0.1:0"], &cfg, want);
    assert_command_refused(&["sim"], &cfg, want);
    drop(dir);
    // `cellcal sim` reads [sim]: its numbers are checked too
    let text = config_text("tracker_noise_scale = inf", "", "").replacen(
        "tracker_noise_scale = 1.0\n",
        "",
        1,
    );
    let (_dir, cfg) = cell_dir(&text, NO_EDIT);
    let want = "cell.toml: sim.tracker_noise_scale: inf is not a finite number";
    assert_command_refused(&["sim"], &cfg, want);
}

#[test]
fn infeasible_campaigns_exit_2_before_anything_starts() {
    let base = config_text("", "", "");
    let small = |ident: usize| {
        base.replace("poses = 300", "poses = 40")
            .replace("ident = 100", &format!("ident = {ident}"))
    };
    for (text, want) in [
        (
            small(10),
            "cell.toml: campaign.ident: 10 identification poses give 60 equations",
        ),
        (
            small(20).replace("model = \"op\"", "model = \"full\""),
            "cell.toml: campaign.model: full needs the full flange orientation",
        ),
        (
            small(20).replace("[setup]", "[setup]\nhome_deg = [0.0, 30.0, 90.0, 0.0, 150.0, 0.0]"),
            "cell.toml: setup.home_deg[4]: 150° is outside joint 5's limits",
        ),
        (
            small(20).replace("travel_mm = 10.0", "travel_mm = 10.0\np1_mm = 20.0"),
            "cell.toml: stage.p1_mm: P1 = 20 mm and P2 = P1 + travel = 30 mm must lie in stage.range_mm",
        ),
    ] {
        assert_run_refused(&text, NO_EDIT, &[], want);
    }
}

#[test]
fn an_unknown_campaign_id_exits_2() {
    let (dir, cfg) = cell_dir(&config_text("", "", ""), NO_EDIT);
    let err = refused_run(dir.path(), &cfg, &["--campaign", "7"]);
    let want = format!(
        "campaign 7: no such campaign in {}",
        dir.path().join("c.db").display()
    );
    assert!(err.contains(&want), "{err}");
}
