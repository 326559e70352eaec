//! Algorithms 1 and 2 (CPU reference) against a memory-bandwidth baseline.
//!
//! Synthetic scene: `n` instance slots, ~16 instances per hitbox on a square
//! grid of 16 m cells, a quarter of the hitboxes active, a mix of states
//! (including a few percent of instances that change state this frame) and
//! 1% dead slots. The baseline streams the 96-byte instance records and hit
//! counters once (read + write, `copy_from_slice`, 100 B per instance), i.e.
//! the bytes both algorithms touched at least once before the hot/cold
//! split; the algorithms run over the split arrays ([`InstanceArrays`]:
//! Algorithm 2 reads the 8-byte hot record and the hit counter, Algorithm 1
//! the hot record and the TLAS record (or, omitted, the bounds) of emitted
//! slots; the counting boxes' heights are the CPU's hitbox extents, computed
//! once (`write_extents`, also timed); `docs/HOT_COLD.md`). Algorithm 2's input is restored and a
//! 64 MiB buffer streamed before each timed run ([`evict`]), so that it
//! starts from memory, not from the cache the restore filled. The
//! `floor_*` benches time what the algorithms cannot avoid, nothing
//! decided: Algorithm 1's emitted TLAS records copied (or, for a TLAS built
//! from an array of pointers, their addresses written), Algorithm 2's line
//! 4 (docs/BENCHMARKS.md, "Floors").
//!
//! `cargo bench -p lipac-core --bench algorithms`

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::{Vec2, Vec3};
use lipac_core::assembly::{assemble_tlas, AssemblyConfig};
use lipac_core::command::CommandBuffer;
use lipac_core::feedback::{process_feedback, process_feedback_with_rates};
use lipac_core::hitbox_extents::write_extents;
use lipac_core::hitbox_index::HitboxIndex;
use lipac_core::layout::{
    hitbox_bits, instance_bits, HitboxRecord, InstanceArrays, InstanceRecord, InstanceState,
    TlasInstance,
};
use lipac_core::thresholds::{
    DecayedSettings, DecisionRule, Thresholds, RATE_ONE, REFERENCE_RAYS_PER_FRAME,
};
use lipac_test_support::{Rng64, XorShift64};

const CELL: f32 = 16.0;

/// Square grid of `w * w` cells.
struct Grid {
    w: u32,
}

impl HitboxIndex for Grid {
    fn len(&self) -> u32 {
        self.w * self.w
    }
    fn hitbox_at(&self, p: Vec3) -> Option<u32> {
        let (x, z) = ((p.x / CELL).floor(), (p.z / CELL).floor());
        let w = self.w as f32;
        (x >= 0.0 && z >= 0.0 && x < w && z < w).then(|| z as u32 * self.w + x as u32)
    }
    fn xz_bounds(&self, i: u32) -> Option<(Vec2, Vec2)> {
        (i < self.len()).then(|| {
            let lo = Vec2::new((i % self.w) as f32, (i / self.w) as f32) * CELL;
            (lo, lo + Vec2::splat(CELL))
        })
    }
}

struct Rng(XorShift64);

impl Rng {
    fn next(&mut self) -> u32 {
        self.0.next_u32()
    }
    /// True with probability `p`.
    fn chance(&mut self, p: f32) -> bool {
        (self.next() as f32) < p * u32::MAX as f32
    }
    fn unit(&mut self) -> f32 {
        self.next() as f32 / u32::MAX as f32
    }
}

struct Scene {
    grid: Grid,
    instances: Vec<InstanceRecord>,
    arrays: InstanceArrays,
    hits: Vec<u32>,
    hitboxes: Vec<HitboxRecord>,
}

