//! lipac on a Vulkan device with acceleration structures and ray queries or
//! ray-tracing pipelines (lavapipe has both), driven the way an engine
//! drives it: a `Manager` plans each frame, one `LipacVk` executes the plan
//! in the engine's command buffer (BLAS builds, record uploads, GPU
//! Algorithm 1, TLAS build, GPU Algorithm 2, read-back copies), and the
//! "engine" traces its own pass in between: a primary ray per pixel, a sun
//! shadow ray and one diffuse bounce, all generated on the GPU, counted
//! through lipac's includes, with ray queries (`CameraTracer`,
//! `lipac_counting.glsl`) or a ray-tracing pipeline (`PipelineCameraTracer`,
//! `lipac_counting_pipeline.glsl`, counting in the hit shaders). Frames are
//! kept in flight; acknowledgements and read-backs come back through
//! `LipacVk::poll`, which never waits.
//!
//! ```text
//! cargo run --release --features vk,sim --example vk_city -- [--instances N] [--frames F]
//!     [--width W] [--height H] [--in-flight K] [--out FILE.png] [--tracing ray-query|pipeline]
//! ```
//!
//! `--tracing` picks the path; by default ray queries when the device has
//! them (one compute dispatch, no shader binding table), else the pipeline.
//!
//! Defaults: about 5000 instances of lipac-sim's procedural city, 12 frames at
//! 160 × 96, 2 frames in flight, `vk_city.png` (the last frame). Prints per
//! frame the host's blocking waits, the TLAS records and counting boxes,
//! BLAS builds / compactions / frees and lipac's device memory. Without a
//! suitable device it prints why and exits successfully (with
//! `LIPAC_REQUIRE_VULKAN=1` it fails). `LIPAC_VALIDATION=1` runs under the
//! validation layer and fails on any validation error.
//!
//! The integration is `run`'s frame loop; everything above it (`City`) is
//! scene set-up: meshes, instances, the engine's vertex buffers.

use ash::vk;
use glam::Vec3;
use lipac::core::blas_cache::BlasOwner;
use lipac::core::build_plan::{BuildEstimate, SchedulerConfig};
use lipac::core::grid::{GridConfig, HitboxGrid};
use lipac::core::hitbox_index::HitboxIndex;
use lipac::core::hitbox_tree::AdaptiveHitboxes;
use lipac::core::instance::{InstanceDesc, InstanceFlags, MeshId};
use lipac::core::manager::{
    DataUpload, FrameBudgets, Manager, ManagerConfig, ManagerPlan, MeshCatalog, MeshLod,
};
use lipac::core::thresholds::Thresholds;
use lipac::sim::camera::{CameraPath, FlyCamera};
use lipac::sim::mesh::TERRAIN_RESOLUTION;
use lipac::sim::scene::{LodPolicy, Scene, SceneConfig, TERRAIN_MESH};
use lipac::vk::{
    AnyCameraTracer, BlasGeometrySource, Buffer, CameraTraceBuffers, CameraView, DeviceContext,
    FrameSubmitter, GpuBlas, HeadlessContext, InstanceDataSource, LipacVk, LipacVkConfig,
    MemoryLocation, RecordedFrame, Recorder, TracingPath, TriangleGeometry, Validation,
};
use std::collections::HashMap;
use std::error::Error;

/// Errors of the example.
pub type AnyResult<T> = Result<T, Box<dyn Error>>;

/// Command-line options.
#[derive(Clone, Debug)]
pub struct Options {
    /// Instances of the city (scaled).
    pub instances: u64,
    /// Frames to render.
    pub frames: u32,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Frames in flight (the engine's command buffers).
    pub in_flight: usize,
    /// PNG of the last frame, if any.
    pub out: Option<String>,
    /// Run under the validation layer.
    pub validation: Validation,
    /// Print the per-frame table.
    pub print: bool,
    /// The tracing path; `None`: the device's preferred one (ray queries
    /// when it has them).
    pub tracing: Option<TracingPath>,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            instances: 5000,
            frames: 12,
            width: 160,
            height: 96,
            in_flight: 2,
            out: Some("vk_city.png".into()),
            validation: Validation::Off,
            print: true,
            tracing: None,
        }
    }
}

