use super::*;
use crate::grid::GridConfig;

fn at(x: f32, z: f32) -> Aabb {
    Aabb::new(
        Vec3::new(x - 0.5, 0.0, z - 0.5),
        Vec3::new(x + 0.5, 1.0, z + 0.5),
    )
}

fn grid(n: f64, cell: f64) -> HitboxGrid {
    HitboxGrid::new(GridConfig {
        min: [-8.0, 4.0],
        max: [-8.0 + n * cell, 4.0 + n * cell],
        cell_size: cell,
    })
    .unwrap()
}

/// Every position maps to the grid's cell (far border included, outside
/// refused), with the grid's bounds; indices in first-occupation order.
#[test]
fn cells_are_the_grids_and_only_occupied_ones_exist() {
    let g = grid(64.0, 2.0);
    let mut s = SparseGrid::new(g.clone()).unwrap();
    let points = [
        (0.0, 10.0),
        (-8.0, 4.0),     // the near corner
        (120.0, 132.0),  // the far corner: closed, the last cell
        (119.99, 131.0), // the same cell
        (0.0, 10.5),     // the first cell again
    ];
    let mut seen = Vec::new();
    for (x, z) in points {
        let b = at(x, z);
        let cell = g.hitbox_of(&b).unwrap();
        let h = s.occupy(&b).unwrap();
        match seen.iter().position(|&c| c == cell) {
            Some(i) => assert_eq!(h, i as u32, "({x}, {z})"),
            None => {
                assert_eq!(h, seen.len() as u32, "({x}, {z})");
                seen.push(cell);
            }
        }
        assert_eq!(s.hitbox_of(&b), Some(h));
        assert_eq!(s.xz_bounds(h), g.xz_bounds(cell));
        assert_eq!(s.cell(h), g.cell(cell));
    }
    assert_eq!(s.len(), 3);
    assert_eq!(s.cell(2), Some((63, 63)));
    for (x, z) in [(-8.1, 10.0), (120.1, 10.0), (0.0, 132.5)] {
        assert!(matches!(
            s.occupy(&at(x, z)),
            Err(CoreError::OutsideWorld { .. })
        ));
        assert_eq!(s.hitbox_of(&at(x, z)), None);
    }
    // An empty cell keeps its index (never evicted).
    s.vacate(0);
    s.vacate(0);
    let mut evicted = Vec::new();
    s.begin_frame(1 << 40, &mut evicted);
    assert!(evicted.is_empty());
    assert_eq!(s.hitbox_of(&at(0.0, 10.0)), Some(0));
}

/// A grid of 16.7 million cells holding one instance costs a few hundred
/// bytes, not a record per cell.
#[test]
fn memory_follows_the_cells_used() {
    let mut s = SparseGrid::new(grid(4096.0, 1.0)).unwrap();
    s.occupy(&at(2.0, 6.0)).unwrap();
    assert_eq!(s.len(), 1);
    assert!(s.heap_bytes() < 1024, "{}", s.heap_bytes());
}
