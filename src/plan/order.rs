//! Measuring order by time: nearest neighbour, then 2-opt, on the time of each leg over safe
//! routes (docs/method.md §7).
//!
//! A leg's time is the synchronised joint move ([`MotionLimits::move_time_s`]) plus one settle
//! per stop; when the direct move fails the path check, the leg is the route of [`Router`]
//! (through the drift reference, the hub) and costs each of its moves and stops. A tour starts
//! at the hub, returns to it after every `drift_every` poses (not after the last) and at the
//! end, as the engine moves ([`tour_s`]).
//!
//! The nearest neighbour uses a k-d tree over the joint configurations: the time of a
//! synchronised move grows with every joint's travel, so the time to a subtree's bounding box or
//! to the far side of a split plane bounds the time to any point in it from below; the route
//! cost only adds to the direct time, so the nearest by route cost is found by taking nearest
//! points by direct time until the next one's direct time is no shorter than the best cost.
//! 2-opt then reverses stretches of the order (never across a block, see
//! [`order_by_time`]) while that shortens the tour: each pose tries the moves that make it the
//! neighbour of one of its [`NEIGHBOURS`] nearest poses (by direct time), stretches of at most
//! [`MAX_SPAN`] poses; a pose is looked at again only when a move changed one of its legs
//! (don't-look bits). Path checks are made only for legs a move could use after a lower-bound
//! test, and each pair once. Pure and deterministic.

use std::collections::{HashMap, VecDeque};

use super::motion::MotionLimits;
use super::route::Router;

/// Largest joint travel between two configurations (rad).
pub fn travel(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// A move-time measure the k-d tree searches by, with its lower bounds.
trait Metric {
    /// Time-like distance from `a` to `b`.
    fn dist(&self, a: &[f64], b: &[f64]) -> f64;
    /// A lower bound of [`Metric::dist`] from `q` to any point of the box `[min, max]`.
    fn to_box(&self, q: &[f64], min: &[f64], max: &[f64]) -> f64;
    /// A lower bound of [`Metric::dist`] from `q` to any point whose coordinate `dim` lies at
    /// or beyond `plane`.
    fn to_plane(&self, q: &[f64], dim: usize, plane: f64) -> f64;
}

/// Largest joint travel (rad), [`travel`].
#[cfg(test)]
struct Travel;

#[cfg(test)]
impl Metric for Travel {
    fn dist(&self, a: &[f64], b: &[f64]) -> f64 {
        travel(a, b)
    }
    fn to_box(&self, q: &[f64], min: &[f64], max: &[f64]) -> f64 {
        q.iter()
            .zip(min.iter().zip(max))
            .map(|(v, (lo, hi))| (lo - v).max(v - hi).max(0.0))
            .fold(0.0, f64::max)
    }
    fn to_plane(&self, q: &[f64], dim: usize, plane: f64) -> f64 {
        (q[dim] - plane).abs()
    }
}

/// Direct move time (s): a synchronised move takes no less time when any joint travels less,
/// so the time to the nearest point of a box (or plane) bounds that to the box from below.
impl Metric for MotionLimits {
    fn dist(&self, a: &[f64], b: &[f64]) -> f64 {
        self.move_time_s(a, b)
    }
    fn to_box(&self, q: &[f64], min: &[f64], max: &[f64]) -> f64 {
        with_copy(q, |p| {
            for ((v, lo), hi) in p.iter_mut().zip(min).zip(max) {
                *v = v.clamp(*lo, *hi);
            }
            self.move_time_s(q, p)
        })
    }
    fn to_plane(&self, q: &[f64], dim: usize, plane: f64) -> f64 {
        with_copy(q, |p| {
            p[dim] = plane;
            self.move_time_s(q, p)
        })
    }
}

/// `f` of a scratch copy of `q` (on the stack for up to 8 joints: the tree's bounds are
/// evaluated at every node it visits).
fn with_copy(q: &[f64], f: impl FnOnce(&mut [f64]) -> f64) -> f64 {
    let mut stack = [0.0; 8];
    match stack.get_mut(..q.len()) {
        Some(p) => {
            p.copy_from_slice(q);
            f(p)
        }
        None => f(&mut q.to_vec()),
    }
}

/// An implicit k-d tree: the node of the index range `[lo, hi)` sits at `mid = (lo + hi) / 2`,
/// its children hold `[lo, mid)` and `[mid + 1, hi)`.
struct KdTree<'a, M> {
    points: &'a [Vec<f64>],
    metric: &'a M,
    /// Point index at each tree position.
    slot: Vec<usize>,
    /// Split dimension of the node at each position.
    split: Vec<usize>,
    /// Bounding box of the subtree at each position: `dims` minima then `dims` maxima.
    bounds: Vec<f64>,
    /// Joint values per configuration.
    dims: usize,
    /// Unvisited points in the subtree of the node at each position.
    alive: Vec<usize>,
    /// Whether the point at each position is unvisited.
    open: Vec<bool>,
    /// Tree position of each point index.
    position: Vec<usize>,
}

