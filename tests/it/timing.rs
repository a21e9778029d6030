//! The campaign time estimate against the clock: a short campaign on the simulated cell with
//! realistic timings (joints at 60 °/s reached at 120 °/s², 1.5 s settle, 1 s stationary
//! measurement, a 5 mm/s stage), over the real protocols on loopback and a pty.

use std::sync::Arc;
use std::time::{Duration, Instant};

use cellcal::campaign::estimate::{
    cell_times, estimate_campaign_time, SIM_MOVE_OVERHEAD_S, SIM_READING_OVERHEAD_S,
};
use cellcal::campaign::session::{open_session, Session};
use cellcal::campaign::{run_campaign, CampaignCommand, FaultPolicy};
use cellcal::cell::ScriptedPrompter;
use cellcal::config::parse_cell_config;
use cellcal::model::{tx60, write_robot, JointMotion};
use cellcal::plan::CampaignEstimate;

/// The simulated cell of config/cell.sim.toml with realistic timings: the robot file's joint
/// limits (60 °/s, 120 °/s²), settle 1500 ms, stage 5 mm/s; a 1000 ms measuring time; a
/// drift check after every 2 poses; setup: a base registration on 3 poses.
fn realistic_config() -> String {
    crate::campaign::config_text("", "", "")
        .replace(
            "realistic = false\nmove_speed_deg_s = 200000.0\nstage_speed_mm_s = 100000.0\n",
            "realistic = true\n",
        )
        .replace("measure_ms = 5 ", "measure_ms = 1000 ")
        .replace("travel_mm = 10.0", "travel_mm = 5.0")
        .replace("drift_every = 50", "drift_every = 2")
        .replace(
            "tool_frame = true ",
            "tool_frame = false\nbase_poses = 3\n# ",
        )
}

/// What [`run_short`] found: the estimate of the whole plan and of its first three poses, the
/// measured duration of those three (s) and the simulated robot's moves.
struct ShortRun {
    whole: CampaignEstimate,
    short: CampaignEstimate,
    took: f64,
    moves: usize,
}

/// The campaign of `text` (robot file: every joint at 60 °/s, reached in 0.5 s) planned, then
/// its first three poses measured on the simulated cell and timed.
fn run_short(text: &str) -> ShortRun {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let cfg_path = crate::campaign::write_config(d, text);
    // the robot file: every joint at 60 °/s, reached in 0.5 s
    let mut robot = tx60();
    robot.motion = vec![
        JointMotion {
            max_speed: Some(60f64.to_radians()),
            max_accel: Some(120f64.to_radians()),
        };
        6
    ];
    std::fs::write(d.join("robots/staubli_tx60.toml"), write_robot(&robot, &[]))
        .expect("robot file");
    let cfg = parse_cell_config(text, &cfg_path).expect("config");
    let rt = tokio::runtime::Runtime::new().expect("runtime");
    rt.block_on(async {
        let Session {
            mut ctx,
            mut devices,
            sim,
            lock,
            ..
        } = open_session(
            cfg,
            &d.join("c.db"),
            None,
            Arc::new(ScriptedPrompter::exact()),
        )
        .await
        .expect("session");
        let whole = ctx
            .estimate
            .clone()
            .expect("the session estimates the campaign");
        // a short campaign: the plan's first three poses
        ctx.plan.poses.truncate(3);
        let short = estimate_campaign_time(&ctx.cfg, &ctx.nominal, &ctx.plan_request, &ctx.plan);
        ctx.on_fault = FaultPolicy::Fail;
        ctx.control.apply(&CampaignCommand::Arm);
        ctx.control.apply(&CampaignCommand::Start);
        let started = Instant::now();
        // the three poses do not identify a robot: the run ends after its last drift check
        let outcome =
            tokio::time::timeout(Duration::from_secs(150), run_campaign(&ctx, &mut devices))
                .await
                .expect("the campaign ends in time")
                .expect("the campaign runs");
        let took = started.elapsed().as_secs_f64();
        drop(lock);
        let sim = sim.expect("simulated cell");
        let moves = cellcal::sim::lock_world(&sim.world).moves() as usize;
        sim.stop().await;
        eprintln!(
            "estimate {:.1} s ({short:?}), measured {took:.1} s ({:+.1} %), {moves} robot moves \
             (estimated {}), outcome {outcome:?}",
            short.total_s,
            (short.total_s - took) / took * 100.0,
            short.moves
        );
        ShortRun {
            whole,
            short,
            took,
            moves,
        }
    })
}

