//! The tool-frame setup procedure (docs/method.md §4, paper Fig. 6) as pure functions: plan the joint
//! targets from a home pose, then turn the labelled tracker measurements into the flange frame,
//! the ball position in the flange frame (tool) and the stage axis.
//!
//! Procedure (every target is solved from the home pose `q0` on the nominal model by
//! [`crate::model::ik`]):
//! 1. home: ball at stage P1 and P2 (repeated `home_pairs` times; P2 gives the stage axis);
//! 2. jogs of the flange by `±J` along its x and y axes, orientation kept (P1 and P2): the ball
//!    displacement per commanded mm gives the flange x and y axes in the tracker frame;
//! 3. rotations about the flange x and y axes through the flange origin (P1 only): with home,
//!    these ball positions lie on a sphere about the flange origin; its least-squares centre is
//!    the flange origin in the tracker frame.
//!
//! Then `R = [x y z]` (x, y orthonormalised symmetrically, `z = x × y`), tool `t = Rᵀ(b_home − c)`
//! and the stage axis `u = normalise(Σ R_relᵀ Rᵀ (P2 − P1))` (`R_rel` the commanded rotation
//! of the pose relative to home: identity at home and jogs).
//!
//! The engine moves to each [`SetupTarget`] in order, measures P1 (and P2 when
//! [`SetupTarget::measure_p2`]), and passes one [`SetupMeasurement`] per target, with the
//! target's [`SetupMark`], to [`solve_tool_frame`]. Marks may repeat (all are used).

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::sphere::{fit_sphere, Sphere, SphereFitError};
use crate::model::ik::{solve_motion, FlangeMotion, IkError, IkOptions};
use crate::model::kinematics::Pose;
use crate::model::rotation::project_so3;
use crate::model::RobotModel;

/// What a setup measurement is: its commanded flange motion relative to home.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum SetupMark {
    /// The home pose.
    Home,
    /// Flange translated by `offset_mm` along its x axis (orientation kept).
    JogX {
        /// Commanded offset (mm).
        offset_mm: f64,
    },
    /// Flange translated by `offset_mm` along its y axis (orientation kept).
    JogY {
        /// Commanded offset (mm).
        offset_mm: f64,
    },
    /// Flange rotated by `angle_rad` about its x axis through the flange origin.
    RotX {
        /// Commanded angle (rad, right-handed).
        angle_rad: f64,
    },
    /// Flange rotated by `angle_rad` about its y axis through the flange origin.
    RotY {
        /// Commanded angle (rad, right-handed).
        angle_rad: f64,
    },
}

impl SetupMark {
    /// Short label for events and logs, e.g. `home`, `jog_x+20.000mm`, `rot_y-0.2000rad`.
    pub fn label(&self) -> String {
        match *self {
            SetupMark::Home => "home".to_string(),
            SetupMark::JogX { offset_mm } => format!("jog_x{offset_mm:+.3}mm"),
            SetupMark::JogY { offset_mm } => format!("jog_y{offset_mm:+.3}mm"),
            SetupMark::RotX { angle_rad } => format!("rot_x{angle_rad:+.4}rad"),
            SetupMark::RotY { angle_rad } => format!("rot_y{angle_rad:+.4}rad"),
        }
    }

    /// The commanded flange motion relative to home, in the home flange frame.
    pub fn motion(&self) -> FlangeMotion {
        match *self {
            SetupMark::Home => FlangeMotion::Relative(Pose::identity()),
            SetupMark::JogX { offset_mm } => FlangeMotion::Translate {
                axis: Vector3::x(),
                distance_mm: offset_mm,
            },
            SetupMark::JogY { offset_mm } => FlangeMotion::Translate {
                axis: Vector3::y(),
                distance_mm: offset_mm,
            },
            SetupMark::RotX { angle_rad } => FlangeMotion::Rotate {
                axis: Vector3::x(),
                angle_rad,
            },
            SetupMark::RotY { angle_rad } => FlangeMotion::Rotate {
                axis: Vector3::y(),
                angle_rad,
            },
        }
    }

    /// Whether the ball lies on the sphere about the home flange origin (home and rotations).
    pub fn on_sphere(&self) -> bool {
        matches!(
            self,
            SetupMark::Home | SetupMark::RotX { .. } | SetupMark::RotY { .. }
        )
    }
}

