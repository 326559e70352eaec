//! A trace recorded from a `lipac_core::Manager` (`TraceRecorder`) replays
//! in hits-only mode: every frame, every instance, and LiPaC reacts to the
//! recorded hits (the hot half of the world becomes traced geometry); a
//! run recorded on the replay's own backend is reproduced decision for
//! decision.

use glam::{Affine3A, Vec3};
use lipac_core::latency::ActivationHeuristic;
use lipac_core::manager::{RecorderOptions, TraceRecorder};
use lipac_core::trace::{Camera, TraceFormat};
use lipac_core::TlasInstance;
use lipac_core::{
    Aabb, Ack, BuildEstimate, FrameBudgets, GridConfig, HitboxGrid, InstanceDesc, Manager,
    ManagerConfig, MeshCatalog, MeshId, MeshLod, ReadbackRing,
};
use lipac_sim::compare::LipacStart;
use lipac_sim::cpu_backend::CpuBackend;
use lipac_sim::memory::mesh_lod;
use lipac_sim::record::from_trace_camera;
use lipac_sim::replay::hits::replay_hits;
use lipac_sim::replay::{ReplayConfig, ReplayMode, TraceInput};
use lipac_sim::strategy::lipac::LipacConfig;
use lipac_sim::strategy::StrategyKind;
use lipac_sim::tlas::CountingBoxes;
use lipac_sim::traversal::SlotSet;

const UNIT: u64 = 0xC0BE;
const FRAMES: u64 = 24;

/// A 128 m world of 256 instances; rays hit the west half hard. Some
/// instances move, change LOD, go and come every few frames.
fn record() -> Vec<u8> {
    let lod = |tris: u64| MeshLod {
        estimate: BuildEstimate {
            primitives: tris,
            result_bytes: tris * 64,
            build_scratch_bytes: tris * 16,
            update_scratch_bytes: 0,
        },
        data_bytes: 32,
    };
    let mut catalog = MeshCatalog::new();
    catalog.insert(MeshId(3), vec![lod(800), lod(200)]).unwrap();
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [128.0, 128.0],
        cell_size: 16.0,
    })
    .unwrap();
    let mut config = ManagerConfig::new(UNIT);
    config.culling.latency_mitigation = None;
    config.culling.readback_latency = 1;
    let mut m = Manager::new(grid, config, catalog).unwrap();
    m.attach_recorder(TraceRecorder::new(
        Vec::<u8>::new(),
        RecorderOptions::default(),
    ))
    .unwrap();
    let desc = |i: u32, shift: f32| {
        let c = Vec3::new(
            4.0 + 8.0 * (i % 16) as f32 + shift,
            1.0,
            4.0 + 8.0 * (i / 16) as f32,
        );
        InstanceDesc::new(
            MeshId(3),
            Affine3A::from_translation(c),
            Aabb::new(c - Vec3::ONE, c + Vec3::ONE),
        )
    };
    let mut handles: Vec<_> = (0..256)
        .map(|i| m.register(desc(i, 0.0)).unwrap())
        .collect();
    let mut ring = ReadbackRing::new(1).unwrap();
    let mut acks = Vec::new();
    let mut tlas = Vec::new();
    let mut next = 0u64;
    for frame in 0..FRAMES {
        m.begin_frame(frame).unwrap();
        for a in acks.drain(..) {
            m.handle_ack(a).unwrap();
        }
        while let Some(r) = ring.pop_ready(frame) {
            m.ingest_readback(r.frame, r.counter, &r.words);
        }
        m.record_camera(Camera::look_to(
            Vec3::new(64.0, 40.0, -20.0 - frame as f32),
            Vec3::new(0.0, -0.6, 1.0),
            Vec3::Y,
            1.0,
            1.0,
        ))
        .unwrap();
        let i = (frame as usize * 37) % 256;
        m.set_transform(
            handles[i],
            desc(i as u32, 0.5).transform,
            desc(i as u32, 0.5).aabb,
        )
        .unwrap();
        m.set_lod(handles[(i + 1) % 256], (frame % 2) as u32)
            .unwrap();
        if frame % 4 == 3 {
            let j = (i + 2) % 256;
            m.remove(handles[j]).unwrap();
            handles[j] = m.register(desc(j as u32, 0.0)).unwrap();
        }
        let plan = m.plan(&FrameBudgets::default()).unwrap();
        for b in plan.blas.builds() {
            next += 0x1_0000;
            acks.push(Ack::Built {
                build: b.id,
                result_bytes: b.result_bytes,
                address: next,
            });
        }
        m.assemble(&mut tlas).unwrap();
        for t in &tlas {
            let i = t.custom_index() as usize;
            let west = t.transform[3] < 64.0;
            if t.acceleration_structure_reference == UNIT {
                // Hitbox counting box (no omitted instances in this scene).
                let west = (i % 8) < 4;
                m.hitboxes_mut()[i].add_hits(if west { 40_000 } else { 0 });
            } else {
                m.instance_hits_mut()[i] += if west { 20_000 } else { 2 };
            }
        }
        m.process_feedback().unwrap();
        ring.push(m.take_commands().unwrap()).unwrap();
    }
    let done = m.detach_recorder().unwrap();
    assert_eq!(done.frames, FRAMES);
    done.into_writer().unwrap()
}

