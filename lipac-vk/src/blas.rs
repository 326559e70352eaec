//! Triangle BLASes built by device address, batched, with compaction.

use crate::accel::{record_build_barrier, same_context, AccelerationStructure, AsSizes};
use crate::commands::Recorder;
use crate::context::DeviceContext;
use crate::error::{Result, VkContext, VkError};
use crate::memory::{align_up, Buffer, ScratchBuffer};
use ash::vk;

/// Index format of a triangle geometry.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum IndexFormat {
    /// 16-bit indices.
    U16,
    /// 32-bit indices.
    U32,
}

impl IndexFormat {
    fn bytes(self) -> u64 {
        match self {
            Self::U16 => 2,
            Self::U32 => 4,
        }
    }
    fn vk(self) -> vk::IndexType {
        match self {
            Self::U16 => vk::IndexType::UINT16,
            Self::U32 => vk::IndexType::UINT32,
        }
    }
}

/// One triangle geometry of a BLAS, read by the build straight from the
/// engine's vertex and index buffers by device address (no copy).
///
/// Vertices are `R32G32B32_SFLOAT` positions at `vertex_stride` bytes apart.
/// The buffers need `ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR` usage
/// and must stay alive until the build has executed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TriangleGeometry {
    /// Device address of the first vertex (4-byte aligned).
    pub vertex_address: vk::DeviceAddress,
    /// Bytes between vertices (at least 12, a multiple of 4).
    pub vertex_stride: u64,
    /// Number of vertices addressable (highest index + 1).
    pub vertex_count: u32,
    /// Device address and format of the indices; `None` = non-indexed
    /// (three consecutive vertices per triangle).
    pub indices: Option<(vk::DeviceAddress, IndexFormat)>,
    /// Number of triangles.
    pub triangle_count: u32,
    /// Whether the geometry is opaque (no any-hit / candidate processing).
    pub opaque: bool,
}

fn need_build_input(b: &Buffer) -> Result<()> {
    if b.usage()
        .contains(vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR)
    {
        Ok(())
    } else {
        Err(VkError::MissingUsage(
            "ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR",
        ))
    }
}

fn check_span(b: &Buffer, offset: u64, len: u64) -> Result<()> {
    match offset.checked_add(len) {
        Some(end) if end <= b.size() => Ok(()),
        _ => Err(VkError::OutOfBounds {
            offset,
            len,
            size: b.size(),
        }),
    }
}

impl TriangleGeometry {
    /// An indexed geometry from lipac [`Buffer`]s, checked against their
    /// sizes and usages.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingUsage`], [`VkError::OutOfBounds`],
    /// [`VkError::InvalidArgument`] (see [`TriangleGeometry::validate`]).
    #[allow(clippy::too_many_arguments)]
    pub fn indexed(
        vertices: &Buffer,
        vertex_offset: u64,
        vertex_stride: u64,
        vertex_count: u32,
        indices: &Buffer,
        index_offset: u64,
        index_format: IndexFormat,
        triangle_count: u32,
    ) -> Result<Self> {
        need_build_input(vertices)?;
        need_build_input(indices)?;
        let g = Self {
            vertex_address: vertices.device_address().wrapping_add(vertex_offset),
            vertex_stride,
            vertex_count,
            indices: Some((
                indices.device_address().wrapping_add(index_offset),
                index_format,
            )),
            triangle_count,
            opaque: true,
        };
        g.validate()?;
        // validate() guarantees vertex_count >= 1 and stride >= 12.
        let vertex_span = (u64::from(vertex_count) - 1) * vertex_stride + 12;
        check_span(vertices, vertex_offset, vertex_span)?;
        check_span(
            indices,
            index_offset,
            u64::from(triangle_count) * 3 * index_format.bytes(),
        )?;
        Ok(g)
    }

