//! Forward kinematics of the MDH chain and the parameter screws behind the analytic Jacobians.
//!
//! A change of one MDH parameter moves everything after it rigidly: a rotation parameter turns
//! the rest of the chain about a spatial axis through a point (so a point `p` moves by
//! `axis × (p − point)` and a direction `v` by `axis × v`), a length parameter translates it
//! along an axis. [`Frames::screws`] returns these axes for all 5n parameters in the robot base
//! frame; the identification builds every Jacobian from them.

use nalgebra::{DMatrix, Matrix3, Vector3};

use super::chain::{Mdh, RobotModel};
use super::gravity::STANDARD_GRAVITY_M_S2;
pub use super::pose::Pose;

/// `sin_cos(x)` of a joint's non-geometric correction (µrad to mrad) by the Taylor series,
/// whose first omitted term is below half an ulp for `|x| ≤ 1e-3`; larger angles by the library.
pub fn sin_cos_small(x: f64) -> (f64, f64) {
    if x.abs() > 1e-3 {
        return x.sin_cos();
    }
    let x2 = x * x;
    (
        x * (1.0 - x2 / 6.0 * (1.0 - x2 / 20.0)),
        1.0 - x2 / 2.0 * (1.0 - x2 / 12.0 * (1.0 - x2 / 30.0)),
    )
}

/// Link transform `A = RotZ(θ+q) · TransZ(d) · TransX(a) · RotX(α) · RotY(β)` in closed form.
pub fn link(m: &Mdh, q: f64) -> Pose {
    link_trig(m, (m.theta + q).sin_cos(), &Twists::of(m))
}

/// Sines and cosines of a link's constant twists α and β, and the values they belong to.
#[derive(Debug, Clone, Copy)]
struct Twists {
    alpha: f64,
    beta: f64,
    sa: f64,
    ca: f64,
    sb: f64,
    cb: f64,
}

impl Twists {
    fn of(m: &Mdh) -> Twists {
        let (sa, ca) = m.alpha.sin_cos();
        let (sb, cb) = m.beta.sin_cos();
        Twists {
            alpha: m.alpha,
            beta: m.beta,
            sa,
            ca,
            sb,
            cb,
        }
    }

    /// Whether these are the twists of `m` (bitwise).
    fn belong_to(&self, m: &Mdh) -> bool {
        self.alpha.to_bits() == m.alpha.to_bits() && self.beta.to_bits() == m.beta.to_bits()
    }
}

/// [`link`] from `sin_cos(θ+q)` and the twists' sines and cosines.
fn link_trig(m: &Mdh, (st, ct): (f64, f64), t: &Twists) -> Pose {
    let (sa, ca, sb, cb) = (t.sa, t.ca, t.sb, t.cb);
    // RotZ·RotX
    let (r00, r01, r02) = (ct, -st * ca, st * sa);
    let (r10, r11, r12) = (st, ct * ca, -ct * sa);
    let (r20, r21, r22) = (0.0, sa, ca);
    // · RotY(β)
    let r = Matrix3::new(
        r00 * cb - r02 * sb,
        r01,
        r00 * sb + r02 * cb,
        r10 * cb - r12 * sb,
        r11,
        r10 * sb + r12 * cb,
        r20 * cb - r22 * sb,
        r21,
        r20 * sb + r22 * cb,
    );
    Pose {
        r,
        p: Vector3::new(m.a * ct, m.a * st, m.d),
    }
}

/// One parameter's effect: a rotation about `axis` through `point`, or a translation along `axis`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Screw {
    /// Unit axis in the robot base frame.
    pub axis: Vector3<f64>,
    /// A point on the rotation axis (unused for translations).
    pub point: Vector3<f64>,
    /// Rotation (true) or translation (false).
    pub rotation: bool,
}

impl Screw {
    /// Derivative of a point attached to the moving part.
    #[inline]
    pub fn point_rate(&self, p: &Vector3<f64>) -> Vector3<f64> {
        if self.rotation {
            self.axis.cross(&(p - self.point))
        } else {
            self.axis
        }
    }

