//! A bounded world's grid with hitboxes only for the cells that hold an
//! instance: the cells of a [`HitboxGrid`] (the same exact mapping, its far
//! border closed, nothing outside it), the indices of a
//! [`HashedHitboxes`] (one per occupied cell, in the order cells are first
//! occupied, never evicted).
//!
//! For a world that declares a large grid but uses a few of its cells (a
//! trace's header may declare 4096 x 4096 cells for one instance): memory
//! follows the cells used, not the cells declared. Every instance is in the
//! same cell as with the grid, so a `Manager<SparseGrid>` decides as a
//! `Manager<HitboxGrid>` frame for frame (`tests/hashed_manager.rs`);
//! only the indices differ (first occupation order, not `cx + cz * nx`), and
//! adaptive hitboxes, which need the dense layout, are not available
//! ([`HitboxIndex::dense_dims`] is `None`).
//! [`WorldHitboxes::for_world`](crate::hashed_hitboxes::WorldHitboxes::for_world)
//! picks it for a bounded world of more than
//! [`WorldHitboxes::DENSE_MAX_CELLS`](crate::hashed_hitboxes::WorldHitboxes::DENSE_MAX_CELLS) cells.
//!
//! ```
//! use glam::Vec3;
//! use lipac_core::grid::{GridConfig, HitboxGrid};
//! use lipac_core::hitbox_index::HitboxIndex;
//! use lipac_core::math::Aabb;
//! use lipac_core::sparse_grid::SparseGrid;
//!
//! let world = GridConfig { min: [0.0, 0.0], max: [4096.0, 4096.0], cell_size: 1.0 };
//! let mut index = SparseGrid::new(HitboxGrid::new(world)?)?;
//! assert_eq!(index.len(), 0); // 16.7 million cells declared, none held
//! let at = |x: f32, z: f32| Aabb::new(Vec3::new(x - 0.5, 0.0, z - 0.5), Vec3::new(x + 0.5, 1.0, z + 0.5));
//! assert_eq!(index.occupy(&at(2.0, 2.0))?, 0);
//! assert_eq!(index.occupy(&at(4096.0, 4096.0))?, 1); // the far border is the last cell's
//! assert_eq!(index.cell(1), Some((4095, 4095)));
//! assert!(index.occupy(&at(5000.0, 2.0)).is_err()); // outside the world
//! # Ok::<(), lipac_core::error::CoreError>(())
//! ```

use glam::{Vec2, Vec3};

use crate::error::CoreError;
use crate::grid::{HitboxGrid, DEFAULT_MAX_GRID_CELLS};
use crate::hashed_hitboxes::{HashedConfig, HashedHitboxes};
use crate::hitbox_index::{BoundsChanges, HitboxIndex};
use crate::math::Aabb;

/// A [`HitboxGrid`] whose hitboxes exist only for occupied cells; see the
/// [module docs](self).
#[derive(Clone, Debug)]
pub struct SparseGrid {
    grid: HitboxGrid,
    /// Keyed by the grid's cell index (as `[index as i32, 0]`).
    cells: HashedHitboxes,
}

/// The hashed index's key of grid cell `index` (a bijection of `u32`).
fn key(index: u32) -> [i32; 2] {
    [index as i32, 0]
}

impl SparseGrid {
    /// An index over `grid` holding no cell yet; at most
    /// `min(grid cells, 2^24)` cells (the 24-bit TLAS custom index).
    pub fn new(grid: HitboxGrid) -> Result<Self, CoreError> {
        let max_cells = u64::from(grid.len()).clamp(1, DEFAULT_MAX_GRID_CELLS) as u32;
        let cells = HashedHitboxes::new(HashedConfig {
            max_cells,
            evict_after_frames: u32::MAX,
            initial_buckets: 16,
            ..HashedConfig::default()
        })?;
        Ok(Self { grid, cells })
    }

    /// The grid whose cells these are.
    pub fn grid(&self) -> &HitboxGrid {
        &self.grid
    }

    /// The grid cell `(cx, cz)` of hitbox `index`, or `None` for an index
    /// out of range.
    pub fn cell(&self, index: u32) -> Option<(u32, u32)> {
        let (k, _) = self.cells.cell(index)?;
        self.grid.cell(k as u32)
    }

    /// CPU bytes held ([`HashedHitboxes::heap_bytes`]).
    pub fn heap_bytes(&self) -> u64 {
        self.cells.heap_bytes()
    }
}

impl HitboxIndex for SparseGrid {
    /// Cells occupied so far.
    fn len(&self) -> u32 {
        self.cells.len()
    }

    fn hitbox_at(&self, p: Vec3) -> Option<u32> {
        let g = self.grid.hitbox_at(p)?;
        self.cells.index(key(g)[0], 0)
    }

    fn hitbox_of(&self, aabb: &Aabb) -> Option<u32> {
        let g = self.grid.hitbox_of(aabb)?;
        self.cells.index(key(g)[0], 0)
    }

    /// The grid cell's bounds ([`HitboxGrid`]'s, bit for bit).
    fn xz_bounds(&self, index: u32) -> Option<(Vec2, Vec2)> {
        let (k, _) = self.cells.cell(index)?;
        self.grid.xz_bounds(k as u32)
    }

    /// The hitbox of the grid cell holding `aabb`'s exact centre, created
    /// on its first instance. Errors: [`CoreError::OutsideWorld`] outside
    /// the grid, [`CoreError::TooManyHitboxes`] past 2^24 cells.
    fn occupy(&mut self, aabb: &Aabb) -> Result<u32, CoreError> {
        let g = self.grid.hitbox_of(aabb).ok_or(CoreError::OutsideWorld {
            center: aabb.center(),
        })?;
        self.cells.occupy_key(key(g), aabb)
    }

    fn vacate(&mut self, hitbox: u32) {
        self.cells.vacate(hitbox);
    }

    fn begin_frame(&mut self, frame: u64, evicted: &mut Vec<u32>) {
        self.cells.begin_frame(frame, evicted);
    }

    fn bounds_changes(&self) -> BoundsChanges<'_> {
        self.cells.bounds_changes()
    }
}

#[cfg(test)]
mod tests;
