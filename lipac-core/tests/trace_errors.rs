//! Bad input gives the documented error, naming frame, location and cause.

mod trace_common;

use glam::Vec3;
use lipac_core::instance::{InstanceFlags, MeshId};
use lipac_core::math::Aabb;
use lipac_core::trace::*;
use trace_common::*;

fn header() -> TraceHeader {
    TraceHeader {
        scene_name: "err".into(),
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

fn camera() -> Camera {
    Camera::look_to(Vec3::ZERO, Vec3::NEG_Z, Vec3::Y, 1.0, 1.5)
}

fn add(id: u64) -> InstanceEvent {
    InstanceEvent::Add(AddInstance {
        id,
        mesh: MeshId(1),
        lod: 0,
        flags: InstanceFlags::empty(),
        mask: None,
        pose: pose_at(1.0, 2.0, 3.0),
        slot: None,
    })
}

// Layout facts from docs/trace-format.md, computed independently of the code.
const PREAMBLE: usize = 20;
/// Header of `header()`: name (4 + 3), world (40), mesh count (4), mesh id
/// (4), bounds (24), LOD count (4), triangles (4), geometry flag (1).
const HEADER_LEN: usize = 4 + 3 + 40 + 4 + 4 + 24 + 4 + 4 + 1;
const FRAME0: usize = PREAMBLE + HEADER_LEN; // first record's length field
const PAYLOAD0: usize = FRAME0 + 4;
const EVENT_COUNT0: usize = PAYLOAD0 + 8 + 36;
const EVENT0: usize = EVENT_COUNT0 + 4;
/// In an add without mask: tag 1, id 8, mesh 4, lod 4, flags 4, options 1.
const ADD_MESH: usize = 1 + 8;
const ADD_TRANSFORM: usize = 1 + 8 + 4 + 4 + 4 + 1;
const ADD_AABB: usize = ADD_TRANSFORM + 48;

/// A one-frame trace (frame number 5) adding instance 1.
fn one_add() -> Vec<u8> {
    to_binary(
        &header(),
        &[Frame {
            number: 5,
            camera: camera(),
            events: vec![add(1)],
            hits: None,
            slot_hits: None,
        }],
    )
}

#[test]
fn layout_offsets_used_here_match_the_writer() {
    let b = one_add();
    assert_eq!(
        u64::from_le_bytes(b[12..20].try_into().unwrap()) as usize,
        HEADER_LEN
    );
    assert_eq!(
        u64::from_le_bytes(b[PAYLOAD0..PAYLOAD0 + 8].try_into().unwrap()),
        5
    );
    assert_eq!(
        u32::from_le_bytes(b[EVENT_COUNT0..EVENT0].try_into().unwrap()),
        1
    );
    assert_eq!(b[EVENT0], 1); // add tag
    assert!(read_binary(&b).is_ok());
}

#[test]
fn wrong_magic_and_version() {
    let e = err(b"PK\x03\x04 not a trace at all");
    assert_eq!(e.location, TraceLocation::Byte(0));
    assert!(matches!(e.kind, TraceErrorKind::BadMagic { .. }), "{e}");
    assert!(e.to_string().contains("not a lipac trace"), "{e}");

    let e = err(&patch(one_add(), 8, &[3, 0]));
    assert_eq!(e.location, TraceLocation::Byte(8));
    assert_eq!(
        e.kind,
        TraceErrorKind::UnsupportedVersion {
            found: 3,
            supported: 2
        }
    );
    assert!(e.to_string().contains("version 3"), "{e}");
    assert!(e.to_string().contains("versions 1 to 2"), "{e}");
}

#[test]
fn truncation_in_header_and_frame() {
    let b = one_add();
    let e = err(&b[..30]);
    assert_eq!(e.frame_index, None);
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::Truncated {
                what: "header record",
                ..
            }
        ),
        "{e}"
    );
    assert_eq!(e.location, TraceLocation::Byte(30));

    let cut = EVENT0 + 10;
    let e = err(&b[..cut]);
    assert_eq!((e.frame_index, e.frame_number), (Some(0), Some(5)));
    assert_eq!(e.location, TraceLocation::Byte(cut as u64));
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::Truncated {
                what: "frame record",
                ..
            }
        ),
        "{e}"
    );
    let s = e.to_string();
    assert!(
        s.contains("frame record 0") && s.contains("frame number 5"),
        "{s}"
    );

    // Cut exactly at the end marker: the missing marker is reported.
    let e = err(&b[..b.len() - 12]);
    assert_eq!(e.kind, TraceErrorKind::MissingEnd { frames: 1 });
    assert_eq!(e.location, TraceLocation::Byte((b.len() - 12) as u64));
}

