//! Forward kinematics of the MDH chain and the parameter screws behind the analytic Jacobians.
//!
//! A change of one MDH parameter moves everything after it rigidly: a rotation parameter turns
//! the rest of the chain about a spatial axis through a point (so a point `p` moves by
//! `axis × (p − point)` and a direction `v` by `axis × v`), a length parameter translates it
//! along an axis. [`Frames::screws`] returns these axes for all 5n parameters in the robot base
//! frame; the identification builds every Jacobian from them.

use nalgebra::{Matrix3, Vector3};

use super::chain::{Mdh, RobotModel};
pub use super::pose::Pose;

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

/// Forward kinematics: every frame of the chain (robot base frame, base and tool not applied).
pub fn forward(model: &RobotModel, q: &[f64]) -> Frames {
    forward_joints(&model.joints, q)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::tx60;

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
