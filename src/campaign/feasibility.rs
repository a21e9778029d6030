//! Campaign feasibility: what must hold before a campaign is planned, stored or moves, checked
//! on the nominal model from the configuration alone (no device, no store write):
//!
//! - the observation model is one this cell's 1D stage can measure: a 1D stage gives the
//!   ball position P1 and one flange axis per pose, `L = R·u` (docs/method.md §4). `position` uses P1
//!   only; `np` measures n (flange x), so `stage.axis` must be ±x; `op` measures o (flange y),
//!   so ±y; `full` needs n, o and a (a 6-DOF measurement, docs/method.md §5), which no 1D stage gives,
//!   so it is refused;
//! - enough identification poses: equations (rows per pose × poses) ≥ 3 × the parameters the
//!   model identifies, counted by the structural identifiability of the nominal model with
//!   the configured base/tool identification ([`crate::identify::structural_set`]);
//! - `setup.home_deg` has one value per joint, inside the joint limits, and (with the
//!   tool-frame step) every setup target from it passes the engine's joint-limit/workspace
//!   check;
//! - stage P1 and P2 = P1 + travel inside `stage.range_mm`;
//! - the tracker position is finite;
//! - `campaign.nongeometric` asks for compliance only of a robot file with masses;
//! - a campaign to resume exists (the store is read, never created).

use std::path::{Path, PathBuf};

use super::engine::identify_options;
use super::session::plan_request;
use crate::config::CellConfig;
use crate::dataset::PoseSet;
use crate::identify::{all_params, structural_set, ObsModel};
use crate::measure::tool_frame::plan_tool_frame;
use crate::model::{RobotModel, SignedAxis, TermFamily};
use crate::plan::target_ok;
use crate::store::{Store, StoreError};

/// Why a campaign cannot run as configured (each message starts with the key to change).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Infeasible {
    /// Fewer equations than three per identified parameter.
    #[error("campaign.ident: {ident} identification poses give {equations} equations ({rows} per pose for model {model}), but the {parameters} parameters it identifies need at least {} (3 per parameter): at least {needed_poses} identification poses", 3 * parameters)]
    TooFewIdentPoses {
        /// Observation model name.
        model: &'static str,
        /// Identification poses.
        ident: usize,
        /// Equations per pose.
        rows: usize,
        /// Equations in all.
        equations: usize,
        /// Structurally identifiable parameters.
        parameters: usize,
        /// Fewest identification poses that suffice.
        needed_poses: usize,
    },
    /// The observation model needs a quantity the stage cannot measure.
    #[error("campaign.model: {model} {reason}")]
    NotMeasurable {
        /// Observation model name.
        model: &'static str,
        /// What it needs and why the cell cannot give it.
        reason: String,
    },
    /// A stored campaign's model is not a known one.
    #[error("campaign.model: the stored model `{0}` is not one of position, np, op, full")]
    UnknownModel(String),
    /// `setup.home_deg` has the wrong number of values.
    #[error("setup.home_deg: has {got} values; the robot has {dof} joints")]
    HomeLength {
        /// Values given.
        got: usize,
        /// Joints of the robot.
        dof: usize,
    },
    /// A `setup.home_deg` value is outside its joint's limits.
    #[error("setup.home_deg[{index}]: {value_deg}° is outside joint {}'s limits [{min_deg}, {max_deg}]°", index + 1)]
    HomeOutsideLimits {
        /// Index into `home_deg` (joint − 1).
        index: usize,
        /// The value (deg).
        value_deg: f64,
        /// Lower limit (deg).
        min_deg: f64,
        /// Upper limit (deg).
        max_deg: f64,
    },
    /// The tool-frame targets planned from `setup.home_deg` fail a check.
    #[error("setup.home_deg: {0}")]
    HomeTargets(String),
    /// P1 or P2 outside the stage's range.
    #[error("stage.p1_mm: P1 = {p1_mm} mm and P2 = P1 + travel = {p2_mm} mm must lie in stage.range_mm [{min_mm}, {max_mm}]")]
    StageOutOfRange {
        /// P1 (mm).
        p1_mm: f64,
        /// P2 (mm).
        p2_mm: f64,
        /// Range start (mm).
        min_mm: f64,
        /// Range end (mm).
        max_mm: f64,
    },
    /// The tracker position is not finite.
    #[error("tracker.position_mm: {0:?} is not three finite numbers")]
    TrackerPosition([f64; 3]),
    /// Compliance is asked for, but the robot file gives no mass to make a gravity torque.
    #[error("campaign.nongeometric: compliance multiplies the gravity torque of the robot's masses, but the robot file has no [[masses]]: add them (docs/configuration.md) or leave compliance out")]
    ComplianceWithoutMasses,
}

