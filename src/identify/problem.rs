//! The calibration least-squares problem over a set of poses.

use std::borrow::Cow;
use std::ops::Range;

use nalgebra::{DVector, Vector3};

use super::normal::{Folder, NormalSums, SplitSums, BLOCK_POSES};
use super::observation::{
    residual_into, turns_directions, ColumnNeeds, JacobianSink, Measured, ObsConfig, PoseTables,
    RowMajor,
};
use super::params::{retract, ParamId};
use super::solver::{Linearization, Problem};
use crate::model::gravity::Mass;
use crate::model::kinematics::{forward_from, torques_into, Frames, Pose};
use crate::model::{Mdh, RobotModel};

/// `sin_cos` of every pose's joint values, pose after pose: no parameter changes them, so one
/// table serves the identifiability analysis, every linearisation and the metrics, which then
/// evaluate no sine or cosine per pose. With [`with_torques`](Self::with_torques) it also
/// holds every pose's gravity torques: no identified parameter changes them either (they are
/// computed on the model's torque chain, §10).
#[derive(Debug, Clone, PartialEq)]
pub struct JointTrig {
    /// `sin_cos` of the joint values, pose after pose.
    sin_cos: Vec<(f64, f64)>,
    /// Start of each pose's joint values in `sin_cos` (and the end).
    start: Vec<usize>,
    /// The gravity torques about each joint, pose after pose as `sin_cos`, and what they were
    /// computed from.
    torques: Option<(TorqueKey, Vec<f64>)>,
}

/// What gravity torques are computed from: a model's torque chain, masses and gravity.
#[derive(Debug, Clone, PartialEq)]
struct TorqueKey {
    chain: Vec<Mdh>,
    masses: Vec<Mass>,
    gravity: Vector3<f64>,
}

impl JointTrig {
    /// The table of `poses`, its two halves filled on two threads above
    /// [`PARALLEL_MIN_POSES`] (in place: no copy of the table).
    pub fn of(poses: &[Measured]) -> JointTrig {
        let mut start = Vec::with_capacity(poses.len() + 1);
        start.push(0);
        for p in poses {
            start.push(start[start.len() - 1] + p.q.len());
        }
        let mut sin_cos = vec![(0.0, 0.0); start[poses.len()]];
        let fill = |_: usize, poses: &[Measured], out: &mut [(f64, f64)]| {
            let q = poses.iter().flat_map(|p| &p.q);
            out.iter_mut().zip(q).for_each(|(sc, q)| *sc = q.sin_cos());
        };
        in_halves(poses, &mut sin_cos, &start, fill);
        JointTrig {
            sin_cos,
            start,
            torques: None,
        }
    }

    /// This table of `poses` with their gravity torques on `model`'s torque model (its torque
    /// chain, masses and gravity); unchanged when the model has no masses.
    pub fn with_torques(mut self, poses: &[Measured], model: &RobotModel) -> JointTrig {
        assert!(self.covers(poses.len()), "a joint table of other poses");
        if model.masses.is_empty() {
            return self;
        }
        let mut tau = vec![0.0; self.sin_cos.len()];
        let (start, sin_cos) = (&self.start, &self.sin_cos);
        let chain = model.torque_joints();
        in_halves(poses, &mut tau, start, |first_pose, part, out| {
            let first = start[first_pose];
            let (mut frames, mut one) = (Frames::new(), Vec::new());
            let mut at = 0;
            for p in part {
                let n = p.q.len();
                let sc = &sin_cos[first + at..first + at + n];
                forward_from(&Pose::identity(), chain, &p.q, Some(sc), &mut frames);
                torques_into(model, &frames, &model.gravity, &mut one);
                out[at..at + n].copy_from_slice(&one);
                at += n;
            }
        });
        let key = TorqueKey {
            chain: chain.to_vec(),
            masses: model.masses.clone(),
            gravity: model.gravity,
        };
        self.torques = Some((key, tau));
        self
    }

    /// `sin_cos` of pose `i`'s joint values.
    pub fn pose(&self, i: usize) -> &[(f64, f64)] {
        &self.sin_cos[self.start[i]..self.start[i + 1]]
    }

    /// The table's gravity torques when they are `model`'s (the same torque chain, masses and
    /// gravity), pose after pose; to read with [`pose_tables`](Self::pose_tables).
    pub fn torques_of(&self, model: &RobotModel) -> Option<&[f64]> {
        let (key, tau) = self.torques.as_ref()?;
        let same = key.chain == model.torque_joints()
            && key.masses == model.masses
            && key.gravity == model.gravity;
        same.then_some(tau.as_slice())
    }

