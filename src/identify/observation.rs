//! Observation models: what is measured at each pose, its model, residuals and Jacobian rows.
//!
//! Rows per pose: position `[Δp]` (3), NP/OP `[Δp; w·ΔL]` (6) with `L = R·u` the stage axis,
//! full `[Δp; w·Δn; w·Δo; w·Δa]` (12). Residual = model − measurement. Direction rows are
//! dimensionless and multiplied by the direction weight `w` (mm); the default
//! `w = σ_p/σ_L = s/√2` (stage travel `s`) is the maximum-likelihood choice when P1 and P2 carry
//! the same isotropic noise. Every row of a pose is further multiplied by the pose weight.

use nalgebra::{Matrix3, Vector3};

use std::cell::RefCell;

use super::params::ParamId;
use crate::model::kinematics::{forward, forward_from, sin_cos_small, torques_into, Frames, Pose};
use crate::model::{ParamKind, RobotModel, TermKind};

thread_local! {
    /// Per-thread buffers of [`residual_into`], so the hot loop does not allocate.
    static SCRATCH: RefCell<Scratch> = const { RefCell::new(Scratch::new()) };
}

/// What [`residual_into`] computes on the way to one pose's residual.
struct Scratch {
    /// The chain's frames (measurement frame).
    frames: Frames,
    /// The bare chain's frames (robot base frame), for the gravity torques.
    bare: Frames,
    /// `sin_cos` of the joint values when no table gives them.
    q_sin_cos: Vec<(f64, f64)>,
    /// The joint values with their non-geometric corrections, and their `sin_cos`.
    angles: Vec<f64>,
    angle_sin_cos: Vec<(f64, f64)>,
    /// Gravity torques about each joint (N·m; empty when no term needs them).
    tau: Vec<f64>,
}

impl Scratch {
    const fn new() -> Scratch {
        Scratch {
            frames: Frames::new(),
            bare: Frames::new(),
            q_sin_cos: Vec::new(),
            angles: Vec::new(),
            angle_sin_cos: Vec::new(),
            tau: Vec::new(),
        }
    }
}

/// Which quantities the identification uses; spelled `position`, `np`, `op`, `full` in every
/// file, flag and body (serde, [`FromStr`](std::str::FromStr), [`Display`](std::fmt::Display)).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ObsModel {
    /// Position of the ball only.
    Position,
    /// Position + one stage axis (nominally flange x).
    Np,
    /// Position + one stage axis (nominally flange y).
    Op,
    /// Position + full flange rotation.
    Full,
}

impl ObsModel {
    /// Contract name: `position`, `np`, `op`, `full`.
    pub fn name(self) -> &'static str {
        match self {
            ObsModel::Position => "position",
            ObsModel::Np => "np",
            ObsModel::Op => "op",
            ObsModel::Full => "full",
        }
    }

    /// Parse a contract name (exact spelling).
    pub fn parse(s: &str) -> Result<ObsModel, UnknownModel> {
        [
            ObsModel::Position,
            ObsModel::Np,
            ObsModel::Op,
            ObsModel::Full,
        ]
        .into_iter()
        .find(|m| m.name() == s)
        .ok_or_else(|| UnknownModel(s.to_owned()))
    }

    /// Residual rows per pose.
    pub fn rows(self) -> usize {
        match self {
            ObsModel::Position => 3,
            ObsModel::Np | ObsModel::Op => 6,
            ObsModel::Full => 12,
        }
    }

    /// Independent observations per pose: position 3, a unit direction 2 more, a rotation 3
    /// more — fewer than [`rows`](Self::rows), since a unit direction's 3 rows and a rotation's
    /// 9 are constrained (the redundancy of a fit counts these, not rows).
    pub fn observations(self) -> usize {
        match self {
            ObsModel::Position => 3,
            ObsModel::Np | ObsModel::Op => 3 + 2,
            ObsModel::Full => 3 + 3,
        }
    }

    /// Default stage axis in the flange frame (+x for NP, +y for OP).
    pub fn default_stage_axis(self) -> Vector3<f64> {
        match self {
            ObsModel::Np => Vector3::x(),
            _ => Vector3::y(),
        }
    }

    /// Whether the model measures an orientation quantity.
    pub fn measures_attitude(self) -> bool {
        self != ObsModel::Position
    }
}

