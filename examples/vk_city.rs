//! lipac's whole loop on a Vulkan ray-query device (lavapipe works): the
//! procedural city of lipac-sim, real BLAS/TLAS builds, GPU Algorithm 1 →
//! TLAS build → ray-query trace with counting boxes → GPU Algorithm 2 →
//! readback ring → command queue → BLAS build plans for the next frames.
//!
//! ```text
//! cargo run --release --features vk,sim --example vk_city -- [--instances N] [--full] [--frames F]
//!                                          [--width W] [--height H] [--out FILE.png]
//! ```
//!
//! Defaults: about 5000 instances, 12 frames at 160 × 96, `vk_city.png`.
//! `--full` renders the default city (about 20k instances). Prints, per frame,
//! the active instances, BLAS builds / updates / compactions / frees, the
//! acceleration-structure pool's used bytes, the TLAS bytes and the counting
//! boxes; writes the last frame as a PNG. Without a ray-query device it
//! prints why and exits successfully.
//!
//! `LIPAC_VALIDATION=1` runs it under the validation layer and fails on any
//! validation error.
//!
//! The GPU owns the state bits: the instance and hitbox records live in
//! device-local memory, the host changes them only through
//! [`RecordUploader`] (BLAS addresses from the CPU registry's dirty ranges,
//! scattered without touching the state bits), and the tracer
//! (`trace_counting.comp`, [`HitboxCounting::Records`]) counts hitbox boxes
//! straight into the hitbox records Algorithm 2 reads.
//!
//! Simplifications (see docs/VULKAN.md): the host generates the rays
//! (primary rays, then shadow rays from their hits, both counting boxes
//! through `lipac_counting.glsl`), so each frame's three submissions run in
//! lockstep. Animated instances use their shared mesh.

use ash::vk;
use glam::Vec3;
use lipac::core::blas_cache::BlasOwner;
use lipac::core::blas_ids::{InstanceKey, Lod};
use lipac::core::build_plan::{
    BlasGeometry, BuildBudgets, BuildEstimate, BuildScheduler, InstanceBlasRequest, SchedulerConfig,
};
use lipac::core::command::{CommandKind, CommandQueue};
use lipac::core::culling::Uploads;
use lipac::core::grid::{GridConfig, HitboxGrid};
use lipac::core::hitbox_index::HitboxIndex;
use lipac::core::instance::InstanceDesc;
use lipac::core::layout::InstanceState;
use lipac::core::registry::{InstanceRegistry, RegistryConfig};
use lipac::core::thresholds::Thresholds;
use lipac::core::MeshId;
use lipac::sim::camera::CameraPath;
use lipac::sim::scene::{LodPolicy, Scene, SceneConfig};
use lipac::vk::{
    hitbox_bounds, AccelerationStructurePool, AssemblyBuffers, AssemblyPipeline, Blas, BlasBatch,
    Buffer, CountingConfig, FeedbackBuffers, FeedbackPipeline, FrameSubmitter, GpuHit, GpuRay,
    HeadlessContext, HitboxCounting, MemoryLocation, OneShot, PlanExecutor, ReadbackRing,
    RecordUploader, Retirement, ScratchBuffer, TlasPair, TraceBuffers, TracePipeline,
    TriangleGeometry, UnitCube, UploadTargets, Validation, VkError, DEFAULT_POOL_BLOCK_SIZE,
};
use std::collections::HashMap;
use std::error::Error;
use std::time::Instant;

type AnyResult<T> = Result<T, Box<dyn Error>>;

struct Args {
    instances: u64,
    full: bool,
    frames: u32,
    width: u32,
    height: u32,
    out: String,
}

fn parse_args() -> AnyResult<Args> {
    let mut a = Args {
        instances: 5000,
        full: false,
        frames: 12,
        width: 160,
        height: 96,
        out: "vk_city.png".into(),
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or(format!("{flag} needs a value"));
        match flag.as_str() {
            "--instances" => a.instances = value()?.parse()?,
            "--full" => a.full = true,
            "--frames" => a.frames = value()?.parse()?,
            "--width" => a.width = value()?.parse()?,
            "--height" => a.height = value()?.parse()?,
            "--out" => a.out = value()?,
            other => return Err(format!("unknown argument {other}").into()),
        }
    }
    if a.width == 0 || a.height == 0 || a.frames == 0 || a.instances == 0 {
        return Err("width, height, frames and instances must be positive".into());
    }
    Ok(a)
}

