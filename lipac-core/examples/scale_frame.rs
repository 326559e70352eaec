//! Scale figures of the full `Manager` frame: registration time, per-frame
//! CPU cost of `plan`, Algorithm 1 (`assemble`), Algorithm 2
//! (`process_feedback`) and the whole frame, and memory per instance and per
//! hitbox, with the dense grid or the sparse hashed grid of hitboxes, for
//! any instance count and world size.
//!
//! ```sh
//! cargo run --release -p lipac-core --example scale_frame -- \
//!     [instances=100000] [grid|hashed] [side_m=auto] [frames=30] [adaptive_levels=0]
//! /usr/bin/time -f %M cargo run ...   # peak RSS in KiB
//! ```
//!
//! `side_m = auto` makes a square world of ~16 instances per 16 m cell (as
//! the `scale` bench); `100000` is the 100 km x 100 km world (39M cells of
//! 16 m, ~1 instance per occupied cell at 1M instances).
//!
//! Scene (as the `recorder` bench's Manager frame): 64 meshes x 3 LODs, 15 %
//! unique BLASes, instances (4 x 6 x 4 m) at seeded random positions; per
//! frame 1 % of them move, 64 LOD requests, 32 removals + 32
//! registrations, `plan` with fake builds acknowledged next frame, a stub
//! tracer (every TLAS record hit; a band a quarter of the world wide is hot
//! and moves one column of cells every 8 frames), `process_feedback`,
//! `take_commands`. Latency mitigation off. 16 warm-up frames, then medians
//! over `frames`. `adaptive_levels > 0` (grid only) turns on adaptive
//! hitboxes (`lipac_core::hitbox_tree`); the stub tracer hits a merged box
//! as its leaf boxes.

use std::time::Instant;

use glam::{Affine3A, Vec3};
use lipac_core::assembly::AssemblyStats;
use lipac_core::hashed_hitboxes::{HashedConfig, HashedHitboxes};
use lipac_core::hitbox_tree::AdaptiveHitboxes;
use lipac_core::{
    Aabb, Ack, BuildEstimate, FrameBudgets, GridConfig, HitboxGrid, HitboxIndex, InstanceDesc,
    InstanceFlags, InstanceHandle, Manager, ManagerConfig, MeshCatalog, MeshId, MeshLod,
    ReadbackRing, TlasInstance,
};

const CELL: f64 = 16.0;
const CUBE: u64 = 0xC0BE;
const MESHES: u32 = 64;

struct Loop<H: HitboxIndex> {
    m: Manager<H>,
    ring: ReadbackRing,
    acks: Vec<Ack>,
    tlas: Vec<TlasInstance>,
    handles: Vec<InstanceHandle>,
    frame: u64,
    side: f64,
    next_blas: u64,
    rng: u64,
    last: AssemblyStats,
}

/// Seconds of `plan`, `assemble`, `process_feedback` and the whole frame.
type Times = [f64; 4];