#[test]
fn end_marker_rules() {
    let b = one_add();
    let mut extra = b.clone();
    extra.push(0);
    assert_eq!(err(&extra).kind, TraceErrorKind::TrailingData);
    let n = b.len();
    let e = err(&patch(b, n - 8, &7u64.to_le_bytes()));
    assert_eq!(
        e.kind,
        TraceErrorKind::FrameCountMismatch {
            recorded: 7,
            read: 1
        }
    );
}

#[test]
fn unknown_mesh_and_lod() {
    let e = err(&patch(one_add(), EVENT0 + ADD_MESH, &99u32.to_le_bytes()));
    assert_eq!(e.kind, TraceErrorKind::UnknownMesh { mesh: 99 });
    assert_eq!(e.location, TraceLocation::Byte(EVENT0 as u64));
    assert_eq!((e.frame_number, e.event), (Some(5), Some(0)));

    let e = err(&patch(
        one_add(),
        EVENT0 + ADD_MESH + 4,
        &1u32.to_le_bytes(),
    ));
    assert_eq!(
        e.kind,
        TraceErrorKind::LodOutOfRange {
            mesh: 1,
            lod: 1,
            lods: 1
        }
    );
}

#[test]
fn non_finite_and_inverted_boxes() {
    let e = err(&patch(
        one_add(),
        EVENT0 + ADD_TRANSFORM + 7 * 4,
        &f32::NAN.to_le_bytes(),
    ));
    match &e.kind {
        TraceErrorKind::NonFinite { what, value } => {
            assert!(what.contains("element 7"), "{what}");
            assert!(value.is_nan());
        }
        k => panic!("{k:?}"),
    }
    assert_eq!(e.event, Some(0));

    let e = err(&patch(
        one_add(),
        EVENT0 + ADD_AABB + 4,
        &f32::INFINITY.to_le_bytes(),
    ));
    assert!(
        matches!(e.kind, TraceErrorKind::InvalidAabb { ref reason, .. } if reason.contains("finite")),
        "{e}"
    );

    // min.x = 100 > max.x = 1.5
    let e = err(&patch(one_add(), EVENT0 + ADD_AABB, &100f32.to_le_bytes()));
    assert!(
        matches!(e.kind, TraceErrorKind::InvalidAabb { ref reason, .. } if reason.contains("inverted")),
        "{e}"
    );

    // Camera: NaN position.
    let e = err(&patch(one_add(), PAYLOAD0 + 8, &f32::NAN.to_le_bytes()));
    assert!(matches!(e.kind, TraceErrorKind::NonFinite { .. }), "{e}");
    assert_eq!(e.location, TraceLocation::Byte(PAYLOAD0 as u64 + 8));
}

#[test]
fn absurd_counts_are_capped_by_limit_and_by_record_size() {
    let huge = u32::MAX.to_le_bytes();
    let e = err(&patch(one_add(), EVENT_COUNT0, &huge));
    assert_eq!(e.location, TraceLocation::Byte(EVENT_COUNT0 as u64));
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::LimitExceeded {
                what: "events in frame",
                value: 4_294_967_295,
                ..
            }
        ),
        "{e}"
    );

    let no_limit = TraceLimits {
        max_events_per_frame: u32::MAX,
        max_meshes: u32::MAX,
        max_lods: u32::MAX,
        max_frame_bytes: u32::MAX,
        max_header_bytes: u64::MAX,
        ..TraceLimits::default()
    };
    let e = err_of(&patch(one_add(), EVENT_COUNT0, &huge), no_limit);
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::CountExceedsRecord {
                what: "event count",
                remaining: 95,
                ..
            }
        ),
        "{e}"
    );

    let mesh_count = PREAMBLE + 4 + 3 + 40;
    let e = err(&patch(one_add(), mesh_count, &huge));
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::LimitExceeded {
                what: "mesh count",
                ..
            }
        ),
        "{e}"
    );
    assert_eq!(e.location, TraceLocation::Byte(mesh_count as u64));
    let e = err_of(&patch(one_add(), mesh_count, &huge), no_limit);
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::CountExceedsRecord {
                what: "mesh count",
                ..
            }
        ),
        "{e}"
    );

    let lod_count = mesh_count + 4 + 4 + 24;
    let e = err(&patch(one_add(), lod_count, &huge));
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::LimitExceeded {
                what: "LOD count",
                ..
            }
        ),
        "{e}"
    );
    let e = err_of(&patch(one_add(), lod_count, &huge), no_limit);
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::CountExceedsRecord {
                what: "LOD count",
                ..
            }
        ),
        "{e}"
    );

    // A frame length of 4 GiB: over the limit, or (without one) reported as
    // truncated after reading only what is there.
    let e = err(&patch(one_add(), FRAME0, &huge));
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::LimitExceeded {
                what: "frame record bytes",
                ..
            }
        ),
        "{e}"
    );
    let e = err_of(&patch(one_add(), FRAME0, &huge), no_limit);
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::Truncated {
                what: "frame record",
                ..
            }
        ),
        "{e}"
    );

    let e = err(&patch(one_add(), 12, &u64::MAX.to_le_bytes()));
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::LimitExceeded {
                what: "header bytes",
                ..
            }
        ),
        "{e}"
    );
    let e = err_of(&patch(one_add(), 12, &u64::MAX.to_le_bytes()), no_limit);
    assert!(
        matches!(
            e.kind,
            TraceErrorKind::Truncated {
                what: "header record",
                ..
            }
        ),
        "{e}"
    );
}

