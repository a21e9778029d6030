//! The campaign time estimate of a session ([`estimate_campaign_time`]): the cell's timings
//! ([`cell_times`]: the configuration for real devices, the simulated cell's effective timings
//! for simulated ones) and the walk of the plan the way the engine measures it (setup, frame
//! reference, poses, drift checks).

use crate::config::{CellConfig, DeviceMode, StageMode};
use crate::model::RobotModel;
use crate::plan::setup::{base_registration_targets, tool_frame_targets};
use crate::plan::timing::{campaign_walk, estimate_campaign, CellTimes, StageTimes, Visit};
use crate::plan::{CampaignEstimate, MotionLimits, Plan, PlanRequest, Router};

/// A real tracker's time per reading beyond the measuring time (s): the emScon command, the
/// AT960's start of a stationary measurement and the result's transfer (an assumption; the
/// measuring time itself is [`CellConfig::tracker_measure_ms`]).
pub const REAL_READING_OVERHEAD_S: f64 = 0.3;
/// The simulated tracker's time per reading beyond its measuring time (s): loopback round
/// trips.
pub const SIM_READING_OVERHEAD_S: f64 = 0.005;
/// A real robot's settling after a move when `[robot_controller] settle_ms` is unset (ms).
pub const REAL_SETTLE_MS: u64 = 500;
/// A real motorised stage's speed when `[stage] speed_mm_s` is unset (mm/s).
pub const REAL_STAGE_SPEED_MM_S: f64 = 5.0;
/// A real motorised stage's time per move beyond the distance at its speed (s): start,
/// settling and the serial round trips (an assumption).
pub const REAL_STAGE_PER_MOVE_S: f64 = 0.2;
/// A real laser tracker's preparation before the first reading (s): emScon Initialize
/// (an assumption; the AT960 takes tens of seconds).
pub const REAL_TRACKER_PREPARE_S: f64 = 30.0;
/// Per robot move on the simulated cell beyond the move and the settling (s): the robotlink
/// round trips (JOINTS, MOVEJ, WAIT polling).
pub const SIM_MOVE_OVERHEAD_S: f64 = 0.01;

/// How long each device of `cfg` takes: simulated devices with the simulated cell's
/// effective timings (`[sim]`, with the `[tracker]` and `[stage]` settings the session gives
/// them), real ones from the configuration (unset keys: the stated assumptions above).
pub fn cell_times(cfg: &CellConfig, nominal: &RobotModel) -> CellTimes {
    let sim = cfg.sim.clone().unwrap_or_default();
    let speed = cfg.robot_controller.speed_pct;
    let (motion, settle_s) = match cfg.robot_controller.mode {
        DeviceMode::Sim => {
            let settle_s = cfg
                .robot_controller
                .settle_ms
                .map_or(sim.settle_s(), |ms| ms as f64 / 1000.0);
            (
                sim.motion_limits(nominal).at_speed_pct(speed),
                settle_s + SIM_MOVE_OVERHEAD_S,
            )
        }
        DeviceMode::Real => (
            MotionLimits::of(nominal, speed),
            cfg.robot_controller.settle_ms.unwrap_or(REAL_SETTLE_MS) as f64 / 1000.0,
        ),
    };
    let measure_s = f64::from(cfg.tracker_measure_ms()) / 1000.0;
    let (reading_s, tracker_prepare_s) = match cfg.tracker.mode {
        DeviceMode::Sim => (
            measure_s * sim.measuring_scale() + SIM_READING_OVERHEAD_S,
            0.0,
        ),
        DeviceMode::Real => (measure_s + REAL_READING_OVERHEAD_S, REAL_TRACKER_PREPARE_S),
    };
    let stage = match (cfg.stage.kind, cfg.stage.mode) {
        (StageMode::Manual | StageMode::ManualGauge, _) => StageTimes::Manual {
            per_reading_s: cfg.stage.technician_s_per_reading,
        },
        (StageMode::Serial, DeviceMode::Sim) => {
            let poll_ms = cfg
                .stage
                .poll_interval_ms
                .unwrap_or(if sim.realistic { 20 } else { 1 });
            StageTimes::Motorised {
                speed_mm_s: cfg
                    .stage
                    .speed_mm_s
                    .unwrap_or(sim.stage_speed_scaled_mm_s()),
                per_move_s: sim.stage_settle_s() + poll_ms as f64 / 1000.0,
            }
        }
        (StageMode::Serial, DeviceMode::Real) => StageTimes::Motorised {
            speed_mm_s: cfg.stage.speed_mm_s.unwrap_or(REAL_STAGE_SPEED_MM_S),
            per_move_s: REAL_STAGE_PER_MOVE_S,
        },
    };
    // homing the motorised stage at preparation: from anywhere in its range, half on average
    let homing_s = match stage {
        StageTimes::Motorised {
            speed_mm_s,
            per_move_s,
        } if cfg.stage.home_on_prepare && cfg.stage.mode == DeviceMode::Real => {
            per_move_s + (cfg.stage.range_mm[1] - cfg.stage.range_mm[0]) / 2.0 / speed_mm_s
        }
        _ => 0.0,
    };
    CellTimes {
        motion,
        settle_s,
        reading_s,
        stage,
        prepare_s: tracker_prepare_s + homing_s,
    }
}

/// The planned duration of a fresh run of `plan` on the cell of `cfg` (`req`: the campaign's
/// planning request; `nominal`: the robot model with the configured tool): the setup's
/// tool-frame targets and base registration poses, the frame reference, every pose and drift
/// check, along the routes the engine takes.
pub fn estimate_campaign_time(
    cfg: &CellConfig,
    nominal: &RobotModel,
    req: &PlanRequest,
    plan: &Plan,
) -> CampaignEstimate {
    let p1 = cfg.stage.p1_mm;
    let p2 = p1 + cfg.stage.travel_mm;
    let mut setup = Vec::new();
    if cfg.setup.tool_frame {
        let home: Option<Vec<f64>> = cfg
            .setup
            .home_deg
            .as_ref()
            .map(|h| h.iter().map(|d| d.to_radians()).collect());
        let targets = tool_frame_targets(
            nominal,
            plan,
            req,
            &cfg.setup.tool_frame_request(),
            home.as_deref(),
        );
        setup.extend(targets.unwrap_or_default().into_iter().map(|t| {
            let stage_mm = if t.measure_p2 { vec![p1, p2] } else { vec![p1] };
            Visit {
                q_rad: t.q_rad,
                approach: None,
                readings: stage_mm.len(),
                stage_mm,
            }
        }));
    }
    if cfg.setup.base_registration {
        let poses = base_registration_targets(nominal, plan, cfg.setup.base_poses);
        setup.extend(poses.into_iter().map(|q_rad| Visit {
            q_rad,
            approach: None,
            stage_mm: vec![p1],
            readings: 1,
        }));
    }
    let start_q = match (cfg.robot_controller.mode, &cfg.sim) {
        (DeviceMode::Sim, Some(sim)) => Some(
            sim.initial_joints_deg
                .iter()
                .map(|d| d.to_radians())
                .collect(),
        ),
        _ => None,
    };
    let walk = campaign_walk(
        plan,
        cfg.campaign.drift_every,
        setup,
        start_q,
        (p1, cfg.stage.travel_mm, cfg.stage.tolerance_mm),
        cfg.axis_readings(),
    );
    let times = cell_times(cfg, nominal);
    let mut router = Router::new(nominal, &req.workspace, &req.tool_mm, &plan.drift_reference).ok();
    estimate_campaign(&walk, &times, router.as_mut())
}
