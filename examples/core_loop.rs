//! A few frames of the LiPaC loop on a tiny synthetic scene: a 4 x 4 grid of
//! 16 m hitboxes with three houses in one cell and a lamp post elsewhere.
//! Rays hit the houses' cell hard, the rest of the world barely. Prints the
//! TLAS size and the commands of every frame.
//!
//! `cargo run --example core_loop`

use glam::{Affine3A, Vec3};
use lipac::core::culling::{BlasAction, Culling, CullingConfig, ReadbackRing};
use lipac::core::error::CoreError;
use lipac::core::grid::{GridConfig, HitboxGrid};
use lipac::core::instance::{InstanceDesc, MeshId};
use lipac::core::math::Aabb;

const UNIT_CUBE_BLAS: u64 = 0xC0BE;

fn main() -> Result<(), CoreError> {
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [64.0, 64.0],
        cell_size: 16.0,
    })?;
    let mut config = CullingConfig::new(UNIT_CUBE_BLAS);
    config.latency_mitigation = None;
    let mut culling = Culling::new(grid, config)?;
    let mut ring = ReadbackRing::new(config.readback_latency)?;
    for (x, z, mesh) in [
        (4.0, 4.0, 1),
        (8.0, 10.0, 1),
        (12.0, 5.0, 2),
        (40.0, 40.0, 3),
    ] {
        let aabb = Aabb::new(
            Vec3::new(x - 1.5, 0.0, z - 1.5),
            Vec3::new(x + 1.5, 5.0, z + 1.5),
        );
        let at = Affine3A::from_translation(Vec3::new(x, 0.0, z));
        culling.register(InstanceDesc::new(MeshId(mesh), at, aabb))?;
    }

    let (mut tlas, mut events) = (Vec::new(), Vec::new());
    let mut next_blas = 0x1000;
    for frame in 0..6 {
        culling.begin_frame(frame)?;
        while let Some(r) = ring.pop_ready(frame) {
            culling.ingest_readback(r.frame, r.counter, &r.words);
        }
        let mut processed = culling.process_commands(usize::MAX, &mut events);
        for e in &events {
            if e.action == BlasAction::Acquire {
                next_blas += 1; // a real manager looks up or builds the BLAS
                culling.set_blas(e.handle, next_blas)?;
                processed.acquired += 1;
            }
        }
        let stats = culling.assemble(&mut tlas)?;
        // Stub tracer: hitbox 0 (the houses' cell) is in full view.
        for r in &tlas {
            let i = r.custom_index() as usize;
            if r.acceleration_structure_reference == UNIT_CUBE_BLAS {
                culling.hitboxes_mut()[i].add_hits(if i == 0 { 3000 } else { 20 });
            } else {
                culling.instance_hits_mut()[i] = 900;
            }
        }
        let feedback = culling.process_feedback()?;
        let readback = culling.take_commands().expect("feedback ran this frame");
        println!(
            "frame {frame}: TLAS {} records ({} instances, {} hitbox boxes); \
             acquired {} BLASes; feedback: {} hitboxes activated, {} commands",
            tlas.len(),
            stats.active,
            stats.hitbox_boxes,
            processed.acquired,
            feedback.hitboxes_activated,
            readback.counter
        );
        ring.push(readback)?;
    }
    Ok(())
}