#[test]
fn live_instance_rules() {
    let h = header();
    let frame = |number, events| Frame {
        number,
        camera: camera(),
        events,
        hits: None,
        slot_hits: None,
    };
    let write = |frames: &[Frame]| -> TraceError {
        let mut w = TraceWriter::new(Vec::new(), &h).unwrap();
        for f in frames {
            if let Err(e) = w.write_frame(f) {
                return e;
            }
        }
        panic!("no error");
    };
    let e = write(&[frame(0, vec![add(1)]), frame(1, vec![add(2), add(1)])]);
    assert_eq!(e.kind, TraceErrorKind::DuplicateInstance { id: 1 });
    assert_eq!(
        (e.frame_index, e.frame_number, e.event),
        (Some(1), Some(1), Some(1))
    );

    let e = write(&[
        frame(0, vec![add(1), InstanceEvent::Remove { id: 1 }]),
        frame(1, vec![InstanceEvent::Remove { id: 1 }]),
    ]);
    assert_eq!(
        e.kind,
        TraceErrorKind::UnknownInstance {
            op: "remove",
            id: 1
        }
    );

    let upd = InstanceEvent::Update(UpdateInstance {
        id: 1,
        pose: None,
        lod: Some(0),
        flags: None,
        mask: None,
    });
    let e = write(&[
        frame(0, vec![add(1)]),
        frame(1, vec![InstanceEvent::Remove { id: 1 }, upd]),
    ]);
    assert_eq!(
        e.kind,
        TraceErrorKind::UnknownInstance {
            op: "update",
            id: 1
        }
    );
    assert_eq!(e.event, Some(1));

    let e = write(&[frame(3, vec![]), frame(3, vec![])]);
    assert_eq!(
        e.kind,
        TraceErrorKind::FrameOrder {
            previous: 3,
            given: 3
        }
    );

    let mut f = frame(0, vec![add(1)]);
    f.hits = Some(vec![InstanceHits { id: 2, hits: 1 }]);
    assert_eq!(
        write(&[f.clone()]).kind,
        TraceErrorKind::UnknownInstance { op: "hits", id: 2 }
    );
    f.hits = Some(vec![
        InstanceHits { id: 1, hits: 1 },
        InstanceHits { id: 1, hits: 2 },
    ]);
    assert_eq!(write(&[f]).kind, TraceErrorKind::DuplicateHits { id: 1 });
}

#[test]
fn semantic_errors_in_binary_name_the_event_offset() {
    // Two frames each adding id 1: the second add is a duplicate.
    let h = header();
    let f0 = Frame {
        number: 0,
        camera: camera(),
        events: vec![add(1)],
        hits: None,
        slot_hits: None,
    };
    let f1 = Frame {
        number: 1,
        camera: camera(),
        events: vec![add(2)],
        hits: None,
        slot_hits: None,
    };
    let b = to_binary(&h, &[f0, f1]);
    let frame1 = FRAME0 + 4 + u32::from_le_bytes(b[FRAME0..PAYLOAD0].try_into().unwrap()) as usize;
    let event = frame1 + 4 + 8 + 36 + 4;
    let e = err(&patch(b, event + 1, &1u64.to_le_bytes()));
    assert_eq!(e.kind, TraceErrorKind::DuplicateInstance { id: 1 });
    assert_eq!(e.location, TraceLocation::Byte(event as u64));
    assert_eq!(
        (e.frame_index, e.frame_number, e.event),
        (Some(1), Some(1), Some(0))
    );
}

#[test]
fn skipping_frames_stops_live_tracking_but_keeps_value_checks() {
    let (h, frames) = random_trace(3, 10);
    let b = to_binary(&h, &frames);
    let mut r = TraceReader::new(b.as_slice()).unwrap();
    assert_eq!(r.skip_frame().unwrap(), Some(frames[0].number));
    assert!(!r.validator().tracks_live());
    let mut n = 1;
    // Hits by slot cannot be named without the live set: not derived.
    let frames = without_derived_hits(&frames);
    while let Some(f) = r.next_frame().unwrap() {
        assert_eq!(f, frames[n]);
        n += 1;
    }
    assert_eq!(n, frames.len());
}

