//! The Manager's trace recorder: a scripted scene (adds, moves, LOD changes,
//! removes over several frames, hits) recorded, read back through the
//! reader (which validates every frame) and compared with the calls made;
//! a writer failing mid-run stops the recorder with a clear error and the
//! manager keeps working.

use std::collections::HashMap;
use std::io::{self, Write};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use glam::{Affine3A, Quat, Vec3};
use lipac_core::manager::{RecorderError, RecorderOptions, TraceRecorder, DEFAULT_CAMERA};
use lipac_core::math::affine_to_rows;
use lipac_core::trace::{
    Camera, InstanceEvent, JsonlReader, LodGeometry, Pose, TraceReader, UpdateInstance,
};
use lipac_core::{
    Aabb, Ack, BuildEstimate, FrameBudgets, GridConfig, HitboxGrid, InstanceDesc, InstanceFlags,
    InstanceHandle, Manager, ManagerConfig, MeshCatalog, MeshId, MeshLod, ReadbackRing,
};
use lipac_test_support::synthetic::ImmediateAcks;

const UNIT: u64 = 0xC0BE;

fn lod(tris: u64) -> MeshLod {
    MeshLod {
        estimate: BuildEstimate {
            primitives: tris,
            result_bytes: tris * 64,
            build_scratch_bytes: tris * 16,
            update_scratch_bytes: tris * 8,
        },
        data_bytes: 64,
    }
}

fn manager() -> Manager {
    let mut catalog = MeshCatalog::new();
    catalog
        .insert(MeshId(1), vec![lod(1000), lod(250)])
        .unwrap();
    catalog.insert(MeshId(7), vec![lod(12)]).unwrap();
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [128.0, 128.0],
        cell_size: 16.0,
    })
    .unwrap();
    let mut config = ManagerConfig::new(UNIT);
    config.culling.latency_mitigation = None;
    config.culling.readback_latency = 1;
    config.scheduler.lod_hysteresis_frames = 1;
    Manager::new(grid, config, catalog).unwrap()
}

fn desc(mesh: u32, x: f32, z: f32) -> InstanceDesc {
    let c = Vec3::new(x, 1.0, z);
    InstanceDesc::new(
        MeshId(mesh),
        Affine3A::from_rotation_translation(Quat::from_rotation_y(x * 0.1), c),
        Aabb::new(c - Vec3::splat(1.0), c + Vec3::splat(1.0)),
    )
}

fn pose_of(d: &InstanceDesc) -> Pose {
    Pose {
        transform: affine_to_rows(&d.transform),
        aabb: d.aabb,
    }
}

/// Drives one frame's backend side: acks of last frame, read-backs, plan,
/// "builds" acknowledged next frame, assemble, hits on everything traced,
/// feedback.
struct Loop {
    ring: ReadbackRing,
    acks: Vec<Ack>,
    immediate: ImmediateAcks,
    tlas: Vec<lipac_core::TlasInstance>,
    /// Hits the stub tracer wrote, per frame.
    traced: Vec<u64>,
}

impl Loop {
    fn new() -> Self {
        Self {
            ring: ReadbackRing::new(1).unwrap(),
            acks: Vec::new(),
            immediate: ImmediateAcks::new(0x1_0000),
            tlas: Vec::new(),
            traced: Vec::new(),
        }
    }
    fn before_plan(&mut self, m: &mut Manager, frame: u64) {
        m.begin_frame(frame).unwrap();
        for a in self.acks.drain(..) {
            m.handle_ack(a).unwrap();
        }
        while let Some(r) = self.ring.pop_ready(frame) {
            m.ingest_readback(r.frame, r.counter, &r.words);
        }
    }
    fn plan_and_trace(&mut self, m: &mut Manager) {
        let plan = m.plan(&FrameBudgets::default()).unwrap();
        self.acks.extend(self.immediate.acks(&plan.blas));
        m.assemble(&mut self.tlas).unwrap();
        let mut total = 0;
        for t in &self.tlas {
            let i = t.custom_index() as usize;
            let h = if t.acceleration_structure_reference == UNIT {
                m.hitboxes_mut()[i].add_hits(2501);
                2501
            } else {
                m.instance_hits_mut()[i] += 3000 + i as u32;
                3000 + i as u32
            };
            total += u64::from(h);
        }
        self.traced.push(total);
        m.process_feedback().unwrap();
        self.ring.push(m.take_commands().unwrap()).unwrap();
    }
}

