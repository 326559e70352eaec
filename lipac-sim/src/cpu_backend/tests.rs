use glam::{Affine3A, Vec3};
use lipac_core::grid::GridConfig;
use lipac_core::instance::{InstanceFlags, MeshId};

use super::*;
use crate::memory::mesh_lod;

fn backend(latency: u32) -> CpuBackend {
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [64.0, 64.0],
        cell_size: 32.0,
    })
    .unwrap();
    let mut catalog = MeshCatalog::new();
    catalog
        .insert(MeshId(1), vec![mesh_lod(100), mesh_lod(10)])
        .unwrap();
    // A cold start: what is active, hits activated (the default warm
    // start takes both instances, within 800 m of the camera); one
    // counting box per hitbox (`frame` heats the hitbox boxes, not merged
    // ones).
    let config = LipacConfig {
        readback_latency: latency,
        warm_start: None,
        ..LipacConfig::for_rays_per_frame(1000)
            .unwrap()
            .with_adaptive_hitboxes(0)
    };
    CpuBackend::new(grid, &config, catalog).unwrap()
}

fn desc(x: f32, flags: InstanceFlags) -> InstanceDesc {
    let aabb = Aabb::new(Vec3::new(x - 1.0, 0.0, 7.0), Vec3::new(x + 1.0, 2.0, 9.0));
    InstanceDesc {
        flags,
        ..InstanceDesc::new(
            MeshId(1),
            Affine3A::from_translation(Vec3::new(x, 0.0, 8.0)),
            aabb,
        )
    }
}

/// One frame with `heat` hits on every traced record.
fn frame(b: &mut CpuBackend, f: u32, out: &mut Vec<TlasInstance>) -> BackendFrame {
    let counting = CountingBoxes::default();
    for t in out.clone() {
        let i = t.custom_index() as usize;
        if t.sbt_offset() == counting.hitbox_box_sbt {
            b.hitboxes_mut()[i].add_hits(5000);
        } else {
            b.instance_hits_mut()[i] += 5000;
        }
    }
    b.end_frame().unwrap();
    b.begin_frame(f).unwrap();
    let camera =
        FlyCamera::look_at(Vec3::new(8.0, 2.0, 0.0), Vec3::new(8.0, 2.0, 8.0), 1.0, 1.0).unwrap();
    b.run(&camera, out).unwrap()
}

#[test]
fn hits_activate_instances_and_their_builds_are_acknowledged() {
    let mut b = backend(2);
    let shared = b.register(desc(8.0, InstanceFlags::STATIC)).unwrap();
    let own = b
        .register(desc(
            40.0,
            InstanceFlags::UNIQUE_BLAS | InstanceFlags::STATIC,
        ))
        .unwrap();
    let mut out = Vec::new();
    let mut work = BlasWork::default();
    let mut ingested = 0;
    for f in 0..30 {
        let s = frame(&mut b, f, &mut out);
        work.add(&s.work);
        ingested += s.commands_ingested;
        assert!(b.readbacks_in_flight() <= 2);
    }
    assert!(ingested > 0);
    // Both built once (a shared and an own static BLAS), never refit.
    assert_eq!((work.builds, work.refits), (2, 0), "{work:?}");
    let counting = CountingBoxes::default();
    for h in [shared, own] {
        let v = b.instance(h).unwrap();
        assert_ne!(v.blas, 0);
        assert!(out.iter().any(|t| t.custom_index() == v.slot
            && t.sbt_offset() != counting.hitbox_box_sbt
            && t.sbt_offset() != counting.instance_box_sbt));
    }
    assert_eq!(b.blas_bytes(), 2 * crate::memory::blas_bytes(100));
    assert_eq!(b.slot_count(), 2);
}

#[test]
fn frames_are_refused_out_of_order() {
    let mut b = backend(1);
    let camera = FlyCamera::look_at(Vec3::ZERO, Vec3::Z, 1.0, 1.0).unwrap();
    let mut out = Vec::new();
    assert!(b.run(&camera, &mut out).is_err(), "run before begin_frame");
    b.begin_frame(0).unwrap();
    assert!(b.begin_frame(1).is_err(), "begin_frame before end_frame");
    b.run(&camera, &mut out).unwrap();
    b.end_frame().unwrap();
    b.begin_frame(1).unwrap();
    assert!(b.frame_open());
}

#[test]
fn a_bad_configuration_is_an_error() {
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [64.0, 64.0],
        cell_size: 32.0,
    })
    .unwrap();
    let config = LipacConfig {
        readback_latency: 0,
        ..LipacConfig::for_rays_per_frame(1000).unwrap()
    };
    assert!(CpuBackend::new(grid, &config, MeshCatalog::new()).is_err());
}