impl<H: HitboxIndex> Loop<H> {
    fn rand(&mut self) -> u64 {
        // xorshift64*
        self.rng ^= self.rng >> 12;
        self.rng ^= self.rng << 25;
        self.rng ^= self.rng >> 27;
        self.rng.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn unit(&mut self) -> f32 {
        (self.rand() >> 40) as f32 / (1u64 << 24) as f32
    }

    fn desc(&mut self) -> InstanceDesc {
        let x = self.unit() * self.side as f32;
        let z = self.unit() * self.side as f32;
        let mesh = MeshId((self.rand() % u64::from(MESHES)) as u32);
        let c = Vec3::new(x, 3.0, z);
        let mut d = InstanceDesc::new(
            mesh,
            Affine3A::from_translation(c),
            Aabb::new(c - Vec3::new(2.0, 3.0, 2.0), c + Vec3::new(2.0, 3.0, 2.0)),
        );
        if self.rand() % 100 < 15 {
            d.flags = InstanceFlags::UNIQUE_BLAS;
        }
        d
    }

    /// The Manager with `n` instances registered; returns it and the
    /// registration time in seconds (`reserve` + `register` one by one).
    fn new(index: H, n: u32, side: f64, adaptive: u8) -> (Self, f64) {
        let lod = |tris: u64| MeshLod {
            estimate: BuildEstimate {
                primitives: tris,
                result_bytes: tris * 64,
                build_scratch_bytes: tris * 16,
                update_scratch_bytes: tris * 8,
            },
            data_bytes: 64,
        };
        let mut catalog = MeshCatalog::new();
        for mesh in 0..MESHES {
            catalog
                .insert(MeshId(mesh), vec![lod(4000), lod(1000), lod(250)])
                .expect("mesh");
        }
        let mut config = ManagerConfig::new(CUBE);
        config.culling.latency_mitigation = None;
        config.culling.readback_latency = 2;
        config.culling.adaptive_hitboxes = AdaptiveHitboxes::with_levels(adaptive);
        let m = Manager::new(index, config, catalog).expect("manager");
        let mut l = Self {
            m,
            ring: ReadbackRing::new(2).expect("ring"),
            acks: Vec::new(),
            tlas: Vec::new(),
            handles: Vec::with_capacity(n as usize),
            frame: 0,
            side,
            next_blas: 0,
            rng: 0x9E37_79B9_7F4A_7C15,
            last: AssemblyStats::default(),
        };
        let start = Instant::now();
        l.m.reserve(n as usize).expect("reserve");
        for _ in 0..n {
            let d = l.desc();
            let h = l.m.register(d).expect("register");
            l.handles.push(h);
        }
        (l, start.elapsed().as_secs_f64())
    }

    fn frame(&mut self) -> Times {
        let t0 = Instant::now();
        let frame = self.frame;
        self.frame += 1;
        self.m.begin_frame(frame).expect("begin");
        for a in self.acks.drain(..) {
            self.m.handle_ack(a).expect("ack");
        }
        while let Some(r) = self.ring.pop_ready(frame) {
            self.m.ingest_readback(r.frame, r.counter, &r.words);
        }
        let n = self.handles.len();
        for _ in 0..n / 100 {
            let i = (self.rand() % n as u64) as usize;
            let d = self.desc();
            self.m
                .set_transform(self.handles[i], d.transform, d.aabb)
                .expect("move");
        }
        for _ in 0..64 {
            let i = (self.rand() % n as u64) as usize;
            let lod = (self.rand() % 3) as u32;
            self.m.set_lod(self.handles[i], lod).expect("lod");
        }
        for _ in 0..32 {
            let i = (self.rand() % n as u64) as usize;
            self.m.remove(self.handles[i]).expect("remove");
            let d = self.desc();
            self.handles[i] = self.m.register(d).expect("register");
        }
        let t_plan = Instant::now();
        let plan = self.m.plan(&FrameBudgets::default()).expect("plan");
        let plan_s = t_plan.elapsed().as_secs_f64();
        for b in plan.blas.builds() {
            self.next_blas += 0x1_0000;
            self.acks.push(Ack::Built {
                build: b.id,
                result_bytes: b.result_bytes,
                address: self.next_blas,
            });
        }
        let t_a1 = Instant::now();
        self.last = self.m.assemble(&mut self.tlas).expect("assemble");
        let a1_s = t_a1.elapsed().as_secs_f64();
        // Stub tracer: a hot band of cell columns moving every 8 frames.
        let columns = (self.side / CELL).ceil().max(1.0) as u64;
        let hot_start = frame / 8 % columns;
        let hot = |x: f32| {
            let col = ((f64::from(x) / CELL).max(0.0) as u64).min(columns - 1);
            (col + columns - hot_start) % columns < columns.div_ceil(4)
        };
        let hitbox_sbt = self.m.culling_config().assembly.hitbox_sbt_offset;
        let merged_sbt = self
            .m
            .culling_config()
            .adaptive_hitboxes
            .merged_box_sbt_offset;
        let mut leaves = Vec::new();
        for t in &self.tlas {
            let i = t.custom_index();
            // Adaptive hitboxes: a merged box is hit as its leaf boxes would
            // have been (one hit count per leaf box).
            if self.m.hitbox_tree().is_some() && t.sbt_offset() == merged_sbt {
                leaves.clear();
                self.m.merged_leaf_boxes(i, &mut leaves);
                for &(leaf, lt) in &leaves {
                    let h = if hot(lt[3]) { 2500 } else { 10 };
                    if let Some(b) = self.m.hitboxes_mut().get_mut(leaf as usize) {
                        b.add_hits(h);
                    }
                }
                continue;
            }
            // A hitbox's counting box (an omitted instance's box names its
            // slot, like a traced instance).
            if t.acceleration_structure_reference == CUBE && t.sbt_offset() == hitbox_sbt {
                let x = self
                    .m
                    .registry()
                    .hitbox_index()
                    .xz_bounds(i)
                    .map_or(0.0, |(lo, _)| lo.x);
                let h = if hot(x) { 2500 } else { 10 };
                if let Some(b) = self.m.hitboxes_mut().get_mut(i as usize) {
                    b.add_hits(h);
                }
            } else {
                let h = if hot(t.transform[3]) { 1500 } else { 5 };
                self.m.instance_hits_mut()[i as usize] += h;
            }
        }
        let t_a2 = Instant::now();
        self.m.process_feedback().expect("feedback");
        let a2_s = t_a2.elapsed().as_secs_f64();
        self.ring
            .push(self.m.take_commands().expect("commands"))
            .expect("ring");
        [plan_s, a1_s, a2_s, t0.elapsed().as_secs_f64()]
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn run<H: HitboxIndex>(
    index: H,
    n: u32,
    side: f64,
    frames: usize,
    adaptive: u8,
    index_heap: impl Fn(&H) -> u64,
) {
    let (mut l, reg) = Loop::new(index, n, side, adaptive);
    for _ in 0..16 {
        l.frame();
    }
    let times: Vec<Times> = (0..frames).map(|_| l.frame()).collect();
    let med = |k: usize| median(times.iter().map(|t| t[k]).collect()) * 1e3;
    let cull = l.m.memory_usage();
    let hitboxes = l.m.hitboxes().len() as u64;
    let index = l.m.registry().hitbox_index();
    let stats = l.m.stats();
    println!(
        "n = {n}, side = {side} m, {} hitboxes ({} occupied of {:.0} cells)",
        hitboxes,
        (0..index.len())
            .filter(|&i| index.xz_bounds(i).is_some())
            .count(),
        (side / CELL).ceil().powi(2)
    );
    println!(
        "registration {reg:.3} s ({:.0} ns/instance)",
        reg * 1e9 / f64::from(n)
    );
    println!(
        "median of {frames} frames: plan {:.3} ms, Algorithm 1 {:.3} ms, Algorithm 2 {:.3} ms, \
         Manager frame {:.3} ms; TLAS {} records, active {}",
        med(0),
        med(1),
        med(2),
        med(3),
        l.tlas.len(),
        stats.instances.active
    );
    let a = l.last;
    println!(
        "last frame: counting boxes {} (hitbox boxes {}, merged boxes {} for {} hitboxes, \
         omitted-instance boxes {}), active instances emitted {}",
        a.hitbox_boxes + a.merged_boxes + a.omitted_boxes,
        a.hitbox_boxes,
        a.merged_boxes,
        a.merged_hitboxes,
        a.omitted_boxes,
        a.active
    );
    println!(
        "CPU memory: Culling per slot {:.1} B/instance; hitbox records {:.1} MB \
         ({} B/hitbox CPU + GPU), index {:.1} MB ({:.1} B/hitbox); GPU instance records {:.1} MB",
        cull.per_slot() as f64 / f64::from(n),
        cull.hitboxes as f64 / 1e6,
        cull.hitboxes / hitboxes.max(1),
        index_heap(index) as f64 / 1e6,
        index_heap(index) as f64 / hitboxes.max(1) as f64,
        stats.memory.instance_record_bytes as f64 / 1e6
    );
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let n: u32 = args.first().and_then(|s| s.parse().ok()).unwrap_or(100_000);
    let kind = args.get(1).map_or("grid", String::as_str);
    let auto = (f64::from(n) / 16.0).sqrt().ceil().max(1.0) * CELL;
    let side: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(auto);
    let frames: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(30);
    let adaptive: u8 = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(0);
    match kind {
        "hashed" => {
            let index = HashedHitboxes::new(HashedConfig {
                cell_size: CELL,
                ..HashedConfig::default()
            })
            .expect("hashed index");
            run(index, n, side, frames, adaptive, HashedHitboxes::heap_bytes);
        }
        _ => {
            let grid = HitboxGrid::new(GridConfig {
                min: [0.0, 0.0],
                max: [side, side],
                cell_size: CELL,
            })
            .expect("grid");
            run(grid, n, side, frames, adaptive, |_| 0);
        }
    }
}
