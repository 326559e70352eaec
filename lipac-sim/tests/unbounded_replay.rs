//! A hits-only replay of a trace whose header omits the world bounds
//! (`WorldInfo::unbounded`) runs LiPaC on the sparse hashed hitbox index:
//! on the same instances and hits it decides as the replay of the bounded
//! trace (the cells are the same), and instances 1000 km apart replay too.

use glam::{Affine3A, Vec3};
use lipac_core::trace::{
    AddInstance, Camera, Frame, InstanceEvent, InstanceHits, LodInfo, MeshInfo, Pose, TraceFormat,
    TraceHeader, TraceWriter, WorldInfo,
};
use lipac_core::{math::affine_to_rows, Aabb, InstanceFlags, MeshId};
use lipac_sim::metrics::FrameMetrics;
use lipac_sim::replay::hits::replay_hits;
use lipac_sim::replay::{ReplayConfig, ReplayMode, TraceInput};

const FRAMES: u64 = 16;

/// 256 instances on a 16 x 16 lattice of pitch `pitch` from the origin; the
/// west half gets many hits.
fn trace(world: WorldInfo, pitch: f32) -> Vec<u8> {
    let header = TraceHeader {
        scene_name: "unbounded".into(),
        world,
        meshes: vec![MeshInfo {
            id: MeshId(3),
            bounds: Aabb::new(-Vec3::ONE, Vec3::ONE),
            lods: vec![LodInfo {
                triangles: 800,
                geometry: None,
            }],
        }],
    };
    let mut w = TraceWriter::new(Vec::new(), &header).unwrap();
    let pos = |i: u64| {
        Vec3::new(
            4.0 + pitch * (i % 16) as f32,
            1.0,
            4.0 + pitch * (i / 16) as f32,
        )
    };
    for number in 0..FRAMES {
        let events = if number == 0 {
            (0..256)
                .map(|id| {
                    let c = pos(id);
                    InstanceEvent::Add(AddInstance {
                        id,
                        mesh: MeshId(3),
                        lod: 0,
                        flags: InstanceFlags::empty(),
                        mask: None,
                        pose: Pose {
                            transform: affine_to_rows(&Affine3A::from_translation(c)),
                            aabb: Aabb::new(c - Vec3::ONE, c + Vec3::ONE),
                        },
                        slot: None,
                    })
                })
                .collect()
        } else {
            Vec::new()
        };
        let hits = (0..256)
            .map(|id| InstanceHits {
                id,
                hits: if id % 16 < 8 { 20_000 } else { 0 },
            })
            .collect();
        let camera = Camera::look_to(Vec3::new(64.0, 40.0, -20.0), Vec3::Z, Vec3::Y, 1.0, 1.0);
        w.write_frame(&Frame {
            number,
            camera,
            events,
            hits: Some(hits),
            slot_hits: None,
        })
        .unwrap();
    }
    w.finish().unwrap()
}

fn lipac_frames(bytes: &[u8]) -> Vec<FrameMetrics> {
    let mut input = TraceInput::new(TraceFormat::Binary, bytes).unwrap();
    let config = ReplayConfig {
        mode: Some(ReplayMode::HitsOnly),
        ..ReplayConfig::default()
    };
    let report = replay_hits(&mut input, &config, &mut |_| {}).expect("hits-only replay");
    assert_eq!(report.instances, 256);
    report
        .strategies
        .into_iter()
        .find(|s| s.name.to_lowercase().starts_with("lipac"))
        .expect("a LiPaC run")
        .frames
}

#[test]
fn an_unbounded_trace_replays_as_the_bounded_one() {
    let bounded = WorldInfo {
        min: [0.0, 0.0],
        max: [128.0, 128.0],
        cell_size: 16.0,
    };
    let a = lipac_frames(&trace(bounded, 8.0));
    let b = lipac_frames(&trace(WorldInfo::unbounded(16.0), 8.0));
    assert_eq!(a.len() as u64, FRAMES);
    assert_eq!(a.len(), b.len());
    let key = |f: &FrameMetrics| {
        (
            f.tlas_instances,
            f.counting_boxes,
            f.builds,
            f.state_changes,
        )
    };
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(key(x), key(y), "frame {}", x.frame);
    }
    let last = b.last().unwrap();
    assert!(last.tlas_instances > last.counting_boxes, "{last:?}");
    assert!(last.counting_boxes > 0, "{last:?}");
}

#[test]
fn instances_1000_km_apart_replay_without_bounds() {
    let f = lipac_frames(&trace(WorldInfo::unbounded(16.0), 66_000.0));
    let last = f.last().unwrap();
    // One instance per cell: the east half stays in 128 counting boxes.
    assert_eq!(last.counting_boxes, 128, "{last:?}");
    assert!(f.iter().map(|m| m.state_changes).sum::<u64>() > 0);
}