impl std::str::FromStr for ObsModel {
    type Err = UnknownModel;
    fn from_str(s: &str) -> Result<ObsModel, UnknownModel> {
        ObsModel::parse(s)
    }
}

impl std::fmt::Display for ObsModel {
    /// The contract name.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A name that is not an observation model.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("`{0}` is not one of position, np, op, full")]
pub struct UnknownModel(pub String);

/// How observations are turned into residuals.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObsConfig {
    /// Observation model.
    pub model: ObsModel,
    /// Unit stage axis `u` in the flange frame (NP/OP).
    pub stage_axis: Vector3<f64>,
    /// Weight of direction rows (mm per unit of direction).
    pub direction_weight_mm: f64,
}

impl ObsConfig {
    /// Default configuration for a model and a stage travel (mm): default axis, `w = s/√2`.
    pub fn new(model: ObsModel, stage_travel_mm: f64) -> ObsConfig {
        ObsConfig {
            model,
            stage_axis: model.default_stage_axis(),
            direction_weight_mm: stage_travel_mm / std::f64::consts::SQRT_2,
        }
    }
}

/// What was measured at one pose (measurement frame, mm).
#[derive(Debug, Clone, PartialEq)]
pub struct Measured {
    /// Joint values (rad).
    pub q: Vec<f64>,
    /// Ball position at stage position P1 (mm).
    pub p1: Vector3<f64>,
    /// Measured unit stage direction `(P2 − P1)/‖P2 − P1‖`, when P2 was measured.
    pub direction: Option<Vector3<f64>>,
    /// Measured flange rotation (columns n, o, a), when measured (boxed: only the full model
    /// has one, and a pose without one stays small).
    pub rotation: Option<Box<Matrix3<f64>>>,
    /// Relative weight of this pose (1 = nominal; from the tracker uncertainty model or IRLS).
    pub weight: f64,
}

impl Measured {
    /// A pose with joint values only (for structural analyses; nothing measured, weight 1).
    pub fn joints_only(q: Vec<f64>) -> Measured {
        Measured {
            q,
            p1: Vector3::zeros(),
            direction: None,
            rotation: None,
            weight: 1.0,
        }
    }
}

/// Modelled observation quantities at one pose.
#[derive(Debug, Clone, Copy)]
pub struct Predicted {
    /// Ball position in the measurement frame (mm).
    pub p: Vector3<f64>,
    /// Flange rotation in the measurement frame.
    pub r: Matrix3<f64>,
}

/// Model prediction of the point and the flange rotation at joints `q`.
pub fn predict(model: &RobotModel, q: &[f64]) -> Predicted {
    let f = forward(model, q);
    let fl = f.flange();
    Predicted {
        p: model.base_rotation * fl.transform_point(&model.tool) + model.base_translation,
        r: model.base_rotation * fl.r,
    }
}

/// Weighted residual (`rows` entries) and Jacobian (`rows × params.len()`, row-major) of one pose.
///
/// `jac` may be empty to skip the Jacobian.
pub fn residual_jacobian(
    model: &RobotModel,
    meas: &Measured,
    cfg: &ObsConfig,
    params: &[ParamId],
    res: &mut [f64],
    jac: &mut [f64],
) {
    let np = params.len();
    debug_assert!(jac.is_empty() || cfg.model.rows() * np <= jac.len());
    let needs = ColumnNeeds::of(params);
    residual_into(
        model,
        meas,
        PoseTables::default(),
        cfg,
        params,
        needs,
        res,
        &mut RowMajor { jac, np },
    );
}

