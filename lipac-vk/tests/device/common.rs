//! Shared helpers of lipac-vk's device tests.
#![allow(dead_code)]

use ash::vk;
use bytemuck::Zeroable;
use glam::{Affine3A, Vec3};
use lipac_core::layout::HitboxRecord;
use lipac_core::layout::TlasInstance;
use lipac_core::math::affine_to_rows;
use lipac_vk::{
    BlasBatch, BlasBatchOutput, Buffer, CountingBoxConfig, GpuBlas, GpuHit, GpuRay, GpuTlas,
    HeadlessContext, HitboxCounting, MemoryLocation, MergedBoxes, MergedTraceBuffers,
    MergedTraceTestPipeline, OneShot, PipelineTestBuffers, PipelineTestTracer, RayQueryTestBuffers,
    RayQueryTestPipeline, ScratchBuffer, TracingPath, TriangleGeometry, UnitCube, Validation,
};

/// Whether the environment demands a Vulkan device with the validation
/// layer and glslangValidator (`LIPAC_REQUIRE_VULKAN=1`, CI).
pub fn vulkan_required() -> bool {
    std::env::var("LIPAC_REQUIRE_VULKAN").is_ok_and(|v| v == "1")
}

/// Whether the environment demands a Vulkan device (`LIPAC_REQUIRE_VULKAN=1`,
/// or `=device` on a GPU machine without the validation layer or glslang).
pub fn device_required() -> bool {
    vulkan_required() || std::env::var("LIPAC_REQUIRE_VULKAN").is_ok_and(|v| v == "device")
}

/// The validation the tests ask for: required with `LIPAC_REQUIRE_VULKAN=1`.
pub fn validation() -> Validation {
    if vulkan_required() {
        Validation::Required
    } else {
        Validation::IfAvailable
    }
}

/// A headless context (the harness runs a device test only after its
/// probe found a device that can run it, so failing here is a failure).
pub fn headless(test: &str) -> HeadlessContext {
    match HeadlessContext::new(validation()) {
        Ok(h) => h,
        Err(e) => panic!("{test}: no Vulkan context: {e}"),
    }
}

/// The tracing paths of `h`'s device, ray queries first.
pub fn paths(h: &HeadlessContext) -> Vec<TracingPath> {
    [TracingPath::RayQuery, TracingPath::RayTracingPipeline]
        .into_iter()
        .filter(|p| h.context().tracing().has(*p))
        .collect()
}

/// lipac's test tracer on one path: `trace_counting.comp` / `trace_merged.comp`
/// ([`RayQueryTestPipeline`] with hitbox records, [`MergedTraceTestPipeline`])
/// or [`PipelineTestTracer`]; hitbox hits go into `HitboxRecord`s either way.
pub enum TestTracer {
    /// Ray queries.
    RayQuery {
        leaf: RayQueryTestPipeline,
        merged: MergedTraceTestPipeline,
    },
    /// A ray-tracing pipeline.
    Pipeline(PipelineTestTracer),
}

/// The merged-box SBT offset the tests use: `AdaptiveHitboxes`' default 3,
/// or past the box kinds' offsets when `cfg` uses 3.
pub fn merged_sbt(cfg: &CountingBoxConfig) -> u32 {
    if cfg.omitted_box_sbt_offset == 3 || cfg.hitbox_box_sbt_offset == 3 {
        cfg.omitted_box_sbt_offset.max(cfg.hitbox_box_sbt_offset) + 1
    } else {
        3
    }
}

impl TestTracer {
    /// The tracer of `path`.
    pub fn new(h: &HeadlessContext, cfg: &CountingBoxConfig, path: TracingPath) -> Self {
        let ctx = h.context();
        match path {
            TracingPath::RayQuery => Self::RayQuery {
                leaf: RayQueryTestPipeline::with_hitbox_counting(ctx, cfg, HitboxCounting::Records)
                    .unwrap(),
                merged: MergedTraceTestPipeline::new(ctx, cfg).unwrap(),
            },
            TracingPath::RayTracingPipeline => {
                Self::Pipeline(PipelineTestTracer::new(ctx, cfg, merged_sbt(cfg)).unwrap())
            }
        }
    }

    /// The tracer of the device's preferred path.
    pub fn preferred(h: &HeadlessContext, cfg: &CountingBoxConfig) -> Self {
        let path = h.context().tracing().preferred().expect("a tracing path");
        Self::new(h, cfg, path)
    }

    pub fn path(&self) -> TracingPath {
        match self {
            Self::RayQuery { .. } => TracingPath::RayQuery,
            Self::Pipeline(_) => TracingPath::RayTracingPipeline,
        }
    }

