//! Overhead of the Manager's trace recorder (`lipac_core::manager::recorder`):
//! one full CPU frame of the [`Manager`] at 100k instances, without a
//! recorder, with a [`TraceRecorder`] writing the binary trace's events and
//! cameras to `std::io::sink()`, and with the hits as well, in one run.
//!
//! Frame: `begin_frame`, acknowledgements of last frame's builds, the
//! read-back of 2 frames ago, engine changes (1 % of the instances moved,
//! 64 LOD requests, 32 removals and 32 registrations), `record_camera`,
//! `plan`, fake builds (acknowledged next frame), `assemble`, a stub tracer
//! (hits on every TLAS record; a band a quarter of the world wide is hot and
//! moves one hitbox column every 8 frames), `process_feedback`,
//! `take_commands`. Warmed up for 64 frames first.
//!
//! Then the three run frame by frame in turn (150 frames each) and the
//! per-frame medians and ratios are printed: robust to a shared machine's
//! changing load.
//!
//! `cargo bench -p lipac-core --bench recorder -- --warm-up-time 1 --measurement-time 3`
//!
//! Instruction counts (stable on a loaded machine): with
//! `LIPAC_RECORDER_ONLY=without|events|hits` the bench sets up that one loop,
//! runs `LIPAC_RECORDER_FRAMES` (default 20) frames in [`measured`] and
//! exits, for `valgrind --tool=callgrind --collect-atstart=no
//! --toggle-collect='*measured*'` (see docs/BENCHMARKS.md).

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, BenchmarkId, Criterion};
use glam::{Affine3A, Vec3};
use lipac_core::manager::{RecorderOptions, TraceRecorder};
use lipac_core::trace::Camera;
use lipac_core::{
    Aabb, Ack, BuildEstimate, FrameBudgets, GridConfig, HitboxGrid, InstanceDesc, InstanceFlags,
    InstanceHandle, Manager, ManagerConfig, MeshCatalog, MeshId, MeshLod, ReadbackRing,
    TlasInstance,
};
use lipac_test_support::synthetic::ImmediateAcks;
use lipac_test_support::{Rng64, XorShift64Star};

const CELL: f64 = 16.0;
const CUBE: u64 = 0xC0BE;
const MESHES: u32 = 64;

struct Loop {
    m: Manager,
    ring: ReadbackRing,
    acks: Vec<Ack>,
    tlas: Vec<TlasInstance>,
    handles: Vec<InstanceHandle>,
    frame: u64,
    columns: u32,
    immediate: ImmediateAcks,
    rng: XorShift64Star,
}