/// Whether a parameter can turn the measured directions: rotations (and the non-geometric
/// terms, which turn a joint) can; the direction rows of a translation (MDH d and a, base
/// translation, tool) are zero.
pub fn turns_directions(p: &ParamId) -> bool {
    p.is_rotation()
}

/// Receives the weighted Jacobian of one pose, column by column.
pub trait JacobianSink {
    /// Whether the Jacobian is wanted at all (else only residuals are computed).
    fn wanted(&self) -> bool;
    /// Column `c`: the position rows `dp` and the rows of each measured direction `dd`
    /// (all zero for a translation parameter).
    fn column(&mut self, c: usize, dp: &Vector3<f64>, dd: &[Vector3<f64>]);
}

/// The row-major Jacobian of [`residual_jacobian`] (`rows × np`; an empty `jac` wants none).
pub(crate) struct RowMajor<'a> {
    pub(crate) jac: &'a mut [f64],
    pub(crate) np: usize,
}

impl JacobianSink for RowMajor<'_> {
    fn wanted(&self) -> bool {
        !self.jac.is_empty()
    }

    #[inline(always)]
    fn column(&mut self, c: usize, dp: &Vector3<f64>, dd: &[Vector3<f64>]) {
        let np = self.np;
        for r in 0..3 {
            self.jac[r * np + c] = dp[r];
        }
        for (k, d) in dd.iter().enumerate() {
            for r in 0..3 {
                self.jac[(3 + 3 * k + r) * np + c] = d[r];
            }
        }
    }
}

/// What the columns of a set of parameters need of each pose besides the chain's frames,
/// found once for a pass over the poses instead of once per pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ColumnNeeds {
    /// A non-geometric term is among the parameters: its basis needs the pose's sines.
    terms: bool,
    /// A compliance is: its basis needs the gravity torques.
    torques: bool,
}

impl ColumnNeeds {
    /// The needs of the columns of `params`.
    pub fn of(params: &[ParamId]) -> ColumnNeeds {
        ColumnNeeds {
            terms: params.iter().any(ParamId::is_term),
            torques: params.iter().any(|p| {
                matches!(
                    p,
                    ParamId::Term {
                        kind: TermKind::Compliance,
                        ..
                    }
                )
            }),
        }
    }
}

/// What tables may give of one pose before its residual is computed: the `sin_cos` of its
/// joint values (see [`forward_from`]) and its gravity torques on the model's torque chain
/// (N·m, [`gravity_torques`](crate::model::gravity_torques)); each computed when absent.
#[derive(Debug, Clone, Copy, Default)]
pub struct PoseTables<'a> {
    /// `sin_cos` of the joint values.
    pub sin_cos: Option<&'a [(f64, f64)]>,
    /// Gravity torques about each joint, for the model's torque model.
    pub torques: Option<&'a [f64]>,
}