/// One mesh LOD uploaded as build input (non-indexed positions).
struct GpuLod {
    _vertices: Buffer,
    geometry: TriangleGeometry,
    estimate: BuildEstimate,
}

/// Uploads a mesh LOD's triangles (or `None` when it has none).
fn upload(
    ctx: &lipac::vk::DeviceContext,
    mesh: &lipac::sim::mesh::MeshLod,
) -> AnyResult<Option<GpuLod>> {
    let positions: Vec<[f32; 3]> = mesh
        .triangles
        .iter()
        .flat_map(|t| [t.v0, t.v1, t.v2])
        .map(|v| [v.x, v.y, v.z])
        .collect();
    if positions.is_empty() {
        return Ok(None);
    }
    let vertices = Buffer::with_data(ctx, BUILD_INPUT, MemoryLocation::CpuToGpu, &positions)?;
    let geometry = TriangleGeometry {
        vertex_address: vertices.device_address(),
        vertex_stride: 12,
        vertex_count: positions.len() as u32,
        indices: None,
        triangle_count: (positions.len() / 3) as u32,
        opaque: true,
    };
    let s = Blas::query_sizes(ctx, &[geometry], BLAS_FLAGS)?;
    Ok(Some(GpuLod {
        _vertices: vertices,
        geometry,
        estimate: BuildEstimate {
            primitives: u64::from(geometry.triangle_count),
            result_bytes: s.acceleration_structure,
            build_scratch_bytes: s.build_scratch,
            update_scratch_bytes: s.update_scratch,
        },
    }))
}

const STORAGE: vk::BufferUsageFlags = vk::BufferUsageFlags::STORAGE_BUFFER;
const XFER: vk::BufferUsageFlags = vk::BufferUsageFlags::from_raw(
    vk::BufferUsageFlags::TRANSFER_SRC.as_raw() | vk::BufferUsageFlags::TRANSFER_DST.as_raw(),
);
const BUILD_INPUT: vk::BufferUsageFlags =
    vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR;
const HOST: MemoryLocation = MemoryLocation::GpuToCpu;
const BLAS_FLAGS: vk::BuildAccelerationStructureFlagsKHR =
    vk::BuildAccelerationStructureFlagsKHR::from_raw(
        vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE.as_raw()
            | vk::BuildAccelerationStructureFlagsKHR::ALLOW_COMPACTION.as_raw(),
    );

