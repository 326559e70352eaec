//! Traces for the trace tests: the hand-built golden `tiny` trace and a
//! seeded generator of valid random traces.
#![allow(dead_code)]

use glam::{Quat, Vec3};
use lipac_core::instance::{InstanceFlags, MeshId};
use lipac_core::math::Aabb;
use lipac_core::trace::*;
use std::path::PathBuf;

/// `tests/data/` at the repository root.
pub fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../tests/data")
}

/// A pose translated to `(x, y, z)` with a unit box around it.
pub fn pose_at(x: f32, y: f32, z: f32) -> Pose {
    Pose {
        transform: [1.0, 0.0, 0.0, x, 0.0, 1.0, 0.0, y, 0.0, 0.0, 1.0, z],
        aabb: Aabb::new(
            Vec3::new(x - 0.5, y - 0.5, z - 0.5),
            Vec3::new(x + 0.5, y + 0.5, z + 0.5),
        ),
    }
}

/// The golden trace (`tests/data/tiny.*`): two meshes (one with geometry),
/// three frames exercising every event kind and both hit-count forms, and
/// floats that do not print exactly (0.1, 1/3, -0.0, a subnormal).
pub fn tiny_trace() -> (TraceHeader, Vec<Frame>) {
    let header = TraceHeader {
        scene_name: "tiny — golden".into(),
        world: WorldInfo {
            min: [-64.0, -64.0],
            max: [64.0, 64.0],
            cell_size: 16.0,
        },
        meshes: vec![
            MeshInfo {
                id: MeshId(7),
                bounds: Aabb::new(Vec3::new(-0.5, 0.0, -0.5), Vec3::new(0.5, 0.0, 0.5)),
                lods: vec![
                    LodInfo {
                        triangles: 2,
                        geometry: Some(LodGeometry {
                            positions: vec![
                                [-0.5, 0.0, -0.5],
                                [0.5, 0.0, -0.5],
                                [0.5, 0.0, 0.5],
                                [-0.5, 0.0, 0.5],
                            ],
                            indices: vec![0, 1, 2, 0, 2, 3],
                        }),
                    },
                    LodInfo {
                        triangles: 1,
                        geometry: None,
                    },
                ],
            },
            MeshInfo {
                id: MeshId(900),
                bounds: Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0)),
                lods: vec![LodInfo {
                    triangles: 12,
                    geometry: None,
                }],
            },
        ],
    };
    let camera = Camera {
        position: Vec3::new(0.1, 1.7, 1.0 / 3.0),
        orientation: Quat::from_xyzw(0.0, 0.12467473, 0.0, 0.9921977), // 0.25 rad about +Y
        vertical_fov: std::f32::consts::FRAC_PI_3,
        aspect: 16.0 / 9.0,
    };
    let mut p2 = pose_at(-0.0, 2.5, 30.0);
    p2.transform[0] = f32::from_bits(1); // a subnormal scale
    let frames = vec![
        Frame {
            number: 10,
            camera,
            events: vec![
                InstanceEvent::Add(AddInstance {
                    id: 1,
                    mesh: MeshId(7),
                    lod: 0,
                    flags: InstanceFlags::STATIC,
                    mask: None,
                    pose: pose_at(0.1, 0.0, -20.0),
                }),
                InstanceEvent::Add(AddInstance {
                    id: u64::MAX,
                    mesh: MeshId(900),
                    lod: 0,
                    flags: InstanceFlags::UNIQUE_BLAS | InstanceFlags::VEGETATION,
                    mask: Some(0x0F),
                    pose: p2,
                }),
            ],
            hits: None,
        },
        Frame {
            number: 11,
            camera: Camera {
                position: Vec3::new(0.2, 1.7, 1.0 / 3.0),
                ..camera
            },
            events: vec![
                InstanceEvent::Update(UpdateInstance {
                    id: 1,
                    pose: Some(pose_at(0.3, 0.0, -20.0)),
                    lod: Some(1),
                    flags: None,
                    mask: None,
                }),
                InstanceEvent::Update(UpdateInstance {
                    id: u64::MAX,
                    pose: None,
                    lod: None,
                    flags: Some(InstanceFlags::empty()),
                    mask: Some(0xFF),
                }),
            ],
            hits: Some(vec![
                InstanceHits { id: 1, hits: 1234 },
                InstanceHits {
                    id: u64::MAX,
                    hits: 0,
                },
            ]),
        },
        Frame {
            number: 13,
            camera,
            events: vec![InstanceEvent::Remove { id: 1 }],
            hits: Some(vec![]),
        },
    ];
    (header, frames)
}

/// The tests' deterministic PRNG: xorshift64* from lipac-test-support,
/// seeded through `Rng::from_seed` (state `seed * golden | 1`).
pub use lipac_test_support::{Rng64, XorShift64Star as Rng};

