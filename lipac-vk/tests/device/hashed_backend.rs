//! `LipacVk` driven by a `Manager<HashedHitboxes>` (the sparse hitbox index
//! of unbounded worlds) equals the CPU backend frame by frame: cells are
//! occupied, emptied, evicted and their indices reused (with the hitbox
//! count unchanged, too), and the index grows three times (from an empty first frame), so the hitbox
//! records and bounds grow on the GPU and the bounds of new and reused
//! indices are rewritten. A second `Manager<HashedHitboxes>` runs the CPU
//! reference (`assemble`, the GPU's hit counts, `process_feedback`,
//! `take_commands`) with the same acknowledgements and its own commands;
//! their TLAS record multisets, command streams, plans and escape-fraction
//! sums (summed on the GPU, read back in the ring slot, handed over by
//! `Polled::deliver`) are equal every frame, under a random camera per
//! frame. Every frame the GPU's whole hitbox table is read back: each
//! record's extent (heights, cost word) is the Vulkan manager's, uploaded
//! (evicted and reused indices included), and every spare record past the
//! index (first frame, growth) is `HitboxRecord::default()` bit for bit; in one run both also warm-start, held, at some frames (the
//! rate floors uploaded to the GPU). Serial frames (each waited for): the frames-in-flight loop is
//! `tests/vk_city.rs`'s.

use crate::common::*;
use ash::vk;
use glam::Vec3;
use lipac_core::blas_cache::BlasOwner;
use lipac_core::build_plan::SchedulerConfig;
use lipac_core::hashed_hitboxes::{HashedConfig, HashedHitboxes};
use lipac_core::hitbox_extents::HitboxExtent;
use lipac_core::hitbox_index::HitboxIndex;
use lipac_core::instance::{InstanceDesc, MeshId};
use lipac_core::latency::{ActivationHeuristic, Frustum};
use lipac_core::layout::{tlas_multiset, HitboxRecord};
use lipac_core::manager::{DataUpload, FrameBudgets, Manager, ManagerConfig, MeshCatalog};
use lipac_core::registry::InstanceHandle;
use lipac_core::thresholds::{DecayedRule, DecisionRule, Thresholds, RATE_ONE};
use lipac_test_support::{Rng64, SplitMix64};
use lipac_vk::{
    AnyCameraTracer, Buffer, CameraTraceBuffers, CameraView, FrameSubmitter, HeadlessContext,
    LipacVk, LipacVkConfig, MemoryLocation, Polled, TriangleGeometry,
};

const FRAMES: u64 = 22;
const CELL: f32 = 16.0;
const DATA_BYTES: u64 = 16;

/// A tile at a random spot of the cells `cx0..cx1` x `cz0..cz1`.
fn random_desc(rng: &mut SplitMix64, cx: (u32, u32), cz: (u32, u32)) -> InstanceDesc {
    let pick = |rng: &mut SplitMix64, (a, b): (u32, u32)| {
        let c = a + rng.below(u64::from(b - a)) as u32;
        c as f32 * CELL + 4.0 + 8.0 * rng.unit_f64() as f32
    };
    let x = pick(rng, cx);
    let z = pick(rng, cz);
    let (t, aabb) = tile(x, 0.5 + 2.0 * rng.unit_f64() as f32, z);
    InstanceDesc::new(MeshId(1), t, aabb)
}

/// One manager's side of the scene: the same script runs on both.
struct Scene {
    rng: SplitMix64,
    handles: Vec<(InstanceHandle, InstanceDesc)>,
}

impl Scene {
    fn new() -> Self {
        Self {
            rng: SplitMix64::new(0x5EED),
            handles: Vec::new(),
        }
    }

    fn add(&mut self, m: &mut Manager<HashedHitboxes>, n: u32, cx: (u32, u32), cz: (u32, u32)) {
        for _ in 0..n {
            let d = random_desc(&mut self.rng, cx, cz);
            self.handles.push((m.register(d).unwrap(), d));
        }
    }

    /// Removes every instance whose centre lies in cells `cx < below`.
    fn clear_columns(&mut self, m: &mut Manager<HashedHitboxes>, below: u32) {
        let limit = below as f32 * CELL;
        self.handles.retain(|(h, d)| {
            let keep = d.aabb.center().x >= limit;
            if !keep {
                m.remove(*h).unwrap();
            }
            keep
        });
    }