    /// What the table gives of pose `i`: its sines, and its torques from `torques` (the
    /// answer of [`torques_of`](Self::torques_of)) when given.
    pub fn pose_tables<'t>(&'t self, i: usize, torques: Option<&'t [f64]>) -> PoseTables<'t> {
        let range = self.start[i]..self.start[i + 1];
        PoseTables {
            sin_cos: Some(&self.sin_cos[range.clone()]),
            torques: torques.map(|t| &t[range]),
        }
    }

    /// Whether this is the table of `n` poses.
    pub fn covers(&self, n: usize) -> bool {
        self.start.len() == n + 1
    }
}

/// Fill `out` (per joint of each pose, `start` its offsets) by `fill` over `poses`, its two
/// halves on two threads above [`PARALLEL_MIN_POSES`] (in place: no copy; `fill` gets the
/// index of a run's first pose, the run and its part of `out`).
fn in_halves<T: Send>(
    poses: &[Measured],
    out: &mut [T],
    start: &[usize],
    fill: impl Fn(usize, &[Measured], &mut [T]) + Sync,
) {
    if poses.len() < PARALLEL_MIN_POSES {
        fill(0, poses, out);
    } else {
        let half = poses.len() / 2;
        let (a, b) = out.split_at_mut(start[half]);
        std::thread::scope(|s| {
            s.spawn(|| fill(half, &poses[half..], b));
            fill(0, &poses[..half], a);
        });
    }
}

/// Stacked residuals of all poses with respect to the chosen parameters.
pub struct CalibProblem<'a> {
    poses: &'a [Measured],
    cfg: &'a ObsConfig,
    params: &'a [ParamId],
    /// The poses' joint trigonometry (own, or shared with the analysis and the metrics).
    trig: Cow<'a, JointTrig>,
    /// The columns of parameters that turn directions (the direction blocks hold only these).
    turning: Vec<usize>,
    /// Per column, its index among `turning`.
    dir_col: Vec<Option<usize>>,
    /// What the columns need of each pose.
    needs: ColumnNeeds,
}

impl<'a> CalibProblem<'a> {
    /// A problem over `poses` (weights in each pose) for `params`.
    pub fn new(poses: &'a [Measured], cfg: &'a ObsConfig, params: &'a [ParamId]) -> Self {
        Self::build(poses, Cow::Owned(JointTrig::of(poses)), cfg, params)
    }

    /// [`new`](Self::new) with the poses' joint trigonometry computed already (`trig` must be
    /// [`JointTrig::of`] these poses).
    pub fn with_trig(
        poses: &'a [Measured],
        trig: &'a JointTrig,
        cfg: &'a ObsConfig,
        params: &'a [ParamId],
    ) -> Self {
        assert!(trig.covers(poses.len()), "a joint table of other poses");
        Self::build(poses, Cow::Borrowed(trig), cfg, params)
    }

    fn build(
        poses: &'a [Measured],
        trig: Cow<'a, JointTrig>,
        cfg: &'a ObsConfig,
        params: &'a [ParamId],
    ) -> Self {
        let turning: Vec<usize> = (0..params.len())
            .filter(|&c| turns_directions(&params[c]))
            .collect();
        let mut dir_col = vec![None; params.len()];
        for (j, &c) in turning.iter().enumerate() {
            dir_col[c] = Some(j);
        }
        CalibProblem {
            poses,
            cfg,
            params,
            trig,
            turning,
            dir_col,
            needs: ColumnNeeds::of(params),
        }
    }

    /// `rᵀr` of pose `i` at a state (its sines, and its torques when `torques` is the table's
    /// of that state, from the joint table; `res` has a pose's rows).
    fn squared_residual(
        &self,
        state: &RobotModel,
        torques: Option<&[f64]>,
        i: usize,
        res: &mut [f64],
    ) -> f64 {
        let (p, t) = (&self.poses[i], self.trig.pose_tables(i, torques));
        let mut none = RowMajor {
            jac: &mut [],
            np: self.params.len(),
        };
        residual_into(
            state,
            p,
            t,
            self.cfg,
            self.params,
            self.needs,
            res,
            &mut none,
        );
        res.iter().map(|r| r * r).sum()
    }