/// The best candidate of a search: (distance, point index).
type Best = Option<(f64, usize)>;

impl<'a, M: Metric> KdTree<'a, M> {
    /// A tree over the points `ids` (indices into `points`).
    fn build(points: &'a [Vec<f64>], metric: &'a M, ids: Vec<usize>) -> KdTree<'a, M> {
        let n = ids.len();
        let dims = points.first().map_or(0, Vec::len);
        let mut t = KdTree {
            points,
            metric,
            slot: ids,
            split: vec![0; n],
            bounds: vec![0.0; 2 * dims * n],
            dims,
            alive: vec![0; n],
            open: vec![true; n],
            position: vec![0; points.len()],
        };
        t.build_range(0, n);
        for (pos, &i) in t.slot.iter().enumerate() {
            t.position[i] = pos;
        }
        t
    }

    /// Unvisited points left.
    fn left(&self) -> usize {
        self.alive.get(self.slot.len() / 2).copied().unwrap_or(0)
    }

    /// The tree over the unvisited points only (searches stop wading through visited ones).
    fn rebuilt(self) -> KdTree<'a, M> {
        let ids = self
            .slot
            .iter()
            .zip(&self.open)
            .filter(|(_, open)| **open)
            .map(|(i, _)| *i)
            .collect();
        KdTree::build(self.points, self.metric, ids)
    }

    /// Arrange `[lo, hi)` into a subtree: split on the widest dimension at the median.
    fn build_range(&mut self, lo: usize, hi: usize) {
        if lo >= hi {
            return;
        }
        let mid = (lo + hi) / 2;
        let dim = self.bound_range(lo, hi, mid);
        let points = self.points;
        self.slot[lo..hi].select_nth_unstable_by(mid - lo, |&a, &b| {
            points[a][dim].total_cmp(&points[b][dim]).then(a.cmp(&b))
        });
        self.split[mid] = dim;
        self.alive[mid] = hi - lo;
        self.build_range(lo, mid);
        self.build_range(mid + 1, hi);
    }

    /// Store the bounding box of `[lo, hi)` at `mid`; returns its widest dimension.
    fn bound_range(&mut self, lo: usize, hi: usize, mid: usize) -> usize {
        let dims = self.dims;
        let (mut widest, mut width) = (0, f64::NEG_INFINITY);
        for d in 0..dims {
            let (min, max) = self.slot[lo..hi]
                .iter()
                .map(|&i| self.points[i][d])
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                    (a.min(v), b.max(v))
                });
            self.bounds[2 * dims * mid + d] = min;
            self.bounds[2 * dims * mid + dims + d] = max;
            if max - min > width {
                (widest, width) = (d, max - min);
            }
        }
        widest
    }

    /// Lower bound of the distance from `q` to the subtree at `mid`.
    fn box_bound(&self, q: &[f64], mid: usize) -> f64 {
        let b = &self.bounds[2 * self.dims * mid..2 * self.dims * (mid + 1)];
        let (min, max) = b.split_at(self.dims);
        self.metric.to_box(q, min, max)
    }

    /// Mark point `i` visited (`-1`) or unvisited again (`+1`, after a visit).
    fn mark(&mut self, i: usize, open: bool) {
        let target = self.position[i];
        self.open[target] = open;
        let (mut lo, mut hi) = (0, self.slot.len());
        while lo < hi {
            let mid = (lo + hi) / 2;
            if open {
                self.alive[mid] += 1;
            } else {
                self.alive[mid] -= 1;
            }
            match target.cmp(&mid) {
                std::cmp::Ordering::Less => hi = mid,
                std::cmp::Ordering::Greater => lo = mid + 1,
                std::cmp::Ordering::Equal => break,
            }
        }
    }

    /// Mark point `i` visited.
    fn remove(&mut self, i: usize) {
        self.mark(i, false);
    }

    /// The unvisited point nearest to `q` and its distance (ties: lowest index).
    fn nearest(&self, q: &[f64]) -> Best {
        let mut best = None;
        self.search(q, 0, self.slot.len(), &mut best);
        best
    }

    fn search(&self, q: &[f64], lo: usize, hi: usize, best: &mut Best) {
        if lo >= hi {
            return;
        }
        let mid = (lo + hi) / 2;
        if self.alive[mid] == 0 || best.is_some_and(|(bd, _)| self.box_bound(q, mid) > bd) {
            return;
        }
        let i = self.slot[mid];
        let p = &self.points[i];
        if self.open[mid] {
            let d = self.metric.dist(q, p);
            if best.is_none_or(|(bd, bi)| d < bd || (d == bd && i < bi)) {
                *best = Some((d, i));
            }
        }
        let dim = self.split[mid];
        let diff = q[dim] - p[dim];
        let (near, far) = if diff < 0.0 {
            ((lo, mid), (mid + 1, hi))
        } else {
            ((mid + 1, hi), (lo, mid))
        };
        self.search(q, near.0, near.1, best);
        if best.is_none_or(|(bd, _)| self.metric.to_plane(q, dim, p[dim]) <= bd) {
            self.search(q, far.0, far.1, best);
        }
    }

    /// The `k` unvisited points nearest to `q` (nearest first; ties: lowest index), in one
    /// search that prunes by the `k`-th best so far.
    fn k_nearest(&self, q: &[f64], k: usize) -> Vec<usize> {
        let mut best = Vec::with_capacity(k + 1);
        if k > 0 {
            self.search_k(q, 0, self.slot.len(), k, &mut best);
        }
        best.into_iter().map(|(_, i)| i).collect()
    }

    /// [`KdTree::search`] keeping the `k` best, sorted.
    fn search_k(&self, q: &[f64], lo: usize, hi: usize, k: usize, best: &mut Vec<(f64, usize)>) {
        if lo >= hi {
            return;
        }
        let worst = |best: &Vec<(f64, usize)>| {
            if best.len() < k {
                f64::INFINITY
            } else {
                best[k - 1].0
            }
        };
        let mid = (lo + hi) / 2;
        if self.alive[mid] == 0 || self.box_bound(q, mid) > worst(best) {
            return;
        }
        let i = self.slot[mid];
        let p = &self.points[i];
        if self.open[mid] {
            let d = self.metric.dist(q, p);
            let at = best.partition_point(|&(bd, bi)| bd < d || (bd == d && bi < i));
            if at < k {
                best.insert(at, (d, i));
                best.truncate(k);
            }
        }
        let dim = self.split[mid];
        let diff = q[dim] - p[dim];
        let (near, far) = if diff < 0.0 {
            ((lo, mid), (mid + 1, hi))
        } else {
            ((mid + 1, hi), (lo, mid))
        };
        self.search_k(q, near.0, near.1, k, best);
        if self.metric.to_plane(q, dim, p[dim]) <= worst(best) {
            self.search_k(q, far.0, far.1, k, best);
        }
    }
}

