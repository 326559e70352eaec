//! Format version 2 (slots on adds, hits by slot with counting boxes):
//! hostile input gives the documented errors in both encodings, version 1
//! rejects version 2's fields, and the hits derived from slots follow the
//! documented rule (no overflow at the extremes).

mod trace_common;

use glam::Vec3;
use lipac_core::instance::{InstanceFlags, MeshId};
use lipac_core::math::Aabb;
use lipac_core::trace::*;
use trace_common::*;

fn header() -> TraceHeader {
    TraceHeader {
        scene_name: "v2".into(),
        // 8 x 8 hitboxes of 16 m.
        world: WorldInfo {
            min: [-64.0, -64.0],
            max: [64.0, 64.0],
            cell_size: 16.0,
        },
        meshes: vec![MeshInfo {
            id: MeshId(1),
            bounds: Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0)),
            lods: vec![LodInfo {
                triangles: 12,
                geometry: None,
            }],
        }],
    }
}

fn add(id: u64, slot: Option<u32>, x: f32) -> InstanceEvent {
    InstanceEvent::Add(AddInstance {
        id,
        mesh: MeshId(1),
        lod: 0,
        flags: InstanceFlags::empty(),
        mask: None,
        pose: pose_at(x, 2.0, 3.0),
        slot,
    })
}

fn frame(events: Vec<InstanceEvent>, slot_hits: Option<SlotHits>) -> Frame {
    Frame {
        number: 5,
        camera: Camera::look_to(Vec3::ZERO, Vec3::NEG_Z, Vec3::Y, 1.0, 1.5),
        events,
        hits: None,
        slot_hits,
    }
}

fn sh(slots: &[u32], boxes: &[(u32, u32)]) -> Option<SlotHits> {
    Some(SlotHits {
        slots: slots.to_vec(),
        boxes: boxes
            .iter()
            .map(|&(hitbox, hits)| BoxHits { hitbox, hits })
            .collect(),
    })
}

// Layout (docs/trace-format.md), computed independently of the code.
const HEADER_LEN: usize = 4 + 2 + 40 + 4 + 4 + 24 + 4 + 4 + 1;
const PAYLOAD0: usize = 20 + HEADER_LEN + 4;
const EVENT0: usize = PAYLOAD0 + 8 + 36 + 4;
/// An add with a slot and no mask: tag, id, mesh, LOD, flags, options,
/// slot, pose.
const ADD_SLOT_BYTES: usize = 1 + 8 + 4 + 4 + 4 + 1 + 4 + 72;
const ADD_OPTIONS: usize = 1 + 8 + 4 + 4 + 4;

/// One frame: instance 1 in slot 0 at x = 1 (hitbox 36), instance 2 in
/// slot 1; hits by slot `[5, 0, 0]` and counting boxes of hitboxes 36, 37.
fn base() -> (Vec<u8>, usize) {
    let f = frame(
        vec![add(1, Some(0), 1.0), add(2, Some(1), 17.0)],
        sh(&[5, 0, 0], &[(36, 10), (37, 20)]),
    );
    let b = to_binary(&header(), &[f]);
    (b, EVENT0 + 2 * ADD_SLOT_BYTES)
}

#[test]
fn the_layout_is_as_documented() {
    let (b, hits) = base();
    assert_eq!(&b[8..10], &[2, 0]);
    assert_eq!(b[EVENT0 + ADD_OPTIONS], 2); // slot, no mask
    assert_eq!(
        u32::from_le_bytes(b[EVENT0 + ADD_OPTIONS + 1..][..4].try_into().unwrap()),
        0
    );
    assert_eq!(b[hits], 2); // hits by slot
    let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap());
    assert_eq!(u32_at(hits + 1), 3);
    assert_eq!(
        [u32_at(hits + 5), u32_at(hits + 9), u32_at(hits + 13)],
        [5, 0, 0]
    );
    assert_eq!(u32_at(hits + 17), 2);
    assert_eq!([u32_at(hits + 21), u32_at(hits + 25)], [36, 10]);
    assert_eq!([u32_at(hits + 29), u32_at(hits + 33)], [37, 20]);
    // Then the end marker.
    assert_eq!(u32_at(hits + 37), 0);
    assert_eq!(b.len(), hits + 37 + 12);
    // Instance 2 (no hits of its own) takes box 37's 20; box 36's 10 has
    // no instance without hits (instance 1 has 5 of its own).
    let (_, frames) = read_binary(&b).unwrap();
    assert_eq!(
        frames[0].hits.as_deref(),
        Some(
            &[
                InstanceHits { id: 1, hits: 5 },
                InstanceHits { id: 2, hits: 20 }
            ][..]
        )
    );
}

