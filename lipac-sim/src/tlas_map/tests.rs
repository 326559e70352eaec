use super::*;

/// A 10 m x 10 m map with no instances, the camera in a corner looking
/// out of it (+x), drawn at 16 x 16 pixels (1.6 px per m).
fn empty() -> TlasMap {
    TlasMap {
        instances: Vec::new(),
        hitboxes: Vec::new(),
        camera: Vec2::new(9.5, 0.5),
        frustum: [Vec2::X, Vec2::X],
        bounds_min: Vec2::ZERO,
        bounds_max: Vec2::splat(10.0),
    }
}

fn instance(min: f32, max: f32, state: MapState) -> MapInstance {
    MapInstance {
        min: Vec2::splat(min),
        max: Vec2::splat(max),
        state,
        hits: 0,
        terrain: false,
        pinned: false,
    }
}

fn pixel(px: &[u8], n: usize, x: usize, y: usize) -> [u8; 3] {
    let i = (y * n + x) * 3;
    [px[i], px[i + 1], px[i + 2]]
}

fn legend_count(map: &TlasMap, color: [u8; 3]) -> usize {
    map.legend()
        .iter()
        .filter(|(_, c, _)| *c == color)
        .map(|&(_, _, n)| n)
        .sum()
}

#[test]
fn pinned_instances_have_their_own_colour_and_count() {
    let mut map = empty();
    // A pinned object (TLAS: active) at 1..4 m, pixels 2..6; a pinned
    // terrain tile at 5..9 m, outline on pixels 8 and 14; an unpinned
    // active one at 0..1 m, pixels 0..2.
    map.instances.push(MapInstance {
        pinned: true,
        ..instance(1.0, 4.0, MapState::Active)
    });
    map.instances.push(MapInstance {
        pinned: true,
        terrain: true,
        ..instance(5.0, 9.0, MapState::Active)
    });
    map.instances.push(instance(0.0, 1.0, MapState::Active));
    let px = map.pixels(16);
    assert_eq!(pixel(&px, 16, 4, 4), PINNED);
    assert_eq!(pixel(&px, 16, 8, 11), PINNED, "terrain outline");
    assert_eq!(pixel(&px, 16, 11, 11), [255; 3], "terrain interior");
    assert_eq!(pixel(&px, 16, 0, 0), ACTIVE);
    assert_eq!(map.pinned(), 2);
    assert_eq!(map.count(MapState::Active), 1, "pinned ones left out");
    assert_eq!(legend_count(&map, PINNED), 2);
    assert_eq!(legend_count(&map, TERRAIN), 0, "the tile counts as pinned");
    assert_eq!(legend_count(&map, ACTIVE), 1);
}