    /// Derivative of a direction attached to the moving part.
    #[inline]
    pub fn direction_rate(&self, v: &Vector3<f64>) -> Vector3<f64> {
        if self.rotation {
            self.axis.cross(v)
        } else {
            Vector3::zeros()
        }
    }
}

/// All frames of the chain at one joint configuration (robot base frame, or that of the base
/// given to [`forward_from`]; no tool).
///
/// Reused storage ([`forward_into`]) also keeps the sines and cosines of the constant angles
/// θ, α, β and recomputes them only when the joints change, so repeated kinematics of one chain
/// evaluate one sine/cosine pair per joint, or none given those of the joint values
/// ([`forward_from`]).
#[derive(Debug, Clone)]
pub struct Frames {
    /// Frames 0 (base) … n (flange).
    pub frames: Vec<Pose>,
    /// θ_i + q_i per joint (rad).
    pub angles: Vec<f64>,
    /// `sin_cos` of each angle (shared by the link transforms and the screws).
    sin_cos: Vec<(f64, f64)>,
    /// Twist trigonometry of the chain of the previous call.
    twists: Vec<Twists>,
    /// `(θ, sin θ, cos θ)` per joint of the chain of the previous [`forward_from`] call given
    /// the joint values' sines and cosines.
    offsets: Vec<(f64, f64, f64)>,
}

impl Default for Frames {
    fn default() -> Self {
        Frames::new()
    }
}

impl Frames {
    /// Empty storage for [`forward_into`].
    pub const fn new() -> Frames {
        Frames {
            frames: Vec::new(),
            angles: Vec::new(),
            sin_cos: Vec::new(),
            twists: Vec::new(),
            offsets: Vec::new(),
        }
    }

    /// Empty storage with room for a chain of `n` joints.
    fn with_capacity(n: usize) -> Frames {
        Frames {
            frames: Vec::with_capacity(n + 1),
            angles: Vec::with_capacity(n),
            sin_cos: Vec::with_capacity(n),
            twists: Vec::with_capacity(n),
            offsets: Vec::new(),
        }
    }

    /// The flange frame `A_1 ⋯ A_n` (after the base given to [`forward_from`], if any).
    pub fn flange(&self) -> &Pose {
        &self.frames[self.frames.len() - 1]
    }

    /// The 5n parameter screws, in the per-joint order `[θ, d, a, α, β]`.
    pub fn screws(&self, joints: &[Mdh]) -> Vec<Screw> {
        let mut out = Vec::with_capacity(5 * joints.len());
        self.screws_into(joints, &mut out);
        out
    }

    /// The 5n parameter screws written into `out` (cleared first; no allocation once grown).
    pub fn screws_into(&self, joints: &[Mdh], out: &mut Vec<Screw>) {
        out.clear();
        for i in 0..joints.len() {
            let j = self.joint_axes(i);
            let screw = |axis, point, rotation| Screw {
                axis,
                point,
                rotation,
            };
            out.extend([
                screw(j.z, j.origin, true),
                screw(j.z, j.origin, false),
                screw(j.x, j.origin, false),
                screw(j.x, j.next, true),
                screw(j.y, j.next, true),
            ]);
        }
    }

    /// The axes and points behind the five screws of joint `i` (in the frame of frame 0).
    #[inline(always)]
    pub fn joint_axes(&self, i: usize) -> JointAxes {
        let prev = &self.frames[i];
        let next = &self.frames[i + 1];
        let (s, c) = self.sin_cos[i];
        JointAxes {
            z: prev.r.column(2).into_owned(),
            x: prev.r.column(0) * c + prev.r.column(1) * s,
            y: next.r.column(1).into_owned(),
            origin: prev.p,
            next: next.p,
        }
    }
}

/// The screws of one joint's parameters share three axes and two points: θ turns about `z`
/// through `origin`, d moves along `z`, a along `x`, α turns about `x` through `next`, β about
/// `y` through `next` (robot base frame, or the frame the chain was computed in).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointAxes {
    /// Joint axis (θ, d).
    pub z: Vector3<f64>,
    /// Common normal after the joint rotation (a, α).
    pub x: Vector3<f64>,
    /// y axis of the next frame (β).
    pub y: Vector3<f64>,
    /// Origin of the joint's frame (the θ screw's point).
    pub origin: Vector3<f64>,
    /// Origin of the next frame (the α and β screws' point).
    pub next: Vector3<f64>,
}