#[test]
fn a_trace_recorded_from_the_manager_replays_hits_only() {
    let bytes = record();
    let mut input = TraceInput::new(TraceFormat::Binary, bytes.as_slice()).unwrap();
    let config = ReplayConfig {
        mode: Some(ReplayMode::HitsOnly),
        ..ReplayConfig::default()
    };
    let report = replay_hits(&mut input, &config, &mut |_| {}).expect("hits-only replay");
    assert_eq!(u64::from(report.frames), FRAMES);
    assert_eq!(report.instances, 256);
    let lipac = report
        .strategies
        .iter()
        .find(|s| s.name.to_lowercase().starts_with("lipac"))
        .expect("a LiPaC run");
    assert_eq!(lipac.frames.len() as u64, FRAMES);
    // The recorded hits drive LiPaC: the west half's instances get traced
    // geometry, the east half stays in counting boxes.
    let last = lipac.frames.last().unwrap();
    assert!(last.tlas_instances > 0, "{last:?}");
    assert!(last.counting_boxes > 0, "{last:?}");
    assert!(lipac.frames.iter().map(|f| f.state_changes).sum::<u64>() > 0);
    assert!(lipac.frames.iter().map(|f| f.builds).sum::<u64>() > 0);
}

/// Per frame of a LiPaC run: TLAS records, counting boxes among them, BLAS
/// builds, refits (what its activation and deactivation decisions produce).
type Decisions = Vec<(u64, u64, u64, u64)>;

/// The hits-only replay of these tests with a warm start of the frustum
/// alone: the default one's 800 m around the camera would take the whole
/// 128 m world at once, and nothing would be culled.
fn replay_config(strategies: Vec<StrategyKind>) -> ReplayConfig {
    ReplayConfig {
        mode: Some(ReplayMode::HitsOnly),
        strategies,
        lipac_start: LipacStart::Warm(ActivationHeuristic {
            max_distance: f32::INFINITY,
            min_projected_size: 0.0,
            surround_radius: 0.0,
        }),
        ..ReplayConfig::default()
    }
}

