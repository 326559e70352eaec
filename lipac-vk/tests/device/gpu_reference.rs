//! GPU Algorithms 1 and 2 against lipac-core's CPU reference on random
//! inputs, and the readback ring.
//!
//! Algorithm 1 must produce the same TLAS records (as a multiset, bit for
//! bit) and the same hitbox records as `assemble_tlas`; Algorithm 2 the same
//! instance and hitbox records, command multiset and counter as
//! `process_feedback` when every command fits. Under overflow, which
//! requests get a slot depends on GPU thread order, so the test checks the
//! invariants that make it safe instead (see `feedback_overflow_invariants`).
//!
//! The GPU holds the instance arrays split (hot, TLAS records, bounds); the CPU runs
//! on `InstanceArrays` built from the same records, and the GPU's arrays are
//! compared with the CPU's word for word.

use crate::common::*;
use ash::vk;
use glam::{Vec2, Vec3};
use lipac_core::assembly::{assemble_tlas, AssemblyConfig};
use lipac_core::command::{CommandBuffer, CommandQueue};
use lipac_core::feedback::{FeedbackError, FeedbackStats};
use lipac_core::hitbox_extents::write_extents;
use lipac_core::hitbox_index::HitboxIndex;
use lipac_core::layout::{
    hitbox_bits, instance_bits, HitboxRecord, InstanceArrays, InstanceBounds, InstanceHot,
    InstanceRecord, InstanceState, InstanceTlas, TlasInstance,
};
use lipac_core::thresholds::{DecayedRule, DecisionRule, Thresholds, RATE_ONE};
use lipac_test_support::{Rng64, XorShift64Star as Rng};
use lipac_vk::{
    hitbox_bounds, AssemblyBindings, AssemblyBuffers, AssemblyPipeline, Buffer,
    CommandReadbackRing, DeviceContext, FeedbackBindings, FeedbackBuffers, FeedbackPipeline,
    FrameSubmitter, InstanceBuffers, MemoryLocation, OneShot, TimelineSemaphore, VkError,
};
use std::collections::{BTreeSet, HashMap};

const STORAGE: vk::BufferUsageFlags = vk::BufferUsageFlags::STORAGE_BUFFER;

/// Uniform in [lo, hi), never -0.0 (`f32::min` of ±0 is unspecified, so
/// the reference's choice there is not something to compare bits on).
fn uniform(rng: &mut Rng, lo: f32, hi: f32) -> f32 {
    let v = rng.range_f32(lo, hi);
    if v == 0.0 {
        0.0
    } else {
        v
    }
}

/// An `nx` × `nz` grid of square cells; the last cell has no bounds.
struct Grid {
    nx: u32,
    nz: u32,
    origin: Vec2,
    size: f32,
}

impl HitboxIndex for Grid {
    fn len(&self) -> u32 {
        self.nx * self.nz
    }
    fn hitbox_at(&self, p: Vec3) -> Option<u32> {
        let c = ((Vec2::new(p.x, p.z) - self.origin) / self.size).floor();
        (c.x >= 0.0 && c.y >= 0.0 && (c.x as u32) < self.nx && (c.y as u32) < self.nz)
            .then(|| c.y as u32 * self.nx + c.x as u32)
    }
    fn xz_bounds(&self, i: u32) -> Option<(Vec2, Vec2)> {
        if i + 1 >= self.len() {
            return None;
        }
        let lo = self.origin + Vec2::new((i % self.nx) as f32, (i / self.nx) as f32) * self.size;
        Some((lo, lo + Vec2::splat(self.size)))
    }
}

fn bytes_eq<T: bytemuck::Pod>(a: &[T], b: &[T]) -> bool {
    bytemuck::cast_slice::<T, u8>(a) == bytemuck::cast_slice::<T, u8>(b)
}

/// A random AABB: near the origin or up to 1e6 away, sizes from 0 (flat)
/// over sub-ulp to large; sometimes min > max, sometimes not finite.
fn random_aabb(rng: &mut Rng) -> ([f32; 3], [f32; 3]) {
    let centre = match rng.below_scaled(4) {
        0 => 50.0,
        1 => 1.0e5,
        2 => 1.0e6,
        _ => 3.0,
    };
    let mut min = [0.0f32; 3];
    let mut max = [0.0f32; 3];
    for a in 0..3 {
        let c = uniform(rng, -centre, centre);
        let size = match rng.below_scaled(6) {
            0 => 0.0,
            1 => uniform(rng, 0.0, 1e-5),
            2 => uniform(rng, 0.0, 1e-2),
            3 => uniform(rng, 0.0, 30.0),
            _ => uniform(rng, 0.0, 2.0),
        };
        min[a] = c;
        max[a] = {
            let v = c + size;
            if v == 0.0 {
                0.0
            } else {
                v
            }
        };
    }
    if rng.chance(0.03) {
        std::mem::swap(&mut min[1], &mut max[1]);
    }
    if rng.chance(0.02) {
        let a = rng.below_scaled(3) as usize;
        min[a] = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY][rng.below_scaled(3) as usize];
    }
    if rng.chance(0.01) {
        max[1] = f32::NAN;
    }
    (min, max)
}

/// The split arrays of `records` (the CPU reference's input).
fn arrays(records: &[InstanceRecord]) -> InstanceArrays {
    InstanceArrays::from_records(records)
}

/// `record` as the instance arrays hold it (`HAS_BLAS` from its BLAS).
fn normalized(record: &InstanceRecord) -> InstanceRecord {
    InstanceRecord::from_parts(&record.hot(), &record.tlas(0), &record.bounds())
}

/// The CPU's Algorithm 2 on the hot parts of `records`, writing the packed
/// words back (so `records` are normalized, see [`normalized`]).
fn cpu_feedback_with_rates(
    records: &mut [InstanceRecord],
    hits: &[u32],
    rates: &mut [u32],
    hitboxes: &mut [HitboxRecord],
    th: &Thresholds,
    commands: &mut CommandBuffer,
) -> Result<FeedbackStats, FeedbackError> {
    let mut hot: Vec<InstanceHot> = records.iter().map(InstanceRecord::hot).collect();
    let stats = lipac_core::feedback::process_feedback_with_rates(
        &mut hot, hits, rates, hitboxes, th, commands,
    );
    for (r, h) in records.iter_mut().zip(&hot) {
        r.packed = h.packed;
    }
    stats
}

/// [`cpu_feedback_with_rates`] under the paper's rule, without rates.
fn cpu_feedback(
    records: &mut [InstanceRecord],
    hits: &[u32],
    hitboxes: &mut [HitboxRecord],
    th: &Thresholds,
    commands: &mut CommandBuffer,
) -> Result<FeedbackStats, FeedbackError> {
    let mut hot: Vec<InstanceHot> = records.iter().map(InstanceRecord::hot).collect();
    let stats = lipac_core::feedback::process_feedback(&mut hot, hits, hitboxes, th, commands);
    for (r, h) in records.iter_mut().zip(&hot) {
        r.packed = h.packed;
    }
    stats
}

/// A random record, normalized ([`normalized`]).
fn random_instance(rng: &mut Rng, hitboxes: u32) -> InstanceRecord {
    normalized(&random_record(rng, hitboxes))
}