    /// Weighted residual norm of each pose at a state.
    pub fn pose_norms(&self, state: &RobotModel) -> Vec<f64> {
        let mut res = vec![0.0; self.cfg.model.rows()];
        let torques = self.trig.torques_of(state);
        (0..self.poses.len())
            .map(|i| self.squared_residual(state, torques, i, &mut res).sqrt())
            .collect()
    }
}

/// Poses above which the work is split over two threads.
pub const PARALLEL_MIN_POSES: usize = 256;

/// Apply `f` to two fixed halves of the index range `0..n` on two threads (or to all of it on
/// this thread when `n` is small). The split does not depend on the machine, so sums are
/// bit-for-bit reproducible.
pub fn split_map<R: Send>(n: usize, f: impl Fn(Range<usize>) -> R + Sync) -> Vec<R> {
    if n < PARALLEL_MIN_POSES {
        return vec![f(0..n)];
    }
    let half = n / 2;
    std::thread::scope(|s| {
        let hb = s.spawn(|| f(half..n));
        let ra = f(0..half);
        match hb.join() {
            Ok(rb) => vec![ra, rb],
            Err(_) => vec![ra, f(half..n)],
        }
    })
}

/// The vectors of [`split_map`]'s parts, in order, joined into the first one's room (a first
/// part with room for all copies nothing); the first error in that order.
pub fn join_parts<T, E>(parts: impl IntoIterator<Item = Result<Vec<T>, E>>) -> Result<Vec<T>, E> {
    let mut parts = parts.into_iter();
    let mut out = parts.next().unwrap_or_else(|| Ok(Vec::new()))?;
    for part in parts {
        out.extend(part?);
    }
    Ok(out)
}

/// Writes one pose's Jacobian into rows `[J r]` of a position block (all columns) and of a
/// direction block (the columns that turn directions).
struct BlockSink<'a> {
    pos: &'a mut [f64],
    dir: &'a mut [f64],
    /// Entries per row of the position block and of the direction block.
    pos_stride: usize,
    dir_stride: usize,
    /// Per column, its index in the direction block.
    dir_col: &'a [Option<usize>],
}

impl JacobianSink for BlockSink<'_> {
    fn wanted(&self) -> bool {
        true
    }

    #[inline(always)]
    fn column(&mut self, c: usize, dp: &Vector3<f64>, dd: &[Vector3<f64>]) {
        for r in 0..3 {
            self.pos[r * self.pos_stride + c] = dp[r];
        }
        if let Some(j) = self.dir_col[c] {
            for (m, d) in dd.iter().enumerate() {
                for r in 0..3 {
                    self.dir[(3 * m + r) * self.dir_stride + j] = d[r];
                }
            }
        }
    }
}

impl BlockSink<'_> {
    /// The residuals `res` (position rows, then direction rows) into the rows' residual
    /// entries (after the `k` position and the `kd` direction columns).
    fn residuals(&mut self, res: &[f64], k: usize, kd: usize) {
        let (p, d) = res.split_at(3);
        let put = |rows: &mut [f64], stride: usize, at: usize, r: &[f64]| {
            for (row, v) in rows.chunks_exact_mut(stride).zip(r) {
                row[at] = *v;
            }
        };
        put(self.pos, self.pos_stride, k, p);
        put(self.dir, self.dir_stride, kd, d);
    }
}