/// Why a session may not start: an infeasible configuration, or a campaign to resume that is
/// not there.
#[derive(Debug, thiserror::Error)]
pub enum FeasibilityError {
    /// The configuration cannot run (the file and the key are named).
    #[error("{path}: {problem}")]
    Config {
        /// Configuration file.
        path: PathBuf,
        /// What cannot run.
        problem: Infeasible,
    },
    /// `--campaign N` names no stored campaign.
    #[error("campaign {id}: no such campaign in {store}")]
    UnknownCampaign {
        /// Requested id.
        id: i64,
        /// Store file.
        store: PathBuf,
    },
    /// The store could not be read (its message names the campaign store).
    #[error(transparent)]
    Store(#[from] StoreError),
}

/// Check a session before anything starts: a new campaign from the configuration, or the
/// stored campaign `campaign` (its stored model and identification poses) with the
/// configuration's cell.
pub fn check_session(
    cfg: &CellConfig,
    nominal: &RobotModel,
    store_path: &Path,
    campaign: Option<i64>,
) -> Result<(), FeasibilityError> {
    match campaign {
        None => check_new(cfg, nominal),
        Some(id) => {
            if !store_path.exists() {
                return Err(FeasibilityError::UnknownCampaign {
                    id,
                    store: store_path.to_owned(),
                });
            }
            let store = Store::open(store_path)?;
            check_resumed(cfg, nominal, &store, id).map_err(|e| match e {
                FeasibilityError::UnknownCampaign { id, .. } => FeasibilityError::UnknownCampaign {
                    id,
                    store: store_path.to_owned(),
                },
                e => e,
            })
        }
    }
}

/// [`check_campaign`] of a new campaign from the configuration.
pub fn check_new(cfg: &CellConfig, nominal: &RobotModel) -> Result<(), FeasibilityError> {
    in_file(cfg, check_campaign(cfg, nominal, cfg.campaign.ident))
}

/// [`check_campaign`] of stored campaign `id` (its stored model and identification poses)
/// with the configuration's cell.
pub fn check_resumed(
    cfg: &CellConfig,
    nominal: &RobotModel,
    store: &Store,
    id: i64,
) -> Result<(), FeasibilityError> {
    let row = match store.campaign(id) {
        Err(StoreError::NoCampaign(_)) => {
            return Err(FeasibilityError::UnknownCampaign {
                id,
                store: PathBuf::from("the store"),
            })
        }
        r => r?,
    };
    let ident = store
        .plan(id)?
        .iter()
        .filter(|p| p.set == PoseSet::Ident)
        .count();
    let mut cfg = cfg.clone();
    cfg.campaign.model = match row.model.parse() {
        Ok(m) => m,
        Err(_) => return in_file(&cfg, Err(Infeasible::UnknownModel(row.model))),
    };
    in_file(&cfg, check_campaign(&cfg, nominal, ident))
}

fn in_file(cfg: &CellConfig, r: Result<(), Infeasible>) -> Result<(), FeasibilityError> {
    r.map_err(|problem| FeasibilityError::Config {
        path: cfg.path.clone(),
        problem,
    })
}

/// Every feasibility rule of the module doc for a campaign of `ident` identification poses.
pub fn check_campaign(
    cfg: &CellConfig,
    nominal: &RobotModel,
    ident: usize,
) -> Result<(), Infeasible> {
    let model = cfg.campaign.model;
    check_measurable(model, &cfg.stage.axis)?;
    check_tracker(cfg)?;
    check_stage_range(cfg)?;
    check_home(cfg, nominal)?;
    check_terms(cfg, nominal)?;
    check_ident_poses(cfg, nominal, model, ident)
}

/// Compliance needs masses: without them every compliance would be held at zero, unasked.
fn check_terms(cfg: &CellConfig, nominal: &RobotModel) -> Result<(), Infeasible> {
    let compliance = cfg.campaign.nongeometric.contains(&TermFamily::Compliance);
    if compliance && nominal.masses.is_empty() {
        return Err(Infeasible::ComplianceWithoutMasses);
    }
    Ok(())
}

/// The model is one a 1D stage along `axis` can measure (module doc).
fn check_measurable(model: ObsModel, axis: &SignedAxis) -> Result<(), Infeasible> {
    let reason = match model {
        ObsModel::Position => return Ok(()),
        ObsModel::Np if axis.is_named_along(0) => return Ok(()),
        ObsModel::Op if axis.is_named_along(1) => return Ok(()),
        ObsModel::Np => format!("measures flange x (n): stage.axis must be +x or -x, not {axis}"),
        ObsModel::Op => format!("measures flange y (o): stage.axis must be +y or -y, not {axis}"),
        ObsModel::Full => "needs the full flange orientation (n, o and a: a 6-DOF measurement); \
                           a 1D stage measures one flange axis per pose: use np or op"
            .to_owned(),
    };
    Err(Infeasible::NotMeasurable {
        model: model.name(),
        reason,
    })
}

/// The tracker position is finite (the line-of-sight check divides by the distance to it).
fn check_tracker(cfg: &CellConfig) -> Result<(), Infeasible> {
    let p = cfg.tracker.position_mm;
    if p.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(Infeasible::TrackerPosition(p))
    }
}