fn random_record(rng: &mut Rng, hitboxes: u32) -> InstanceRecord {
    let (aabb_min, aabb_max) = random_aabb(rng);
    let mut transform = [0.0f32; 12];
    for v in &mut transform {
        *v = uniform(rng, -100.0, 100.0);
    }
    let mut packed = rng.below_scaled(4); // state, including the unused value 3
    if rng.chance(0.9) {
        packed |= instance_bits::ALIVE;
    }
    if rng.chance(0.4) {
        packed |= instance_bits::UNIQUE_BLAS;
    }
    packed |= rng.next_u32() & 0xFFFF_FF30; // vegetation/static bits, mask, vk flags, junk
    if rng.chance(0.15) {
        packed |= instance_bits::PINNED; // in any state and hitbox
    }
    InstanceRecord {
        transform,
        aabb_min,
        hitbox: if rng.chance(0.02) {
            hitboxes + rng.below_scaled(5)
        } else {
            rng.below_scaled(hitboxes)
        },
        aabb_max,
        packed,
        blas: if rng.chance(0.2) {
            0
        } else {
            rng.next_u64() | 1
        },
        sbt_offset: rng.next_u32(),
        lod: rng.below_scaled(4),
    }
}

/// Random hitbox state: stale heights, active bit, streak, hits around the
/// thresholds and near saturation.
fn random_hitbox(rng: &mut Rng, th: &Thresholds) -> HitboxRecord {
    let mut h = HitboxRecord {
        min_y: uniform(rng, -10.0, 10.0),
        max_y: uniform(rng, -10.0, 10.0),
        packed: u32::from(rng.chance(0.5)),
        rate: random_rate(rng),
        cost: rng.next_u32(),
    };
    let streak = match rng.below_scaled(4) {
        0 => th.n_a.saturating_sub(1),
        1 => th.n_d.saturating_sub(1),
        2 => hitbox_bits::STREAK_MAX - rng.below_scaled(2),
        _ => rng.below_scaled(128),
    };
    h.packed |= streak << hitbox_bits::STREAK_SHIFT;
    let hits = match rng.below_scaled(6) {
        0 => 0,
        1 => th.theta_d - 1 + rng.below_scaled(3),
        2 => th.theta_a - 1 + rng.below_scaled(3),
        3 => 2 * th.theta_a - 1 + rng.below_scaled(3),
        4 => hitbox_bits::HITS_MAX - rng.below_scaled(100),
        _ => rng.below_scaled(3 * th.theta_a),
    };
    h.add_hits(hits);
    h
}

/// A decayed hit rate (16.16): 0, around the test rule's thresholds, or
/// near the top of the range.
fn random_rate(rng: &mut Rng) -> u32 {
    match rng.below_scaled(4) {
        0 => 0,
        1 => u32::MAX - rng.below_scaled(1 << 20),
        _ => rng.below_scaled(120 * RATE_ONE),
    }
}

fn random_hits(rng: &mut Rng, th: &Thresholds) -> u32 {
    match rng.below_scaled(8) {
        0..=2 => 0,
        3 => th.sigma_o - 1 + rng.below_scaled(3),
        4 => th.sigma_a - 1 + rng.below_scaled(3),
        5 => hitbox_bits::HITS_MAX - rng.below_scaled(1000),
        6 => u32::MAX - rng.below_scaled(3),
        _ => rng.below_scaled(4 * th.sigma_a),
    }
}

/// The feedback buffers of `scene`.
fn scene_buffers(scene: &Scene) -> FeedbackBuffers<'_> {
    FeedbackBuffers {
        instance_hot: &scene.hot,
        instance_hits: &scene.instance_hits,
        hitboxes: &scene.hitboxes,
        commands: &scene.commands,
        command_counter: &scene.command_counter,
        instance_rates: &scene.instance_rates,
    }
}

/// GPU-side buffers of one test scene.
struct Scene {
    hot: Buffer,
    slot_tlas: Buffer,
    slot_bounds: Buffer,
    instance_hits: Buffer,
    hitboxes: Buffer,
    bounds: Buffer,
    tlas_out: Buffer,
    tlas_counter: Buffer,
    commands: Buffer,
    command_counter: Buffer,
    instance_rates: Buffer,
}

impl Scene {
    fn new(
        ctx: &DeviceContext,
        instances: &[InstanceRecord],
        hits: &[u32],
        hitboxes: &[HitboxRecord],
        index: &impl HitboxIndex,
        command_capacity: u32,
    ) -> Self {
        let host = MemoryLocation::GpuToCpu;
        let xfer = vk::BufferUsageFlags::TRANSFER_DST | vk::BufferUsageFlags::TRANSFER_SRC;
        let tlas_capacity = instances.len() + hitboxes.len();
        let mut tlas_out = Buffer::new(
            ctx,
            (tlas_capacity * 64) as u64,
            STORAGE | xfer | BUILD_INPUT,
            host,
        )
        .unwrap();
        // Garbage that the assembly must clear.
        tlas_out
            .write(0, &vec![0xA5A5_A5A5u32; tlas_capacity * 16])
            .unwrap();
        let split = arrays(instances);
        Self {
            hot: Buffer::with_data(ctx, STORAGE, host, split.hot()).unwrap(),
            slot_tlas: Buffer::with_data(ctx, STORAGE, host, split.tlas()).unwrap(),
            slot_bounds: Buffer::with_data(ctx, STORAGE, host, split.bounds()).unwrap(),
            instance_hits: Buffer::with_data(ctx, STORAGE | xfer, host, hits).unwrap(),
            hitboxes: Buffer::with_data(ctx, STORAGE, host, hitboxes).unwrap(),
            bounds: Buffer::with_data(ctx, STORAGE, host, &hitbox_bounds(index)).unwrap(),
            tlas_out,
            tlas_counter: Buffer::with_data(ctx, STORAGE | xfer, host, &[7u32]).unwrap(),
            commands: Buffer::new(ctx, u64::from(command_capacity) * 4, STORAGE | xfer, host)
                .unwrap(),
            command_counter: Buffer::with_data(ctx, STORAGE | xfer, host, &[99u32]).unwrap(),
            instance_rates: Buffer::with_data(ctx, STORAGE | xfer, host, &vec![0u32; hits.len()])
                .unwrap(),
        }
    }

    fn instance_buffers(&self) -> InstanceBuffers<'_> {
        InstanceBuffers {
            hot: &self.hot,
            tlas: &self.slot_tlas,
            bounds: &self.slot_bounds,
        }
    }

    fn assembly_bindings(&self, p: &AssemblyPipeline) -> AssemblyBindings {
        p.bind(&AssemblyBuffers {
            instances: self.instance_buffers(),
            hitboxes: &self.hitboxes,
            hitbox_bounds: &self.bounds,
            tlas_instances: &self.tlas_out,
            tlas_counter: &self.tlas_counter,
        })
        .unwrap()
    }

    fn feedback_bindings(&self, p: &FeedbackPipeline) -> FeedbackBindings {
        p.bind(&FeedbackBuffers {
            instance_hot: &self.hot,
            instance_hits: &self.instance_hits,
            hitboxes: &self.hitboxes,
            commands: &self.commands,
            command_counter: &self.command_counter,
            instance_rates: &self.instance_rates,
        })
        .unwrap()
    }

    /// The GPU's instance arrays joined per slot; asserts that each TLAS
    /// record holds its slot and the hot record's mask and flags.
    fn read_instances(&self, n: usize) -> Vec<InstanceRecord> {
        let hot: Vec<InstanceHot> = self.hot.read(0, n).unwrap();
        let tlas: Vec<InstanceTlas> = self.slot_tlas.read(0, n).unwrap();
        let bounds: Vec<InstanceBounds> = self.slot_bounds.read(0, n).unwrap();
        for (slot, (t, h)) in tlas.iter().zip(&hot).enumerate() {
            let t = &t.record;
            assert_eq!(
                (t.custom_index(), t.mask(), t.flags()),
                (slot as u32, h.mask(), h.vk_flags()),
                "slot {slot}: TLAS record"
            );
        }
        hot.iter()
            .zip(&tlas)
            .zip(&bounds)
            .map(|((h, t), b)| InstanceRecord::from_parts(h, t, b))
            .collect()
    }
    fn read_hitboxes(&self, n: usize) -> Vec<HitboxRecord> {
        self.hitboxes.read(0, n).unwrap()
    }
    /// Counter and the stored TLAS records; asserts the tail is zero.
    fn read_tlas(&self, capacity: usize) -> (u32, Vec<TlasInstance>) {
        let counter = self.tlas_counter.read::<u32>(0, 1).unwrap()[0];
        let all: Vec<TlasInstance> = self.tlas_out.read(0, capacity).unwrap();
        let stored = (counter as usize).min(capacity);
        assert!(
            all[stored..]
                .iter()
                .all(|r| bytemuck::bytes_of(r).iter().all(|&b| b == 0)),
            "records past the counter are zero (inactive)"
        );
        (counter, all[..stored].to_vec())
    }
    fn read_commands(&self, capacity: u32) -> (u32, Vec<u32>) {
        let counter = self.command_counter.read::<u32>(0, 1).unwrap()[0];
        let words = self
            .commands
            .read(0, counter.min(capacity) as usize)
            .unwrap();
        (counter, words)
    }
}