/// Forward kinematics: every frame of the chain (robot base frame, base and tool not applied)
/// at commanded joints `q`, the links turned by the model's non-geometric terms
/// ([`RobotModel::link_angles`]) when it has any.
pub fn forward(model: &RobotModel, q: &[f64]) -> Frames {
    if model.has_terms() {
        forward_joints(&model.joints, &model.link_angles(q))
    } else {
        forward_joints(&model.joints, q)
    }
}

/// Forward kinematics from bare MDH parameters.
pub fn forward_joints(joints: &[Mdh], q: &[f64]) -> Frames {
    let mut f = Frames::with_capacity(joints.len());
    forward_into(joints, q, &mut f);
    f
}

/// Forward kinematics into reusable storage (no allocation once grown).
pub fn forward_into(joints: &[Mdh], q: &[f64], f: &mut Frames) {
    forward_from(&Pose::identity(), joints, q, None, f);
}

/// [`forward_into`] with every frame expressed in the frame of `base` (frame 0 is `base`), and,
/// when `q_sin_cos` gives `sin_cos` of each joint value, `sin_cos(θ+q)` by the angle-sum
/// formulas, so no sine or cosine is evaluated once the chain's own are known.
pub fn forward_from(
    base: &Pose,
    joints: &[Mdh],
    q: &[f64],
    q_sin_cos: Option<&[(f64, f64)]>,
    f: &mut Frames,
) {
    if f.twists.len() != joints.len() || !f.twists.iter().zip(joints).all(|(t, m)| t.belong_to(m)) {
        f.twists.clear();
        f.twists.extend(joints.iter().map(Twists::of));
    }
    f.angles.clear();
    f.sin_cos.clear();
    f.angles
        .extend(joints.iter().zip(q).map(|(m, qi)| m.theta + qi));
    match q_sin_cos {
        None => f.sin_cos.extend(f.angles.iter().map(|a| a.sin_cos())),
        Some(sc) => {
            let same = |(o, m): (&(f64, f64, f64), &Mdh)| o.0.to_bits() == m.theta.to_bits();
            if f.offsets.len() != joints.len() || !f.offsets.iter().zip(joints).all(same) {
                f.offsets.clear();
                f.offsets.extend(joints.iter().map(|m| {
                    let (s, c) = m.theta.sin_cos();
                    (m.theta, s, c)
                }));
            }
            let sum = |(&(_, st, ct), &(sq, cq)): (&(f64, f64, f64), &(f64, f64))| {
                (st * cq + ct * sq, ct * cq - st * sq)
            };
            f.sin_cos
                .extend(f.offsets.iter().zip(sc).take(f.angles.len()).map(sum));
        }
    }
    f.frames.clear();
    let mut t = *base;
    f.frames.push(t);
    for ((m, sc), tw) in joints.iter().zip(&f.sin_cos).zip(&f.twists) {
        t = t.compose(&link_trig(m, *sc, tw));
        f.frames.push(t);
    }
}

/// Position of the target ball in the measurement frame: `T_base · T(q) · tool`.
pub fn measured_point(model: &RobotModel, q: &[f64]) -> Vector3<f64> {
    let f = forward(model, q);
    let fl = f.flange();
    model.base_rotation * fl.transform_point(&model.tool) + model.base_translation
}

/// Flange rotation in the measurement frame: `R_base · R(q)`.
pub fn measured_rotation(model: &RobotModel, q: &[f64]) -> Matrix3<f64> {
    model.base_rotation * forward(model, q).flange().r
}

/// Static gravity torque about each joint's +z axis (N·m) at commanded joints `q`: the weight
/// of every mass in the frames the joint moves, on the model's torque chain
/// ([`RobotModel::torque_joints`]: a corrected model's nominal one) without the non-geometric
/// terms (a deflection of a few µrad changes no lever measurably), gravity along
/// `model.gravity` in the robot base frame.
pub fn gravity_torques(model: &RobotModel, q: &[f64]) -> Vec<f64> {
    torques_of_frames(model, &forward_joints(model.torque_joints(), q))
}

