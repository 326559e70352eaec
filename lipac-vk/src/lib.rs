//! # lipac-vk
//!
//! The Vulkan backend of lipac, binding to an engine's own `ash` device. It
//! executes `lipac-core`'s plans: BLAS/TLAS builds, the GPU versions of TLAS
//! assembly (Algorithm 1) and hit-feedback processing (Algorithm 2), and the
//! readback ring that returns commands to the core.
//!
//! This crate is being built up; see the project's issues.
#![warn(missing_docs)]

/// Size in bytes of one TLAS instance record as the GPU consumes it.
pub const TLAS_INSTANCE_BYTES: usize = std::mem::size_of::<lipac_core::layout::TlasInstance>();
