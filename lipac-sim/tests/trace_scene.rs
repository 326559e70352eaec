//! Geometry replay of traces lipac never generated (written here through
//! lipac-core's trace writer): instances added, moved, re-LODed and removed
//! at any frame, the error reported as in `compare`.

use std::io::Cursor;

use glam::{Affine3A, Quat, Vec3};
use lipac_core::instance::{InstanceFlags, MeshId};
use lipac_core::math::{affine_to_rows, Aabb};
use lipac_core::trace::{
    AddInstance, Camera, Frame, InstanceEvent, LodGeometry, LodInfo, MeshInfo, Pose, TraceFormat,
    TraceHeader, TraceWriter, UpdateInstance, WorldInfo,
};
use lipac_sim::compare::LipacStart;
use lipac_sim::mesh::leaf_opaque;
use lipac_sim::replay::{ReplayConfig, TraceInput};
use lipac_sim::strategy::StrategyKind;
use lipac_sim::trace_scene::{
    replay_stream, replay_trace, TracePlan, TraceReplay, TraceScene, TraceSceneOptions,
};
use lipac_sim::SimError;

/// An axis-aligned box as indexed triangles.
fn boxed(min: Vec3, max: Vec3) -> LodGeometry {
    let mut positions = Vec::new();
    for i in 0..8u32 {
        let p = |bit: u32, lo: f32, hi: f32| if i & bit != 0 { hi } else { lo };
        positions.push([p(1, min.x, max.x), p(2, min.y, max.y), p(4, min.z, max.z)]);
    }
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let mut indices = Vec::new();
    for q in quads {
        indices.extend([q[0], q[1], q[2], q[0], q[2], q[3]]);
    }
    LodGeometry { positions, indices }
}

fn mesh(id: u32, min: Vec3, max: Vec3, lods: usize, geometry: bool) -> MeshInfo {
    MeshInfo {
        id: MeshId(id),
        bounds: Aabb::new(min, max),
        lods: (0..lods)
            .map(|_| LodInfo {
                triangles: 12,
                geometry: geometry.then(|| boxed(min, max)),
            })
            .collect(),
    }
}

const GROUND: u32 = 1;
const HOUSE: u32 = 2;
const DEER: u32 = 3;

fn header(deer_geometry: bool) -> TraceHeader {
    TraceHeader {
        scene_name: "hand-written valley".into(),
        world: WorldInfo {
            min: [-128.0, -128.0],
            max: [128.0, 128.0],
            cell_size: 16.0,
        },
        meshes: vec![
            mesh(
                GROUND,
                Vec3::new(-120.0, -1.0, -120.0),
                Vec3::new(120.0, 0.0, 120.0),
                1,
                true,
            ),
            mesh(
                HOUSE,
                Vec3::new(-4.0, 0.0, -4.0),
                Vec3::new(4.0, 9.0, 4.0),
                3,
                true,
            ),
            mesh(
                DEER,
                Vec3::new(-0.5, 0.0, -1.0),
                Vec3::new(0.5, 1.5, 1.0),
                2,
                deer_geometry,
            ),
        ],
    }
}

fn pose(m: &MeshInfo, at: Vec3, yaw: f32) -> Pose {
    let t = Affine3A::from_rotation_translation(Quat::from_rotation_y(yaw), at);
    let c: Vec<Vec3> = (0..8)
        .map(|i| {
            let (a, b) = (m.bounds.min, m.bounds.max);
            t.transform_point3(Vec3::new(
                if i & 1 != 0 { b.x } else { a.x },
                if i & 2 != 0 { b.y } else { a.y },
                if i & 4 != 0 { b.z } else { a.z },
            ))
        })
        .collect();
    let lo = c.iter().fold(Vec3::splat(f32::INFINITY), |a, &p| a.min(p));
    let hi = c
        .iter()
        .fold(Vec3::splat(f32::NEG_INFINITY), |a, &p| a.max(p));
    Pose {
        transform: affine_to_rows(&t),
        aabb: Aabb::new(lo, hi),
    }
}

fn add(
    h: &TraceHeader,
    id: u64,
    mesh: u32,
    lod: u32,
    at: Vec3,
    flags: InstanceFlags,
) -> InstanceEvent {
    let m = h.meshes.iter().find(|m| m.id.0 == mesh).unwrap();
    InstanceEvent::Add(AddInstance {
        id,
        mesh: MeshId(mesh),
        lod,
        flags,
        mask: None,
        pose: pose(m, at, 0.0),
        slot: None,
    })
}

