//! Traces for the trace tests: the hand-built golden `tiny` trace and a
//! seeded generator of valid random traces.
#![allow(dead_code)]

use glam::{Quat, Vec3};
use lipac_core::hitbox_index::HitboxIndex;
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
                    slot: None,
                }),
                InstanceEvent::Add(AddInstance {
                    id: u64::MAX,
                    mesh: MeshId(900),
                    lod: 0,
                    flags: InstanceFlags::UNIQUE_BLAS | InstanceFlags::VEGETATION,
                    mask: Some(0x0F),
                    pose: p2,
                    slot: None,
                }),
            ],
            hits: None,
            slot_hits: None,
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
            slot_hits: None,
        },
        Frame {
            number: 13,
            camera,
            events: vec![InstanceEvent::Remove { id: 1 }],
            hits: Some(vec![]),
            slot_hits: None,
        },
    ];
    (header, frames)
}

/// The version-2 golden trace (`tests/data/tiny-v2.*`): the tiny trace
/// with slots on its adds and a fourth frame whose hits are by slot, with
/// a counting box split over an instance without hits of its own.
pub fn tiny_v2_trace() -> (TraceHeader, Vec<Frame>) {
    let (header, mut frames) = tiny_trace();
    for (e, slot) in frames[0].events.iter_mut().zip([0, 5]) {
        if let InstanceEvent::Add(a) = e {
            a.slot = Some(slot);
        }
    }
    // Instance 2 takes slot 0 (freed by instance 1's removal in frame 13)
    // in hitbox 9 (cell (1, 1) of the 8 x 8 grid); instance u64::MAX keeps
    // slot 5 with 7 hits of its own.
    let pose = pose_at(-40.0, 0.0, -40.0);
    let camera = frames[2].camera;
    frames.push(Frame {
        number: 14,
        camera,
        events: vec![InstanceEvent::Add(AddInstance {
            id: 2,
            mesh: MeshId(7),
            lod: 1,
            flags: InstanceFlags::empty(),
            mask: None,
            pose,
            slot: Some(0),
        })],
        hits: Some(vec![
            InstanceHits { id: 2, hits: 10 },
            InstanceHits {
                id: u64::MAX,
                hits: 7,
            },
        ]),
        slot_hits: Some(SlotHits {
            slots: vec![0, 0, 0, 0, 0, 7],
            boxes: vec![BoxHits {
                hitbox: 9,
                hits: 10,
            }],
        }),
    });
    (header, frames)
}

/// The tests' deterministic PRNG: xorshift64* from lipac-test-support,
/// seeded through `Rng::from_seed` (state `seed * golden | 1`).
pub use lipac_test_support::{Rng64, XorShift64Star as Rng};

/// A live instance of [`random_trace`]: id, mesh index, slot, flags, box.
#[derive(Clone, Copy)]
struct LiveInstance {
    id: u64,
    mesh: usize,
    slot: Option<u32>,
    flags: InstanceFlags,
    aabb: Aabb,
}

/// A valid random trace (format version 2): 1..=3 meshes, `frames` frames
/// of adds (most with a slot), updates, removes and hit counts, listed by
/// id or by slot with counting boxes ([`SlotHits`]; then `hits` holds what
/// a reader derives, computed here from the rule in docs/trace-format.md).
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
    let grid = lipac_core::HitboxGrid::new(header.world.grid_config()).unwrap();
    let mut live: Vec<LiveInstance> = Vec::new();
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
                    let flags = InstanceFlags::from_bits_truncate(rng.next_u64() as u32);
                    // A free slot (lowest free, or a random one above).
                    let slot = rng.chance_percent(80).then(|| {
                        let taken = |s: u32| live.iter().any(|l| l.slot == Some(s));
                        let mut s = if rng.chance_percent(70) {
                            0
                        } else {
                            rng.below(40) as u32
                        };
                        while taken(s) {
                            s += 1;
                        }
                        s
                    });
                    events.push(InstanceEvent::Add(AddInstance {
                        id: next_id,
                        mesh: m.id,
                        lod: rng.below(m.lods.len() as u64) as u32,
                        flags,
                        mask: rng.chance_percent(50).then(|| rng.next_u64() as u8),
                        pose,
                        slot,
                    }));
                    live.push(LiveInstance {
                        id: next_id,
                        mesh,
                        slot,
                        flags,
                        aabb: pose.aabb,
                    });
                }
                1 if !live.is_empty() => {
                    let i = rng.below(live.len() as u64) as usize;
                    let l = &mut live[i];
                    let lods = header.meshes[l.mesh].lods.len() as u64;
                    let u = UpdateInstance {
                        id: l.id,
                        pose: rng.chance_percent(50).then_some(pose),
                        lod: rng.chance_percent(50).then(|| rng.below(lods) as u32),
                        flags: rng
                            .chance_percent(30)
                            .then(|| InstanceFlags::from_bits_truncate(rng.next_u64() as u32)),
                        mask: rng.chance_percent(30).then(|| rng.next_u64() as u8),
                    };
                    if let Some(p) = u.pose {
                        l.aabb = p.aabb;
                    }
                    if let Some(f) = u.flags {
                        l.flags = f;
                    }
                    events.push(InstanceEvent::Update(u));
                }
                2 if !live.is_empty() => {
                    let i = rng.below(live.len() as u64) as usize;
                    let l = live.swap_remove(i);
                    events.push(InstanceEvent::Remove { id: l.id });
                }
                _ => {}
            }
        }
        let mut slot_hits = None;
        let hits = if rng.chance_percent(40) {
            let mut hits = Vec::new();
            for l in &live {
                if rng.chance_percent(50) {
                    hits.push(InstanceHits {
                        id: l.id,
                        hits: rng.below(5000) as u32,
                    });
                }
            }
            Some(hits)
        } else if rng.chance_percent(50) {
            let top = live
                .iter()
                .filter_map(|l| l.slot)
                .max()
                .map_or(0, |s| s + 1);
            let mut sh = SlotHits {
                slots: vec![0; (top + rng.below(3) as u32) as usize],
                boxes: Vec::new(),
            };
            for l in &live {
                if let Some(s) = l.slot {
                    if rng.chance_percent(50) {
                        sh.slots[s as usize] = rng.below(5000) as u32;
                    }
                }
            }
            let mut hitbox = 0u32;
            while rng.chance_percent(60) {
                hitbox += rng.below(200) as u32;
                if hitbox >= grid.len() {
                    break;
                }
                sh.boxes.push(BoxHits {
                    hitbox,
                    hits: rng.below(20_000) as u32,
                });
                hitbox += 1;
            }
            // Occupied hitboxes get counting-box hits too, most of the time.
            for l in &live {
                if let Some(h) = grid.hitbox_of(&l.aabb) {
                    if rng.chance_percent(50) {
                        if let Err(i) = sh.boxes.binary_search_by_key(&h, |b| b.hitbox) {
                            sh.boxes.insert(
                                i,
                                BoxHits {
                                    hitbox: h,
                                    hits: rng.below(20_000) as u32,
                                },
                            );
                        }
                    }
                }
            }
            let derived = derive_hits(&grid, &live, &sh);
            slot_hits = Some(sh);
            Some(derived)
        } else {
            None
        };
        out.push(Frame {
            number,
            camera,
            events,
            hits,
            slot_hits,
        });
    }
    (header, out)
}