fn assert_hitboxes_equal(gpu: &[HitboxRecord], cpu: &[HitboxRecord], what: &str) {
    for (i, (g, c)) in gpu.iter().zip(cpu).enumerate() {
        assert!(
            bytemuck::bytes_of(g) == bytemuck::bytes_of(c),
            "{what}: hitbox {i}: GPU {g:?} ({:#x}, {:#x}) CPU {c:?} ({:#x}, {:#x})",
            g.min_y.to_bits(),
            g.max_y.to_bits(),
            c.min_y.to_bits(),
            c.max_y.to_bits()
        );
    }
}

fn assert_instances_equal(gpu: &[InstanceRecord], cpu: &[InstanceRecord], what: &str) {
    assert_eq!(gpu.len(), cpu.len(), "{what}: slots");
    for (slot, (g, c)) in gpu.iter().zip(cpu).enumerate() {
        let c = &normalized(c);
        assert!(
            bytemuck::bytes_of(g) == bytemuck::bytes_of(c),
            "{what}: slot {slot}: GPU packed {:#x}, CPU packed {:#x}",
            g.packed,
            c.packed
        );
    }
}

/// Polls `try_read` until the slot's frame is there. (lavapipe may update
/// the semaphore's counter value a moment after the submission's fence.)
fn read_when_ready(ring: &mut CommandReadbackRing, slot: usize) -> lipac_vk::CommandReadback {
    let start = std::time::Instant::now();
    loop {
        if let Some(r) = ring.try_read(slot).unwrap() {
            return r;
        }
        assert!(
            start.elapsed() < std::time::Duration::from_secs(30),
            "slot {slot}: the GPU never signalled"
        );
        std::thread::yield_now();
    }
}

fn sorted(mut v: Vec<u32>) -> Vec<u32> {
    v.sort_unstable();
    v
}

pub fn assembly_matches_cpu_reference() {
    let h = headless("assembly_matches_cpu_reference");
    let ctx = h.context();
    let pipeline = AssemblyPipeline::new(ctx).unwrap();
    let mut one_shot = OneShot::new(ctx).unwrap();
    let th = Thresholds::paper();
    let cases = [
        (1u64, 1e-3f32, Vec2::new(-40.0, -40.0), 16.0f32),
        (2, 0.0, Vec2::new(99_000.0, -100_200.0), 64.0),
        (3, 0.25, Vec2::new(-1.0e6, 1.0e6), 3.3),
        (4, f32::NAN, Vec2::new(0.0, 0.0), 1.0),
    ];
    for (seed, min_extent, origin, size) in cases {
        let mut rng = Rng::new(0x9E37_79B9_7F4A_7C15 ^ seed);
        let index = Grid {
            nx: 9,
            nz: 7,
            origin,
            size,
        };
        let n_hitboxes = index.len();
        let instances: Vec<InstanceRecord> = (0..3000)
            .map(|_| random_instance(&mut rng, n_hitboxes))
            .collect();
        let mut hitboxes: Vec<HitboxRecord> = (0..n_hitboxes)
            .map(|_| random_hitbox(&mut rng, &th))
            .collect();
        let cfg = AssemblyConfig {
            unit_cube_blas: rng.next_u64() | 1,
            counting_mask: rng.next_u32() as u8,
            omitted_box_sbt_offset: rng.next_u32(),
            hitbox_sbt_offset: rng.next_u32(),
            min_box_extent: min_extent,
        };
        let what = format!("seed {seed}");
        let hits = vec![0u32; instances.len()];
        // The extents are the CPU's; the GPU gets them with the records.
        write_extents(&arrays(&instances), &mut hitboxes);
        let scene = Scene::new(ctx, &instances, &hits, &hitboxes, &index, 1);
        let bindings = scene.assembly_bindings(&pipeline);
        assert_eq!(
            bindings.tlas_capacity() as usize,
            3000 + n_hitboxes as usize
        );

        let mut cpu_out = Vec::new();
        let stats = assemble_tlas(
            &arrays(&instances),
            &mut hitboxes,
            &index,
            &cfg,
            &mut cpu_out,
        )
        .unwrap();
        // The random scene exercises every branch.
        assert!(stats.active > 100 && stats.omitted_boxes > 100 && stats.inactive > 100);
        assert!(
            stats.hitbox_boxes > 5 && stats.invalid_instances > 0 && stats.active_without_blas > 0
        );
        // Pinned instances outside the active state or in inactive hitboxes
        // are traced with their own BLAS.
        let pinned_elsewhere = instances
            .iter()
            .filter(|m| {
                m.is_alive()
                    && m.is_pinned()
                    && m.blas != 0
                    && (m.state() != InstanceState::Active
                        || hitboxes
                            .get(m.hitbox as usize)
                            .is_some_and(|h| !h.is_active()))
            })
            .count();
        assert!(pinned_elsewhere > 100, "{pinned_elsewhere}");

        one_shot
            .run(|rec| pipeline.record(rec, &bindings, &cfg, instances.len() as u32))
            .unwrap();
        let (counter, gpu_out) = scene.read_tlas(bindings.tlas_capacity() as usize);
        assert_eq!(counter as usize, cpu_out.len(), "{what}: counter");
        assert_tlas_equal(gpu_out, cpu_out, &what);
        assert_hitboxes_equal(&scene.read_hitboxes(hitboxes.len()), &hitboxes, &what);
        // Instance records are read-only here.
        assert_instances_equal(&scene.read_instances(instances.len()), &instances, &what);
    }
    assert_no_validation_errors(&h);
}