    /// Traces `rays` through `tlas` (cull mask, GLSL ray flags, merged
    /// boxes as `merged` says) into `results`, `instance_hits` and the
    /// hitbox records `hitboxes` (with `bounds`), waiting for the GPU.
    #[allow(clippy::too_many_arguments)]
    pub fn run(
        &self,
        h: &HeadlessContext,
        tlas: &GpuTlas,
        rays: &Buffer,
        ray_count: u32,
        results: &Buffer,
        instance_hits: &Buffer,
        hitboxes: &Buffer,
        bounds: &Buffer,
        merged: &MergedBoxes,
        cull_mask: u8,
        ray_flags: u32,
    ) {
        let mut one_shot = OneShot::new(h.context()).unwrap();
        match self {
            Self::RayQuery { leaf, .. } if !merged.is_on() => {
                let b = leaf
                    .bind(&RayQueryTestBuffers {
                        tlas,
                        rays,
                        results,
                        instance_hits,
                        hitbox_hits: hitboxes,
                    })
                    .unwrap();
                one_shot
                    .run(|rec| leaf.record(rec, &b, ray_count, cull_mask, ray_flags))
                    .unwrap();
            }
            Self::RayQuery { merged: m, .. } => {
                let b = m
                    .bind(&MergedTraceBuffers {
                        tlas,
                        rays,
                        results,
                        instance_hits,
                        hitboxes,
                        hitbox_bounds: bounds,
                    })
                    .unwrap();
                one_shot
                    .run(|rec| m.record_merged(rec, &b, merged, ray_count, cull_mask, ray_flags))
                    .unwrap();
            }
            Self::Pipeline(p) => {
                let b = p
                    .bind(&PipelineTestBuffers {
                        tlas,
                        rays,
                        results,
                        instance_hits,
                        hitboxes,
                        hitbox_bounds: bounds,
                    })
                    .unwrap();
                one_shot
                    .run(|rec| p.record(rec, &b, merged, ray_count, cull_mask, ray_flags))
                    .unwrap();
            }
        }
    }
}

/// Asserts that the validation layer (and any other messenger source)
/// reported no errors.
pub fn assert_no_validation_errors(h: &HeadlessContext) {
    let errors = h.validation_errors();
    assert!(
        errors.is_empty(),
        "validation errors:\n{}",
        errors.join("\n")
    );
}

pub const BUILD_INPUT: vk::BufferUsageFlags =
    vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR;

/// A CPU-side triangle mesh.
#[derive(Clone, Debug)]
pub struct Mesh {
    pub vertices: Vec<[f32; 3]>,
    pub indices: Vec<u32>,
}

impl Mesh {
    /// The square [-1,1]^2 in the z = 0 plane (2 triangles).
    pub fn quad() -> Self {
        Self {
            vertices: vec![
                [-1.0, -1.0, 0.0],
                [1.0, -1.0, 0.0],
                [-1.0, 1.0, 0.0],
                [1.0, 1.0, 0.0],
            ],
            indices: vec![0, 1, 2, 1, 3, 2],
        }
    }

    /// An n x n grid over [-1,1]^2 with a bumpy z (2 n^2 triangles).
    pub fn bumpy_grid(n: u32) -> Self {
        let mut vertices = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                let x = -1.0 + 2.0 * i as f32 / n as f32;
                let y = -1.0 + 2.0 * j as f32 / n as f32;
                vertices.push([x, y, 0.1 * (3.0 * x).sin() * (2.0 * y).cos()]);
            }
        }
        let mut indices = Vec::new();
        let v = |i: u32, j: u32| j * (n + 1) + i;
        for j in 0..n {
            for i in 0..n {
                indices.extend([v(i, j), v(i + 1, j), v(i, j + 1)]);
                indices.extend([v(i + 1, j), v(i + 1, j + 1), v(i, j + 1)]);
            }
        }
        Self { vertices, indices }
    }

    pub fn triangle_count(&self) -> u32 {
        (self.indices.len() / 3) as u32
    }
}

/// A quad's BLAS (`built.blases[0]`) and lipac's unit cube's (the counting
/// boxes, `built.blases[1]`), built in one fast-trace batch, with what they
/// were built from and the build's scratch.
pub struct QuadAndCube {
    pub quad: GpuMesh,
    pub cube: UnitCube,
    pub built: BlasBatchOutput,
    pub scratch: ScratchBuffer,
}