/// The per-instance hits a reader derives from `sh` (docs/trace-format.md,
/// "Hits by slot"), written out independently of the reader: own hits by
/// slot; each counting box's hits split evenly over the live, slotted, not
/// pinned instances without own hits whose AABB centre is in its hitbox,
/// by slot, the first `hits % k` one more; zeros left out; slot order.
fn derive_hits(
    grid: &lipac_core::HitboxGrid,
    live: &[LiveInstance],
    sh: &SlotHits,
) -> Vec<InstanceHits> {
    let mut slotted: Vec<&LiveInstance> = live.iter().filter(|l| l.slot.is_some()).collect();
    slotted.sort_by_key(|l| l.slot);
    let own = |l: &LiveInstance| sh.slots.get(l.slot.unwrap() as usize).copied().unwrap_or(0);
    let culled_box = |l: &LiveInstance| -> Option<BoxHits> {
        if own(l) != 0 || l.flags.contains(InstanceFlags::PINNED) {
            return None;
        }
        let h = grid.hitbox_of(&l.aabb)?;
        sh.boxes.iter().find(|b| b.hitbox == h).copied()
    };
    let mut given: std::collections::HashMap<u32, u32> = Default::default();
    let mut out = Vec::new();
    for l in &slotted {
        let hits = match culled_box(l) {
            Some(b) => {
                let k = slotted
                    .iter()
                    .filter(|o| culled_box(o).map(|x| x.hitbox) == Some(b.hitbox))
                    .count() as u32;
                let seen = given.entry(b.hitbox).or_default();
                let h = b.hits / k + u32::from(*seen < b.hits % k);
                *seen += 1;
                h
            }
            None => own(l),
        };
        if hits != 0 {
            out.push(InstanceHits { id: l.id, hits });
        }
    }
    out
}

/// `frames` as a reader returns them after a skipped frame: hits by slot
/// cannot be named any more, so their derived `hits` are absent.
pub fn without_derived_hits(frames: &[Frame]) -> Vec<Frame> {
    frames
        .iter()
        .cloned()
        .map(|mut f| {
            if f.slot_hits.is_some() {
                f.hits = None;
            }
            f
        })
        .collect()
}

/// The binary encoding of a trace in format `version`.
pub fn to_binary_v(version: u16, header: &TraceHeader, frames: &[Frame]) -> Vec<u8> {
    let mut w = TraceWriter::with_version(Vec::new(), header, TraceLimits::default(), version)
        .expect("valid header");
    for f in frames {
        w.write_frame(f).expect("valid frame");
    }
    w.finish().expect("finish")
}

/// The JSON-lines encoding of a trace in format `version`.
pub fn to_jsonl_v(version: u16, header: &TraceHeader, frames: &[Frame]) -> Vec<u8> {
    let mut w = JsonlWriter::with_version(Vec::new(), header, TraceLimits::default(), version)
        .expect("valid header");
    for f in frames {
        w.write_frame(f).expect("valid frame");
    }
    w.finish().expect("finish")
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

/// The first error reading `bytes` under `limits` gives (header or
/// frames); panics if the whole trace reads without one.
pub fn err_of(bytes: &[u8], limits: TraceLimits) -> TraceError {
    let mut r = match TraceReader::with_limits(bytes, limits) {
        Ok(r) => r,
        Err(e) => return e,
    };
    loop {
        match r.next_frame() {
            Ok(Some(_)) => {}
            Ok(None) => panic!("trace parsed without error"),
            Err(e) => return e,
        }
    }
}

/// [`err_of`] under the default limits.
pub fn err(bytes: &[u8]) -> TraceError {
    err_of(bytes, TraceLimits::default())
}

/// `b` with `with` written over it at byte `at`.
pub fn patch(mut b: Vec<u8>, at: usize, with: &[u8]) -> Vec<u8> {
    b[at..at + with.len()].copy_from_slice(with);
    b
}