/// Inactive instances whose heights are ±0, NaN (both signs), ±inf or
/// subnormal: the shader's atomicMin/atomicMax on ordered keys and the CPU
/// reference give the same hitbox heights bit for bit (−0 is the lower
/// bound, NaN never wins) and the same counting boxes.
pub fn assembly_signed_zero_and_nan_heights_match_cpu() {
    let h = headless("assembly_signed_zero_and_nan_heights_match_cpu");
    let ctx = h.context();
    let pipeline = AssemblyPipeline::new(ctx).unwrap();
    let mut one_shot = OneShot::new(ctx).unwrap();
    let odd: [u32; 10] = [
        0x0000_0000,
        0x8000_0000,
        0x0000_0001,
        0x8000_0001,
        0x3F80_0000,
        0xBF80_0000,
        0x7F80_0000,
        0xFF80_0000,
        0x7FC0_0000,
        0xFFC0_0000,
    ];
    let mut rng = Rng::new(0x5160_0000);
    let index = Grid {
        nx: 6,
        nz: 5,
        origin: Vec2::new(-8.0, -8.0),
        size: 16.0,
    };
    let n_hitboxes = index.len();
    let instances: Vec<InstanceRecord> = (0..2000)
        .map(|i| {
            let mut r = random_instance(&mut rng, n_hitboxes);
            r.packed |= instance_bits::ALIVE;
            r.packed &= !instance_bits::PINNED;
            r.set_state(InstanceState::Inactive);
            // Hitboxes 0..10 see only ±0 (and NaN); the others any pattern.
            r.hitbox = (i as u32) % n_hitboxes;
            let pick = |rng: &mut Rng, k: u32| {
                if r.hitbox < 10 {
                    [0x0000_0000, 0x8000_0000, 0x7FC0_0000][rng.below_scaled(3) as usize]
                } else {
                    odd[rng.below_scaled(k) as usize]
                }
            };
            r.aabb_min[1] = f32::from_bits(pick(&mut rng, 10));
            r.aabb_max[1] = f32::from_bits(pick(&mut rng, 10));
            r
        })
        .collect();
    let mut hitboxes = vec![HitboxRecord::default(); n_hitboxes as usize];
    let cfg = AssemblyConfig::new(0xC0BE);
    let hits = vec![0u32; instances.len()];
    // The extents are the CPU's; the GPU gets them with the records.
    write_extents(&arrays(&instances), &mut hitboxes);
    let scene = Scene::new(ctx, &instances, &hits, &hitboxes, &index, 1);
    let bindings = scene.assembly_bindings(&pipeline);
    let mut cpu_out = Vec::new();
    let stats = assemble_tlas(
        &arrays(&instances),
        &mut hitboxes,
        &index,
        &cfg,
        &mut cpu_out,
    )
    .unwrap();
    assert_eq!(stats.inactive, 2000);
    // Both zeros met in the ±0-only hitboxes: -0 below, +0 above.
    assert!(hitboxes[..10]
        .iter()
        .any(|h| h.min_y.to_bits() == 0x8000_0000 && h.max_y.to_bits() == 0));
    one_shot
        .run(|rec| pipeline.record(rec, &bindings, &cfg, instances.len() as u32))
        .unwrap();
    let (counter, gpu_out) = scene.read_tlas(bindings.tlas_capacity() as usize);
    assert_eq!(counter as usize, cpu_out.len(), "counter");
    assert_tlas_equal(gpu_out, cpu_out, "signed zeros");
    assert_hitboxes_equal(
        &scene.read_hitboxes(hitboxes.len()),
        &hitboxes,
        "signed zeros",
    );
    assert_no_validation_errors(&h);
}

/// Some slots processed, a full TLAS buffer: only the first `capacity`
/// appends are stored, the counter says how many were asked for.
pub fn assembly_slot_count_and_small_tlas_buffer() {
    let h = headless("assembly_slot_count_and_small_tlas_buffer");
    let ctx = h.context();
    let pipeline = AssemblyPipeline::new(ctx).unwrap();
    let th = Thresholds::paper();
    let mut rng = Rng::new(77);
    let index = Grid {
        nx: 4,
        nz: 4,
        origin: Vec2::ZERO,
        size: 8.0,
    };
    let instances: Vec<InstanceRecord> = (0..500).map(|_| random_instance(&mut rng, 16)).collect();
    let mut hitboxes: Vec<HitboxRecord> = (0..16).map(|_| random_hitbox(&mut rng, &th)).collect();
    let cfg = AssemblyConfig::new(0xC0BE);
    // The extents are the CPU's; the GPU gets them with the records.
    write_extents(&arrays(&instances), &mut hitboxes);
    let scene = Scene::new(ctx, &instances, &[0; 500], &hitboxes, &index, 1);
    // Processing only the first 200 slots equals the CPU on those 200.
    let mut cpu_out = Vec::new();
    assemble_tlas(
        &arrays(&instances[..200]),
        &mut hitboxes,
        &index,
        &cfg,
        &mut cpu_out,
    )
    .unwrap();
    let small = Buffer::new(
        ctx,
        64 * 10,
        STORAGE | vk::BufferUsageFlags::TRANSFER_DST,
        MemoryLocation::GpuToCpu,
    )
    .unwrap();
    let bindings = pipeline
        .bind(&AssemblyBuffers {
            instances: scene.instance_buffers(),
            hitboxes: &scene.hitboxes,
            hitbox_bounds: &scene.bounds,
            tlas_instances: &small,
            tlas_counter: &scene.tlas_counter,
        })
        .unwrap();
    assert!(pipeline
        .bind(&AssemblyBuffers {
            tlas_instances: &scene.hot, // no TRANSFER_DST
            ..AssemblyBuffers {
                instances: scene.instance_buffers(),
                hitboxes: &scene.hitboxes,
                hitbox_bounds: &scene.bounds,
                tlas_instances: &small,
                tlas_counter: &scene.tlas_counter,
            }
        })
        .is_err_and(|e| matches!(e, VkError::MissingUsage(_))));
    let mut one_shot = OneShot::new(ctx).unwrap();
    let too_many = one_shot.run(|rec| pipeline.record(rec, &bindings, &cfg, 501));
    assert!(matches!(too_many, Err(VkError::InvalidArgument(_))));
    one_shot
        .run(|rec| pipeline.record(rec, &bindings, &cfg, 200))
        .unwrap();
    let counter = scene.tlas_counter.read::<u32>(0, 1).unwrap()[0];
    assert!(cpu_out.len() > 10);
    assert_eq!(counter as usize, cpu_out.len());
    let stored: Vec<TlasInstance> = small.read(0, 10).unwrap();
    // Each stored record is one of the CPU's.
    let cpu_bytes: BTreeSet<Vec<u8>> = cpu_out
        .iter()
        .map(|r| bytemuck::bytes_of(r).to_vec())
        .collect();
    for r in &stored {
        assert!(cpu_bytes.contains(bytemuck::bytes_of(r)), "{r:?}");
    }
    assert_hitboxes_equal(&scene.read_hitboxes(16), &hitboxes, "200 slots");
    assert_no_validation_errors(&h);
}

fn feedback_thresholds() -> Thresholds {
    let th = Thresholds {
        theta_a: 40,
        theta_d: 8,
        sigma_a: 30,
        sigma_o: 5,
        n_a: 3,
        n_d: 5,
        rule: DecisionRule::Paper,
    };
    th.validate().unwrap();
    th
}

/// [`feedback_thresholds`] deciding with a fast decayed rule whose rates sit
/// in the range of the random hits, with both cost terms.
fn decayed_thresholds() -> Thresholds {
    let th = feedback_thresholds().with_rule(DecisionRule::Decayed(DecayedRule {
        shift: 1,
        rise_shift: 1,
        activate: 30 * RATE_ONE,
        deactivate: 8 * RATE_ONE,
        instance_activate: 25 * RATE_ONE,
        instance_omit: 5 * RATE_ONE,
        per_shared: RATE_ONE / 4,
        per_unique: RATE_ONE + 3,
    }));
    th.validate().unwrap();
    th
}

/// [`decayed_thresholds`] with a rate that rises faster than it decays
/// (`rise_shift` 2 < `shift` 3; not 1, which a missing push constant,
/// clamped from 0, would also give).
fn decayed_rise_thresholds() -> Thresholds {
    let DecisionRule::Decayed(r) = decayed_thresholds().rule else {
        unreachable!()
    };
    let th = decayed_thresholds().with_rule(DecisionRule::Decayed(DecayedRule {
        shift: 3,
        rise_shift: 2,
        ..r
    }));
    th.validate().unwrap();
    th
}