/// Builds a [`QuadAndCube`] with `one_shot`.
pub fn quad_and_cube(h: &HeadlessContext, one_shot: &mut OneShot) -> QuadAndCube {
    let ctx = h.context();
    let quad = GpuMesh::new(h, Mesh::quad());
    let cube = UnitCube::new(ctx).unwrap();
    let mut batch = BlasBatch::new();
    let flags = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE;
    batch.push(&[quad.geometry()], flags).unwrap();
    batch.push(&[cube.geometry()], flags).unwrap();
    let mut scratch = ScratchBuffer::new(ctx);
    let built = one_shot.run(|rec| batch.record(rec, &mut scratch)).unwrap();
    QuadAndCube {
        quad,
        cube,
        built,
        scratch,
    }
}

/// A mesh uploaded as build input.
pub struct GpuMesh {
    pub mesh: Mesh,
    pub vertices: Buffer,
    pub indices: Buffer,
}

impl GpuMesh {
    pub fn new(h: &HeadlessContext, mesh: Mesh) -> Self {
        let ctx = h.context();
        let vertices =
            Buffer::with_data(ctx, BUILD_INPUT, MemoryLocation::CpuToGpu, &mesh.vertices).unwrap();
        let indices =
            Buffer::with_data(ctx, BUILD_INPUT, MemoryLocation::CpuToGpu, &mesh.indices).unwrap();
        Self {
            mesh,
            vertices,
            indices,
        }
    }

    pub fn geometry(&self) -> TriangleGeometry {
        TriangleGeometry::indexed(
            &self.vertices,
            0,
            12,
            self.mesh.vertices.len() as u32,
            &self.indices,
            0,
            lipac_vk::IndexFormat::U32,
            self.mesh.triangle_count(),
        )
        .unwrap()
    }
}

/// The backend tests' one mesh: `Mesh::bumpy_grid(4)` uploaded, and a
/// catalog holding it as `MeshId(1)` with one LOD whose build estimate is
/// the device's size query (fast trace) and whose geometry data is
/// `data_bytes`.
pub fn one_mesh_catalog(
    h: &HeadlessContext,
    data_bytes: u64,
) -> (GpuMesh, lipac_core::manager::MeshCatalog) {
    use lipac_core::build_plan::BuildEstimate;
    use lipac_core::instance::MeshId;
    use lipac_core::manager::{MeshCatalog, MeshLod};
    let mesh = GpuMesh::new(h, Mesh::bumpy_grid(4));
    let fast = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE;
    let s = GpuBlas::query_sizes(h.context(), &[mesh.geometry()], fast).unwrap();
    let mut catalog = MeshCatalog::new();
    let lod = MeshLod {
        estimate: BuildEstimate {
            primitives: u64::from(mesh.mesh.triangle_count()),
            result_bytes: s.acceleration_structure,
            build_scratch_bytes: s.build_scratch,
            update_scratch_bytes: s.update_scratch,
        },
        data_bytes,
    };
    catalog.insert(MeshId(1), vec![lod]).unwrap();
    (mesh, catalog)
}

/// Builds one BLAS per mesh in one batch.
pub fn build_blases(
    h: &HeadlessContext,
    meshes: &[&GpuMesh],
    flags: vk::BuildAccelerationStructureFlagsKHR,
) -> Vec<GpuBlas> {
    let ctx = h.context();
    let mut batch = BlasBatch::new();
    for m in meshes {
        batch.push(&[m.geometry()], flags).unwrap();
    }
    let mut scratch = ScratchBuffer::new(ctx);
    let out = OneShot::new(ctx)
        .unwrap()
        .run(|rec| batch.record(rec, &mut scratch))
        .unwrap();
    out.blases
}

/// One instance of the CPU reference scene.
#[derive(Clone, Debug)]
pub struct SceneInstance {
    pub mesh: Mesh,
    pub transform: Affine3A,
    pub custom_index: u32,
    pub sbt_offset: u32,
    pub active: bool,
}

/// The CPU reference's closest hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CpuHit {
    pub custom_index: u32,
    pub t: f64,
    /// Whether another hit (or a triangle edge) is so close that a GPU
    /// traversal may legitimately report something else.
    pub ambiguous: bool,
}

