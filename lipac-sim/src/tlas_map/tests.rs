use super::*;

/// A 10 m x 10 m map with no instances, the camera in a corner looking
/// out of it (+x), drawn at 16 x 16 pixels (1.6 px per m).
fn empty() -> TlasMap {
    TlasMap {
        instances: Vec::new(),
        hitboxes: Vec::new(),
        active_hitboxes: Vec::new(),
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

#[test]
fn active_hitboxes_are_outlined_inactive_ones_shaded() {
    let mut map = empty();
    // Active cell 0..5 m (pixels 0..8, outline on 0 and 7), inactive hit
    // cell 5..10 m x 5..10 m (pixels 8..16).
    map.active_hitboxes.push(MapHitbox {
        index: 0,
        merged: false,
        min: Vec2::ZERO,
        max: Vec2::splat(5.0),
        hits: 3,
    });
    map.hitboxes.push(MapHitbox {
        index: 3,
        merged: false,
        min: Vec2::splat(5.0),
        max: Vec2::splat(10.0),
        hits: 2,
    });
    let px = map.pixels(16);
    assert_eq!(pixel(&px, 16, 0, 4), HITBOX_ACTIVE, "outline");
    assert_eq!(pixel(&px, 16, 7, 4), HITBOX_ACTIVE, "outline");
    let inside = pixel(&px, 16, 4, 4);
    assert_ne!(inside, [255; 3], "light fill");
    assert!(inside.iter().all(|&c| c > 200), "light: {inside:?}");
    let hot = pixel(&px, 16, 12, 12);
    assert!(
        hot[0] > hot[2] && hot[2] < 100,
        "hit inactive hitbox: {hot:?}"
    );
    assert_eq!(legend_count(&map, HITBOX_ACTIVE), 1);
    assert_eq!(legend_count(&map, HITBOX_HOT), 1);
    assert_eq!(legend_count(&map, HITBOX_COLD), 0);
}

#[test]
fn new_takes_the_active_cells_only() {
    use crate::camera::FlyCamera;
    use crate::scene::{Scene, SceneConfig};
    let scene = Scene::generate(&SceneConfig::small()).unwrap();
    let camera = FlyCamera::look_at(Vec3::new(0.0, 10.0, 0.0), Vec3::X, 1.0, 1.5).unwrap();
    let cell = |index, active, max: f32| HitboxCell {
        index,
        min: Vec2::ZERO,
        max: Vec2::splat(max),
        active,
        hits: index,
    };
    let cells = [
        cell(0, true, 4.0),
        cell(1, false, 4.0),
        cell(2, true, f32::INFINITY),
    ];
    let counting = CountingBoxes::default();
    let counters = Counters::default();
    let map = TlasMap::new(&scene, &[], &counting, &counters, &camera, Some(&cells)).unwrap();
    assert_eq!(map.active_hitboxes.len(), 1);
    assert_eq!(map.active_hitboxes[0].index, 0);
    assert!(map.hitboxes.is_empty(), "inactive ones come from records");
    // Every instance of the scene, pinned terrain tiles flagged so.
    assert_eq!(map.instances.len(), scene.instances().len());
    assert_eq!(
        map.pinned(),
        scene.instances().iter().filter(|i| i.is_pinned()).count()
    );
    let none = TlasMap::new(&scene, &[], &counting, &counters, &camera, None).unwrap();
    assert!(none.active_hitboxes.is_empty());
}