/// A valid random trace: 1..=3 meshes, `frames` frames of adds, updates,
/// removes and hit counts.
pub fn random_trace(seed: u64, frames: usize) -> (TraceHeader, Vec<Frame>) {
    let mut rng = Rng::from_seed(seed);
    let mesh_count = 1 + rng.below(3) as u32;
    let meshes: Vec<MeshInfo> = (0..mesh_count)
        .map(|m| {
            let lods = (0..1 + rng.below(3))
                .map(|l| {
                    let geometry = (m == 0 && l == 0).then(|| LodGeometry {
                        positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                        indices: vec![0, 1, 2],
                    });
                    LodInfo {
                        triangles: if geometry.is_some() {
                            1
                        } else {
                            rng.below(1000) as u32
                        },
                        geometry,
                    }
                })
                .collect();
            MeshInfo {
                id: MeshId(m * 3 + 1),
                bounds: Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0)),
                lods,
            }
        })
        .collect();
    let header = TraceHeader {
        scene_name: format!("random {seed}"),
        world: WorldInfo {
            min: [-256.0, -256.0],
            max: [256.0, 256.0],
            cell_size: 16.0,
        },
        meshes,
    };
    let mut live: Vec<(u64, usize)> = Vec::new();
    let mut next_id = rng.below(1000);
    let mut number = rng.below(100);
    let mut out = Vec::with_capacity(frames);
    for _ in 0..frames {
        number += 1 + rng.below(3);
        let camera = Camera::look_to(
            Vec3::new(
                rng.range_f32(-100.0, 100.0),
                2.0,
                rng.range_f32(-100.0, 100.0),
            ),
            Vec3::new(rng.range_f32(-1.0, 1.0), rng.range_f32(-0.2, 0.2), 1.0),
            Vec3::Y,
            rng.range_f32(0.5, 1.5),
            rng.range_f32(1.0, 2.0),
        );
        let mut events = Vec::new();
        for _ in 0..rng.below(6) {
            let pose = pose_at(
                rng.range_f32(-200.0, 200.0),
                rng.range_f32(0.0, 20.0),
                rng.range_f32(-200.0, 200.0),
            );
            match rng.below(3) {
                0 => {
                    let mesh = rng.below(header.meshes.len() as u64) as usize;
                    let m = &header.meshes[mesh];
                    next_id += 1 + rng.below(5);
                    events.push(InstanceEvent::Add(AddInstance {
                        id: next_id,
                        mesh: m.id,
                        lod: rng.below(m.lods.len() as u64) as u32,
                        flags: InstanceFlags::from_bits_truncate(rng.next_u64() as u32),
                        mask: rng.chance_percent(50).then(|| rng.next_u64() as u8),
                        pose,
                    }));
                    live.push((next_id, mesh));
                }
                1 if !live.is_empty() => {
                    let (id, mesh) = live[rng.below(live.len() as u64) as usize];
                    let lods = header.meshes[mesh].lods.len() as u64;
                    events.push(InstanceEvent::Update(UpdateInstance {
                        id,
                        pose: rng.chance_percent(50).then_some(pose),
                        lod: rng.chance_percent(50).then(|| rng.below(lods) as u32),
                        flags: rng
                            .chance_percent(30)
                            .then(|| InstanceFlags::from_bits_truncate(rng.next_u64() as u32)),
                        mask: rng.chance_percent(30).then(|| rng.next_u64() as u8),
                    }));
                }
                2 if !live.is_empty() => {
                    let i = rng.below(live.len() as u64) as usize;
                    let (id, _) = live.swap_remove(i);
                    events.push(InstanceEvent::Remove { id });
                }
                _ => {}
            }
        }
        let hits = if rng.chance_percent(60) {
            let mut hits = Vec::new();
            for &(id, _) in &live {
                if rng.chance_percent(50) {
                    hits.push(InstanceHits {
                        id,
                        hits: rng.below(5000) as u32,
                    });
                }
            }
            Some(hits)
        } else {
            None
        };
        out.push(Frame {
            number,
            camera,
            events,
            hits,
        });
    }
    (header, out)
}

/// The binary encoding of a trace.
pub fn to_binary(header: &TraceHeader, frames: &[Frame]) -> Vec<u8> {
    let mut w = TraceWriter::new(Vec::new(), header).expect("valid header");
    for f in frames {
        w.write_frame(f).expect("valid frame");
    }
    w.finish().expect("finish")
}

/// The JSON-lines encoding of a trace.
pub fn to_jsonl(header: &TraceHeader, frames: &[Frame]) -> Vec<u8> {
    let mut w = JsonlWriter::new(Vec::new(), header).expect("valid header");
    for f in frames {
        w.write_frame(f).expect("valid frame");
    }
    w.finish().expect("finish")
}

/// Reads a whole binary trace.
pub fn read_binary(bytes: &[u8]) -> Result<(TraceHeader, Vec<Frame>), TraceError> {
    let mut r = TraceReader::new(bytes)?;
    let mut frames = Vec::new();
    while let Some(f) = r.next_frame()? {
        frames.push(f);
    }
    Ok((r.header().clone(), frames))
}

/// Reads a whole JSON-lines trace.
pub fn read_jsonl(bytes: &[u8]) -> Result<(TraceHeader, Vec<Frame>), TraceError> {
    let mut r = JsonlReader::new(bytes)?;
    let mut frames = Vec::new();
    while let Some(f) = r.next_frame()? {
        frames.push(f);
    }
    Ok((r.header().clone(), frames))
}