/// Time charged for a leg that has no route (s): far more than any campaign, finite so that
/// sums and differences stay numbers.
const UNROUTABLE_S: f64 = 1e9;

/// Leg times between planned poses and the hub, each pair's path checked and routed once.
pub struct Legs<'a> {
    /// The poses (rad); index `points.len()` is the hub.
    points: &'a [Vec<f64>],
    hub: Vec<f64>,
    limits: &'a MotionLimits,
    settle_s: f64,
    router: &'a mut Router,
    /// Leg time of each pair routed so far, by (lower, higher) index.
    known: HashMap<(usize, usize), f64>,
}

impl<'a> Legs<'a> {
    /// Leg times between `points` and the hub of `router` (whose checks every leg passes) at
    /// `limits`, with `settle_s` per stop.
    pub fn new(
        points: &'a [Vec<f64>],
        router: &'a mut Router,
        limits: &'a MotionLimits,
        settle_s: f64,
    ) -> Legs<'a> {
        Legs {
            points,
            hub: router.hub().to_vec(),
            limits,
            settle_s,
            router,
            known: HashMap::new(),
        }
    }

    /// The index that stands for the hub.
    pub fn hub(&self) -> usize {
        self.points.len()
    }

    /// Joints of index `i` (the hub's for [`Legs::hub`]).
    fn q(&self, i: usize) -> &[f64] {
        self.points.get(i).map_or(&self.hub, Vec::as_slice)
    }

    /// The direct move `i → j` and its settle (s): a lower bound of [`Legs::leg_s`].
    fn direct_s(&self, i: usize, j: usize) -> f64 {
        self.limits.move_time_s(self.q(i), self.q(j)) + self.settle_s
    }

    /// Time of the leg `i → j` (s): the direct move and its settle when it passes the path
    /// check, else every move and settle of its route. Symmetric.
    pub fn leg_s(&mut self, i: usize, j: usize) -> f64 {
        if i == j {
            return 0.0;
        }
        let key = (i.min(j), i.max(j));
        if let Some(&t) = self.known.get(&key) {
            return t;
        }
        let (a, b) = (self.q(key.0).to_vec(), self.q(key.1).to_vec());
        let t = match self.router.route(&a, &b) {
            Ok(vias) => {
                let mut at = a.as_slice();
                let mut t = 0.0;
                for leg_end in vias
                    .iter()
                    .map(Vec::as_slice)
                    .chain(std::iter::once(&b[..]))
                {
                    t += self.limits.move_time_s(at, leg_end) + self.settle_s;
                    at = leg_end;
                }
                t
            }
            Err(_) => UNROUTABLE_S,
        };
        self.known.insert(key, t);
        t
    }
}

