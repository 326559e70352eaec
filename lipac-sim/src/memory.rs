//! The acceleration-structure memory model of the comparison, calibrated to
//! the sizes lavapipe reports (docs/VULKAN.md, "Acceleration-structure sizes
//! on lavapipe"; model and reasoning in docs/MEMORY_MODEL.md).
//!
//! * a BLAS of `n` triangles: `104·n − 16` bytes (exact on lavapipe for
//!   every measured size; compaction gives nothing there, so the model has
//!   no compacted sizes);
//! * a TLAS of `n` instances: `176·n − 16` bytes, and 216 bytes for one
//!   instance (lavapipe: exact from n = 16 on);
//! * LiPaC's own buffers: 20 bytes per hitbox (the paper's 12 plus the
//!   decayed rule's rate and cost words) and 4 bytes of hit feedback per
//!   instance slot ([`lipac_core::grid`]), plus, under the decayed rule, its
//!   4-byte rate per slot ([`decayed_rate_bytes`]).
//!
//! The CPU tracer's own structures (obvhs CWBVHs) are a different size; the
//! comparison reports the model, which is what a Vulkan backend on lavapipe
//! would allocate for the same BLASes and TLAS records.

use lipac_core::build_plan::BuildEstimate;
use lipac_core::grid::{HITBOX_BYTES, HIT_FEEDBACK_BYTES_PER_INSTANCE};
use lipac_core::manager::MeshLod;

/// Bytes per BLAS triangle.
pub const BLAS_BYTES_PER_TRIANGLE: u64 = 104;
/// Bytes per TLAS instance.
pub const TLAS_BYTES_PER_INSTANCE: u64 = 176;
/// Build scratch of any build on lavapipe (a constant: it builds on the CPU).
pub const BUILD_SCRATCH_BYTES: u64 = 64;

/// Modelled size of a BLAS of `triangles` triangles (never 0: an empty
/// BLAS still takes a header).
///
/// ```
/// use lipac_sim::memory::blas_bytes;
/// assert_eq!(blas_bytes(12), 1232); // lavapipe's unit cube
/// assert_eq!(blas_bytes(2), 192);
/// ```
pub fn blas_bytes(triangles: u64) -> u64 {
    (BLAS_BYTES_PER_TRIANGLE * triangles)
        .saturating_sub(16)
        .max(64)
}

/// Modelled size of a TLAS over `instances` instances (0 for none).
///
/// ```
/// use lipac_sim::memory::tlas_bytes;
/// assert_eq!(tlas_bytes(0), 0);
/// assert_eq!(tlas_bytes(1), 216);
/// assert_eq!(tlas_bytes(16), 2800); // lavapipe's figure
/// ```
pub fn tlas_bytes(instances: u64) -> u64 {
    match instances {
        0 => 0,
        n => (TLAS_BYTES_PER_INSTANCE * n).saturating_sub(16).max(216),
    }
}

/// LiPaC's own GPU buffers: hitbox records and per-slot hit counters.
///
/// ```
/// use lipac_sim::memory::lipac_overhead_bytes;
/// assert_eq!(lipac_overhead_bytes(512 * 512, 1_000_000), 5 * 1024 * 1024 + 4_000_000);
/// ```
pub fn lipac_overhead_bytes(hitboxes: u64, instance_slots: u64) -> u64 {
    hitboxes * HITBOX_BYTES + instance_slots * HIT_FEEDBACK_BYTES_PER_INSTANCE
}

/// Bytes of the decayed rule's per-slot rate buffer
/// ([`lipac_core::thresholds::DecisionRule::Decayed`]: one `u32` per
/// instance slot), 0 under the paper's rule.
///
/// ```
/// use lipac_sim::memory::decayed_rate_bytes;
/// use lipac_core::thresholds::Thresholds;
/// assert_eq!(decayed_rate_bytes(&Thresholds::paper(), 1000), 0);
/// ```
pub fn decayed_rate_bytes(thresholds: &lipac_core::thresholds::Thresholds, slots: u64) -> u64 {
    match thresholds.rule {
        lipac_core::thresholds::DecisionRule::Paper => 0,
        lipac_core::thresholds::DecisionRule::Decayed(_) => 4 * slots,
    }
}

/// Bytes of geometry-instance data one instance needs in the Manager's
/// geometry-data buffer (one record of material and vertex/index offsets the
/// hit shaders read). Not part of the comparison's memory figures, which
/// count acceleration structures and LiPaC's own buffers.
pub const GEOMETRY_DATA_BYTES: u64 = 64;

/// The build sizes of a BLAS of `triangles` triangles ([`blas_bytes`],
/// [`BUILD_SCRATCH_BYTES`] for builds and updates).
///
/// ```
/// use lipac_sim::memory::{blas_bytes, build_estimate};
/// let e = build_estimate(12);
/// assert_eq!((e.primitives, e.result_bytes), (12, blas_bytes(12)));
/// ```
pub fn build_estimate(triangles: u64) -> BuildEstimate {
    BuildEstimate {
        primitives: triangles,
        result_bytes: blas_bytes(triangles),
        build_scratch_bytes: BUILD_SCRATCH_BYTES,
        update_scratch_bytes: BUILD_SCRATCH_BYTES,
    }
}

/// One LOD of a mesh for the Manager's catalog: [`build_estimate`] and
/// [`GEOMETRY_DATA_BYTES`].
pub fn mesh_lod(triangles: u64) -> MeshLod {
    MeshLod {
        estimate: build_estimate(triangles),
        data_bytes: GEOMETRY_DATA_BYTES,
    }
}
