//! Shared by `benches/frame_loop.rs` and `benches/scale.rs`: a synthetic
//! scene on a square grid of 16 m hitboxes (~16 instances per hitbox) and
//! one CPU frame of [`Culling`]'s loop, with synthetic hits from a band of
//! hot hitbox columns that moves one column every 8 frames.
#![allow(dead_code)]

use glam::{Affine3A, Vec3};
use lipac_core::culling::{BlasAction, CommandEvent, Culling, CullingConfig, ReadbackRing};
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::instance::{InstanceDesc, InstanceFlags, MeshId};
use lipac_core::layout::TlasInstance;
use lipac_core::math::Aabb;
use lipac_test_support::{Rng64, XorShift64};

/// Hitbox edge in metres.
pub const CELL: f64 = 16.0;
/// BLAS address of the counting box.
pub const CUBE: u64 = 0xC0BE;

/// What differs between the benches' scenes.
pub struct Scene {
    /// Share of instances that need a unique BLAS.
    pub unique_fraction: f32,
    /// The hot band is `1 / hot_divisor` of the world wide.
    pub hot_divisor: u32,
    /// Mesh ids drawn at random (else instance `i` uses mesh `i % 64`).
    pub random_meshes: bool,
    /// Call `Culling::reserve` for all instances before registering them.
    pub reserve: bool,
}

/// The culling loop with its read-back ring and counters.
pub struct Loop {
    pub culling: Culling,
    pub ring: ReadbackRing,
    /// Commands processed per frame.
    pub budget: usize,
    /// The BLAS work of the last `process_commands` (kept for its
    /// allocation).
    pub events: Vec<CommandEvent>,
    pub tlas: Vec<TlasInstance>,
    pub frame: u64,
    /// Hitbox columns of the grid.
    pub columns: u32,
    pub hot_divisor: u32,
    pub next_blas: u64,
    /// Commands read back since the last reset.
    pub commands: u64,
    /// Commands in the last frame's read-back.
    pub last_counter: u32,
}

/// `n` instances (4 m x 6 m boxes) at seeded random positions, registered
/// one by one; no frame run yet.
pub fn build(n: u32, scene: &Scene) -> Loop {
    let w = ((f64::from(n) / 16.0).sqrt().ceil() as u32).max(1);
    let side = f64::from(w) * CELL;
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [side, side],
        cell_size: CELL,
    })
    .unwrap();
    let mut cfg = CullingConfig::new(CUBE);
    cfg.latency_mitigation = None;
    let mut culling = Culling::new(grid, cfg).unwrap();
    let mut rng = XorShift64::new(0x9E37_79B9_7F4A_7C15 ^ u64::from(n));
    let mut unit = || rng.unit_f32();
    if scene.reserve {
        culling.reserve(n as usize).unwrap();
    }
    for i in 0..n {
        let c = Vec3::new(unit() * side as f32, 0.0, unit() * side as f32);
        let aabb = Aabb::new(c - Vec3::new(2.0, 0.0, 2.0), c + Vec3::new(2.0, 6.0, 2.0));
        let mesh = if scene.random_meshes {
            (unit() * 64.0) as u32
        } else {
            i % 64
        };
        let mut d = InstanceDesc::new(MeshId(mesh), Affine3A::from_translation(c), aabb);
        if unit() < scene.unique_fraction {
            d.flags = InstanceFlags::UNIQUE_BLAS;
        }
        culling.register(d).unwrap();
    }
    Loop {
        culling,
        ring: ReadbackRing::new(2).unwrap(),
        budget: 4096,
        events: Vec::new(),
        tlas: Vec::new(),
        frame: 0,
        columns: w,
        hot_divisor: scene.hot_divisor,
        next_blas: 0x10_0000,
        commands: 0,
        last_counter: 0,
    }
}

/// One frame: `begin_frame`, ingest of the read-back from `k = 2` frames
/// ago, `process_commands` under `budget` (every acquired BLAS gets a fresh
/// address through `set_blas`),
/// `assemble`, synthetic hits for every TLAS record (2500 per counting box
/// and 1500 per traced instance in the hot band, 10 and 5 elsewhere),
/// `process_feedback` and `take_commands`.
pub fn frame(l: &mut Loop) {
    let c = &mut l.culling;
    c.begin_frame(l.frame).unwrap();
    while let Some(r) = l.ring.pop_ready(l.frame) {
        c.ingest_readback(r.frame, r.counter, &r.words);
    }
    c.process_commands(l.budget, &mut l.events);
    for e in &l.events {
        if e.action == BlasAction::Acquire {
            l.next_blas += 1;
            c.set_blas(e.handle, l.next_blas).unwrap();
        }
    }
    c.assemble(&mut l.tlas).unwrap();
    let (w, shift) = (l.columns, (l.frame / 8) as u32);
    let band = w.div_ceil(l.hot_divisor);
    let hot = |hitbox: u32| (hitbox % w + shift) % w < band;
    for r in &l.tlas {
        let i = r.custom_index();
        if r.acceleration_structure_reference == CUBE && r.sbt_offset() == 2 {
            c.hitboxes_mut()[i as usize].add_hits(if hot(i) { 2500 } else { 10 });
        } else {
            let hitbox = c.registry().record_at(i).unwrap().hitbox;
            c.instance_hits_mut()[i as usize] = if hot(hitbox) { 1500 } else { 5 };
        }
    }
    c.process_feedback().unwrap();
    let rb = c.take_commands().unwrap();
    l.commands += u64::from(rb.counter);
    l.last_counter = rb.counter;
    l.ring.push(rb).unwrap();
    l.frame += 1;
}