fn intersect(o: [f64; 3], d: [f64; 3], a: Vec3, b: Vec3, c: Vec3) -> Option<(f64, f64)> {
    let v = |p: Vec3| [p.x as f64, p.y as f64, p.z as f64];
    let (a, b, c) = (v(a), v(b), v(c));
    let sub = |p: [f64; 3], q: [f64; 3]| [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
    let cross = |p: [f64; 3], q: [f64; 3]| {
        [
            p[1] * q[2] - p[2] * q[1],
            p[2] * q[0] - p[0] * q[2],
            p[0] * q[1] - p[1] * q[0],
        ]
    };
    let dot = |p: [f64; 3], q: [f64; 3]| p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
    let e1 = sub(b, a);
    let e2 = sub(c, a);
    let p = cross(d, e2);
    let det = dot(e1, p);
    if det.abs() < 1e-12 {
        return None;
    }
    let s = sub(o, a);
    let u = dot(s, p) / det;
    let q = cross(s, e1);
    let w = dot(d, q) / det;
    let t = dot(e2, q) / det;
    let margin = u.min(w).min(1.0 - u - w);
    (margin >= -1e-9).then_some((t, margin))
}

/// Closest hit of a ray among active instances within [t_min, t_max].
pub fn cpu_trace(scene: &[SceneInstance], ray: &GpuRay) -> Option<CpuHit> {
    let o = ray.origin.map(f64::from);
    let d = ray.direction.map(f64::from);
    let mut hits: Vec<(f64, u32, f64)> = Vec::new();
    for inst in scene.iter().filter(|i| i.active) {
        let w: Vec<Vec3> = inst
            .mesh
            .vertices
            .iter()
            .map(|p| inst.transform.transform_point3((*p).into()))
            .collect();
        for t in inst.mesh.indices.chunks(3) {
            let (a, b, c) = (w[t[0] as usize], w[t[1] as usize], w[t[2] as usize]);
            if let Some((t, margin)) = intersect(o, d, a, b, c) {
                if t >= f64::from(ray.t_min) && t <= f64::from(ray.t_max) {
                    hits.push((t, inst.custom_index, margin));
                }
            }
        }
    }
    hits.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (t, custom_index, margin) = *hits.first()?;
    let close_other = hits
        .iter()
        .skip(1)
        .any(|h| h.0 - t < 1e-3 && h.1 != custom_index);
    Some(CpuHit {
        custom_index,
        t,
        ambiguous: margin < 1e-4 || close_other,
    })
}

/// A TLAS record for a scene instance.
pub fn tlas_record(inst: &SceneInstance, blas: &GpuBlas, mask: u8) -> TlasInstance {
    TlasInstance::new(
        affine_to_rows(&inst.transform),
        inst.custom_index,
        mask,
        inst.sbt_offset,
        lipac_core::layout::VK_INSTANCE_CULL_DISABLE,
        if inst.active {
            blas.device_address()
        } else {
            0
        },
    )
}

/// Result of one trace: per-ray hits and the two counter arrays.
pub struct TraceOutcome {
    pub hits: Vec<GpuHit>,
    pub instance_hits: Vec<u32>,
    pub hitbox_hits: Vec<u32>,
}

/// Uploads `records`, builds a TLAS (starting at `initial_capacity`) and
/// traces `rays` with `cull_mask` on `tracer`'s path; `counters` instance
/// counters and hitbox records (their hit counts returned as `hitbox_hits`).
pub fn trace(
    h: &HeadlessContext,
    tracer: &TestTracer,
    records: &[TlasInstance],
    initial_capacity: u32,
    rays: &[GpuRay],
    cull_mask: u8,
    counters: usize,
) -> (GpuTlas, TraceOutcome) {
    let ctx = h.context();
    let instances = Buffer::with_data(ctx, BUILD_INPUT, MemoryLocation::CpuToGpu, records).unwrap();
    let mut tlas = GpuTlas::new(
        ctx,
        initial_capacity,
        vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
    )
    .unwrap();
    let mut scratch = ScratchBuffer::new(ctx);
    let mut one_shot = OneShot::new(ctx).unwrap();
    let _retired = one_shot
        .run(|rec| tlas.record_build(rec, &instances, 0, records.len() as u32, &mut scratch))
        .unwrap();
    let outcome = trace_tlas(h, tracer, &tlas, rays, cull_mask, counters);
    (tlas, outcome)
}

/// Traces `rays` through a built `tlas` on `tracer`'s path (no merged
/// boxes): `counters` instance counters and zeroed hitbox records.
pub fn trace_tlas(
    h: &HeadlessContext,
    tracer: &TestTracer,
    tlas: &GpuTlas,
    rays: &[GpuRay],
    cull_mask: u8,
    counters: usize,
) -> TraceOutcome {
    let ctx = h.context();
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let ray_buf = Buffer::with_data(ctx, storage, MemoryLocation::CpuToGpu, rays).unwrap();
    let results = Buffer::new(
        ctx,
        (rays.len().max(1) * 16) as u64,
        storage,
        MemoryLocation::GpuToCpu,
    )
    .unwrap();
    let zeros = vec![0u32; counters];
    let instance_hits = Buffer::with_data(ctx, storage, MemoryLocation::GpuToCpu, &zeros).unwrap();
    let empty = vec![HitboxRecord::zeroed(); counters];
    let hitboxes = Buffer::with_data(ctx, storage, MemoryLocation::GpuToCpu, &empty).unwrap();
    let bounds = Buffer::with_data(
        ctx,
        storage,
        MemoryLocation::CpuToGpu,
        &vec![[0f32; 4]; counters],
    )
    .unwrap();
    tracer.run(
        h,
        tlas,
        &ray_buf,
        rays.len() as u32,
        &results,
        &instance_hits,
        &hitboxes,
        &bounds,
        &MergedBoxes::OFF,
        cull_mask,
        0,
    );
    let records: Vec<HitboxRecord> = hitboxes.read(0, counters).unwrap();
    TraceOutcome {
        hits: results.read(0, rays.len()).unwrap(),
        instance_hits: instance_hits.read(0, counters).unwrap(),
        hitbox_hits: records.iter().map(HitboxRecord::hits).collect(),
    }
}

/// Compares GPU hits with the CPU reference; returns how many rays were
/// compared and how many of them hit.
pub fn compare_with_cpu(
    scene: &[SceneInstance],
    rays: &[GpuRay],
    hits: &[GpuHit],
) -> (usize, usize) {
    let mut compared = 0;
    let mut hit_count = 0;
    for (i, (ray, gpu)) in rays.iter().zip(hits).enumerate() {
        let cpu = cpu_trace(scene, ray);
        if cpu.is_some_and(|c| c.ambiguous) {
            continue;
        }
        compared += 1;
        match cpu {
            None => assert!(!gpu.is_hit(), "ray {i} {ray:?}: CPU miss, GPU hit {gpu:?}"),
            Some(c) => {
                hit_count += 1;
                assert!(gpu.is_hit(), "ray {i} {ray:?}: CPU hit {c:?}, GPU miss");
                assert_eq!(
                    gpu.custom_index, c.custom_index,
                    "ray {i} {ray:?}: {c:?} vs {gpu:?}"
                );
                let tol = 1e-4 * c.t.max(1.0);
                assert!(
                    (f64::from(gpu.t) - c.t).abs() <= tol,
                    "ray {i} {ray:?}: t {} vs CPU {}",
                    gpu.t,
                    c.t
                );
            }
        }
    }
    (compared, hit_count)
}

/// Asserts that two TLAS record lists are the same multiset, bit for bit
/// (both sorted canonically), naming the first differing record.
pub fn assert_tlas_equal(mut gpu: Vec<TlasInstance>, mut cpu: Vec<TlasInstance>, what: &str) {
    assert_eq!(gpu.len(), cpu.len(), "{what}: record count");
    lipac_core::assembly::sort_canonical(&mut gpu);
    lipac_core::assembly::sort_canonical(&mut cpu);
    for (i, (g, c)) in gpu.iter().zip(&cpu).enumerate() {
        assert!(
            bytemuck::bytes_of(g) == bytemuck::bytes_of(c),
            "{what}: record {i} differs:\nGPU {g:?}\nCPU {c:?}"
        );
    }
}

/// A fast-trace TLAS over `records` (room for at least one), built and
/// waited for, with its instance buffer (keep it while tracing).
pub fn build_tlas(h: &HeadlessContext, records: &[TlasInstance]) -> (GpuTlas, Buffer) {
    let ctx = h.context();
    let instances = Buffer::with_data(ctx, BUILD_INPUT, MemoryLocation::CpuToGpu, records).unwrap();
    let fast = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE;
    let mut tlas = GpuTlas::new(ctx, (records.len() as u32).max(1), fast).unwrap();
    let mut scratch = ScratchBuffer::new(ctx);
    let mut one_shot = OneShot::new(ctx).unwrap();
    let _retired = one_shot
        .run(|rec| tlas.record_build(rec, &instances, 0, records.len() as u32, &mut scratch))
        .unwrap();
    (tlas, instances)
}

/// A horizontal 6 m tile ([`Mesh::bumpy_grid`] scaled by 3, rotated into the
/// x/z plane) at `(x, y, z)`, with its AABB (1 m high).
pub fn tile(x: f32, y: f32, z: f32) -> (Affine3A, lipac_core::math::Aabb) {
    let at = Vec3::new(x, y, z);
    let t = Affine3A::from_scale_rotation_translation(
        Vec3::splat(3.0),
        glam::Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2),
        at,
    );
    (
        t,
        lipac_core::math::Aabb::new(at - Vec3::new(3.0, 0.5, 3.0), at + Vec3::new(3.0, 0.5, 3.0)),
    )
}
