//! vk_city on the Vulkan device (lavapipe in CI, `LIPAC_REQUIRE_VULKAN=1`):
//!
//! * the example's own loop with frames in flight: lipac never blocks the
//!   host, every frame's read-back comes back, BLASes are built and
//!   compacted, the validation layer reports nothing;
//! * the same scene through the Vulkan backend and the CPU backend (a
//!   second `Manager` running the CPU reference: `assemble`, the GPU's hit
//!   counts, `process_feedback`, `take_commands`): their TLAS record
//!   multisets, command streams and plans are equal frame by frame.
//!
//! Without a ray-query device both skip (and fail with
//! `LIPAC_REQUIRE_VULKAN=1`).

#[allow(dead_code)]
#[path = "../examples/vk_city.rs"]
mod vk_city;

use lipac::core::blas_cache::BlasOwner;
use lipac::core::layout::TlasInstance;
use lipac::core::manager::FrameBudgets;
use lipac::vk::{
    Buffer, CameraTraceBuffers, CameraTracer, FrameSubmitter, HeadlessContext, LipacVk,
    LipacVkConfig, MemoryLocation, Polled, Validation,
};
use vk_city::{City, Options};

fn headless() -> Option<HeadlessContext> {
    let required = std::env::var("LIPAC_REQUIRE_VULKAN").is_ok_and(|v| v == "1");
    let validation = if required {
        Validation::Required
    } else {
        Validation::IfAvailable
    };
    match HeadlessContext::new(validation) {
        Ok(h) => Some(h),
        Err(e) if e.is_unsupported_machine() && !required => {
            eprintln!("skipped: no Vulkan ray-query device: {e}");
            None
        }
        Err(e) => panic!("Vulkan device: {e}"),
    }
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
    }
}

