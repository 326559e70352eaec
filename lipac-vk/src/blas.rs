//! Triangle BLASes built by device address, batched, with compaction.

use crate::accel::{
    build_sizes, record_build_barrier, same_context, AccelerationStructure, AsSizes,
};
use crate::as_pool::AccelerationStructurePool;
use crate::commands::Recorder;
use crate::context::DeviceContext;
use crate::error::{Result, VkContext, VkError};
use crate::memory::{align_up, Buffer, ScratchBuffer};
use ash::vk;

const BOTTOM_LEVEL: vk::AccelerationStructureTypeKHR =
    vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL;

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

/// What an update must keep from the original build, per geometry
/// (Vulkan requires these to match for `BUILD_MODE_UPDATE`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct GeometrySignature {
    triangle_count: u32,
    vertex_count: u32,
    index_format: Option<IndexFormat>,
    opaque: bool,
}

impl From<&TriangleGeometry> for GeometrySignature {
    fn from(g: &TriangleGeometry) -> Self {
        Self {
            triangle_count: g.triangle_count,
            vertex_count: g.vertex_count,
            index_format: g.indices.map(|(_, f)| f),
            opaque: g.opaque,
        }
    }
}

/// A bottom-level acceleration structure over triangles.
#[derive(Debug)]
pub struct GpuBlas {
    accel: AccelerationStructure,
    triangle_count: u64,
    flags: vk::BuildAccelerationStructureFlagsKHR,
    sizes: AsSizes,
    compacted: bool,
    signature: Vec<GeometrySignature>,
}

impl GpuBlas {
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
        Ok(build_sizes(ctx, BOTTOM_LEVEL, &vk_geoms, &counts, flags))
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
    pub fn record_compact(&self, rec: &mut Recorder<'_>, compacted_size: u64) -> Result<GpuBlas> {
        let mut out = record_compactions(rec, &[(self, compacted_size)])?;
        out.pop()
            .ok_or_else(|| VkError::InvalidArgument("no compaction recorded".into()))
    }

    fn check_update(
        &self,
        geometries: &[TriangleGeometry],
        mode: BlasUpdateMode,
    ) -> Result<Vec<GeometrySignature>> {
        let bad = |s: String| Err(VkError::InvalidArgument(s));
        if geometries.is_empty() {
            return bad("update without geometries".into());
        }
        for g in geometries {
            g.validate()?;
        }
        let sig: Vec<GeometrySignature> = geometries.iter().map(Into::into).collect();
        if mode == BlasUpdateMode::Refit
            && !self
                .flags
                .contains(vk::BuildAccelerationStructureFlagsKHR::ALLOW_UPDATE)
        {
            return bad("refit of a BLAS built without ALLOW_UPDATE".into());
        }
        if mode == BlasUpdateMode::Refit && sig != self.signature {
            return bad(format!(
                "refit geometries {sig:?} differ from the build's {:?} (counts, index format and opacity must match)",
                self.signature
            ));
        }
        Ok(sig)
    }
}

fn make_blas(
    accel: AccelerationStructure,
    geoms: &[TriangleGeometry],
    flags: vk::BuildAccelerationStructureFlagsKHR,
    sizes: AsSizes,
) -> GpuBlas {
    GpuBlas {
        accel,
        triangle_count: geoms.iter().map(|g| u64::from(g.triangle_count)).sum(),
        flags,
        sizes,
        compacted: false,
        signature: geoms.iter().map(Into::into).collect(),
    }
}

fn create_blas_storage(
    ctx: &DeviceContext,
    pool: Option<&AccelerationStructurePool>,
    size: u64,
) -> Result<AccelerationStructure> {
    let ty = vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL;
    match pool {
        Some(p) => {
            same_context(ctx, p.context())?;
            p.create(ty, size)
        }
        None => AccelerationStructure::new(ctx, ty, size),
    }
}