    /// Checks the fields: non-zero counts and addresses, alignment, stride,
    /// and enough vertices for a non-indexed geometry.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] saying what is wrong.
    pub fn validate(&self) -> Result<()> {
        let bad = |s: String| Err(VkError::InvalidArgument(s));
        if self.triangle_count == 0 || self.vertex_count == 0 {
            return bad("geometry with no triangles or no vertices".into());
        }
        if self.vertex_address == 0 || self.vertex_address % 4 != 0 {
            return bad(format!(
                "vertex address {:#x} is 0 or not 4-aligned",
                self.vertex_address
            ));
        }
        if self.vertex_stride < 12
            || self.vertex_stride % 4 != 0
            || self.vertex_stride > u64::from(u32::MAX)
        {
            return bad(format!(
                "vertex stride {} (need >= 12, multiple of 4)",
                self.vertex_stride
            ));
        }
        match self.indices {
            Some((addr, format)) => {
                if addr == 0 || addr % format.bytes() != 0 {
                    return bad(format!("index address {addr:#x} is 0 or misaligned"));
                }
            }
            None => {
                if u64::from(self.triangle_count) * 3 > u64::from(self.vertex_count) {
                    return bad(format!(
                        "{} non-indexed triangles need {} vertices, have {}",
                        self.triangle_count,
                        u64::from(self.triangle_count) * 3,
                        self.vertex_count
                    ));
                }
            }
        }
        Ok(())
    }

    fn to_vk(self) -> vk::AccelerationStructureGeometryKHR<'static> {
        let (index_type, index_address) = match self.indices {
            Some((addr, f)) => (f.vk(), addr),
            None => (vk::IndexType::NONE_KHR, 0),
        };
        let triangles = vk::AccelerationStructureGeometryTrianglesDataKHR::default()
            .vertex_format(vk::Format::R32G32B32_SFLOAT)
            .vertex_data(vk::DeviceOrHostAddressConstKHR {
                device_address: self.vertex_address,
            })
            .vertex_stride(self.vertex_stride)
            .max_vertex(self.vertex_count - 1)
            .index_type(index_type)
            .index_data(vk::DeviceOrHostAddressConstKHR {
                device_address: index_address,
            });
        vk::AccelerationStructureGeometryKHR::default()
            .geometry_type(vk::GeometryTypeKHR::TRIANGLES)
            .geometry(vk::AccelerationStructureGeometryDataKHR { triangles })
            .flags(if self.opaque {
                vk::GeometryFlagsKHR::OPAQUE
            } else {
                vk::GeometryFlagsKHR::empty()
            })
    }
}

fn check_geometries(ctx: &DeviceContext, geometries: &[TriangleGeometry]) -> Result<u64> {
    if geometries.is_empty() {
        return Err(VkError::InvalidArgument("BLAS without geometries".into()));
    }
    let limits = ctx.limits();
    if geometries.len() as u64 > limits.max_geometry_count {
        return Err(VkError::InvalidArgument(format!(
            "{} geometries exceed maxGeometryCount {}",
            geometries.len(),
            limits.max_geometry_count
        )));
    }
    let mut total = 0u64;
    for g in geometries {
        g.validate()?;
        total += u64::from(g.triangle_count);
    }
    if total > limits.max_primitive_count {
        return Err(VkError::InvalidArgument(format!(
            "{total} triangles exceed maxPrimitiveCount {}",
            limits.max_primitive_count
        )));
    }
    Ok(total)
}

fn build_sizes(
    ctx: &DeviceContext,
    vk_geoms: &[vk::AccelerationStructureGeometryKHR<'_>],
    counts: &[u32],
    flags: vk::BuildAccelerationStructureFlagsKHR,
) -> AsSizes {
    let info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
        .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL)
        .flags(flags)
        .mode(vk::BuildAccelerationStructureModeKHR::BUILD)
        .geometries(vk_geoms);
    let mut sizes = vk::AccelerationStructureBuildSizesInfoKHR::default();
    // SAFETY: the geometry info is complete; `counts` has one entry per
    // geometry (ash asserts it); the function only computes sizes.
    unsafe {
        ctx.acceleration_structure()
            .get_acceleration_structure_build_sizes(
                vk::AccelerationStructureBuildTypeKHR::DEVICE,
                &info,
                counts,
                &mut sizes,
            )
    };
    sizes.into()
}

/// A bottom-level acceleration structure over triangles.
#[derive(Debug)]
pub struct Blas {
    accel: AccelerationStructure,
    triangle_count: u64,
    flags: vk::BuildAccelerationStructureFlagsKHR,
    sizes: AsSizes,
    compacted: bool,
}

