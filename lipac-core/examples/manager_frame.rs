//! The per-frame API of `lipac_core::manager::Manager` with a tiny synthetic
//! backend: it "builds" every BLAS at once by handing out a fake address and
//! acknowledges the build one frame later. A house is registered, rays hit its
//! cell, the house becomes active, its BLAS is built and traced, then it
//! switches to a coarser LOD, keeping the old BLAS until the new one is
//! acknowledged. (This file is also the doc test of `lipac_core::manager`.)
//!
//! cargo run -p lipac-core --example manager_frame

use glam::{Affine3A, Vec3};
use lipac_core::{
    Aabb, Ack, BuildEstimate, FrameBudgets, GridConfig, HitboxGrid, HitboxIndex, InstanceDesc,
    Manager, ManagerConfig, ManagerError, ManagerPlan, MeshCatalog, MeshId, MeshLod, ReadbackRing,
};

const UNIT_CUBE_BLAS: u64 = 0xC0BE;

/// Builds finish at once; acknowledgements arrive one frame later.
struct Backend {
    next_address: u64,
    /// (frame it arrives in, the acknowledgement)
    acks: Vec<(u64, Ack)>,
    data_buffer_bytes: u64,
}

impl Backend {
    fn execute(&mut self, plan: &ManagerPlan) {
        if let Some(growth) = plan.data_growth {
            self.data_buffer_bytes = growth.to; // grow, keeping the contents
        }
        // (write each plan.data_uploads range, upload plan.uploads records,
        // destroy plan.blas.frees, record plan.blas.batches ...)
        for build in plan.blas.builds() {
            self.next_address += 0x1_0000;
            let ack = Ack::Built {
                build: build.id,
                result_bytes: build.result_bytes, // the real size would come back
                address: self.next_address,
            };
            self.acks.push((plan.frame + 1, ack));
        }
    }

    /// Hands the acknowledgements that have arrived to the manager.
    fn deliver<H: HitboxIndex>(
        &mut self,
        frame: u64,
        manager: &mut Manager<H>,
    ) -> Result<(), ManagerError> {
        let mut i = 0;
        while i < self.acks.len() {
            if self.acks[i].0 <= frame {
                manager.handle_ack(self.acks.swap_remove(i).1)?;
            } else {
                i += 1;
            }
        }
        Ok(())
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // The engine's meshes: per LOD the build sizes and the geometry-instance
    // data an instance needs.
    let lod = |triangles: u64, data_bytes: u64| MeshLod {
        estimate: BuildEstimate {
            primitives: triangles,
            result_bytes: triangles * 64,
            build_scratch_bytes: triangles * 16,
            update_scratch_bytes: 0,
        },
        data_bytes,
    };
    let mut catalog = MeshCatalog::new();
    catalog.insert(MeshId(1), vec![lod(2000, 96), lod(500, 48)])?;

    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [64.0, 64.0],
        cell_size: 16.0,
    })?;
    let mut config = ManagerConfig::new(UNIT_CUBE_BLAS);
    config.culling.latency_mitigation = None;
    config.culling.readback_latency = 1;
    config.scheduler.lod_hysteresis_frames = 1;
    let mut manager = Manager::new(grid, config, catalog)?;
    let mut ring = ReadbackRing::new(1)?;
    let mut backend = Backend {
        next_address: 0,
        acks: Vec::new(),
        data_buffer_bytes: config.data.initial_capacity,
    };

    let aabb = Aabb::new(Vec3::new(7.0, 0.0, 7.0), Vec3::new(9.0, 2.0, 9.0));
    let at = Affine3A::from_translation(Vec3::new(8.0, 0.0, 8.0));
    let house = manager.register(InstanceDesc::new(MeshId(1), at, aabb))?;

    let mut tlas = Vec::new();
    let mut traced = Vec::new(); // the house's BLAS address per frame (0 = absent)
    for frame in 0..6 {
        manager.begin_frame(frame)?;
        backend.deliver(frame, &mut manager)?;
        while let Some(r) = ring.pop_ready(frame) {
            manager.ingest_readback(r.frame, r.counter, &r.words);
        }
        if frame == 3 {
            manager.set_lod(house, 1)?; // the camera moved away
        }
        let plan = manager.plan(&FrameBudgets::default())?;
        backend.execute(&plan);

        manager.assemble(&mut tlas)?;
        // "Trace": rays hit the house's cell hard.
        let mut house_blas = 0;
        for t in &tlas {
            let i = t.custom_index() as usize;
            if t.acceleration_structure_reference == UNIT_CUBE_BLAS {
                manager.hitboxes_mut()[i].add_hits(2500); // a hitbox's counting box
            } else {
                manager.instance_hits_mut()[i] += 2500; // the house itself
                house_blas = t.acceleration_structure_reference;
            }
        }
        traced.push(house_blas);
        manager.process_feedback()?;
        ring.push(manager.take_commands().ok_or("feedback ran this frame")?)?;

        let view = manager.instance(house)?;
        println!(
            "frame {frame}: {:?}, BLAS {:#x}, LOD requested {} traced {}, data {:?}; \
             {} builds planned",
            view.state,
            view.blas,
            view.requested_lod,
            view.traced_lod,
            view.data,
            plan.blas.builds().count(),
        );
    }
    // Frame 0's feedback activated the house; frame 1 planned its build,
    // acknowledged in frame 2, traced from frame 2 on. The LOD 1 build
    // planned in frame 4 (one frame of hysteresis) replaced it in frame 5.
    assert_eq!(traced, [0, 0, 0x1_0000, 0x1_0000, 0x1_0000, 0x2_0000]);
    assert_eq!(manager.instance(house)?.traced_lod, 1);
    assert!(backend.data_buffer_bytes >= manager.data_allocator().capacity());
    Ok(())
}