/// P1 and P1 + travel inside `stage.range_mm`.
fn check_stage_range(cfg: &CellConfig) -> Result<(), Infeasible> {
    let s = &cfg.stage;
    let [min_mm, max_mm] = s.range_mm;
    let p2_mm = s.p1_mm + s.travel_mm;
    let inside = |v: f64| v >= min_mm && v <= max_mm;
    if inside(s.p1_mm) && inside(p2_mm) {
        Ok(())
    } else {
        Err(Infeasible::StageOutOfRange {
            p1_mm: s.p1_mm,
            p2_mm,
            min_mm,
            max_mm,
        })
    }
}

/// `setup.home_deg`: one value per joint inside the limits; with the tool-frame step, every
/// setup target from it passes the engine's check.
fn check_home(cfg: &CellConfig, nominal: &RobotModel) -> Result<(), Infeasible> {
    let Some(home_deg) = &cfg.setup.home_deg else {
        return Ok(());
    };
    if home_deg.len() != nominal.dof() {
        return Err(Infeasible::HomeLength {
            got: home_deg.len(),
            dof: nominal.dof(),
        });
    }
    for (index, (&value_deg, l)) in home_deg.iter().zip(&nominal.limits).enumerate() {
        let q = value_deg.to_radians();
        if !(q >= l.min && q <= l.max) {
            return Err(Infeasible::HomeOutsideLimits {
                index,
                value_deg,
                min_deg: l.min.to_degrees(),
                max_deg: l.max.to_degrees(),
            });
        }
    }
    if !cfg.setup.tool_frame {
        return Ok(());
    }
    let q0: Vec<f64> = home_deg.iter().map(|d| d.to_radians()).collect();
    let targets = plan_tool_frame(nominal, &q0, &cfg.setup.tool_frame_request())
        .map_err(|e| Infeasible::HomeTargets(e.to_string()))?;
    let req = plan_request(cfg);
    match targets
        .iter()
        .find(|t| !(nominal.within_limits(&t.q_rad) && target_ok(nominal, &t.q_rad, &req)))
    {
        Some(bad) => Err(Infeasible::HomeTargets(format!(
            "setup target {} fails the joint-limit/workspace check",
            bad.mark.label()
        ))),
        None => Ok(()),
    }
}