/// [`gravity_torques`] from the frames of the bare chain at the commanded joints (robot base
/// frame).
///
/// From the tip inwards: with `W` the summed weight of the masses joint `j` moves and `M` the
/// sum of their moments `r × w`, `τ_j = z_j · (M − o_j × W)` (`o_j`, `z_j` the joint's origin
/// and axis), so each mass is visited once.
pub fn torques_of_frames(model: &RobotModel, frames: &Frames) -> Vec<f64> {
    let mut tau = Vec::new();
    torques_into(model, frames, &model.gravity, &mut tau);
    tau
}

/// [`torques_of_frames`] into `tau` (its length becomes the number of joints), for frames of
/// the bare chain in any frame, `gravity` the unit direction of gravity in that frame.
pub fn torques_into(
    model: &RobotModel,
    frames: &Frames,
    gravity: &Vector3<f64>,
    tau: &mut Vec<f64>,
) {
    let n = model.dof();
    tau.clear();
    tau.resize(n, 0.0);
    let (mut weight, mut moment) = (Vector3::zeros(), Vector3::zeros());
    for j in (0..n).rev() {
        // the masses of frame j + 1 (those beyond the chain's end count in its last frame)
        for m in model.masses.iter().filter(|m| m.frame.min(n) == j + 1) {
            let w = gravity * (m.kg * STANDARD_GRAVITY_M_S2); // N
            weight += w;
            moment += frames.frames[j + 1].transform_point(&m.at).cross(&w);
        }
        let joint = &frames.frames[j];
        let arm = moment - joint.p.cross(&weight);
        tau[j] = joint.r.column(2).dot(&arm) * 1e-3; // N·mm → N·m
    }
}

/// `∂τ_j/∂q_i` of the gravity torques of [`gravity_torques`] at commanded joints `q` (row `j`,
/// column `i`; N·m/rad), analytic: joint `i` turns the masses beyond it, and the axes and
/// origins of the joints after it, about its axis.
pub fn gravity_torque_rates(model: &RobotModel, q: &[f64]) -> DMatrix<f64> {
    let n = model.dof();
    let frames = forward_joints(model.torque_joints(), q);
    let axes: Vec<JointAxes> = (0..n).map(|j| frames.joint_axes(j)).collect();
    let mut rates = DMatrix::zeros(n, n);
    for m in &model.masses {
        let k = m.frame.min(n);
        let r = frames.frames[k].transform_point(&m.at);
        let w = model.gravity * (m.kg * STANDARD_GRAVITY_M_S2); // N
        for (i, turning) in axes.iter().enumerate().take(k) {
            let omega = turning.z;
            let dr = omega.cross(&(r - turning.origin));
            for (j, joint) in axes.iter().enumerate().take(k) {
                let a = r - joint.origin;
                let rate = if j <= i {
                    // joint j's axis stays; the mass turns about joint i
                    joint.z.dot(&dr.cross(&w))
                } else {
                    // joint j's axis, its origin and the mass turn together about joint i
                    omega.cross(&joint.z).dot(&a.cross(&w))
                        + joint.z.dot(&omega.cross(&a).cross(&w))
                };
                // N·mm → N·m
                rates[(j, i)] += rate * 1e-3;
            }
        }
    }
    rates
}

/// Joint configurations over the joint limits that [`gravity_levers`] probes: a fixed
/// low-discrepancy (Halton) sequence, so the answer is the same on every call.
fn probe_configurations(model: &RobotModel, count: usize) -> impl Iterator<Item = Vec<f64>> + '_ {
    const PRIMES: [u32; 8] = [2, 3, 5, 7, 11, 13, 17, 19];
    let radical_inverse = |mut i: u32, base: u32| {
        let (mut f, mut r) = (1.0, 0.0);
        while i > 0 {
            f /= f64::from(base);
            r += f * f64::from(i % base);
            i /= base;
        }
        r
    };
    (1..=count as u32).map(move |i| {
        model
            .limits
            .iter()
            .enumerate()
            .map(|(j, l)| {
                let u = radical_inverse(i, PRIMES[j % PRIMES.len()]);
                l.min + u * (l.max - l.min)
            })
            .collect()
    })
}