impl CalibProblem<'_> {
    /// Normal-equation sums of the position rows and of the direction rows (embedded in all
    /// columns) over the poses `range` under `cfg`.
    fn accumulate(
        &self,
        state: &RobotModel,
        range: Range<usize>,
        cfg: &ObsConfig,
    ) -> (NormalSums, NormalSums) {
        let k = self.params.len();
        let nd = cfg.model.rows() - 3;
        let block = BLOCK_POSES.min(range.len()).max(1);
        let mut pos = Folder::new((0..k).collect(), k, block * 3);
        let mut dir = Folder::new(self.turning.clone(), k, block * nd);
        let (pos_stride, dir_stride) = (pos.stride(), dir.stride());
        let mut res = vec![0.0; 3 + nd];
        let torques = self.trig.torques_of(state);
        for i in range.filter(|&i| self.poses[i].weight != 0.0) {
            let mut sink = BlockSink {
                pos: pos.rows(3),
                dir: dir.rows(nd),
                pos_stride,
                dir_stride,
                dir_col: &self.dir_col,
            };
            let (p, t) = (&self.poses[i], self.trig.pose_tables(i, torques));
            residual_into(
                state,
                p,
                t,
                cfg,
                self.params,
                self.needs,
                &mut res,
                &mut sink,
            );
            sink.residuals(&res, k, self.turning.len());
        }
        (pos.finish(), dir.finish())
    }

    /// `Σ Jᵢᵀ·(r(moved) − r(state) − h·J·v)` over the poses `range`, `J` and `r` row by row at
    /// `state` (the unscaled sum of [`Problem::second_directional`]).
    fn curvature_sum(
        &self,
        state: &RobotModel,
        moved: &RobotModel,
        v: &[f64],
        h: f64,
        range: Range<usize>,
    ) -> DVector<f64> {
        let (k, rows) = (self.params.len(), self.cfg.model.rows());
        let mut jac = vec![0.0; rows * k];
        let (mut r0, mut r1) = (vec![0.0; rows], vec![0.0; rows]);
        let mut sum = DVector::zeros(k);
        let (at_state, at_moved) = (self.trig.torques_of(state), self.trig.torques_of(moved));
        for i in range.filter(|&i| self.poses[i].weight != 0.0) {
            let p = &self.poses[i];
            let mut sink = RowMajor {
                jac: &mut jac,
                np: k,
            };
            residual_into(
                state,
                p,
                self.trig.pose_tables(i, at_state),
                self.cfg,
                self.params,
                self.needs,
                &mut r0,
                &mut sink,
            );
            let mut none = RowMajor {
                jac: &mut [],
                np: k,
            };
            residual_into(
                moved,
                p,
                self.trig.pose_tables(i, at_moved),
                self.cfg,
                self.params,
                self.needs,
                &mut r1,
                &mut none,
            );
            for (row, (a, b)) in jac.chunks_exact(k).zip(r0.iter().zip(&r1)) {
                let jv: f64 = row.iter().zip(v).map(|(j, x)| j * x).sum();
                let c = b - a - h * jv;
                sum.iter_mut().zip(row).for_each(|(s, j)| *s += c * j);
            }
        }
        sum
    }

    /// The sums of the position rows and of the direction rows at `state`, apart (the direction
    /// weight of the configuration is not applied).
    pub fn linearize_split(&self, state: &RobotModel) -> SplitSums {
        let k = self.params.len();
        let unit = ObsConfig {
            direction_weight_mm: 1.0,
            ..*self.cfg
        };
        let (pos, dir): (Vec<_>, Vec<_>) =
            split_map(self.poses.len(), |r| self.accumulate(state, r, &unit))
                .into_iter()
                .unzip();
        SplitSums {
            params: self.params.to_vec(),
            position: NormalSums::merge(pos, k),
            direction: NormalSums::merge(dir, k),
        }
    }
}

impl Problem for CalibProblem<'_> {
    type State = RobotModel;

    fn dim(&self) -> usize {
        self.params.len()
    }

    fn rows(&self) -> usize {
        self.poses.len() * self.cfg.model.rows()
    }

    fn linearize(&self, state: &RobotModel) -> Linearization {
        let k = self.params.len();
        let (pos, dir): (Vec<_>, Vec<_>) =
            split_map(self.poses.len(), |r| self.accumulate(state, r, self.cfg))
                .into_iter()
                .unzip();
        NormalSums::merge([NormalSums::merge(pos, k), NormalSums::merge(dir, k)], k).linearization()
    }

    fn cost(&self, state: &RobotModel) -> f64 {
        let torques = self.trig.torques_of(state);
        let parts = split_map(self.poses.len(), |range| {
            let mut res = vec![0.0; self.cfg.model.rows()];
            range
                .filter(|&i| self.poses[i].weight != 0.0)
                .map(|i| self.squared_residual(state, torques, i, &mut res))
                .sum::<f64>()
        });
        0.5 * parts.iter().sum::<f64>()
    }

    fn retract(&self, state: &RobotModel, step: &[f64]) -> RobotModel {
        retract(state, self.params, step)
    }

    fn values(&self, state: &RobotModel) -> Vec<f64> {
        self.params.iter().map(|p| p.value(state)).collect()
    }

    fn second_directional(&self, state: &RobotModel, v: &[f64], h: f64) -> Option<DVector<f64>> {
        let hv: Vec<f64> = v.iter().map(|x| h * x).collect();
        let moved = retract(state, self.params, &hv);
        let parts = split_map(self.poses.len(), |r| {
            self.curvature_sum(state, &moved, v, h, r)
        });
        let sum = parts
            .into_iter()
            .fold(DVector::zeros(self.params.len()), |a, b| a + b);
        Some(sum * (2.0 / (h * h)))
    }
}
