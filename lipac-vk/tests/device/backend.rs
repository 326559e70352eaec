//! `LipacVk` on a device, driven by a `Manager`: the per-slot tables and the
//! geometry-data buffer grow while frames are recorded (old contents kept,
//! new records uploaded), GPU Algorithm 1's TLAS records equal the
//! manager's CPU assembly every frame, the data ranges and per-slot offsets
//! on the GPU are what the manager planned, and recording the end of a frame
//! that was never begun is an error.

use crate::common::*;
use ash::vk;
use glam::{Affine3A, Vec3};
use lipac_core::blas_cache::BlasOwner;
use lipac_core::build_plan::SchedulerConfig;
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::instance::{InstanceDesc, MeshId};
use lipac_core::latency::{ActivationHeuristic, Frustum};
use lipac_core::layout::tlas_multiset;
use lipac_core::manager::{DataUpload, FrameBudgets, Manager, ManagerConfig};
use lipac_core::math::Aabb;
use lipac_core::registry::InstanceHandle;
use lipac_vk::{
    Buffer, FrameSubmitter, LipacVk, LipacVkConfig, MemoryLocation, OneShot, Polled,
    TriangleGeometry, VkError,
};

const DATA_BYTES: u64 = 24;

fn pattern(slot: u32) -> Vec<u8> {
    (0..DATA_BYTES as u32)
        .map(|i| (slot * 7 + i) as u8)
        .collect()
}

fn desc(i: u32) -> InstanceDesc {
    let at = Vec3::new(4.0 + 9.0 * i as f32, 1.0, 6.0 + 5.0 * (i % 3) as f32);
    InstanceDesc::new(
        MeshId(1),
        Affine3A::from_translation(at),
        Aabb::new(at - Vec3::splat(1.0), at + Vec3::splat(1.0)),
    )
}

pub fn tables_and_data_grow_and_assembly_matches_the_manager() {
    grow_and_match(
        "tables_and_data_grow_and_assembly_matches_the_manager",
        false,
    );
}

/// The same frames with a warm start at frame 1 (`Manager::warm_start`):
/// its state and hitbox overrides reach the GPU's records, so GPU
/// Algorithm 1 equals the manager's assembly with the instances active,
/// and from frame 2 on (their BLASes built) they are geometry records.
pub fn a_warm_start_reaches_the_gpu_records() {
    grow_and_match("a_warm_start_reaches_the_gpu_records", true);
}

