//! `LipacVk`'s frame loop with adaptive hitboxes
//! (`CullingConfig::adaptive_hitboxes`, a `Manager<HitboxGrid>`): GPU
//! Algorithm 1 merges cold quadtree nodes into one counting box each, and
//! `CameraTracer` (`camera_trace.comp`) resolves them to their leaf
//! hitboxes' boxes. Over 20 frames of a scene whose instances arrive, leave
//! and move under a random camera (hitboxes activate and deactivate, so
//! nodes split and merge), every frame:
//!
//! * plans and command words equal those of a second `Manager` running the
//!   CPU reference (`assemble`, the GPU's hit counts, `process_feedback`);
//! * the GPU's TLAS record multiset (merged boxes included) equals the CPU's;
//! * the trace counts what one box per hitbox counts: the same camera traced
//!   by the same shader against the *leaf-only* TLAS
//!   (`assemble_tlas_adaptive` without the tree, over the CPU's records)
//!   leaves hitbox records (hit counts, heights, bits), per-slot hit
//!   counters and image equal to the frame loop's, bit for bit. A tracer
//!   that took merged boxes for geometry (`MergedBoxes::OFF` pushed with a
//!   merged TLAS) fails this at the first merged box on a ray.

use std::collections::BTreeSet;

use crate::common::*;
use ash::vk;
use glam::Vec3;
use lipac_core::assembly::assemble_tlas_adaptive;
use lipac_core::blas_cache::BlasOwner;
use lipac_core::build_plan::SchedulerConfig;
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::hitbox_tree::AdaptiveHitboxes;
use lipac_core::instance::{InstanceDesc, MeshId};
use lipac_core::layout::{tlas_multiset, HitboxRecord, TlasInstance};
use lipac_core::manager::{DataUpload, FrameBudgets, Manager, ManagerConfig, MeshCatalog};
use lipac_core::registry::InstanceHandle;
use lipac_core::thresholds::Thresholds;
use lipac_test_support::{Rng64, SplitMix64};
use lipac_vk::{
    hitbox_bounds, AnyCameraTracer, Buffer, CameraTraceBuffers, CameraView, FrameSubmitter,
    HeadlessContext, LipacVk, LipacVkConfig, MemoryLocation, MergedBoxes, OneShot, Polled,
    TriangleGeometry,
};

const FRAMES: u64 = 20;
const CELL: f32 = 16.0;
const NX: u32 = 12;
const NZ: u32 = 10;
const DATA_BYTES: u64 = 16;
const WIDTH: u32 = 48;
const HEIGHT: u32 = 32;
const STORAGE: vk::BufferUsageFlags = vk::BufferUsageFlags::STORAGE_BUFFER;

/// One manager's side of the scene: the same script runs on both.
struct Scene {
    rng: SplitMix64,
    handles: Vec<(InstanceHandle, InstanceDesc)>,
}

impl Scene {
    fn new() -> Self {
        Self {
            rng: SplitMix64::new(0xADA9),
            handles: Vec::new(),
        }
    }

    /// `n` tiles at random spots of the cells `cx.0..cx.1` x `cz.0..cz.1`.
    fn add(&mut self, m: &mut Manager, n: u32, cx: (u32, u32), cz: (u32, u32)) {
        for _ in 0..n {
            let rng = &mut self.rng;
            let mut pick = |(a, b): (u32, u32)| {
                let c = a + rng.below(u64::from(b - a)) as u32;
                c as f32 * CELL + 4.0 + 8.0 * rng.unit_f64() as f32
            };
            let (x, z) = (pick(cx), pick(cz));
            let (t, aabb) = tile(x, 0.5 + 3.0 * self.rng.unit_f64() as f32, z);
            let d = InstanceDesc::new(MeshId(1), t, aabb);
            self.handles.push((m.register(d).unwrap(), d));
        }
    }