#[test]
fn hostile_slot_hits_are_rejected_with_clear_errors() {
    let (b, hits) = base();
    // Hits for slot 2, which no live instance holds.
    let e = err(&patch(b.clone(), hits + 13, &7u32.to_le_bytes()));
    assert_eq!(e.kind, TraceErrorKind::UnknownSlot { slot: 2, hits: 7 });
    assert_eq!(e.location, TraceLocation::Byte(hits as u64));
    assert!(e.to_string().contains("slot 2"), "{e}");
    // A slot count over the limit (2^24 slots) and one over the record.
    let e = err(&patch(b.clone(), hits + 1, &u32::MAX.to_le_bytes()));
    assert!(
        matches!(e.kind, TraceErrorKind::LimitExceeded { value, .. } if value == u64::from(u32::MAX)),
        "{e}"
    );
    let e = err(&patch(b.clone(), hits + 1, &1000u32.to_le_bytes()));
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::CountExceedsRecord {
                count: 1000,
                min_element_bytes: 4,
                ..
            }
        ),
        "{e}"
    );
    let limits = TraceLimits {
        max_live_instances: 2,
        ..TraceLimits::default()
    };
    let e = err_of(&b, limits);
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::LimitExceeded {
                value: 3,
                limit: 2,
                ..
            }
        ),
        "{e}"
    );
    // Box count over the record, boxes out of order, out of the grid.
    let e = err(&patch(b.clone(), hits + 17, &0x1000_0000u32.to_le_bytes()));
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::CountExceedsRecord { .. } | TraceErrorKind::LimitExceeded { .. }
        ),
        "{e}"
    );
    let e = err(&patch(b.clone(), hits + 29, &36u32.to_le_bytes()));
    assert!(e.to_string().contains("increasing order"), "{e}");
    let e = err(&patch(b.clone(), hits + 29, &64u32.to_le_bytes()));
    assert!(e.to_string().contains("64 hitboxes"), "{e}");
    // Every truncation is an error.
    for cut in hits..b.len() {
        assert!(
            TraceReader::new(&b[..cut])
                .and_then(|mut r| r.next_frame().and_then(|_| r.next_frame()))
                .is_err(),
            "cut at {cut}"
        );
    }
}

#[test]
fn hostile_slots_on_adds_are_rejected() {
    let (b, _) = base();
    // Instance 2's slot patched to instance 1's.
    let second = EVENT0 + ADD_SLOT_BYTES;
    let e = err(&patch(
        b.clone(),
        second + ADD_OPTIONS + 1,
        &0u32.to_le_bytes(),
    ));
    assert_eq!(e.kind, TraceErrorKind::SlotInUse { slot: 0, id: 1 });
    assert_eq!(e.location, TraceLocation::Byte(second as u64));
    assert_eq!(e.event, Some(1));
    // A slot at or above the live-instance limit.
    let e = err(&patch(
        b.clone(),
        second + ADD_OPTIONS + 1,
        &u32::MAX.to_le_bytes(),
    ));
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::LimitExceeded {
                what: "instance slot",
                ..
            }
        ),
        "{e}"
    );
    // A slot freed by a removal is free again in the same frame.
    let f = frame(
        vec![
            add(1, Some(0), 1.0),
            InstanceEvent::Remove { id: 1 },
            add(2, Some(0), 1.0),
        ],
        sh(&[9], &[]),
    );
    let (_, frames) = read_binary(&to_binary(&header(), &[f])).unwrap();
    assert_eq!(frames[0].hits, Some(vec![InstanceHits { id: 2, hits: 9 }]));
}