impl Blas {
    /// The sizes a build of these geometries with these flags needs.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] for invalid geometries or counts over the
    /// device limits.
    pub fn query_sizes(
        ctx: &DeviceContext,
        geometries: &[TriangleGeometry],
        flags: vk::BuildAccelerationStructureFlagsKHR,
    ) -> Result<AsSizes> {
        check_geometries(ctx, geometries)?;
        let vk_geoms: Vec<_> = geometries.iter().map(|g| g.to_vk()).collect();
        let counts: Vec<u32> = geometries.iter().map(|g| g.triangle_count).collect();
        Ok(build_sizes(ctx, &vk_geoms, &counts, flags))
    }

    /// The acceleration structure.
    pub fn accel(&self) -> &AccelerationStructure {
        &self.accel
    }
    /// Device address for [`lipac_core::layout::TlasInstance`] records.
    pub fn device_address(&self) -> vk::DeviceAddress {
        self.accel.device_address()
    }
    /// Size in bytes of the acceleration structure (the compacted size once compacted).
    pub fn size(&self) -> u64 {
        self.accel.size()
    }
    /// Triangles in the BLAS.
    pub fn triangle_count(&self) -> u64 {
        self.triangle_count
    }
    /// The build flags.
    pub fn build_flags(&self) -> vk::BuildAccelerationStructureFlagsKHR {
        self.flags
    }
    /// The sizes the build was made with.
    pub fn build_sizes(&self) -> AsSizes {
        self.sizes
    }
    /// Whether this BLAS is a compacted copy.
    pub fn is_compacted(&self) -> bool {
        self.compacted
    }

    /// Records a compacting copy of this BLAS into a new one of
    /// `compacted_size` bytes (read from a [`CompactionQuery`]) and the
    /// barrier after it. Drop `self` once the copy has executed and no TLAS
    /// references it any more.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] when the BLAS was not built with
    /// `ALLOW_COMPACTION` or the size is 0 or larger than the BLAS;
    /// [`VkError::WrongContext`]; as [`AccelerationStructure::new`].
    pub fn record_compact(&self, rec: &mut Recorder<'_>, compacted_size: u64) -> Result<Blas> {
        let mut out = record_compactions(rec, &[(self, compacted_size)])?;
        out.pop()
            .ok_or_else(|| VkError::InvalidArgument("no compaction recorded".into()))
    }
}

/// Records compacting copies of several BLASes (each with the compacted size
/// from its [`CompactionQuery`]) followed by one barrier.
///
/// # Errors
///
/// As [`Blas::record_compact`]; nothing is recorded on error.
pub fn record_compactions(rec: &mut Recorder<'_>, items: &[(&Blas, u64)]) -> Result<Vec<Blas>> {
    let ctx = rec.context();
    for (blas, size) in items {
        same_context(ctx, blas.accel.context())?;
        if !blas
            .flags
            .contains(vk::BuildAccelerationStructureFlagsKHR::ALLOW_COMPACTION)
        {
            return Err(VkError::InvalidArgument(
                "compacting a BLAS built without ALLOW_COMPACTION".into(),
            ));
        }
        if *size == 0 || *size > blas.size() {
            return Err(VkError::InvalidArgument(format!(
                "compacted size {size} for a BLAS of {} bytes",
                blas.size()
            )));
        }
    }
    let mut out = Vec::with_capacity(items.len());
    for (blas, size) in items {
        let accel =
            AccelerationStructure::new(ctx, vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL, *size)?;
        out.push(Blas {
            accel,
            triangle_count: blas.triangle_count,
            flags: blas.flags,
            sizes: blas.sizes,
            compacted: true,
        });
    }
    for ((src, _), dst) in items.iter().zip(&out) {
        let info = vk::CopyAccelerationStructureInfoKHR::default()
            .src(src.accel.raw())
            .dst(dst.accel.raw())
            .mode(vk::CopyAccelerationStructureModeKHR::COMPACT);
        // SAFETY: the recorder is recording on this device; both structures are
        // live BLASes of this device; the source allows compaction and the
        // destination has the queried compacted size. The source's build was
        // made visible by the barrier after its batch.
        unsafe {
            ctx.acceleration_structure()
                .cmd_copy_acceleration_structure(rec.raw(), &info)
        };
    }
    record_build_barrier(rec);
    Ok(out)
}