/// Torque below which a joint is taken to carry no gravity lever (N·m).
pub const NO_LEVER_NM: f64 = 1e-6;

/// Per joint, whether gravity puts a torque on it anywhere within the joint limits (a vertical
/// first axis, or a joint with no mass beyond it, carries none).
pub fn gravity_levers(model: &RobotModel) -> Vec<bool> {
    let mut lever = vec![false; model.dof()];
    for q in probe_configurations(model, 64) {
        for (l, t) in lever.iter_mut().zip(gravity_torques(model, &q)) {
            *l |= t.abs() > NO_LEVER_NM;
        }
    }
    lever
}

impl RobotModel {
    /// `Δθ_j(q)` of every joint (rad), the gravity torques `tau` given or computed when a
    /// compliance needs them.
    pub fn joint_corrections_with(&self, q: &[f64], tau: Option<&[f64]>) -> Vec<f64> {
        if !self.has_terms() {
            return vec![0.0; q.len()];
        }
        let own;
        let tau = match tau {
            Some(t) => t,
            None if self.has_compliance() => {
                own = gravity_torques(self, q);
                &own
            }
            None => &[],
        };
        q.iter()
            .enumerate()
            .map(|(j, qj)| {
                let t = tau.get(j).copied().unwrap_or(0.0);
                self.terms
                    .get(j)
                    .map_or(0.0, |terms| terms.correction(*qj, t))
            })
            .collect()
    }

    /// `Δθ_j(q)` of every joint (rad).
    pub fn joint_corrections(&self, q: &[f64]) -> Vec<f64> {
        self.joint_corrections_with(q, None)
    }

    /// `∂Δθ_j/∂q_i` at commanded joints `q` (row `j`, column `i`; rad/rad): the harmonics' rate
    /// on the diagonal plus each compliance times its torque's rates; zero without terms.
    pub fn correction_rates(&self, q: &[f64]) -> DMatrix<f64> {
        let n = q.len();
        let mut d = DMatrix::zeros(n, n);
        if !self.has_terms() {
            return d;
        }
        if self.has_compliance() {
            let tau = gravity_torque_rates(self, q);
            for j in 0..n.min(tau.nrows()) {
                let c = self.term(j, super::terms::TermKind::Compliance);
                for i in 0..n.min(tau.ncols()) {
                    d[(j, i)] = c * tau[(j, i)];
                }
            }
        }
        for (j, t) in self.terms.iter().enumerate().take(n) {
            d[(j, j)] += t.harmonic_rate(q[j]);
        }
        d
    }