fn scene(n: usize) -> Scene {
    let w = ((n as f64 / 16.0).sqrt().ceil() as u32).max(1);
    let grid = Grid { w };
    let mut rng = Rng(XorShift64::new(0x9E37_79B9_7F4A_7C15 ^ n as u64));
    let hitboxes: Vec<HitboxRecord> = (0..grid.len())
        .map(|_| {
            let mut h = HitboxRecord::default();
            if rng.chance(0.25) {
                h.packed = hitbox_bits::ACTIVE;
            }
            h
        })
        .collect();
    let mut instances = Vec::with_capacity(n);
    let mut hits = Vec::with_capacity(n);
    for slot in 0..n {
        // Mostly spatially coherent slots (allocation order), some scattered.
        let hb = if rng.chance(0.9) {
            (slot / 16) as u32 % grid.len()
        } else {
            rng.next() % grid.len()
        };
        let (lo, _) = grid.xz_bounds(hb).unwrap();
        let p = Vec3::new(lo.x + rng.unit() * 14.0, 0.0, lo.y + rng.unit() * 14.0);
        let size = Vec3::new(1.0 + rng.unit(), 2.0 + 8.0 * rng.unit(), 1.0 + rng.unit());
        let unique = rng.chance(0.15);
        let active_hb = hitboxes[hb as usize].is_active();
        let r = rng.unit();
        let state = match (active_hb, unique) {
            (true, false) if r < 0.95 => InstanceState::Active,
            (true, true) if r < 0.6 => InstanceState::Omitted,
            (true, true) if r < 0.95 => InstanceState::Active,
            (false, _) if r < 0.01 => InstanceState::Active, // will be removed
            _ => InstanceState::Inactive,
        };
        let mut packed = instance_bits::ALIVE | (0xFF << instance_bits::MASK_SHIFT);
        if unique {
            packed |= instance_bits::UNIQUE_BLAS;
        }
        if rng.chance(0.01) {
            packed &= !instance_bits::ALIVE;
        }
        let mut m = InstanceRecord {
            transform: [1.0, 0.0, 0.0, p.x, 0.0, 1.0, 0.0, p.y, 0.0, 0.0, 1.0, p.z],
            aabb_min: p.to_array(),
            aabb_max: (p + size).to_array(),
            hitbox: hb,
            packed,
            blas: if rng.chance(0.98) {
                0x1000 + slot as u64 * 256
            } else {
                0
            },
            sbt_offset: 0,
            lod: 0,
        };
        m.set_state(state);
        instances.push(m);
        // Most instances get a few hits, one in twenty a lot.
        hits.push(match state {
            InstanceState::Inactive => 0,
            _ if rng.chance(0.05) => rng.next() % 2000,
            _ => rng.next() % 64,
        });
    }
    Scene {
        grid,
        arrays: InstanceArrays::from_records(&instances),
        instances,
        hits,
        hitboxes,
    }
}

/// Bytes [`evict`] streams: twice the 32 MiB L3 of the measuring machine.
const EVICT_BYTES: usize = 64 << 20;

