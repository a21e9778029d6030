//! Path checks of joint moves. The robot moves linearly in joint space (MOVEJ), so a move from
//! `a` to `b` sweeps `q(t) = a + t (b − a)`, `t ∈ [0, 1]`; every point of that sweep is held to
//! the joint limits, the workspace box grown by [`Workspace::path_margin_mm`] (flange origin and
//! ball), the floor (every frame origin and the ball) and the wrist-singularity distance.
//!
//! Guarantee. The move is checked on the grid `t_k = k / N`, `k = 0 ..= N`, with
//! `N = ⌈L / PATH_STEP_MM⌉` and `L = Σ_i |b_i − a_i| · R_i`, where the lever arm
//! `R_i = Σ_{j ≥ i} √(a_j² + d_j²) + |tool|` bounds the distance of every checked point moved by
//! joint `i` from that joint's axis. A checked point's speed is `|Σ_i q̇_i z_i × (p − o_i)| ≤ L`,
//! so no checked point (frame origins, flange, ball) moves more than [`PATH_STEP_MM`] between
//! consecutive grid samples, and every point of the continuous sweep lies within
//! `PATH_STEP_MM / 2` of a checked sample. Grid samples are evaluated in order; a sample whose
//! clearance (to the grown box faces, the floor, the joint limits, the wrist limit) exceeds
//! what the next `m` samples can change (`m · L / N` mm; the wrist angle depends on the fifth
//! joint only and changes by at most `|Δq_5| / N` per sample) certifies those `m` samples
//! without forward kinematics. Every grid sample is thus decided, and a failure names the first
//! failing grid sample exactly. Pure and deterministic.

use nalgebra::Vector3;

use super::workspace::{wrist_angle_rad, Workspace};
use crate::model::kinematics::{forward_into, Frames};
use crate::model::{JointLimit, Mdh, RobotModel};

/// Largest displacement (mm) of any checked point (frame origins, flange, ball) between two
/// consecutive samples of a checked move.
pub const PATH_STEP_MM: f64 = 10.0;

/// A point of the arm that the path check follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CheckedPoint {
    /// Origin of frame `k` (1-based: after joint `k`), not the flange.
    Frame(usize),
    /// The flange origin.
    Flange,
    /// The target ball (tool point).
    Ball,
    /// The target ball with the stage at P2 (see [`PathChecker::with_ball_at_p2`]).
    BallAtP2,
}

impl std::fmt::Display for CheckedPoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CheckedPoint::Frame(k) => write!(f, "frame {k} origin"),
            CheckedPoint::Flange => f.write_str("flange"),
            CheckedPoint::Ball => f.write_str("ball"),
            CheckedPoint::BallAtP2 => f.write_str("ball at P2"),
        }
    }
}

/// A face of the workspace box (robot base frame).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BoxFace {
    /// x = centre − size/2 − margin.
    XMin,
    /// x = centre + size/2 + margin.
    XMax,
    /// y = centre − size/2 − margin.
    YMin,
    /// y = centre + size/2 + margin.
    YMax,
    /// z = centre − size/2 − margin.
    ZMin,
    /// z = centre + size/2 + margin.
    ZMax,
}

impl BoxFace {
    /// The face crossed along `axis` (0 = x) on the positive or negative side.
    fn of(axis: usize, positive: bool) -> BoxFace {
        const FACES: [[BoxFace; 2]; 3] = [
            [BoxFace::XMin, BoxFace::XMax],
            [BoxFace::YMin, BoxFace::YMax],
            [BoxFace::ZMin, BoxFace::ZMax],
        ];
        FACES[axis][usize::from(positive)]
    }
}

impl std::fmt::Display for BoxFace {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            BoxFace::XMin => "−x",
            BoxFace::XMax => "+x",
            BoxFace::YMin => "−y",
            BoxFace::YMax => "+y",
            BoxFace::ZMin => "−z",
            BoxFace::ZMax => "+z",
        })
    }
}

