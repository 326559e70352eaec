//! # lipac-core
//!
//! Renderer-agnostic state of light path guided culling (LiPaC; Kelling,
//! Ströter, Kuijper 2024, and Kelling's 2023 thesis §3.3).
//!
//! The crate is *sans-IO*: it never touches a GPU. It owns the truth about
//! instances and hitboxes and exposes the two GPU algorithms of the paper as
//! CPU reference implementations over exactly the buffer layouts a GPU backend
//! uses ([`layout`]), so that `lipac-vk`'s compute shaders can be tested
//! against them record for record.
//!
//! # For integrators: the crate root
//!
//! An engine (or a backend) drives one object, the [`Manager`], and needs only
//! the names re-exported here: calls in (`register`, `begin_frame`,
//! `ingest_readback`, ...), one [`ManagerPlan`] out per frame
//! ([`Manager::plan`]), [`Ack`]s in ([`Manager::handle_ack`]). Every type an
//! integrator meets in those signatures is at the crate root, once.
//!
//! # Low-level modules
//!
//! The modules are public so that backends, tests and benches can reach the
//! parts the manager is made of; an integrator should not need them:
//!
//! * the parts the [`Manager`] owns and keeps consistent: [`culling`] (the
//!   command loop), [`registry`] (slots and records), [`build_plan`] and
//!   [`blas_cache`] (the BLAS scheduler and cache), [`allocator`] (TLSF
//!   ranges), [`command`] (the command words and the read-back rule),
//!   [`latency`] (latency mitigation);
//! * the CPU references of the GPU algorithms a GPU backend tests its shaders
//!   against: [`assembly`] (Algorithm 1), [`feedback`] (Algorithm 2),
//!   [`state`] (the state machine), [`thresholds`] (and [`controller`], the
//!   closed loop on them);
//! * [`trace`]: recorded instance traces.
//!
//! [`culling::Culling`], [`registry::InstanceRegistry`] and
//! [`build_plan::BuildScheduler`] stay public, as low-level parts, because
//! lipac-core's integration tests and benches, lipac-test-support and
//! lipac-vk's executor tests drive them without a Manager. Their per-slot
//! state is one table, a row per GPU slot with a column per part (the
//! registry's occupant, the command loop's view, the Manager's LODs and data
//! range); the scheduler keeps only the BLAS residency of active instances,
//! dense by slot (`docs/MANAGER.md`, "Per-slot state: one table").
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod allocator;
pub mod assembly;
pub mod blas_cache;
pub mod blas_ids;
pub mod build_plan;
pub mod command;
pub mod controller;
pub mod culling;
mod dirty;
pub mod error;
pub mod feedback;
pub mod grid;
pub mod hashed_hitboxes;
pub mod hitbox_extents;
pub mod hitbox_index;
pub mod hitbox_tree;
pub mod instance;
pub mod latency;
pub mod layout;
pub mod manager;
pub mod math;
pub mod memory;
pub mod registry;
mod slot_table;
pub mod sparse_grid;
pub mod state;
pub mod thresholds;
pub mod trace;

// The manager: calls in, a plan out, acknowledgements in.
pub use manager::{
    Ack, DataConfig, DataGrowth, DataUpload, FrameBudgets, InstanceCounts, InstanceView, Manager,
    ManagerConfig, ManagerError, ManagerPlan, ManagerStats, MemoryStats, MeshCatalog, MeshLod,
};
// Recording the manager as a trace.
pub use manager::{FinishedTrace, RecorderError, RecorderOptions, TraceRecorder};
// Instances and meshes.
pub use instance::{InstanceDesc, InstanceFlags, MeshId};
pub use math::Aabb;
pub use registry::{InstanceHandle, RegistryConfig, RemovedInstance};
// Settings inside `ManagerConfig`.
pub use assembly::AssemblyConfig;
pub use build_plan::{BuildBudgets, BuildEstimate, SchedulerConfig};
pub use controller::{
    ControlTarget, ControllerConfig, ControllerError, ControllerStats, EscapeSample,
};
pub use culling::{CullingConfig, Selection};
pub use grid::{GridConfig, HitboxGrid};
pub use hashed_hitboxes::{HashedConfig, HashedHitboxes, WorldHitboxes};
pub use hitbox_index::HitboxIndex;
pub use latency::{ActivationHeuristic, Frustum};
pub use thresholds::Thresholds;
// What a plan and the frame calls hand out.
pub use assembly::AssemblyStats;
pub use blas_cache::BlasFree;
pub use blas_ids::BuildId;
pub use build_plan::{BlasBuild, BlasUpdate, BuildBatch, CompactionPlan, FramePlan, UpdateMode};
pub use command::IngestSummary;
pub use culling::{LatencyOutcome, ProcessStats, Readback, ReadbackRing, Uploads};
pub use feedback::FeedbackStats;
// The GPU buffer layouts.
pub use layout::{HitboxRecord, InstanceRecord, InstanceState, TlasInstance};
// Errors (all of them convert into `ManagerError`).
pub use allocator::AllocError;
pub use build_plan::BuildPlanError;
pub use error::CoreError;