    /// The changes before frame `f`.
    fn script(&mut self, f: u64, m: &mut Manager<HashedHitboxes>) {
        match f {
            // Frame 1 has no instance and no hitbox.
            2 => self.add(m, 24, (0, 4), (0, 4)),
            4 => self.add(m, 30, (4, 8), (0, 4)),
            6 => self.clear_columns(m, 2),
            7 => {
                // Moves across cells (vacate + occupy), every third instance.
                for (i, (h, d)) in self.handles.iter_mut().enumerate() {
                    if i % 3 == 0 {
                        let c = d.aabb.center();
                        let (t, aabb) = tile(c.x, c.y, c.z + CELL);
                        m.set_transform(*h, t, aabb).unwrap();
                        d.aabb = aabb;
                    }
                }
            }
            // Evicted cells' indices reused, and growth past twice the capacity.
            10 => self.add(m, 60, (0, 8), (4, 9)),
            12 => self.clear_columns(m, 3),
            // New cells at an unchanged hitbox count (freed indices reused).
            16 => self.add(m, 3, (0, 1), (0, 2)),
            _ => {}
        }
    }
}

/// A random camera above the scene looking into it.
fn random_view(rng: &mut SplitMix64, f: u64) -> CameraView {
    let origin = Vec3::new(
        40.0 + 50.0 * rng.unit_f64() as f32,
        45.0 + 30.0 * rng.unit_f64() as f32,
        -30.0 + 20.0 * rng.unit_f64() as f32,
    );
    let target = Vec3::new(
        30.0 + 70.0 * rng.unit_f64() as f32,
        0.0,
        30.0 + 80.0 * rng.unit_f64() as f32,
    );
    let forward = (target - origin).normalize();
    let right = forward.cross(Vec3::Y).normalize();
    let up = right.cross(forward);
    let th = 0.6f32;
    let (width, height) = (48, 32);
    CameraView {
        origin: origin.to_array(),
        forward: forward.to_array(),
        right: (right * th * width as f32 / height as f32).to_array(),
        up: (up * th).to_array(),
        sun: Vec3::new(0.4, 0.8, 0.3).normalize().to_array(),
        t_max: 1.0e4,
        width,
        height,
        seed: f as u32,
        shadows: true,
        bounce: true,
    }
}

/// The paper's rule at this scene's scale (about 1.5k rays per frame).
fn paper() -> Thresholds {
    Thresholds {
        theta_a: 12,
        theta_d: 3,
        sigma_a: 6,
        sigma_o: 2,
        n_a: 2,
        n_d: 3,
        ..Thresholds::paper()
    }
}

/// The decayed rule at this scene's scale (its rates carry over frames, so
/// evicted hitboxes must be reset on the GPU as on the CPU).
fn decayed() -> Thresholds {
    paper().with_rule(DecisionRule::Decayed(DecayedRule {
        shift: 2,
        rise_shift: 1,
        activate: 8 * RATE_ONE,
        deactivate: 2 * RATE_ONE,
        instance_activate: 4 * RATE_ONE,
        instance_omit: RATE_ONE,
        per_shared: RATE_ONE / 4,
        per_unique: RATE_ONE,
    }))
}

fn manager(
    cube: u64,
    align: u64,
    catalog: &MeshCatalog,
    commands: u32,
    thresholds: Thresholds,
    warm_start_hold: u32,
) -> Manager<HashedHitboxes> {
    let index = HashedHitboxes::new(HashedConfig {
        cell_size: f64::from(CELL),
        evict_after_frames: 2,
        initial_buckets: 4,
        ..HashedConfig::default()
    })
    .unwrap();
    let mut mc = ManagerConfig::new(cube);
    mc.culling.latency_mitigation = None;
    mc.culling.command_capacity = commands;
    mc.culling.thresholds = thresholds;
    mc.culling.warm_start_hold = warm_start_hold;
    mc.scheduler = SchedulerConfig {
        scratch_alignment: align,
        ..SchedulerConfig::default()
    };
    Manager::new(index, mc, catalog.clone()).unwrap()
}

pub fn hashed_index_on_the_gpu_equals_the_cpu_backend_paper_rule() {
    let h = headless("hashed_index_on_the_gpu_equals_the_cpu_backend_paper_rule");
    gpu_equals_cpu(&h, paper(), false, None);
}

