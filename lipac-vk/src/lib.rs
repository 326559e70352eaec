//! # lipac-vk
//!
//! The Vulkan backend of lipac, binding to an engine's own `ash` device. It
//! executes `lipac-core`'s plans: BLAS/TLAS builds, the GPU versions of TLAS
//! assembly (Algorithm 1) and hit-feedback processing (Algorithm 2), and the
//! readback ring that returns commands to the core.
//!
//! Contents:
//!
//! * [`DeviceContext`]: lipac's binding to an engine's instance, device and
//!   queues; [`HeadlessContext`]: a device of its own for tests and examples.
//! * [`Buffer`] (device addresses, mapped upload/readback), [`ScratchBuffer`];
//!   memory from the context's [`DeviceAllocator`] ([`GpuAllocator`] on
//!   gpu-allocator by default, or the engine's own), counted exactly
//!   ([`DeviceMemoryStats`]);
//!   [`AccelerationStructurePool`]: acceleration structures at 256-byte
//!   aligned TLSF ranges of large blocks, with [`PoolStats`].
//! * [`BlasBatch`]: batched triangle BLAS builds by device address, with
//!   compaction ([`CompactionQuery`], [`record_compactions`]) and in-place
//!   updates ([`BlasUpdateMode`]); [`Tlas`]: builds from
//!   [`lipac_core::layout::TlasInstance`] records with geometric growth;
//!   [`TlasPair`]: a double-buffered TLAS.
//! * [`Retirement`]: deferred destruction keyed by timeline value (never
//!   waits); [`PlanExecutor`]: records lipac-core's BLAS build plans and
//!   acknowledges them.
//! * Counting boxes: [`UnitCube`], [`counting_box_instance`], and the GLSL
//!   include [`shaders::LIPAC_COUNTING_GLSL`]; [`TracePipeline`] traces rays
//!   from a buffer with it, counting hitbox hits into plain counters or
//!   straight into the hitbox records ([`HitboxCounting`]).
//! * [`RecordUploader`]: the GPU version of
//!   [`lipac_core::culling::apply_uploads`], scattering CPU-written records
//!   into the GPU instance buffer without overwriting its state bits.
//! * GPU Algorithm 1: [`AssemblyPipeline`] (TLAS instance assembly, equal to
//!   [`lipac_core::assembly::assemble_tlas`]); GPU Algorithm 2:
//!   [`FeedbackPipeline`] (hit feedback, equal to
//!   [`lipac_core::feedback::process_feedback`]).
//! * [`ReadbackRing`]: commands back to the host via a [`TimelineSemaphore`],
//!   never waiting; [`FrameSubmitter`] submits without waiting.
//!
//! Objects free their Vulkan resources when dropped; keep each alive until
//! the GPU has finished the work that uses it. See `docs/VULKAN.md`.
#![warn(missing_docs)]
#![deny(unsafe_op_in_unsafe_fn)]
#![warn(clippy::undocumented_unsafe_blocks)]

mod accel;
mod as_pool;
mod assembly;
mod blas;
mod commands;
mod compute;
mod context;
mod counting;
mod device_allocator;
mod error;
mod executor;
mod feedback;
mod lifetimes;
mod memory;
mod readback;
pub mod shaders;
mod timeline;
mod tlas;
mod trace;
mod upload;

pub use accel::{AccelerationStructure, AsSizes};
pub use as_pool::{
    AccelerationStructurePool, PoolStats, AS_OFFSET_ALIGNMENT, DEFAULT_POOL_BLOCK_SIZE,
};
pub use assembly::{
    hitbox_bounds, AssemblyBindings, AssemblyBuffers, AssemblyPipeline, HitboxBounds,
};
pub use blas::{
    record_compactions, record_compactions_pooled, Blas, BlasBatch, BlasBatchOutput,
    BlasUpdateMode, CompactionQuery, IndexFormat, TriangleGeometry,
};
pub use commands::{FrameSubmitter, OneShot, Recorder};
pub use context::{
    preferred_queue_family, AccelerationStructureLimits, DeviceContext, EngineQueue,
    HeadlessContext, Validation, REQUIRED_DEVICE_EXTENSIONS,
};
pub use counting::{
    counting_box_instance, CountingBoxKind, CountingConfig, UnitCube, UNIT_CUBE_INDICES,
    UNIT_CUBE_VERTICES,
};
pub use device_allocator::{
    AllocationRequest, AllocatorBlocks, DeviceAllocation, DeviceAllocator, DeviceMemoryStats,
    GpuAllocator, GPU_ALLOCATOR_DEVICE_BLOCK_BYTES, GPU_ALLOCATOR_HOST_BLOCK_BYTES,
};
pub use error::{Result, VkError};
pub use executor::{BlasGeometrySource, ExecutedFrame, ExecutorStats, PlanExecutor};
pub use feedback::{FeedbackBindings, FeedbackBuffers, FeedbackPipeline};
pub use lifetimes::{Retirement, TlasPair};
pub use memory::{Buffer, MemoryLocation, ScratchBuffer};
pub use readback::{Readback, ReadbackRing, ReadbackTicket};
pub use timeline::TimelineSemaphore;
pub use tlas::{Tlas, TlasBuildOutput};
pub use trace::{GpuHit, GpuRay, HitboxCounting, TraceBindings, TraceBuffers, TracePipeline};
pub use upload::{RecordUploader, UploadBindings, UploadStats, UploadTargets};

/// Size in bytes of one TLAS instance record as the GPU consumes it.
pub const TLAS_INSTANCE_BYTES: usize = std::mem::size_of::<lipac_core::layout::TlasInstance>();
