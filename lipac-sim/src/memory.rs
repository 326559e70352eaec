//! The acceleration-structure memory model of the comparison
//! ([`MemoryModel`]; model and reasoning in docs/MEMORY_MODEL.md).
//!
//! A model holds the sizes a device reports for BLASes by triangle count
//! and TLASes by instance count, interpolated between measured sizes. It
//! comes from a device profile ([`crate::device_profile::DeviceProfile`],
//! `lipac compare --device-profile FILE`); without one the built-in
//! profile is lavapipe's sizes (docs/VULKAN.md, "Acceleration-structure
//! sizes on lavapipe"), which the free functions of this module give:
//!
//! * a BLAS of `n` triangles: `104·n − 16` bytes (exact on lavapipe for
//!   every measured size; compaction gives nothing there);
//! * a TLAS of `n` instances: `176·n − 16` bytes, and 216 bytes for one
//!   instance (lavapipe: exact from n = 16 on);
//! * LiPaC's own buffers (any device): 20 bytes per hitbox (the paper's 12
//!   plus the decayed rule's rate and cost words) and 4 bytes of hit
//!   feedback per instance slot ([`lipac_core::grid`]), plus, under the
//!   decayed rule, its 4-byte rate per slot ([`decayed_rate_bytes`]).
//!
//! The CPU tracer's own structures (obvhs CWBVHs) are a different size; the
//! comparison reports the model, which is what a Vulkan backend on the
//! profile's device would allocate for the same BLASes and TLAS records.

use lipac_core::build_plan::BuildEstimate;
use lipac_core::grid::{HITBOX_BYTES, HIT_FEEDBACK_BYTES_PER_INSTANCE};
use lipac_core::manager::MeshLod;

/// Bytes per BLAS triangle (the built-in profile).
pub const BLAS_BYTES_PER_TRIANGLE: u64 = 104;
/// Bytes per TLAS instance (the built-in profile).
pub const TLAS_BYTES_PER_INSTANCE: u64 = 176;
/// Build scratch of any build on lavapipe (a constant: it builds on the CPU);
/// the built-in profile's, and the model's where a profile measured none.
pub const BUILD_SCRATCH_BYTES: u64 = 64;

/// Modelled size of a BLAS of `triangles` triangles under the built-in
/// profile (never 0: an empty BLAS still takes a header).
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

/// Modelled size of a TLAS over `instances` instances (0 for none) under
/// the built-in profile.
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

/// The build sizes of a BLAS of `triangles` triangles under the built-in
/// profile ([`blas_bytes`], [`BUILD_SCRATCH_BYTES`] for builds and updates).
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

/// One LOD of a mesh for the Manager's catalog under the built-in profile:
/// [`build_estimate`] and [`GEOMETRY_DATA_BYTES`].
pub fn mesh_lod(triangles: u64) -> MeshLod {
    MeshLod {
        estimate: build_estimate(triangles),
        data_bytes: GEOMETRY_DATA_BYTES,
    }
}

/// Sizes by count, piecewise linear through measured `(count, bytes)`
/// points (counts strictly increasing, bytes never decreasing): exact at
/// every point, linear between two, the last segment extended above the
/// last point, proportional to the first point below it (rounded up).
/// Integer arithmetic, so a profile's points come back exactly.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SizeCurve {
    points: Vec<(u64, u64)>,
}

impl SizeCurve {
    /// The curve through `points`; `None` when there are none, counts do
    /// not strictly increase or bytes decrease, or a lone point is at
    /// count 0 (a first point at count 0 gives the size of nothing).
    ///
    /// ```
    /// use lipac_sim::memory::SizeCurve;
    /// let c = SizeCurve::new(vec![(2, 192), (12, 1232)]).unwrap();
    /// assert_eq!((c.at(2), c.at(7), c.at(12), c.at(100)), (192, 712, 1232, 10384));
    /// assert_eq!(c.at(1), 96); // proportional below the first point
    /// assert!(SizeCurve::new(vec![(4, 10), (2, 20)]).is_none());
    /// ```
    pub fn new(points: Vec<(u64, u64)>) -> Option<Self> {
        let ordered = points
            .windows(2)
            .all(|w| w[0].0 < w[1].0 && w[0].1 <= w[1].1);
        let lone_zero = points.len() == 1 && points[0].0 == 0;
        (!points.is_empty() && !lone_zero && ordered).then_some(Self { points })
    }

    /// A constant size (e.g. lavapipe's build scratch).
    ///
    /// ```
    /// use lipac_sim::memory::SizeCurve;
    /// let c = SizeCurve::constant(64);
    /// assert_eq!((c.at(0), c.at(1), c.at(1 << 40)), (64, 64, 64));
    /// ```
    pub fn constant(bytes: u64) -> Self {
        Self {
            points: vec![(0, bytes), (1, bytes)],
        }
    }

    /// The measured points.
    pub fn points(&self) -> &[(u64, u64)] {
        &self.points
    }