fn main() -> std::process::ExitCode {
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("vk_city: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run() -> AnyResult<()> {
    let args = parse_args()?;
    // LIPAC_VALIDATION=1 runs under the validation layer and fails on errors.
    let validate = std::env::var("LIPAC_VALIDATION").is_ok_and(|v| v == "1");
    let validation = if validate {
        Validation::Required
    } else {
        Validation::Off
    };
    let headless = match HeadlessContext::new(validation) {
        Ok(h) => h,
        Err(e) if e.is_unsupported_machine() => {
            println!("vk_city: skipped, no Vulkan ray-query device: {e}");
            return Ok(());
        }
        Err(e) => return Err(e.into()),
    };
    let ctx = headless.context();
    let start = Instant::now();

    // ---- scene, hitbox grid, registry ------------------------------------
    let config = if args.full {
        SceneConfig::city()
    } else {
        SceneConfig::city().scaled_to(args.instances)
    };
    let scene = Scene::generate(&config)?;
    let bounds = scene.bounds();
    let grid = HitboxGrid::new(GridConfig {
        min: [f64::from(bounds.min.x), f64::from(bounds.min.z)],
        max: [f64::from(bounds.max.x), f64::from(bounds.max.z)],
        cell_size: 32.0,
    })?;
    let aspect = args.width as f32 / args.height as f32;
    let path = CameraPath::flythrough(&scene, aspect);
    let lod_policy = LodPolicy::default();
    let eye0 = path.camera_at(0).position;
    let mut registry = InstanceRegistry::new(grid.clone(), RegistryConfig::default())?;
    for inst in scene.instances() {
        let mut desc = InstanceDesc::new(MeshId(inst.mesh), inst.transform, inst.aabb);
        desc.lod = lod_policy.lod(eye0, &inst.aabb) as u32;
        registry.register(desc)?;
    }
    let slots = registry.slot_count();
    let hitbox_count = grid.len();
    println!(
        "vk_city: {} instances, {} meshes, {} hitboxes, {}x{} px, {} frames, device: {}",
        slots,
        scene.library().len(),
        hitbox_count,
        args.width,
        args.height,
        args.frames,
        ctx.device_name()
    );

    // ---- mesh LODs as build inputs ---------------------------------------
    let mut lods: HashMap<(u32, u8), GpuLod> = HashMap::new();
    for inst in scene.instances().iter().filter(|i| !i.is_unique()) {
        let key = (inst.mesh, lod_policy.lod(eye0, &inst.aabb) as u8);
        if let std::collections::hash_map::Entry::Vacant(e) = lods.entry(key) {
            if let Some(l) = upload(ctx, scene.library().lod(key.0, usize::from(key.1))?)? {
                e.insert(l);
            }
        }
    }
    // Unique instances (terrain tiles, terrain-adapted buildings, units) get
    // their own geometry when they first become active.
    let mut unique_lods: HashMap<u32, GpuLod> = HashMap::new();
    let mut unique_mesh = lipac::sim::mesh::MeshLod::default();

    // ---- GPU state --------------------------------------------------------
    let mut one_shot = OneShot::new(ctx)?;
    let cube = UnitCube::new(ctx)?;
    let mut cube_batch = BlasBatch::new();
    cube_batch.push(
        &[cube.geometry()],
        vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
    )?;
    let mut setup_scratch = ScratchBuffer::new(ctx);
    let cube_blas = one_shot
        .run(|rec| cube_batch.record(rec, &mut setup_scratch))?
        .blases
        .remove(0);
    let counting = CountingConfig::default();
    let mut assembly_config =
        lipac::core::assembly::AssemblyConfig::new(cube_blas.device_address());
    assembly_config.counting_mask = counting.counting_mask;
    assembly_config.omitted_box_sbt_offset = counting.omitted_box_sbt_offset;
    assembly_config.hitbox_sbt_offset = counting.hitbox_box_sbt_offset;
    let rays_per_frame = f64::from(args.width * args.height);
    let mut thresholds = Thresholds::for_rays_per_frame(rays_per_frame)?;
    thresholds.n_a = 2;
    thresholds.validate()?;

    let tlas_capacity = slots + hitbox_count;
    let command_capacity = slots.max(1);
    // Instance and hitbox records are device-local: Algorithm 2 owns their
    // state bits and the host writes them only through the RecordUploader.
    let instances = Buffer::new(
        ctx,
        u64::from(slots) * std::mem::size_of::<lipac::core::layout::InstanceRecord>() as u64,
        STORAGE,
        MemoryLocation::GpuOnly,
    )?;
    let hitboxes = Buffer::new(
        ctx,
        u64::from(hitbox_count) * 12,
        STORAGE,
        MemoryLocation::GpuOnly,
    )?;
    let bounds_buf = Buffer::with_data(ctx, STORAGE, HOST, &hitbox_bounds(&grid))?;
    let tlas_out = Buffer::new(
        ctx,
        u64::from(tlas_capacity) * 64,
        STORAGE | XFER | BUILD_INPUT,
        MemoryLocation::GpuOnly,
    )?;
    let tlas_counter = Buffer::with_data(ctx, STORAGE | XFER, HOST, &[0u32])?;
    let instance_hits = Buffer::with_data(ctx, STORAGE | XFER, HOST, &vec![0u32; slots as usize])?;
    let commands = Buffer::new(ctx, u64::from(command_capacity) * 4, STORAGE | XFER, HOST)?;
    let command_counter = Buffer::with_data(ctx, STORAGE | XFER, HOST, &[0u32])?;
    let pixel_count = (args.width * args.height) as usize;
    let mut rays = Buffer::new(
        ctx,
        (pixel_count * 32) as u64,
        STORAGE,
        MemoryLocation::CpuToGpu,
    )?;
    let results = Buffer::new(ctx, (pixel_count * 16) as u64, STORAGE, HOST)?;

    let assembly = AssemblyPipeline::new(ctx)?;
    let feedback = FeedbackPipeline::new(ctx)?;
    let tracer = TracePipeline::with_hitbox_counting(ctx, &counting, HitboxCounting::Records)?;
    let uploader = RecordUploader::new(ctx)?;
    // One staging set suffices: every frame waits for its submissions.
    let mut ub = uploader.bind(&UploadTargets {
        instances: &instances,
        hitboxes: &hitboxes,
    })?;
    // The first upload: every record, registration's state (inactive) for
    // every slot, every hitbox inactive with streak 0 (Algorithm 1's reset
    // clears the heights and hits).
    let initial = Uploads {
        records: registry.take_dirty(),
        state_overrides: (0..slots).map(|s| (s, InstanceState::Inactive)).collect(),
        hitbox_overrides: (0..hitbox_count).map(|i| (i, false)).collect(),
    };
    one_shot.run(|rec| uploader.record(rec, &mut ub, &initial, registry.records()))?;
    let ab = assembly.bind(&AssemblyBuffers {
        instances: &instances,
        hitboxes: &hitboxes,
        hitbox_bounds: &bounds_buf,
        tlas_instances: &tlas_out,
        tlas_counter: &tlas_counter,
    })?;
    let fb = feedback.bind(&FeedbackBuffers {
        instances: &instances,
        instance_hits: &instance_hits,
        hitboxes: &hitboxes,
        commands: &commands,
        command_counter: &command_counter,
    })?;
    let mut ring = ReadbackRing::new(ctx, 3, command_capacity)?;
    let ring_semaphore = ring.semaphore().clone();
    let mut submitter = FrameSubmitter::new(ctx, 2)?;
    let pool = AccelerationStructurePool::new(ctx, DEFAULT_POOL_BLOCK_SIZE)?;
    let mut executor = PlanExecutor::new(ctx, pool.clone())?;
    let mut scheduler = BuildScheduler::new(SchedulerConfig {
        scratch_alignment: executor.scratch_alignment(),
        lod_hysteresis_frames: 2,
        ..SchedulerConfig::default()
    })?;
    let budgets = BuildBudgets::default();
    let mut queue = CommandQueue::new(slots);
    let mut tlas = TlasPair::new(
        ctx,
        1024.min(tlas_capacity),
        vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
    )?;
    let mut tlas_scratch = ScratchBuffer::new(ctx);
    let mut retirement = Retirement::new();
    let sun = Vec3::new(0.4, 0.8, 0.3).normalize();
    let mut image = vec![0u8; pixel_count * 3];

    println!(
        "frame | active | builds upd compact freed | pool used / capacity (blocks, frag) | TLAS bytes | TLAS records | cmds | uploaded"
    );
    for f in 1..=u64::from(args.frames) {
        let camera = path.camera_at(f as u32);
        registry.begin_frame(f)?;
        scheduler.begin_frame(f)?;
        // Commands of earlier frames, never waiting.
        let mut ingested = 0;
        for slot in 0..ring.slot_count() {
            if let Some(r) = ring.try_read(slot)? {
                ingested += r.counter();
                r.ingest_into(&mut queue);
            }
        }
        for c in queue.drain(usize::MAX) {
            let key = InstanceKey(c.slot);
            let Some(handle) = registry.handle_at(c.slot) else {
                continue;
            };
            let desc = registry.desc(handle)?;
            let active =
                scheduler.current_blas(key).is_some() || scheduler.pending_lod(key).is_some();
            match c.kind {
                CommandKind::Add if !active => {
                    let lod = desc.lod as u8;
                    let unique = scene.instance(c.slot)?.is_unique();
                    if unique && !unique_lods.contains_key(&c.slot) {
                        scene.unique_geometry(c.slot, usize::from(lod), 0, &mut unique_mesh)?;
                        if let Some(l) = upload(ctx, &unique_mesh)? {
                            unique_lods.insert(c.slot, l);
                        }
                    }
                    let l = if unique {
                        unique_lods.get(&c.slot)
                    } else {
                        lods.get(&(desc.mesh.0, lod))
                    };
                    let Some(l) = l else {
                        continue;
                    };
                    let geometry = if unique {
                        BlasGeometry::Unique { mesh: desc.mesh }
                    } else {
                        BlasGeometry::Shared {
                            mesh: desc.mesh,
                            variant: 0,
                            compactable: true,
                        }
                    };
                    let request = InstanceBlasRequest {
                        geometry,
                        lod: Lod(lod),
                        estimate: l.estimate,
                        hits: u32::from(c.priority),
                        in_frustum: true,
                    };
                    if scheduler.activate(key, request).is_err() {
                        continue;
                    }
                }
                CommandKind::Remove if active => {
                    scheduler.deactivate(key)?;
                    registry.set_blas_at(c.slot, 0)?;
                }
                _ => {}
            }
        }
        executor.poll(&mut scheduler)?;
        let plan = scheduler.plan(&budgets)?;
        let source = |owner: &BlasOwner| -> Option<Vec<TriangleGeometry>> {
            let l = match *owner {
                BlasOwner::Shared(k) => lods.get(&(k.mesh.0, k.lod.0)),
                BlasOwner::Unique { instance, .. } => unique_lods.get(&instance.0),
            };
            l.map(|l| vec![l.geometry])
        };

        // Primary rays for this frame's camera.
        let primary: Vec<GpuRay> = (0..pixel_count as u32)
            .map(|i| {
                let d = camera.ray_direction(
                    i % args.width,
                    i / args.width,
                    args.width,
                    args.height,
                    (0.0, 0.0),
                );
                GpuRay {
                    origin: camera.position.to_array(),
                    t_min: 0.0,
                    direction: d.to_array(),
                    t_max: 1.0e5,
                }
            })
            .collect();
        rays.write(0, &primary)?;

        // Submission 1: BLAS plan, record uploads, GPU Algorithm 1, TLAS build.
        let mut uploaded = 0;
        let report = submitter.submit(&[], &[], |rec| {
            let report = executor.record(rec, &plan, &mut scheduler, &source, f)?;
            for key in scheduler.take_address_changes() {
                let addr = scheduler.blas_address(key).unwrap_or(0);
                registry
                    .set_blas_at(key.0, addr)
                    .map_err(|e| VkError::InvalidArgument(e.to_string()))?;
            }
            // The changed records go up without touching the GPU's state bits.
            let uploads = Uploads {
                records: registry.take_dirty(),
                ..Uploads::default()
            };
            uploaded = uploader
                .record(rec, &mut ub, &uploads, registry.records())?
                .records;
            feedback.record_clear_instance_hits(rec, &fb)?;
            assembly.record(rec, &ab, &assembly_config, slots)?;
            tlas.record_build(
                rec,
                &tlas_out,
                0,
                tlas_capacity,
                &mut tlas_scratch,
                &mut retirement,
                f,
            )?;
            Ok(report)
        })?;
        let tb = tracer.bind(&TraceBuffers {
            tlas: tlas.current(),
            rays: &rays,
            results: &results,
            instance_hits: &instance_hits,
            hitbox_hits: &hitboxes,
        })?;
        submitter.submit(&[], &[], |rec| {
            tracer.record(rec, &tb, pixel_count as u32, 0xFF, 0)
        })?;
        submitter.wait_idle()?;
        let hits: Vec<GpuHit> = results.read(0, pixel_count)?;

        // Submission 2: shadow rays from the primary hits (they count too).
        let shadow_of: Vec<usize> = (0..pixel_count).filter(|&i| hits[i].is_hit()).collect();
        let shadow: Vec<GpuRay> = shadow_of
            .iter()
            .map(|&i| {
                let p = Vec3::from(primary[i].origin)
                    + Vec3::from(primary[i].direction) * hits[i].t * 0.999;
                GpuRay {
                    origin: (p + sun * 0.05).to_array(),
                    t_min: 0.0,
                    direction: sun.to_array(),
                    t_max: 1.0e4,
                }
            })
            .collect();
        let mut lit = vec![true; pixel_count];
        if !shadow.is_empty() {
            rays.write(0, &shadow)?;
            submitter.submit(&[], &[], |rec| {
                tracer.record(rec, &tb, shadow.len() as u32, 0xFF, 0)
            })?;
            submitter.wait_idle()?;
            let sh: Vec<GpuHit> = results.read(0, shadow.len())?;
            for (k, &i) in shadow_of.iter().enumerate() {
                lit[i] = !sh[k].is_hit();
            }
        }

        // The tracer counted hitbox boxes into the hitbox records already.
        // Submission 3: GPU Algorithm 2 and the readback copy.
        let ring_value = f;
        submitter.submit(&[], &[(&ring_semaphore, ring_value)], |rec| {
            feedback.record(rec, &fb, &thresholds, slots)?;
            let ticket = ring.record_copy(rec, &commands, &command_counter)?;
            debug_assert_eq!(ticket.value, ring_value);
            Ok(())
        })?;
        submitter.wait_idle()?;
        drop(tb);
        executor.collect(ring.semaphore().value()?);
        retirement.collect_signalled(ring.semaphore())?;

        let tlas_records: u32 = tlas_counter.read(0, 1)?[0];
        let ps = executor.stats().pool;
        println!(
            "{f:5} | {:6} | {:6} {:3} {:7} {:5} | {:>9} / {:>9} ({}, {:.2}) | {:>10} | {:12} | {:4} | {}",
            scheduler.stats().instances,
            report.builds,
            report.updates,
            report.compactions,
            report.retired.len(),
            ps.used_bytes,
            ps.capacity_bytes,
            ps.blocks,
            ps.fragmentation,
            tlas.memory_bytes(),
            tlas_records,
            ingested,
            uploaded,
        );
        if f == u64::from(args.frames) {
            for i in 0..pixel_count {
                let rgb = if hits[i].is_hit() {
                    let h = hits[i].custom_index.wrapping_mul(2_654_435_761);
                    let albedo = Vec3::new(
                        0.45 + 0.4 * ((h & 0xFF) as f32 / 255.0),
                        0.45 + 0.4 * (((h >> 8) & 0xFF) as f32 / 255.0),
                        0.45 + 0.4 * (((h >> 16) & 0xFF) as f32 / 255.0),
                    );
                    let fog = (-hits[i].t / 1500.0).exp();
                    albedo * if lit[i] { 1.0 } else { 0.35 } * fog + Vec3::splat(0.7) * (1.0 - fog)
                } else {
                    let d = Vec3::from(primary[i].direction);
                    Vec3::new(0.55, 0.7, 0.9).lerp(Vec3::new(0.9, 0.9, 0.95), 1.0 - d.y.max(0.0))
                };
                for (c, v) in rgb.to_array().iter().enumerate() {
                    image[i * 3 + c] = (v.clamp(0.0, 1.0) * 255.0).round() as u8;
                }
            }
        }
    }
    let file = std::io::BufWriter::new(std::fs::File::create(&args.out)?);
    let mut encoder = png::Encoder::new(file, args.width, args.height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.write_header()?.write_image_data(&image)?;
    let stats = scheduler.stats();
    println!(
        "vk_city: wrote {} in {:.1} s; {} live BLASes ({} bytes; cache: shared {} B, compacted {} B), pool {} bytes of device memory",
        args.out,
        start.elapsed().as_secs_f64(),
        executor.stats().live_blases,
        executor.stats().live_bytes,
        stats.cache.shared_bytes,
        stats.cache.compacted_bytes,
        pool.memory_bytes(),
    );
    submitter.wait_idle()?;
    executor.collect(u64::MAX);
    retirement.collect(u64::MAX);
    let errors = headless.validation_errors();
    if !errors.is_empty() {
        return Err(format!("{} validation errors:\n{}", errors.len(), errors.join("\n")).into());
    }
    Ok(())
}