fn parse_args() -> AnyResult<Options> {
    let mut a = Options::default();
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or(format!("{flag} needs a value"));
        match flag.as_str() {
            "--instances" => a.instances = value()?.parse()?,
            "--frames" => a.frames = value()?.parse()?,
            "--width" => a.width = value()?.parse()?,
            "--height" => a.height = value()?.parse()?,
            "--in-flight" => a.in_flight = value()?.parse()?,
            "--out" => a.out = Some(value()?),
            "--tracing" => a.tracing = Some(value()?.parse()?),
            other => return Err(format!("unknown argument {other}").into()),
        }
    }
    if a.width == 0 || a.height == 0 || a.frames == 0 || a.instances == 0 || a.in_flight < 2 {
        return Err("width, height, frames, instances must be positive, in-flight >= 2".into());
    }
    if std::env::var("LIPAC_VALIDATION").is_ok_and(|v| v == "1") {
        a.validation = Validation::Required;
    }
    Ok(a)
}

fn main() -> std::process::ExitCode {
    let result = parse_args().and_then(|o| {
        let Some(headless) = device(o.validation)? else {
            return Ok(());
        };
        run(&headless, &o).map(|_| ())
    });
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("vk_city: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// A headless device (acceleration structures and a tracing path), or
/// `None` (with a message) on a machine without one unless
/// `LIPAC_REQUIRE_VULKAN=1`.
pub fn device(validation: Validation) -> AnyResult<Option<HeadlessContext>> {
    match HeadlessContext::new(validation) {
        Ok(h) => Ok(Some(h)),
        Err(e) if e.is_unsupported_machine() && std::env::var("LIPAC_REQUIRE_VULKAN").is_err() => {
            println!("vk_city: not run, no suitable Vulkan device: {e}");
            Ok(None)
        }
        Err(e) => Err(e.into()),
    }
}

// ---- scene set-up ---------------------------------------------------------

const BUILD_INPUT: vk::BufferUsageFlags =
    vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR;
/// Geometry data per instance: RGB albedo and one spare `f32`.
const DATA_BYTES: u64 = 16;

fn positions(mesh: &lipac::sim::mesh::LodTriangles) -> Vec<[f32; 3]> {
    let t = mesh.triangles.iter().flat_map(|t| [t.v0, t.v1, t.v2]);
    t.map(|v| v.to_array()).collect()
}

fn triangles(vertices: Option<&Buffer>, count: usize) -> TriangleGeometry {
    TriangleGeometry {
        // Size queries ignore addresses: any aligned placeholder will do.
        vertex_address: vertices.map_or(256, Buffer::device_address),
        vertex_stride: 12,
        vertex_count: count as u32,
        indices: None,
        triangle_count: (count / 3) as u32,
        opaque: true,
    }
}

/// The scene and the engine's meshes: lipac-sim's city, its instances, and
/// the vertex buffers of the (mesh, LOD)s and unique instances BLASes are
/// built from, uploaded when a plan first asks for them.
pub struct City {
    /// The procedural city.
    pub scene: Scene,
    /// 32 m hitbox cells over it.
    pub grid: HitboxGrid,
    /// Per-mesh LOD sizes for the manager.
    pub catalog: MeshCatalog,
    /// The instances to register (slot order).
    pub descs: Vec<InstanceDesc>,
    /// The camera path.
    pub path: CameraPath,
    /// Rays per frame (for the thresholds).
    pub rays_per_frame: f64,
    /// The scene slot of each registered instance (manager slot order).
    scene_slots: Vec<u32>,
    shared: HashMap<(u32, u32), (Buffer, TriangleGeometry)>,
    unique: HashMap<u32, (Buffer, TriangleGeometry)>,
}

impl City {
    /// Generates the scene and measures every mesh LOD's build sizes.
    pub fn new(ctx: &DeviceContext, o: &Options) -> AnyResult<Self> {
        let scene = Scene::generate(&SceneConfig::city().scaled_to(o.instances))?;
        let b = scene.bounds();
        let grid = HitboxGrid::new(GridConfig {
            min: [f64::from(b.min.x), f64::from(b.min.z)],
            max: [f64::from(b.max.x), f64::from(b.max.z)],
            cell_size: 32.0,
        })?;
        let flags = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE
            | vk::BuildAccelerationStructureFlagsKHR::ALLOW_COMPACTION;
        // Triangles per (mesh, LOD): the library's meshes and the terrain tiles.
        let mut meshes: Vec<(u32, Vec<usize>)> = scene
            .library()
            .iter()
            .map(|(id, m)| (id, m.lods.iter().map(|l| l.triangles.len()).collect()))
            .collect();
        let tiles = TERRAIN_RESOLUTION.iter().map(|r| 2 * (r * r) as usize);
        meshes.push((TERRAIN_MESH, tiles.collect()));
        let mut catalog = MeshCatalog::new();
        let mut triangle_counts = HashMap::new();
        for (id, counts) in meshes {
            let mut lods = Vec::new();
            for &n in &counts {
                let s = GpuBlas::query_sizes(ctx, &[triangles(None, n.max(1) * 3)], flags)?;
                let estimate = BuildEstimate {
                    primitives: n as u64,
                    result_bytes: s.acceleration_structure,
                    build_scratch_bytes: s.build_scratch,
                    update_scratch_bytes: s.update_scratch,
                };
                lods.push(MeshLod {
                    estimate,
                    data_bytes: DATA_BYTES,
                });
            }
            catalog.insert(MeshId(id), lods)?;
            triangle_counts.insert(id, counts);
        }
        let aspect = o.width as f32 / o.height as f32;
        let path = CameraPath::flythrough(&scene, aspect);
        let eye0 = path.camera_at(0).position;
        let policy = LodPolicy::default();
        let (mut descs, mut scene_slots) = (Vec::new(), Vec::new());
        for (slot, inst) in scene.instances().iter().enumerate() {
            let lod = policy.lod(eye0, &inst.aabb);
            if triangle_counts[&inst.mesh].get(lod).is_none_or(|&n| n == 0) {
                continue; // nothing to build: not an instance for the TLAS
            }
            let mut desc = InstanceDesc::new(MeshId(inst.mesh), inst.transform, inst.aabb);
            desc.lod = lod as u32;
            desc.flags |= if inst.is_unique() {
                InstanceFlags::UNIQUE_BLAS
            } else {
                InstanceFlags::STATIC
            };
            descs.push(desc);
            scene_slots.push(slot as u32);
        }
        Ok(Self {
            rays_per_frame: f64::from(o.width * o.height) * 3.0,
            scene,
            grid,
            catalog,
            descs,
            path,
            scene_slots,
            shared: HashMap::new(),
            unique: HashMap::new(),
        })
    }

    /// A manager for this city around `lipac`'s unit cube and scratch
    /// alignment (the same for the Vulkan run and its CPU mirror).
    pub fn manager(&self, unit_cube: u64, scratch_alignment: u64) -> AnyResult<Manager> {
        let mut config = ManagerConfig::new(unit_cube);
        config.culling.latency_mitigation = None;
        config.culling.thresholds = Thresholds::for_rays_per_frame(self.rays_per_frame)?;
        config.culling.thresholds.n_a = 2;
        config.culling.command_capacity = (self.descs.len() as u32).max(1);
        config.scheduler = SchedulerConfig {
            scratch_alignment,
            lod_hysteresis_frames: 2,
            ..SchedulerConfig::default()
        };
        config.data.initial_capacity = 1 << 16;
        let mut manager = Manager::new(self.grid.clone(), config, self.catalog.clone())?;
        for d in &self.descs {
            manager.register(*d)?;
        }
        Ok(manager)
    }

    /// Uploads the vertex buffers the plan's builds and updates need (the
    /// engine's meshes; lipac reads them by device address).
    pub fn prepare(&mut self, ctx: &DeviceContext, plan: &ManagerPlan) -> AnyResult<()> {
        for owner in plan.blas.builds().map(|b| b.owner) {
            let (key, mesh) = match owner {
                BlasOwner::Shared(k) => {
                    if self.shared.contains_key(&(k.mesh.0, k.lod.0.into())) {
                        continue;
                    }
                    let lod = self.scene.library().lod(k.mesh.0, k.lod.0.into())?;
                    (Err((k.mesh.0, u32::from(k.lod.0))), lod.clone())
                }
                BlasOwner::Unique { instance, lod, .. } => {
                    if self.unique.contains_key(&instance.0) {
                        continue;
                    }
                    let mut m = lipac::sim::mesh::LodTriangles::default();
                    let slot = self.scene_slots[instance.0 as usize];
                    self.scene.unique_geometry(slot, lod.0.into(), 0, &mut m)?;
                    (Ok(instance.0), m)
                }
            };
            let p = positions(&mesh);
            let buffer = Buffer::with_data(ctx, BUILD_INPUT, MemoryLocation::CpuToGpu, &p)?;
            let g = triangles(Some(&buffer), p.len());
            match key {
                Ok(slot) => self.unique.insert(slot, (buffer, g)),
                Err(k) => self.shared.insert(k, (buffer, g)),
            };
        }
        Ok(())
    }

    /// The triangles of a BLAS (what `LipacVk::record_frame` builds).
    pub fn geometry(&self, owner: &BlasOwner) -> Option<Vec<TriangleGeometry>> {
        let g = match *owner {
            BlasOwner::Shared(k) => self.shared.get(&(k.mesh.0, k.lod.0.into())),
            BlasOwner::Unique { instance, .. } => self.unique.get(&instance.0),
        };
        g.map(|(_, g)| vec![*g])
    }
}

/// An instance's geometry data (the `InstanceDataSource`): a colour per mesh, varied per slot.
pub fn albedo(upload: &DataUpload, out: &mut [u8]) {
    let h = (upload.mesh.0.wrapping_mul(0x9E37_79B9) ^ upload.slot.wrapping_mul(31)) as u64;
    let c = |s: u64| 0.45 + 0.4 * ((h >> s) & 0xFF) as f32 / 255.0;
    let rgba = [c(0), c(8), c(16), 1.0f32];
    let bytes: Vec<u8> = rgba.iter().flat_map(|v| v.to_ne_bytes()).collect();
    let n = out.len().min(bytes.len());
    out[..n].copy_from_slice(&bytes[..n]);
}

pub fn view(camera: &FlyCamera, o: &Options, frame: u64) -> CameraView {
    let (right, up) = camera.basis();
    let th = (0.5 * camera.vfov).tan();
    CameraView {
        origin: camera.position.to_array(),
        forward: camera.forward().to_array(),
        right: (right * th * camera.aspect).to_array(),
        up: (up * th).to_array(),
        sun: Vec3::new(0.4, 0.8, 0.3).normalize().to_array(),
        t_max: 1.0e5,
        width: o.width,
        height: o.height,
        seed: frame as u32,
        shadows: true,
        bounce: true,
    }
}

/// What one run measured.
#[derive(Clone, Debug, Default)]
pub struct Summary {
    /// Frames whose read-back came back.
    pub frames_read_back: u64,
    /// Times lipac blocked the host during the frame loop (must be 0).
    pub lipac_waits: u64,
    /// Times the engine's frame pacing blocked (its command buffer of frame
    /// `f − in_flight` still running).
    pub pacing_waits: u64,
    /// BLAS builds recorded.
    pub builds: usize,
    /// Compactions recorded.
    pub compactions: usize,
    /// Largest TLAS record count read back.
    pub max_tlas_records: u32,
    /// Commands read back.
    pub commands: u64,
    /// Validation errors.
    pub validation_errors: Vec<String>,
    /// The tracing path the frames were traced with.
    pub tracing: Option<TracingPath>,
}

/// The run's settings and the per-frame table's header.
fn print_header(city: &City, o: &Options, headless: &HeadlessContext, path: TracingPath) {
    println!(
        "vk_city: {} instances, {} hitboxes, {}x{} px, {} frames, {} in flight, tracing with {}",
        city.descs.len(),
        city.grid.len(),
        o.width,
        o.height,
        o.frames,
        o.in_flight,
        path
    );
    println!("vk_city: device {}", headless.summary());
    println!(
        "frame | host waits lipac pacing | read back: frame TLAS-records boxes cmds \
         | builds compact freed | lipac device bytes"
    );
}

/// Writes the `width × height` RGBA8 `image` as an RGB PNG.
fn write_png(image: &Buffer, o: &Options, path: &str) -> AnyResult<()> {
    let px: Vec<u32> = image.read(0, (o.width * o.height) as usize)?;
    let rgb: Vec<u8> = px
        .iter()
        .flat_map(|p| p.to_le_bytes()[..3].to_vec())
        .collect();
    let file = std::io::BufWriter::new(std::fs::File::create(path)?);
    let mut encoder = png::Encoder::new(file, o.width, o.height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.write_header()?.write_image_data(&rgb)?;
    Ok(())
}

// ---- the integration ------------------------------------------------------

/// One frame's GPU work in the engine's command buffer: lipac's part
/// (growth, data and record uploads, BLAS batches, Algorithm 1, TLAS), the
/// engine's own pass (ray queries or a ray-tracing pipeline) counting
/// through lipac's include, then
/// Algorithm 2 and the read-back copies (`record_feedback` signals the
/// frame's timeline value, as submitted).
#[allow(clippy::too_many_arguments)]
pub fn record_frame(
    rec: &mut Recorder<'_>,
    lipac: &mut LipacVk,
    plan: &ManagerPlan,
    manager: &Manager,
    geometry: &dyn BlasGeometrySource,
    data: &dyn InstanceDataSource,
    tracer: &AnyCameraTracer,
    image: &Buffer,
    view: &CameraView,
) -> lipac::vk::Result<RecordedFrame> {
    let recorded = lipac.record_frame(rec, plan, manager, geometry, data)?;
    let (hits, data, offsets) = lipac.trace_targets()?;
    let bindings = tracer.bind(&CameraTraceBuffers {
        tlas: lipac.tlas(),
        instance_hits: hits,
        hitboxes: lipac.hitbox_records(),
        data,
        data_offsets: offsets,
        image,
        hitbox_bounds: lipac.hitbox_bounds(),
    })?;
    tracer.record(rec, &bindings, view, &lipac.merged_boxes())?;
    lipac.retire_after_frame(bindings); // destroyed once the GPU passed it
    lipac.record_feedback(rec)?;
    Ok(recorded)
}

/// Renders `o.frames` frames of the city on `headless`.
pub fn run(headless: &HeadlessContext, o: &Options) -> AnyResult<Summary> {
    let ctx = headless.context();
    let mut city = City::new(ctx, o)?;
    let config = LipacVkConfig {
        command_capacity: (city.descs.len() as u32).max(1),
        initial_slot_capacity: city.descs.len() as u32 + 1,
        readback_slots: o.in_flight + 2,
        pool_block_size: 8 << 20,
        ..LipacVkConfig::default()
    };
    let mut lipac = LipacVk::new(ctx, &city.grid, config)?;
    let mut manager = city.manager(lipac.unit_cube_address(), lipac.scratch_alignment())?;
    let merged_sbt = AdaptiveHitboxes::default().merged_box_sbt_offset;
    let tracer = AnyCameraTracer::new(ctx, lipac.counting(), merged_sbt, o.tracing)?;
    let pixels = u64::from(o.width * o.height);
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let image = Buffer::new(ctx, pixels * 4, storage, MemoryLocation::GpuToCpu)?;
    let mut submitter = FrameSubmitter::new(ctx, o.in_flight)?;
    let timeline = lipac.timeline().clone();
    let budgets = FrameBudgets::default();
    let mut s = Summary {
        tracing: Some(tracer.path()),
        ..Summary::default()
    };
    // Instances with a BLAS in each frame's records (the rest of its TLAS
    // records are counting boxes).
    let mut with_blas = HashMap::new();
    if o.print {
        print_header(&city, o, headless, tracer.path());
    }
    for f in 1..=u64::from(o.frames) {
        let waits_before = (ctx.host_waits(), submitter.blocking_waits());
        manager.begin_frame(f)?;
        // What the GPU finished, never waiting: acks, then commands and hits.
        let polled = lipac.poll()?;
        polled.deliver(&mut manager)?;
        let plan = manager.plan(&budgets)?;
        city.prepare(ctx, &plan)?;
        with_blas.insert(f, manager.stats().instances.with_blas as u32);

        let camera = city.path.camera_at(f as u32);
        let value = lipac.next_frame_value();
        let city_ref = &city;
        let geometry = |owner: &BlasOwner| city_ref.geometry(owner);
        let camera_view = view(&camera, o, f);
        let recorded = submitter.submit(&[], &[(&timeline, value)], |rec| {
            record_frame(
                rec,
                &mut lipac,
                &plan,
                &manager,
                &geometry,
                &albedo,
                &tracer,
                &image,
                &camera_view,
            )
        })?;
        let pacing = submitter.blocking_waits() - waits_before.1;
        let lipac_waits = ctx.host_waits() - waits_before.0 - pacing;
        s.lipac_waits += lipac_waits;
        s.pacing_waits += pacing;
        s.builds += recorded.blas.builds;
        s.compactions += recorded.blas.compactions;
        for r in &polled.readbacks {
            s.frames_read_back += 1;
            s.commands += u64::from(r.commands.counter());
            s.max_tlas_records = s.max_tlas_records.max(r.tlas_records);
        }
        if o.print {
            let back = polled.readbacks.last().map_or("-".to_string(), |r| {
                let boxes = r.tlas_records.saturating_sub(with_blas[&r.frame]);
                let cmds = r.commands.counter();
                format!("{:5} {:12} {boxes:5} {cmds:4}", r.frame, r.tlas_records)
            });
            println!(
                "{f:5} | {lipac_waits:16} {pacing:6} | {back:>30} | {:6} {:7} {:5} | {}",
                recorded.blas.builds,
                recorded.blas.compactions,
                recorded.blas.retired.len(),
                lipac.stats().device_bytes(),
            );
        }
    }
    // Shut-down (not a frame): let the GPU finish, take its last results
    // (the timeline's last value may become visible after the fences).
    submitter.wait_idle()?;
    let last = lipac.next_frame_value() - 1;
    let start = std::time::Instant::now();
    while timeline.value()? < last && start.elapsed().as_secs() < 10 {
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    let polled = lipac.poll()?;
    polled.deliver(&mut manager)?;
    s.frames_read_back += polled.readbacks.len() as u64;
    if let Some(out) = &o.out {
        write_png(&image, o, out)?;
    }
    if o.print {
        let st = lipac.stats();
        println!(
            "vk_city: {} frames read back, host waits: {} by lipac, {} pacing; {} builds, \
             {} compactions; {} live BLASes ({} B), lipac device memory {} B",
            s.frames_read_back,
            s.lipac_waits,
            s.pacing_waits,
            s.builds,
            s.compactions,
            st.executor.live_blases,
            st.executor.live_bytes,
            st.device_bytes()
        );
    }
    drop((lipac, tracer, image, submitter));
    s.validation_errors = headless.validation_errors();
    if o.validation == Validation::Required && !s.validation_errors.is_empty() {
        return Err(format!(
            "{} validation errors:\n{}",
            s.validation_errors.len(),
            s.validation_errors.join("\n")
        )
        .into());
    }
    Ok(s)
}