/// Records compacting copies of several BLASes (each with the compacted size
/// from its [`CompactionQuery`]) followed by one barrier. Each copy gets a
/// buffer of its own; [`record_compactions_pooled`] puts them in a pool.
///
/// # Errors
///
/// As [`GpuBlas::record_compact`]; nothing is recorded on error.
pub fn record_compactions(
    rec: &mut Recorder<'_>,
    items: &[(&GpuBlas, u64)],
) -> Result<Vec<GpuBlas>> {
    compactions(rec, items, None)
}

/// [`record_compactions`] with the copies created in `pool`.
///
/// # Errors
///
/// As [`record_compactions`]; [`VkError::WrongContext`] for a pool of
/// another context.
pub fn record_compactions_pooled(
    rec: &mut Recorder<'_>,
    items: &[(&GpuBlas, u64)],
    pool: &AccelerationStructurePool,
) -> Result<Vec<GpuBlas>> {
    compactions(rec, items, Some(pool))
}

fn compactions(
    rec: &mut Recorder<'_>,
    items: &[(&GpuBlas, u64)],
    pool: Option<&AccelerationStructurePool>,
) -> Result<Vec<GpuBlas>> {
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
        let accel = create_blas_storage(ctx, pool, *size)?;
        out.push(GpuBlas {
            accel,
            triangle_count: blas.triangle_count,
            flags: blas.flags,
            sizes: blas.sizes,
            compacted: true,
            signature: blas.signature.clone(),
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

/// How [`BlasBatch::push_update`] updates a BLAS in place.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BlasUpdateMode {
    /// `BUILD_MODE_UPDATE` with source = destination (a refit): needs
    /// `ALLOW_UPDATE` and geometries with the build's counts, index format
    /// and opacity; uses the update scratch size.
    Refit,
    /// A full build into the same acceleration structure (restores trace
    /// quality after many refits); the new build must fit its size.
    Rebuild,
}

#[derive(Clone, Debug)]
struct UpdateRequest<'a> {
    blas: &'a GpuBlas,
    geometries: Vec<TriangleGeometry>,
    mode: BlasUpdateMode,
}

/// Several BLAS builds and in-place updates recorded together: one
/// `vkCmdBuildAccelerationStructuresKHR` with scratch slices of one
/// [`ScratchBuffer`], one barrier after the batch, and a compacted-size query
/// for the builds that allow compaction.
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
pub struct BlasBatch<'a> {
    requests: Vec<(
        Vec<TriangleGeometry>,
        vk::BuildAccelerationStructureFlagsKHR,
    )>,
    updates: Vec<UpdateRequest<'a>>,
}

/// What [`BlasBatch::record`] produced.
#[derive(Debug)]
pub struct BlasBatchOutput {
    /// The BLASes, in the order they were pushed (valid once the recording has executed).
    pub blases: Vec<GpuBlas>,
    /// Compacted-size queries of the builds with `ALLOW_COMPACTION`.
    pub compaction: Option<CompactionQuery>,
    /// A scratch buffer replaced while growing: keep it until GPU work
    /// recorded before this batch has completed.
    pub retired_scratch: Option<Buffer>,
    /// Byte offset of each build's scratch slice (builds first, in push
    /// order, then updates), from the scratch buffer's base address.
    pub scratch_offsets: Vec<u64>,
    /// Scratch bytes the batch used (end of its last slice).
    pub scratch_bytes: u64,
}

impl<'a> BlasBatch<'a> {
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

