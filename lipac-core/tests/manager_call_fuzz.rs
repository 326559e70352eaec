//! Random `Manager` call sequences with invariant checks after every call.
//!
//! Each case builds a manager with a random configuration and catalog, then
//! makes random calls: mostly the frame loop in order (begin, read-back,
//! churn, latency mitigation, plan, acknowledgements, assemble, feedback,
//! take), mixed with calls out of order, stale, foreign and default
//! handles, invalid descriptions, meshes and LODs, garbage read-backs,
//! unknown, duplicate and corrupt acknowledgements, and frames that go
//! backwards or past `MAX_FRAME`. After every call:
//!
//! * a refused call changed nothing (a snapshot of statistics, instance
//!   views, records, scheduler and allocations compares equal; `register`
//!   may only have grown the data buffer, as documented), and no call
//!   reports [`ManagerError::Invariant`];
//! * statistics agree with the model: live instances, data ranges and
//!   bytes, slots (`live + free + quarantined = slot_count`, no handle or
//!   slot leaked), the data allocator's used bytes are the sum of its live
//!   ranges, which tile within the capacity without overlap;
//! * BLAS memory accounting equals the backend's: bytes of the structures
//!   the backend holds plus the reservations of operations in flight are
//!   `blas_shared + blas_unique + blas_compacted + blas_pending_free`, and
//!   the budget holds;
//! * every TLAS and every free names a live structure; no structure is
//!   freed while a frame in flight may use it.
//!
//! At the end everything is removed, every acknowledgement delivered and
//! the frames in flight passed: nothing may be left allocated.
//!
//! Runs `LIPAC_FUZZ_CASES` cases (default 16) of `LIPAC_FUZZ_CALLS` calls
//! (default 1000), about two seconds in debug. Long run, e.g.:
//! `LIPAC_FUZZ_CASES=5000 LIPAC_FUZZ_CALLS=2000 cargo test -p lipac-core --profile release-checked --test manager_call_fuzz`
//! (`release-checked`: optimised, with overflow checks and debug
//! assertions; see the workspace `Cargo.toml`). A failure
//! prints its case seed; `LIPAC_FUZZ_SEED=<seed>` replays that case alone.

use std::collections::HashMap;

use glam::{Affine3A, Vec3};
use lipac_core::blas_cache::{CacheConfig, MAX_BLAS_BYTES, MAX_FRAME};
use lipac_core::blas_ids::BuildId;
use lipac_core::build_plan::{BuildBudgets, BuildEstimate, SchedulerConfig, SchedulerStats};
use lipac_core::culling::ReadbackRing;
use lipac_core::instance::{InstanceDesc, InstanceFlags, MeshId};
use lipac_core::latency::{ActivationHeuristic, Frustum};
use lipac_core::layout::{InstanceRecord, TlasInstance};
use lipac_core::manager::{
    DataConfig, FrameBudgets, InstanceView, Manager, ManagerConfig, ManagerError, ManagerPlan,
    ManagerStats, MeshCatalog, MeshLod,
};
use lipac_core::math::Aabb;
use lipac_core::registry::InstanceHandle;
use lipac_core::thresholds::{DecayedRule, DecisionRule, Thresholds, RATE_ONE};
use lipac_test_support::scene::{frustums, random_instance, world_grid, WORLD};
use lipac_test_support::synthetic::{Owed, SyntheticDevice};
use lipac_test_support::{Rng64, SplitMix64 as Rng};

/// The three acknowledgements as calls, each sent through
/// [`Manager::handle_ack`] (the only acknowledgement entry point).
trait SendAck {
    fn send_built(&mut self, build: BuildId, bytes: u64, address: u64) -> Result<(), ManagerError>;
    fn send_compacted_size(&mut self, build: BuildId, bytes: u64) -> Result<(), ManagerError>;
    fn send_compacted(&mut self, op: BuildId, address: u64) -> Result<(), ManagerError>;
}

impl SendAck for Manager {
    fn send_built(&mut self, build: BuildId, bytes: u64, address: u64) -> Result<(), ManagerError> {
        self.handle_ack(lipac_core::Ack::Built {
            build,
            result_bytes: bytes,
            address,
        })
    }
    fn send_compacted_size(&mut self, build: BuildId, bytes: u64) -> Result<(), ManagerError> {
        self.handle_ack(lipac_core::Ack::CompactedSize {
            build,
            compacted_bytes: bytes,
        })
    }
    fn send_compacted(&mut self, op: BuildId, address: u64) -> Result<(), ManagerError> {
        self.handle_ack(lipac_core::Ack::Compacted { op, address })
    }
}