pub fn hashed_index_on_the_gpu_equals_the_cpu_backend_decayed_rule() {
    let h = headless("hashed_index_on_the_gpu_equals_the_cpu_backend_decayed_rule");
    gpu_equals_cpu(&h, decayed(), false, None);
}

/// Warm starts at some frames, held for 3 frames without hits: the GPU
/// gets the rate floors through the upload and decides as the CPU does.
pub fn held_warm_starts_on_the_gpu_equal_the_cpu_backend() {
    let h = headless("held_warm_starts_on_the_gpu_equal_the_cpu_backend");
    gpu_equals_cpu(&h, decayed(), false, Some(3));
}

/// The frustum of `view` (as the camera tracer shoots its rays).
fn frustum_of(view: &CameraView) -> Frustum {
    let origin = Vec3::from(view.origin);
    let v = glam::camera::rh::view::look_to_mat4(origin, Vec3::from(view.forward), Vec3::Y);
    let half = Vec3::from(view.up).length().atan();
    let aspect = Vec3::from(view.right).length() / Vec3::from(view.up).length();
    let p = glam::camera::rh::proj::vulkan::perspective(2.0 * half, aspect, 0.1, view.t_max);
    Frustum::from_view_projection(p * v).unwrap()
}

/// The escape sums with random per-slot hit counts up to `u32::MAX`
/// written over the trace's (so that the sums pass 2^32 and carry).
pub fn escape_sums_equal_the_cpu_for_random_large_hit_counts() {
    let h = headless("escape_sums_equal_the_cpu_for_random_large_hit_counts");
    gpu_equals_cpu(&h, paper(), true, None);
}

/// Random hit counts for `slots` slots: zero, small, or up to `u32::MAX`.
fn random_hits(rng: &mut SplitMix64, slots: u32) -> Vec<u32> {
    (0..slots.max(1))
        .map(|_| match rng.below(4) {
            0 => 0,
            1 => rng.below(50) as u32,
            2 => u32::MAX - rng.below(1000) as u32,
            _ => rng.next_u32(),
        })
        .collect()
}

/// Records a global memory barrier.
fn barrier(
    rec: &mut lipac_vk::Recorder<'_>,
    src: vk::PipelineStageFlags2,
    src_access: vk::AccessFlags2,
    dst: vk::PipelineStageFlags2,
    dst_access: vk::AccessFlags2,
) {
    let b = [vk::MemoryBarrier2::default()
        .src_stage_mask(src)
        .src_access_mask(src_access)
        .dst_stage_mask(dst)
        .dst_access_mask(dst_access)];
    let dep = vk::DependencyInfo::default().memory_barriers(&b);
    // SAFETY: recording on this device; the headless context enables
    // synchronization2.
    unsafe {
        rec.context()
            .device()
            .cmd_pipeline_barrier2(rec.raw(), &dep)
    };
}

/// Records a copy of `hits` over the first counters of `dst` after the
/// trace's writes (and before Algorithm 2 reads them); `staging` is kept
/// alive by the caller until the frame has run.
fn overwrite_hits(rec: &mut lipac_vk::Recorder<'_>, staging: &Buffer, dst: &Buffer) {
    barrier(
        rec,
        vk::PipelineStageFlags2::ALL_COMMANDS,
        vk::AccessFlags2::MEMORY_WRITE,
        vk::PipelineStageFlags2::TRANSFER,
        vk::AccessFlags2::TRANSFER_WRITE,
    );
    let region = [vk::BufferCopy::default().size(staging.size())];
    // SAFETY: recording on this device; `staging` (TRANSFER_SRC) and `dst`
    // (the hit counters, TRANSFER_DST) are live, and the region lies inside
    // both (at most one counter per slot of the tables).
    unsafe {
        rec.context()
            .device()
            .cmd_copy_buffer(rec.raw(), staging.raw(), dst.raw(), &region)
    };
    barrier(
        rec,
        vk::PipelineStageFlags2::TRANSFER,
        vk::AccessFlags2::TRANSFER_WRITE,
        vk::PipelineStageFlags2::ALL_COMMANDS,
        vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE,
    );
}