/// Which check a configuration fails (the first in the order joints, limits, box, floor, wrist).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PathCheck {
    /// Wrong number of joint values, or a value that is not finite.
    #[error("joint values {q_rad:?} are not {dof} finite numbers")]
    Joints {
        /// Joints of the model.
        dof: usize,
        /// The values given (rad).
        q_rad: Vec<f64>,
    },
    /// A joint outside its limits.
    #[error(
        "joint {joint} at {:.3}° is outside its limits [{:.3}°, {:.3}°]",
        q_rad.to_degrees(), min_rad.to_degrees(), max_rad.to_degrees()
    )]
    JointLimit {
        /// Joint number (1-based).
        joint: usize,
        /// Its value (rad).
        q_rad: f64,
        /// Lower limit (rad).
        min_rad: f64,
        /// Upper limit (rad).
        max_rad: f64,
    },
    /// A point beyond a face of the grown workspace box.
    #[error("{point} is {outside_mm:.1} mm beyond the {face} face of the workspace box grown by {margin_mm} mm")]
    Box {
        /// The point.
        point: CheckedPoint,
        /// The face it crossed.
        face: BoxFace,
        /// How far beyond the grown face (mm).
        outside_mm: f64,
        /// The margin the box was grown by (mm).
        margin_mm: f64,
    },
    /// A point at or below the floor.
    #[error("{point} at z = {z_mm:.1} mm is not above the floor at {floor_z_mm} mm")]
    Floor {
        /// The point.
        point: CheckedPoint,
        /// Its height (mm).
        z_mm: f64,
        /// The floor height (mm).
        floor_z_mm: f64,
    },
    /// The wrist too close to its singular configuration.
    #[error(
        "wrist {:.2}° from singular, below the minimum {:.2}°",
        angle_rad.to_degrees(), min_rad.to_degrees()
    )]
    Wrist {
        /// Angle between the axes of joints 4 and 6 (rad, 0 = singular).
        angle_rad: f64,
        /// The minimum (rad).
        min_rad: f64,
    },
}

/// The first grid sample of a move that fails a check.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("path sample {sample} of {last} (t = {:.4}): {check}", *sample as f64 / (*last).max(1) as f64)]
pub struct PathFault {
    /// Index `k` of the failing sample on the grid `t_k = k / last`.
    pub sample: usize,
    /// Index of the last sample (`N`: the target).
    pub last: usize,
    /// The failing configuration (rad).
    pub q_rad: Vec<f64>,
    /// The check it fails.
    pub check: PathCheck,
}

/// Clearances of one configuration: how far each checked quantity may change before it fails.
#[derive(Debug, Clone, Copy)]
struct Clearance {
    /// Distance of the checked points to the grown box faces and the floor (mm).
    points_mm: f64,
    /// Wrist angle above the minimum (rad; infinite when there is no wrist check).
    wrist_rad: f64,
}

/// Checks configurations and joint moves against one model, workspace and tool; keeps its
/// forward-kinematics storage between calls.
#[derive(Debug, Clone)]
pub struct PathChecker {
    joints: Vec<Mdh>,
    limits: Vec<JointLimit>,
    workspace: Workspace,
    tool_mm: Vector3<f64>,
    /// The ball with the stage at P2 (flange frame, mm), when it is checked too.
    p2_mm: Option<Vector3<f64>>,
    /// `R_i` per joint (mm): bound on the distance of any checked point from joint i's axis.
    lever_mm: Vec<f64>,
    frames: Frames,
}

impl PathChecker {
    /// A checker of `model`'s chain and limits (its base and tool are not used) with the ball
    /// at `tool_mm` in the flange frame.
    pub fn new(model: &RobotModel, workspace: &Workspace, tool_mm: &Vector3<f64>) -> PathChecker {
        PathChecker {
            joints: model.joints.clone(),
            limits: model.limits.clone(),
            workspace: *workspace,
            tool_mm: *tool_mm,
            p2_mm: None,
            lever_mm: lever_arms_mm(&model.joints, tool_mm.norm()),
            frames: Frames::new(),
        }
    }

    /// The same checker that also holds the ball at `tool_mm + offset_mm` (the stage at P2;
    /// flange frame) to every check: a configuration or move passes only with the ball at both
    /// ends of the stage travel, and so anywhere between (the box and the half-space above the
    /// floor are convex). A zero offset checks the ball at P1 only.
    pub fn with_ball_at_p2(mut self, offset_mm: &Vector3<f64>) -> PathChecker {
        if *offset_mm == Vector3::zeros() {
            self.p2_mm = None;
            self.lever_mm = lever_arms_mm(&self.joints, self.tool_mm.norm());
        } else {
            let p2 = self.tool_mm + offset_mm;
            self.p2_mm = Some(p2);
            self.lever_mm = lever_arms_mm(&self.joints, self.tool_mm.norm().max(p2.norm()));
        }
        self
    }