impl Loop {
    fn rand(&mut self) -> u64 {
        self.rng.next_u64()
    }
    fn unit(&mut self) -> f32 {
        self.rng.unit_f32()
    }
    fn desc(&mut self) -> InstanceDesc {
        let side = f64::from(self.columns) * CELL;
        let x = self.unit() * side as f32;
        let z = self.unit() * side as f32;
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

    /// `record`: `None` no recorder, `Some(record_hits)`; the recorder is
    /// attached before the instances are registered, so the trace holds
    /// all `n` (and a frame up to `n` hit counts).
    fn new(n: u32, record: Option<bool>) -> Self {
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
        let columns = ((f64::from(n) / 16.0).sqrt().ceil() as u32).max(1);
        let side = f64::from(columns) * CELL;
        let grid = HitboxGrid::new(GridConfig {
            min: [0.0, 0.0],
            max: [side, side],
            cell_size: CELL,
        })
        .expect("grid");
        let mut config = ManagerConfig::new(CUBE);
        config.culling.latency_mitigation = None;
        config.culling.readback_latency = 2;
        let m = Manager::new(grid, config, catalog).expect("manager");
        let mut l = Self {
            m,
            ring: ReadbackRing::new(2).expect("ring"),
            acks: Vec::new(),
            tlas: Vec::new(),
            handles: Vec::new(),
            frame: 0,
            columns,
            immediate: ImmediateAcks::new(0x1_0000),
            rng: XorShift64Star::new(0x9E37_79B9_7F4A_7C15),
        };
        if let Some(record_hits) = record {
            let options = RecorderOptions {
                record_hits,
                ..RecorderOptions::default()
            };
            l.m.attach_recorder(TraceRecorder::new(std::io::sink(), options))
                .expect("attach");
        }
        l.m.reserve(n as usize).expect("reserve");
        for _ in 0..n {
            let d = l.desc();
            let h = l.m.register(d).expect("register");
            l.handles.push(h);
        }
        l
    }

    fn frame(&mut self) {
        let frame = self.frame;
        self.frame += 1;
        self.m.begin_frame(frame).expect("begin");
        for a in self.acks.drain(..) {
            self.m.handle_ack(a).expect("ack");
        }
        while let Some(r) = self.ring.pop_ready(frame) {
            self.m.ingest_readback(r.frame, r.counter, &r.words);
        }
        // The engine's changes.
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
        let t = frame as f32 * 0.01;
        let cam = Camera::look_to(
            Vec3::new(t.cos() * 100.0, 30.0, t.sin() * 100.0),
            Vec3::new(-t.cos(), -0.2, -t.sin()),
            Vec3::Y,
            1.0,
            16.0 / 9.0,
        );
        self.m.record_camera(cam).expect("camera");
        let plan = self.m.plan(&FrameBudgets::default()).expect("plan");
        self.acks.extend(self.immediate.acks(&plan.blas));
        self.m.assemble(&mut self.tlas).expect("assemble");
        // Stub tracer: a hot band of hitbox columns moving every 8 frames.
        let hot_start = (frame / 8) as u32 % self.columns;
        let hot = |col: u32| (col + self.columns - hot_start) % self.columns < self.columns / 4;
        let cols = self.columns;
        for t in &self.tlas {
            let i = t.custom_index() as usize;
            if t.acceleration_structure_reference == CUBE {
                let col = i as u32 % cols;
                let h = if hot(col) { 2500 } else { 10 };
                if let Some(b) = self.m.hitboxes_mut().get_mut(i) {
                    b.add_hits(h);
                }
            } else {
                let x = t.transform[3];
                let col = ((f64::from(x) / CELL) as u32).min(cols - 1);
                self.m.instance_hits_mut()[i] += if hot(col) { 1500 } else { 5 };
            }
        }
        self.m.process_feedback().expect("feedback");
        self.ring
            .push(self.m.take_commands().expect("commands"))
            .expect("ring");
    }
}

/// `record`: `None` no recorder, `Some(record_hits)`.
fn setup(n: u32, record: Option<bool>) -> Loop {
    let mut l = Loop::new(n, record);
    for _ in 0..64 {
        l.frame();
    }
    l
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("recorder");
    g.sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    let n = 100_000u32;
    for (name, record) in [
        ("without", None),
        ("with_events", Some(false)),
        ("with_events_and_hits", Some(true)),
    ] {
        let mut l = setup(n, record);
        g.bench_with_input(BenchmarkId::new(name, n), &n, |b, _| {
            b.iter(|| {
                l.frame();
                black_box(l.tlas.len())
            })
        });
        if record.is_some() {
            let frames = l.m.recorder().map_or(0, |r| r.frames_written());
            let done = l.m.detach_recorder().expect("recorder ok");
            println!(
                "n = {n}, recorder: {frames} frames, {} events written",
                done.events
            );
        }
    }
    g.finish();
    interleaved(n);
}

/// The three loops run frame by frame in turn (A B C A B C ...), so that
/// the load of a shared machine hits them alike; prints per-frame medians
/// and ratios.
fn interleaved(n: u32) {
    let mut loops = [setup(n, None), setup(n, Some(false)), setup(n, Some(true))];
    let mut times: [Vec<f64>; 3] = Default::default();
    for _ in 0..150 {
        for (l, t) in loops.iter_mut().zip(&mut times) {
            let start = std::time::Instant::now();
            l.frame();
            t.push(start.elapsed().as_secs_f64() * 1e3);
        }
    }
    let med: Vec<f64> = times
        .iter_mut()
        .map(|t| {
            t.sort_by(f64::total_cmp);
            t[t.len() / 2]
        })
        .collect();
    println!(
        "interleaved, 150 frames each, n = {n}: medians without {:.3} ms, events {:.3} ms \
         (ratio {:.3}), events + hits {:.3} ms (ratio {:.3})",
        med[0],
        med[1],
        med[1] / med[0],
        med[2],
        med[2] / med[0]
    );
}

/// The frames a callgrind run counts (`--toggle-collect='*measured*'`).
#[inline(never)]
fn measured(l: &mut Loop, frames: u32) {
    for _ in 0..frames {
        l.frame();
    }
    black_box(l.tlas.len());
}

criterion_group!(benches, bench);

fn main() {
    if let Ok(only) = std::env::var("LIPAC_RECORDER_ONLY") {
        let record = match only.as_str() {
            "without" => None,
            "events" => Some(false),
            "hits" => Some(true),
            other => panic!("LIPAC_RECORDER_ONLY={other}: want without, events or hits"),
        };
        let frames = std::env::var("LIPAC_RECORDER_FRAMES")
            .ok()
            .map_or(20, |f| f.parse().expect("LIPAC_RECORDER_FRAMES: a number"));
        let mut l = setup(100_000, record);
        measured(&mut l, frames);
        if record.is_some() {
            l.m.detach_recorder().expect("recorder ok");
        }
        return;
    }
    benches();
    Criterion::default().configure_from_args().final_summary();
}
