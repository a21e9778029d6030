//! Planning: pose sampling in the workspace box (docs/method.md §7), campaign plans, path checks of
//! joint moves and their routing, the ISO 9283 test poses and cycles.

pub mod campaign;
pub mod iso9283;
pub mod motion;
pub mod order;
pub mod path;
pub mod route;
pub mod sampling;
pub mod selection;
pub mod setup;
pub mod timing;
pub mod workspace;

pub use campaign::{
    campaign_checker, campaign_router, count_via_points, order_plan, order_times, plan_campaign,
    target_ok, OrderedPlan, Plan, PlanEntry, PlanRequest,
};
pub use path::{BoxFace, CheckedPoint, PathCheck, PathChecker, PathFault, PATH_STEP_MM};
pub use route::{RouteError, Router};
pub use sampling::{sample_poses, PlanError};
pub use timing::{CampaignEstimate, MotionLimits};
pub use workspace::Workspace;