const JSON_HEADER: &str = r#"{"format":"lipac-trace","version":1,"scene":"j","world":{"min":[0.0,0.0],"max":[64.0,64.0],"cell_size":16.0},"meshes":[{"id":1,"bounds":{"min":[-1.0,-1.0,-1.0],"max":[1.0,1.0,1.0]},"lods":[{"triangles":12}]}]}"#;
const CAM: &str = r#""camera":{"position":[0.0,1.0,0.0],"orientation":[0.0,0.0,0.0,1.0],"vertical_fov":1.0,"aspect":1.5}"#;
const ADD1: &str = r#"{"add":{"id":1,"mesh":1,"lod":0,"transform":[1.0,0.0,0.0,8.0,0.0,1.0,0.0,0.0,0.0,0.0,1.0,8.0],"aabb":{"min":[7.0,0.0,7.0],"max":[9.0,2.0,9.0]}}}"#;

fn json_err(text: &str) -> TraceError {
    let mut r = match JsonlReader::new(text.as_bytes()) {
        Ok(r) => r,
        Err(e) => return e,
    };
    loop {
        match r.next_frame() {
            Ok(Some(_)) => {}
            Ok(None) => panic!("parsed without error"),
            Err(e) => return e,
        }
    }
}

#[test]
fn jsonl_errors_name_the_line() {
    let ok = format!(
        "{JSON_HEADER}\n{{\"frame\":0,{CAM},\"events\":[{ADD1}]}}\n{{\"end\":{{\"frames\":1}}}}\n"
    );
    assert!(read_jsonl(ok.as_bytes()).is_ok());

    let dup = format!("{JSON_HEADER}\n{{\"frame\":0,{CAM},\"events\":[{ADD1}]}}\n{{\"frame\":1,{CAM},\"events\":[{ADD1}]}}\n");
    let e = json_err(&dup);
    assert_eq!(e.kind, TraceErrorKind::DuplicateInstance { id: 1 });
    assert_eq!(e.location, TraceLocation::Line(3));
    assert_eq!((e.frame_number, e.event), (Some(1), Some(0)));
    assert!(
        e.to_string()
            .starts_with("trace error at line 3 (frame record 1, frame number 1, event 0)"),
        "{e}"
    );

    let e = json_err(&format!(
        "{JSON_HEADER}\n{{\"frame\":0,{CAM},\"events\":[{{\"remove\":{{\"id\":4}}}}]}}\n"
    ));
    assert_eq!(
        e.kind,
        TraceErrorKind::UnknownInstance {
            op: "remove",
            id: 4
        }
    );
    assert_eq!(e.location, TraceLocation::Line(2));

    let e = json_err(&format!(
        "{JSON_HEADER}\n{{\"frame\":0,{CAM},\"evnts\":[]}}\n"
    ));
    assert_eq!(e.location, TraceLocation::Line(2));
    assert!(
        matches!(&e.kind, TraceErrorKind::Json { message, .. } if message.contains("evnts")),
        "{e}"
    );

    let e = json_err(&format!(
        "{JSON_HEADER}\n{{\"frame\":0,{CAM},\"events\":[{}]}}\n",
        ADD1.replace("\"mesh\":1", "\"mesh\":3")
    ));
    assert_eq!(e.kind, TraceErrorKind::UnknownMesh { mesh: 3 });

    let e = json_err(&format!("{JSON_HEADER}\n{{\"frame\":0,{CAM}}}\n"));
    assert_eq!(e.kind, TraceErrorKind::MissingEnd { frames: 1 });
    assert_eq!(e.location, TraceLocation::Line(3));

    let e = json_err(&JSON_HEADER.replace("\"version\":1", "\"version\":9"));
    assert_eq!(
        e.kind,
        TraceErrorKind::UnsupportedVersion {
            found: 9,
            supported: 2
        }
    );
    assert_eq!(e.location, TraceLocation::Line(1));

    let e = json_err("{\"hello\":1}\n");
    assert!(matches!(e.kind, TraceErrorKind::BadMagic { .. }), "{e}");

    let half =
        r#"{"update":{"id":1,"transform":[1.0,0.0,0.0,8.0,0.0,1.0,0.0,0.0,0.0,0.0,1.0,8.0]}}"#;
    let e = json_err(&format!(
        "{JSON_HEADER}\n{{\"frame\":0,{CAM},\"events\":[{ADD1},{half}]}}\n"
    ));
    assert!(
        matches!(&e.kind, TraceErrorKind::InvalidValue { reason, .. } if reason.contains("together")),
        "{e}"
    );
    assert_eq!(e.event, Some(1));
}