fn grow_and_match(name: &str, warm: bool) {
    let h = headless(name);
    let ctx = h.context();
    let (mesh, catalog) = crate::common::one_mesh_catalog(&h, DATA_BYTES);
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [64.0, 64.0],
        cell_size: 16.0,
    })
    .unwrap();
    let config = LipacVkConfig {
        initial_slot_capacity: 2,
        readback_slots: 3,
        command_capacity: 64,
        pool_block_size: 1 << 20,
        read_back_diagnostics: true,
        ..LipacVkConfig::default()
    };
    let mut lipac = LipacVk::new(ctx, &grid, config).unwrap();
    let mut mc = ManagerConfig::new(lipac.unit_cube_address());
    mc.culling.latency_mitigation = None;
    mc.culling.command_capacity = 64;
    mc.scheduler = SchedulerConfig {
        scratch_alignment: lipac.scratch_alignment(),
        ..SchedulerConfig::default()
    };
    mc.data.initial_capacity = 32;
    let mut manager = Manager::new(grid, mc, catalog).unwrap();
    let mut handles: Vec<InstanceHandle> =
        (0..2).map(|i| manager.register(desc(i)).unwrap()).collect();

    let geometry = |_: &BlasOwner| -> Option<Vec<TriangleGeometry>> { Some(vec![mesh.geometry()]) };
    let data = |u: &DataUpload, out: &mut [u8]| out.copy_from_slice(&pattern(u.slot));
    let mut submitter = FrameSubmitter::new(ctx, 2).unwrap();
    let timeline = lipac.timeline().clone();
    let mut last: Option<Polled> = None;
    let (mut table_growths, mut data_growths) = (Vec::new(), Vec::new());
    for f in 1..=6u64 {
        if f == 3 {
            // More instances than the tables and the data buffer hold.
            handles.extend((2..7).map(|i| manager.register(desc(i)).unwrap()));
        }
        manager.begin_frame(f).unwrap();
        if warm && f == 1 {
            // Above the 64 m world, looking down at all of it.
            let eye = Vec3::new(32.0, 80.0, 32.0);
            let view = glam::camera::rh::view::look_to_mat4(eye, Vec3::NEG_Y, Vec3::NEG_Z);
            let proj =
                glam::camera::rh::proj::vulkan::perspective(100f32.to_radians(), 1.0, 0.1, 500.0);
            let frustum = Frustum::from_view_projection(proj * view).unwrap();
            let all = ActivationHeuristic {
                max_distance: f32::INFINITY,
                min_projected_size: 0.0,
                surround_radius: 0.0,
            };
            let out = manager.warm_start(eye, &frustum, all).unwrap();
            assert_eq!(out.requests.len(), 2, "both instances in view");
        }
        if let Some(p) = last.take() {
            p.deliver(&mut manager).unwrap();
        }
        let plan = manager.plan(&FrameBudgets::default()).unwrap();
        let value = lipac.next_frame_value();
        let recorded = submitter
            .submit(&[], &[(&timeline, value)], |rec| {
                let r = lipac.record_frame(rec, &plan, &manager, &geometry, &data)?;
                let signal = lipac.record_feedback(rec)?;
                assert_eq!(signal.value, value);
                Ok(r)
            })
            .unwrap();
        assert_eq!(recorded.value, value);
        assert_eq!(recorded.data_uploads, plan.data_uploads.len());
        if recorded.slot_tables_grew {
            table_growths.push(f);
        }
        if recorded.data_grew {
            data_growths.push(f);
        }
        submitter.wait_idle().unwrap();
        while timeline.value().unwrap() < value {
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        let polled = lipac.poll().unwrap();
        assert_eq!(polled.readbacks.len(), 1, "frame {f}");
        let r = &polled.readbacks[0];
        assert_eq!((r.frame, r.instance_hits.len()), (f, handles.len()));
        let mut cpu = Vec::new();
        manager.assemble(&mut cpu).unwrap();
        let diag = r.diagnostics.as_ref().unwrap();
        assert_eq!(r.tlas_records as usize, cpu.len(), "frame {f}");
        if warm && f == 1 {
            // Both instances active without their BLASes yet, their
            // hitboxes active: nothing to emit, on the GPU too.
            assert!(cpu.is_empty(), "{cpu:?}");
        } else {
            assert!(!cpu.is_empty(), "hitbox boxes over the inactive instances");
        }
        assert!(
            tlas_multiset(&cpu) == tlas_multiset(&diag.tlas_instances),
            "frame {f}"
        );
        if warm && f >= 2 {
            let unit_cube = lipac.unit_cube_address();
            let geometry = cpu
                .iter()
                .filter(|r| r.acceleration_structure_reference != unit_cube)
                .count();
            assert!(geometry >= 2, "frame {f}: {geometry} geometry records");
        }
        last = Some(polled);
    }
    assert_eq!(table_growths, [3], "2 slots, then 7");
    assert_eq!(data_growths, [3], "the data buffer grew with the manager's");
    assert!(lipac.stats().slot_capacity >= 7);

    // The data ranges and offsets on the GPU are the manager's.
    let (_, gpu_data, gpu_offsets) = lipac.trace_targets().unwrap();
    let dst = |size| {
        Buffer::new(
            ctx,
            size,
            vk::BufferUsageFlags::TRANSFER_DST,
            MemoryLocation::GpuToCpu,
        )
        .unwrap()
    };
    let (data_copy, offsets_copy) = (dst(gpu_data.size()), dst(gpu_offsets.size()));
    OneShot::new(ctx)
        .unwrap()
        .run(|rec| {
            for (src, dst) in [(gpu_data, &data_copy), (gpu_offsets, &offsets_copy)] {
                let region = [vk::BufferCopy::default().size(src.size())];
                // SAFETY: recording on this device; both buffers are live, of
                // equal size, with TRANSFER_SRC / TRANSFER_DST usage.
                unsafe {
                    ctx.device()
                        .cmd_copy_buffer(rec.raw(), src.raw(), dst.raw(), &region)
                };
            }
            Ok(())
        })
        .unwrap();
    let bytes: Vec<u8> = data_copy.read(0, data_copy.size() as usize).unwrap();
    let offsets: Vec<u32> = offsets_copy.read(0, handles.len()).unwrap();
    for &handle in &handles {
        let view = manager.instance(handle).unwrap();
        assert_eq!(u64::from(offsets[view.slot as usize]), view.data.start);
        let range = view.data.start as usize..view.data.end as usize;
        assert_eq!(bytes[range], pattern(view.slot)[..], "slot {}", view.slot);
    }

    // Misuse: the end of a frame that was never begun.
    let mut one = OneShot::new(ctx).unwrap();
    assert!(matches!(
        one.run(|rec| lipac.record_feedback(rec)),
        Err(VkError::InvalidArgument(_))
    ));
    drop((submitter, lipac));
    assert_no_validation_errors(&h);
}
