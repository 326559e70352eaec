//! The paper's hitbox structure: a regular grid of cells in x/z.
//!
//! Cell `(cx, cz)` has index `cx + cz * nx`. Cells are half-open in exact
//! (`f64`) arithmetic: cell `cx` holds `x` with
//! `min_x + cx * cell <= x < min_x + (cx + 1) * cell`, so a point exactly on a
//! border between two cells belongs to the upper one, deterministically. The
//! far border of the grid is closed: a point exactly on it belongs to the last
//! cell.
//!
//! Positions arrive as `f32` and are widened to `f64` (exactly) before any
//! arithmetic, so indexing stays exact far from the origin (±100 km and
//! beyond), where `f32` cell borders would already be rounded.
//!
//! An instance belongs to the cell holding its AABB's *exact* centre
//! ([`HitboxIndex::hitbox_of`]): the centre `(min + max) / 2` of the `f32`
//! corners is kept as an unevaluated `f64` sum (no rounding at all), so it is
//! never moved across a cell border or out of the world by rounding.
//! [`HitboxIndex::xz_bounds`] rounds the `f64` cell borders *outwards* to
//! `f32`, so a cell's `f32` bounds contain its exact region; where a border
//! is not an `f32` value, neighbouring cells overlap by one `f32` step (never
//! a gap). See `docs/PRECISION.md`.
//!
//! # Memory
//!
//! Each hitbox costs [`HITBOX_BYTES`] = 20 bytes on the GPU
//! ([`crate::layout::HitboxRecord`]: the paper's 12 plus the decayed rule's
//! rate and cost words) and each instance
//! [`HIT_FEEDBACK_BYTES_PER_INSTANCE`] = 4 bytes of hit feedback. The paper's
//! 8 × 8 km world with 16 m cells is 512 × 512 hitboxes = 5 MiB (the paper's
//! 12-byte records: 3 MiB) ([`HitboxGrid::memory_bytes`]); a million
//! instances need 4 MB of hit counters ([`hit_feedback_bytes`]).

use crate::error::CoreError;
use crate::hitbox_index::HitboxIndex;
use crate::layout::HitboxRecord;
use crate::math::Aabb;
use glam::{Vec2, Vec3};

/// GPU bytes per hitbox (one [`HitboxRecord`]).
pub const HITBOX_BYTES: u64 = std::mem::size_of::<HitboxRecord>() as u64;

/// GPU bytes of hit feedback per instance slot (one `u32` counter).
pub const HIT_FEEDBACK_BYTES_PER_INSTANCE: u64 = 4;

/// GPU bytes of hit feedback for `instance_slots` instance slots.
pub const fn hit_feedback_bytes(instance_slots: u32) -> u64 {
    instance_slots as u64 * HIT_FEEDBACK_BYTES_PER_INSTANCE
}

/// A sensible cap on the cells of a grid that something will allocate per
/// cell (hitbox records, per-cell state): 2^24 cells, i.e. 192 MiB of
/// hitbox records at [`HITBOX_BYTES`] each, a 4096 × 4096 grid (65 km
/// square at the paper's 16 m cells). See [`HitboxGrid::with_max_cells`].
pub const DEFAULT_MAX_GRID_CELLS: u64 = 1 << 24;

/// Parameters of a [`HitboxGrid`], in metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridConfig {
    /// Minimum world corner `[x, z]`.
    pub min: [f64; 2],
    /// Maximum world corner `[x, z]`. Rounded up to a whole number of cells.
    pub max: [f64; 2],
    /// Edge length of the square cells (the paper uses 16 m).
    pub cell_size: f64,
}

impl Default for GridConfig {
    /// The paper's setting: an 8 × 8 km world centred on the origin with
    /// 16 m cells (512 × 512 hitboxes, 3 MiB).
    fn default() -> Self {
        Self {
            min: [-4096.0, -4096.0],
            max: [4096.0, 4096.0],
            cell_size: 16.0,
        }
    }
}