    /// The link angles the chain turns by at commanded joints `q`: `q + Δθ(q)` (rad).
    pub fn link_angles(&self, q: &[f64]) -> Vec<f64> {
        q.iter()
            .zip(self.joint_corrections(q))
            .map(|(q, d)| q + d)
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::tx60;

    #[test]
    fn the_series_of_a_small_angle_is_the_library_sine_and_cosine_to_the_ulp() {
        let mut worst: f64 = 0.0;
        for i in -2000..=2000 {
            let x = i as f64 * 0.6e-6 + 1.3e-9;
            let ((s, c), (ls, lc)) = (sin_cos_small(x), x.sin_cos());
            worst = worst.max((s - ls).abs() / ls.abs()).max((c - lc).abs());
        }
        assert!(
            worst <= 2.0 * f64::EPSILON,
            "worst relative difference {worst:e}"
        );
        assert_eq!(
            sin_cos_small(0.5),
            0.5_f64.sin_cos(),
            "large angles by the library"
        );
        assert_eq!(sin_cos_small(0.0), (0.0, 1.0));
    }

    #[test]
    fn a_pose_is_the_rigid_transform_of_its_rotation_vector_and_translation() {
        let rv = Vector3::new(0.3, -0.2, 1.1);
        let t = Vector3::new(2400.0, -30.0, 700.0);
        let a = Pose::from_rotation_vector(&rv, t);
        assert!((a.rotation_vector() - rv).norm() < 1e-14);
        assert!((a.rotation_angle() - rv.norm()).abs() < 1e-14);
        let x = Vector3::new(1.0, 2.0, 3.0);
        assert_eq!(a.transform_point(&x), a.r * x + t);
        assert_eq!(a.transform_vector(&x), a.r * x);
        // inverse and composition
        let back = a.inverse().compose(&a);
        assert!((back.r - Matrix3::identity()).norm() < 1e-14 && back.p.norm() < 1e-12);
        assert!(back.rotation_angle() < 1e-7);
        // the robot base of a model is one
        let mut m = tx60();
        m.set_base(a);
        assert_eq!(m.base(), a);
        assert_eq!((m.base_rotation, m.base_translation), (a.r, a.p));
    }

    #[test]
    fn candle_pose() {
        let m = tx60();
        let f = forward(&m, &[0.0; 6]);
        let p = f.flange().p;
        assert!((p - Vector3::new(0.0, 20.0, 670.0)).norm() < 1e-12, "{p}");
    }

    #[test]
    fn link_matches_factor_product() {
        let m = Mdh {
            theta: 0.3,
            d: 12.0,
            a: 40.0,
            alpha: -0.7,
            beta: 0.2,
        };
        let q = 1.1;
        let rz = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), m.theta + q);
        let rx = nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), m.alpha);
        let ry = nalgebra::Rotation3::from_axis_angle(&Vector3::y_axis(), m.beta);
        let r = (rz * rx * ry).into_inner();
        let p = rz * Vector3::new(m.a, 0.0, m.d);
        let l = link(&m, q);
        assert!((l.r - r).norm() < 1e-14);
        assert!((l.p - p).norm() < 1e-12);
    }
}

#[cfg(test)]
mod gravity_tests {
    use super::*;
    use crate::model::tx60;
    use crate::model::Mass;

    fn with_mass(frame: usize, at: [f64; 3], kg: f64) -> RobotModel {
        let mut m = tx60();
        m.masses = vec![Mass {
            frame,
            at: Vector3::from(at),
            kg,
        }];
        m
    }

    #[test]
    fn torque_is_weight_times_horizontal_lever_with_the_right_sign() {
        // TX60 with the upper arm leaning: joint 2's axis is horizontal; 10 kg at frame 2's origin.
        let m = with_mass(2, [0.0, 0.0, 0.0], 10.0);
        let q = [0.2, 0.5, -0.3, 0.0, 0.0, 0.0];
        let f = forward_joints(&m.joints, &q);
        let r = f.frames[2].p;
        let axes = f.joint_axes(1);
        let lever = (r - axes.origin).cross(&(-Vector3::z())).dot(&axes.z);
        let tau = gravity_torques(&m, &q);
        let expected = 10.0 * STANDARD_GRAVITY_M_S2 * lever * 1e-3;
        assert!((tau[1] - expected).abs() < 1e-12, "{tau:?} vs {expected}");
        // the mass does not load the joints after its frame
        assert!(tau[2..].iter().all(|t| *t == 0.0), "{tau:?}");
        // numerically: τ = −∂V/∂q with V = m g h, so turning the joint against τ raises it
        let h = 1e-5;
        let (mut qp, mut qm) = (q, q);
        qp[1] += h;
        qm[1] -= h;
        let height = |q: &[f64]| forward_joints(&m.joints, q).frames[2].p.z;
        let dv = 10.0 * STANDARD_GRAVITY_M_S2 * (height(&qp) - height(&qm)) / (2.0 * h) * 1e-3;
        assert!((tau[1] + dv).abs() < 1e-6, "τ {} vs −dV/dq {}", tau[1], -dv);
    }

    #[test]
    fn a_vertical_first_axis_carries_no_lever_and_massless_joints_none_either() {
        let m = with_mass(3, [50.0, 20.0, 100.0], 5.0);
        let levers = gravity_levers(&m);
        assert_eq!(levers, vec![false, true, true, false, false, false]);
        let massless = RobotModel {
            masses: Vec::new(),
            ..tx60()
        };
        assert_eq!(gravity_levers(&massless), vec![false; 6]);
    }
}