fn upd(id: u64) -> UpdateInstance {
    UpdateInstance {
        id,
        pose: None,
        lod: None,
        flags: None,
        mask: None,
    }
}

#[test]
fn scripted_scene_round_trips_through_the_trace() {
    let mut m = manager();
    let options = RecorderOptions {
        scene_name: "scripted".into(),
        ..RecorderOptions::default()
    };
    let mut rec = TraceRecorder::new(Vec::<u8>::new(), options);
    let tri = LodGeometry {
        positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0]],
        indices: (0..36).map(|i| i % 3).collect(),
    };
    rec.set_geometry(MeshId(7), 0, tri.clone()).unwrap();
    m.attach_recorder(rec).unwrap();
    assert_eq!(
        m.attach_recorder(TraceRecorder::new(
            Vec::<u8>::new(),
            RecorderOptions::default()
        )),
        Err(RecorderError::AlreadyAttached)
    );

    let mut lp = Loop::new();
    // Expected events per frame, built beside the calls.
    let mut expected: Vec<Vec<InstanceEvent>> = vec![Vec::new(); 8];
    let mut cameras = vec![DEFAULT_CAMERA; 8];
    let mut handles: HashMap<u64, InstanceHandle> = HashMap::new();
    let mut next_id = 0u64;
    let mut add = |m: &mut Manager, frame: usize, d: InstanceDesc, exp: &mut Vec<Vec<_>>| {
        let h = m.register(d).unwrap();
        let id = next_id;
        next_id += 1;
        assert_eq!(m.trace_id(h), Some(id));
        exp[frame].push(InstanceEvent::Add(lipac_core::trace::AddInstance {
            id,
            mesh: d.mesh,
            lod: d.lod,
            flags: d.flags,
            mask: (d.mask != 0xFF).then_some(d.mask),
            pose: pose_of(&d),
            // The manager's GPU slot: the index of the instance's hits.
            slot: Some(m.registry().slot(h).unwrap()),
        }));
        (id, h)
    };

    // Scene load before the first frame: part of frame 0.
    for i in 0..6u32 {
        let mut d = desc(if i % 3 == 0 { 7 } else { 1 }, 8.0 + 16.0 * i as f32, 8.0);
        if i == 4 {
            d.flags = InstanceFlags::STATIC | InstanceFlags::PINNED;
            d.mask = 0x0F;
        }
        let (id, h) = add(&mut m, 0, d, &mut expected);
        handles.insert(id, h);
    }
    let mut removed_slots = Vec::new();
    for frame in 0..8u64 {
        let f = frame as usize;
        lp.before_plan(&mut m, frame);
        if frame % 3 == 1 {
            let cam = Camera::look_to(
                Vec3::new(frame as f32, 20.0, -5.0),
                Vec3::new(0.3, -0.5, 1.0),
                Vec3::Y,
                1.1,
                1.5,
            );
            m.record_camera(cam).unwrap();
            for c in &mut cameras[f..] {
                *c = cam;
            }
        }
        match frame {
            1 => {
                // Moves (bit-exact poses) and a LOD change.
                let d = desc(1, 40.5, 23.25);
                m.set_transform(handles[&1], d.transform, d.aabb).unwrap();
                expected[f].push(InstanceEvent::Update(UpdateInstance {
                    pose: Some(pose_of(&d)),
                    ..upd(1)
                }));
                m.set_lod(handles[&2], 1).unwrap();
                expected[f].push(InstanceEvent::Update(UpdateInstance {
                    lod: Some(1),
                    ..upd(2)
                }));
            }
            2 => {
                let h = handles.remove(&0).unwrap();
                removed_slots.push(m.instance(h).unwrap().slot);
                m.remove(h).unwrap();
                expected[f].push(InstanceEvent::Remove { id: 0 });
            }
            4 => {
                // update() with a new LOD, flags kept, mask changed: one event.
                let mut d = desc(1, 70.0, 70.0);
                d.lod = 1;
                d.mask = 0x3;
                m.update(handles[&5], d).unwrap();
                expected[f].push(InstanceEvent::Update(UpdateInstance {
                    pose: Some(pose_of(&d)),
                    lod: Some(1),
                    mask: Some(0x3),
                    ..upd(5)
                }));
            }
            6 => {
                // Unpinned: the flag change is recorded.
                let mut d = desc(1, 8.0 + 16.0 * 4.0, 8.0);
                d.flags = InstanceFlags::STATIC;
                d.mask = 0x0F;
                m.update(handles[&4], d).unwrap();
                expected[f].push(InstanceEvent::Update(UpdateInstance {
                    pose: Some(pose_of(&d)),
                    flags: Some(InstanceFlags::STATIC),
                    ..upd(4)
                }));
            }
            7 => {
                // The removed slot is reused (quarantine over): a new id.
                let (id, h) = add(&mut m, f, desc(7, 100.0, 100.0), &mut expected);
                assert!(removed_slots.contains(&m.instance(h).unwrap().slot));
                assert_eq!(id, 6);
                handles.insert(id, h);
            }
            _ => {}
        }
        lp.plan_and_trace(&mut m);
        if frame == 5 {
            // After frame 5's plan: recorded with frame 6.
            let h = handles.remove(&3).unwrap();
            m.remove(h).unwrap();
            expected[f + 1].push(InstanceEvent::Remove { id: 3 });
        }
    }
    // A change after the last plan is not written.
    m.set_lod(handles[&1], 1).unwrap();
    let done = m.detach_recorder().unwrap();
    assert_eq!(done.frames, 8);
    assert_eq!(done.unwritten_events, 1);
    assert_eq!(m.detach_recorder().unwrap_err(), RecorderError::NotAttached);
    assert_eq!(
        done.events,
        expected.iter().map(|e| e.len() as u64).sum::<u64>()
    );
    let bytes: Vec<u8> = done.into_writer().unwrap();

    let mut r = TraceReader::new(bytes.as_slice()).unwrap();
    let h = r.header().clone();
    assert_eq!(h.scene_name, "scripted");
    assert_eq!(h.world.min, [0.0, 0.0]);
    assert_eq!(h.world.max, [128.0, 128.0]);
    assert_eq!(h.world.cell_size, 16.0);
    let ids: Vec<u32> = h.meshes.iter().map(|m| m.id.0).collect();
    assert_eq!(ids, [1, 7]);
    let tris: Vec<u32> = h.meshes[0].lods.iter().map(|l| l.triangles).collect();
    assert_eq!(tris, [1000, 250]);
    assert_eq!(h.meshes[1].lods[0].geometry.as_ref(), Some(&tri));
    assert_eq!(
        h.meshes[1].bounds,
        Aabb::new(Vec3::ZERO, Vec3::new(1.0, 2.0, 0.0))
    );
    assert!(h.meshes[0].lods[0].geometry.is_none());

    let mut hit_frames = 0;
    for (f, exp) in expected.iter().enumerate() {
        let frame = r.next_frame().unwrap().expect("frame");
        assert_eq!(frame.number, f as u64);
        assert_eq!(&frame.events, exp, "frame {f}");
        assert_eq!(frame.camera, cameras[f], "frame {f}");
        let hits = frame.hits.expect("hits recorded");
        hit_frames += usize::from(!hits.is_empty());
        // Every ray the tracer counted is in the trace, once.
        let sum: u64 = hits.iter().map(|h| u64::from(h.hits)).sum();
        assert_eq!(sum, lp.traced[f], "frame {f}");
        // Every recorded hit names a live instance (the reader checked it)
        // and is positive.
        assert!(hits.iter().all(|h| h.hits > 0));
    }
    assert!(r.next_frame().unwrap().is_none());
    assert!(r.is_finished());
    assert!(hit_frames >= 6, "{hit_frames} frames with hits");
    // The pinned flag survives the JSON-lines form too.
    let jsonl = lipac_core::trace::binary_to_jsonl(
        bytes.as_slice(),
        Vec::new(),
        lipac_core::trace::TraceLimits::default(),
    )
    .unwrap();
    let text = String::from_utf8(jsonl.clone()).unwrap();
    assert!(text.contains(r#""flags":["static","pinned"]"#), "{text}");
    let back = lipac_core::trace::jsonl_to_binary(
        jsonl.as_slice(),
        Vec::new(),
        lipac_core::trace::TraceLimits::default(),
    )
    .unwrap();
    assert_eq!(back, bytes);
}

#[test]
fn counting_box_hits_are_split_over_inactive_instances() {
    let mut m = manager();
    m.attach_recorder(TraceRecorder::jsonl(
        Vec::<u8>::new(),
        RecorderOptions::default(),
    ))
    .unwrap();
    // Three inactive instances in one cell, one in another.
    for x in [3.0, 5.0, 7.0, 40.0] {
        m.register(desc(1, x, 3.0)).unwrap();
    }
    let mut lp = Loop::new();
    lp.before_plan(&mut m, 0);
    lp.plan_and_trace(&mut m); // 2501 hits per counting box
    let bytes: Vec<u8> = m.detach_recorder().unwrap().into_writer().unwrap();
    let mut r = JsonlReader::new(bytes.as_slice()).unwrap();
    let f = r.next_frame().unwrap().unwrap();
    let hits: Vec<(u64, u32)> = f.hits.unwrap().iter().map(|h| (h.id, h.hits)).collect();
    assert_eq!(hits, [(0, 834), (1, 834), (2, 833), (3, 2501)]);
}

#[test]
fn a_pinned_instance_takes_no_counting_box_share() {
    let mut m = manager();
    m.attach_recorder(TraceRecorder::new(
        Vec::<u8>::new(),
        RecorderOptions::default(),
    ))
    .unwrap();
    // Two inactive instances and a pinned one (always traced) in one cell.
    for x in [3.0, 5.0] {
        m.register(desc(1, x, 3.0)).unwrap();
    }
    let mut d = desc(1, 7.0, 3.0);
    d.flags = InstanceFlags::PINNED;
    m.register(d).unwrap();
    let mut lp = Loop::new();
    lp.before_plan(&mut m, 0);
    lp.plan_and_trace(&mut m);
    let bytes: Vec<u8> = m.detach_recorder().unwrap().into_writer().unwrap();
    let mut r = TraceReader::new(bytes.as_slice()).unwrap();
    let f = r.next_frame().unwrap().unwrap();
    let hits: Vec<(u64, u32)> = f.hits.unwrap().iter().map(|h| (h.id, h.hits)).collect();
    // The box's 2501 over the two inactive ones only (the pinned one is
    // never reduced into the box; without its BLAS yet, it has no hits).
    assert_eq!(hits, [(0, 1251), (1, 1250)]);
}

#[test]
fn hits_leave_out_instances_registered_after_the_plan() {
    // The recorder does not look the hits' ids up (they are consistent by
    // construction): an instance registered between plan and feedback
    // belongs to the next frame, so its hits must not be in this one, or
    // the trace would not read back.
    let mut m = manager();
    m.attach_recorder(TraceRecorder::new(
        Vec::<u8>::new(),
        RecorderOptions::default(),
    ))
    .unwrap();
    let a = m.register(desc(7, 3.0, 3.0)).unwrap();
    let mut lp = Loop::new();
    lp.before_plan(&mut m, 0);
    m.plan(&FrameBudgets::default()).unwrap();
    m.remove(a).unwrap();
    let b = m.register(desc(7, 40.0, 40.0)).unwrap();
    assert_eq!(m.trace_id(b), Some(1));
    // Hits on every slot, the new instance's among them.
    m.instance_hits_mut().iter_mut().for_each(|h| *h += 77);
    m.process_feedback().unwrap();
    lp.ring.push(m.take_commands().unwrap()).unwrap();
    lp.before_plan(&mut m, 1);
    m.plan(&FrameBudgets::default()).unwrap();
    m.instance_hits_mut().iter_mut().for_each(|h| *h += 5);
    m.process_feedback().unwrap();
    lp.ring.push(m.take_commands().unwrap()).unwrap();
    let bytes: Vec<u8> = m.detach_recorder().unwrap().into_writer().unwrap();
    let mut r = TraceReader::new(bytes.as_slice()).unwrap();
    let f0 = r.next_frame().unwrap().unwrap();
    // Instance 0's removal and instance 1's add are frame 1's events:
    // neither has hits in frame 0 (1 is not live yet, 0's slot was freed).
    assert_eq!(f0.hits.as_deref(), Some(&[][..]));
    let f1 = r.next_frame().unwrap().unwrap();
    assert_eq!(f1.events.len(), 2);
    let hits: Vec<(u64, u32)> = f1.hits.unwrap().iter().map(|h| (h.id, h.hits)).collect();
    assert_eq!(hits, [(1, 5)]);
    assert_eq!(r.next_frame().unwrap(), None);
}

#[test]
fn a_refused_process_feedback_records_no_hits() {
    // The recorder takes a frame's hits before Algorithm 2 changes the
    // states; a call the manager then refuses (here: the frame's feedback
    // was already processed) must leave the frame's hits as they were.
    let mut m = manager();
    m.attach_recorder(TraceRecorder::new(
        Vec::<u8>::new(),
        RecorderOptions::default(),
    ))
    .unwrap();
    for x in [3.0, 5.0, 40.0] {
        m.register(desc(1, x, 3.0)).unwrap();
    }
    let mut lp = Loop::new();
    for frame in 0..3 {
        lp.before_plan(&mut m, frame);
        lp.plan_and_trace(&mut m);
        // More hits, then a second feedback in the same frame: refused.
        m.instance_hits_mut()
            .iter_mut()
            .for_each(|h| *h += 1_000_000);
        for b in m.hitboxes_mut() {
            b.add_hits(1_000_000);
        }
        assert!(m.process_feedback().is_err());
    }
    let bytes: Vec<u8> = m.detach_recorder().unwrap().into_writer().unwrap();
    let mut r = TraceReader::new(bytes.as_slice()).unwrap();
    for frame in 0..3 {
        let f = r.next_frame().unwrap().unwrap();
        let hits = f.hits.expect("hits of the accepted call");
        let sum: u64 = hits.iter().map(|h| u64::from(h.hits)).sum();
        assert_eq!(sum, lp.traced[frame], "frame {frame}");
        assert!(
            hits.iter().all(|h| h.hits < 1_000_000),
            "frame {frame}: {hits:?}"
        );
    }
    assert_eq!(r.next_frame().unwrap(), None);
}

#[test]
fn instances_registered_before_attaching_get_no_hits() {
    // Their slots are in the hit counters but not in the trace: the
    // recorder's slot hits must leave them at 0 (a reader would refuse
    // hits for a slot no live instance holds).
    let mut m = manager();
    m.register(desc(1, 3.0, 3.0)).unwrap();
    m.register(desc(1, 5.0, 3.0)).unwrap();
    m.attach_recorder(TraceRecorder::new(
        Vec::<u8>::new(),
        RecorderOptions::default(),
    ))
    .unwrap();
    let c = m.register(desc(7, 40.0, 40.0)).unwrap();
    let mut lp = Loop::new();
    lp.before_plan(&mut m, 0);
    m.plan(&FrameBudgets::default()).unwrap();
    m.instance_hits_mut().iter_mut().for_each(|h| *h += 9);
    m.process_feedback().unwrap();
    lp.ring.push(m.take_commands().unwrap()).unwrap();
    let bytes: Vec<u8> = m.detach_recorder().unwrap().into_writer().unwrap();
    let mut r = TraceReader::new(bytes.as_slice()).unwrap();
    assert_eq!(r.version(), 2);
    let f = r.next_frame().unwrap().unwrap();
    assert_eq!(f.events.len(), 1);
    assert_eq!(m.trace_id(c), None); // detached
    let sh = f.slot_hits.as_ref().expect("hits by slot");
    assert_eq!(sh.slots, [0, 0, 9]);
    let hits: Vec<(u64, u32)> = f.hits.unwrap().iter().map(|h| (h.id, h.hits)).collect();
    assert_eq!(hits, [(0, 9)]);
}

/// Fails every write after `ok` bytes.
#[derive(Clone)]
struct Failing {
    left: Arc<AtomicUsize>,
}

impl Write for Failing {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let left = self.left.load(Ordering::Relaxed);
        if left < buf.len() {
            return Err(io::Error::other("disk full"));
        }
        self.left.store(left - buf.len(), Ordering::Relaxed);
        Ok(buf.len())
    }
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

#[test]
fn a_failing_writer_stops_the_recorder_and_the_manager_keeps_working() {
    let mut m = manager();
    let w = Failing {
        left: Arc::new(AtomicUsize::new(600)),
    };
    m.attach_recorder(TraceRecorder::new(w, RecorderOptions::default()))
        .unwrap();
    let mut reference = manager();
    let mut lp = Loop::new();
    let mut lp_ref = Loop::new();
    let mut hs = Vec::new();
    let mut failed_at = None;
    for frame in 0..12u64 {
        for mm in [&mut m, &mut reference] {
            let h = mm.register(desc(1, 4.0 + 8.0 * frame as f32, 9.0)).unwrap();
            if mm.recorder().is_some() {
                hs.push(h);
            }
        }
        lp.before_plan(&mut m, frame);
        lp_ref.before_plan(&mut reference, frame);
        let cam = Camera::look_to(Vec3::ZERO, Vec3::X, Vec3::Y, 1.0, 1.0);
        match m.record_camera(cam) {
            Ok(()) => assert!(failed_at.is_none()),
            Err(e) => {
                assert!(matches!(e, RecorderError::Write(_)), "{e}");
                assert!(e.to_string().contains("disk full"), "{e}");
                failed_at.get_or_insert(frame);
            }
        }
        lp.plan_and_trace(&mut m);
        lp_ref.plan_and_trace(&mut reference);
        // The manager's state does not depend on the recorder.
        assert_eq!(m.records(), reference.records(), "frame {frame}");
        assert_eq!(m.stats(), reference.stats(), "frame {frame}");
    }
    let failed_at = failed_at.expect("the writer failed");
    assert!(failed_at > 0, "the header and some frames fit");
    assert!(m.recorder_error().is_some());
    // Invalid cameras are refused before anything is recorded.
    let bad = Camera {
        aspect: -1.0,
        ..DEFAULT_CAMERA
    };
    let mut m2 = manager();
    m2.attach_recorder(TraceRecorder::new(
        Vec::<u8>::new(),
        RecorderOptions::default(),
    ))
    .unwrap();
    assert!(matches!(
        m2.record_camera(bad),
        Err(RecorderError::InvalidCamera(_))
    ));
    // Without a recorder, record_camera does nothing.
    assert_eq!(reference.record_camera(bad), Ok(()));
    let e = m.detach_recorder().unwrap_err();
    assert!(matches!(e, RecorderError::Write(_)));
    // The manager keeps working after the recorder is gone.
    m.remove(hs[0]).unwrap();
    lp.before_plan(&mut m, 12);
    lp.plan_and_trace(&mut m);
}

#[test]
fn meshes_registered_after_the_header_stop_the_recorder() {
    let mut m = manager();
    m.attach_recorder(TraceRecorder::new(
        Vec::<u8>::new(),
        RecorderOptions::default(),
    ))
    .unwrap();
    let mut lp = Loop::new();
    lp.before_plan(&mut m, 0);
    lp.plan_and_trace(&mut m);
    lp.before_plan(&mut m, 1); // frame 0 and the header are written
    m.register_mesh(MeshId(9), vec![lod(4)]).unwrap();
    assert!(m
        .recorder_mut()
        .unwrap()
        .set_mesh_bounds(MeshId(1), Aabb::new(Vec3::ZERO, Vec3::ONE))
        .is_err());
    lp.plan_and_trace(&mut m);
    let e = m.detach_recorder().unwrap_err();
    assert!(matches!(e, RecorderError::Header { .. }), "{e}");
    assert!(e.to_string().contains("registered after"), "{e}");
}

#[test]
fn a_manager_with_a_recorder_stays_send_and_sync() {
    fn check<T: Send + Sync>(_: &T) {}
    let mut m = manager();
    m.attach_recorder(TraceRecorder::new(io::sink(), RecorderOptions::default()))
        .unwrap();
    check(&m);
    assert!(m.recorder().is_some());
}