/// Records a copy of the whole of `src` (`TRANSFER_SRC`) into a new
/// host-readable buffer after every earlier command, and returns that
/// buffer (read it once the frame has run).
fn read_back_whole(rec: &mut lipac_vk::Recorder<'_>, src: &Buffer) -> lipac_vk::Result<Buffer> {
    let dst = Buffer::new(
        rec.context(),
        src.size(),
        vk::BufferUsageFlags::TRANSFER_DST,
        MemoryLocation::GpuToCpu,
    )?;
    barrier(
        rec,
        vk::PipelineStageFlags2::ALL_COMMANDS,
        vk::AccessFlags2::MEMORY_WRITE,
        vk::PipelineStageFlags2::TRANSFER,
        vk::AccessFlags2::TRANSFER_READ,
    );
    let region = [vk::BufferCopy::default().size(src.size())];
    // SAFETY: recording on this device; `src` (TRANSFER_SRC) and `dst`
    // (TRANSFER_DST, as large) are live until the frame has run (the
    // caller waits for it).
    unsafe {
        rec.context()
            .device()
            .cmd_copy_buffer(rec.raw(), src.raw(), dst.raw(), &region)
    };
    barrier(
        rec,
        vk::PipelineStageFlags2::TRANSFER,
        vk::AccessFlags2::TRANSFER_WRITE,
        vk::PipelineStageFlags2::HOST,
        vk::AccessFlags2::HOST_READ,
    );
    Ok(dst)
}

