//! Traces of unbounded worlds: the header may omit the world bounds
//! (`WorldInfo::unbounded`, no new format version: the binary header keeps
//! its five `f64`s, with `-inf`/`+inf` bounds; JSON lines omit `min` and
//! `max`), they round-trip in both formats and through conversion, older
//! bounded traces read as before, and half-declared bounds are refused.

mod trace_common;

use lipac_core::trace::*;
use trace_common::*;

fn unbounded_trace() -> (TraceHeader, Vec<Frame>) {
    let (mut h, f) = tiny_trace();
    h.world = WorldInfo::unbounded(16.0);
    (h, f)
}

#[test]
fn an_unbounded_world_round_trips_in_both_formats() {
    let (h, f) = unbounded_trace();
    assert!(!h.world.is_bounded());
    let bin = to_binary(&h, &f);
    let (h2, f2) = read_binary(&bin).unwrap();
    assert_eq!((&h2, &f2), (&h, &f));
    let jsonl = to_jsonl(&h, &f);
    let text = String::from_utf8(jsonl.clone()).unwrap();
    let first = text.lines().next().unwrap();
    assert!(first.contains(r#""world":{"cell_size":16.0}"#), "{first}");
    let (h3, f3) = read_jsonl(&jsonl).unwrap();
    assert_eq!((&h3, &f3), (&h, &f));
    // Conversion keeps it.
    let mut out = Vec::new();
    binary_to_jsonl(bin.as_slice(), &mut out, TraceLimits::default()).unwrap();
    assert_eq!(out, jsonl);
    // Its cells: the hashed index anchored at the origin.
    let c = h.world.hashed_config();
    assert_eq!((c.origin, c.cell_size), ([0.0, 0.0], 16.0));
}

#[test]
fn bounded_worlds_read_as_before() {
    let (h, f) = tiny_trace();
    assert!(h.world.is_bounded());
    let text = String::from_utf8(to_jsonl(&h, &f)).unwrap();
    assert!(text.contains(r#""world":{"min":[-64.0,-64.0],"max":[64.0,64.0],"cell_size":16.0}"#));
    assert_eq!(read_binary(&to_binary(&h, &f)).unwrap().0, h);
    assert_eq!(h.world.hashed_config().origin, h.world.min);
}

#[test]
fn half_declared_or_invalid_unbounded_worlds_are_refused() {
    let (h, f) = tiny_trace();
    let text = String::from_utf8(to_jsonl(&h, &f)).unwrap();
    for (world, needle) in [
        (
            r#""world":{"min":[-64.0,-64.0],"cell_size":16.0}"#,
            "world grid",
        ),
        (
            r#""world":{"max":[64.0,64.0],"cell_size":16.0}"#,
            "world grid",
        ),
        (r#""world":{"cell_size":0.0}"#, "unbounded world"),
    ] {
        let bad = text.replacen(
            r#""world":{"min":[-64.0,-64.0],"max":[64.0,64.0],"cell_size":16.0}"#,
            world,
            1,
        );
        let e = JsonlReader::new(bad.as_bytes()).unwrap_err();
        assert_eq!(e.location, TraceLocation::Line(1));
        assert!(e.to_string().contains(needle), "{world}: {e}");
    }
    // Binary: only one bound infinite.
    let (mut h, f) = unbounded_trace();
    h.world.max[1] = 64.0;
    let mut w = Vec::new();
    let e = TraceWriter::new(&mut w, &h).err();
    let bytes = to_binary(&unbounded_trace().0, &f);
    let name_len = u32::from_le_bytes(bytes[20..24].try_into().unwrap()) as usize;
    let at = 24 + name_len;
    let mut bad = bytes.clone();
    bad[at + 24..at + 32].copy_from_slice(&64.0f64.to_le_bytes()); // max_z
    let e2 = TraceReader::new(bad.as_slice()).unwrap_err();
    assert_eq!(e2.location, TraceLocation::Byte(at as u64), "{e2}");
    assert!(e2.to_string().contains("world grid"), "{e2}");
    assert!(e.is_some(), "the writer refuses the header too");
}

#[test]
fn the_world_picks_the_hitbox_structure() {
    use lipac_core::hitbox_index::HitboxIndex;
    use lipac_core::WorldHitboxes;
    let (h, _) = tiny_trace();
    let grid = WorldHitboxes::for_world(&h.world, 1 << 24).unwrap();
    assert!(matches!(grid, WorldHitboxes::Grid(_)));
    assert_eq!(grid.len(), 64, "128 m / 16 m cells squared");
    assert!(WorldHitboxes::for_world(&h.world, 63).is_err());
    let mut hashed = WorldHitboxes::for_world(&WorldInfo::unbounded(16.0), 1).unwrap();
    assert!(matches!(hashed, WorldHitboxes::Hashed(_)));
    assert_eq!(hashed.len(), 0);
    let far = lipac_core::Aabb::new(glam::Vec3::splat(5.0e5), glam::Vec3::splat(5.0e5 + 1.0));
    assert_eq!(hashed.occupy(&far), Ok(0));
    assert_eq!(hashed.hitbox_of(&far), Some(0));
}
