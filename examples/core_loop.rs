//! A few frames of the LiPaC loop on a tiny synthetic scene, driven through
//! the `Manager`: a 4 x 4 grid of 16 m hitboxes with three houses in one
//! cell and a lamp post elsewhere. Rays hit the houses' cell hard, the rest
//! of the world barely. The "backend" builds every planned BLAS at once and
//! acknowledges it in the next frame. Prints the TLAS size, the BLAS work
//! and the commands of every frame.
//!
//! `cargo run --example core_loop`

use glam::{Affine3A, Vec3};
use lipac::core::{
    Aabb, Ack, BuildEstimate, FrameBudgets, GridConfig, HitboxGrid, InstanceDesc, Manager,
    ManagerConfig, MeshCatalog, MeshId, MeshLod, ReadbackRing,
};

const UNIT_CUBE_BLAS: u64 = 0xC0BE;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut catalog = MeshCatalog::new();
    for (mesh, triangles) in [(1, 2000), (2, 1200), (3, 100)] {
        let lod = MeshLod {
            estimate: BuildEstimate {
                primitives: triangles,
                result_bytes: triangles * 64,
                build_scratch_bytes: triangles * 16,
                update_scratch_bytes: 0,
            },
            data_bytes: 64,
        };
        catalog.insert(MeshId(mesh), vec![lod])?;
    }
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [64.0, 64.0],
        cell_size: 16.0,
    })?;
    let mut config = ManagerConfig::new(UNIT_CUBE_BLAS);
    config.culling.latency_mitigation = None;
    let mut manager = Manager::new(grid, config, catalog)?;
    let mut ring = ReadbackRing::new(config.culling.readback_latency)?;
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
        manager.register(InstanceDesc::new(MeshId(mesh), at, aabb))?;
    }

    let mut tlas = Vec::new();
    let mut acks: Vec<Ack> = Vec::new(); // last frame's builds, acknowledged now
    let mut next_blas = 0x1000;
    for frame in 0..6 {
        manager.begin_frame(frame)?;
        for ack in acks.drain(..) {
            manager.handle_ack(ack)?;
        }
        while let Some(r) = ring.pop_ready(frame) {
            manager.ingest_readback(r.frame, r.counter, &r.words);
        }
        let plan = manager.plan(&FrameBudgets::default())?;
        // The "backend": every build finishes at once (a real one records
        // them into a command buffer and acknowledges them when done).
        for build in plan.blas.builds() {
            next_blas += 0x100;
            acks.push(Ack::Built {
                build: build.id,
                result_bytes: build.result_bytes,
                address: next_blas,
            });
        }
        let stats = manager.assemble(&mut tlas)?;
        // Stub tracer: hitbox 0 (the houses' cell) is in full view.
        for r in &tlas {
            let i = r.custom_index() as usize;
            if r.acceleration_structure_reference == UNIT_CUBE_BLAS {
                manager.hitboxes_mut()[i].add_hits(if i == 0 { 3000 } else { 20 });
            } else {
                manager.instance_hits_mut()[i] = 900;
            }
        }
        let feedback = manager.process_feedback()?;
        let readback = manager.take_commands().ok_or("feedback ran this frame")?;
        println!(
            "frame {frame}: TLAS {} records ({} instances, {} hitbox boxes); \
             {} BLAS builds planned, {} commands processed; feedback: {} hitboxes \
             activated, {} commands",
            tlas.len(),
            stats.active,
            stats.hitbox_boxes,
            plan.blas.builds().count(),
            plan.commands.drained,
            feedback.hitboxes_activated,
            readback.counter
        );
        ring.push(readback)?;
    }
    Ok(())
}
