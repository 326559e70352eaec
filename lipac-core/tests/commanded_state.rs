//! The Manager's commanded state: [`Manager::ingest_readback`] sets each
//! slot's state from the kind of its newest command (add → active, remove →
//! inactive), for CPU and GPU backends alike, without reading or uploading
//! the records' state bits (Algorithm 2's), so the plan acquires and
//! releases BLASes as the commands say; commands older than one of the
//! Manager's own decisions (latency mitigation) do not move it.

use glam::{Affine3A, Vec3};
use lipac_core::build_plan::BuildEstimate;
use lipac_core::command::{Command, CommandKind};
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::instance::{InstanceDesc, MeshId};
use lipac_core::layout::InstanceState;
use lipac_core::manager::{Ack, FrameBudgets, Manager, ManagerConfig, MeshCatalog, MeshLod};
use lipac_core::math::Aabb;

fn manager() -> (Manager, Vec<lipac_core::registry::InstanceHandle>) {
    let mut catalog = MeshCatalog::new();
    let estimate = BuildEstimate {
        primitives: 100,
        result_bytes: 6400,
        build_scratch_bytes: 1600,
        update_scratch_bytes: 0,
    };
    catalog
        .insert(
            MeshId(1),
            vec![MeshLod {
                estimate,
                data_bytes: 16,
            }],
        )
        .unwrap();
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [64.0, 64.0],
        cell_size: 16.0,
    })
    .unwrap();
    let mut config = ManagerConfig::new(0xC0BE);
    config.culling.latency_mitigation = None;
    let mut m = Manager::new(grid, config, catalog).unwrap();
    let handles = (0..3)
        .map(|i| {
            let at = Vec3::new(8.0 + 16.0 * i as f32, 0.0, 8.0);
            let aabb = Aabb::new(at - Vec3::ONE, at + Vec3::ONE);
            m.register(InstanceDesc::new(
                MeshId(1),
                Affine3A::from_translation(at),
                aabb,
            ))
            .unwrap()
        })
        .collect();
    (m, handles)
}

fn word(slot: u32, kind: CommandKind) -> u32 {
    Command::new(slot, kind, 40).unwrap().encode()
}

#[test]
fn commands_move_the_commanded_state_and_the_blas_plan() {
    let (mut m, h) = manager();
    m.begin_frame(1).unwrap();
    let first = m.plan(&FrameBudgets::default()).unwrap();
    assert!(first.blas.builds().next().is_none());

    // Frame 2: the GPU turned slots 0 and 2 active.
    m.begin_frame(2).unwrap();
    let words = [word(0, CommandKind::Add), word(2, CommandKind::Add)];
    let s = m.ingest_readback(1, 2, &words);
    assert_eq!(s.accepted, 2);
    for (i, expected) in [
        (0, InstanceState::Active),
        (1, InstanceState::Inactive),
        (2, InstanceState::Active),
    ] {
        assert_eq!(m.instance(h[i]).unwrap().state, expected, "slot {i}");
    }
    let plan = m.plan(&FrameBudgets::default()).unwrap();
    assert_eq!(plan.commands.stale_kind, 0);
    assert_eq!(plan.commands.requested + plan.commands.acquired, 2);
    // No state is uploaded over the GPU's bits.
    assert!(
        plan.uploads.state_overrides.is_empty(),
        "{:?}",
        plan.uploads
    );
    let builds: Vec<_> = plan.blas.builds().map(|b| b.id).collect();
    assert_eq!(builds.len(), 1, "one shared BLAS for both");
    m.handle_ack(Ack::Built {
        build: builds[0],
        result_bytes: 6000,
        address: 0x10_0000,
    })
    .unwrap();
    assert_eq!(m.instance(h[0]).unwrap().blas, 0x10_0000);

    // Frame 3: the GPU removed slot 0; its BLAS reference goes.
    m.begin_frame(3).unwrap();
    m.ingest_readback(2, 1, &[word(0, CommandKind::Remove)]);
    assert_ne!(m.instance(h[0]).unwrap().state, InstanceState::Active);
    let plan = m.plan(&FrameBudgets::default()).unwrap();
    assert_eq!(plan.commands.released, 1);
    assert_eq!(m.instance(h[0]).unwrap().blas, 0);
    assert_eq!(m.instance(h[2]).unwrap().blas, 0x10_0000);

    // The records' state bits are neither read nor written: an add makes
    // slot 1 active while its record stays inactive.
    m.begin_frame(4).unwrap();
    m.ingest_readback(3, 1, &[word(1, CommandKind::Add)]);
    assert_eq!(m.instance(h[1]).unwrap().state, InstanceState::Active);
    assert_eq!(m.registry().state(h[1]).unwrap(), InstanceState::Inactive);
    let plan = m.plan(&FrameBudgets::default()).unwrap();
    assert_eq!(plan.commands.stale_kind, 0);
    assert_eq!(plan.commands.requested + plan.commands.acquired, 1);
}

#[test]
fn commands_older_than_a_mitigation_keep_its_override() {
    use lipac_core::latency::{ActivationHeuristic, Frustum};
    let (mut m, h) = manager();
    // The same scene with latency mitigation on.
    let mut config = ManagerConfig::new(0xC0BE);
    config.culling.latency_mitigation = Some(ActivationHeuristic::default());
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [64.0, 64.0],
        cell_size: 16.0,
    })
    .unwrap();
    let catalog = m.catalog().clone();
    let descs: Vec<_> = h.iter().map(|&x| m.registry().desc(x).unwrap()).collect();
    m = Manager::new(grid, config, catalog).unwrap();
    let h: Vec<_> = descs.into_iter().map(|d| m.register(d).unwrap()).collect();

    m.begin_frame(1).unwrap();
    m.plan(&FrameBudgets::default()).unwrap();
    m.begin_frame(2).unwrap();
    use glam::camera::rh::{proj, view};
    let eye = Vec3::new(32.0, 40.0, 32.0);
    let v = view::look_to_mat4(eye, Vec3::NEG_Y, Vec3::NEG_Z);
    let p = proj::vulkan::perspective(100f32.to_radians(), 1.0, 0.1, 500.0);
    let frustum = Frustum::from_view_projection(p * v).unwrap();
    let out = m.mitigate_latency(eye, &frustum).unwrap();
    assert!(out.requests.iter().any(|r| r.slot == 1), "{out:?}");
    assert_eq!(m.instance(h[1]).unwrap().state, InstanceState::Active);
    // Frame 1's feedback (before the override reached the GPU) said remove:
    // the override stands.
    m.ingest_readback(1, 1, &[word(1, CommandKind::Remove)]);
    assert_eq!(m.instance(h[1]).unwrap().state, InstanceState::Active);
    // Frame 2's feedback ran after the upload: it moves the mirror.
    m.ingest_readback(2, 1, &[word(1, CommandKind::Remove)]);
    assert_eq!(m.instance(h[1]).unwrap().state, InstanceState::Inactive);
}