/// A regular 2D grid of hitboxes over x/z (Y is up; heights come from the
/// instances).
///
/// ```
/// use glam::Vec3;
/// use lipac_core::grid::{GridConfig, HitboxGrid};
/// use lipac_core::hitbox_index::HitboxIndex;
///
/// let grid = HitboxGrid::new(GridConfig {
///     min: [0.0, 0.0],
///     max: [64.0, 32.0],
///     cell_size: 16.0,
/// })?;
/// assert_eq!(grid.dims(), (4, 2));
/// assert_eq!(grid.len(), 8);
/// // A point on the border between cells 0 and 1 belongs to cell 1 ...
/// assert_eq!(grid.hitbox_at(Vec3::new(16.0, 100.0, 0.0)), Some(1));
/// // ... and one on the far border of the world to the last cell.
/// assert_eq!(grid.hitbox_at(Vec3::new(64.0, 0.0, 32.0)), Some(7));
/// assert_eq!(grid.hitbox_at(Vec3::new(-0.01, 0.0, 0.0)), None);
/// assert_eq!(grid.memory_bytes(), 8 * 20);
/// # Ok::<(), lipac_core::error::CoreError>(())
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct HitboxGrid {
    min: [f64; 2],
    cell_size: f64,
    /// `1 / cell_size`, for the first estimate only (fixed up exactly).
    inv_cell: f64,
    dims: [u32; 2],
}

impl HitboxGrid {
    /// Builds a grid, rejecting non-finite values, `cell_size <= 0`,
    /// `max <= min` and grids with more than `u32::MAX` cells.
    pub fn new(config: GridConfig) -> Result<Self, CoreError> {
        let GridConfig {
            min,
            max,
            cell_size,
        } = config;
        let invalid = |what: String| Err(CoreError::InvalidConfig { what });
        if !cell_size.is_finite() || cell_size <= 0.0 {
            return invalid(format!("grid cell size {cell_size} must be finite and > 0"));
        }
        let mut dims = [0u32; 2];
        for (axis, name) in ["x", "z"].into_iter().enumerate() {
            let (lo, hi) = (min[axis], max[axis]);
            if !lo.is_finite() || !hi.is_finite() {
                return invalid(format!("grid bounds {name} {lo}..{hi} must be finite"));
            }
            if hi <= lo {
                return invalid(format!(
                    "grid bounds {name} {lo}..{hi}: max must exceed min"
                ));
            }
            let cells = ((hi - lo) / cell_size).ceil();
            if cells > f64::from(u32::MAX) {
                return invalid(format!(
                    "grid {name} extent {} / cell size {cell_size} = {cells} cells exceeds u32",
                    hi - lo
                ));
            }
            dims[axis] = (cells as u32).max(1);
        }
        if u64::from(dims[0]) * u64::from(dims[1]) > u64::from(u32::MAX) {
            return invalid(format!(
                "grid of {} x {} cells has more than u32::MAX cells",
                dims[0], dims[1]
            ));
        }
        Ok(Self {
            min,
            cell_size,
            inv_cell: cell_size.recip(),
            dims,
        })
    }

    /// As [`HitboxGrid::new`], also rejecting grids of more than `max_cells`
    /// cells, with an error naming the dimensions, the cell count, the
    /// hitbox bytes it would take and the limit. For grids from untrusted
    /// input (a trace header, a configuration file) whose consumers allocate
    /// per cell; [`DEFAULT_MAX_GRID_CELLS`] is a sensible `max_cells`.
    ///
    /// ```
    /// use lipac_core::grid::{GridConfig, HitboxGrid, DEFAULT_MAX_GRID_CELLS};
    /// // 65535 x 65535 one-metre cells: 51.5 GB of hitbox records.
    /// let huge = GridConfig { min: [0.0, 0.0], max: [65535.0, 65535.0], cell_size: 1.0 };
    /// assert!(HitboxGrid::new(huge).is_ok()); // only its size is stored
    /// let e = HitboxGrid::with_max_cells(huge, DEFAULT_MAX_GRID_CELLS).unwrap_err();
    /// assert!(e.to_string().contains("4294836225 cells"), "{e}");
    /// ```
    pub fn with_max_cells(config: GridConfig, max_cells: u64) -> Result<Self, CoreError> {
        let grid = Self::new(config)?;
        let cells = u64::from(grid.len());
        if cells > max_cells {
            let (nx, nz) = grid.dims();
            return Err(CoreError::InvalidConfig {
                what: format!(
                    "grid of {nx} x {nz} = {cells} cells ({} bytes of hitbox records; \
                     world {:?}..{:?}, cell size {}) exceeds the limit of {max_cells} cells",
                    cells * HITBOX_BYTES,
                    config.min,
                    config.max,
                    config.cell_size
                ),
            });
        }
        Ok(grid)
    }