    /// Adds an in-place update of `blas` from `geometries` (its deformed
    /// vertices): a refit (`BUILD_MODE_UPDATE`, source = destination) or a
    /// rebuild into the same structure, with the BLAS's build flags. Its
    /// address does not change, so TLAS records stay valid. Returns the
    /// update's index among the batch's updates.
    ///
    /// The batch records a barrier before its builds when it holds updates,
    /// so earlier traces and builds reading the BLAS finish first.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`]: no or invalid geometries, a refit of a
    /// BLAS built without `ALLOW_UPDATE` or with other geometry counts, index
    /// format or opacity, or the same BLAS twice in one batch.
    pub fn push_update(
        &mut self,
        blas: &'a GpuBlas,
        geometries: &[TriangleGeometry],
        mode: BlasUpdateMode,
    ) -> Result<usize> {
        blas.check_update(geometries, mode)?;
        if self
            .updates
            .iter()
            .any(|u| u.blas.accel.raw() == blas.accel.raw())
        {
            return Err(VkError::InvalidArgument(
                "the same BLAS updated twice in one batch".into(),
            ));
        }
        self.updates.push(UpdateRequest {
            blas,
            geometries: geometries.to_vec(),
            mode,
        });
        Ok(self.updates.len() - 1)
    }

    /// Number of builds in the batch.
    pub fn len(&self) -> usize {
        self.requests.len()
    }

    /// Number of updates in the batch.
    pub fn update_count(&self) -> usize {
        self.updates.len()
    }

    /// Whether the batch has neither builds nor updates.
    pub fn is_empty(&self) -> bool {
        self.requests.is_empty() && self.updates.is_empty()
    }