/// Several BLAS builds recorded together: one `vkCmdBuildAccelerationStructuresKHR`
/// with scratch slices of one [`ScratchBuffer`], one barrier after the batch,
/// and a compacted-size query for the builds that allow compaction.
///
/// ```no_run
/// use ash::vk;
/// use lipac_vk::{BlasBatch, HeadlessContext, OneShot, ScratchBuffer, UnitCube, Validation};
/// let headless = HeadlessContext::new(Validation::Off)?;
/// let ctx = headless.context();
/// let cube = UnitCube::new(ctx)?;
/// let mut batch = BlasBatch::new();
/// batch.push(&[cube.geometry()], vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE)?;
/// let mut scratch = ScratchBuffer::new(ctx);
/// let built = OneShot::new(ctx)?.run(|rec| batch.record(rec, &mut scratch))?;
/// println!("unit cube BLAS: {} bytes", built.blases[0].size());
/// # Ok::<(), lipac_vk::VkError>(())
/// ```
#[derive(Clone, Debug, Default)]
pub struct BlasBatch {
    requests: Vec<(
        Vec<TriangleGeometry>,
        vk::BuildAccelerationStructureFlagsKHR,
    )>,
}

/// What [`BlasBatch::record`] produced.
#[derive(Debug)]
pub struct BlasBatchOutput {
    /// The BLASes, in the order they were pushed (valid once the recording has executed).
    pub blases: Vec<Blas>,
    /// Compacted-size queries of the builds with `ALLOW_COMPACTION`.
    pub compaction: Option<CompactionQuery>,
    /// A scratch buffer replaced while growing: keep it until GPU work
    /// recorded before this batch has completed.
    pub retired_scratch: Option<Buffer>,
}