/// Streams `buf` (read and write) so that the next timed iteration finds the
/// frame's buffers out of the cache, as after a frame of other work.
fn evict(buf: &mut [u64]) {
    for (i, x) in buf.iter_mut().enumerate() {
        *x = x.wrapping_add(i as u64);
    }
    black_box(buf);
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("algorithms");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
    let cfg = AssemblyConfig::new(0xC0BE);
    let th = Thresholds::paper();
    for n in [10_000usize, 100_000, 1_000_000] {
        let s = scene(n);
        group.throughput(Throughput::Elements(n as u64));

        // Baseline: stream the instance records and hit counters once.
        let mut dst_i = s.instances.clone();
        let mut dst_h = s.hits.clone();
        group.bench_function(BenchmarkId::new("baseline_copy", n), |b| {
            b.iter(|| {
                dst_i.copy_from_slice(black_box(&s.instances));
                dst_h.copy_from_slice(black_box(&s.hits));
                black_box((&dst_i, &dst_h));
            })
        });

        // The hitbox extents are the CPU's, kept where instances change
        // (`hitbox_extents`); the frame's records are unchanged, so they
        // are computed once. `write_extents` is what recomputing all of
        // them costs (the per-slot reduction Algorithm 1 did before).
        let mut hitboxes = s.hitboxes.clone();
        write_extents(&s.arrays, &mut hitboxes);
        let mut extents_out = hitboxes.clone();
        group.bench_function(BenchmarkId::new("write_extents", n), |b| {
            b.iter(|| write_extents(black_box(&s.arrays), &mut extents_out))
        });
        drop(extents_out);
        let mut out = Vec::with_capacity(n);
        group.bench_function(BenchmarkId::new("assemble_tlas", n), |b| {
            b.iter(|| {
                let st =
                    assemble_tlas(black_box(&s.arrays), &mut hitboxes, &s.grid, &cfg, &mut out)
                        .unwrap();
                black_box((st, out.len()))
            })
        });

        // Floor: what Algorithm 1 cannot avoid, nothing decided
        // (docs/BENCHMARKS.md, "Floors"): the emitted slots' TLAS records
        // copied as they are laid out (`InstanceTlas`, 64 B, one line each);
        // the slot list is made outside the timing.
        let hot = s.arrays.hot();
        let emitted: Vec<u32> = (0u32..)
            .zip(hot)
            .filter(|(_, m)| {
                m.is_alive() && (m.is_pinned() || m.state() != InstanceState::Inactive)
            })
            .map(|(slot, _)| slot)
            .collect();
        let ready = s.arrays.tlas();
        let mut floor_out: Vec<TlasInstance> = Vec::with_capacity(emitted.len());
        group.bench_function(BenchmarkId::new("floor_assemble_ready", n), |b| {
            b.iter(|| {
                floor_out.clear();
                floor_out.extend(
                    black_box(&emitted)
                        .iter()
                        .map(|&slot| ready[slot as usize].record),
                );
                black_box(floor_out.len())
            })
        });

        // The same floor for a TLAS built from an array of pointers
        // (`arrayOfPointers`): the device address of each emitted slot's
        // TLAS-ready record, 8 bytes written, the record neither read nor
        // copied (docs/BENCHMARKS.md, "Both goals against the passes as
        // they are").
        const RECORDS_ADDRESS: u64 = 0x1_0000_0000;
        let record_bytes = std::mem::size_of::<TlasInstance>() as u64;
        let mut floor_pointers: Vec<u64> = Vec::with_capacity(emitted.len());
        group.bench_function(BenchmarkId::new("floor_assemble_pointers", n), |b| {
            b.iter(|| {
                floor_pointers.clear();
                floor_pointers.extend(
                    black_box(&emitted)
                        .iter()
                        .map(|&slot| RECORDS_ADDRESS + u64::from(slot) * record_bytes),
                );
                black_box(floor_pointers.len())
            })
        });

        // Counting-box hits of the frame, on top of the reset hitboxes.
        let mut start_hitboxes = s.hitboxes.clone();
        for (i, h) in start_hitboxes.iter_mut().enumerate() {
            // A few inactive hitboxes get enough box hits to activate at once,
            // others start or extend a streak.
            let x = (i as u32).wrapping_mul(2_654_435_761) >> 20; // 0..4096
            h.add_hits(if h.is_active() {
                0
            } else if x < 40 {
                2500
            } else {
                x % 1100
            });
        }
        let start_hot = s.arrays.hot().to_vec();
        let mut instances = start_hot.clone();
        let mut hitboxes = start_hitboxes.clone();
        let mut commands = CommandBuffer::new(n as u32);
        let mut flush = vec![0u64; EVICT_BYTES / 8];
        group.bench_function(BenchmarkId::new("process_feedback", n), |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    // Restore the frame's input state (not timed).
                    instances.copy_from_slice(&start_hot);
                    hitboxes.copy_from_slice(&start_hitboxes);
                    commands.clear();
                    evict(&mut flush);
                    let t = Instant::now();
                    let st = process_feedback(
                        &mut instances,
                        black_box(&s.hits),
                        &mut hitboxes,
                        &th,
                        &mut commands,
                    )
                    .unwrap();
                    total += t.elapsed();
                    black_box(st);
                }
                total
            })
        });

        // Floor of Algorithm 2: line 4 alone (every slot's hit counter
        // read, the hits of slots that have any added to their hitbox's
        // sum), from memory as above.
        let mut sums = vec![0u32; s.hitboxes.len()];
        group.bench_function(BenchmarkId::new("floor_feedback", n), |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    instances.copy_from_slice(&start_hot);
                    sums.fill(0);
                    evict(&mut flush);
                    let t = Instant::now();
                    for (m, &h) in instances.iter().zip(black_box(&s.hits)) {
                        if h != 0 {
                            if let Some(x) = sums.get_mut(m.hitbox as usize) {
                                *x = x.wrapping_add(h);
                            }
                        }
                    }
                    total += t.elapsed();
                    black_box(&sums);
                }
                total
            })
        });

        // The same frame under the decayed rule with the sim's default
        // settings (lipac-sim `LipacConfig::DEFAULT_DECAYED`) at 1080p:
        // active hitboxes start at a rate between the thresholds, inactive
        // ones at 0 (the 2500-hit boxes activate); unique slots' rates start
        // at their hits of this frame.
        let decayed = DecayedSettings {
            half_life_frames: 5.0,
            activate: 150.0,
            deactivate: 30.0,
            instance_activate: 150.0,
            instance_omit: 30.0,
            per_shared: 0.0,
            per_unique: 0.0,
            rise_shift: None,
        }
        .rule_for_rays_per_frame(REFERENCE_RAYS_PER_FRAME)
        .unwrap();
        let th_decayed = th.with_rule(DecisionRule::Decayed(decayed));
        let mut start_hitboxes_decayed = start_hitboxes.clone();
        for h in &mut start_hitboxes_decayed {
            h.rate = if h.is_active() { 100 * RATE_ONE } else { 0 };
        }
        let start_rates: Vec<u32> = s.hits.iter().map(|&h| h.min(0xFFFF) << 16).collect();
        let mut rates = start_rates.clone();
        group.bench_function(BenchmarkId::new("process_feedback_decayed", n), |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    instances.copy_from_slice(&start_hot);
                    hitboxes.copy_from_slice(&start_hitboxes_decayed);
                    rates.copy_from_slice(&start_rates);
                    commands.clear();
                    evict(&mut flush);
                    let t = Instant::now();
                    let st = process_feedback_with_rates(
                        &mut instances,
                        black_box(&s.hits),
                        &mut rates,
                        &mut hitboxes,
                        &th_decayed,
                        &mut commands,
                    )
                    .unwrap();
                    total += t.elapsed();
                    black_box(st);
                }
                total
            })
        });

        // Report what the synthetic frame does (once, outside timing).
        let mut i2 = start_hot.clone();
        let mut h2 = start_hitboxes.clone();
        let mut c2 = CommandBuffer::new(n as u32);
        let fs = process_feedback(&mut i2, &s.hits, &mut h2, &th, &mut c2).unwrap();
        let mut h3 = s.hitboxes.clone();
        write_extents(&s.arrays, &mut h3);
        let as_ = assemble_tlas(&s.arrays, &mut h3, &s.grid, &cfg, &mut Vec::new()).unwrap();
        let (mut i4, mut h4, mut r4) = (
            start_hot.clone(),
            start_hitboxes_decayed.clone(),
            start_rates.clone(),
        );
        let mut c4 = CommandBuffer::new(n as u32);
        let fd =
            process_feedback_with_rates(&mut i4, &s.hits, &mut r4, &mut h4, &th_decayed, &mut c4)
                .unwrap();
        eprintln!(
            "n = {n}: {as_:?}\n         {fs:?}, commands {}\n         decayed: {fd:?}, commands {}",
            c2.stored(),
            c4.stored()
        );
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