/// The estimate of a short campaign is within 10 % of the clock and walks every robot move.
fn assert_matches_the_clock(r: &ShortRun) {
    let short = &r.short;
    assert_eq!(r.moves, short.moves, "the estimate walks every robot move");
    let off = (short.total_s - r.took) / r.took;
    assert!(
        off.abs() <= 0.10,
        "estimate {:.1} s vs measured {:.1} s ({:+.1} %): {short:?}",
        short.total_s,
        r.took,
        off * 100.0
    );
}

#[test]
fn estimate_matches_the_clock() {
    let text = realistic_config();
    assert!(text.contains("realistic = true\n"), "{text}");
    assert!(text.contains("measure_ms = 1000 "), "{text}");
    let r = run_short(&text);
    let (whole, short) = (&r.whole, &r.short);
    assert_eq!((whole.poses, whole.readings), (300, 600));
    assert!(
        whole.total_s > 300.0 * 4.0 * 2.0,
        "300 poses of 4 s stage travel at least: {whole:?}"
    );
    assert_eq!((short.poses, short.readings), (3, 6));
    assert!(short.setup_s > 3.0 * 2.5, "3 registration poses: {short:?}");
    // one stage move per pose where the stage stands first (P1 P2 | P2 P1 | drift at P1 |
    // P1 P2), and back to P1 for the final drift check
    assert!(
        short.stage_s >= 4.0 * 1.0,
        "4 stage moves of 1 s: {short:?}"
    );
    assert_matches_the_clock(&r);
}

/// `[sim] time_scale = 0.1`: every simulated duration (the trapezoidal moves, settling,
/// measuring, the stage) ten times shorter, the estimate's parts too, and the estimate still
/// within 10 % of the clock.
#[test]
fn a_time_scaled_cell_runs_and_is_estimated_ten_times_faster() {
    let text = realistic_config().replacen("\ntime_scale = 1.0 ", "\ntime_scale = 0.1 ", 1);
    assert!(text.contains("\ntime_scale = 0.1 "), "{text}");
    let dir = tempfile::tempdir().expect("tempdir");
    let path = crate::campaign::write_config(dir.path(), &realistic_config());
    let (cfg, scaled) = (
        parse_cell_config(&realistic_config(), &path).expect("config"),
        parse_cell_config(&text, &path).expect("scaled config"),
    );
    let model = tx60();
    let (t, s) = (cell_times(&cfg, &model), cell_times(&scaled, &model));
    let q0 = [0.0; 6];
    let q1 = [0.3, -0.2, 0.5, 1.0, 0.4, -0.7];
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs().max(1.0);
    assert!(close(
        s.motion.move_time_s(&q0, &q1),
        0.1 * t.motion.move_time_s(&q0, &q1)
    ));
    assert!(close(
        s.settle_s - SIM_MOVE_OVERHEAD_S,
        0.1 * (t.settle_s - SIM_MOVE_OVERHEAD_S)
    ));
    assert!(close(
        s.reading_s - SIM_READING_OVERHEAD_S,
        0.1 * (t.reading_s - SIM_READING_OVERHEAD_S)
    ));
    // the clock agrees with the scaled estimate: the world ran ten times faster
    assert_matches_the_clock(&run_short(&text));
}