/// Full frames on both sides: assembly (hitbox reset), random box hits added
/// to the hitboxes as a trace would, Algorithm 2 with every command fitting.
pub fn frames_match_cpu_reference_without_overflow() {
    let h = headless("frames_match_cpu_reference_without_overflow");
    let ctx = h.context();
    let assembly = AssemblyPipeline::new(ctx).unwrap();
    let feedback = FeedbackPipeline::new(ctx).unwrap();
    let mut one_shot = OneShot::new(ctx).unwrap();
    for (seed, th) in [
        (11u64, feedback_thresholds()),
        (12, Thresholds::paper()),
        (13, decayed_thresholds()),
        (14, decayed_rise_thresholds()),
    ] {
        let mut rng = Rng::new(0xD1B5_4A32_D192_ED03 ^ seed);
        let index = Grid {
            nx: 8,
            nz: 8,
            origin: Vec2::new(-64.0, 1000.0),
            size: 16.0,
        };
        let n = 3000usize;
        let mut instances: Vec<InstanceRecord> = (0..n)
            .map(|_| random_instance(&mut rng, index.len()))
            .collect();
        let mut hitboxes: Vec<HitboxRecord> = (0..index.len())
            .map(|_| random_hitbox(&mut rng, &th))
            .collect();
        let capacity = n as u32; // at most one command per slot: never full
                                 // The extents are the CPU's; the GPU gets them with the records.
        write_extents(&arrays(&instances), &mut hitboxes);
        let mut scene = Scene::new(ctx, &instances, &vec![0; n], &hitboxes, &index, capacity);
        let ab = scene.assembly_bindings(&assembly);
        let fb = scene.feedback_bindings(&feedback);
        let cfg = AssemblyConfig::new(0xC0BE);
        // Random starting rates (the rule zeroes those it does not keep).
        let mut rates: Vec<u32> = (0..n).map(|_| random_rate(&mut rng)).collect();
        scene.instance_rates.write(0, &rates).unwrap();
        let mut queue_cpu = CommandQueue::new(n as u32);
        let mut queue_gpu = CommandQueue::new(n as u32);
        let mut transitions = 0;
        for frame in 0..4 {
            let what = format!("seed {seed} frame {frame}");
            // Algorithm 1 (also the frame reset of the hitboxes).
            let mut cpu_out = Vec::new();
            assemble_tlas(
                &arrays(&instances),
                &mut hitboxes,
                &index,
                &cfg,
                &mut cpu_out,
            )
            .unwrap();
            one_shot
                .run(|rec| assembly.record(rec, &ab, &cfg, n as u32))
                .unwrap();
            let (_, gpu_out) = scene.read_tlas(ab.tlas_capacity() as usize);
            assert_tlas_equal(gpu_out, cpu_out, &what);
            assert_hitboxes_equal(&scene.read_hitboxes(hitboxes.len()), &hitboxes, &what);

            // "Trace": counting-box hits into the hitboxes, instance hits.
            for hb in hitboxes.iter_mut() {
                let box_hits = random_hitbox(&mut rng, &th).hits();
                hb.add_hits(box_hits);
            }
            let hits: Vec<u32> = (0..n).map(|_| random_hits(&mut rng, &th)).collect();
            scene.hitboxes.write(0, &hitboxes).unwrap();
            scene.instance_hits.write(0, &hits).unwrap();

            // Algorithm 2.
            let before = instances.clone();
            let mut buf = CommandBuffer::new(capacity);
            let stats = cpu_feedback_with_rates(
                &mut instances,
                &hits,
                &mut rates,
                &mut hitboxes,
                &th,
                &mut buf,
            )
            .unwrap();
            assert_eq!(stats.overflowed, 0);
            one_shot
                .run(|rec| feedback.record(rec, &fb, &th, n as u32))
                .unwrap();
            let (counter, words) = scene.read_commands(capacity);
            assert_eq!(counter, buf.requested(), "{what}: counter");
            assert_eq!(
                sorted(words.clone()),
                sorted(buf.words().to_vec()),
                "{what}"
            );
            assert_instances_equal(&scene.read_instances(n), &instances, &what);
            assert_hitboxes_equal(&scene.read_hitboxes(hitboxes.len()), &hitboxes, &what);
            let gpu_rates: Vec<u32> = scene.instance_rates.read(0, n).unwrap();
            assert!(gpu_rates == rates, "{what}: instance rates differ");
            transitions += before
                .iter()
                .zip(&instances)
                .filter(|(a, b)| a.packed != b.packed)
                .count();
            assert!(before
                .iter()
                .zip(&instances)
                .all(|(a, b)| !a.is_pinned() || a.packed == b.packed));
            // Both read-backs give the core's queue the same pending commands.
            let a = queue_cpu.ingest_buffer(&buf);
            let b = queue_gpu.ingest(counter, &words);
            assert_eq!(
                (a.accepted, a.replaced, a.superseded),
                (b.accepted, b.replaced, b.superseded)
            );
        }
        assert!(
            transitions > 200,
            "seed {seed}: only {transitions} transitions"
        );
        if th.rule != DecisionRule::Paper {
            // The decayed rule kept some rates and zeroed others.
            assert!(rates.iter().filter(|&&r| r != 0).count() > 50);
            assert!(rates.iter().filter(|&&r| r == 0).count() > 50);
        }
        assert_eq!(queue_cpu.drain(usize::MAX), queue_gpu.drain(usize::MAX));
    }
    assert_no_validation_errors(&h);
}