/// What to plan.
#[derive(Debug, Clone, PartialEq)]
pub struct ToolFramePlanRequest {
    /// Jog distance `J` along flange x and y, both signs (mm).
    pub jog_mm: f64,
    /// Rotation angles about flange x and about flange y (rad; non-zero).
    pub angles_rad: Vec<f64>,
    /// P1/P2 pairs measured at home (≥ 1).
    pub home_pairs: usize,
    /// Inverse-kinematics options.
    pub ik: IkOptions,
}

impl Default for ToolFramePlanRequest {
    /// J = 25 mm, angles ±0.25 and ±0.5 rad (sphere centre noise gain ≈ 6 for a ball on the
    /// flange z axis; ±0.2/±0.4 rad gives ≈ 9.5), 3 home pairs.
    fn default() -> Self {
        ToolFramePlanRequest {
            jog_mm: 25.0,
            angles_rad: vec![-0.5, -0.25, 0.25, 0.5],
            home_pairs: 3,
            ik: IkOptions::default(),
        }
    }
}

/// One planned setup target.
#[derive(Debug, Clone, PartialEq)]
pub struct SetupTarget {
    /// What this target is (pass it back with the measurement).
    pub mark: SetupMark,
    /// Joint target (rad), solved on the nominal model from the home pose.
    pub q_rad: Vec<f64>,
    /// Whether to measure the ball at stage P2 as well as P1.
    pub measure_p2: bool,
}

/// Why the setup targets could not be planned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ToolFramePlanError {
    /// The request itself is unusable.
    #[error("tool-frame plan: {0}")]
    InvalidRequest(String),
    /// A target has no inverse-kinematics solution from the home pose.
    #[error("tool-frame plan: target {label}: {cause}")]
    Ik {
        /// Label of the target.
        label: String,
        /// Why the inverse kinematics failed.
        cause: IkError,
    },
}

/// Plan the setup targets from the home pose `q0` (nominal model; order: home pairs, jogs
/// +x, −x, +y, −y, rotations about x, rotations about y, in the order of `angles_rad`).
pub fn plan_tool_frame(
    model: &RobotModel,
    q0: &[f64],
    req: &ToolFramePlanRequest,
) -> Result<Vec<SetupTarget>, ToolFramePlanError> {
    if !(req.jog_mm.is_finite() && req.jog_mm > 0.0) {
        return Err(ToolFramePlanError::InvalidRequest(format!(
            "jog distance must be positive, got {} mm",
            req.jog_mm
        )));
    }
    if req.angles_rad.len() < 2 {
        return Err(ToolFramePlanError::InvalidRequest(
            "at least two rotation angles are needed for the sphere".into(),
        ));
    }
    if let Some(a) = req.angles_rad.iter().find(|a| !a.is_finite() || **a == 0.0) {
        return Err(ToolFramePlanError::InvalidRequest(format!(
            "rotation angles must be finite and non-zero, got {a}"
        )));
    }
    if req.home_pairs == 0 {
        return Err(ToolFramePlanError::InvalidRequest(
            "at least one P1/P2 pair at home is needed for the stage axis".into(),
        ));
    }
    let mut marks: Vec<(SetupMark, bool)> = vec![(SetupMark::Home, true); req.home_pairs];
    let j = req.jog_mm;
    marks.push((SetupMark::JogX { offset_mm: j }, true));
    marks.push((SetupMark::JogX { offset_mm: -j }, true));
    marks.push((SetupMark::JogY { offset_mm: j }, true));
    marks.push((SetupMark::JogY { offset_mm: -j }, true));
    marks.extend(
        req.angles_rad
            .iter()
            .map(|&angle_rad| (SetupMark::RotX { angle_rad }, false)),
    );
    marks.extend(
        req.angles_rad
            .iter()
            .map(|&angle_rad| (SetupMark::RotY { angle_rad }, false)),
    );
    marks
        .into_iter()
        .map(|(mark, measure_p2)| {
            let q_rad = match mark {
                SetupMark::Home => {
                    if !model.within_limits(q0) {
                        return Err(ToolFramePlanError::InvalidRequest(
                            "the home pose is outside the joint limits".into(),
                        ));
                    }
                    q0.to_vec()
                }
                _ => {
                    solve_motion(model, q0, &mark.motion(), &req.ik)
                        .map_err(|cause| ToolFramePlanError::Ik {
                            label: mark.label(),
                            cause,
                        })?
                        .q
                }
            };
            Ok(SetupTarget {
                mark,
                q_rad,
                measure_p2,
            })
        })
        .collect()
}