    /// Creates the BLASes (each in a buffer of its own) and records the
    /// batch: a barrier if it has updates, a query-pool reset (when some
    /// builds allow compaction), all builds and updates in one call with
    /// disjoint aligned scratch slices, one barrier, then the compacted-size
    /// queries.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] for an empty batch, counts over the
    /// device limits or a rebuild that does not fit its BLAS; creation
    /// errors. Nothing is recorded on error.
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        scratch: &mut ScratchBuffer,
    ) -> Result<BlasBatchOutput> {
        self.record_impl(rec, scratch, None)
    }

    /// [`BlasBatch::record`] with the new BLASes created in `pool`.
    ///
    /// # Errors
    ///
    /// As [`BlasBatch::record`]; [`VkError::WrongContext`] for a pool of
    /// another context.
    pub fn record_pooled(
        &self,
        rec: &mut Recorder<'_>,
        scratch: &mut ScratchBuffer,
        pool: &AccelerationStructurePool,
    ) -> Result<BlasBatchOutput> {
        self.record_impl(rec, scratch, Some(pool))
    }

    fn record_impl(
        &self,
        rec: &mut Recorder<'_>,
        scratch: &mut ScratchBuffer,
        pool: Option<&AccelerationStructurePool>,
    ) -> Result<BlasBatchOutput> {
        if self.is_empty() {
            return Err(VkError::InvalidArgument("empty BLAS batch".into()));
        }
        let ctx = rec.context();
        let align = scratch.alignment();
        let ops = self.requests.len() + self.updates.len();
        let mut vk_geoms = Vec::with_capacity(ops);
        let mut ranges = Vec::with_capacity(ops);
        let mut sizes = Vec::with_capacity(self.requests.len());
        let mut scratch_offsets = Vec::with_capacity(ops);
        let mut scratch_total = 0u64;
        let overflow = || VkError::InvalidArgument("scratch size overflows u64".into());
        let all = self.requests.iter().map(|(g, f)| (g, *f, None)).chain(
            self.updates
                .iter()
                .map(|u| (&u.geometries, u.blas.flags, Some((u.blas, u.mode)))),
        );
        for (geoms, flags, update) in all {
            if let Some((blas, _)) = update {
                same_context(ctx, blas.accel.context())?;
            }
            check_geometries(ctx, geoms)?;
            let g: Vec<_> = geoms.iter().map(|g| g.to_vk()).collect();
            let counts: Vec<u32> = geoms.iter().map(|g| g.triangle_count).collect();
            let s = build_sizes(ctx, BOTTOM_LEVEL, &g, &counts, flags);
            let needed = match update {
                Some((_, BlasUpdateMode::Refit)) => s.update_scratch,
                Some((blas, BlasUpdateMode::Rebuild)) => {
                    if s.acceleration_structure > blas.size() {
                        return Err(VkError::InvalidArgument(format!(
                            "rebuild needs {} bytes, the BLAS has {}",
                            s.acceleration_structure,
                            blas.size()
                        )));
                    }
                    s.build_scratch
                }
                None => {
                    sizes.push(s);
                    s.build_scratch
                }
            };
            scratch_offsets.push(scratch_total);
            scratch_total = align_up(
                scratch_total.checked_add(needed).ok_or_else(overflow)?,
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
        }
        let mut blases = Vec::with_capacity(self.requests.len());
        for ((geoms, flags), s) in self.requests.iter().zip(&sizes) {
            let accel = create_blas_storage(ctx, pool, s.acceleration_structure)?;
            blases.push(make_blas(accel, geoms, *flags, *s));
        }
        let retired_scratch = scratch.reserve(scratch_total.max(1))?;
        let base = scratch.base_address();
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

        let mut infos = Vec::with_capacity(ops);
        for (i, ((_, flags), blas)) in self.requests.iter().zip(&blases).enumerate() {
            infos.push(
                vk::AccelerationStructureBuildGeometryInfoKHR::default()
                    .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL)
                    .flags(*flags)
                    .mode(vk::BuildAccelerationStructureModeKHR::BUILD)
                    .dst_acceleration_structure(blas.accel.raw())
                    .geometries(&vk_geoms[i])
                    .scratch_data(vk::DeviceOrHostAddressKHR {
                        device_address: base + scratch_offsets[i],
                    }),
            );
        }
        let first_update = self.requests.len();
        for (k, u) in self.updates.iter().enumerate() {
            let i = first_update + k;
            let info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
                .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL)
                .flags(u.blas.flags)
                .dst_acceleration_structure(u.blas.accel.raw())
                .geometries(&vk_geoms[i])
                .scratch_data(vk::DeviceOrHostAddressKHR {
                    device_address: base + scratch_offsets[i],
                });
            infos.push(match u.mode {
                BlasUpdateMode::Refit => info
                    .mode(vk::BuildAccelerationStructureModeKHR::UPDATE)
                    .src_acceleration_structure(u.blas.accel.raw()),
                BlasUpdateMode::Rebuild => info.mode(vk::BuildAccelerationStructureModeKHR::BUILD),
            });
        }
        let range_refs: Vec<&[vk::AccelerationStructureBuildRangeInfoKHR]> =
            ranges.iter().map(|r| r.as_slice()).collect();

        if !self.updates.is_empty() {
            // Earlier traces, copies and builds reading or writing the updated
            // BLASes come first.
            rec.memory_barrier(
                vk::PipelineStageFlags2::ALL_COMMANDS,
                vk::AccessFlags2::ACCELERATION_STRUCTURE_READ_KHR
                    | vk::AccessFlags2::ACCELERATION_STRUCTURE_WRITE_KHR
                    | vk::AccessFlags2::SHADER_READ,
                vk::PipelineStageFlags2::ACCELERATION_STRUCTURE_BUILD_KHR,
                vk::AccessFlags2::ACCELERATION_STRUCTURE_READ_KHR
                    | vk::AccessFlags2::ACCELERATION_STRUCTURE_WRITE_KHR,
            );
        }
        if let Some(q) = &compaction {
            // SAFETY: recording on this device, outside a render pass; the pool
            // was just created with `q.len()` queries.
            unsafe {
                ctx.device()
                    .cmd_reset_query_pool(rec.raw(), q.pool, 0, q.len() as u32)
            };
        }
        // SAFETY: recording on this device; every build destination is a fresh
        // BLAS of the queried size, every update destination a live BLAS whose
        // size fits the rebuild (checked) or, for a refit, its own source with
        // the build's flags and geometry signature (checked at push); scratch
        // slices are disjoint, aligned to minAccelerationStructureScratchOffsetAlignment
        // and inside the reserved scratch; geometry addresses were validated
        // (the caller keeps the vertex/index buffers alive until execution,
        // per `TriangleGeometry`); no BLAS is updated twice (checked at push).
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
            scratch_offsets,
            scratch_bytes: scratch_total,
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
mod tests;