impl BlasBatch {
    /// An empty batch.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a build of one BLAS from `geometries`; returns its index in the
    /// batch (and in [`BlasBatchOutput::blases`]).
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] for no geometries or an invalid one.
    pub fn push(
        &mut self,
        geometries: &[TriangleGeometry],
        flags: vk::BuildAccelerationStructureFlagsKHR,
    ) -> Result<usize> {
        if geometries.is_empty() {
            return Err(VkError::InvalidArgument("BLAS without geometries".into()));
        }
        for g in geometries {
            g.validate()?;
        }
        if flags.contains(vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE)
            && flags.contains(vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_BUILD)
        {
            return Err(VkError::InvalidArgument(
                "PREFER_FAST_TRACE and PREFER_FAST_BUILD together".into(),
            ));
        }
        self.requests.push((geometries.to_vec(), flags));
        Ok(self.requests.len() - 1)
    }

    /// Number of builds in the batch.
    pub fn len(&self) -> usize {
        self.requests.len()
    }

    /// Whether the batch is empty.
    pub fn is_empty(&self) -> bool {
        self.requests.is_empty()
    }

    /// Creates the BLASes and records their builds: a query-pool reset (when
    /// some builds allow compaction), all builds in one call with disjoint
    /// aligned scratch slices, one barrier, then the compacted-size queries.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] for an empty batch or counts over the
    /// device limits; creation errors. Nothing is recorded on error.
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        scratch: &mut ScratchBuffer,
    ) -> Result<BlasBatchOutput> {
        if self.requests.is_empty() {
            return Err(VkError::InvalidArgument("empty BLAS batch".into()));
        }
        let ctx = rec.context();
        let align = scratch.alignment();
        let mut vk_geoms = Vec::with_capacity(self.requests.len());
        let mut ranges = Vec::with_capacity(self.requests.len());
        let mut sizes = Vec::with_capacity(self.requests.len());
        let mut scratch_offsets = Vec::with_capacity(self.requests.len());
        let mut scratch_total = 0u64;
        let overflow = || VkError::InvalidArgument("scratch size overflows u64".into());
        for (geoms, flags) in &self.requests {
            check_geometries(ctx, geoms)?;
            let g: Vec<_> = geoms.iter().map(|g| g.to_vk()).collect();
            let counts: Vec<u32> = geoms.iter().map(|g| g.triangle_count).collect();
            let s = build_sizes(ctx, &g, &counts, *flags);
            scratch_offsets.push(scratch_total);
            scratch_total = align_up(
                scratch_total
                    .checked_add(s.build_scratch)
                    .ok_or_else(overflow)?,
                align,
            )
            .ok_or_else(overflow)?;
            ranges.push(
                counts
                    .iter()
                    .map(|&c| {
                        vk::AccelerationStructureBuildRangeInfoKHR::default().primitive_count(c)
                    })
                    .collect::<Vec<_>>(),
            );
            vk_geoms.push(g);
            sizes.push(s);
        }
        let retired_scratch = scratch.reserve(scratch_total)?;
        let base = scratch.base_address();

        let mut blases = Vec::with_capacity(self.requests.len());
        for ((geoms, flags), s) in self.requests.iter().zip(&sizes) {
            let accel = AccelerationStructure::new(
                ctx,
                vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL,
                s.acceleration_structure,
            )?;
            blases.push(Blas {
                accel,
                triangle_count: geoms.iter().map(|g| u64::from(g.triangle_count)).sum(),
                flags: *flags,
                sizes: *s,
                compacted: false,
            });
        }
        let compactable: Vec<usize> = blases
            .iter()
            .enumerate()
            .filter(|(_, b)| {
                b.flags
                    .contains(vk::BuildAccelerationStructureFlagsKHR::ALLOW_COMPACTION)
            })
            .map(|(i, _)| i)
            .collect();
        let compaction = if compactable.is_empty() {
            None
        } else {
            Some(CompactionQuery::new(ctx, compactable)?)
        };

        let infos: Vec<_> = self
            .requests
            .iter()
            .zip(&vk_geoms)
            .zip(&blases)
            .zip(&scratch_offsets)
            .map(|((((_, flags), g), blas), off)| {
                vk::AccelerationStructureBuildGeometryInfoKHR::default()
                    .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL)
                    .flags(*flags)
                    .mode(vk::BuildAccelerationStructureModeKHR::BUILD)
                    .dst_acceleration_structure(blas.accel.raw())
                    .geometries(g)
                    .scratch_data(vk::DeviceOrHostAddressKHR {
                        device_address: base + off,
                    })
            })
            .collect();
        let range_refs: Vec<&[vk::AccelerationStructureBuildRangeInfoKHR]> =
            ranges.iter().map(|r| r.as_slice()).collect();

        if let Some(q) = &compaction {
            // SAFETY: recording on this device, outside a render pass; the pool
            // was just created with `q.len()` queries.
            unsafe {
                ctx.device()
                    .cmd_reset_query_pool(rec.raw(), q.pool, 0, q.len() as u32)
            };
        }
        // SAFETY: recording on this device; every destination is a fresh BLAS of
        // the queried size; scratch slices are disjoint, aligned to
        // minAccelerationStructureScratchOffsetAlignment and inside the reserved
        // scratch; geometry addresses were validated (the caller keeps the
        // vertex/index buffers alive until execution, per `TriangleGeometry`).
        unsafe {
            ctx.acceleration_structure()
                .cmd_build_acceleration_structures(rec.raw(), &infos, &range_refs)
        };
        record_build_barrier(rec);
        if let Some(q) = &compaction {
            let handles: Vec<_> = q.indices.iter().map(|&i| blases[i].accel.raw()).collect();
            // SAFETY: the structures were built above and the barrier orders the
            // builds before this query write; the pool has one query per handle
            // and was reset above.
            unsafe {
                ctx.acceleration_structure()
                    .cmd_write_acceleration_structures_properties(
                        rec.raw(),
                        &handles,
                        vk::QueryType::ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR,
                        q.pool,
                        0,
                    )
            };
        }
        Ok(BlasBatchOutput {
            blases,
            compaction,
            retired_scratch,
        })
    }
}

/// Compacted-size queries of one [`BlasBatch`], read back once the batch has
/// executed (typically a frame or more later).
#[derive(Debug)]
pub struct CompactionQuery {
    ctx: DeviceContext,
    pool: vk::QueryPool,
    indices: Vec<usize>,
}