    /// Removes every instance whose centre lies in cells `cx < below`.
    fn clear_columns(&mut self, m: &mut Manager, below: u32) {
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
    fn script(&mut self, f: u64, m: &mut Manager) {
        match f {
            1 => self.add(m, 40, (0, 8), (0, 6)),
            5 => self.add(m, 30, (6, NX), (4, NZ)),
            8 => self.clear_columns(m, 3),
            11 => {
                // Every third instance one cell further in z (within the grid).
                for (i, (h, d)) in self.handles.iter_mut().enumerate() {
                    let c = d.aabb.center();
                    if i % 3 == 0 && c.z + CELL < NZ as f32 * CELL {
                        let (t, aabb) = tile(c.x, c.y, c.z + CELL);
                        m.set_transform(*h, t, aabb).unwrap();
                        d.aabb = aabb;
                    }
                }
            }
            14 => self.add(m, 20, (0, 4), (5, NZ)),
            17 => self.clear_columns(m, 5),
            _ => {}
        }
    }
}

/// A random camera above the scene looking into it.
fn random_view(rng: &mut SplitMix64, f: u64) -> CameraView {
    let origin = Vec3::new(
        40.0 + 110.0 * rng.unit_f64() as f32,
        45.0 + 30.0 * rng.unit_f64() as f32,
        -40.0 + 30.0 * rng.unit_f64() as f32,
    );
    let target = Vec3::new(
        192.0 * rng.unit_f64() as f32,
        0.0,
        20.0 + 140.0 * rng.unit_f64() as f32,
    );
    let forward = (target - origin).normalize();
    let right = forward.cross(Vec3::Y).normalize();
    let up = right.cross(forward);
    let th = 0.6f32;
    CameraView {
        origin: origin.to_array(),
        forward: forward.to_array(),
        right: (right * th * WIDTH as f32 / HEIGHT as f32).to_array(),
        up: (up * th).to_array(),
        sun: Vec3::new(0.4, 0.8, 0.3).normalize().to_array(),
        t_max: 1.0e4,
        width: WIDTH,
        height: HEIGHT,
        seed: f as u32,
        shadows: true,
        bounce: true,
    }
}

/// The paper's rule at this scene's scale (about 4.5k rays per frame).
fn thresholds() -> Thresholds {
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

fn grid() -> HitboxGrid {
    HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [
            f64::from(NX) * f64::from(CELL),
            f64::from(NZ) * f64::from(CELL),
        ],
        cell_size: f64::from(CELL),
    })
    .unwrap()
}

fn manager(cube: u64, align: u64, catalog: &MeshCatalog, commands: u32, levels: u8) -> Manager {
    let mut mc = ManagerConfig::new(cube);
    mc.culling.latency_mitigation = None;
    mc.culling.command_capacity = commands;
    mc.culling.thresholds = thresholds();
    mc.culling.adaptive_hitboxes = AdaptiveHitboxes::with_levels(levels);
    mc.scheduler = SchedulerConfig {
        scratch_alignment: align,
        ..SchedulerConfig::default()
    };
    Manager::new(grid(), mc, catalog.clone()).unwrap()
}

/// What a trace left: hitbox records, per-slot counters, image.
struct Traced {
    hitboxes: Vec<HitboxRecord>,
    instance_hits: Vec<u32>,
    image: Vec<u32>,
}

/// The reference: `view` traced by `tracer` against `records` (the
/// leaf-only TLAS), counting into a copy of `hitboxes`, shading from
/// `lipac`'s geometry data (the GPU is idle).
#[allow(clippy::too_many_arguments)]
fn trace_reference(
    h: &HeadlessContext,
    tracer: &AnyCameraTracer,
    lipac: &LipacVk,
    records: &[TlasInstance],
    hitboxes: &[HitboxRecord],
    slots: usize,
    view: &CameraView,
    merged: &MergedBoxes,
) -> Traced {
    let ctx = h.context();
    let host = MemoryLocation::GpuToCpu;
    let (tlas, _inputs) = build_tlas(h, records);
    let hits = Buffer::with_data(ctx, STORAGE, host, &vec![0u32; slots.max(1)]).unwrap();
    let hb = Buffer::with_data(ctx, STORAGE, host, hitboxes).unwrap();
    let bounds = Buffer::with_data(ctx, STORAGE, host, &hitbox_bounds(&grid())).unwrap();
    let image = Buffer::new(ctx, u64::from(WIDTH * HEIGHT) * 4, STORAGE, host).unwrap();
    let bindings = tracer
        .bind(&CameraTraceBuffers {
            tlas: &tlas,
            instance_hits: &hits,
            hitboxes: &hb,
            data: lipac.instance_data().unwrap(),
            data_offsets: lipac.instance_data_offsets().unwrap(),
            image: &image,
            hitbox_bounds: &bounds,
        })
        .unwrap();
    OneShot::new(ctx)
        .unwrap()
        .run(|rec| tracer.record(rec, &bindings, view, merged))
        .unwrap();
    Traced {
        hitboxes: hb.read(0, hitboxes.len()).unwrap(),
        instance_hits: hits.read(0, slots).unwrap(),
        image: image.read(0, (WIDTH * HEIGHT) as usize).unwrap(),
    }
}

