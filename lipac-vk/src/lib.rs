//! # lipac-vk
//!
//! Start with [`LipacVk`] (and `docs/INTEGRATION.md`): one object that an
//! engine binds to its device and drives with a `Manager`. The rest are its
//! parts, usable on their own.
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
//!   updates ([`BlasUpdateMode`]); [`GpuTlas`]: builds from
//!   [`lipac_core::layout::TlasInstance`] records with geometric growth;
//!   [`TlasPair`]: a double-buffered TLAS.
//! * [`Retirement`]: deferred destruction keyed by timeline value (never
//!   waits); [`PlanExecutor`]: records lipac-core's BLAS build plans and
//!   acknowledges them.
//! * Counting boxes: [`UnitCube`], [`counting_box_instance`], and the GLSL
//!   include [`shaders::LIPAC_COUNTING_GLSL`]; [`RayQueryTestPipeline`] traces rays
//!   from a buffer with it, counting hitbox hits into plain counters or
//!   straight into the hitbox records ([`HitboxCounting`]); [`CameraTracer`]
//!   generates a frame's primary, shadow and bounce rays on the GPU, the
//!   stand-in for an engine's own ray-query pass.
//! * [`RecordUploader`]: the GPU version of
//!   [`lipac_core::culling::apply_uploads`], scattering CPU-written records
//!   into the GPU instance buffer without overwriting its state bits.
//! * GPU Algorithm 1: [`AssemblyPipeline`] (TLAS instance assembly, equal to
//!   [`lipac_core::assembly::assemble_tlas`]); GPU Algorithm 2:
//!   [`FeedbackPipeline`] (hit feedback, equal to
//!   [`lipac_core::feedback::process_feedback`]).
//! * [`CommandReadbackRing`]: commands back to the host via a
//!   [`TimelineSemaphore`], never waiting; [`FrameSubmitter`] submits without
//!   waiting.
//! * [`LipacVk`]: the engine-facing object that executes a
//!   [`lipac_core::manager::Manager`]'s plans in the engine's command
//!   buffers (all of the above, per frame) and returns its
//!   acknowledgements and read-backs ([`LipacVk::poll`]).
//!
//! Objects free their Vulkan resources when dropped; keep each alive until
//! the GPU has finished the work that uses it. See `docs/VULKAN.md`.
#![warn(missing_docs)]
#![deny(unsafe_op_in_unsafe_fn)]
#![warn(clippy::undocumented_unsafe_blocks)]

mod accel;
mod as_pool;
mod assembly;
mod backend;
mod blas;
mod camera_trace;
mod commands;
mod compute;
mod context;
mod counting;
mod counting_pipeline;
mod device_allocator;
mod error;
mod escape;
mod executor;
mod feedback;
mod headless;
mod hitbox_tables;
mod lifetimes;
mod memory;
mod merged_boxes;
mod merged_trace;
mod pipeline_camera;
mod pipeline_test_tracer;
mod ray_query;
mod ray_query_test_pipeline;
mod readback;
mod sbt;
pub mod shaders;
mod timeline;
mod tlas;
mod trace_resources;
mod tracing_paths;
mod upload;

pub use accel::{AccelerationStructure, AsSizes};
pub use as_pool::{
    AccelerationStructurePool, PoolStats, AS_OFFSET_ALIGNMENT, DEFAULT_POOL_BLOCK_SIZE,
};
pub use assembly::{
    hitbox_bounds, AssemblyBindings, AssemblyBuffers, AssemblyPipeline, HitboxBounds,
    InstanceBuffers,
};
pub use backend::{
    FrameDiagnostics, FrameReadback, FrameSignal, InstanceDataSource, LipacVk, LipacVkConfig,
    LipacVkStats, Polled, RecordedFrame,
};
pub use blas::{
    record_compactions, record_compactions_pooled, BlasBatch, BlasBatchOutput, BlasUpdateMode,
    CompactionQuery, GpuBlas, IndexFormat, TriangleGeometry,
};
pub use camera_trace::{CameraTraceBindings, CameraTraceBuffers, CameraTracer, CameraView};
pub use commands::{FrameSubmitter, OneShot, Recorder};
pub use context::{
    preferred_queue_family, AccelerationStructureLimits, DeviceContext, EngineQueue,
    RAY_QUERY_EXTENSIONS, RAY_TRACING_PIPELINE_EXTENSIONS, REQUIRED_DEVICE_EXTENSIONS,
};
pub use counting::{
    counting_box_instance, CountingBoxConfig, CountingBoxKind, UnitCube, UNIT_CUBE_INDICES,
    UNIT_CUBE_VERTICES,
};
pub use counting_pipeline::MAX_PIPELINE_SBT_OFFSET;
pub use device_allocator::{
    AllocationRequest, AllocatorBlocks, DeviceAllocation, DeviceAllocator, DeviceMemoryStats,
    GpuAllocator, GPU_ALLOCATOR_DEVICE_BLOCK_BYTES, GPU_ALLOCATOR_HOST_BLOCK_BYTES,
};
pub use error::{Result, VkError};
pub use executor::{BlasGeometrySource, ExecutedFrame, ExecutorStats, PlanExecutor};
pub use feedback::{FeedbackBindings, FeedbackBuffers, FeedbackPipeline};
pub use headless::{HeadlessContext, HeadlessOptions, Validation, DEVICE_ENV, HIDE_ENV};
pub use lifetimes::{Retirement, TlasPair};
pub use memory::{Buffer, MemoryLocation, ScratchBuffer};
pub use merged_boxes::MergedBoxes;
pub use merged_trace::{MergedTraceBindings, MergedTraceBuffers, MergedTraceTestPipeline};
pub use pipeline_camera::{
    AnyCameraBindings, AnyCameraTracer, PipelineCameraBindings, PipelineCameraTracer,
};
pub use pipeline_test_tracer::{PipelineTestBindings, PipelineTestBuffers, PipelineTestTracer};
pub use ray_query_test_pipeline::{
    GpuHit, GpuRay, HitboxCounting, RayQueryTestBindings, RayQueryTestBuffers, RayQueryTestPipeline,
};
pub use readback::{CommandReadback, CommandReadbackRing, CommandReadbackTicket};
pub use sbt::{SbtLayout, SbtRecords, SbtRegion};
pub use timeline::TimelineSemaphore;
pub use tlas::{GpuTlas, TlasBuildOutput};
pub use trace_resources::TraceResources;
pub use tracing_paths::{RayTracingPipelineProperties, TracingPath, TracingPaths};
pub use upload::{RecordUploader, UploadBindings, UploadStats, UploadTargets};

/// Size in bytes of one TLAS instance record as the GPU consumes it.
pub const TLAS_INSTANCE_BYTES: usize = std::mem::size_of::<lipac_core::layout::TlasInstance>();
