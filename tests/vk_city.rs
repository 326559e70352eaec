//! vk_city on the Vulkan device (lavapipe in CI, `LIPAC_REQUIRE_VULKAN=1`):
//!
//! * the example's own loop with frames in flight: lipac never blocks the
//!   host, every frame's read-back comes back, BLASes are built and
//!   compacted, the validation layer reports nothing;
//! * the same scene through the Vulkan backend and the CPU backend (a
//!   second `Manager` running the CPU reference: `assemble`, the GPU's hit
//!   counts, `process_feedback`, `take_commands`), with frames in flight:
//!   the Vulkan manager never waits and ingests whatever read-backs have
//!   finished; the CPU backend runs each frame once the GPU's hit counts of
//!   that frame are back, handed the same acknowledgements and (its own)
//!   commands of the same frames. Their TLAS record multisets, command
//!   streams and plans are equal frame by frame, which holds because both
//!   reconcile against the commanded state, not the records' state bits.
//!
//! Both run on each tracing path the device has (ray queries:
//! `CameraTracer`; ray-tracing pipelines: `PipelineCameraTracer`). A custom
//! harness (libtest-mimic, as lipac-vk's device tests) probes the device
//! first and reports a test it cannot run as ignored, with the reason, and
//! never as passed; without a device they fail with
//! `LIPAC_REQUIRE_VULKAN=1`.

#[allow(dead_code)]
#[path = "../examples/vk_city.rs"]
mod vk_city;

use std::collections::BTreeMap;

use libtest_mimic::{Arguments, Trial};
use lipac::core::blas_cache::BlasOwner;
use lipac::core::build_plan::FramePlan;
use lipac::core::culling::{ProcessStats, Readback};
use lipac::core::layout::tlas_multiset;
use lipac::core::manager::{Ack, FrameBudgets, Manager, ManagerPlan};
use lipac::core::MeshId;
use lipac::vk::TracingPath;
use lipac::vk::{
    AnyCameraTracer, Buffer, FrameReadback, FrameSubmitter, HeadlessContext, LipacVk,
    LipacVkConfig, MemoryLocation, Validation,
};
use std::process::ExitCode;
use vk_city::{City, Options};

/// `LIPAC_REQUIRE_VULKAN=1` (CI): a device with the validation layer;
/// `=device` (a GPU machine without the layer): a device.
fn required() -> bool {
    std::env::var("LIPAC_REQUIRE_VULKAN").is_ok_and(|v| v == "1" || v == "device")
}

fn validation() -> Validation {
    if std::env::var("LIPAC_REQUIRE_VULKAN").is_ok_and(|v| v == "1") {
        Validation::Required
    } else {
        Validation::IfAvailable
    }
}

/// The device (the harness runs a test only after its probe found one).
fn headless() -> HeadlessContext {
    HeadlessContext::new(validation()).unwrap_or_else(|e| panic!("Vulkan device: {e}"))
}