/// One measured setup target (tracker frame, mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SetupMeasurement {
    /// The target's mark.
    pub mark: SetupMark,
    /// Ball at stage P1 (mm).
    pub p1: Vector3<f64>,
    /// Ball at stage P2 (mm), when measured.
    pub p2: Option<Vector3<f64>>,
}

/// The result of the tool-frame procedure, with its quality numbers.
#[derive(Debug, Clone, PartialEq)]
pub struct ToolFrame {
    /// Flange x axis at home (unit, tracker frame).
    pub x_axis: Vector3<f64>,
    /// Flange y axis at home (unit, tracker frame; orthogonal to x).
    pub y_axis: Vector3<f64>,
    /// Flange z axis at home, `x × y` (unit, tracker frame).
    pub z_axis: Vector3<f64>,
    /// Flange origin at home: the sphere centre (mm, tracker frame).
    pub origin_mm: Vector3<f64>,
    /// Ball at stage P1 in the flange frame: the tool translation (mm).
    pub tool_mm: Vector3<f64>,
    /// Stage axis `u` in the flange frame (unit; the ball moves by `+s·u` from P1 to P2).
    pub stage_axis: Vector3<f64>,
    /// Mean measured stage travel `‖P2 − P1‖` (mm).
    pub stage_travel_mm: f64,
    /// Number of P1/P2 pairs behind the stage axis.
    pub stage_pairs: usize,
    /// Mean ball position at home, stage P1 (mm, tracker frame).
    pub home_ball_mm: Vector3<f64>,
    /// The sphere fit (radius, RMS, residuals, conditioning).
    pub sphere: Sphere,
    /// Angle between the measured jog axes before orthonormalisation (rad; ideally π/2).
    pub jog_axes_angle_rad: f64,
    /// Measured ball displacement per commanded mm along x and y (ideally 1).
    pub jog_scale: [f64; 2],
    /// RMS distance of the jog points from their fitted lines (mm).
    pub jog_rms_mm: f64,
    /// RMS of measured − commanded rotation angles about the measured axes (rad); `None` when
    /// the ball lies (nearly) on the rotation axes.
    pub rotation_angle_rms_rad: Option<f64>,
}

impl ToolFrame {
    /// Flange rotation at home in the tracker frame (columns x, y, z).
    pub fn rotation(&self) -> Matrix3<f64> {
        Matrix3::from_columns(&[self.x_axis, self.y_axis, self.z_axis])
    }

    /// Flange pose at home in the tracker frame.
    pub fn flange_pose(&self) -> Pose {
        Pose {
            r: self.rotation(),
            p: self.origin_mm,
        }
    }
}

/// Why the tool frame could not be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ToolFrameError {
    /// No measurement at the home pose.
    #[error("tool frame: no measurement at the home pose")]
    NoHome,
    /// No jog with a non-zero offset along this axis.
    #[error("tool frame: no jog along flange {0} with a non-zero offset")]
    NoJog(&'static str),
    /// No P1/P2 pair: the stage axis is undetermined.
    #[error("tool frame: no P2 measurement, the stage axis is undetermined")]
    NoStage,
    /// P2 coincides with P1 (the stage did not move).
    #[error("tool frame: the stage did not move between P1 and P2")]
    ZeroStageTravel,
    /// A measurement contains a NaN or an infinity.
    #[error("tool frame: measurement {index} ({label}) is not finite")]
    NotFinite {
        /// Index in the input.
        index: usize,
        /// Its mark's label.
        label: String,
    },
    /// The jog axes are within 30° of parallel (a failed or mislabelled jog).
    #[error("tool frame: the measured x and y jog axes are {angle_deg:.1}° apart (expected 90°)")]
    DegenerateAxes {
        /// Angle between the axes (degrees).
        angle_deg: f64,
    },
    /// The sphere fit failed (too few or degenerate rotation points).
    #[error("tool frame: {0}")]
    Sphere(SphereFitError),
}