    /// The workspace checked against.
    pub fn workspace(&self) -> &Workspace {
        &self.workspace
    }

    /// Number of grid steps `N` of the move `from → to` (samples `0 ..= N`); 0 for no motion.
    /// Both ends must hold `dof` finite values (see [`PathChecker::check_pose`]).
    pub fn steps(&self, from: &[f64], to: &[f64]) -> usize {
        let sweep_mm = self.sweep_bound_mm(from, to);
        (sweep_mm / PATH_STEP_MM).ceil() as usize
    }

    /// `L = Σ |Δq_i| R_i` (mm): bound on the path length of any checked point over the move.
    fn sweep_bound_mm(&self, from: &[f64], to: &[f64]) -> f64 {
        from.iter()
            .zip(to)
            .zip(&self.lever_mm)
            .map(|((a, b), r)| (b - a).abs() * r)
            .sum()
    }

    /// Sample `k` of `steps` of the move `from → to` (exactly `from` at 0 and `to` at `steps`).
    pub fn sample(from: &[f64], to: &[f64], k: usize, steps: usize) -> Vec<f64> {
        let mut q = to.to_vec();
        interpolate_into(from, to, k, steps, &mut q);
        q
    }

    /// Checked points of the configuration in `self.frames`: every frame origin after the
    /// base (the last is the flange), the ball and, when checked, the ball at P2.
    fn points(&self) -> impl Iterator<Item = (CheckedPoint, Vector3<f64>)> + '_ {
        let n = self.joints.len();
        let frames = &self.frames.frames[1..];
        let named = frames.iter().enumerate().map(move |(i, fr)| {
            let point = if i + 1 == n {
                CheckedPoint::Flange
            } else {
                CheckedPoint::Frame(i + 1)
            };
            (point, fr.p)
        });
        let flange = self.frames.flange();
        let ball = flange.transform_point(&self.tool_mm);
        let p2 = self
            .p2_mm
            .map(|t| (CheckedPoint::BallAtP2, flange.transform_point(&t)));
        named
            .chain(std::iter::once((CheckedPoint::Ball, ball)))
            .chain(p2)
    }

    /// Box, floor and wrist checks of the configuration whose frames are in `self.frames`;
    /// on success, the clearances.
    fn check_frames(&self) -> Result<Clearance, PathCheck> {
        let ws = &self.workspace;
        let mut points_mm = f64::INFINITY;
        for (point, p) in self.points() {
            if matches!(
                point,
                CheckedPoint::Flange | CheckedPoint::Ball | CheckedPoint::BallAtP2
            ) {
                let d = p - ws.center_mm;
                for k in 0..3 {
                    let room = 0.5 * ws.size_mm[k] + ws.path_margin_mm - d[k].abs();
                    if room < 0.0 {
                        return Err(PathCheck::Box {
                            point,
                            face: BoxFace::of(k, d[k] > 0.0),
                            outside_mm: -room,
                            margin_mm: ws.path_margin_mm,
                        });
                    }
                    points_mm = points_mm.min(room);
                }
            }
        }
        for (point, p) in self.points() {
            let above = p.z - ws.floor_z_mm;
            if above <= 0.0 {
                return Err(PathCheck::Floor {
                    point,
                    z_mm: p.z,
                    floor_z_mm: ws.floor_z_mm,
                });
            }
            points_mm = points_mm.min(above);
        }
        let wrist_rad = match wrist_angle_rad(&self.frames) {
            Some(angle) if angle < ws.wrist_min_rad => {
                return Err(PathCheck::Wrist {
                    angle_rad: angle,
                    min_rad: ws.wrist_min_rad,
                })
            }
            Some(angle) => angle - ws.wrist_min_rad,
            None => f64::INFINITY,
        };
        Ok(Clearance {
            points_mm,
            wrist_rad,
        })
    }

    /// Joint count and finiteness.
    fn check_joints(&self, q: &[f64]) -> Result<(), PathCheck> {
        if q.len() != self.joints.len() || q.iter().any(|v| !v.is_finite()) {
            return Err(PathCheck::Joints {
                dof: self.joints.len(),
                q_rad: q.to_vec(),
            });
        }
        Ok(())
    }

    /// Joint limits.
    fn check_limits(&self, q: &[f64]) -> Result<(), PathCheck> {
        for (i, (v, l)) in q.iter().zip(&self.limits).enumerate() {
            if !l.contains(*v) {
                return Err(PathCheck::JointLimit {
                    joint: i + 1,
                    q_rad: *v,
                    min_rad: l.min,
                    max_rad: l.max,
                });
            }
        }
        Ok(())
    }

    /// Whether one configuration passes every path check (the box grown by the margin).
    pub fn check_pose(&mut self, q: &[f64]) -> Result<(), PathCheck> {
        self.check_joints(q)?;
        self.check_limits(q)?;
        forward_into(&self.joints, q, &mut self.frames);
        self.check_frames().map(|_| ())
    }

    /// Whether the joint move `from → to` passes every check at every grid sample (see the
    /// module documentation for the guarantee); otherwise the first failing sample.
    pub fn check_move(&mut self, from: &[f64], to: &[f64]) -> Result<(), PathFault> {
        let fault = |sample, last, q: &[f64], check| PathFault {
            sample,
            last,
            q_rad: q.to_vec(),
            check,
        };
        self.check_joints(from).map_err(|c| fault(0, 0, from, c))?;
        self.check_joints(to).map_err(|c| fault(0, 0, to, c))?;
        let steps = self.steps(from, to);
        let step_mm = self.sweep_bound_mm(from, to) / steps.max(1) as f64;
        let wrist_step_rad = self.wrist_step_rad(from, to, steps);
        let mut q = from.to_vec();
        let mut k = 0;
        loop {
            interpolate_into(from, to, k, steps, &mut q);
            self.check_limits(&q).map_err(|c| fault(k, steps, &q, c))?;
            forward_into(&self.joints, &q, &mut self.frames);
            let clear = self.check_frames().map_err(|c| fault(k, steps, &q, c))?;
            if k >= steps {
                return Ok(());
            }
            let certified = certified_steps(clear.points_mm, step_mm)
                .min(certified_steps(clear.wrist_rad, wrist_step_rad))
                .min(self.limit_steps(&q, from, to, steps));
            k = (k + 1 + certified).min(steps);
        }
    }

    /// Largest change of the wrist angle per grid step (rad): the angle between the axes of
    /// joints 4 and 6 depends on joint 5 alone and changes no faster than it.
    fn wrist_step_rad(&self, from: &[f64], to: &[f64], steps: usize) -> f64 {
        if self.joints.len() != 6 {
            return 0.0;
        }
        (to[4] - from[4]).abs() / steps.max(1) as f64
    }

    /// Grid steps after the configuration `q` certified inside the joint limits.
    fn limit_steps(&self, q: &[f64], from: &[f64], to: &[f64], steps: usize) -> usize {
        q.iter()
            .zip(from.iter().zip(to))
            .zip(&self.limits)
            .map(|((v, (a, b)), l)| {
                let per_step = (b - a).abs() / steps.max(1) as f64;
                certified_steps((v - l.min).min(l.max - v), per_step)
            })
            .min()
            .unwrap_or(usize::MAX)
    }
}