fn camera(f: u64) -> Camera {
    Camera::look_to(
        Vec3::new(-30.0 + f as f32, 12.0, 40.0),
        Vec3::new(0.6, -0.35, -1.0),
        Vec3::Y,
        1.0,
        16.0 / 9.0,
    )
}

/// Ground, five houses (one moving every frame, one re-LODed, one removed
/// at frame 6), a deer replaced by a new one (new id) every frame.
fn valley(frames: u64, deer_geometry: bool) -> (TraceHeader, Vec<Frame>) {
    let h = header(deer_geometry);
    let mut out = Vec::new();
    for f in 0..frames {
        let mut events = Vec::new();
        if f == 0 {
            events.push(add(&h, 1000, GROUND, 0, Vec3::ZERO, InstanceFlags::STATIC));
            for i in 0..5u64 {
                let at = Vec3::new(-20.0 + 10.0 * i as f32, 0.0, -10.0 - 4.0 * (i % 2) as f32);
                events.push(add(&h, 10 + i, HOUSE, 0, at, InstanceFlags::STATIC));
            }
        } else {
            let m = &h.meshes[1];
            events.push(InstanceEvent::Update(UpdateInstance {
                id: 10,
                pose: Some(pose(
                    m,
                    // Back and forth, inside the 256 m world.
                    Vec3::new(-20.0 + 0.7 * (f % 200) as f32, 0.0, -10.0),
                    0.1 * f as f32,
                )),
                lod: None,
                flags: None,
                mask: None,
            }));
            events.push(InstanceEvent::Remove { id: 100 + f - 1 });
        }
        if f == 4 {
            events.push(InstanceEvent::Update(UpdateInstance {
                id: 12,
                pose: None,
                lod: Some(2),
                flags: None,
                mask: None,
            }));
        }
        if f == 6 {
            events.push(InstanceEvent::Remove { id: 13 });
        }
        let deer_at = Vec3::new(-5.0 + 1.5 * (f % 7) as f32, 0.0, 2.0);
        events.push(add(
            &h,
            100 + f,
            DEER,
            (f % 2) as u32,
            deer_at,
            InstanceFlags::empty(),
        ));
        out.push(Frame {
            number: 3 * f + 1,
            camera: camera(f),
            events,
            hits: None,
            slot_hits: None,
        });
    }
    (h, out)
}

fn write(h: &TraceHeader, frames: &[Frame]) -> Vec<u8> {
    let mut w = TraceWriter::new(Vec::new(), h).unwrap();
    for f in frames {
        w.write_frame(f).unwrap();
    }
    w.finish().unwrap()
}

fn run(
    bytes: &[u8],
    strategies: &[StrategyKind],
    options: &TraceSceneOptions,
) -> Result<TraceReplay, SimError> {
    let config = ReplayConfig {
        strategies: strategies.to_vec(),
        width: 48,
        height: 27,
        threads: 2,
        // The paper's cold start: LiPaC's error is then never zero in the
        // first frames, which the tests below rely on.
        lipac_start: LipacStart::Cold,
        ..ReplayConfig::default()
    };
    replay_trace(
        || TraceInput::new(TraceFormat::Binary, Cursor::new(bytes)),
        &config,
        options,
        &mut |_| {},
    )
}

#[test]
fn a_foreign_trace_replays_with_the_error_reported() {
    let (h, frames) = valley(10, true);
    let bytes = write(&h, &frames);
    let r = run(
        &bytes,
        &[
            StrategyKind::Full,
            StrategyKind::Oracle,
            StrategyKind::Lipac,
            StrategyKind::Frustum,
        ],
        &TraceSceneOptions::default(),
    )
    .unwrap();
    // Ground, five houses, one deer slot reused by every new deer.
    assert_eq!(r.slots, 7);
    assert!(r.box_proxies.is_empty());
    let rep = &r.report;
    assert_eq!(rep.frames, 10);
    assert_eq!(rep.scene, "hand-written valley");
    let full = rep.strategy("full").unwrap();
    assert!(full.frames.iter().all(|m| m.error == 0.0));
    // The oracle traces exactly the instances the ground truth's bounce
    // rays hit: the same images, exactly (a tie between two instances at
    // the same distance goes to the lower slot in both TLASes).
    let oracle = rep.strategy("oracle").unwrap();
    assert!(
        oracle.frames.iter().all(|m| m.error == 0.0),
        "{:?}",
        oracle.frames.iter().map(|m| m.error).collect::<Vec<_>>()
    );
    assert!(oracle.summary.mean_instances < full.summary.mean_instances);
    // The error is a real figure: LiPaC starts cold, so it is not zero.
    let lipac = rep.strategy("lipac").unwrap();
    assert!(lipac.frames.iter().all(|m| m.error.is_finite()));
    assert!(
        lipac.summary.max_error > 1e-3,
        "{}",
        lipac.summary.max_error
    );
    // The recorded frame numbers are kept.
    assert_eq!(full.frames.last().unwrap().frame, 28);
}