from_cause!(SphereFitError => ToolFrameError::Sphere);

/// Least-squares line through `(offset, point)`: slope (mm/mm) and RMS distance from the line.
fn jog_line(points: &[(f64, Vector3<f64>)]) -> Option<(Vector3<f64>, Vec<f64>)> {
    let n = points.len() as f64;
    let mo = points.iter().map(|(o, _)| o).sum::<f64>() / n;
    let mp = points.iter().map(|(_, p)| p).sum::<Vector3<f64>>() / n;
    let soo: f64 = points.iter().map(|(o, _)| (o - mo).powi(2)).sum();
    if soo <= 0.0 {
        return None;
    }
    let slope = points
        .iter()
        .map(|(o, p)| (p - mp) * (o - mo))
        .sum::<Vector3<f64>>()
        / soo;
    let res = points
        .iter()
        .map(|(o, p)| (p - mp - slope * (o - mo)).norm())
        .collect();
    Some((slope, res))
}

/// Compute the tool frame from the labelled setup measurements (tracker frame).
pub fn solve_tool_frame(meas: &[SetupMeasurement]) -> Result<ToolFrame, ToolFrameError> {
    check_finite(meas)?;
    let home_ball = mean_home_ball(meas)?;
    let axes = jog_axes(meas)?;
    let r = axes.rotation;
    // flange origin: sphere through home and the rotations
    let sphere_pts: Vec<Vector3<f64>> = meas
        .iter()
        .filter(|m| m.mark.on_sphere())
        .map(|m| m.p1)
        .collect();
    let sphere = fit_sphere(&sphere_pts)?;
    let c = sphere.centre;
    let stage = stage_axis_in_flange(meas, &r)?;
    Ok(ToolFrame {
        x_axis: r.column(0).into_owned(),
        y_axis: r.column(1).into_owned(),
        z_axis: r.column(2).into_owned(),
        origin_mm: c,
        tool_mm: r.transpose() * (home_ball - c),
        stage_axis: stage.axis,
        stage_travel_mm: stage.travel_mm,
        stage_pairs: stage.pairs,
        home_ball_mm: home_ball,
        sphere,
        jog_axes_angle_rad: axes.angle_rad,
        jog_scale: axes.scale,
        jog_rms_mm: axes.rms_mm,
        rotation_angle_rms_rad: rotation_angle_rms(meas, &r, &c, &home_ball),
    })
}

/// Every point and every commanded offset/angle finite, else the first bad measurement.
fn check_finite(meas: &[SetupMeasurement]) -> Result<(), ToolFrameError> {
    let bad = |v: &Vector3<f64>| v.iter().any(|x| !x.is_finite());
    for (index, m) in meas.iter().enumerate() {
        let bad_mark = match m.mark {
            SetupMark::Home => false,
            SetupMark::JogX { offset_mm } | SetupMark::JogY { offset_mm } => !offset_mm.is_finite(),
            SetupMark::RotX { angle_rad } | SetupMark::RotY { angle_rad } => !angle_rad.is_finite(),
        };
        if bad(&m.p1) || m.p2.as_ref().is_some_and(bad) || bad_mark {
            return Err(ToolFrameError::NotFinite {
                index,
                label: m.mark.label(),
            });
        }
    }
    Ok(())
}

/// The mean P1 of the home measurements.
fn mean_home_ball(meas: &[SetupMeasurement]) -> Result<Vector3<f64>, ToolFrameError> {
    let home: Vec<Vector3<f64>> = meas
        .iter()
        .filter(|m| m.mark == SetupMark::Home)
        .map(|m| m.p1)
        .collect();
    if home.is_empty() {
        return Err(ToolFrameError::NoHome);
    }
    Ok(home.iter().sum::<Vector3<f64>>() / home.len() as f64)
}

/// The flange x and y axes measured by the jogs, orthonormalised into a rotation.
struct JogAxes {
    /// Columns x, y, z = x × y of the flange frame in the tracker frame.
    rotation: Matrix3<f64>,
    /// Angle between the two jog lines before orthonormalisation.
    angle_rad: f64,
    /// Measured mm per commanded mm along x and y.
    scale: [f64; 2],
    /// RMS distance of the jog points from their lines.
    rms_mm: f64,
}

