//! Acceleration structures on the device: grid meshes, BLAS batches timed
//! (rebuilt in place) and sized (built and compacted), TLAS builds of
//! active instances timed and sized.

use super::timing::Stats;
use super::{Bench, Res};
use ash::vk;
use glam::{Affine3A, Vec3};
use lipac_core::layout::TlasInstance;
use lipac_core::math::affine_to_rows;
use lipac_vk::{
    BlasBatch, BlasUpdateMode, Buffer, GpuBlas, GpuTlas, IndexFormat, ScratchBuffer,
    TriangleGeometry,
};
use serde::Serialize;

const BUILD_INPUT: vk::BufferUsageFlags =
    vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR;

/// lipac's flags for a static shared BLAS (`PlanExecutor`: fast trace,
/// compactable).
pub const STATIC_BLAS_FLAGS: vk::BuildAccelerationStructureFlagsKHR =
    vk::BuildAccelerationStructureFlagsKHR::from_raw(
        vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE.as_raw()
            | vk::BuildAccelerationStructureFlagsKHR::ALLOW_COMPACTION.as_raw(),
    );

/// lipac's TLAS flags (`LipacVkConfig::tlas_flags`).
pub const TLAS_FLAGS: vk::BuildAccelerationStructureFlagsKHR =
    vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE;

/// An `n` x `n` grid of quads (2 n² triangles) with a bumpy height, in
/// device-local build-input buffers.
pub struct GridMesh {
    vertices: Buffer,
    indices: Buffer,
    vertex_count: u32,
    pub triangles: u32,
}

impl GridMesh {
    pub fn new(b: &mut Bench<'_>, n: u32) -> Res<Self> {
        let mut v = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                let (x, y) = (i as f32 / n as f32, j as f32 / n as f32);
                v.push([x, y, 0.05 * (17.0 * x).sin() * (13.0 * y).cos()]);
            }
        }
        let at = |i: u32, j: u32| j * (n + 1) + i;
        let mut idx = Vec::new();
        for j in 0..n {
            for i in 0..n {
                idx.extend([
                    at(i, j),
                    at(i + 1, j),
                    at(i, j + 1),
                    at(i + 1, j),
                    at(i + 1, j + 1),
                    at(i, j + 1),
                ]);
            }
        }
        Ok(Self {
            vertices: b.upload("grid vertices", BUILD_INPUT, &v)?,
            indices: b.upload("grid indices", BUILD_INPUT, &idx)?,
            vertex_count: v.len() as u32,
            triangles: (idx.len() / 3) as u32,
        })
    }

    pub fn geometry(&self) -> TriangleGeometry {
        TriangleGeometry {
            vertex_address: self.vertices.device_address(),
            vertex_stride: 12,
            vertex_count: self.vertex_count,
            indices: Some((self.indices.device_address(), IndexFormat::U32)),
            triangle_count: self.triangles,
            opaque: true,
        }
    }
}

/// One BLAS size: built and compacted bytes, build scratch.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct BlasSize {
    pub triangles: u64,
    pub built_bytes: u64,
    pub compacted_bytes: u64,
    pub build_scratch_bytes: u64,
    pub update_scratch_bytes: u64,
}

/// Builds one BLAS per mesh (with [`STATIC_BLAS_FLAGS`]) and reads the
/// built and compacted sizes; the update scratch is queried with
/// `ALLOW_UPDATE` (lipac's flags for an animated BLAS).
pub fn blas_sizes(b: &mut Bench<'_>, meshes: &[&GridMesh]) -> Res<Vec<BlasSize>> {
    let ctx = b.ctx().clone();
    let geoms: Vec<TriangleGeometry> = meshes.iter().map(|m| m.geometry()).collect();
    let mut batch = BlasBatch::new();
    for g in &geoms {
        batch.push(std::slice::from_ref(g), STATIC_BLAS_FLAGS)?;
    }
    let mut scratch = ScratchBuffer::new(&ctx);
    let built = b.one_shot.run(|rec| batch.record(rec, &mut scratch))?;
    let compacted = built
        .compaction
        .as_ref()
        .map(|q| q.read_sizes())
        .transpose()?
        .unwrap_or_default();
    let update_flags = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE
        | vk::BuildAccelerationStructureFlagsKHR::ALLOW_UPDATE;
    built
        .blases
        .iter()
        .enumerate()
        .map(|(i, blas)| {
            let c = compacted
                .iter()
                .find(|(k, _)| *k == i)
                .map_or(blas.size(), |(_, s)| *s);
            let update = GpuBlas::query_sizes(&ctx, std::slice::from_ref(&geoms[i]), update_flags)?;
            Ok(BlasSize {
                triangles: blas.triangle_count(),
                built_bytes: blas.size(),
                compacted_bytes: c,
                build_scratch_bytes: blas.build_sizes().build_scratch,
                update_scratch_bytes: update.update_scratch,
            })
        })
        .collect()
}