#[test]
fn vk_city_keeps_frames_in_flight_without_lipac_waits() {
    let Some(h) = headless() else {
        return;
    };
    let o = small(10);
    let s = vk_city::run(&h, &o).unwrap();
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

/// The records as sorted bit patterns (a multiset, bit-exact floats).
fn bits(records: &[TlasInstance]) -> Vec<([u32; 12], u32, u32, u64)> {
    let mut v: Vec<_> = records
        .iter()
        .map(|r| {
            (
                r.transform.map(f32::to_bits),
                r.custom_index_and_mask,
                r.sbt_offset_and_flags,
                r.acceleration_structure_reference,
            )
        })
        .collect();
    v.sort_unstable();
    v
}

#[test]
fn vulkan_backend_equals_cpu_backend_frame_by_frame() {
    let Some(h) = headless() else {
        return;
    };
    let ctx = h.context();
    let o = small(10);
    let mut city = City::new(ctx, &o).unwrap();
    let n = city.descs.len() as u32;
    let config = LipacVkConfig {
        command_capacity: n,
        initial_slot_capacity: n,
        readback_slots: 3,
        pool_block_size: 4 << 20,
        read_back_diagnostics: true,
        ..LipacVkConfig::default()
    };
    let mut lipac = LipacVk::new(ctx, &city.grid, config).unwrap();
    let (cube, align) = (lipac.unit_cube_address(), lipac.scratch_alignment());
    let mut gpu = city.manager(cube, align).unwrap();
    let mut cpu = city.manager(cube, align).unwrap();
    let tracer = CameraTracer::new(ctx, lipac.counting()).unwrap();
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
    let mut last: Option<(Polled, lipac::core::culling::Readback)> = None;
    let (mut builds, mut commands, mut active_records) = (0, 0, 0);
    for f in 1..=u64::from(o.frames) {
        gpu.begin_frame(f).unwrap();
        cpu.begin_frame(f).unwrap();
        // Frame f − 1's results: the GPU's to the Vulkan manager, the CPU
        // reference's commands to the CPU one; the same acknowledgements.
        if let Some((polled, cpu_commands)) = last.take() {
            polled.deliver(&mut gpu).unwrap();
            for &ack in &polled.acks {
                cpu.handle_ack(ack).unwrap();
            }
            cpu.ingest_readback(
                cpu_commands.frame,
                cpu_commands.counter,
                &cpu_commands.words,
            );
        }
        let plan = gpu.plan(&budgets).unwrap();
        let cpu_plan = cpu.plan(&budgets).unwrap();
        assert_eq!(
            plan.commands, cpu_plan.commands,
            "frame {f}: commands processed"
        );
        assert_eq!(plan.blas, cpu_plan.blas, "frame {f}: BLAS plans");
        // (Handles name their manager, so compare the rest.)
        let data = |p: &lipac::core::manager::ManagerPlan| -> Vec<_> {
            let d = p.data_uploads.iter();
            d.map(|u| (u.slot, u.mesh, u.lod, u.offset, u.bytes))
                .collect()
        };
        assert!(data(&plan) == data(&cpu_plan), "frame {f}: data uploads");
        builds += plan.blas.builds().count();
        city.prepare(ctx, &plan).unwrap();
        let value = lipac.next_frame_value();
        let camera = city.path.camera_at(f as u32);
        let city_ref = &city;
        let geometry = |owner: &BlasOwner| city_ref.geometry(owner);
        submitter
            .submit(&[], &[(&timeline, value)], |rec| {
                lipac.record_frame(rec, &plan, &gpu, &geometry, &vk_city::albedo)?;
                let (hits, data, offsets) = lipac.trace_targets()?;
                let bindings = tracer.bind(&CameraTraceBuffers {
                    tlas: lipac.tlas(),
                    instance_hits: hits,
                    hitboxes: lipac.hitbox_records(),
                    data,
                    data_offsets: offsets,
                    image: &image,
                })?;
                tracer.record(rec, &bindings, &vk_city::view(&camera, &o, f))?;
                lipac.retire_after_frame(bindings);
                lipac.record_feedback(rec)
            })
            .unwrap();
        // The test (not the backend) waits, so that frame f's GPU results
        // reach the CPU reference before its frame f feedback.
        submitter.wait_idle().unwrap();
        // (The fence may signal before the timeline value is visible.)
        let start = std::time::Instant::now();
        while timeline.value().unwrap() < value {
            assert!(start.elapsed().as_secs() < 10, "frame {f}: timeline stuck");
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        let polled = lipac.poll().unwrap();
        assert_eq!(polled.readbacks.len(), 1, "frame {f}");
        let r = &polled.readbacks[0];
        assert_eq!(r.frame, f);
        let diag = r.diagnostics.as_ref().expect("diagnostics enabled");

        // CPU backend, Algorithm 1: the same TLAS records (as a multiset).
        let mut tlas = Vec::new();
        cpu.assemble(&mut tlas).unwrap();
        assert_eq!(tlas.len() as u32, r.tlas_records, "frame {f}: TLAS records");
        assert!(
            bits(&tlas) == bits(&diag.tlas_instances),
            "frame {f}: TLAS record multisets differ"
        );
        active_records += tlas
            .iter()
            .filter(|t| t.acceleration_structure_reference != cube)
            .count();

        // The GPU's hit counts, then Algorithm 2: the same commands.
        let slots = r.instance_hits.len().min(cpu.instance_hits_mut().len());
        cpu.instance_hits_mut()[..slots].copy_from_slice(&r.instance_hits[..slots]);
        for (c, g) in cpu.hitboxes_mut().iter_mut().zip(&diag.hitboxes) {
            c.add_hits(g.hits());
        }
        cpu.process_feedback().unwrap();
        let cpu_commands = cpu.take_commands().expect("feedback ran");
        assert_eq!(cpu_commands.counter, r.commands.counter(), "frame {f}");
        let (mut a, mut b) = (cpu_commands.words.clone(), r.commands.words().to_vec());
        a.sort_unstable();
        b.sort_unstable();
        assert_eq!(a, b, "frame {f}: command words");
        commands += a.len();
        last = Some((polled, cpu_commands));
    }
    // The run exercised the loop: commands came back, BLASes were built and
    // instances went into the TLAS with their own BLAS.
    assert!(builds > 0 && commands > 0 && active_records > 0);
    drop((lipac, tracer, image, submitter));
    let errors = h.validation_errors();
    assert!(errors.is_empty(), "{errors:?}");
}