/// Lines through home and the jogs along x and y → the flange axes (symmetric
/// orthonormalisation, z = x × y); refused when the lines are closer than 30° to parallel.
fn jog_axes(meas: &[SetupMeasurement]) -> Result<JogAxes, ToolFrameError> {
    let jog = |name: &'static str, pick: fn(&SetupMark) -> Option<f64>| {
        let pts: Vec<(f64, Vector3<f64>)> = meas
            .iter()
            .filter_map(|m| match m.mark {
                SetupMark::Home => Some((0.0, m.p1)),
                _ => pick(&m.mark).map(|o| (o, m.p1)),
            })
            .collect();
        jog_line(&pts).ok_or(ToolFrameError::NoJog(name))
    };
    let (gx, rx) = jog("x", |m| match m {
        SetupMark::JogX { offset_mm } => Some(*offset_mm),
        _ => None,
    })?;
    let (gy, ry) = jog("y", |m| match m {
        SetupMark::JogY { offset_mm } => Some(*offset_mm),
        _ => None,
    })?;
    let (sx, sy) = (gx.norm(), gy.norm());
    let (xh, yh) = (gx / sx, gy / sy);
    let angle_rad = xh.cross(&yh).norm().atan2(xh.dot(&yh));
    if angle_rad.sin() < 0.5 {
        return Err(ToolFrameError::DegenerateAxes {
            angle_deg: angle_rad.to_degrees(),
        });
    }
    let residuals: Vec<f64> = rx.iter().chain(&ry).copied().collect();
    Ok(JogAxes {
        rotation: project_so3(&Matrix3::from_columns(&[xh, yh, xh.cross(&yh).normalize()])),
        angle_rad,
        scale: [sx, sy],
        rms_mm: (residuals.iter().map(|v| v * v).sum::<f64>() / residuals.len() as f64).sqrt(),
    })
}

/// RMS of (measured − commanded) rotation angle about the measured flange x and y axes, seen
/// from the sphere centre `c` (`None` without a usable rotation).
fn rotation_angle_rms(
    meas: &[SetupMeasurement],
    r: &Matrix3<f64>,
    c: &Vector3<f64>,
    home_ball: &Vector3<f64>,
) -> Option<f64> {
    let v0 = home_ball - c;
    let mut sq = 0.0;
    let mut count = 0usize;
    for m in meas {
        let (axis, commanded) = match m.mark {
            SetupMark::RotX { angle_rad } => (r.column(0).into_owned(), angle_rad),
            SetupMark::RotY { angle_rad } => (r.column(1).into_owned(), angle_rad),
            _ => continue,
        };
        let a = v0 - axis * axis.dot(&v0);
        let v1 = m.p1 - c;
        let b = v1 - axis * axis.dot(&v1);
        if a.norm() < 0.05 * v0.norm() || b.norm() < 0.05 * v0.norm() {
            continue;
        }
        let measured = axis.dot(&a.cross(&b)).atan2(a.dot(&b));
        sq += (measured - commanded).powi(2);
        count += 1;
    }
    (count > 0).then(|| (sq / count as f64).sqrt())
}

/// The stage axis in the flange frame: the mean of every P2 − P1 taken back through its
/// measurement's flange motion and the measured flange rotation `r`.
struct StageAxis {
    axis: Vector3<f64>,
    travel_mm: f64,
    pairs: usize,
}

