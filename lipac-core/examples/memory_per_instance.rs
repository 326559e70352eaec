//! CPU bytes per instance of the per-frame loop (`Culling`), computed from
//! container capacities (`Culling::memory_usage`), at several scene sizes.
//!
//! `cargo run --release -p lipac-core --example memory_per_instance [max_instances]`
//! (default 1,000,000; pass 10000000 for 10M).
//!
//! Scene: ~16 instances per 16 m hitbox (square world), latency mitigation
//! on, a few frames run so every per-slot buffer exists. Each size is built
//! twice: instances registered one by one into empty containers (which grow
//! by doubling), and after `Culling::reserve(n)` (each container allocated
//! once). Registration time (wall clock, one run) is printed with each row.
//! Figures are taken before and after the first `take_uploads` (a GPU
//! backend takes them every frame; a CPU backend never does, so the
//! CPU-write overrides stay allocated).

use glam::camera::rh::{proj, view};
use glam::{Affine3A, Vec3};
use lipac_core::culling::{BlasAction, Culling, CullingConfig};
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::instance::{InstanceDesc, MeshId};
use lipac_core::latency::Frustum;
use lipac_core::math::Aabb;
use lipac_core::memory::MemoryUsage;

fn build(n: u32, reserve: bool) -> (Culling, f64) {
    let w = ((f64::from(n) / 16.0).sqrt().ceil() as u32).max(1);
    let side = f64::from(w) * 16.0;
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [side, side],
        cell_size: 16.0,
    })
    .expect("grid");
    let mut culling = Culling::new(grid, CullingConfig::new(0xC0BE)).expect("config");
    let start = std::time::Instant::now();
    if reserve {
        culling.reserve(n as usize).expect("reserve");
    }
    let mut rng = 0x9E37_79B9_7F4A_7C15u64;
    let mut unit = || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 40) as f32 / (1u64 << 24) as f32
    };
    for i in 0..n {
        let c = Vec3::new(unit() * side as f32, 0.0, unit() * side as f32);
        let aabb = Aabb::new(c - Vec3::new(2.0, 0.0, 2.0), c + Vec3::new(2.0, 6.0, 2.0));
        let d = InstanceDesc::new(MeshId(i % 64), Affine3A::from_translation(c), aabb);
        culling.register(d).expect("register");
    }
    let registration = start.elapsed().as_secs_f64();
    let camera = Vec3::new(side as f32 * 0.5, 2.0, side as f32 * 0.5);
    let v = view::look_to_mat4(camera, Vec3::NEG_Z, Vec3::Y);
    let p = proj::vulkan::perspective(1.0, 1.7, 0.1, 1000.0);
    let frustum = Frustum::from_view_projection(p * v).expect("frustum");
    let (mut tlas, mut events) = (Vec::new(), Vec::new());
    for frame in 0..3 {
        culling.begin_frame(frame).expect("frame");
        let out = culling.mitigate_latency(camera, &frustum).expect("camera");
        for r in out.requests {
            culling.set_blas(r.handle, 0xB1A5).expect("live");
        }
        culling.process_commands(usize::MAX, &mut events);
        for e in &events {
            if e.action == BlasAction::Acquire {
                culling.set_blas(e.handle, 0xB1A5).expect("live");
            }
        }
        culling.assemble(&mut tlas).expect("assemble");
        culling.process_feedback().expect("feedback");
        culling.take_commands();
    }
    (culling, registration)
}

fn row(label: &str, n: u32, registration: f64, m: &MemoryUsage) {
    let per = |b: u64| b as f64 / f64::from(n);
    println!(
        "| {label} | {n} | {registration:.3} s | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} MB | {:.1} MB |",
        per(m.records),
        per(m.handles),
        per(m.slot_occupants),
        per(m.free_lists + m.dirty),
        per(m.instance_hits + m.awaiting),
        per(m.latency_bits),
        per(m.command_queue),
        per(m.overrides),
        per(m.scratch),
        per(m.extent_lists),
        per(m.per_slot()),
        m.per_slot() as f64 / 1e6,
        (m.hitboxes + m.command_buffer) as f64 / 1e6,
    );
}

fn main() {
    let max: u32 = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(1_000_000);
    println!("CPU bytes per instance (from capacities; see lipac_core::memory)");
    println!();
    println!("| registration, when | instances | registration time | records | handles | occupants | free + dirty | hits + awaiting | latency bits | queue | overrides | scratch | extent lists | **per instance** | per-slot total | hitboxes + command buffer |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    let mut n = 10_000u32;
    while n <= max {
        for (reserve, how) in [(false, "one by one"), (true, "reserve(n) first")] {
            let (mut culling, t) = build(n, reserve);
            row(
                &format!("{how}, before take_uploads"),
                n,
                t,
                &culling.memory_usage(),
            );
            culling.take_uploads();
            row(
                &format!("{how}, after take_uploads"),
                n,
                t,
                &culling.memory_usage(),
            );
        }
        n = n.saturating_mul(10);
    }
}