/// A small command buffer: which requests get a slot is up to GPU thread
/// order, but the outcome must be one the overflow rule allows.
pub fn feedback_overflow_invariants() {
    let h = headless("feedback_overflow_invariants");
    let ctx = h.context();
    let feedback = FeedbackPipeline::new(ctx).unwrap();
    let th = feedback_thresholds();
    for (seed, capacity) in [(21u64, 17u32), (22, 1), (23, 200)] {
        let what = format!("seed {seed} capacity {capacity}");
        let mut rng = Rng::new(0x5851_F42D_4C95_7F2D ^ seed);
        let n = 2500usize;
        let n_hitboxes = 40;
        let instances: Vec<InstanceRecord> = (0..n)
            .map(|_| random_instance(&mut rng, n_hitboxes))
            .collect();
        let hitboxes: Vec<HitboxRecord> = (0..n_hitboxes)
            .map(|_| random_hitbox(&mut rng, &th))
            .collect();
        let hits: Vec<u32> = (0..n).map(|_| random_hits(&mut rng, &th)).collect();

        // CPU with room for everything, and with room for nothing.
        let (mut unlimited, mut hb_unlimited) = (instances.clone(), hitboxes.clone());
        let mut all = CommandBuffer::new(n as u32);
        cpu_feedback(&mut unlimited, &hits, &mut hb_unlimited, &th, &mut all).unwrap();
        let (mut none_fit, mut hb_none) = (instances.clone(), hitboxes.clone());
        let mut zero = CommandBuffer::new(0);
        cpu_feedback(&mut none_fit, &hits, &mut hb_none, &th, &mut zero).unwrap();
        assert_eq!(zero.requested(), all.requested());
        assert!(all.requested() > capacity, "{what}: the case must overflow");

        let index = Grid {
            nx: 8,
            nz: 5,
            origin: Vec2::ZERO,
            size: 1.0,
        };
        let scene = Scene::new(ctx, &instances, &hits, &hitboxes, &index, capacity);
        let fb = scene.feedback_bindings(&feedback);
        assert_eq!(fb.command_capacity(), capacity);
        let mut ring = CommandReadbackRing::new(ctx, 3, capacity).unwrap();
        let mut submitter = FrameSubmitter::new(ctx, 2).unwrap();
        let mut ticket = None;
        let signal_value = ring.semaphore().value().unwrap() + 1;
        let sem = ring.semaphore().clone();
        submitter
            .submit(&[], &[(&sem, signal_value)], |rec| {
                feedback.record(rec, &fb, &th, n as u32)?;
                ticket = Some(ring.record_copy(rec, &scene.commands, &scene.command_counter)?);
                Ok(())
            })
            .unwrap();
        let ticket = ticket.unwrap();
        assert_eq!(ticket.value, signal_value);
        submitter.wait_idle().unwrap();
        let readback = read_when_ready(&mut ring, ticket.slot);

        // The counter counts every request; the buffer holds the first `capacity`.
        assert_eq!(readback.counter(), all.requested(), "{what}");
        assert_eq!(readback.words().len(), capacity as usize);
        assert_eq!(readback.overflowed(), all.requested() - capacity);
        assert!(readback.is_full());
        let (counter, words) = scene.read_commands(capacity);
        assert_eq!(
            (counter, &words[..]),
            (readback.counter(), readback.words())
        );

        // Every stored command is one the CPU emits, for distinct slots.
        let cpu_by_slot: HashMap<u32, u32> =
            all.words().iter().map(|&w| (w & 0xFF_FFFF, w)).collect();
        let mut stored_slots = BTreeSet::new();
        for &w in readback.words() {
            let slot = w & 0xFF_FFFF;
            assert_eq!(cpu_by_slot.get(&slot), Some(&w), "{what}: word {w:#x}");
            assert!(stored_slots.insert(slot), "{what}: slot {slot} twice");
        }
        // Instances whose command fitted made the transition; the others are
        // exactly where they would be had nothing fitted.
        let gpu = scene.read_instances(n);
        for slot in 0..n {
            let expected = if stored_slots.contains(&(slot as u32)) {
                &unlimited[slot]
            } else {
                &none_fit[slot]
            };
            assert!(
                bytemuck::bytes_of(&gpu[slot]) == bytemuck::bytes_of(expected),
                "{what}: slot {slot}: GPU {:#x}, expected {:#x} (unlimited {:#x}, none {:#x})",
                gpu[slot].packed,
                expected.packed,
                unlimited[slot].packed,
                none_fit[slot].packed
            );
        }
        assert!(bytes_eq(&hb_unlimited, &hb_none));
        assert_hitboxes_equal(
            &scene.read_hitboxes(n_hitboxes as usize),
            &hb_unlimited,
            &what,
        );

        // The read-back carries the counter and the stored words as they are
        // (for Manager::ingest_readback), overflow included.
        assert_eq!(readback.words().len(), capacity as usize);
        assert_eq!(readback.counter(), all.requested());
        assert_eq!(readback.overflowed(), all.requested() - capacity);
        assert!(readback.is_full());
    }
    assert_no_validation_errors(&h);
}

pub fn feedback_rejects_bad_arguments() {
    let h = headless("feedback_rejects_bad_arguments");
    let ctx = h.context();
    let feedback = FeedbackPipeline::new(ctx).unwrap();
    let th = feedback_thresholds();
    let instances = vec![InstanceRecord::default(); 4];
    let index = Grid {
        nx: 2,
        nz: 1,
        origin: Vec2::ZERO,
        size: 1.0,
    };
    let hitboxes = vec![HitboxRecord::default(); 2];
    let mut scene = Scene::new(ctx, &instances, &[0; 4], &hitboxes, &index, 4);
    let fb = scene.feedback_bindings(&feedback);
    let mut one_shot = OneShot::new(ctx).unwrap();
    let bad = Thresholds {
        theta_d: th.theta_a,
        ..th
    };
    assert!(matches!(
        one_shot.run(|rec| feedback.record(rec, &fb, &bad, 4)),
        Err(VkError::InvalidArgument(_))
    ));
    assert!(matches!(
        one_shot.run(|rec| feedback.record(rec, &fb, &th, 5)),
        Err(VkError::InvalidArgument(_))
    ));
    // Too few hit counters for the slots.
    let short = Buffer::new(ctx, 8, STORAGE, MemoryLocation::GpuOnly).unwrap();
    assert!(matches!(
        feedback.bind(&FeedbackBuffers {
            instance_hits: &short,
            instance_hot: &scene.hot,
            hitboxes: &scene.hitboxes,
            commands: &scene.commands,
            command_counter: &scene.command_counter,
            instance_rates: &scene.instance_rates,
        }),
        Err(VkError::InvalidArgument(_))
    ));
    // Too few rates for the slots.
    match feedback.bind(&FeedbackBuffers {
        instance_rates: &short,
        ..scene_buffers(&scene)
    }) {
        Err(VkError::InvalidArgument(what)) => assert!(what.contains("rates"), "{what}"),
        other => panic!("{other:?}"),
    }
    // Clearing the hit counters works and is visible.
    scene.instance_hits.write(0, &[1u32, 2, 3, 4]).unwrap();
    one_shot
        .run(|rec| feedback.record_clear_instance_hits(rec, &fb))
        .unwrap();
    assert_eq!(scene.instance_hits.read::<u32>(0, 4).unwrap(), vec![0; 4]);
    assert_no_validation_errors(&h);
}

pub fn readback_ring_waits_for_the_gpu_wraps_and_never_blocks() {
    let h = headless("readback_ring_waits_for_the_gpu_wraps_and_never_blocks");
    let ctx = h.context();
    let capacity = 8u32;
    let mut ring = CommandReadbackRing::new(ctx, 3, capacity).unwrap();
    assert!(CommandReadbackRing::new(ctx, 0, 8).is_err());
    assert!(CommandReadbackRing::new(ctx, 3, 0).is_err());
    let gate = TimelineSemaphore::new(ctx, 0).unwrap();
    let mut submitter = FrameSubmitter::new(ctx, 4).unwrap();
    let usage = STORAGE | vk::BufferUsageFlags::TRANSFER_SRC;
    let host = MemoryLocation::CpuToGpu;
    // Three frames' command buffers and counters: 5 commands, exactly full,
    // and overflowing by 4.
    let frames: Vec<(Vec<u32>, u32)> = vec![
        ((100..108).collect(), 5),
        ((200..208).collect(), 8),
        ((300..308).collect(), 12),
        ((400..408).collect(), 3),
    ];
    let buffers: Vec<(Buffer, Buffer)> = frames
        .iter()
        .map(|(w, c)| {
            (
                Buffer::with_data(ctx, usage, host, w).unwrap(),
                Buffer::with_data(ctx, usage, host, &[*c]).unwrap(),
            )
        })
        .collect();
    // Frames 1..=3 wait on a gate the host has not opened yet.
    let mut tickets = Vec::new();
    let sem = ring.semaphore().clone();
    for (commands, counter) in &buffers[..3] {
        let value = ring.semaphore().value().unwrap() + tickets.len() as u64 + 1;
        let t = submitter
            .submit(&[(&gate, 1)], &[(&sem, value)], |rec| {
                ring.record_copy(rec, commands, counter)
            })
            .unwrap();
        assert_eq!(t.value, value);
        tickets.push(t);
    }
    assert_eq!(
        tickets.iter().map(|t| t.slot).collect::<Vec<_>>(),
        [0, 1, 2]
    );
    // Nothing is readable while the GPU is held back, and asking does not
    // wait (the gate is opened only below; a blocking read would hang here).
    for t in &tickets {
        assert_eq!(ring.pending(t.slot), Some(t.value));
        assert!(ring.try_read(t.slot).unwrap().is_none());
    }
    // The ring is full of unread frames: a fourth copy is refused, nothing lost.
    let refused = submitter.submit(&[], &[], |rec| {
        ring.record_copy(rec, &buffers[3].0, &buffers[3].1)
    });
    assert!(matches!(
        refused,
        Err(VkError::ReadbackSlotBusy { slot: 0, value: 1 })
    ));
    gate.signal(1).unwrap();
    let start = std::time::Instant::now();
    let mut got = [None, None, None];
    while got.iter().any(Option::is_none) {
        for (i, t) in tickets.iter().enumerate() {
            if got[i].is_none() {
                got[i] = ring.try_read(t.slot).unwrap();
            }
        }
        assert!(
            start.elapsed() < std::time::Duration::from_secs(30),
            "GPU never finished"
        );
        std::thread::yield_now();
    }
    for (i, r) in got.iter().enumerate() {
        let r = r.as_ref().unwrap();
        let (words, counter) = &frames[i];
        assert_eq!(r.value(), tickets[i].value);
        assert_eq!(r.counter(), *counter);
        let stored = (*counter).min(capacity) as usize;
        assert_eq!(r.words(), &words[..stored]);
        assert_eq!(r.overflowed(), counter.saturating_sub(capacity));
        assert_eq!(r.is_full(), *counter >= capacity);
        // Read once: the slot is free again.
        assert!(ring.try_read(tickets[i].slot).unwrap().is_none());
        assert_eq!(ring.pending(tickets[i].slot), None);
    }
    // The ring wraps to slot 0 with the next value.
    assert_eq!(ring.next_slot(), 0);
    let t = submitter
        .submit(&[], &[(&sem, 4)], |rec| {
            ring.record_copy(rec, &buffers[3].0, &buffers[3].1)
        })
        .unwrap();
    assert_eq!((t.slot, t.value), (0, 4));
    submitter.wait_idle().unwrap();
    let r = read_when_ready(&mut ring, 0);
    assert_eq!((r.counter(), r.words()), (3, &[400, 401, 402][..]));
    assert!(ring.try_read(3).is_err());
    assert_no_validation_errors(&h);
}