/// Whether the engine returns to the hub before the pose at position `m` (of `n` poses):
/// before the first, after every `drift_every` poses, and at the end (`m == n`).
fn hub_before(m: usize, n: usize, drift_every: usize) -> bool {
    m == 0 || m == n || (drift_every > 0 && m.is_multiple_of(drift_every))
}

/// Time (s) of the measuring legs of `order` (indices into the poses): from the hub to the
/// first pose, pose to pose, back to the hub after every `drift_every` poses (not after the
/// last) and at the end; each leg's moves and settles ([`Legs::leg_s`]).
pub fn tour_s(legs: &mut Legs, order: &[usize], drift_every: usize) -> f64 {
    let n = order.len();
    let hub = legs.hub();
    let mut sum = 0.0;
    for m in 0..=n {
        let a = m.checked_sub(1).map(|k| order[k]);
        sum += gap_s(legs, m, n, drift_every, a, order.get(m).copied(), hub);
    }
    sum
}

/// Time (s) between the poses `a` (position `m − 1`) and `b` (position `m`) of a tour of `n`
/// poses: through the hub when the engine returns there ([`hub_before`]; a missing end is the
/// hub itself), else the leg `a → b`.
fn gap_s(
    legs: &mut Legs,
    m: usize,
    n: usize,
    drift_every: usize,
    a: Option<usize>,
    b: Option<usize>,
    hub: usize,
) -> f64 {
    match (a, b) {
        (Some(a), Some(b)) if !hub_before(m, n, drift_every) => legs.leg_s(a, b),
        (a, b) => a.map_or(0.0, |a| legs.leg_s(a, hub)) + b.map_or(0.0, |b| legs.leg_s(hub, b)),
    }
}