fn stage_axis_in_flange(
    meas: &[SetupMeasurement],
    r: &Matrix3<f64>,
) -> Result<StageAxis, ToolFrameError> {
    let mut sum = Vector3::zeros();
    let mut travel = 0.0;
    let mut pairs = 0usize;
    for m in meas {
        let Some(p2) = m.p2 else { continue };
        let d = p2 - m.p1;
        let rel = m.mark.motion().as_pose().r;
        sum += rel.transpose() * (r.transpose() * d);
        travel += d.norm();
        pairs += 1;
    }
    if pairs == 0 {
        return Err(ToolFrameError::NoStage);
    }
    if sum.norm() <= 1e-9 {
        return Err(ToolFrameError::ZeroStageTravel);
    }
    Ok(StageAxis {
        axis: sum.normalize(),
        travel_mm: travel / pairs as f64,
        pairs,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::ik::flange_pose;
    use crate::model::rotation::from_rotation_vector;
    use crate::model::tx60;

    const HOME: [f64; 6] = [0.1, 0.4, 1.7, 0.3, -0.6, 0.2];

    /// Measure a plan on an exact robot (`model` with base and tool; stage axis `u`, travel 10).
    fn measure(
        model: &RobotModel,
        u: &Vector3<f64>,
        plan: &[SetupTarget],
    ) -> Vec<SetupMeasurement> {
        plan.iter()
            .map(|t| {
                let f = flange_pose(model, &t.q_rad);
                let at = |s: f64| {
                    model.base_rotation * f.transform_point(&(model.tool + u * s))
                        + model.base_translation
                };
                SetupMeasurement {
                    mark: t.mark,
                    p1: at(0.0),
                    p2: t.measure_p2.then(|| at(10.0)),
                }
            })
            .collect()
    }

    fn exact_cell() -> (RobotModel, Vector3<f64>) {
        let mut m = tx60();
        m.base_rotation = from_rotation_vector(&Vector3::new(0.05, -0.03, 2.9));
        m.base_translation = Vector3::new(2400.0, 300.0, -500.0);
        m.tool = Vector3::new(8.0, -25.0, 45.0);
        let u = from_rotation_vector(&Vector3::new(0.01, 0.0, -0.02)) * Vector3::y();
        (m, u)
    }

    #[test]
    fn plan_has_the_documented_order() {
        let plan = plan_tool_frame(&tx60(), &HOME, &ToolFramePlanRequest::default()).unwrap();
        let labels: Vec<String> = plan.iter().map(|t| t.mark.label()).collect();
        assert_eq!(
            labels,
            [
                "home",
                "home",
                "home",
                "jog_x+25.000mm",
                "jog_x-25.000mm",
                "jog_y+25.000mm",
                "jog_y-25.000mm",
                "rot_x-0.5000rad",
                "rot_x-0.2500rad",
                "rot_x+0.2500rad",
                "rot_x+0.5000rad",
                "rot_y-0.5000rad",
                "rot_y-0.2500rad",
                "rot_y+0.2500rad",
                "rot_y+0.5000rad",
            ]
        );
        let p2: Vec<bool> = plan.iter().map(|t| t.measure_p2).collect();
        assert_eq!(p2.iter().filter(|b| **b).count(), 7);
        // every target performs its motion on the nominal model
        let m = tx60();
        let f0 = flange_pose(&m, &HOME);
        for t in &plan {
            let want = f0.compose(&t.mark.motion().as_pose());
            let got = flange_pose(&m, &t.q_rad);
            assert!((want.p - got.p).norm() < 1e-9 && (want.r - got.r).norm() < 1e-9);
        }
    }

    #[test]
    fn exact_measurements_give_the_exact_frame() {
        let (m, u) = exact_cell();
        let plan = plan_tool_frame(&m, &HOME, &ToolFramePlanRequest::default()).unwrap();
        let tf = solve_tool_frame(&measure(&m, &u, &plan)).expect("solves");
        let truth = flange_pose(&m, &HOME);
        let r_true = m.base_rotation * truth.r;
        let o_true = m.base_rotation * truth.p + m.base_translation;
        assert!((tf.rotation() - r_true).norm() < 1e-10);
        assert!(
            (tf.origin_mm - o_true).norm() < 1e-8,
            "{}",
            tf.origin_mm - o_true
        );
        assert!(
            (tf.tool_mm - m.tool).norm() < 1e-8,
            "{}",
            tf.tool_mm - m.tool
        );
        assert!((tf.stage_axis - u).norm() < 1e-12);
        assert!((tf.stage_travel_mm - 10.0).abs() < 1e-9);
        assert_eq!(tf.stage_pairs, 7);
        assert!((tf.jog_axes_angle_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!((tf.jog_scale[0] - 1.0).abs() < 1e-12 && (tf.jog_scale[1] - 1.0).abs() < 1e-12);
        assert!(tf.jog_rms_mm < 1e-9 && tf.sphere.rms_mm < 1e-9);
        assert!((tf.sphere.radius_mm - m.tool.norm()).abs() < 1e-8);
        assert!(tf.rotation_angle_rms_rad.unwrap() < 1e-10);
        assert!((tf.flange_pose().p - o_true).norm() < 1e-8);
    }

    #[test]
    fn missing_parts_are_errors() {
        let (m, u) = exact_cell();
        let plan = plan_tool_frame(&m, &HOME, &ToolFramePlanRequest::default()).unwrap();
        let all = measure(&m, &u, &plan);
        let without = |f: &dyn Fn(&SetupMark) -> bool| -> Vec<SetupMeasurement> {
            all.iter().filter(|x| !f(&x.mark)).copied().collect()
        };
        assert_eq!(
            solve_tool_frame(&without(&|k| *k == SetupMark::Home)),
            Err(ToolFrameError::NoHome)
        );
        assert_eq!(
            solve_tool_frame(&without(&|k| matches!(k, SetupMark::JogY { .. }))),
            Err(ToolFrameError::NoJog("y"))
        );
        let no_p2: Vec<_> = all
            .iter()
            .map(|x| SetupMeasurement { p2: None, ..*x })
            .collect();
        assert_eq!(solve_tool_frame(&no_p2), Err(ToolFrameError::NoStage));
        let no_rot = without(&|k| matches!(k, SetupMark::RotX { .. } | SetupMark::RotY { .. }));
        assert!(matches!(
            solve_tool_frame(&no_rot),
            Err(ToolFrameError::Sphere(SphereFitError::TooFewPoints(3)))
        ));
        // rotations about x only: home and one circle are coplanar
        let only_x = without(&|k| matches!(k, SetupMark::RotY { .. }));
        assert!(matches!(
            solve_tool_frame(&only_x),
            Err(ToolFrameError::Sphere(SphereFitError::Degenerate { .. }))
        ));
        // swapped labels: x jogs labelled as y jogs
        let swapped: Vec<_> = all
            .iter()
            .map(|x| match x.mark {
                SetupMark::JogY { offset_mm } => SetupMeasurement {
                    mark: SetupMark::JogX { offset_mm },
                    ..*x
                },
                _ => *x,
            })
            .collect();
        assert!(matches!(
            solve_tool_frame(&swapped),
            Err(ToolFrameError::NoJog("y"))
        ));
        let mut nan = all.clone();
        nan[4].p1.z = f64::NAN;
        assert!(matches!(
            solve_tool_frame(&nan),
            Err(ToolFrameError::NotFinite { index: 4, .. })
        ));
    }

    #[test]
    fn bad_requests_are_errors() {
        let m = tx60();
        let bad = |req: ToolFramePlanRequest| {
            matches!(
                plan_tool_frame(&m, &HOME, &req),
                Err(ToolFramePlanError::InvalidRequest(_))
            )
        };
        let d = ToolFramePlanRequest::default;
        assert!(bad(ToolFramePlanRequest { jog_mm: 0.0, ..d() }));
        assert!(bad(ToolFramePlanRequest {
            angles_rad: vec![0.3],
            ..d()
        }));
        assert!(bad(ToolFramePlanRequest {
            angles_rad: vec![0.3, 0.0],
            ..d()
        }));
        assert!(bad(ToolFramePlanRequest {
            home_pairs: 0,
            ..d()
        }));
        // a jog out of reach
        let far = ToolFramePlanRequest {
            jog_mm: 2000.0,
            ..d()
        };
        assert!(matches!(
            plan_tool_frame(&m, &HOME, &far),
            Err(ToolFramePlanError::Ik { .. })
        ));
    }

    #[test]
    fn marks_serialise_with_a_kind_tag() {
        let m = SetupMark::RotY { angle_rad: -0.25 };
        let s = serde_json::to_string(&m).unwrap();
        assert_eq!(s, r#"{"kind":"rot_y","angle_rad":-0.25}"#);
        assert_eq!(serde_json::from_str::<SetupMark>(&s).unwrap(), m);
        assert_eq!(
            serde_json::to_string(&SetupMark::Home).unwrap(),
            r#"{"kind":"home"}"#
        );
    }
}