fn main() -> ExitCode {
    let args = Arguments::from_args();
    let probe = HeadlessContext::new(validation());
    let device = match &probe {
        Ok(h) => h.summary(),
        Err(e) => format!("none ({e})"),
    };
    if !args.list {
        println!("vk_city tests on: {device}");
    }
    if required() && probe.is_err() {
        eprintln!("LIPAC_REQUIRE_VULKAN is set but there is no suitable Vulkan device: {device}");
        return ExitCode::FAILURE;
    }
    type Test = (&'static str, fn(TracingPath));
    let tests: [Test; 2] = [
        (
            "vk_city_keeps_frames_in_flight_without_lipac_waits",
            vk_city_keeps_frames_in_flight_without_lipac_waits,
        ),
        (
            "vulkan_backend_equals_cpu_backend_frame_by_frame",
            vulkan_backend_equals_cpu_backend_frame_by_frame,
        ),
    ];
    let mut skipped = Vec::new();
    let mut trials = Vec::new();
    for (name, run) in tests {
        for path in [TracingPath::RayQuery, TracingPath::RayTracingPipeline] {
            let full = format!("{name}::{}", path.name().replace('-', "_"));
            let why = match &probe {
                Err(e) => Some(format!("no suitable Vulkan device: {e}")),
                Ok(h) => h
                    .context()
                    .tracing()
                    .require(path, "this test")
                    .err()
                    .map(|e| e.to_string()),
            };
            let trial = Trial::test(full.clone(), move || {
                run(path);
                Ok(())
            });
            trials.push(match why {
                Some(why) => {
                    skipped.push((full, why));
                    trial.with_ignored_flag(true)
                }
                None => trial,
            });
        }
    }
    drop(probe);
    let conclusion = libtest_mimic::run(&args, trials);
    if !args.list {
        println!(
            "vk_city tests: {} ran ({} failed), {} not run, on {device}",
            conclusion.num_passed + conclusion.num_failed,
            conclusion.num_failed,
            conclusion.num_ignored
        );
        if conclusion.num_ignored > 0 && !args.ignored && !args.include_ignored {
            for (name, why) in &skipped {
                println!("  not run: {name}: {why}");
            }
        }
    }
    conclusion.exit_code()
}

fn small(frames: u32) -> Options {
    Options {
        instances: 1200,
        frames,
        width: 64,
        height: 48,
        in_flight: 2,
        out: None,
        validation: Validation::IfAvailable,
        print: false,
        tracing: None,
    }
}

fn vk_city_keeps_frames_in_flight_without_lipac_waits(path: TracingPath) {
    let h = headless();
    let o = Options {
        tracing: Some(path),
        ..small(10)
    };
    let s = vk_city::run(&h, &o).unwrap();
    assert_eq!(s.tracing, Some(path));
    assert_eq!(s.lipac_waits, 0, "lipac blocked the host");
    assert_eq!(
        s.frames_read_back,
        u64::from(o.frames),
        "every frame read back"
    );
    assert!(s.builds > 0 && s.compactions > 0, "{s:?}");
    assert!(s.commands > 0 && s.max_tlas_records > 0, "{s:?}");
    assert!(s.validation_errors.is_empty(), "{:?}", s.validation_errors);
}

/// A plan's data uploads without the handles (they name their manager).
fn data(p: &ManagerPlan) -> Vec<(u32, MeshId, u32, u64, u64)> {
    let d = p.data_uploads.iter();
    d.map(|u| (u.slot, u.mesh, u.lod, u.offset, u.bytes))
        .collect()
}

/// What the Vulkan manager was handed and planned in one frame.
struct FrameLog {
    acks: Vec<Ack>,
    /// The frames whose read-backs it ingested, in order.
    ingested: Vec<u64>,
    commands: ProcessStats,
    blas: FramePlan,
    data: Vec<(u32, MeshId, u32, u64, u64)>,
}

/// The CPU backend, one frame behind the GPU's results: it runs frame `g`
/// once the GPU's read-back of `g` is back, with the acknowledgements the
/// Vulkan manager got in `g` and its own commands of the frames whose
/// read-backs the Vulkan manager ingested in `g`.
struct CpuReplay {
    manager: Manager,
    next: u64,
    commands: BTreeMap<u64, Readback>,
    cube: u64,
    /// (command words, TLAS records with their own BLAS).
    totals: (usize, usize),
}

impl CpuReplay {
    fn replay(
        &mut self,
        log: &BTreeMap<u64, FrameLog>,
        arrived: &mut BTreeMap<u64, FrameReadback>,
    ) {
        while let (Some(l), Some(r)) = (log.get(&self.next), arrived.remove(&self.next)) {
            let (g, cpu) = (self.next, &mut self.manager);
            cpu.begin_frame(g).unwrap();
            for &ack in &l.acks {
                cpu.handle_ack(ack).unwrap();
            }
            for frame in &l.ingested {
                let c = self.commands.remove(frame).expect("ran before");
                // Build priorities follow: the hits of that frame, as the
                // Vulkan manager's `record_hits` of the same read-back.
                cpu.ingest_readback(c.frame, c.counter, &c.words);
            }
            let plan = cpu.plan(&FrameBudgets::default()).unwrap();
            assert_eq!(l.commands, plan.commands, "frame {g}: commands processed");
            assert_eq!(l.blas, plan.blas, "frame {g}: BLAS plans");
            assert!(l.data == data(&plan), "frame {g}: data uploads");
            assert_eq!(r.frame, g);
            let diag = r.diagnostics.as_ref().expect("diagnostics enabled");

            // CPU backend, Algorithm 1: the same TLAS records (as a multiset).
            let mut tlas = Vec::new();
            cpu.assemble(&mut tlas).unwrap();
            assert_eq!(tlas.len() as u32, r.tlas_records, "frame {g}: TLAS records");
            assert!(
                tlas_multiset(&tlas) == tlas_multiset(&diag.tlas_instances),
                "frame {g}: TLAS record multisets differ"
            );
            self.totals.1 += tlas
                .iter()
                .filter(|t| t.acceleration_structure_reference != self.cube)
                .count();

            // The GPU's hit counts, then Algorithm 2: the same commands.
            let slots = r.instance_hits.len().min(cpu.instance_hits_mut().len());
            cpu.instance_hits_mut()[..slots].copy_from_slice(&r.instance_hits[..slots]);
            for (c, h) in cpu.hitboxes_mut().iter_mut().zip(&diag.hitboxes) {
                c.add_hits(h.hits());
            }
            cpu.process_feedback().unwrap();
            let commands = cpu.take_commands().expect("feedback ran");
            assert_eq!(commands.counter, r.commands.counter(), "frame {g}");
            let (mut a, mut b) = (commands.words.clone(), r.commands.words().to_vec());
            a.sort_unstable();
            b.sort_unstable();
            assert_eq!(a, b, "frame {g}: command words");
            self.totals.0 += a.len();
            self.commands.insert(g, commands);
            self.next += 1;
        }
    }
}

fn vulkan_backend_equals_cpu_backend_frame_by_frame(path: TracingPath) {
    let h = headless();
    let ctx = h.context();
    let o = small(10);
    let mut city = City::new(ctx, &o).unwrap();
    let n = city.descs.len() as u32;
    let config = LipacVkConfig {
        command_capacity: n,
        initial_slot_capacity: n,
        // In flight + 2, as the example: with 2 in flight and 3 slots, a
        // frame's fence can signal before its timeline value is visible to
        // the next poll, and record_feedback then finds its slot unread
        // (ReadbackSlotBusy; about 1 run in 10 on a loaded machine).
        readback_slots: 4,
        pool_block_size: 4 << 20,
        read_back_diagnostics: true,
        ..LipacVkConfig::default()
    };
    let mut lipac = LipacVk::new(ctx, &city.grid, config).unwrap();
    let (cube, align) = (lipac.unit_cube_address(), lipac.scratch_alignment());
    let mut gpu = city.manager(cube, align).unwrap();
    let cpu = city.manager(cube, align).unwrap();
    let merged_sbt = lipac::core::hitbox_tree::AdaptiveHitboxes::default().merged_box_sbt_offset;
    let tracer = AnyCameraTracer::new(ctx, lipac.counting(), merged_sbt, Some(path)).unwrap();
    assert_eq!(tracer.path(), path);
    let pixels = u64::from(o.width * o.height);
    let image = Buffer::new(
        ctx,
        pixels * 4,
        ash::vk::BufferUsageFlags::STORAGE_BUFFER,
        MemoryLocation::GpuOnly,
    )
    .unwrap();
    let mut submitter = FrameSubmitter::new(ctx, 2).unwrap();
    let timeline = lipac.timeline().clone();
    let budgets = FrameBudgets::default();
    // What the Vulkan manager saw and decided per frame, for the CPU
    // backend's replay of that frame.
    let mut log: BTreeMap<u64, FrameLog> = BTreeMap::new();
    // The GPU's read-backs by frame, until the CPU replays that frame.
    let mut arrived: BTreeMap<u64, FrameReadback> = BTreeMap::new();
    let mut cpu = CpuReplay {
        manager: cpu,
        next: 1,
        commands: BTreeMap::new(),
        cube,
        totals: (0, 0),
    };
    let (mut builds, mut max_latency) = (0, 0);
    for f in 1..=u64::from(o.frames) {
        // Frames in flight, as the example runs: never wait for the GPU;
        // hand the Vulkan manager whatever has finished.
        gpu.begin_frame(f).unwrap();
        let polled = lipac.poll().unwrap();
        polled.deliver(&mut gpu).unwrap();
        let plan = gpu.plan(&budgets).unwrap();
        log.insert(
            f,
            FrameLog {
                acks: polled.acks.clone(),
                ingested: polled.readbacks.iter().map(|r| r.frame).collect(),
                commands: plan.commands,
                blas: plan.blas.clone(),
                data: data(&plan),
            },
        );
        for r in polled.readbacks {
            max_latency = max_latency.max(f - r.frame);
            arrived.insert(r.frame, r);
        }
        // The CPU backend runs each frame once the GPU's results of that
        // frame (its hit counts) are back.
        cpu.replay(&log, &mut arrived);
        builds += plan.blas.builds().count();
        city.prepare(ctx, &plan).unwrap();
        let value = lipac.next_frame_value();
        let camera = city.path.camera_at(f as u32);
        let city_ref = &city;
        let geometry = |owner: &BlasOwner| city_ref.geometry(owner);
        let view = vk_city::view(&camera, &o, f);
        submitter
            .submit(&[], &[(&timeline, value)], |rec| {
                let (lipac, data) = (&mut lipac, &vk_city::albedo);
                vk_city::record_frame(
                    rec, lipac, &plan, &gpu, &geometry, data, &tracer, &image, &view,
                )
            })
            .unwrap();
    }
    // Shut-down: the GPU's last results, then the CPU's last frames.
    submitter.wait_idle().unwrap();
    let last = lipac.next_frame_value() - 1;
    let start = std::time::Instant::now();
    while timeline.value().unwrap() < last {
        assert!(start.elapsed().as_secs() < 10, "timeline stuck");
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    for r in lipac.poll().unwrap().readbacks {
        arrived.insert(r.frame, r);
    }
    cpu.replay(&log, &mut arrived);
    assert_eq!(cpu.next, u64::from(o.frames) + 1, "every frame replayed");
    assert!(max_latency >= 1, "read-backs come frames later");
    eprintln!("largest read-back latency: {max_latency} frames");
    let (commands, active_records) = cpu.totals;
    // The run exercised the loop: commands came back, BLASes were built and
    // instances went into the TLAS with their own BLAS.
    assert!(builds > 0 && commands > 0 && active_records > 0);
    drop((lipac, tracer, image, submitter));
    let errors = h.validation_errors();
    assert!(errors.is_empty(), "{errors:?}");
}