/// Weighted residual (`rows` entries) of one pose, and its Jacobian into `sink`; `known`: what
/// tables give of the pose; `needs`: [`ColumnNeeds::of`] `params`.
#[allow(clippy::too_many_arguments)]
pub fn residual_into<S: JacobianSink>(
    model: &RobotModel,
    meas: &Measured,
    known: PoseTables,
    cfg: &ObsConfig,
    params: &[ParamId],
    needs: ColumnNeeds,
    res: &mut [f64],
    sink: &mut S,
) {
    SCRATCH.with(|cell| {
        let Scratch {
            frames: f,
            bare,
            q_sin_cos: own,
            angles,
            angle_sin_cos,
            tau,
        } = &mut *cell.borrow_mut();
        let base = Pose {
            r: model.base_rotation,
            p: model.base_translation,
        };
        let wants_terms = sink.wanted() && needs.terms;
        // the pose's sines: the table's when given, else computed once here when a term needs them
        let q_sin_cos = match known.sin_cos {
            None if model.has_terms() || wants_terms => {
                own.clear();
                own.extend(meas.q.iter().map(|q| q.sin_cos()));
                Some(own.as_slice())
            }
            sc => sc,
        };
        let wants_tau = model.has_compliance() || (sink.wanted() && needs.torques);
        // the torques: the table's, else from the chain's own frames when they are the torque
        // chain's turned into the measurement frame (no terms turn them), else a bare pass
        tau.clear();
        let from_frames = match known.torques {
            Some(t) if wants_tau => {
                tau.extend_from_slice(t);
                false
            }
            None if wants_tau => {
                let own_frames = !model.has_terms() && model.torques_on_own_chain();
                if !own_frames {
                    let chain = model.torque_joints();
                    forward_from(&Pose::identity(), chain, &meas.q, q_sin_cos, bare);
                    torques_into(model, bare, &model.gravity, tau);
                }
                own_frames
            }
            _ => false,
        };
        match q_sin_cos {
            Some(sc) if model.has_terms() => {
                // q + Δθ(q) and its sines by the sum identities: no sine of a joint value
                angles.clear();
                angle_sin_cos.clear();
                for (j, (q, &(s, c))) in meas.q.iter().zip(sc).enumerate() {
                    let torque = tau.get(j).copied().unwrap_or(0.0);
                    let d = model
                        .terms
                        .get(j)
                        .map_or(0.0, |t| t.correction_trig((s, c), torque));
                    let (sd, cd) = sin_cos_small(d);
                    angles.push(q + d);
                    angle_sin_cos.push((s * cd + c * sd, c * cd - s * sd));
                }
                forward_from(&base, &model.joints, angles, Some(angle_sin_cos), f);
            }
            _ => {
                forward_from(&base, &model.joints, &meas.q, q_sin_cos, f);
                // without corrections these are the bare chain's frames turned into the
                // measurement frame: the torques with gravity turned alike
                if from_frames {
                    torques_into(model, f, &(model.base_rotation * model.gravity), tau);
                }
            }
        }
        let basis = TermBasis {
            sin_cos: q_sin_cos.unwrap_or(&[]),
            tau: (!tau.is_empty()).then_some(tau.as_slice()),
        };
        residual_jacobian_with(model, meas, cfg, params, res, sink, f, &basis);
    });
}

/// What the non-geometric terms' columns multiply the joint's θ column by at one pose: the
/// commanded joint values and, when a compliance is wanted, the gravity torques.
struct TermBasis<'a> {
    /// `sin_cos` of the commanded joint values (empty when no term is wanted).
    sin_cos: &'a [(f64, f64)],
    tau: Option<&'a [f64]>,
}

impl TermBasis<'_> {
    /// The basis of term `kind` of joint `joint`.
    fn of(&self, joint: usize, kind: TermKind) -> f64 {
        let tau = self.tau.and_then(|t| t.get(joint)).copied().unwrap_or(0.0);
        kind.basis_trig(self.sin_cos[joint], tau)
    }
}