/// Runs Algorithm 2 once on both sides with room for every command and
/// asserts identical outcomes; returns the CPU's command words.
fn feedback_once_exact(
    h: &lipac_vk::HeadlessContext,
    instances: &[InstanceRecord],
    hits: &[u32],
    hitboxes: &[HitboxRecord],
    th: &Thresholds,
    what: &str,
) -> Vec<u32> {
    let ctx = h.context();
    let feedback = FeedbackPipeline::new(ctx).unwrap();
    let index = Grid {
        nx: hitboxes.len() as u32,
        nz: 1,
        origin: Vec2::ZERO,
        size: 1.0,
    };
    let capacity = instances.len().max(1) as u32;
    let scene = Scene::new(ctx, instances, hits, hitboxes, &index, capacity);
    let fb = scene.feedback_bindings(&feedback);
    let (mut cpu_inst, mut cpu_hb) = (instances.to_vec(), hitboxes.to_vec());
    let mut buf = CommandBuffer::new(capacity);
    let mut rates = vec![0u32; instances.len()];
    cpu_feedback_with_rates(&mut cpu_inst, hits, &mut rates, &mut cpu_hb, th, &mut buf).unwrap();
    OneShot::new(ctx)
        .unwrap()
        .run(|rec| feedback.record(rec, &fb, th, instances.len() as u32))
        .unwrap();
    let (counter, words) = scene.read_commands(capacity);
    assert_eq!(counter, buf.requested(), "{what}");
    let gpu_rates: Vec<u32> = scene.instance_rates.read(0, instances.len()).unwrap();
    assert_eq!(gpu_rates, rates, "{what}: rates");
    assert_eq!(sorted(words), sorted(buf.words().to_vec()), "{what}");
    assert_instances_equal(&scene.read_instances(instances.len()), &cpu_inst, what);
    assert_hitboxes_equal(&scene.read_hitboxes(hitboxes.len()), &cpu_hb, what);
    buf.words().to_vec()
}

/// Lines 7–13 for every (active, streak, hits near each threshold)
/// combination, with streak lengths at their extremes too.
pub fn hitbox_transitions_match_exhaustively() {
    let h = headless("hitbox_transitions_match_exhaustively");
    for th in [
        feedback_thresholds(),
        Thresholds {
            n_a: 1,
            n_d: 127,
            ..feedback_thresholds()
        },
        Thresholds {
            n_a: 127,
            n_d: 1,
            ..Thresholds::paper()
        },
    ] {
        let mut hitboxes = Vec::new();
        for active in [0, 1] {
            for streak in 0..=hitbox_bits::STREAK_MAX {
                for base in [
                    0,
                    th.theta_d,
                    th.theta_a,
                    2 * th.theta_a,
                    hitbox_bits::HITS_MAX - 1,
                ] {
                    for hits in base.saturating_sub(1)..=base + 1 {
                        let mut r = HitboxRecord {
                            packed: active | (streak << hitbox_bits::STREAK_SHIFT),
                            ..Default::default()
                        };
                        r.add_hits(hits);
                        hitboxes.push(r);
                    }
                }
            }
        }
        // One dead instance: nothing but the hitbox pass does anything.
        let dead = InstanceRecord::default();
        let words = feedback_once_exact(&h, &[dead], &[0], &hitboxes, &th, &format!("{th:?}"));
        assert!(words.is_empty());
    }
    assert_no_validation_errors(&h);
}

/// The decayed rule's hitbox pass on every combination of state, rate and
/// hits around each threshold, cost words included (saturated counts, the
/// largest threshold a validated rule allows).
pub fn decayed_hitbox_transitions_match_exhaustively() {
    let h = headless("decayed_hitbox_transitions_match_exhaustively");
    for (what, th) in [
        ("decayed", decayed_thresholds()),
        ("decayed, rise shift 2 of 3", decayed_rise_thresholds()),
    ] {
        decayed_hitbox_transitions(&h, &th, what);
    }
    assert_no_validation_errors(&h);
}

fn decayed_hitbox_transitions(h: &lipac_vk::HeadlessContext, th: &Thresholds, what: &str) {
    let DecisionRule::Decayed(rule) = th.rule else {
        unreachable!()
    };
    let mut hitboxes = Vec::new();
    for active in [0, 1] {
        for cost in [0, 3, 0x0002_0005, 0xFFFF_FFFF, 0x0100_0100] {
            let need = rule.activation_threshold((cost & 0xFFFF).min(255), (cost >> 16).min(255));
            // Rates around the thresholds, and around this frame's hits in
            // 16.16 (where the rise shift takes over from the decay shift).
            for rate_base in [
                0,
                rule.deactivate,
                need,
                u32::MAX - 2,
                30 * RATE_ONE,
                0xFFFF * RATE_ONE,
            ] {
                for rate in rate_base.saturating_sub(2)..=rate_base.saturating_add(2) {
                    for hits in [0, 1, 29, 30, 31, 0xFFFF, 0x10000, hitbox_bits::HITS_MAX] {
                        let mut r = HitboxRecord {
                            packed: active | (5 << hitbox_bits::STREAK_SHIFT),
                            rate,
                            cost,
                            ..Default::default()
                        };
                        r.add_hits(hits);
                        hitboxes.push(r);
                    }
                }
            }
        }
    }
    let dead = InstanceRecord::default();
    let words = feedback_once_exact(h, &[dead], &[0], &hitboxes, th, what);
    assert!(words.is_empty());
}