/// Grid steps certified by a clearance `clear` when each step changes the quantity by at most
/// `per_step`: the largest `m` with `m · per_step < clear`.
fn certified_steps(clear: f64, per_step: f64) -> usize {
    if per_step <= 0.0 {
        return usize::MAX;
    }
    let m = (clear / per_step * (1.0 - 1e-12)).ceil() - 1.0;
    if m >= usize::MAX as f64 {
        usize::MAX
    } else {
        m.max(0.0) as usize
    }
}

/// Sample `k` of `steps` written into `q` (exactly `to` at the last sample).
fn interpolate_into(from: &[f64], to: &[f64], k: usize, steps: usize, q: &mut [f64]) {
    if k >= steps {
        q.copy_from_slice(to);
        return;
    }
    let t = k as f64 / steps as f64;
    for ((v, a), b) in q.iter_mut().zip(from).zip(to) {
        *v = a + t * (b - a);
    }
}

/// `R_i = Σ_{j ≥ i} √(a_j² + d_j²) + tool` per joint (mm): the distance from joint i's axis
/// (through the origin of frame i − 1) of any point carried by joints i…n is at most the sum of
/// the translations of links i…n and the tool.
fn lever_arms_mm(joints: &[Mdh], tool_mm: f64) -> Vec<f64> {
    let mut out = vec![0.0; joints.len()];
    let mut sum = tool_mm;
    for (i, m) in joints.iter().enumerate().rev() {
        sum += m.a.hypot(m.d);
        out[i] = sum;
    }
    out
}