    /// Cells along x and z.
    pub fn dims(&self) -> (u32, u32) {
        (self.dims[0], self.dims[1])
    }

    /// Edge length of a cell.
    pub fn cell_size(&self) -> f64 {
        self.cell_size
    }

    /// Minimum world corner `[x, z]`.
    pub fn min(&self) -> [f64; 2] {
        self.min
    }

    /// Maximum world corner `[x, z]` actually covered: `min` plus a whole
    /// number of cells (at least the configured `max`).
    pub fn max(&self) -> [f64; 2] {
        [self.border(0, self.dims[0]), self.border(1, self.dims[1])]
    }

    /// GPU memory of the hitbox records: [`HITBOX_BYTES`] per hitbox.
    pub fn memory_bytes(&self) -> u64 {
        u64::from(self.len()) * HITBOX_BYTES
    }

    /// Index of cell `(cx, cz)`, or `None` outside the grid.
    pub fn index(&self, cx: u32, cz: u32) -> Option<u32> {
        (cx < self.dims[0] && cz < self.dims[1]).then(|| cx + cz * self.dims[0])
    }

    /// Cell coordinates `(cx, cz)` of `index`, or `None` out of range.
    pub fn cell(&self, index: u32) -> Option<(u32, u32)> {
        (index < self.len()).then(|| (index % self.dims[0], index / self.dims[0]))
    }

    /// Cell `(cx, cz)` holding the point `(x, z)`, or `None` outside the grid
    /// or for non-finite input.
    pub fn cell_at(&self, x: f64, z: f64) -> Option<(u32, u32)> {
        Some((self.axis_cell(0, x)?, self.axis_cell(1, z)?))
    }

    /// Exact (`f64`) bounds `([min x, min z], [max x, max z])` of cell
    /// `index`; the cell holds `min <= p < max` (and `p == max` on the far
    /// border of the grid).
    pub fn bounds_f64(&self, index: u32) -> Option<([f64; 2], [f64; 2])> {
        let (cx, cz) = self.cell(index)?;
        Some((
            [self.border(0, cx), self.border(1, cz)],
            [self.border(0, cx + 1), self.border(1, cz + 1)],
        ))
    }

    /// Position of border `k` (between cells `k - 1` and `k`) on `axis`.
    fn border(&self, axis: usize, k: u32) -> f64 {
        self.min[axis] + f64::from(k) * self.cell_size
    }

    fn axis_cell(&self, axis: usize, v: f64) -> Option<u32> {
        self.axis_cell_exact(axis, v, 0.0)
    }

    /// The cell on `axis` holding the exact value `hi + lo` (an unevaluated
    /// sum with `|lo| <= ulp(hi) / 2`, as [`exact_center`] returns).
    fn axis_cell_exact(&self, axis: usize, hi: f64, lo: f64) -> Option<u32> {
        // `hi + lo < b` exactly, for an f64 border `b`: since `hi` is the
        // f64 nearest to `hi + lo`, the sign of `hi - b` decides unless
        // `hi == b`, where the sign of `lo` does.
        let below = |b: f64| hi < b || (hi == b && lo < 0.0);
        let above = |b: f64| hi > b || (hi == b && lo > 0.0);
        let n = self.dims[axis];
        if !hi.is_finite()
            || !lo.is_finite()
            || below(self.border(axis, 0))
            || above(self.border(axis, n))
        {
            return None;
        }
        let estimate = ((hi - self.min[axis]) * self.inv_cell).floor();
        // The estimate may round across a border; fix up against the exact
        // borders so that border(k) <= v < border(k + 1) holds, using the same
        // `border` function as `bounds_f64`.
        let mut k = (estimate.max(0.0) as u32).min(n - 1);
        while k > 0 && below(self.border(axis, k)) {
            k -= 1;
        }
        while k + 1 < n && !below(self.border(axis, k + 1)) {
            k += 1;
        }
        Some(k)
    }

