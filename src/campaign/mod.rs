//! The campaign engine: a service driven by commands (arm, start, pause, resume, abort, answer)
//! that emits a stream of events (state, progress, prompts, faults, results). The terminal
//! front end and the REST front end are thin clients of the same engine.
//!
//! Data flow per pose (DESIGN.md): safety check → move → settle → read joints → stage at P1 →
//! measure → stage to P2 → measure → stage back → **store commits** → next pose. The robot is
//! never sent anywhere before the pose's measurements are durable.

pub mod cell_lock;
pub mod engine;
pub mod estimate;
pub mod events;
pub mod feasibility;
pub mod iso;
pub mod lock;
pub mod report;
pub mod session;
pub mod stored;

pub use engine::{
    journal_event, run_campaign, CampaignContext, CampaignError, Devices, FaultPolicy, Outcome,
    SetupResult,
};
pub use events::{CampaignCommand, CampaignEvent, CampaignState, Control, Journalled};