/// Which side of its singular configuration the wrist of a 6-axis arm is bent to: the sign of
/// `(z4 × z6) · z5` (Stäubli TX60: positive for q5 > 0); `None` for other arms or a singular
/// wrist.
pub fn wrist_side(f: &Frames) -> Option<bool> {
    if f.frames.len() != 7 {
        return None;
    }
    let z4 = f.frames[3].r.column(2);
    let z5 = f.frames[4].r.column(2);
    let z6 = f.frames[5].r.column(2);
    let s = z4.cross(&z6).dot(&z5);
    (s != 0.0).then_some(s > 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::kinematics::forward;
    use crate::model::tx60;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn tool() -> Vector3<f64> {
        Vector3::new(0.0, 0.0, 60.0)
    }

    fn rad(deg: [f64; 6]) -> Vec<f64> {
        deg.iter().map(|d| d.to_radians()).collect()
    }

    /// Every checked point of `q`: frame origins after the base, then the ball.
    fn points(m: &RobotModel, q: &[f64]) -> Vec<Vector3<f64>> {
        let f = forward(m, q);
        let mut out: Vec<Vector3<f64>> = f.frames[1..].iter().map(|fr| fr.p).collect();
        out.push(f.flange().transform_point(&tool()));
        out
    }

    fn random_move(m: &RobotModel, rng: &mut ChaCha8Rng) -> (Vec<f64>, Vec<f64>) {
        let mut draw = || -> Vec<f64> {
            m.limits
                .iter()
                .map(|l| rng.random_range(l.min..=l.max))
                .collect()
        };
        (draw(), draw())
    }

    #[test]
    fn no_checked_point_moves_more_than_the_step_between_samples() {
        let m = tx60();
        let c = PathChecker::new(&m, &Workspace::default(), &tool());
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut largest: f64 = 0.0;
        for _ in 0..200 {
            let (a, b) = random_move(&m, &mut rng);
            let n = c.steps(&a, &b);
            let mut prev = points(&m, &a);
            for k in 1..=n {
                let next = points(&m, &PathChecker::sample(&a, &b, k, n));
                for (p, q) in prev.iter().zip(&next) {
                    largest = largest.max((q - p).norm());
                }
                prev = next;
            }
            assert_eq!(PathChecker::sample(&a, &b, n, n), b);
        }
        assert!(largest <= PATH_STEP_MM, "{largest} mm between samples");
        // the bound is not wasteful by orders of magnitude
        assert!(largest > 0.2 * PATH_STEP_MM, "{largest} mm between samples");
    }

    #[test]
    fn skipping_decides_every_grid_sample_like_checking_each() {
        let m = tx60();
        let ws = Workspace::default();
        let mut c = PathChecker::new(&m, &ws, &tool());
        let mut brute = PathChecker::new(&m, &ws, &tool());
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let (mut passed, mut failed) = (0, 0);
        for _ in 0..300 {
            let (a, b) = random_move(&m, &mut rng);
            let n = c.steps(&a, &b);
            let first_bad = (0..=n).find_map(|k| {
                let q = PathChecker::sample(&a, &b, k, n);
                brute.check_pose(&q).err().map(|check| (k, check))
            });
            match (c.check_move(&a, &b), first_bad) {
                (Ok(()), None) => passed += 1,
                (Err(f), Some((k, check))) => {
                    assert_eq!((f.sample, f.last, &f.check), (k, n, &check));
                    failed += 1;
                }
                (r, b) => panic!("check_move {r:?}, every sample {b:?}"),
            }
        }
        assert!(passed > 0 && failed > 0, "{passed} passed, {failed} failed");
    }

    #[test]
    fn a_move_leaving_the_box_between_inside_ends_is_named() {
        let m = tx60();
        let ws = Workspace::default();
        let mut c = PathChecker::new(&m, &ws, &tool());
        // elbow flip: both flanges inside the box, the ball swings out past +y on the way
        let a = rad([64.0, 96.0, -77.0, 71.0, 47.0, -84.0]);
        let b = rad([66.0, 14.0, 108.0, -52.0, 47.0, 50.0]);
        assert!(ws.accepts(&m, &a) && ws.accepts(&m, &b));
        assert_eq!(c.check_pose(&a), Ok(()));
        assert_eq!(c.check_pose(&b), Ok(()));
        let f = c.check_move(&a, &b).unwrap_err();
        assert!(f.sample > 0 && f.sample < f.last, "{f}");
        let PathCheck::Box {
            point,
            face,
            outside_mm,
            margin_mm,
        } = f.check
        else {
            panic!("{f}")
        };
        assert_eq!(
            (point, face, margin_mm),
            (CheckedPoint::Ball, BoxFace::YMax, 100.0)
        );
        let ball = points(&m, &f.q_rad)[6];
        let beyond = ball.y - (ws.center_mm.y + 0.5 * ws.size_mm.y + margin_mm);
        assert!(
            (beyond - outside_mm).abs() < 1e-9 && beyond > 0.0,
            "{beyond}"
        );
        assert!(f.to_string().contains("+y face"), "{f}");
    }

    #[test]
    fn crossing_the_wrist_singularity_is_named_at_the_first_sample_below_the_minimum() {
        let m = tx60();
        let ws = Workspace::default();
        let mut c = PathChecker::new(&m, &ws, &tool());
        let a = rad([-173.0, -33.0, -21.0, -42.0, 20.0, 149.0]);
        let mut b = a.clone();
        b[4] = -20f64.to_radians();
        let f = c.check_move(&a, &b).unwrap_err();
        assert!(matches!(f.check, PathCheck::Wrist { .. }), "{f}");
        let q5 = |k: usize| PathChecker::sample(&a, &b, k, f.last)[4];
        assert!(q5(f.sample).abs() < ws.wrist_min_rad);
        assert!(q5(f.sample - 1).abs() >= ws.wrist_min_rad);
        let side = |q: &[f64]| wrist_side(&forward(&m, q));
        assert_eq!(
            (side(&a), side(&b)),
            (Some(true), Some(false)),
            "TX60: q5 > 0 is the positive side"
        );
    }

    #[test]
    fn limits_floor_and_bad_input_are_named() {
        let m = tx60();
        let mut c = PathChecker::new(&m, &Workspace::default(), &tool());
        let a = rad([-173.0, -33.0, -21.0, -42.0, 20.0, 149.0]);
        let mut over = a.clone();
        over[5] = 181f64.to_radians();
        let f = c.check_move(&a, &over).unwrap_err();
        assert!(
            matches!(f.check, PathCheck::JointLimit { joint: 6, .. }),
            "{f}"
        );
        assert_eq!(
            PathChecker::sample(&a, &over, f.sample - 1, f.last)[5],
            a[5] + (f.sample - 1) as f64 * (over[5] - a[5]) / f.last as f64
        );
        assert!(f.q_rad[5] > 180f64.to_radians());
        let low = Workspace {
            floor_z_mm: 600.0,
            ..Workspace::default()
        };
        let mut c = PathChecker::new(&m, &low, &tool());
        assert!(matches!(
            c.check_pose(&a),
            Err(PathCheck::Floor {
                point: CheckedPoint::Frame(_),
                ..
            })
        ));
        for bad in [vec![0.0; 5], vec![f64::NAN; 6]] {
            assert!(matches!(
                c.check_pose(&bad),
                Err(PathCheck::Joints { dof: 6, .. })
            ));
            let f = c.check_move(&a, &bad).unwrap_err();
            assert!(matches!(f.check, PathCheck::Joints { .. }), "{f}");
        }
    }
}
