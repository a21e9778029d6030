use super::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Greedy nearest-neighbour order by the tree under `metric`.
fn tree_order<M: Metric>(metric: &M, start: &[f64], points: &[Vec<f64>]) -> Vec<usize> {
    let mut tree = KdTree::build(points, metric, (0..points.len()).collect());
    let mut order = Vec::new();
    let mut at = start.to_vec();
    while let Some((_, i)) = tree.nearest(&at) {
        tree.remove(i);
        order.push(i);
        at.clone_from(&points[i]);
        if tree.left() < tree.slot.len() / 2 {
            tree = tree.rebuilt();
        }
    }
    order
}

/// The quadratic greedy scan the tree replaces.
fn scan_order<M: Metric>(metric: &M, start: &[f64], points: &[Vec<f64>]) -> Vec<usize> {
    let mut left: Vec<usize> = (0..points.len()).collect();
    let mut at = start.to_vec();
    let mut order = Vec::new();
    while !left.is_empty() {
        let (k, _) = left
            .iter()
            .enumerate()
            .fold((0, f64::INFINITY), |a, (k, &i)| {
                let d = metric.dist(&at, &points[i]);
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

fn limits() -> MotionLimits {
    // unequal joints: the time is not a function of the largest travel alone
    MotionLimits {
        speed_rad_s: vec![1.0, 1.2, 1.5, 3.0, 3.5, 4.5],
        accel_rad_s2: vec![2.0, 2.0, 3.0, 8.0, 8.0, 10.0],
    }
}

#[test]
fn tree_order_equals_the_greedy_scan_by_travel_and_by_time() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for n in [0, 1, 2, 7, 300] {
        let pts: Vec<Vec<f64>> = (0..n)
            .map(|_| (0..6).map(|_| rng.random_range(-3.0..3.0)).collect())
            .collect();
        let start = vec![0.1; 6];
        assert_eq!(
            tree_order(&Travel, &start, &pts),
            scan_order(&Travel, &start, &pts)
        );
        assert_eq!(
            tree_order(&limits(), &start, &pts),
            scan_order(&limits(), &start, &pts)
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
    let order = tree_order(&Travel, &[0.0, 0.0], &pts);
    assert_eq!(order, scan_order(&Travel, &[0.0, 0.0], &pts));
    assert_eq!(order[..2], [0, 2]);
}

#[test]
fn k_nearest_are_the_nearest_by_time_and_stay_unvisited() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let pts: Vec<Vec<f64>> = (0..200)
        .map(|_| (0..6).map(|_| rng.random_range(-3.0..3.0)).collect())
        .collect();
    let m = limits();
    let mut tree = KdTree::build(&pts, &m, (0..pts.len()).collect());
    let q = vec![0.3; 6];
    let got = tree.k_nearest(&q, 8);
    let mut all: Vec<(f64, usize)> = (0..pts.len()).map(|i| (m.dist(&q, &pts[i]), i)).collect();
    all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    assert_eq!(got, all[..8].iter().map(|a| a.1).collect::<Vec<_>>());
    assert_eq!(tree.left(), 200);
}

#[test]
fn a_synchronised_move_takes_its_slowest_joint_s_time() {
    let m = limits();
    let a = vec![0.0; 6];
    // joint 1: 2 rad at 1 rad/s, 2 rad/s²: 0.5 s up, 0.5 s down, 1.5 s cruise
    let mut b = a.clone();
    b[0] = 2.0;
    assert!((m.move_time_s(&a, &b) - 2.5).abs() < 1e-12);
    // short: no cruise, 2 √(d / a)
    b[0] = 0.18;
    assert!((m.move_time_s(&a, &b) - 0.6).abs() < 1e-12);
    // a faster joint travelling as far does not decide
    b[5] = 0.18;
    assert!((m.move_time_s(&a, &b) - 0.6).abs() < 1e-12);
    assert_eq!(m.move_time_s(&a, &b), m.move_time_s(&b, &a));
    assert_eq!(m.move_time_s(&a, &a), 0.0);
}