    /// Cell `(cx, cz)` holding the exact centre of `aabb` in x/z, or `None`
    /// outside the grid or for non-finite corners. Unlike
    /// `cell_at(aabb.center())`, the centre is not rounded to `f32`.
    pub fn cell_of_aabb_center(&self, aabb: &Aabb) -> Option<(u32, u32)> {
        let (xh, xl) = exact_center(aabb.min.x, aabb.max.x);
        let (zh, zl) = exact_center(aabb.min.z, aabb.max.z);
        Some((
            self.axis_cell_exact(0, xh, xl)?,
            self.axis_cell_exact(1, zh, zl)?,
        ))
    }
}

/// The exact midpoint of two `f32` values as an unevaluated `f64` sum
/// `hi + lo` (`hi` the nearest `f64`, `|lo| <= ulp(hi) / 2`): Knuth's TwoSum
/// of the widened values, halved. Exact for every pair of finite `f32`
/// (no overflow in `f64`; halving a multiple of 2^-149 stays exact).
pub(crate) fn exact_center(a: f32, b: f32) -> (f64, f64) {
    let (a, b) = (f64::from(a), f64::from(b));
    let s = a + b;
    let bb = s - a;
    let e = (a - (s - bb)) + (b - bb);
    (s * 0.5, e * 0.5)
}

/// The largest `f32` not above `v` (`v` finite and within `f32` range).
fn f32_down(v: f64) -> f32 {
    let r = v as f32; // nearest
    if f64::from(r) > v {
        next_toward_neg_inf(r)
    } else {
        r
    }
}

/// The next `f32` below a finite `x`.
fn next_toward_neg_inf(x: f32) -> f32 {
    if x == 0.0 {
        -f32::from_bits(1)
    } else if x > 0.0 {
        f32::from_bits(x.to_bits() - 1)
    } else {
        f32::from_bits(x.to_bits() + 1)
    }
}

impl HitboxIndex for HitboxGrid {
    fn len(&self) -> u32 {
        // Checked in `new` to fit.
        self.dims[0] * self.dims[1]
    }

    fn dense_dims(&self) -> Option<(u32, u32)> {
        Some(self.dims())
    }

    fn hitbox_at(&self, p: Vec3) -> Option<u32> {
        let (cx, cz) = self.cell_at(f64::from(p.x), f64::from(p.z))?;
        self.index(cx, cz)
    }

    /// The exact centre of `aabb` (not rounded to `f32`); see
    /// [`HitboxGrid::cell_of_aabb_center`].
    fn hitbox_of(&self, aabb: &Aabb) -> Option<u32> {
        let (cx, cz) = self.cell_of_aabb_center(aabb)?;
        self.index(cx, cz)
    }

    /// Bounds rounded *outwards* to `f32` (minimum down, maximum up), so they
    /// contain the exact cell `bounds_f64(index)`: unchanged where a border
    /// is an `f32` value, one `f32` step of overlap with the neighbour where
    /// it is not. A cell reaching beyond the `f32` range gets infinite
    /// bounds (and then no counting box).
    fn xz_bounds(&self, index: u32) -> Option<(Vec2, Vec2)> {
        let (lo, hi) = self.bounds_f64(index)?;
        Some(outward_f32_bounds(lo, hi))
    }
}

/// Exact (`f64`) cell bounds `lo..hi` rounded *outwards* to `f32` (minimum
/// down, maximum up), so they contain the exact cell; beyond the `f32` range
/// they become infinite.
pub(crate) fn outward_f32_bounds(lo: [f64; 2], hi: [f64; 2]) -> (Vec2, Vec2) {
    let down = |v: f64| {
        if v < -f64::from(f32::MAX) {
            f32::NEG_INFINITY
        } else if v > f64::from(f32::MAX) {
            f32::MAX
        } else {
            f32_down(v)
        }
    };
    let up = |v: f64| -down(-v);
    (
        Vec2::new(down(lo[0]), down(lo[1])),
        Vec2::new(up(hi[0]), up(hi[1])),
    )
}

#[cfg(test)]
mod tests;