/// Greedy order by leg time: from the hub, each step goes to the pose of the current block with
/// the shortest leg ([`Legs::leg_s`]; the hub after every `drift_every` poses); blocks follow
/// one another in the given order, each pose of a block before any of the next.
pub fn nearest_neighbour_by_time(
    legs: &mut Legs,
    blocks: &[Vec<usize>],
    drift_every: usize,
) -> Vec<usize> {
    let (points, limits, hub) = (legs.points, legs.limits, legs.hub());
    let mut order = Vec::with_capacity(blocks.iter().map(Vec::len).sum());
    let mut at = hub;
    for block in blocks {
        let mut tree = KdTree::build(points, limits, block.clone());
        while tree.left() > 0 {
            if drift_every > 0 && !order.is_empty() && order.len().is_multiple_of(drift_every) {
                at = hub;
            }
            let Some(i) = nearest_by_leg(&mut tree, legs, at) else {
                break;
            };
            tree.remove(i);
            order.push(i);
            at = i;
            if tree.left() < tree.slot.len() / 2 {
                tree = tree.rebuilt();
            }
        }
    }
    order
}

/// The unvisited point of `tree` with the shortest leg from `at` (ties: the nearer by direct
/// time, then the lowest index): points are taken nearest first by direct time, a lower bound
/// of the leg, until that bound is no shorter than the best leg found.
fn nearest_by_leg(
    tree: &mut KdTree<'_, MotionLimits>,
    legs: &mut Legs,
    at: usize,
) -> Option<usize> {
    let q = legs.q(at).to_vec();
    let mut best: Option<(f64, usize)> = None;
    let mut passed_over = Vec::new();
    while let Some((d, i)) = tree.nearest(&q) {
        let bound = d + legs.settle_s;
        if best.is_some_and(|(b, _)| bound >= b) {
            break;
        }
        let t = legs.leg_s(at, i);
        if best.is_none_or(|(b, _)| t < b) {
            best = Some((t, i));
        }
        if t <= bound {
            break;
        }
        tree.remove(i);
        passed_over.push(i);
    }
    for i in passed_over {
        tree.mark(i, true);
    }
    best.map(|(_, i)| i)
}

/// Poses each pose tries to become the tour neighbour of in [`improve_2opt`].
pub const NEIGHBOURS: usize = 8;
/// Longest stretch of the order one 2-opt move reverses (poses).
pub const MAX_SPAN: usize = 1000;
/// Smallest gain (s) a 2-opt move must make.
const MIN_GAIN_S: f64 = 1e-9;

/// 2-opt on [`tour_s`]: reverse stretches of `order` while that shortens the tour; a stretch
/// never crosses a block boundary (`block_sizes`: consecutive lengths of the blocks that tile
/// `order`), so every block keeps its poses. Never lengthens the tour.
pub fn improve_2opt(
    legs: &mut Legs,
    mut order: Vec<usize>,
    block_sizes: &[usize],
    drift_every: usize,
) -> Vec<usize> {
    let hub = legs.hub();
    let mut pos = vec![usize::MAX; legs.points.len()];
    for (m, &i) in order.iter().enumerate() {
        pos[i] = m;
    }
    let neighbours = neighbour_lists(legs, &order, block_sizes);
    let mut queue: VecDeque<usize> = order.iter().copied().collect();
    let mut queued = vec![false; legs.points.len()];
    for &i in &order {
        queued[i] = true;
    }
    while let Some(a) = queue.pop_front() {
        queued[a] = false;
        let mut moved = None;
        'tries: for &b in &neighbours[a] {
            let (lo, hi) = (pos[a].min(pos[b]), pos[a].max(pos[b]));
            if hi - lo > MAX_SPAN {
                continue;
            }
            for (s, e) in [(lo + 1, hi), (lo, hi - 1)] {
                if e > s && reversal_gain_s(legs, &order, s, e, drift_every, hub) > MIN_GAIN_S {
                    moved = Some((s, e));
                    break 'tries;
                }
            }
        }
        let Some((s, e)) = moved else { continue };
        order[s..=e].reverse();
        for (m, &i) in order.iter().enumerate().take(e + 1).skip(s) {
            pos[i] = m;
        }
        let mut touched = vec![a, order[s], order[e]];
        touched.extend(s.checked_sub(1).map(|k| order[k]));
        touched.extend(order.get(e + 1).copied());
        for i in touched {
            if !queued[i] {
                queued[i] = true;
                queue.push_back(i);
            }
        }
    }
    order
}