const CUBE: u64 = 0xC0BE;

fn env(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn mesh_lod(rng: &mut Rng) -> MeshLod {
    let tris = 50 + rng.below(2000);
    MeshLod {
        estimate: BuildEstimate {
            primitives: tris,
            result_bytes: tris * (20 + rng.below(40)),
            build_scratch_bytes: tris * 8,
            update_scratch_bytes: tris * 2,
        },
        data_bytes: 1 + rng.below(300),
    }
}

/// A random LOD list; `valid` false makes it one the catalog must refuse.
fn mesh_lods(rng: &mut Rng, valid: bool) -> Vec<MeshLod> {
    let mut lods: Vec<MeshLod> = (0..1 + rng.below(3)).map(|_| mesh_lod(rng)).collect();
    if !valid {
        let l = &mut lods[0];
        match rng.below(5) {
            0 => l.data_bytes = 0,
            1 => l.data_bytes = u64::MAX - rng.below(3),
            2 => l.estimate.result_bytes = 0,
            3 => l.estimate.result_bytes = MAX_BLAS_BYTES + 1 + rng.below(1 << 40),
            _ => lods.clear(),
        }
    }
    lods
}

fn random_desc(rng: &mut Rng, meshes: &HashMap<MeshId, usize>) -> InstanceDesc {
    let mut lods: Vec<(MeshId, u32)> = meshes.iter().map(|(&m, &n)| (m, n as u32)).collect();
    lods.sort_by_key(|m| m.0 .0);
    random_instance(rng, &lods)
}

/// Makes a valid description invalid in one of several ways.
fn corrupt(rng: &mut Rng, d: &mut InstanceDesc) {
    match rng.below(5) {
        0 => d.mesh = MeshId(10_000 + rng.below(5) as u32),
        1 => d.lod = 200 + rng.below(100) as u32,
        2 => d.transform = Affine3A::from_translation(Vec3::new(f32::NAN, 0.0, 0.0)),
        3 => {
            let c = Vec3::new(WORLD * 3.0, 0.0, -WORLD * 2.0);
            d.aabb = Aabb::new(c - Vec3::ONE, c + Vec3::ONE);
        }
        _ => d.aabb = Aabb::new(Vec3::ONE, Vec3::ZERO),
    }
}

/// The synthetic device and the acknowledgements it owes, delivered one at
/// a time in random order (and replayed as duplicates).
#[derive(Default)]
struct Backend {
    device: SyntheticDevice,
    owed: Vec<Owed>,
    /// Reserved bytes of builds and compactions handed out, not acked.
    in_flight: HashMap<BuildId, u64>,
    /// Acknowledgements already delivered (replayed as duplicates).
    delivered: Vec<Owed>,
    /// A build came out larger than its estimate: the budget may be
    /// overrun (by design: the structure exists).
    overran: bool,
    traced_with_blas: u64,
    ring: Option<ReadbackRing>,
    tlas: Vec<TlasInstance>,
}

impl Backend {
    fn execute(&mut self, plan: &ManagerPlan) {
        for owed in self.device.execute(plan) {
            if let Owed::Built { id, bytes, .. } | Owed::Compacted { id, bytes } = owed {
                assert!(self.in_flight.insert(id, bytes).is_none());
            }
            self.owed.push(owed);
        }
    }

    /// Delivers owed acknowledgement `i` (removing it); returns the
    /// manager's answer.
    fn deliver(&mut self, m: &mut Manager, i: usize, rng: &mut Rng) -> Result<(), ManagerError> {
        let owed = self.owed.swap_remove(i);
        let r = match owed {
            Owed::Built {
                id,
                bytes: reserved,
                compactable,
            } => {
                // Mostly at or below the estimate; now and then above it
                // (the cache then evicts, and may overrun its budget).
                let overrun = rng.chance_percent(5);
                let bytes = if overrun {
                    reserved + 1 + rng.below(reserved)
                } else {
                    (reserved - rng.below(reserved / 4 + 1)).max(1)
                };
                let built = Owed::Built {
                    id,
                    bytes,
                    compactable,
                };
                let r = self.device.acknowledge(m, built);
                if r.is_ok() {
                    self.overran |= overrun;
                    self.in_flight.remove(&id);
                    if compactable {
                        // Usually smaller; the cache clamps a larger answer.
                        let compacted = 1 + rng.below(bytes + bytes / 4);
                        self.owed.push(Owed::Size {
                            id,
                            bytes: compacted,
                        });
                    }
                }
                r
            }
            Owed::Size { .. } => self.device.acknowledge(m, owed),
            Owed::Compacted { id, .. } => {
                let r = self.device.acknowledge(m, owed);
                if r.is_ok() {
                    self.in_flight.remove(&id);
                }
                r
            }
        };
        if r.is_ok() {
            self.delivered.push(owed);
        } else {
            self.owed.push(owed);
        }
        r
    }

    fn in_flight_bytes(&self) -> u64 {
        self.in_flight.values().sum()
    }
}

/// What a refused call must leave unchanged.
#[derive(Debug, PartialEq)]
struct Snapshot {
    stats: ManagerStats,
    frame: Option<u64>,
    views: Vec<Option<InstanceView>>,
    records: Vec<InstanceRecord>,
    scheduler: SchedulerStats,
    ranges: Vec<(u64, u64)>,
    meshes: usize,
}

fn snapshot(m: &Manager, live: &[InstanceHandle], ignore_capacity: bool) -> Snapshot {
    let mut stats = m.stats();
    if ignore_capacity {
        let mem = &mut stats.memory;
        (mem.data_capacity, mem.data_free, mem.data_largest_free) = (0, 0, 0);
        mem.data_fragmentation = 0.0;
        stats.data_free_blocks = 0;
    }
    Snapshot {
        stats,
        frame: m.frame(),
        views: live.iter().map(|&h| m.instance(h).ok()).collect(),
        records: m.registry().records().to_vec(),
        scheduler: m.scheduler().stats(),
        ranges: m
            .data_allocator()
            .allocations()
            .map(|a| (a.offset, a.size))
            .collect(),
        meshes: m.catalog().len(),
    }
}

struct Case {
    rng: Rng,
    m: Manager,
    /// A second manager, whose handles must be foreign to `m`.
    other: Manager,
    be: Backend,
    live: Vec<InstanceHandle>,
    dead: Vec<InstanceHandle>,
    foreign: Vec<InstanceHandle>,
    /// Mesh -> number of LODs, as registered.
    meshes: HashMap<MeshId, usize>,
    next_mesh: u32,
    frame: u64,
    budget: u64,
    frustums: Vec<(Vec3, Frustum)>,
    calls: u64,
    /// Position in the frame loop the calls mostly follow.
    phase: usize,
    /// Print every call (`LIPAC_FUZZ_TRACE=1`).
    trace: bool,
    cover: Coverage,
}

/// What the calls reached, summed over the cases (so that a change that
/// makes every call fail early is noticed).
#[derive(Clone, Copy, Debug, Default)]
struct Coverage {
    ok: u64,
    refused: u64,
    registered: u64,
    removed: u64,
    frames: u64,
    builds_acked: u64,
    compactions_acked: u64,
    frees: u64,
    traced_with_blas: u64,
}

impl Coverage {
    fn add(&mut self, o: Coverage) {
        self.ok += o.ok;
        self.refused += o.refused;
        self.registered += o.registered;
        self.removed += o.removed;
        self.frames += o.frames;
        self.builds_acked += o.builds_acked;
        self.compactions_acked += o.compactions_acked;
        self.frees += o.frees;
        self.traced_with_blas += o.traced_with_blas;
    }
}

impl Case {
    fn new(seed: u64) -> Self {
        let mut rng = Rng::new(seed);
        let fif = 1 + rng.below(3) as u32;
        let latency = 1 + rng.below(2) as u32;
        let budget = 20_000 + rng.below(300_000);
        let mut config = ManagerConfig::new(CUBE);
        config.culling.thresholds = Thresholds {
            theta_a: 400,
            theta_d: 60,
            sigma_a: 300,
            sigma_o: 40,
            n_a: 2,
            n_d: 4,
            ..Thresholds::paper()
        };
        if rng.chance_percent(50) {
            config.culling.thresholds =
                config
                    .culling
                    .thresholds
                    .with_rule(DecisionRule::Decayed(DecayedRule {
                        shift: 2,
                        rise_shift: 1,
                        activate: 8 * RATE_ONE,
                        deactivate: 2 * RATE_ONE,
                        instance_activate: 4 * RATE_ONE,
                        instance_omit: RATE_ONE,
                        per_shared: 0,
                        per_unique: 0,
                    }));
        }
        config.culling.warm_start_hold = rng.below(6) as u32;
        config.culling.command_capacity = 4 + rng.below(30) as u32;
        config.culling.readback_latency = latency;
        config.culling.registry.quarantine_frames = latency + 1 + rng.below(3) as u32;
        config.culling.registry.max_slots = 8 + rng.below(40) as u32;
        config.culling.latency_mitigation = rng.chance_percent(60).then_some(ActivationHeuristic {
            max_distance: 60.0,
            min_projected_size: 0.0,
            surround_radius: 0.0,
        });
        config.scheduler = SchedulerConfig {
            cache: CacheConfig {
                memory_budget: budget,
                frames_in_flight: fif,
                max_unused_frames: 5 + rng.below(40) as u32,
            },
            scratch_alignment: 64,
            unique_rebuild_interval: 1 + rng.below(6) as u32,
            lod_hysteresis_frames: rng.below(4) as u32,
            ..SchedulerConfig::default()
        };
        let initial = rng.below(600);
        config.data = DataConfig {
            initial_capacity: initial,
            alignment: 1 << rng.below(6),
        };
        let mut catalog = MeshCatalog::new();
        let mut meshes = HashMap::new();
        let n = 1 + rng.below(4) as u32;
        for mesh in 0..n {
            let lods = mesh_lods(&mut rng, true);
            meshes.insert(MeshId(mesh), lods.len());
            catalog.insert(MeshId(mesh), lods).unwrap();
        }
        let m = Manager::new(world_grid(), config, catalog.clone()).unwrap();
        let mut other = Manager::new(world_grid(), config, catalog).unwrap();
        let foreign = (0..3)
            .filter_map(|_| other.register(random_desc(&mut rng, &meshes)).ok())
            .collect();
        let be = Backend {
            device: SyntheticDevice::new(fif, initial),
            ring: Some(ReadbackRing::new(latency).unwrap()),
            ..Backend::default()
        };
        Case {
            rng,
            m,
            other,
            be,
            live: Vec::new(),
            dead: Vec::new(),
            foreign,
            meshes,
            next_mesh: n,
            frame: 0,
            budget,
            frustums: frustums(),
            calls: 0,
            phase: 0,
            trace: env("LIPAC_FUZZ_TRACE", 0) != 0,
            cover: Coverage::default(),
        }
    }

    /// A handle for a call: mostly live, else dead, foreign or default.
    fn some_handle(&mut self) -> (InstanceHandle, bool) {
        let r = self.rng.below(10);
        if r < 7 {
            if let Some(h) = self.rng.pick(&self.live) {
                return (h, true);
            }
        }
        let h = match r {
            7 => self.rng.pick(&self.dead),
            8 => self.rng.pick(&self.foreign),
            _ => None,
        };
        (h.unwrap_or_default(), false)
    }

    /// One random call; returns whether it was refused and whether a
    /// refused `register` may have grown the buffer.
    fn call(&mut self) -> (Result<(), ManagerError>, bool) {
        // Mostly the next step of the frame loop, else any call.
        const LOOP: [u64; 10] = [0, 20, 46, 58, 66, 10, 20, 30, 36, 41];
        let choice = if self.rng.chance_percent(65) {
            self.phase = (self.phase + 1) % LOOP.len();
            LOOP[self.phase]
        } else {
            self.rng.below(100)
        };
        if self.trace {
            eprintln!("call {} choice {choice} frame {}", self.calls, self.frame);
        }
        match choice {
            // ---- the frame loop, in order ------------------------------
            0..=9 => {
                let f = match self.rng.below(20) {
                    0 => self.frame,
                    1 => self.frame.saturating_sub(1 + self.rng.below(3)),
                    2 => u64::MAX - self.rng.below(4),
                    3 => MAX_FRAME + 1 + self.rng.below(4),
                    _ => self.frame + 1,
                };
                let r = self.m.begin_frame(f);
                if r.is_ok() {
                    self.frame = f;
                    let ring = self.be.ring.as_mut().unwrap();
                    while let Some(rb) = ring.pop_ready(f) {
                        self.m.ingest_readback(rb.frame, rb.counter, &rb.words);
                    }
                }
                (r, false)
            }
            10..=19 => {
                let budgets = FrameBudgets {
                    commands: self.rng.below(8) as usize,
                    builds: BuildBudgets {
                        max_builds: self.rng.below(4) as u32,
                        max_primitives: 500 + self.rng.below(5000),
                        max_result_bytes: 10_000 + self.rng.below(100_000),
                        max_scratch_bytes: 4000 + self.rng.below(20_000),
                        max_batches: self.rng.below(3) as u32,
                        max_compactions: self.rng.below(3) as u32,
                    },
                };
                let r = self.m.plan(&budgets).map(|plan| self.be.execute(&plan));
                (r, false)
            }
            20..=29 => {
                // Owed acknowledgements, sometimes several.
                let mut r = Ok(());
                for _ in 0..1 + self.rng.below(3) {
                    if self.be.owed.is_empty() {
                        break;
                    }
                    let i = self.rng.below(self.be.owed.len() as u64) as usize;
                    r = self.be.deliver(&mut self.m, i, &mut self.rng);
                    if r.is_err() {
                        break;
                    }
                }
                (r, false)
            }
            30..=35 => {
                let r = self.m.assemble(&mut self.be.tlas).map(|_| {
                    for t in &self.be.tlas {
                        let a = t.acceleration_structure_reference;
                        if a != CUBE {
                            self.be.device.traced(a, self.frame);
                            self.be.traced_with_blas += 1;
                        }
                    }
                    // Trace: hits on what was traced.
                    let hitboxes = self.m.hitboxes_mut().len();
                    for t in &self.be.tlas {
                        let i = t.custom_index() as usize;
                        let hits = self.rng.below(900) as u32;
                        if t.acceleration_structure_reference == CUBE && i < hitboxes {
                            self.m.hitboxes_mut()[i].add_hits(hits);
                        } else if let Some(h) = self.m.instance_hits_mut().get_mut(i) {
                            *h += hits;
                        }
                    }
                });
                (r, false)
            }
            36..=40 => (self.m.process_feedback().map(|_| ()), false),
            41..=45 => {
                if let Some(rb) = self.m.take_commands() {
                    // A full ring (out-of-order calls) drops the read-back.
                    let _ = self.be.ring.as_mut().unwrap().push(rb);
                }
                (Ok(()), false)
            }
            // ---- churn ------------------------------------------------
            46..=57 => {
                let mut d = random_desc(&mut self.rng, &self.meshes);
                let valid = self.rng.chance_percent(85);
                if !valid {
                    corrupt(&mut self.rng, &mut d);
                }
                match self.m.register(d) {
                    Ok(h) => {
                        self.live.push(h);
                        (Ok(()), false)
                    }
                    Err(e) => (Err(e), true),
                }
            }
            58..=65 => {
                let (h, is_live) = self.some_handle();
                let r = self.m.remove(h);
                assert_eq!(r.is_ok(), is_live, "remove({h:?}): {r:?}");
                if r.is_ok() {
                    self.live.retain(|&x| x != h);
                    self.dead.push(h);
                }
                (r.map(|_| ()), false)
            }
            66..=72 => {
                let (h, _) = self.some_handle();
                let lod = self.rng.below(4) as u32;
                (self.m.set_lod(h, lod).map(|_| ()), false)
            }
            73..=77 => {
                let (h, _) = self.some_handle();
                let mut d = random_desc(&mut self.rng, &self.meshes);
                if self.rng.chance_percent(30) {
                    corrupt(&mut self.rng, &mut d);
                }
                (self.m.set_transform(h, d.transform, d.aabb), false)
            }
            78..=81 => {
                let (h, _) = self.some_handle();
                let mut d = match self.m.registry().desc(h) {
                    Ok(d) => d,
                    Err(_) => random_desc(&mut self.rng, &self.meshes),
                };
                match self.rng.below(4) {
                    0 => {
                        d.flags = if d.flags.contains(InstanceFlags::UNIQUE_BLAS) {
                            InstanceFlags::empty()
                        } else {
                            InstanceFlags::UNIQUE_BLAS
                        }
                    }
                    1 => corrupt(&mut self.rng, &mut d),
                    _ => d.lod = self.rng.below(3) as u32,
                }
                (self.m.update(h, d).map(|_| ()), false)
            }
            82..=84 => {
                let valid = self.rng.chance_percent(60);
                let lods = mesh_lods(&mut self.rng, valid);
                let count = lods.len();
                let mesh = if self.rng.chance_percent(85) {
                    self.next_mesh += 1;
                    MeshId(self.next_mesh)
                } else {
                    MeshId(0) // already registered
                };
                let r = self.m.register_mesh(mesh, lods);
                if r.is_ok() {
                    self.meshes.insert(mesh, count);
                }
                (r, false)
            }
            85..=87 => {
                let (eye, fr) = self.frustums[self.rng.below(3) as usize];
                let eye = if self.rng.chance_percent(10) {
                    Vec3::NAN
                } else {
                    eye
                };
                if self.rng.chance_percent(50) {
                    (self.m.mitigate_latency(eye, &fr).map(|_| ()), false)
                } else {
                    // A warm start, held or not (config), around the camera
                    // or not, now and then with a bad heuristic.
                    let h = ActivationHeuristic {
                        max_distance: if self.rng.chance_percent(50) {
                            f32::INFINITY
                        } else {
                            30.0
                        },
                        min_projected_size: 0.0,
                        surround_radius: match self.rng.below(4) {
                            0 => 0.0,
                            1 => 20.0,
                            2 => 1.0e6,
                            _ => f32::NAN,
                        },
                    };
                    (self.m.warm_start(eye, &fr, h).map(|_| ()), false)
                }
            }
            // ---- garbage -----------------------------------------------
            88..=90 => {
                let n = self.rng.below(12);
                let words: Vec<u32> = (0..n).map(|_| self.rng.next_u64() as u32).collect();
                let counter = self.rng.below(20) as u32;
                self.m.ingest_readback(self.rng.below(20), counter, &words);
                (Ok(()), false)
            }
            91..=93 => {
                // Corrupt, unknown or duplicate acknowledgements.
                let id = match self.rng.pick(&self.be.owed) {
                    Some(Owed::Built { id, .. }) | Some(Owed::Compacted { id, .. }) => id,
                    Some(Owed::Size { id, .. }) => id,
                    None => BuildId(self.rng.below(50)),
                };
                let r = match self.rng.below(6) {
                    0 => self.m.send_built(id, 0, 0x1234_0000),
                    1 => self
                        .m
                        .send_built(id, MAX_BLAS_BYTES + 1 + self.rng.below(9), 0x1234_0000),
                    2 => self.m.send_built(id, 100, 0),
                    3 => self
                        .m
                        .send_built(BuildId(1 << 40 | self.rng.below(9)), 100, 0x1234_0000),
                    4 => self.m.send_compacted(BuildId(1 << 40), 0x1234_0000),
                    _ => match self.rng.pick(&self.be.delivered) {
                        Some(Owed::Built { id, .. }) => self.m.send_built(id, 100, 0x1234_0000),
                        Some(Owed::Compacted { id, .. }) => self.m.send_compacted(id, 0x1234_0000),
                        _ => self.m.send_compacted_size(BuildId(1 << 41), 10),
                    },
                };
                assert!(r.is_err(), "a corrupt acknowledgement was accepted");
                (r, false)
            }
            94..=95 => {
                let n = self.rng.below(60);
                let hits: Vec<u32> = (0..n).map(|_| self.rng.below(5000) as u32).collect();
                self.m.record_hits(&hits);
                (Ok(()), false)
            }
            96 => {
                if self.rng.chance_percent(50) {
                    self.m.trim_blas_cache();
                } else {
                    self.m.reserve(self.rng.below(40) as usize).unwrap();
                }
                (Ok(()), false)
            }
            _ => {
                // A foreign handle is refused (and the other manager keeps it).
                let h = self.rng.pick(&self.foreign).unwrap_or_default();
                let r = self.m.remove(h).map(|_| ());
                assert!(r.is_err(), "a foreign handle removed an instance");
                if self.foreign.contains(&h) {
                    assert!(self.other.instance(h).is_ok());
                }
                (r, false)
            }
        }
    }

    fn step(&mut self) {
        self.calls += 1;
        let before = snapshot(&self.m, &self.live, false);
        let (live, frame, acked) = (self.live.len(), self.frame, self.be.delivered.len());
        let (r, may_grow) = self.call();
        if self.trace {
            eprintln!("  -> {r:?}");
        }
        let c = &mut self.cover;
        c.ok += u64::from(r.is_ok());
        c.refused += u64::from(r.is_err());
        c.registered += u64::from(self.live.len() > live);
        c.removed += u64::from(self.live.len() < live);
        c.frames += u64::from(self.frame != frame);
        for o in &self.be.delivered[acked..] {
            match o {
                Owed::Built { .. } => c.builds_acked += 1,
                Owed::Compacted { .. } => c.compactions_acked += 1,
                Owed::Size { .. } => {}
            }
        }
        if let Err(e) = &r {
            assert!(
                !matches!(e, ManagerError::Invariant { .. }),
                "internal inconsistency: {e}"
            );
            let after = snapshot(&self.m, &self.live, may_grow);
            let before = if may_grow {
                snapshot_ignoring_capacity(before)
            } else {
                before
            };
            assert_eq!(before, after, "refused call changed the manager: {e}");
        }
        self.check();
    }

    fn check(&self) {
        let m = &self.m;
        let reg = m.registry();
        assert_eq!(reg.len(), self.live.len(), "live instances");
        assert_eq!(
            reg.slot_count(),
            reg.len() as u32 + reg.free_slots() + reg.quarantined_slots(),
            "a slot leaked"
        );
        let st = m.stats();
        let mut data_bytes = 0;
        let mut slots = Vec::new();
        for &h in &self.live {
            let v = m.instance(h).unwrap();
            slots.push(v.slot);
            assert_eq!(reg.record(h).unwrap().lod, v.traced_lod);
            let mesh = reg.mesh(h).unwrap();
            let bytes = m.catalog().lod(mesh, v.traced_lod).unwrap().data_bytes;
            assert_eq!(
                v.data.end - v.data.start,
                bytes,
                "data follows the traced LOD"
            );
            assert_eq!(
                v.scheduled,
                v.blas != 0 || v.awaiting_blas,
                "slot {}",
                v.slot
            );
            if v.blas != 0 {
                assert!(
                    self.be.device.live.contains_key(&v.blas),
                    "record holds a dead BLAS"
                );
            }
            data_bytes += bytes;
        }
        slots.sort_unstable();
        slots.dedup();
        assert_eq!(slots.len(), self.live.len(), "two instances share a slot");
        for &h in &self.dead {
            assert!(m.instance(h).is_err(), "a removed handle is live");
        }
        // Data accounting: the sum of live ranges, which tile the buffer.
        let data = m.data_allocator();
        let mut ranges: Vec<(u64, u64)> = data.allocations().map(|a| (a.offset, a.size)).collect();
        ranges.sort_unstable();
        let mut end = 0;
        for &(offset, size) in &ranges {
            assert!(offset >= end, "data ranges overlap");
            end = offset + size;
        }
        assert!(end <= data.capacity());
        let sum: u64 = ranges.iter().map(|r| r.1).sum();
        assert_eq!(sum, data.used_bytes());
        assert_eq!(st.memory.data_used, data_bytes);
        assert_eq!(st.data_ranges, self.live.len());
        assert_eq!(st.instances.live, self.live.len());
        // BLAS accounting against the backend.
        let mem = &st.memory;
        let cache = mem.blas_shared + mem.blas_unique + mem.blas_compacted;
        let held: u64 = self.be.device.live.values().sum();
        assert_eq!(
            cache + mem.blas_pending_free,
            held + self.be.in_flight_bytes(),
            "BLAS bytes disagree with the backend's structures"
        );
        if !self.be.overran {
            assert!(cache <= self.budget, "BLAS budget broken: {cache}");
        }
        assert_eq!(st.builds_in_flight, self.be.in_flight.len());
        assert_eq!(m.scheduler().stats().instances, st.instances.scheduled);
    }

    /// Removes everything, delivers every acknowledgement and lets the
    /// frames in flight pass: nothing may be left.
    fn teardown(&mut self) {
        for h in std::mem::take(&mut self.live) {
            self.m.remove(h).unwrap();
            self.dead.push(h);
        }
        let mut f = self.frame;
        let mut rounds = 0;
        loop {
            // Finish the frame loop of whatever frame we are in.
            if let Some(rb) = self.m.take_commands() {
                let _ = self.be.ring.as_mut().unwrap().push(rb);
            }
            f += 1;
            self.m.begin_frame(f).unwrap();
            self.frame = f;
            while let Some(rb) = self.be.ring.as_mut().unwrap().pop_ready(f) {
                self.m.ingest_readback(rb.frame, rb.counter, &rb.words);
            }
            while !self.be.owed.is_empty() {
                let r = self.be.deliver(&mut self.m, 0, &mut self.rng);
                r.unwrap();
            }
            let plan = self.m.plan(&FrameBudgets::default()).unwrap();
            self.be.execute(&plan);
            self.m.trim_blas_cache();
            self.m.assemble(&mut self.be.tlas).unwrap();
            self.m.process_feedback().unwrap();
            self.check();
            rounds += 1;
            let st = self.m.stats();
            let quiet = self.be.owed.is_empty()
                && st.builds_in_flight == 0
                && st.blas_pending_frees == 0
                && st.blas_entries == 0
                && st.commands_pending == 0;
            if quiet && rounds > 8 {
                break;
            }
            assert!(rounds < 200, "operations never settle: {st:?}");
        }
        let st = self.m.stats();
        let data = self.m.data_allocator().stats();
        assert_eq!((data.used_bytes, data.allocation_count), (0, 0));
        assert_eq!(data.free_block_count, usize::from(data.capacity > 0));
        assert_eq!(st.memory.blas_shared + st.memory.blas_unique, 0);
        assert_eq!(st.memory.blas_compacted + st.memory.blas_scratch, 0);
        assert_eq!(st.memory.blas_pending_free, 0);
        assert_eq!((st.builds_queued, st.builds_in_flight), (0, 0));
        assert!(self.m.registry().is_empty());
        assert_eq!(st.instances.scheduled + st.instances.with_blas, 0);
        assert!(
            self.be.device.live.is_empty(),
            "structures never freed: {:?}",
            self.be.device.live
        );
    }
}

fn snapshot_ignoring_capacity(mut s: Snapshot) -> Snapshot {
    let mem = &mut s.stats.memory;
    (mem.data_capacity, mem.data_free, mem.data_largest_free) = (0, 0, 0);
    mem.data_fragmentation = 0.0;
    s.stats.data_free_blocks = 0;
    s
}

fn run_case(seed: u64, calls: u64) -> Coverage {
    let result = std::panic::catch_unwind(|| {
        let mut c = Case::new(seed);
        for _ in 0..calls {
            c.step();
        }
        c.teardown();
        assert_eq!(c.calls, calls);
        Coverage {
            frees: c.be.device.frees,
            traced_with_blas: c.be.traced_with_blas,
            ..c.cover
        }
    });
    match result {
        Ok(cover) => cover,
        Err(e) => {
            eprintln!(
                "manager_call_fuzz: case seed {seed} failed (LIPAC_FUZZ_SEED={seed} replays it)"
            );
            std::panic::resume_unwind(e)
        }
    }
}

#[test]
fn random_manager_call_sequences_keep_the_invariants() {
    let calls = env("LIPAC_FUZZ_CALLS", 1000);
    if let Ok(seed) = std::env::var("LIPAC_FUZZ_SEED") {
        run_case(seed.parse().expect("LIPAC_FUZZ_SEED is a number"), calls);
        return;
    }
    let cases = env("LIPAC_FUZZ_CASES", 16);
    let mut total = Coverage::default();
    for case in 0..cases {
        total.add(run_case(0x1217_0000 + case, calls));
    }
    eprintln!("manager_call_fuzz: {cases} cases of {calls} calls: {total:?}");
    if cases >= 16 && calls >= 1000 {
        // The default run reaches every part of the frame loop.
        let c = total;
        assert!(c.ok > c.refused && c.refused > 1000, "{c:?}");
        assert!(
            c.registered > 500 && c.removed > 400 && c.frames > 500,
            "{c:?}"
        );
        assert!(c.builds_acked > 80 && c.compactions_acked > 25, "{c:?}");
        assert!(c.frees > 100 && c.traced_with_blas > 2000, "{c:?}");
    }
}