#[test]
fn the_scene_follows_the_events() {
    let (h, frames) = valley(8, true);
    let bytes = write(&h, &frames);
    let mut input = TraceInput::new(TraceFormat::Binary, Cursor::new(&bytes[..])).unwrap();
    let plan = TracePlan::scan(&h, &mut input).unwrap();
    assert_eq!(plan.slots(), 7);
    assert_eq!(plan.frames(), 8);
    let mut ts = TraceScene::new(&h, &plan, &TraceSceneOptions::default()).unwrap();
    for (f, frame) in frames.iter().enumerate() {
        ts.apply(frame).unwrap();
        let moving = ts.slot_of(10).unwrap();
        let t = ts.scene().instance(moving).unwrap().transform;
        let want = if f == 0 {
            -20.0
        } else {
            -20.0 + 0.7 * f as f32
        };
        assert!(
            (t.translation.x - want).abs() < 1e-5,
            "frame {f}: {}",
            t.translation.x
        );
        let deer = ts.slot_of(100 + f as u64).unwrap();
        assert_eq!(ts.lods()[deer as usize], (f % 2) as u8);
        if f > 0 {
            assert_eq!(ts.slot_of(100 + f as u64 - 1), None);
        }
        // Removed house 13 is parked far below the world from frame 6 on.
        if f >= 6 {
            assert_eq!(ts.slot_of(13), None);
            let below = ts
                .scene()
                .instances()
                .iter()
                .filter(|i| i.aabb.max.y < -1e4)
                .count();
            assert_eq!(below, 1);
        }
        assert_eq!(ts.live(), if f >= 6 { 6 } else { 7 });
    }
    // House 12 went to its coarsest recorded LOD (2 of 3) at frame 4.
    assert_eq!(ts.lods()[ts.slot_of(12).unwrap() as usize], 2);
}

#[test]
fn a_mesh_without_geometry_is_named_or_boxed() {
    let (h, frames) = valley(3, false);
    let bytes = write(&h, &frames);
    let err = run(&bytes, &[StrategyKind::Full], &TraceSceneOptions::default()).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("mesh 3 LOD 0 has no geometry"), "{msg}");
    let boxed = TraceSceneOptions {
        box_proxy: true,
        ..TraceSceneOptions::default()
    };
    let r = run(&bytes, &[StrategyKind::Full, StrategyKind::Oracle], &boxed).unwrap();
    assert_eq!(r.box_proxies, vec![3]);
    assert!(
        r.report.scene.contains("box proxies for meshes 3"),
        "{}",
        r.report.scene
    );
    assert_eq!(r.report.frames, 3);
}

#[test]
fn memory_follows_the_live_instances_not_the_length() {
    // 300 frames, a new deer every frame: 300 instances over the trace,
    // never more than 7 live; the scene keeps 7 slots.
    let (h, frames) = valley(300, true);
    let bytes = write(&h, &frames);
    let config = ReplayConfig {
        strategies: vec![StrategyKind::Full],
        width: 4,
        height: 4,
        threads: 1,
        ..ReplayConfig::default()
    };
    let r = replay_trace(
        || TraceInput::new(TraceFormat::Binary, Cursor::new(&bytes[..])),
        &config,
        &TraceSceneOptions::default(),
        &mut |_| {},
    )
    .unwrap();
    assert_eq!(r.report.frames, 300);
    assert_eq!(r.slots, 7);
    assert_eq!(r.report.instances, 7);
}