/// How much reversing `order[s..=e]` shortens the tour (s; negative: lengthens). Only the two
/// gaps at the stretch's ends and the hub returns inside it change: inside, the same pairs stay
/// neighbours, but a pair at a hub return goes through the hub. The new end legs are path-checked
/// only when their direct times leave room for a gain.
fn reversal_gain_s(
    legs: &mut Legs,
    order: &[usize],
    s: usize,
    e: usize,
    drift_every: usize,
    hub: usize,
) -> f64 {
    let n = order.len();
    let left = s.checked_sub(1).map(|k| order[k]);
    let right = order.get(e + 1).copied();
    let (first, last) = (order[s], order[e]);
    let old = gap_s(legs, s, n, drift_every, left, Some(first), hub)
        + gap_s(legs, e + 1, n, drift_every, Some(last), right, hub);
    // a hub return inside: the pair there pays the hub legs instead of its own leg
    let mut inside = 0.0;
    if drift_every > 0 {
        let mut m = (s + 1).div_ceil(drift_every) * drift_every;
        while m <= e {
            let (a, b) = (order[m - 1], order[m]);
            let (na, nb) = (order[s + e + 1 - m], order[s + e - m]);
            inside += excess_s(legs, na, nb, hub) - excess_s(legs, a, b, hub);
            m += drift_every;
        }
    }
    let lower = |legs: &Legs, m: usize, a: Option<usize>, b: Option<usize>| match (a, b) {
        (Some(a), Some(b)) if !hub_before(m, n, drift_every) => legs.direct_s(a, b),
        _ => 0.0,
    };
    let optimistic = lower(legs, s, left, Some(last)) + lower(legs, e + 1, Some(first), right);
    if old - optimistic - inside <= MIN_GAIN_S {
        return old - optimistic - inside;
    }
    let new = gap_s(legs, s, n, drift_every, left, Some(last), hub)
        + gap_s(legs, e + 1, n, drift_every, Some(first), right, hub);
    old - new - inside
}

/// What a hub return between `a` and `b` costs over the leg `a → b` (s).
fn excess_s(legs: &mut Legs, a: usize, b: usize, hub: usize) -> f64 {
    legs.leg_s(a, hub) + legs.leg_s(hub, b) - legs.leg_s(a, b)
}

/// The [`NEIGHBOURS`] nearest poses (by direct time) of every pose of `order` within its block
/// (indexed by pose).
fn neighbour_lists(legs: &Legs, order: &[usize], block_sizes: &[usize]) -> Vec<Vec<usize>> {
    let mut out = vec![Vec::new(); legs.points.len()];
    let mut start = 0;
    for &size in block_sizes {
        let block = &order[start..start + size];
        start += size;
        let mut tree = KdTree::build(legs.points, legs.limits, block.to_vec());
        for &i in block {
            tree.remove(i);
            out[i] = tree.k_nearest(&legs.points[i], NEIGHBOURS);
            tree.mark(i, true);
        }
    }
    out
}

/// Order `blocks` of pose indices by time: [`nearest_neighbour_by_time`], then
/// [`improve_2opt`] within each block. Returns the nearest-neighbour order and the final one.
pub fn order_by_time(
    legs: &mut Legs,
    blocks: &[Vec<usize>],
    drift_every: usize,
) -> (Vec<usize>, Vec<usize>) {
    let nn = nearest_neighbour_by_time(legs, blocks, drift_every);
    let sizes: Vec<usize> = blocks.iter().map(Vec::len).collect();
    let best = improve_2opt(legs, nn.clone(), &sizes, drift_every);
    (nn, best)
}

#[cfg(test)]
mod tests;