/// Asserts `frame == reference`, naming the first difference and the count.
fn assert_same<T: PartialEq + std::fmt::Debug>(frame: &[T], reference: &[T], f: u64, what: &str) {
    assert_eq!(frame.len(), reference.len(), "frame {f}: {what}");
    let differ: Vec<usize> = (0..frame.len())
        .filter(|&i| frame[i] != reference[i])
        .collect();
    if let Some(&i) = differ.first() {
        panic!(
            "frame {f}: {} {what} differ from the leaf-only trace's, the first at {i}: \
             {:?} vs {:?}",
            differ.len(),
            frame[i],
            reference[i]
        );
    }
}

pub fn adaptive_frame_loop_equals_the_cpu_and_the_leaf_only_trace_levels_2() {
    let h = headless("adaptive_frame_loop_equals_the_cpu_and_the_leaf_only_trace_levels_2");
    adaptive_frame_loop(&h, 2);
}

pub fn adaptive_frame_loop_equals_the_cpu_and_the_leaf_only_trace_levels_3() {
    let h = headless("adaptive_frame_loop_equals_the_cpu_and_the_leaf_only_trace_levels_3");
    adaptive_frame_loop(&h, 3);
}

fn adaptive_frame_loop(h: &HeadlessContext, levels: u8) {
    let ctx = h.context();
    let (mesh, catalog) = crate::common::one_mesh_catalog(h, DATA_BYTES);
    let commands = 512;
    let config = LipacVkConfig {
        initial_slot_capacity: 16,
        // Spare hitbox capacity: Algorithm 1 runs over the grid's records only.
        initial_hitbox_capacity: NX * NZ + 7,
        readback_slots: 3,
        command_capacity: commands,
        pool_block_size: 1 << 20,
        read_back_diagnostics: true,
        ..LipacVkConfig::default()
    };
    let mut lipac = LipacVk::new(ctx, &grid(), config).unwrap();
    assert_eq!(lipac.merged_boxes(), MergedBoxes::OFF);
    let (cube, align) = (lipac.unit_cube_address(), lipac.scratch_alignment());
    let mut gpu = manager(cube, align, &catalog, commands, levels);
    let mut cpu = manager(cube, align, &catalog, commands, levels);
    let (mut gpu_scene, mut cpu_scene) = (Scene::new(), Scene::new());

    let tracer = AnyCameraTracer::new(ctx, lipac.counting(), 3, None).unwrap();
    let pixels = u64::from(WIDTH * HEIGHT);
    let image = Buffer::new(ctx, pixels * 4, STORAGE, MemoryLocation::GpuToCpu).unwrap();
    let geometry = |_: &BlasOwner| -> Option<Vec<TriangleGeometry>> { Some(vec![mesh.geometry()]) };
    let data = |u: &DataUpload, out: &mut [u8]| {
        let albedo = [0.2 + 0.01 * (u.slot % 50) as f32, 0.6, 0.4, 0.0];
        out.copy_from_slice(bytemuck::cast_slice(&albedo));
    };
    let mut submitter = FrameSubmitter::new(ctx, 2).unwrap();
    let timeline = lipac.timeline().clone();
    let mut cameras = SplitMix64::new(0xCA3);
    let mut last: Option<Polled> = None;
    let mut cpu_commands = None;
    let mut prev_merged: BTreeSet<u32> = BTreeSet::new();
    let mut prev_active: Vec<bool> = vec![false; (NX * NZ) as usize];
    let (mut splits, mut merges, mut activations, mut deactivations) = (0, 0, 0, 0);
    let (mut merged_boxes, mut merged_leaf_hits, mut total_commands) = (0usize, 0u64, 0usize);
    let mut box_hits = 0u64;
    for f in 1..=FRAMES {
        gpu_scene.script(f, &mut gpu);
        cpu_scene.script(f, &mut cpu);

        // The Vulkan backend: the previous frame's results, plan, record,
        // trace, Algorithm 2, read-back.
        gpu.begin_frame(f).unwrap();
        let acks = last.as_ref().map(|p| p.acks.clone()).unwrap_or_default();
        if let Some(p) = last.take() {
            p.deliver(&mut gpu).unwrap();
        }
        let plan = gpu.plan(&FrameBudgets::default()).unwrap();
        let view = random_view(&mut cameras, f);
        let value = lipac.next_frame_value();
        submitter
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
                lipac.retire_after_frame(bindings);
                lipac.record_feedback(rec)?;
                Ok(r)
            })
            .unwrap();
        let merged = lipac.merged_boxes();
        assert_eq!(
            (merged.grid_nx, merged.grid_nz, merged.levels),
            (NX, NZ, u32::from(levels))
        );
        submitter.wait_idle().unwrap();
        while timeline.value().unwrap() < value {
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        let polled = lipac.poll().unwrap();
        assert_eq!(polled.readbacks.len(), 1, "frame {f}");
        let r = &polled.readbacks[0];
        assert_eq!(r.frame, f);
        let diag = r.diagnostics.as_ref().unwrap();
        let frame_image: Vec<u32> = image.read(0, pixels as usize).unwrap();

        // The CPU backend, the same frame: the same acknowledgements, its
        // own commands of the last frame.
        cpu.begin_frame(f).unwrap();
        for ack in acks {
            cpu.handle_ack(ack).unwrap();
        }
        if let Some(c) = cpu_commands.take() {
            let c: lipac_core::culling::Readback = c;
            cpu.ingest_readback(c.frame, c.counter, &c.words);
        }
        let cpu_plan = cpu.plan(&FrameBudgets::default()).unwrap();
        assert_eq!(cpu_plan.commands, plan.commands, "frame {f}: commands");
        assert_eq!(cpu_plan.blas, plan.blas, "frame {f}: BLAS plans");
        let mut tlas = Vec::new();
        let stats = cpu.assemble(&mut tlas).unwrap();
        assert_eq!(tlas.len() as u32, r.tlas_records, "frame {f}: TLAS records");
        assert!(
            tlas_multiset(&tlas) == tlas_multiset(&diag.tlas_instances),
            "frame {f}: TLAS record multisets differ"
        );
        merged_boxes += stats.merged_boxes as usize;

        // The leaf-only TLAS of the same state, traced by the same shader.
        let mut leaf_hitboxes = cpu.hitboxes().to_vec();
        let mut leaf = Vec::new();
        assemble_tlas_adaptive(
            cpu.records(),
            &mut leaf_hitboxes,
            cpu.registry().hitbox_index(),
            &cpu.culling_config().assembly,
            None,
            &mut leaf,
        )
        .unwrap();
        assert_eq!(leaf_hitboxes, cpu.hitboxes(), "frame {f}");
        assert!(leaf.len() >= tlas.len());
        let slots = r.instance_hits.len();
        let reference = trace_reference(
            h,
            &tracer,
            &lipac,
            &leaf,
            cpu.hitboxes(),
            slots,
            &view,
            &merged,
        );
        assert_same(&diag.hitboxes, &reference.hitboxes, f, "hitbox records");
        assert_same(
            &r.instance_hits,
            &reference.instance_hits,
            f,
            "hit counters",
        );
        assert_same(&frame_image, &reference.image, f, "pixels");

        // Merged nodes this frame; hits counted on leaves of merged nodes.
        let sbt = cpu.hitbox_tree().unwrap().config().merged_box_sbt_offset;
        let now: BTreeSet<u32> = tlas
            .iter()
            .filter(|t| t.sbt_offset() == sbt)
            .map(TlasInstance::custom_index)
            .collect();
        let mut leaves = Vec::new();
        for &node in &now {
            leaves.clear();
            assert!(cpu.merged_leaf_boxes(node, &mut leaves));
            assert!(leaves.len() >= 2, "frame {f}: node {node}");
            merged_leaf_hits += leaves
                .iter()
                .map(|&(i, _)| u64::from(diag.hitboxes[i as usize].hits()))
                .sum::<u64>();
        }
        splits += prev_merged.difference(&now).count();
        merges += now.difference(&prev_merged).count();
        prev_merged = now;

        // Algorithm 2 on the CPU with the GPU's counts.
        cpu.instance_hits_mut()[..slots].copy_from_slice(&r.instance_hits);
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
        assert_eq!(
            (r.escape.box_hits, r.escape.total_hits - r.escape.box_hits),
            (fed.box_hits, fed.traced_hits),
            "frame {f}: escape sums"
        );
        total_commands += a.len();
        box_hits += r.escape.box_hits;
        for (i, hb) in cpu.hitboxes().iter().enumerate() {
            match (prev_active[i], hb.is_active()) {
                (false, true) => activations += 1,
                (true, false) => deactivations += 1,
                _ => {}
            }
            prev_active[i] = hb.is_active();
        }
        cpu_commands = Some(c);
        last = Some(polled);
    }
    eprintln!(
        "levels {levels}: {merged_boxes} merged boxes, {merges} nodes merged, {splits} split, \
         {activations} hitbox activations, {deactivations} deactivations, {merged_leaf_hits} \
         hits on leaves of merged boxes of {box_hits} box hits, {total_commands} commands"
    );
    assert!(merges > 0 && splits > 0, "nodes merged and split");
    assert!(activations > 0 && deactivations > 0);
    assert!(
        merged_leaf_hits > 0,
        "rays were resolved through merged boxes"
    );
    assert!(total_commands > 0);
    drop((submitter, lipac, tracer, image));
    assert_no_validation_errors(h);
}