#[test]
fn version_1_has_no_slots_and_no_hits_by_slot() {
    let v1 = to_binary_v(1, &header(), &[frame(vec![add(1, None, 1.0)], None)]);
    // The add's options: bit 1 (slot) is undefined in version 1.
    let e = err(&patch(v1.clone(), EVENT0 + ADD_OPTIONS, &[2]));
    assert_eq!(
        e.kind,
        TraceErrorKind::InvalidTag {
            what: "add options",
            value: 2
        }
    );
    // Hits flag 2 is undefined in version 1.
    let hits = EVENT0 + ADD_OPTIONS + 1 + 72;
    assert_eq!(v1[hits], 0);
    let e = err(&patch(v1, hits, &[2]));
    assert_eq!(
        e.kind,
        TraceErrorKind::InvalidTag {
            what: "hits flag",
            value: 2
        }
    );
    // JSON lines: version 1 rejects "slot" and "slot_hits".
    let header = r#"{"format":"lipac-trace","version":1,"scene":"j","world":{"min":[0.0,0.0],"max":[64.0,64.0],"cell_size":16.0},"meshes":[{"id":1,"bounds":{"min":[-1.0,-1.0,-1.0],"max":[1.0,1.0,1.0]},"lods":[{"triangles":12}]}]}"#;
    let cam = r#""camera":{"position":[0.0,1.0,0.0],"orientation":[0.0,0.0,0.0,1.0],"vertical_fov":1.0,"aspect":1.5}"#;
    let add = r#"{"add":{"id":1,"mesh":1,"lod":0,"slot":0,"transform":[1.0,0.0,0.0,8.0,0.0,1.0,0.0,0.0,0.0,0.0,1.0,8.0],"aabb":{"min":[7.0,0.0,7.0],"max":[9.0,2.0,9.0]}}}"#;
    let read = |text: String| -> TraceError {
        let mut r = JsonlReader::new(text.as_bytes()).unwrap();
        loop {
            match r.next_frame() {
                Ok(Some(_)) => {}
                Ok(None) => panic!("parsed"),
                Err(e) => return e,
            }
        }
    };
    let e = read(format!(
        "{header}\n{{\"frame\":0,{cam},\"events\":[{add}]}}\n"
    ));
    assert_eq!(
        e.kind,
        TraceErrorKind::NotInVersion {
            what: "add slot",
            version: 1
        }
    );
    assert_eq!(e.location, TraceLocation::Line(2));
    let e = read(format!(
        "{header}\n{{\"frame\":0,{cam},\"slot_hits\":{{\"slots\":[],\"boxes\":[]}}}}\n"
    ));
    assert!(matches!(e.kind, TraceErrorKind::NotInVersion { .. }), "{e}");
    // Version 2: both hit forms in one line, a missing field, a count
    // past its limit (stopped while parsing).
    let header2 = header.replace("\"version\":1", "\"version\":2");
    let e = read(format!(
        "{header2}\n{{\"frame\":0,{cam},\"events\":[{add}],\"hits\":[],\"slot_hits\":{{\"slots\":[1],\"boxes\":[]}}}}\n"
    ));
    assert!(e.to_string().contains("not both"), "{e}");
    let e = read(format!(
        "{header2}\n{{\"frame\":0,{cam},\"events\":[{add}],\"slot_hits\":{{\"slots\":[1]}}}}\n"
    ));
    assert!(e.to_string().contains("boxes"), "{e}");
    let limits = TraceLimits {
        max_hits_per_frame: 3,
        ..TraceLimits::default()
    };
    let text = format!(
        "{header2}\n{{\"frame\":0,{cam},\"events\":[{add}],\"slot_hits\":{{\"slots\":[1,0,0,0,0,0],\"boxes\":[]}}}}\n"
    );
    let mut r = JsonlReader::with_limits(text.as_bytes(), limits).unwrap();
    let e = r.next_frame().unwrap_err();
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::LimitExceeded {
                value: 4,
                limit: 3,
                ..
            }
        ),
        "{e}"
    );
    let e = read(format!(
        "{header2}\n{{\"frame\":0,{cam},\"events\":[{add}],\"slot_hits\":{{\"slots\":[0,3],\"boxes\":[]}}}}\n"
    ));
    assert_eq!(e.kind, TraceErrorKind::UnknownSlot { slot: 1, hits: 3 });
}

#[test]
fn counting_boxes_need_a_bounded_world() {
    let mut h = header();
    h.world = WorldInfo::unbounded(16.0);
    let mut w = TraceWriter::new(Vec::new(), &h).unwrap();
    let e = w
        .write_frame(&frame(vec![add(1, Some(0), 1.0)], sh(&[0], &[(0, 4)])))
        .unwrap_err();
    assert!(e.to_string().contains("unbounded world"), "{e}");
    // Hits by slot alone are fine there.
    let mut w = TraceWriter::new(Vec::new(), &h).unwrap();
    w.write_frame(&frame(vec![add(1, Some(0), 1.0)], sh(&[4], &[])))
        .unwrap();
    let b = w.finish().unwrap();
    let (_, f) = read_binary(&b).unwrap();
    assert_eq!(f[0].hits, Some(vec![InstanceHits { id: 1, hits: 4 }]));
}

#[test]
fn derived_hits_split_boxes_by_the_rule_without_overflow() {
    // Three instances in hitbox 36 (one pinned), one with hits of its own;
    // the box's u32::MAX hits over the two others, the first one more.
    let mut pinned = add(3, Some(2), 3.0);
    if let InstanceEvent::Add(a) = &mut pinned {
        a.flags = InstanceFlags::PINNED;
    }
    let f = frame(
        vec![
            add(1, Some(4), 1.0),
            add(2, Some(0), 2.0),
            pinned,
            add(4, Some(1), 5.0),
        ],
        sh(&[0, u32::MAX, 0, 0, 0], &[(36, u32::MAX)]),
    );
    let b = to_binary(&header(), std::slice::from_ref(&f));
    let (_, frames) = read_binary(&b).unwrap();
    let half = u32::MAX / 2;
    assert_eq!(
        frames[0].hits,
        Some(vec![
            InstanceHits {
                id: 2,
                hits: half + 1
            },
            InstanceHits {
                id: 4,
                hits: u32::MAX
            },
            InstanceHits { id: 1, hits: half },
        ])
    );
    // The JSON-lines form derives the same and converts back bit for bit.
    let j = to_jsonl(&header(), &[f]);
    let (_, jf) = read_jsonl(&j).unwrap();
    assert_eq!(jf, frames);
    let limits = TraceLimits::default();
    assert_eq!(
        jsonl_to_binary(j.as_slice(), Vec::new(), limits).unwrap(),
        b
    );
}
