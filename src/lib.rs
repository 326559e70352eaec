//! # lipac
//!
//! Light path guided culling (LiPaC) for real-time path tracing: this crate
//! re-exports the crate family so that an engine can depend on one name.
//!
//! * [`core`] — renderer-agnostic state (`lipac-core`): instances, hitboxes,
//!   the instance/hitbox state machine, TLAS assembly and feedback processing
//!   (CPU reference), the readback command loop and latency mitigation.
//! * [`vk`] — the Vulkan backend on `ash` (`lipac-vk`).
//! * [`sim`] — the CPU laboratory on `obvhs` (`lipac-sim`).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub use lipac_core as core;
pub use lipac_sim as sim;
pub use lipac_vk as vk;