/// `warm_start_hold`: both managers warm-start at frames 4, 9 and 15 (the
/// view's frustum and 30 m around the camera), held that many frames.
fn gpu_equals_cpu(
    h: &HeadlessContext,
    thresholds: Thresholds,
    large_hits: bool,
    warm_start_hold: Option<u32>,
) {
    let ctx = h.context();
    let (mesh, catalog) = crate::common::one_mesh_catalog(h, DATA_BYTES);
    let commands = 512;
    let empty = HashedHitboxes::new(HashedConfig::default()).unwrap();
    let config = LipacVkConfig {
        initial_slot_capacity: 16,
        readback_slots: 3,
        command_capacity: commands,
        pool_block_size: 1 << 20,
        read_back_diagnostics: true,
        ..LipacVkConfig::default()
    };
    // Created for an empty index: the hitbox tables start at 1 hitbox.
    let mut lipac = LipacVk::new(ctx, &empty, config).unwrap();
    assert_eq!(lipac.hitbox_capacity(), 1);
    let (cube, align) = (lipac.unit_cube_address(), lipac.scratch_alignment());
    let hold = warm_start_hold.unwrap_or(0);
    let mut gpu = manager(cube, align, &catalog, commands, thresholds, hold);
    let mut cpu = manager(cube, align, &catalog, commands, thresholds, hold);
    let mut warm_activations = 0;
    let (mut gpu_scene, mut cpu_scene) = (Scene::new(), Scene::new());

    let tracer = AnyCameraTracer::new(ctx, lipac.counting(), 3, None).unwrap();
    let image = Buffer::new(
        ctx,
        48 * 32 * 4,
        vk::BufferUsageFlags::STORAGE_BUFFER,
        MemoryLocation::GpuOnly,
    )
    .unwrap();
    let geometry = |_: &BlasOwner| -> Option<Vec<TriangleGeometry>> { Some(vec![mesh.geometry()]) };
    let data = |u: &DataUpload, out: &mut [u8]| {
        let albedo = [0.2 + 0.01 * (u.slot % 50) as f32, 0.6, 0.4, 0.0];
        out.copy_from_slice(bytemuck::cast_slice(&albedo));
    };
    let mut submitter = FrameSubmitter::new(ctx, 2).unwrap();
    let timeline = lipac.timeline().clone();
    let mut cameras = SplitMix64::new(99);
    let mut last: Option<Polled> = None;
    let mut cpu_commands = None;
    let (mut growths, mut evictions, mut reused_at_same_len) = (Vec::new(), 0, 0);
    let (mut emptied_indices, mut spare_records) = (0, 0);
    let (mut total_commands, mut box_hits, mut traced_hits) = (0usize, 0u64, 0u64);
    for f in 1..=FRAMES {
        let len_before = gpu.registry().hitbox_index().len();
        let live_before: Vec<bool> = (0..len_before)
            .map(|i| gpu.registry().hitbox_index().cell(i).is_some())
            .collect();
        gpu_scene.script(f, &mut gpu);
        cpu_scene.script(f, &mut cpu);

        // The Vulkan backend: the previous frame's results, plan, record,
        // trace, Algorithm 2, read-back.
        gpu.begin_frame(f).unwrap();
        let view = random_view(&mut cameras, f);
        let warm = warm_start_hold.is_some() && [4, 9, 15].contains(&f);
        let heuristic = ActivationHeuristic {
            max_distance: f32::INFINITY,
            min_projected_size: 0.0,
            surround_radius: 30.0,
        };
        if warm {
            let out = gpu
                .warm_start(Vec3::from(view.origin), &frustum_of(&view), heuristic)
                .unwrap();
            warm_activations += out.summary.accepted;
        }
        let evicted = gpu.registry().evicted_hitboxes().to_vec();
        evictions += evicted.len();
        let acks = last.as_ref().map(|p| p.acks.clone()).unwrap_or_default();
        if let Some(p) = last.take() {
            p.deliver(&mut gpu).unwrap();
        }
        let plan = gpu.plan(&FrameBudgets::default()).unwrap();
        if warm {
            let floors = plan.uploads.hitbox_rate_floors.len();
            assert!(floors > 0, "frame {f}: the hold's floors are uploaded");
        }
        let value = lipac.next_frame_value();
        let staging = large_hits.then(|| {
            let hits = random_hits(&mut cameras, gpu.slot_count());
            Buffer::with_data(
                ctx,
                vk::BufferUsageFlags::TRANSFER_SRC,
                MemoryLocation::CpuToGpu,
                &hits,
            )
            .unwrap()
        });
        let recorded = submitter
            .submit(&[], &[(&timeline, value)], |rec| {
                let r = lipac.record_frame(rec, &plan, &gpu, &geometry, &data)?;
                let (hits, data, offsets) = lipac.trace_targets()?;
                let bindings = tracer.bind(&CameraTraceBuffers {
                    tlas: lipac.tlas(),
                    instance_hits: hits,
                    hitboxes: lipac.hitbox_records(),
                    data,
                    data_offsets: offsets,
                    image: &image,
                    hitbox_bounds: lipac.hitbox_bounds(),
                })?;
                tracer.record(rec, &bindings, &view, &lipac.merged_boxes())?;
                if let Some(staging) = &staging {
                    overwrite_hits(rec, staging, hits);
                }
                lipac.retire_after_frame(bindings);
                lipac.record_feedback(rec)?;
                // Every hitbox record of the tables, spare capacity included.
                let records = read_back_whole(rec, lipac.hitbox_records())?;
                Ok((r, records))
            })
            .unwrap();
        let (recorded, gpu_records) = recorded;
        let index = gpu.registry().hitbox_index();
        assert!(lipac.hitbox_capacity() >= index.len());
        if recorded.hitbox_tables_grew {
            growths.push(f);
        }
        // Indices that had no cell before this frame's changes and have one now.
        let reused = (0..len_before)
            .filter(|&i| !live_before[i as usize] && index.cell(i).is_some())
            .count() as u32;
        if reused > 0 {
            assert!(
                recorded.hitbox_bounds_written >= reused,
                "frame {f}: the bounds of {reused} reused indices written"
            );
            if index.len() == len_before {
                reused_at_same_len += 1;
            }
        }
        submitter.wait_idle().unwrap();
        drop(staging);
        while timeline.value().unwrap() < value {
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        // The GPU's hitbox extents are the manager's (uploaded), evicted and
        // reused indices included; every record past the index (grown, never
        // used) is the default, empty extent, not zeros.
        let capacity = lipac.hitbox_capacity() as usize;
        let gpu_hitboxes: Vec<HitboxRecord> = gpu_records.read(0, capacity).unwrap();
        let cpu_hitboxes = gpu.hitboxes();
        for (i, (g, c)) in gpu_hitboxes.iter().zip(cpu_hitboxes).enumerate() {
            assert_eq!(
                HitboxExtent::of(g).to_words(),
                HitboxExtent::of(c).to_words(),
                "frame {f}: hitbox {i}'s extent"
            );
            if index.cell(i as u32).is_none() {
                assert!(HitboxExtent::of(g).is_empty(), "frame {f}: hitbox {i}");
                emptied_indices += 1;
            }
        }
        for (i, g) in gpu_hitboxes.iter().enumerate().skip(cpu_hitboxes.len()) {
            assert!(
                bytemuck::bytes_of(g) == bytemuck::bytes_of(&HitboxRecord::default()),
                "frame {f}: spare hitbox record {i} (of {capacity}): {g:?}"
            );
            spare_records += 1;
        }
        drop(gpu_records);
        let polled = lipac.poll().unwrap();
        assert_eq!(polled.readbacks.len(), 1, "frame {f}");
        let r = &polled.readbacks[0];
        assert_eq!(r.frame, f);

        // The CPU backend, the same frame: the same acknowledgements, its
        // own commands of the last frame.
        cpu.begin_frame(f).unwrap();
        if warm {
            cpu.warm_start(Vec3::from(view.origin), &frustum_of(&view), heuristic)
                .unwrap();
        }
        assert_eq!(cpu.registry().evicted_hitboxes(), &evicted[..], "frame {f}");
        for ack in acks {
            cpu.handle_ack(ack).unwrap();
        }
        if let Some(c) = cpu_commands.take() {
            let c: lipac_core::culling::Readback = c;
            cpu.ingest_readback(c.frame, c.counter, &c.words);
        }
        let cpu_plan = cpu.plan(&FrameBudgets::default()).unwrap();
        assert_eq!(
            cpu_plan.commands, plan.commands,
            "frame {f}: commands processed"
        );
        assert_eq!(cpu_plan.blas, plan.blas, "frame {f}: BLAS plans");
        let diag = r.diagnostics.as_ref().unwrap();
        let mut tlas = Vec::new();
        cpu.assemble(&mut tlas).unwrap();
        assert_eq!(tlas.len() as u32, r.tlas_records, "frame {f}: TLAS records");
        assert!(
            tlas_multiset(&tlas) == tlas_multiset(&diag.tlas_instances),
            "frame {f}: TLAS record multisets differ"
        );
        assert_eq!(diag.hitboxes.len(), cpu.hitboxes().len(), "frame {f}");
        let slots = r.instance_hits.len().min(cpu.instance_hits_mut().len());
        cpu.instance_hits_mut()[..slots].copy_from_slice(&r.instance_hits[..slots]);
        for (c, g) in cpu.hitboxes_mut().iter_mut().zip(&diag.hitboxes) {
            c.add_hits(g.hits());
        }
        let fed = cpu.process_feedback().unwrap();
        let c = cpu.take_commands().expect("feedback ran");
        assert_eq!(c.counter, r.commands.counter(), "frame {f}");
        let (mut a, mut b) = (c.words.clone(), r.commands.words().to_vec());
        a.sort_unstable();
        b.sort_unstable();
        assert_eq!(a, b, "frame {f}: command words");
        total_commands += a.len();
        // The escape fraction's sums: the GPU's equal the CPU's sample.
        // Algorithm 2's sums on the CPU (FeedbackStats), and the sample the
        // CPU path hands the manager's controller.
        assert_eq!(
            (r.escape.box_hits, r.escape.total_hits - r.escape.box_hits),
            (fed.box_hits, fed.traced_hits),
            "frame {f}: escape sums"
        );
        let cpu_escape = cpu.stats().escape.expect("process_feedback samples");
        assert_eq!(r.escape, cpu_escape, "frame {f}: escape sample");
        box_hits += r.escape.box_hits;
        traced_hits += r.escape.total_hits - r.escape.box_hits;
        cpu_commands = Some(c);
        last = Some(polled);
    }
    // The delivered sample reached the Vulkan manager.
    if let Some(p) = last.take() {
        let want = p.readbacks[0].escape;
        p.deliver(&mut gpu).unwrap();
        assert_eq!(gpu.stats().escape, Some(want));
    }
    eprintln!(
        "growths at frames {growths:?}, {evictions} evictions, {reused_at_same_len} frames \
         reusing indices at an unchanged count, {total_commands} commands, \
         {box_hits} box hits, {traced_hits} traced hits"
    );
    assert!(growths.len() >= 3, "the hitbox tables grew at {growths:?}");
    assert!(evictions > 0 && reused_at_same_len > 0);
    assert!(
        emptied_indices > 0 && spare_records > 0,
        "{emptied_indices} indices without a cell, {spare_records} spare records checked"
    );
    assert!(total_commands > 0, "instances were activated");
    if warm_start_hold.is_some() {
        assert!(warm_activations > 0, "the warm starts activated instances");
    }
    assert!(box_hits > 0 && traced_hits > 0, "both sums were exercised");
    if large_hits {
        assert!(
            traced_hits > u64::from(u32::MAX),
            "the sums carried past 32 bits"
        );
    }
    drop((submitter, lipac, tracer, image));
    assert_no_validation_errors(h);
}