/// The recorded run on the same [`CpuBackend`] the hits-only replay drives
/// (same configuration, same frame order: feedback of the previous frame,
/// the engine's changes, the frame), so that the replay must reproduce its
/// decisions exactly.
fn record_on_the_replays_backend(frames: u32) -> (Vec<u8>, Decisions) {
    let config = replay_config(Vec::new());
    let mut lipac =
        LipacConfig::for_rays_per_frame(u64::from(config.width) * u64::from(config.height))
            .unwrap();
    config.lipac_start.apply(&mut lipac);
    // The replay's catalog: its estimates from the header's triangle counts.
    let mut catalog = MeshCatalog::new();
    catalog
        .insert(MeshId(3), vec![mesh_lod(800), mesh_lod(200)])
        .unwrap();
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [128.0, 128.0],
        cell_size: 16.0,
    })
    .unwrap();
    let mut b = CpuBackend::new(grid, &lipac, catalog).unwrap();
    b.manager_mut()
        .attach_recorder(TraceRecorder::new(
            Vec::<u8>::new(),
            RecorderOptions::default(),
        ))
        .unwrap();
    let desc = |i: u32, shift: f32| {
        let c = Vec3::new(
            4.0 + 8.0 * (i % 16) as f32 + shift,
            1.0,
            4.0 + 8.0 * (i / 16) as f32,
        );
        InstanceDesc::new(
            MeshId(3),
            Affine3A::from_translation(c),
            Aabb::new(c - Vec3::ONE, c + Vec3::ONE),
        )
    };
    let mut handles: Vec<_> = (0..256)
        .map(|i| b.register(desc(i, 0.0)).unwrap())
        .collect();
    let counting = CountingBoxes::default();
    let mut records: Vec<TlasInstance> = Vec::new();
    let mut decisions = Vec::new();
    // The stub tracer: a hot band of hitbox columns that moves every 6
    // frames, so instances are activated and deactivated all along.
    let trace = |b: &mut CpuBackend, records: &[TlasInstance], frame: u32| {
        b.instance_hits_mut().fill(0);
        let hot = |x: f32| ((x / 16.0) as u32 + 8 - (frame / 6) % 8) % 8 < 3;
        for r in records {
            let i = r.custom_index() as usize;
            if r.sbt_offset() == counting.hitbox_box_sbt {
                let west = hot(16.0 * (i % 8) as f32 + 8.0);
                b.hitboxes_mut()[i].add_hits(if west { 40_000 } else { 3 });
            } else {
                let west = hot(r.transform[3]);
                b.instance_hits_mut()[i] += if west { 20_000 } else { 2 };
            }
        }
    };
    for frame in 0..frames {
        if frame > 0 {
            trace(&mut b, &records, frame - 1);
            b.end_frame().unwrap();
        }
        let i = (frame as usize * 37) % 256;
        let moved = desc(i as u32, 0.5);
        b.set_transform(handles[i], moved.transform, moved.aabb)
            .unwrap();
        b.set_lod(handles[(i + 1) % 256], frame % 2).unwrap();
        if frame % 4 == 3 {
            let j = (i + 2) % 256;
            b.remove(handles[j]).unwrap();
            handles[j] = b.register(desc(j as u32, 0.0)).unwrap();
        }
        b.begin_frame(frame).unwrap();
        let camera = Camera::look_to(
            Vec3::new(64.0, 40.0, -20.0 - frame as f32),
            Vec3::new(0.0, -0.6, 1.0),
            Vec3::Y,
            1.0,
            config.width as f32 / config.height as f32,
        );
        b.manager_mut().record_camera(camera).unwrap();
        // The camera the replay converts the recorded one to.
        let sim_camera = from_trace_camera(&camera).unwrap();
        let f = b.run(&sim_camera, &mut records).unwrap();
        let geometry = SlotSet::from_geometry_records(&records, &counting).len() as u64;
        decisions.push((
            records.len() as u64,
            records.len() as u64 - geometry,
            f.work.builds,
            f.work.refits,
        ));
    }
    trace(&mut b, &records, frames - 1);
    b.end_frame().unwrap();
    let done = b.manager_mut().detach_recorder().unwrap();
    assert_eq!(done.frames, u64::from(frames));
    (done.into_writer().unwrap(), decisions)
}

#[test]
fn a_hits_only_replay_makes_the_recorded_runs_decisions() {
    let frames = 40;
    let (bytes, original) = record_on_the_replays_backend(frames);
    // The run is not trivial: records and counting boxes change.
    let distinct: std::collections::BTreeSet<_> = original.iter().map(|d| (d.0, d.1)).collect();
    assert!(distinct.len() > 3, "{original:?}");
    assert!(original.iter().map(|d| d.2).sum::<u64>() > 0);
    let mut input = TraceInput::new(TraceFormat::Binary, bytes.as_slice()).unwrap();
    let config = replay_config(vec![StrategyKind::Lipac]);
    let report = replay_hits(&mut input, &config, &mut |_| {}).expect("hits-only replay");
    let lipac = report.strategy("lipac").expect("the LiPaC run");
    let replayed: Decisions = lipac
        .frames
        .iter()
        .map(|m| (m.tlas_instances, m.counting_boxes, m.builds, m.refits))
        .collect();
    assert_eq!(replayed, original);
}