/// [`residual_into`] once `f` holds the pose's frames in the measurement frame.
#[allow(clippy::too_many_arguments)]
fn residual_jacobian_with<S: JacobianSink>(
    model: &RobotModel,
    meas: &Measured,
    cfg: &ObsConfig,
    params: &[ParamId],
    res: &mut [f64],
    sink: &mut S,
    f: &Frames,
    basis: &TermBasis,
) {
    let fl = f.flange(); // measurement frame
    let p = fl.transform_point(&model.tool); // ball, measurement frame
    let w = meas.weight;
    let wd = cfg.direction_weight_mm * w;

    // modelled directions (measurement frame) and their measured values
    let mut dirs: [(Vector3<f64>, Vector3<f64>); 3] = [(Vector3::zeros(), Vector3::zeros()); 3];
    let ndir = match cfg.model {
        ObsModel::Position => 0,
        ObsModel::Np | ObsModel::Op => {
            let d = meas.direction.unwrap_or_else(Vector3::zeros);
            dirs[0] = (fl.r * cfg.stage_axis, d);
            1
        }
        ObsModel::Full => {
            let r = meas
                .rotation
                .as_deref()
                .copied()
                .unwrap_or_else(Matrix3::zeros);
            for (k, dir) in dirs.iter_mut().enumerate() {
                *dir = (fl.r.column(k).into_owned(), r.column(k).into_owned());
            }
            3
        }
    };
    let pr = w * (p - meas.p1);
    res[..3].copy_from_slice(pr.as_slice());
    for k in 0..ndir {
        let v = wd * (dirs[k].0 - dirs[k].1);
        res[3 + 3 * k..6 + 3 * k].copy_from_slice(v.as_slice());
    }
    if !sink.wanted() {
        return;
    }
    let cols = Columns {
        params,
        frames: f,
        tb: &model.base_translation,
        p: &p,
        w,
        wd,
        basis,
    };
    // the number of directions as a constant: the column loop unrolls over them
    let models = [dirs[0].0, dirs[1].0, dirs[2].0];
    match ndir {
        0 => cols.emit::<0, S>(&[], sink),
        1 => cols.emit::<1, S>(&[models[0]], sink),
        _ => cols.emit::<3, S>(&models, sink),
    }
}

/// What the Jacobian columns of one pose are built from (measurement frame).
struct Columns<'a> {
    params: &'a [ParamId],
    /// The chain's frames, frame 0 being the base.
    frames: &'a Frames,
    /// Base translation (the base rotation's pivot).
    tb: &'a Vector3<f64>,
    /// The ball.
    p: &'a Vector3<f64>,
    /// Weight of position rows and of direction rows.
    w: f64,
    wd: f64,
    /// The bases of the non-geometric terms.
    basis: &'a TermBasis<'a>,
}

