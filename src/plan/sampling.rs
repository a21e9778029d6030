//! Joint-space sampling with rejection: a configuration is kept when the [`Workspace`] accepts
//! it. Pure and seeded.

use rand::Rng;

use super::workspace::Workspace;
use crate::model::kinematics::Frames;
use crate::model::RobotModel;

/// Why sampling failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    /// Too few configurations satisfied the constraints.
    #[error(
        "only {found} of {wanted} poses found in {tried} tries: is the workspace box reachable?"
    )]
    Unreachable {
        /// Poses found.
        found: usize,
        /// Poses wanted.
        wanted: usize,
        /// Configurations tried.
        tried: usize,
    },
    /// A move of the plan has no route (see [`super::route`]).
    #[error("no route: {0}")]
    Route(super::route::RouteError),
    /// Optimal selection of the identification poses failed.
    #[error("pose selection: {0}")]
    Selection(super::selection::SelectionError),
}

from_cause!(super::route::RouteError => PlanError::Route);

/// Sample `n` configurations uniformly in the joint limits, keeping those the workspace accepts.
pub fn sample_poses<R: Rng>(
    model: &RobotModel,
    ws: &Workspace,
    n: usize,
    rng: &mut R,
) -> Result<Vec<Vec<f64>>, PlanError> {
    let max_tries = 5000 * n.max(1) + 100_000;
    sample_poses_where(model, ws, n, rng, max_tries, |_, _| true)
}

/// [`sample_poses`] keeping only the accepted configurations that `keep` also accepts (given
/// their frames), within `max_tries` draws. The draws do not depend on `keep`.
pub fn sample_poses_where<R: Rng>(
    model: &RobotModel,
    ws: &Workspace,
    n: usize,
    rng: &mut R,
    max_tries: usize,
    mut keep: impl FnMut(&[f64], &Frames) -> bool,
) -> Result<Vec<Vec<f64>>, PlanError> {
    let mut out = Vec::with_capacity(n);
    let mut frames = Frames::new();
    let mut tried = 0;
    while out.len() < n {
        if tried >= max_tries {
            return Err(PlanError::Unreachable {
                found: out.len(),
                wanted: n,
                tried,
            });
        }
        tried += 1;
        let q: Vec<f64> = model
            .limits
            .iter()
            .map(|l| rng.random_range(l.min..=l.max))
            .collect();
        if ws.accepts_into(model, &q, &mut frames) && keep(&q, &frames) {
            out.push(q);
        }
    }
    Ok(out)
}