/// `CameraTracer::record` refuses merged boxes over a grid larger than the
/// bound hitbox records or bounds (the shader would read past them).
pub fn camera_tracer_refuses_a_grid_larger_than_its_hitbox_buffers() {
    let h = headless("camera_tracer_refuses_a_grid_larger_than_its_hitbox_buffers");
    let ctx = h.context();
    let tracer =
        AnyCameraTracer::new(ctx, &lipac_vk::CountingBoxConfig::default(), 3, None).unwrap();
    // One zeroed record: BLAS 0, an inactive instance.
    let (tlas, _inputs) = build_tlas(&h, &[bytemuck::Zeroable::zeroed()]);
    let host = MemoryLocation::GpuToCpu;
    let small = |n: usize| Buffer::new(ctx, 16 * n as u64, STORAGE, host).unwrap();
    let (records, bounds, words) = (small(NX as usize * NZ as usize), small(6), small(4));
    let image = Buffer::new(ctx, u64::from(WIDTH * HEIGHT) * 4, STORAGE, host).unwrap();
    let bindings = tracer
        .bind(&CameraTraceBuffers {
            tlas: &tlas,
            instance_hits: &words,
            hitboxes: &records,
            data: &words,
            data_offsets: &words,
            image: &image,
            hitbox_bounds: &bounds,
        })
        .unwrap();
    let mut view = random_view(&mut SplitMix64::new(1), 1);
    view.shadows = false;
    let merged = MergedBoxes {
        grid_nx: 3,
        grid_nz: 3,
        levels: 1,
        merged_sbt_offset: 3,
        min_box_extent: 0.0,
    };
    let mut one_shot = OneShot::new(ctx).unwrap();
    let e = one_shot.run(|rec| tracer.record(rec, &bindings, &view, &merged));
    assert!(
        matches!(e, Err(lipac_vk::VkError::InvalidArgument(_))),
        "{e:?}"
    );
    // A grid of 6 hitboxes fits; the leaf-only setting reads none.
    for ok in [
        MergedBoxes {
            grid_nx: 3,
            grid_nz: 2,
            ..merged
        },
        MergedBoxes::OFF,
    ] {
        one_shot
            .run(|rec| tracer.record(rec, &bindings, &view, &ok))
            .unwrap();
    }
    drop((bindings, tracer));
    assert_no_validation_errors(&h);
}
