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
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod allocator;
pub mod assembly;
pub mod blas_cache;
pub mod blas_ids;
pub mod build_plan;
pub mod command;
pub mod culling;
pub mod dirty;
pub mod error;
pub mod feedback;
pub mod grid;
pub mod hitbox_index;
pub mod instance;
pub mod latency;
pub mod layout;
pub mod manager;
pub mod math;
pub mod memory;
pub mod registry;
pub mod state;
pub mod thresholds;
pub mod trace;

pub use manager::{Ack, FrameBudgets, Manager, ManagerConfig, ManagerError, ManagerPlan};