impl Columns<'_> {
    /// Every column into `sink`, given the `N` modelled directions.
    #[inline(always)]
    fn emit<const N: usize, S: JacobianSink>(&self, dirs: &[Vector3<f64>; N], sink: &mut S) {
        let turn = |axis: &Vector3<f64>| dirs.map(|d| self.wd * axis.cross(&d));
        // the θ column of the last term's joint: the terms of a joint come together
        let mut theta: Option<(usize, Vector3<f64>, [Vector3<f64>; N])> = None;
        for (c, par) in self.params.iter().enumerate() {
            let (dp, dd) = match par {
                ParamId::Mdh { joint, kind } => {
                    let j = self.frames.joint_axes(*joint);
                    match kind {
                        ParamKind::Theta => (j.z.cross(&(self.p - j.origin)), turn(&j.z)),
                        ParamKind::D => (j.z, [Vector3::zeros(); N]),
                        ParamKind::A => (j.x, [Vector3::zeros(); N]),
                        ParamKind::Alpha => (j.x.cross(&(self.p - j.next)), turn(&j.x)),
                        ParamKind::Beta => (j.y.cross(&(self.p - j.next)), turn(&j.y)),
                    }
                }
                ParamId::BaseTranslation(i) => (Vector3::ith(*i, 1.0), [Vector3::zeros(); N]),
                ParamId::BaseRotation(i) => {
                    let e = Vector3::ith(*i, 1.0);
                    (e.cross(&(self.p - self.tb)), turn(&e))
                }
                ParamId::Tool(i) => (
                    self.frames.flange().r.column(*i).into_owned(),
                    [Vector3::zeros(); N],
                ),
                // only NP/OP model the stage axis (one direction); the full model reads the
                // flange rotation, which the stage axis does not enter
                ParamId::StageAxis(i) if N == 1 => (
                    Vector3::zeros(),
                    turn(&self.frames.flange().r.column(*i).into_owned()),
                ),
                ParamId::StageAxis(_) => (Vector3::zeros(), [Vector3::zeros(); N]),
                // Δθ_j = coefficient · basis: the joint's θ column times the basis
                ParamId::Term { joint, kind } => {
                    let (dp, dd) = match theta {
                        Some((j, dp, dd)) if j == *joint => (dp, dd),
                        _ => {
                            let j = self.frames.joint_axes(*joint);
                            let (dp, dd) = (j.z.cross(&(self.p - j.origin)), turn(&j.z));
                            theta = Some((*joint, dp, dd));
                            (dp, dd)
                        }
                    };
                    let b = self.basis.of(*joint, *kind);
                    (b * dp, dd.map(|d| b * d))
                }
            };
            sink.column(c, &(self.w * dp), &dd);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::params::{all_params, retract, term_params};

    #[test]
    fn model_names_parse_once_and_unknown_ones_are_refused_clearly() {
        for m in [
            ObsModel::Position,
            ObsModel::Np,
            ObsModel::Op,
            ObsModel::Full,
        ] {
            assert_eq!(m.name().parse::<ObsModel>(), Ok(m));
            assert_eq!(m.to_string(), m.name());
            let json = serde_json::to_string(&m).unwrap();
            assert_eq!(json, format!("\"{}\"", m.name()));
            assert_eq!(serde_json::from_str::<ObsModel>(&json).unwrap(), m);
        }
        for bad in ["xyz", "OP", " op", "", "nan"] {
            assert_eq!(
                ObsModel::parse(bad).unwrap_err().to_string(),
                format!("`{bad}` is not one of position, np, op, full")
            );
            assert!(serde_json::from_str::<ObsModel>(&format!("\"{bad}\"")).is_err());
        }
    }
    use crate::model::rotation::from_rotation_vector;
    use proptest::prelude::*;

    fn tx60_with_frames() -> RobotModel {
        let mut m = crate::model::tx60();
        m.base_rotation = from_rotation_vector(&Vector3::new(0.3, -0.2, 2.0));
        m.base_translation = Vector3::new(2000.0, 300.0, -100.0);
        m.tool = Vector3::new(5.0, -12.0, 40.0);
        m.joints[2].beta = 0.01;
        m
    }

    /// [`tx60_with_frames`] with two masses and every non-geometric term non-zero, the
    /// compliances of a real arm's size (µrad/(N·m)): the torques are on the torque chain,
    /// which no parameter moves, so every column is exact (on the model's own chain an MDH
    /// column would miss `c·∂τ/∂p`, ~10⁻⁴ here).
    fn tx60_with_terms() -> RobotModel {
        let mut m = tx60_with_frames();
        m.torque_chain = Some(m.joints.clone());
        m.masses = vec![
            crate::model::Mass {
                frame: 2,
                at: Vector3::new(-150.0, 0.0, 120.0),
                kg: 8.4,
            },
            crate::model::Mass {
                frame: 5,
                at: Vector3::new(0.0, 20.0, 60.0),
                kg: 3.0,
            },
        ];
        for (i, (j, k)) in (0..6)
            .flat_map(|j| TermKind::ALL.map(|k| (j, k)))
            .enumerate()
        {
            let scale = if k == TermKind::Compliance {
                1e-6
            } else {
                1e-4
            };
            *m.term_mut(j, k) =
                scale * (1.0 + (i % 7) as f64) * if i % 2 == 0 { 1.0 } else { -1.0 };
        }
        m
    }

    fn check(model: ObsModel, q: Vec<f64>, with_terms: bool) {
        let (m, params) = if with_terms {
            let mut p = all_params(6, true, true);
            p.extend(term_params(6, &crate::model::TermFamily::ALL));
            (tx60_with_terms(), p)
        } else {
            (tx60_with_frames(), all_params(6, true, true))
        };
        let cfg = ObsConfig {
            stage_axis: Vector3::new(0.6, 0.8, 0.0),
            direction_weight_mm: 7.0,
            model,
        };
        let meas = Measured {
            q,
            p1: Vector3::new(1.0, 2.0, 3.0),
            direction: Some(Vector3::x()),
            rotation: Some(Box::new(Matrix3::identity())),
            weight: 1.3,
        };
        let rows = model.rows();
        let n = params.len();
        let mut r0 = vec![0.0; rows];
        let mut jac = vec![0.0; rows * n];
        residual_jacobian(&m, &meas, &cfg, &params, &mut r0, &mut jac);
        for (c, _) in params.iter().enumerate() {
            let h = 1e-6;
            let mut d = vec![0.0; n];
            d[c] = h;
            let mut rp = vec![0.0; rows];
            residual_jacobian(
                &retract(&m, &params, &d),
                &meas,
                &cfg,
                &params,
                &mut rp,
                &mut [],
            );
            d[c] = -h;
            let mut rm = vec![0.0; rows];
            residual_jacobian(
                &retract(&m, &params, &d),
                &meas,
                &cfg,
                &params,
                &mut rm,
                &mut [],
            );
            for r in 0..rows {
                let fd = (rp[r] - rm[r]) / (2.0 * h);
                let an = jac[r * n + c];
                assert!(
                    (fd - an).abs() <= 1e-5 * (1.0 + an.abs()),
                    "{model:?} param {} row {r}: fd {fd} analytic {an}",
                    params[c].name()
                );
            }
        }
    }

    /// The stage-axis rotation columns (a setup quantity, not in the model) against central
    /// differences of the stage axis rotated about each flange axis.
    #[test]
    fn stage_axis_columns_match_central_differences() {
        let m = tx60_with_frames();
        let q = [0.3, -0.4, 1.2, 0.5, 0.9, -0.7];
        let params = [0, 1, 2].map(ParamId::StageAxis);
        for model in [ObsModel::Np, ObsModel::Op, ObsModel::Full] {
            let cfg = ObsConfig {
                stage_axis: Vector3::new(0.6, 0.8, 0.0),
                direction_weight_mm: 7.0,
                model,
            };
            let meas = Measured {
                q: q.to_vec(),
                p1: Vector3::new(1.0, 2.0, 3.0),
                direction: Some(Vector3::x()),
                rotation: Some(Box::new(Matrix3::identity())),
                weight: 1.3,
            };
            let rows = model.rows();
            let mut r0 = vec![0.0; rows];
            let mut jac = vec![0.0; rows * 3];
            residual_jacobian(&m, &meas, &cfg, &params, &mut r0, &mut jac);
            for i in 0..3 {
                let h = 1e-6;
                let at = |t: f64| {
                    let turned = ObsConfig {
                        stage_axis: from_rotation_vector(&(Vector3::ith(i, t))) * cfg.stage_axis,
                        ..cfg
                    };
                    let mut r = vec![0.0; rows];
                    residual_jacobian(&m, &meas, &turned, &params, &mut r, &mut []);
                    r
                };
                let (rp, rm) = (at(h), at(-h));
                for r in 0..rows {
                    let fd = (rp[r] - rm[r]) / (2.0 * h);
                    let an = jac[r * 3 + i];
                    assert!(
                        (fd - an).abs() <= 1e-5 * (1.0 + an.abs()),
                        "{model:?} stage axis {i} row {r}: fd {fd} analytic {an}"
                    );
                }
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        #[test]
        fn jacobian_matches_central_differences(
            q in proptest::collection::vec(-3.0f64..3.0, 6),
            which in 0usize..4,
            with_terms: bool,
        ) {
            let model = [ObsModel::Position, ObsModel::Np, ObsModel::Op, ObsModel::Full][which];
            check(model, q, with_terms);
        }
    }
}