/// Equations ≥ 3 × structurally identifiable parameters.
fn check_ident_poses(
    cfg: &CellConfig,
    nominal: &RobotModel,
    model: ObsModel,
    ident: usize,
) -> Result<(), Infeasible> {
    let opts = identify_options(cfg);
    let candidates = all_params(nominal.dof(), opts.identify_base, opts.identify_tool);
    let parameters = structural_set(nominal, &opts.obs, &candidates)
        .identified
        .len();
    let rows = model.rows();
    let equations = ident * rows;
    if equations >= 3 * parameters {
        return Ok(());
    }
    Err(Infeasible::TooFewIdentPoses {
        model: model.name(),
        ident,
        rows,
        equations,
        parameters,
        needed_poses: (3 * parameters).div_ceil(rows),
    })
}

/// The stored model and number of identification poses of campaign `id`; the store must
/// exist (it is not created).
#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::parse_cell_config;
    use crate::model::tx60;

    fn check(text: &str) -> Result<(), Infeasible> {
        let cfg = parse_cell_config(text, Path::new("cell.toml")).unwrap();
        let mut nominal = tx60();
        nominal.tool = nalgebra::Vector3::from(cfg.campaign.tool_mm);
        check_campaign(&cfg, &nominal, cfg.campaign.ident)
    }

    fn needed_poses(text: &str) -> usize {
        match check(text) {
            Err(Infeasible::TooFewIdentPoses { needed_poses, .. }) => needed_poses,
            other => panic!("{text}: {other:?}"),
        }
    }

    #[test]
    fn compliance_needs_the_robot_files_masses() {
        let text = "[campaign]\nnongeometric = [\"harmonics\", \"compliance\"]\n";
        assert_eq!(check(text), Ok(()), "the shipped TX60 has masses");
        let cfg = parse_cell_config(text, Path::new("cell.toml")).unwrap();
        let mut bare = tx60();
        bare.masses.clear();
        let e = check_campaign(&cfg, &bare, cfg.campaign.ident).unwrap_err();
        assert_eq!(e, Infeasible::ComplianceWithoutMasses);
        assert!(e.to_string().starts_with("campaign.nongeometric: "), "{e}");
        let harmonics = parse_cell_config(
            "[campaign]\nnongeometric = [\"harmonics\"]\n",
            Path::new("cell.toml"),
        )
        .unwrap();
        assert_eq!(
            check_campaign(&harmonics, &bare, harmonics.campaign.ident),
            Ok(())
        );
    }

    #[test]
    fn the_shipped_defaults_are_feasible() {
        assert_eq!(check(""), Ok(()));
        assert_eq!(
            check("[campaign]\nmodel = \"np\"\n[stage]\naxis = \"-x\"\n"),
            Ok(())
        );
        assert_eq!(
            check("[campaign]\nmodel = \"position\"\n[stage]\naxis = \"+x\"\n"),
            Ok(())
        );
    }

    #[test]
    fn ident_poses_give_three_equations_per_identified_parameter() {
        // OP with the base: 24 MDH + 4 base parameters (the base z rotation and z shift are
        // θ1 and d1 again), 6 equations a pose → 14 poses
        let op = "[campaign]\nposes = 40\nident = 1\n";
        assert_eq!(needed_poses(op), 14);
        assert_eq!(check(&op.replace("ident = 1\n", "ident = 14\n")), Ok(()));
        assert!(check(&op.replace("ident = 1\n", "ident = 13\n")).is_err());
        // position with the base: 20 + 4 parameters, 3 equations a pose → 24 poses
        let position = "[campaign]\nposes = 40\nident = 1\nmodel = \"position\"\n";
        assert_eq!(needed_poses(position), 24);
        // without the base: 24 → 12 poses; identifying the tool too adds one parameter the
        // analysis keeps (25 → 13 poses)
        let no_base = "[campaign]\nposes = 40\nident = 1\nidentify_base = false\n";
        assert_eq!(needed_poses(no_base), 12);
        let tool = format!("{no_base}identify_tool = true\n");
        assert_eq!(needed_poses(&tool), 13);
        let e = check(&op.replace("ident = 1\n", "ident = 13\n"))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("campaign.ident: 13 identification poses give 78 equations")
                && e.contains("the 28 parameters it identifies need at least 84")
                && e.contains("at least 14 identification poses"),
            "{e}"
        );
    }

    #[test]
    fn a_1d_stage_cannot_give_what_full_needs_nor_the_other_axis() {
        for (text, want) in [
            (
                "[campaign]\nmodel = \"full\"\n",
                "campaign.model: full needs",
            ),
            (
                "[campaign]\nmodel = \"np\"\n",
                "campaign.model: np measures flange x (n): stage.axis must be +x or -x, not +y",
            ),
            (
                "[campaign]\nmodel = \"op\"\n[stage]\naxis = \"+x\"\n",
                "campaign.model: op measures flange y (o)",
            ),
        ] {
            let e = check(text).unwrap_err();
            assert!(
                matches!(e, Infeasible::NotMeasurable { .. }),
                "{text}: {e:?}"
            );
            assert!(e.to_string().starts_with(want), "{text}: {e}");
        }
    }

    #[test]
    fn home_must_fit_the_robot_and_carry_the_setup_targets() {
        let home = |h: &str| format!("[setup]\nhome_deg = {h}\n");
        assert_eq!(
            check(&home("[0, 30, 90, 0]")),
            Err(Infeasible::HomeLength { got: 4, dof: 6 })
        );
        let e = check(&home("[0, 30, 90, 0, 140, 0]")).unwrap_err();
        assert!(
            matches!(e, Infeasible::HomeOutsideLimits { index: 4, .. }),
            "{e:?}"
        );
        assert!(e
            .to_string()
            .starts_with("setup.home_deg[4]: 140° is outside joint 5's limits"));
        // within the limits, but the candle pose puts the flange outside the workspace box
        let e = check(&home("[0, 0, 0, 0, 45, 0]")).unwrap_err();
        assert!(matches!(e, Infeasible::HomeTargets(_)), "{e:?}");
        // the same home is not used without the tool-frame step: only its limits are checked
        assert_eq!(
            check("[setup]\ntool_frame = false\nhome_deg = [0, 0, 0, 0, 45, 0]\n"),
            Ok(())
        );
    }

    #[test]
    fn p1_and_p2_lie_in_the_stage_range() {
        for text in [
            "[stage]\np1_mm = 20\n",
            "[stage]\np1_mm = -1\n",
            "[stage]\ntravel_mm = 30\n",
            "[stage]\nrange_mm = [5, 50]\n",
        ] {
            assert!(
                matches!(check(text), Err(Infeasible::StageOutOfRange { .. })),
                "{text}"
            );
        }
        assert_eq!(check("[stage]\np1_mm = 15\n"), Ok(()));
    }

    #[test]
    fn a_tracker_position_set_in_code_is_checked_too() {
        let mut cfg = parse_cell_config("", Path::new("cell.toml")).unwrap();
        cfg.tracker.position_mm[1] = f64::NAN;
        assert!(matches!(
            check_campaign(&cfg, &tx60(), 100),
            Err(Infeasible::TrackerPosition(_))
        ));
    }

    #[test]
    fn a_campaign_to_resume_must_be_stored() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = parse_cell_config("", &dir.path().join("cell.toml")).unwrap();
        let store = dir.path().join("missing.db");
        let e = check_session(&cfg, &tx60(), &store, Some(3)).unwrap_err();
        assert!(
            matches!(e, FeasibilityError::UnknownCampaign { id: 3, .. }),
            "{e:?}"
        );
        assert!(!store.exists(), "the check must not create the store");
        let empty = dir.path().join("empty.db");
        Store::open(&empty).unwrap();
        let e = check_session(&cfg, &tx60(), &empty, Some(3)).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("campaign 3: no such campaign in "),
            "{e}"
        );
    }
}