#[test]
fn a_scene_file_overrides_sun_and_sky() {
    let (h, frames) = valley(2, true);
    let bytes = write(&h, &frames);
    let dark = TraceSceneOptions::default()
        .with_json(r#"{"sun_irradiance":[0,0,0],"sky_radiance":[0,0,0]}"#)
        .unwrap();
    let both = [StrategyKind::Full, StrategyKind::Lipac];
    let lit = run(&bytes, &both, &TraceSceneOptions::default()).unwrap();
    let unlit = run(&bytes, &both, &dark).unwrap();
    // Without light every image is black, so even cold LiPaC has no error.
    let err = |r: &TraceReplay| r.report.strategy("lipac").unwrap().summary.max_error;
    assert!(err(&lit) > 1e-3, "{}", err(&lit));
    assert_eq!(err(&unlit), 0.0);
    assert!(TraceSceneOptions::default()
        .with_json(r#"{"sun_direction":[0,0,0]}"#)
        .is_err());
}

#[test]
fn a_singular_transform_is_named_with_its_frame_and_instance() {
    let (h, mut frames) = valley(3, true);
    // Frame 2 (number 7) squashes house 11 flat.
    frames[2].events.push(InstanceEvent::Update(UpdateInstance {
        id: 11,
        pose: Some(Pose {
            transform: [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
            aabb: Aabb::new(Vec3::ZERO, Vec3::ONE),
        }),
        lod: None,
        flags: None,
        mask: None,
    }));
    let bytes = write(&h, &frames);
    let msg = run(&bytes, &[StrategyKind::Full], &TraceSceneOptions::default())
        .unwrap_err()
        .to_string();
    assert!(msg.contains("frame number 7"), "{msg}");
    assert!(msg.contains("update of instance 11"), "{msg}");
    assert!(msg.contains("singular"), "{msg}");
}

/// An in-process pipe: the bytes come from another thread in chunks, as
/// from standard input (not seekable, read once).
struct Pipe(std::sync::mpsc::Receiver<Vec<u8>>, Vec<u8>, usize);

impl std::io::Read for Pipe {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        while self.2 == self.1.len() {
            match self.0.recv() {
                Ok(chunk) => (self.1, self.2) = (chunk, 0),
                Err(_) => return Ok(0), // the writer hung up: end of input
            }
        }
        let n = buf.len().min(self.1.len() - self.2);
        buf[..n].copy_from_slice(&self.1[self.2..self.2 + n]);
        self.2 += n;
        Ok(n)
    }
}

/// A pipe fed with `bytes` in chunks of `chunk` by a thread.
fn pipe(bytes: Vec<u8>, chunk: usize) -> (Pipe, std::thread::JoinHandle<()>) {
    let (tx, rx) = std::sync::mpsc::channel();
    let feeder = std::thread::spawn(move || {
        for c in bytes.chunks(chunk) {
            tx.send(c.to_vec()).unwrap();
        }
    });
    (Pipe(rx, Vec::new(), 0), feeder)
}

/// The valley with its deer flagged `vegetation`.
fn vegetation_valley(frames: u64) -> (TraceHeader, Vec<Frame>) {
    let (h, mut frames) = valley(frames, true);
    for f in &mut frames {
        for e in &mut f.events {
            if let InstanceEvent::Add(a) = e {
                if a.mesh.0 == DEER {
                    a.flags = InstanceFlags::VEGETATION;
                }
            }
        }
    }
    (h, frames)
}

#[test]
fn vegetation_is_alpha_tested_by_default_and_keeps_its_world_geometry() {
    let (h, frames) = vegetation_valley(2);
    let bytes = write(&h, &frames);
    let mut input = TraceInput::new(TraceFormat::Binary, Cursor::new(&bytes[..])).unwrap();
    let plan = TracePlan::scan(&h, &mut input).unwrap();
    let deer_pose = match &frames[0].events.last().unwrap() {
        InstanceEvent::Add(a) => lipac_core::math::rows_to_affine(&a.pose.transform),
        _ => unreachable!(),
    };
    let geometry = h.meshes[2].lods[0].geometry.as_ref().unwrap();
    for alpha in [true, false] {
        let options = TraceSceneOptions {
            vegetation_alpha: alpha,
            ..TraceSceneOptions::default()
        };
        assert!(TraceSceneOptions::default().vegetation_alpha);
        let mut ts = TraceScene::new(&h, &plan, &options).unwrap();
        ts.apply(&frames[0]).unwrap();
        let lib = ts.scene().library();
        let deer = lib.mesh(2).unwrap();
        let houses = lib.mesh(1).unwrap();
        assert!(deer
            .lods
            .iter()
            .all(|l| l.alpha_tested.iter().all(|&a| a == alpha)));
        assert!(houses
            .lods
            .iter()
            .all(|l| l.alpha_tested.iter().all(|&a| !a)));
        // The scene mesh may live in the crown's space; placed by its
        // slot's transform it is the recorded geometry.
        let slot = ts.slot_of(100).unwrap();
        let t = ts.scene().instance(slot).unwrap().transform;
        for (tri, idx) in deer.lods[0]
            .triangles
            .iter()
            .zip(geometry.indices.chunks(3))
        {
            let got = t.transform_point3(Vec3::from(tri.v0));
            let want = deer_pose.transform_point3(Vec3::from(geometry.positions[idx[0] as usize]));
            assert!((got - want).abs().max_element() < 1e-4, "{got} vs {want}");
        }
        // Alpha-tested, about half of the surface is opaque (the pattern
        // covers the whole mesh, not only the built-in trees' crown).
        let mut opaque = 0;
        let n = 20;
        for tri in &deer.lods[0].triangles {
            let (a, b, c) = (Vec3::from(tri.v0), Vec3::from(tri.v1), Vec3::from(tri.v2));
            for i in 0..n {
                for j in 0..n - i {
                    let (u, v) = ((i as f32 + 0.3) / n as f32, (j as f32 + 0.3) / n as f32);
                    opaque += usize::from(leaf_opaque(a + (b - a) * u + (c - a) * v));
                }
            }
        }
        let samples = deer.lods[0].triangles.len() * n * (n + 1) / 2;
        let frac = opaque as f64 / samples as f64;
        if alpha {
            assert!((0.3..0.8).contains(&frac), "{frac}");
        }
    }
}

#[test]
fn a_trace_from_a_pipe_replays_with_geometry() {
    let (h, frames) = vegetation_valley(6);
    let bytes = write(&h, &frames);
    let strategies = [
        StrategyKind::Full,
        StrategyKind::Oracle,
        StrategyKind::Lipac,
    ];
    let from_file = run(&bytes, &strategies, &TraceSceneOptions::default()).unwrap();
    let config = ReplayConfig {
        strategies: strategies.to_vec(),
        width: 48,
        height: 27,
        threads: 2,
        lipac_start: LipacStart::Cold, // as run()
        ..ReplayConfig::default()
    };
    // Small chunks: the replay reads as the bytes come.
    let (rd, feeder) = pipe(bytes, 100);
    let (report, _) =
        replay_stream(rd, &config, &TraceSceneOptions::default(), &mut |_| {}).unwrap();
    feeder.join().unwrap();
    assert_eq!(report.frames, 6);
    assert_eq!(report.instances, from_file.report.instances);
    for s in ["full", "oracle", "lipac"] {
        let a = report.strategy(s).unwrap();
        let b = from_file.report.strategy(s).unwrap();
        let key = |r: &lipac_sim::compare::StrategyRun| -> Vec<(u64, u64, u64)> {
            r.frames
                .iter()
                .map(|m| (m.error.to_bits(), m.tlas_instances, m.builds))
                .collect()
        };
        assert_eq!(key(a), key(b), "{s}");
    }
    // The spool file is gone.
    let pid = format!("lipac-replay-{}-", std::process::id());
    let left = std::fs::read_dir(std::env::temp_dir())
        .unwrap()
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_string_lossy().starts_with(&pid))
        .count();
    assert_eq!(left, 0);
}

#[test]
fn a_pipe_of_many_frames_keeps_the_slots_of_the_live_instances() {
    let (h, frames) = valley(300, true);
    let bytes = write(&h, &frames);
    let config = ReplayConfig {
        strategies: vec![StrategyKind::Full],
        width: 4,
        height: 4,
        threads: 1,
        ..ReplayConfig::default()
    };
    let (rd, feeder) = pipe(bytes, 64 * 1024);
    let (report, _) =
        replay_stream(rd, &config, &TraceSceneOptions::default(), &mut |_| {}).unwrap();
    feeder.join().unwrap();
    assert_eq!(report.frames, 300);
    assert_eq!(report.instances, 7);
}

/// The valley with two flag updates mid-trace: house 50, buried under the
/// ground where no ray reaches it (so LiPaC never activates it for hits),
/// becomes pinned at frame 3; house 11 becomes vegetation at frame 4 (the
/// other houses stay wall).
fn flag_valley(frames: u64) -> (TraceHeader, Vec<Frame>) {
    let (h, mut out) = valley(frames, true);
    out[0].events.push(add(
        &h,
        50,
        HOUSE,
        0,
        Vec3::new(60.0, -40.0, -60.0),
        InstanceFlags::STATIC,
    ));
    let flags = |id, flags| {
        InstanceEvent::Update(UpdateInstance {
            id,
            pose: None,
            lod: None,
            flags: Some(flags),
            mask: None,
        })
    };
    out[3]
        .events
        .push(flags(50, InstanceFlags::STATIC | InstanceFlags::PINNED));
    out[4]
        .events
        .push(flags(11, InstanceFlags::STATIC | InstanceFlags::VEGETATION));
    (h, out)
}

#[test]
fn mid_trace_flag_updates_reach_the_tracer_and_lipac() {
    let frames_n = 8;
    let (h, frames) = flag_valley(frames_n);
    let bytes = write(&h, &frames);
    // The scene: house 11 moves to a leaves slot (alpha-tested, vegetation
    // mask) at frame 4, its old slot is parked; house 50 is pinned from
    // frame 3 on.
    let mut input = TraceInput::new(TraceFormat::Binary, Cursor::new(&bytes[..])).unwrap();
    let plan = TracePlan::scan(&h, &mut input).unwrap();
    let mut ts = TraceScene::new(&h, &plan, &TraceSceneOptions::default()).unwrap();
    let mut pinned_slot = None;
    for (f, frame) in frames.iter().enumerate() {
        ts.apply(frame).unwrap();
        let s11 = ts.slot_of(11).unwrap();
        let inst = *ts.scene().instance(s11).unwrap();
        let mesh = ts.scene().library().mesh(inst.mesh).unwrap();
        let leaves = mesh.lods[0].alpha_tested.iter().all(|&a| a);
        assert_eq!(inst.is_vegetation(), f >= 4, "frame {f}");
        assert_eq!(leaves, f >= 4, "frame {f}");
        // Same world placement either way (the leaves mesh lives in the
        // crown's space, its instance carries the inverse map).
        let p = inst
            .transform
            .transform_point3(Vec3::from(mesh.lods[0].triangles[0].v0));
        assert!(p.x > -15.0 && p.x < -5.0 && p.y > -1.0, "frame {f}: {p}");
        // Every other house stays wall.
        let s12 = ts.slot_of(12).unwrap();
        let m12 = ts.scene().instance(s12).unwrap().mesh;
        assert!(ts.scene().library().mesh(m12).unwrap().lods[0]
            .alpha_tested
            .iter()
            .all(|&a| !a));
        let s50 = ts.slot_of(50).unwrap();
        assert_eq!(ts.scene().instance(s50).unwrap().is_pinned(), f >= 3);
        pinned_slot = Some(s50);
    }
    let pinned_slot = pinned_slot.unwrap() as usize;
    // Replayed: full and oracle still exact; LiPaC traces house 50 from
    // the update on (its BLAS requested at once).
    let numbers: Vec<u32> = frames.iter().map(|f| f.number as u32).collect();
    let config = ReplayConfig {
        strategies: vec![
            StrategyKind::Full,
            StrategyKind::Oracle,
            StrategyKind::Lipac,
        ],
        width: 48,
        height: 27,
        threads: 2,
        snapshots: numbers.clone(),
        // The paper's cold start: nothing active before feedback.
        lipac_start: LipacStart::Cold,
        ..ReplayConfig::default()
    };
    let r = replay_trace(
        || TraceInput::new(TraceFormat::Binary, Cursor::new(&bytes[..])),
        &config,
        &TraceSceneOptions::default(),
        &mut |_| {},
    )
    .unwrap();
    for name in ["full", "oracle"] {
        let s = r.report.strategy(name).unwrap();
        assert!(
            s.frames.iter().all(|m| m.error == 0.0),
            "{name}: {:?}",
            s.frames.iter().map(|m| m.error).collect::<Vec<_>>()
        );
    }
    assert_eq!(r.snapshots.len(), frames.len());
    let lipac_state = |f: usize| {
        let snap = &r.snapshots[f];
        let s = snap.strategies.iter().find(|s| s.name == "lipac").unwrap();
        s.map.instances[pinned_slot]
    };
    use lipac_sim::tlas_map::MapState;
    // Cold start: nothing is active in the first frame. (With lipac-sim's
    // default 64 m cells, hit feedback may activate the house's cell from
    // the second frame on, before the pin; with 32 m cells it did not.)
    assert_ne!(lipac_state(0).state, MapState::Active, "frame 0");
    for f in 0..3 {
        assert!(!lipac_state(f).pinned, "frame {f}");
    }
    for f in 3..frames.len() {
        let i = lipac_state(f);
        assert!(i.pinned, "frame {f}");
        // Activated and its BLAS requested at once: traced from the
        // update's frame on.
        assert_eq!(i.state, MapState::Active, "frame {f}");
    }
}