/// Command words for hit counts at every priority step (and ±1 around it),
/// so the shader's integer log2 must agree with `priority_from_hits` exactly.
pub fn command_priorities_match_at_every_boundary() {
    let h = headless("command_priorities_match_at_every_boundary");
    use lipac_core::command::priority_from_hits;
    use lipac_core::layout::InstanceState;
    // Smallest hit count of each priority (priority is monotone in hits).
    let mut counts = vec![0u32, 1, 2, u32::MAX - 1, u32::MAX];
    for p in 1..=127u8 {
        let (mut lo, mut hi) = (0u64, u64::from(u32::MAX) + 1);
        while lo < hi {
            let mid = (lo + hi) / 2;
            if priority_from_hits(mid as u32) >= p {
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        if lo <= u64::from(u32::MAX) {
            let b = lo as u32;
            counts.extend([b.saturating_sub(1), b, b.saturating_add(1)]);
        }
    }
    // Active unique instances (BLAS built) emit `remove` with their hits when
    // below σo; omitted unique ones emit `add` when above σa.
    let th = Thresholds {
        theta_a: 4,
        theta_d: 1,
        sigma_a: (1 << 31) + 1,
        sigma_o: 1 << 31,
        n_a: 1,
        n_d: 1,
        rule: DecisionRule::Paper,
    };
    let mut instances = Vec::new();
    let mut hits = Vec::new();
    for &c in &counts {
        for state in [InstanceState::Active, InstanceState::Omitted] {
            let mut r = InstanceRecord {
                packed: instance_bits::ALIVE | instance_bits::UNIQUE_BLAS,
                blas: 0xB1A5,
                ..Default::default()
            };
            r.set_state(state);
            instances.push(r);
            hits.push(c);
        }
    }
    let hitboxes = [HitboxRecord {
        packed: hitbox_bits::ACTIVE,
        ..Default::default()
    }];
    let words = feedback_once_exact(&h, &instances, &hits, &hitboxes, &th, "priorities");
    let priorities: BTreeSet<u32> = words.iter().map(|w| w >> 25).collect();
    let missing: Vec<u32> = (0..128).filter(|p| !priorities.contains(p)).collect();
    // floor(4·log2(x)) skips 1, 2, 3 (x = 1 -> 0, x = 2 -> 4), 5 (x = 3 -> 6)
    // and 7 (x = 4 -> 8); every other priority occurs.
    assert_eq!(missing, [1, 2, 3, 5, 7], "priorities never emitted");
    assert_no_validation_errors(&h);
}

/// The GPU-assembled buffer is a valid TLAS build input in the same command
/// buffer (assembly's final barrier covers the build), and rays count the
/// boxes it made: the omitted instance's box into its slot, the inactive
/// hitbox's box into the hitbox, while the active instance is hit.
pub fn assembled_tlas_builds_and_counts_boxes() {
    let h = headless("assembled_tlas_builds_and_counts_boxes");
    use lipac_core::layout::{InstanceState, VK_INSTANCE_CULL_DISABLE};
    use lipac_vk::{BlasBatch, CountingBoxConfig, GpuRay, GpuTlas, ScratchBuffer, UnitCube};
    let ctx = h.context();
    let quad = GpuMesh::new(&h, Mesh::quad());
    let cube = UnitCube::new(ctx).unwrap();
    let mut batch = BlasBatch::new();
    let flags = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE;
    batch.push(&[quad.geometry()], flags).unwrap();
    batch.push(&[cube.geometry()], flags).unwrap();
    let mut scratch = ScratchBuffer::new(ctx);
    let mut one_shot = OneShot::new(ctx).unwrap();
    let built = one_shot.run(|rec| batch.record(rec, &mut scratch)).unwrap();
    let (quad_blas, cube_blas) = (&built.blases[0], &built.blases[1]);

    // Cells of 10 m along x: 0 and 1 active, 2 inactive (3 has no bounds).
    let index = Grid {
        nx: 4,
        nz: 1,
        origin: Vec2::new(-5.0, -5.0),
        size: 10.0,
    };
    let record = |state, hitbox, min: [f32; 3], max: [f32; 3]| {
        let mut r = InstanceRecord {
            transform: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 5.0],
            aabb_min: min,
            aabb_max: max,
            hitbox,
            packed: instance_bits::ALIVE
                | (0x01 << instance_bits::MASK_SHIFT)
                | (u32::from(VK_INSTANCE_CULL_DISABLE) << instance_bits::VK_FLAGS_SHIFT),
            blas: quad_blas.device_address(),
            sbt_offset: 0,
            lod: 0,
        };
        r.set_state(state);
        r
    };
    let mut dead = record(InstanceState::Active, 0, [0.0; 3], [1.0; 3]);
    dead.packed &= !instance_bits::ALIVE;
    let instances = [
        record(InstanceState::Active, 0, [-1.0, -1.0, 5.0], [1.0, 1.0, 5.0]),
        record(
            InstanceState::Omitted,
            1,
            [9.5, -0.5, 2.0],
            [10.5, 0.5, 3.0],
        ),
        record(
            InstanceState::Inactive,
            2,
            [19.0, 0.0, -1.0],
            [21.0, 4.0, 1.0],
        ),
        dead,
    ];
    let active = HitboxRecord {
        packed: hitbox_bits::ACTIVE,
        ..Default::default()
    };
    let mut hitboxes = [active, active, HitboxRecord::default(), active];
    // The extents are the CPU's; the GPU gets them with the records.
    write_extents(&arrays(&instances), &mut hitboxes);
    let counting = CountingBoxConfig::default();
    let cfg = AssemblyConfig {
        unit_cube_blas: cube_blas.device_address(),
        counting_mask: counting.counting_mask,
        omitted_box_sbt_offset: counting.omitted_box_sbt_offset,
        hitbox_sbt_offset: counting.hitbox_box_sbt_offset,
        min_box_extent: 1e-3,
    };
    let scene = Scene::new(ctx, &instances, &[0; 4], &hitboxes, &index, 1);
    let assembly = AssemblyPipeline::new(ctx).unwrap();
    let ab = scene.assembly_bindings(&assembly);
    let mut tlas = GpuTlas::new(ctx, 2, flags).unwrap();
    let _retired = one_shot
        .run(|rec| {
            assembly.record(rec, &ab, &cfg, 4)?;
            tlas.record_build(rec, &scene.tlas_out, 0, ab.tlas_capacity(), &mut scratch)
        })
        .unwrap();
    let (counter, _) = scene.read_tlas(ab.tlas_capacity() as usize);
    assert_eq!(counter, 3, "quad, omitted box, hitbox box");

    let rays = [
        GpuRay {
            origin: [0.0, 0.0, -10.0],
            t_min: 0.0,
            direction: [0.0, 0.0, 1.0],
            t_max: 100.0,
        },
        GpuRay {
            origin: [10.0, 0.0, -10.0],
            t_min: 0.0,
            direction: [0.0, 0.0, 1.0],
            t_max: 100.0,
        },
        GpuRay {
            origin: [20.0, 10.0, 0.0],
            t_min: 0.0,
            direction: [0.0, -1.0, 0.0],
            t_max: 100.0,
        },
    ];
    let pipeline = TestTracer::preferred(&h, &counting);
    let out = trace_tlas(&h, &pipeline, &tlas, &rays, 0xFF, 4);
    let hits = out.hits;
    assert!(hits[0].is_hit() && hits[0].custom_index == 0);
    assert!((hits[0].t - 15.0).abs() < 1e-4);
    assert!(!hits[1].is_hit() && hits[1].counted_box());
    assert!(!hits[2].is_hit() && hits[2].counted_box());
    // The committed quad hit counts for slot 0 (trace_test counts real hits).
    assert_eq!(out.instance_hits, [1, 1, 0, 0]);
    assert_eq!(out.hitbox_hits, [0, 0, 1, 0]);
    assert_no_validation_errors(&h);
}
