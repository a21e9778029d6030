//! Greedy nearest-neighbour move order in O(n log n) (typical): a k-d tree over the joint
//! configurations answers "nearest unvisited configuration" under the travel metric (largest
//! joint travel, L∞), prunes subtrees by their bounding boxes and by alive counts, and is
//! rebuilt over the unvisited points whenever they fall below half of it (O(n log n) in all).
//! The order equals that of the quadratic greedy scan (ties: the lowest index). Pure and
//! deterministic.

/// Largest joint travel between two configurations (rad): the time-like move distance.
pub fn travel(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// An implicit k-d tree: the node of the index range `[lo, hi)` sits at `mid = (lo + hi) / 2`,
/// its children hold `[lo, mid)` and `[mid + 1, hi)`.
struct KdTree<'a> {
    points: &'a [Vec<f64>],
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

impl<'a> KdTree<'a> {
    /// A tree over the points `ids` (indices into `points`).
    fn build(points: &'a [Vec<f64>], ids: Vec<usize>) -> KdTree<'a> {
        let n = ids.len();
        let dims = points.first().map_or(0, Vec::len);
        let mut t = KdTree {
            points,
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
    fn rebuilt(self) -> KdTree<'a> {
        let ids = self
            .slot
            .iter()
            .zip(&self.open)
            .filter(|(_, open)| **open)
            .map(|(i, _)| *i)
            .collect();
        KdTree::build(self.points, ids)
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

    /// Travel from `q` to the nearest point of the bounding box of the subtree at `mid`.
    fn box_travel(&self, q: &[f64], mid: usize) -> f64 {
        let b = &self.bounds[2 * self.dims * mid..2 * self.dims * (mid + 1)];
        let (min, max) = b.split_at(self.dims);
        q.iter()
            .zip(min.iter().zip(max))
            .map(|(v, (lo, hi))| (lo - v).max(v - hi).max(0.0))
            .fold(0.0, f64::max)
    }

    /// Mark point `i` visited.
    fn remove(&mut self, i: usize) {
        let target = self.position[i];
        self.open[target] = false;
        let (mut lo, mut hi) = (0, self.slot.len());
        while lo < hi {
            let mid = (lo + hi) / 2;
            self.alive[mid] -= 1;
            match target.cmp(&mid) {
                std::cmp::Ordering::Less => hi = mid,
                std::cmp::Ordering::Greater => lo = mid + 1,
                std::cmp::Ordering::Equal => break,
            }
        }
    }

    /// The unvisited point nearest to `q` (ties: lowest index).
    fn nearest(&self, q: &[f64]) -> Option<usize> {
        let mut best = None;
        self.search(q, 0, self.slot.len(), &mut best);
        best.map(|(_, i)| i)
    }

    fn search(&self, q: &[f64], lo: usize, hi: usize, best: &mut Best) {
        if lo >= hi {
            return;
        }
        let mid = (lo + hi) / 2;
        if self.alive[mid] == 0 || best.is_some_and(|(bd, _)| self.box_travel(q, mid) > bd) {
            return;
        }
        let i = self.slot[mid];
        let p = &self.points[i];
        if self.open[mid] {
            let d = travel(q, p);
            if best.is_none_or(|(bd, bi)| d < bd || (d == bd && i < bi)) {
                *best = Some((d, i));
            }
        }
        let diff = q[self.split[mid]] - p[self.split[mid]];
        let (near, far) = if diff < 0.0 {
            ((lo, mid), (mid + 1, hi))
        } else {
            ((mid + 1, hi), (lo, mid))
        };
        self.search(q, near.0, near.1, best);
        if best.is_none_or(|(bd, _)| diff.abs() <= bd) {
            self.search(q, far.0, far.1, best);
        }
    }
}

/// Greedy nearest-neighbour visiting order of `points` starting at `start` (indices into
/// `points`): each step goes to the nearest unvisited configuration by [`travel`].
pub fn nearest_neighbour_order(start: &[f64], points: &[Vec<f64>]) -> Vec<usize> {
    let mut tree = KdTree::build(points, (0..points.len()).collect());
    let mut order = Vec::with_capacity(points.len());
    let mut at = start;
    while let Some(i) = tree.nearest(at) {
        tree.remove(i);
        order.push(i);
        at = &points[i];
        if tree.left() < tree.slot.len() / 2 {
            tree = tree.rebuilt();
        }
    }
    order
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The quadratic greedy scan the tree replaces.
    fn scan_order(start: &[f64], points: &[Vec<f64>]) -> Vec<usize> {
        let mut left: Vec<usize> = (0..points.len()).collect();
        let mut at = start.to_vec();
        let mut order = Vec::new();
        while !left.is_empty() {
            let (k, _) = left
                .iter()
                .enumerate()
                .fold((0, f64::INFINITY), |a, (k, &i)| {
                    let d = travel(&at, &points[i]);
                    if d < a.1 || (d == a.1 && i < left[a.0]) {
                        (k, d)
                    } else {
                        a
                    }
                });
            let i = left.remove(k);
            at = points[i].clone();
            order.push(i);
        }
        order
    }

    #[test]
    fn tree_order_equals_the_greedy_scan() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for n in [0, 1, 2, 7, 300] {
            let pts: Vec<Vec<f64>> = (0..n)
                .map(|_| (0..6).map(|_| rng.random_range(-3.0..3.0)).collect())
                .collect();
            let start = vec![0.1; 6];
            assert_eq!(
                nearest_neighbour_order(&start, &pts),
                scan_order(&start, &pts)
            );
        }
    }

    #[test]
    fn ties_and_duplicates_are_visited_once_in_index_order() {
        let pts = vec![
            vec![1.0, 0.0],
            vec![0.0, 1.0],
            vec![1.0, 0.0],
            vec![-1.0, 0.0],
        ];
        let order = nearest_neighbour_order(&[0.0, 0.0], &pts);
        assert_eq!(order, scan_order(&[0.0, 0.0], &pts));
        assert_eq!(order[..2], [0, 2]);
    }
}