/// A batch of BLAS builds, timed.
#[derive(Clone, Debug, Default, Serialize)]
pub struct BlasBatchResult {
    pub meshes: u32,
    pub triangles_per_mesh: u64,
    /// The batch (one `vkCmdBuildAccelerationStructuresKHR`), rebuilt in
    /// place ([`BlasUpdateMode::Rebuild`]) each run.
    pub build: Stats,
    pub triangles_per_s: f64,
    pub flags: String,
}

/// Builds `meshes` BLASes of `mesh` in one batch, then times `reps`
/// rebuilds of the whole batch.
pub fn blas_batch(b: &mut Bench<'_>, mesh: &GridMesh, meshes: u32) -> Res<BlasBatchResult> {
    let ctx = b.ctx().clone();
    let g = mesh.geometry();
    let mut batch = BlasBatch::new();
    for _ in 0..meshes {
        batch.push(std::slice::from_ref(&g), STATIC_BLAS_FLAGS)?;
    }
    let mut scratch = ScratchBuffer::new(&ctx);
    let built = b.one_shot.run(|rec| batch.record(rec, &mut scratch))?;
    let mut again = BlasBatch::new();
    for blas in &built.blases {
        again.push_update(blas, std::slice::from_ref(&g), BlasUpdateMode::Rebuild)?;
    }
    let mut retired = Vec::new();
    let build = b.timed(
        |_, _| Ok(()),
        |rec, _| {
            let o = again.record(rec, &mut scratch)?;
            retired.push(o);
            Ok(())
        },
    )?;
    drop(retired);
    let triangles = u64::from(meshes) * u64::from(mesh.triangles);
    Ok(BlasBatchResult {
        meshes,
        triangles_per_mesh: u64::from(mesh.triangles),
        triangles_per_s: triangles as f64 / (build.median_us * 1e-6),
        build,
        flags: "PREFER_FAST_TRACE | ALLOW_COMPACTION".into(),
    })
}

/// TLAS sizes by instance count.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct TlasSize {
    pub instances: u64,
    pub bytes: u64,
    pub build_scratch_bytes: u64,
}

/// The sizes of TLASes of `counts` instances ([`TLAS_FLAGS`]).
pub fn tlas_sizes(b: &Bench<'_>, counts: &[u32]) -> Res<Vec<TlasSize>> {
    counts
        .iter()
        .map(|&n| {
            let s = GpuTlas::query_sizes(b.ctx(), n, TLAS_FLAGS)?;
            Ok(TlasSize {
                instances: u64::from(n),
                bytes: s.acceleration_structure,
                build_scratch_bytes: s.build_scratch,
            })
        })
        .collect()
}

/// A TLAS build, timed.
#[derive(Clone, Debug, Default, Serialize)]
pub struct TlasBuildResult {
    pub instances: u64,
    pub build: Stats,
    pub instances_per_s: f64,
}

/// Times `reps` builds of a TLAS over `instances` active instances of
/// `blas` (a grid of them, 4 m apart).
pub fn tlas_build(b: &mut Bench<'_>, blas: &GpuBlas, instances: u32) -> Res<TlasBuildResult> {
    let ctx = b.ctx().clone();
    let side = (f64::from(instances).sqrt().ceil() as u32).max(1);
    let records: Vec<TlasInstance> = (0..instances)
        .map(|i| {
            let at = Vec3::new(4.0 * (i % side) as f32, 0.0, 4.0 * (i / side) as f32);
            TlasInstance::new(
                affine_to_rows(&Affine3A::from_translation(at)),
                i & 0x00FF_FFFF,
                0x01,
                0,
                0,
                blas.device_address(),
            )
        })
        .collect();
    let buffer = b.upload("TLAS instances", BUILD_INPUT, &records)?;
    let mut tlas = GpuTlas::new(&ctx, instances, TLAS_FLAGS)?;
    let mut scratch = ScratchBuffer::new(&ctx);
    let mut retired = Vec::new();
    let build = b.timed(
        |_, _| Ok(()),
        |rec, _| {
            retired.push(tlas.record_build(rec, &buffer, 0, instances, &mut scratch)?);
            Ok(())
        },
    )?;
    drop(retired);
    Ok(TlasBuildResult {
        instances: u64::from(instances),
        instances_per_s: f64::from(instances) / (build.median_us * 1e-6),
        build,
    })
}