#[cfg(test)]
mod terms_tests {
    use super::*;
    use crate::model::gravity::Mass;
    use crate::model::{tx60, TermKind};

    #[test]
    fn corrections_follow_the_formula_and_forward_kinematics_turns_by_them() {
        let mut m = tx60();
        m.masses = vec![Mass {
            frame: 3,
            at: Vector3::new(100.0, 0.0, 50.0),
            kg: 12.0,
        }];
        let q = [0.3, -0.4, 0.9, 0.2, -0.6, 1.1];
        assert_eq!(m.joint_corrections(&q), vec![0.0; 6]);
        *m.term_mut(1, TermKind::Compliance) = 2e-6;
        *m.term_mut(2, TermKind::Sin2Q) = 3e-4;
        *m.term_mut(4, TermKind::CosQ) = -1e-4;
        let tau = gravity_torques(&m, &q);
        let d = m.joint_corrections(&q);
        assert_eq!(d[1], 2e-6 * tau[1]);
        assert_eq!(d[2], 3e-4 * (2.0 * q[2]).sin());
        assert_eq!(d[4], -1e-4 * q[4].cos());
        assert_eq!([d[0], d[3], d[5]], [0.0; 3]);
        let moved = crate::model::forward(&m, &q);
        let bare = crate::model::kinematics::forward_joints(&m.joints, &m.link_angles(&q));
        assert_eq!(moved.flange(), bare.flange());
    }

    #[test]
    fn correction_rates_are_the_derivatives_of_the_corrections() {
        let mut m = tx60();
        m.gravity = Vector3::new(0.3, -0.2, -0.9).normalize();
        m.masses = [(2, [-150.0, 0.0, 120.0], 8.4), (3, [20.0, 80.0, 50.0], 5.0)]
            .into_iter()
            .chain([(5, [0.0, 10.0, 30.0], 1.5), (6, [5.0, 0.0, 60.0], 2.0)])
            .map(|(frame, at, kg)| Mass {
                frame,
                at: Vector3::from(at),
                kg,
            })
            .collect();
        for (j, c) in [(0, 1e-6), (1, 3e-6), (2, -2e-6), (3, 5e-5), (4, 4e-5)] {
            *m.term_mut(j, TermKind::Compliance) = c;
        }
        for (j, k, v) in [(0, TermKind::SinQ, 2e-4), (2, TermKind::Cos2Q, -3e-4)] {
            *m.term_mut(j, k) = v;
        }
        *m.term_mut(4, TermKind::Sin2Q) = 1e-4;
        *m.term_mut(4, TermKind::CosQ) = -2e-4;
        let q = [0.3, -0.4, 0.9, 0.2, -0.6, 1.1];
        let d = m.correction_rates(&q);
        let tau = gravity_torque_rates(&m, &q);
        let h = 1e-6;
        for i in 0..6 {
            let (mut qp, mut qm) = (q, q);
            qp[i] += h;
            qm[i] -= h;
            let (up, down) = (m.joint_corrections(&qp), m.joint_corrections(&qm));
            let (tp, tm) = (gravity_torques(&m, &qp), gravity_torques(&m, &qm));
            for j in 0..6 {
                let want = (up[j] - down[j]) / (2.0 * h);
                assert!(
                    (d[(j, i)] - want).abs() < 1e-10,
                    "∂Δθ{j}/∂q{i}: {} vs {want}",
                    d[(j, i)]
                );
                let want = (tp[j] - tm[j]) / (2.0 * h);
                assert!(
                    (tau[(j, i)] - want).abs() < 1e-5 * (1.0 + want.abs()),
                    "∂τ{j}/∂q{i}: {} vs {want}",
                    tau[(j, i)]
                );
            }
        }
        assert!(tau.iter().filter(|v| v.abs() > 1.0).count() > 10, "{tau}");
        m.terms.clear();
        assert_eq!(m.correction_rates(&q), DMatrix::zeros(6, 6));
    }
}