impl CompactionQuery {
    fn new(ctx: &DeviceContext, indices: Vec<usize>) -> Result<Self> {
        let info = vk::QueryPoolCreateInfo::default()
            .query_type(vk::QueryType::ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR)
            .query_count(indices.len() as u32);
        // SAFETY: valid device and create info.
        let pool =
            unsafe { ctx.device().create_query_pool(&info, None) }.ctx("vkCreateQueryPool")?;
        Ok(Self {
            ctx: ctx.clone(),
            pool,
            indices,
        })
    }

    /// Number of queried BLASes.
    pub fn len(&self) -> usize {
        self.indices.len()
    }

    /// Whether no BLAS is queried.
    pub fn is_empty(&self) -> bool {
        self.indices.is_empty()
    }

    /// Batch indices of the queried BLASes (those built with `ALLOW_COMPACTION`).
    pub fn indices(&self) -> &[usize] {
        &self.indices
    }

    /// The compacted sizes as `(batch index, bytes)`, without waiting.
    ///
    /// # Errors
    ///
    /// [`VkError::QueryNotReady`] when the batch has not finished executing;
    /// [`VkError::Vulkan`] on other failures.
    pub fn read_sizes(&self) -> Result<Vec<(usize, u64)>> {
        let mut sizes = vec![0u64; self.indices.len()];
        // SAFETY: the pool has `indices.len()` 64-bit results; the slice matches.
        let r = unsafe {
            self.ctx.device().get_query_pool_results(
                self.pool,
                0,
                &mut sizes,
                vk::QueryResultFlags::TYPE_64,
            )
        };
        match r {
            Ok(()) => Ok(self.indices.iter().copied().zip(sizes).collect()),
            Err(vk::Result::NOT_READY) => Err(VkError::QueryNotReady),
            Err(e) => Err(VkError::vk("vkGetQueryPoolResults", e)),
        }
    }
}

impl Drop for CompactionQuery {
    fn drop(&mut self) {
        // SAFETY: created on this device; not in use once the caller drops it
        // (queries are only read on the host).
        unsafe { self.ctx.device().destroy_query_pool(self.pool, None) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn good() -> TriangleGeometry {
        TriangleGeometry {
            vertex_address: 0x1000,
            vertex_stride: 12,
            vertex_count: 4,
            indices: Some((0x2000, IndexFormat::U16)),
            triangle_count: 2,
            opaque: true,
        }
    }

    #[test]
    fn geometry_validation_rejects_bad_fields() {
        assert!(good().validate().is_ok());
        let bad = [
            TriangleGeometry {
                triangle_count: 0,
                ..good()
            },
            TriangleGeometry {
                vertex_count: 0,
                ..good()
            },
            TriangleGeometry {
                vertex_address: 0,
                ..good()
            },
            TriangleGeometry {
                vertex_address: 0x1002,
                ..good()
            },
            TriangleGeometry {
                vertex_stride: 8,
                ..good()
            },
            TriangleGeometry {
                vertex_stride: 14,
                ..good()
            },
            TriangleGeometry {
                indices: Some((0x2001, IndexFormat::U16)),
                ..good()
            },
            TriangleGeometry {
                indices: Some((0x2002, IndexFormat::U32)),
                ..good()
            },
            TriangleGeometry {
                indices: None,
                ..good()
            }, // 2 triangles need 6 vertices
        ];
        for g in bad {
            assert!(
                matches!(g.validate(), Err(VkError::InvalidArgument(_))),
                "{g:?}"
            );
        }
        let flat = TriangleGeometry {
            indices: None,
            vertex_count: 6,
            ..good()
        };
        assert!(flat.validate().is_ok());
    }

    #[test]
    fn batch_push_rejects_empty_and_conflicting_flags() {
        let mut b = BlasBatch::new();
        assert!(b
            .push(&[], vk::BuildAccelerationStructureFlagsKHR::empty())
            .is_err());
        let both = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE
            | vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_BUILD;
        assert!(b.push(&[good()], both).is_err());
        assert_eq!(
            b.push(&[good()], vk::BuildAccelerationStructureFlagsKHR::empty())
                .unwrap(),
            0
        );
        assert_eq!(b.len(), 1);
    }
}