    /// Bytes at `count` (saturating at `u64::MAX`).
    pub fn at(&self, count: u64) -> u64 {
        let p = &self.points;
        let (n0, b0) = p[0];
        if count < n0 {
            // Proportional, rounded up.
            let v = (u128::from(b0) * u128::from(count)).div_ceil(u128::from(n0));
            return u64::try_from(v).unwrap_or(u64::MAX);
        }
        let i = p.partition_point(|&(n, _)| n <= count).max(1);
        if p.len() == 1 {
            let v = (u128::from(b0) * u128::from(count)).div_ceil(u128::from(n0));
            return u64::try_from(v).unwrap_or(u64::MAX);
        }
        // The segment [i-1, i] (the last one above the last point).
        let i = i.min(p.len() - 1);
        let (na, ba) = p[i - 1];
        let (nb, bb) = p[i];
        let num = u128::from(count - na) * u128::from(bb - ba);
        let den = u128::from(nb - na);
        let v = u128::from(ba) + (num + den / 2) / den;
        u64::try_from(v).unwrap_or(u64::MAX)
    }

    /// Bytes one more item adds for large counts: the slope of the last
    /// segment (of the one point's proportion), rounded.
    pub fn marginal(&self) -> u64 {
        let p = &self.points;
        match p.len() {
            1 => (p[0].1 + p[0].0 / 2) / p[0].0,
            n => {
                let ((na, ba), (nb, bb)) = (p[n - 2], p[n - 1]);
                (bb - ba + (nb - na) / 2) / (nb - na)
            }
        }
    }
}

/// The acceleration-structure sizes of one device: what BLASes, TLASes and
/// their builds take ([`SizeCurve`]s from a device profile,
/// [`crate::device_profile::DeviceProfile::memory_model`]). The default is
/// the built-in profile (lavapipe), equal to this module's free functions.
///
/// ```
/// use lipac_sim::memory::{blas_bytes, tlas_bytes, MemoryModel};
/// let m = MemoryModel::default();
/// for n in [0, 1, 2, 12, 512, 131_072] {
///     assert_eq!(m.blas_bytes(n), blas_bytes(n));
///     assert_eq!(m.tlas_bytes(n), tlas_bytes(n));
/// }
/// assert_eq!(m.tlas_bytes_per_instance(), 176);
/// ```
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MemoryModel {
    /// BLAS bytes by triangles, as built.
    pub blas: SizeCurve,
    /// BLAS bytes by triangles after compaction (the built sizes where the
    /// device compacts nothing).
    pub blas_compacted: SizeCurve,
    /// The least bytes any BLAS takes (an empty one's header).
    pub blas_min_bytes: u64,
    /// Build scratch by triangles.
    pub build_scratch: SizeCurve,
    /// Update (refit) scratch by triangles.
    pub update_scratch: SizeCurve,
    /// TLAS bytes by instances (0 instances: 0 bytes).
    pub tlas: SizeCurve,
}

impl Default for MemoryModel {
    /// The built-in profile: lavapipe's sizes.
    fn default() -> Self {
        Self::lavapipe()
    }
}

impl MemoryModel {
    /// lavapipe's sizes: [`blas_bytes`], [`tlas_bytes`],
    /// [`BUILD_SCRATCH_BYTES`], no compaction gain.
    pub fn lavapipe() -> Self {
        let blas = SizeCurve {
            points: vec![(1, 88), (2, 192)],
        };
        Self {
            blas_compacted: blas.clone(),
            blas,
            blas_min_bytes: 64,
            build_scratch: SizeCurve::constant(BUILD_SCRATCH_BYTES),
            update_scratch: SizeCurve::constant(BUILD_SCRATCH_BYTES),
            tlas: SizeCurve {
                points: vec![(1, 216), (2, 336), (3, 512)],
            },
        }
    }

    /// Modelled size of a BLAS of `triangles` triangles, as built (at least
    /// [`MemoryModel::blas_min_bytes`], never 0).
    pub fn blas_bytes(&self, triangles: u64) -> u64 {
        self.blas.at(triangles).max(self.blas_min_bytes).max(1)
    }

    /// Modelled size of that BLAS compacted.
    pub fn blas_compacted_bytes(&self, triangles: u64) -> u64 {
        self.blas_compacted
            .at(triangles)
            .max(self.blas_min_bytes)
            .clamp(1, self.blas_bytes(triangles))
    }

    /// Modelled size of a TLAS over `instances` instances (0 for none).
    pub fn tlas_bytes(&self, instances: u64) -> u64 {
        match instances {
            0 => 0,
            n => self.tlas.at(n).max(1),
        }
    }

    /// Bytes one more TLAS record adds (the controller's
    /// `tlas_record_bytes`).
    pub fn tlas_bytes_per_instance(&self) -> u64 {
        self.tlas.marginal().max(1)
    }

    /// The build sizes of a BLAS of `triangles` triangles.
    pub fn build_estimate(&self, triangles: u64) -> BuildEstimate {
        BuildEstimate {
            primitives: triangles,
            result_bytes: self.blas_bytes(triangles),
            build_scratch_bytes: self.build_scratch.at(triangles),
            update_scratch_bytes: self.update_scratch.at(triangles),
        }
    }

    /// One LOD of a mesh for the Manager's catalog:
    /// [`MemoryModel::build_estimate`] and [`GEOMETRY_DATA_BYTES`].
    pub fn mesh_lod(&self, triangles: u64) -> MeshLod {
        MeshLod {
            estimate: self.build_estimate(triangles),
            data_bytes: GEOMETRY_DATA_BYTES,
        }
    }
}
