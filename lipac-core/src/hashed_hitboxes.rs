//! A sparse hashed grid of hitboxes for unbounded worlds: memory proportional
//! to the occupied cells, no world bounds declared up front.
//!
//! The cells are those of a regular x/z grid of square cells anchored at
//! [`HashedConfig::origin`] (cell `(cx, cz)` holds
//! `origin + c * cell_size <= p < origin + (c + 1) * cell_size` per axis,
//! in exact `f64` arithmetic, with `cx, cz` any `i32`): the same half-open
//! cells as [`crate::grid::HitboxGrid`] with `min = origin`, but without a
//! far border. Only cells that hold an instance exist. A cell gets a hitbox
//! index when its first instance arrives ([`HitboxIndex::occupy`]); the
//! indices are dense (`0..len()`, `len()` the most cells alive at once) as
//! Algorithms 1 and 2 and the GPU buffers need, and the GPU only ever sees
//! these indices and the hitbox records, never the table.
//!
//! The lookup from cell to index is AMD GI-1.0's spatial hash (Boissé et
//! al. 2022, §5.2): a 64-bit hash of the cell coordinates picks the bucket,
//! a second part of it is stored as the bucket's *fingerprint*, and
//! collisions probe linearly (wrapping around the table end). A lookup
//! compares fingerprints first and the full cell key only on a match, so
//! lookups are exact (two cells never share a hitbox, unlike the lossy
//! GPU table of GI-1.0). The table doubles when it is half full, so probes
//! stay short; rehashing never changes an index. Removal shifts the
//! following entries back (no tombstones).
//!
//! Eviction is GI-1.0's decay: a cell left empty ([`HitboxIndex::vacate`]
//! of its last instance) is kept for [`HashedConfig::evict_after_frames`]
//! frames, so an instance moving back and forth over a border does not
//! churn; at the [`HitboxIndex::begin_frame`] after that it is dropped and
//! its index goes to a free list (reused lowest first). The caller resets
//! the hitbox record of an evicted index
//! ([`crate::culling::Culling::begin_frame`] does).
//!
//! Every index that gets a cell or loses one is logged for GPU backends,
//! which keep a copy of the bounds ([`HitboxIndex::bounds_changes`]; the
//! log keeps the changes since the frame start before the last one).
//!
//! A full index ([`HashedConfig::max_cells`] live cells) refuses a new cell
//! with [`CoreError::TooManyHitboxes`]; nothing panics on input.
//!
//! # Memory
//!
//! CPU: [`HashedHitboxes::heap_bytes`], 16 bytes per table bucket (at most
//! 4 buckets per live cell, at least 2 once grown) plus 24 bytes per index
//! ever handed out. GPU: [`crate::grid::HITBOX_BYTES`] = 20 bytes per index
//! ([`HashedHitboxes::memory_bytes`]), plus 16 bytes of bounds in lipac-vk.
//!
//! ```
//! use glam::Vec3;
//! use lipac_core::hashed_hitboxes::{HashedConfig, HashedHitboxes};
//! use lipac_core::hitbox_index::HitboxIndex;
//! use lipac_core::math::Aabb;
//!
//! let mut index = HashedHitboxes::new(HashedConfig::default())?; // 16 m cells
//! let far = Aabb::new(Vec3::new(1.0e6, 0.0, -3.0e6), Vec3::new(1.0e6 + 2.0, 5.0, -3.0e6 + 2.0));
//! assert_eq!(index.hitbox_of(&far), None); // no cell there yet
//! let h = index.occupy(&far)?; // first instance: the cell gets index 0
//! assert_eq!((h, index.len()), (0, 1));
//! assert_eq!(index.hitbox_at(Vec3::new(1.0e6 + 1.0, 0.0, -3.0e6 + 1.0)), Some(0));
//! index.vacate(h); // its last instance left
//! let mut evicted = Vec::new();
//! index.begin_frame(64, &mut evicted); // empty for 64 frames: dropped
//! assert_eq!(evicted, vec![0]);
//! assert_eq!(index.hitbox_of(&far), None);
//! # Ok::<(), lipac_core::error::CoreError>(())
//! ```

use std::cmp::Reverse;
use std::collections::{BinaryHeap, VecDeque};

use crate::error::CoreError;
use crate::grid::{exact_center, outward_f32_bounds, DEFAULT_MAX_GRID_CELLS, HITBOX_BYTES};
use crate::hitbox_index::{BoundsChanges, HitboxIndex};
use crate::math::Aabb;
use crate::memory::vec_bytes;
use glam::{Vec2, Vec3};

/// Parameters of a [`HashedHitboxes`], in metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HashedConfig {
    /// Corner `[x, z]` of cell `(0, 0)`; cells extend from it in both
    /// directions without bound (within `i32` cell coordinates).
    pub origin: [f64; 2],
    /// Edge length of the square cells (the paper uses 16 m).
    pub cell_size: f64,
    /// Most cells alive at once (and so the most hitbox indices); a new
    /// cell beyond it is [`CoreError::TooManyHitboxes`]. At most 2^24 (the
    /// 24-bit TLAS custom index of a counting box).
    pub max_cells: u32,
    /// Frames an empty cell is kept before it is evicted (0: at the next
    /// frame start; `u32::MAX`: never, and nothing is queued for it).
    pub evict_after_frames: u32,
    /// Buckets of the table at first (a power of two, at least 2); it
    /// doubles whenever it would be more than half full.
    pub initial_buckets: u32,
    /// Bits of the stored fingerprint (1..=32). Fewer bits only make
    /// fingerprint collisions more frequent (they are resolved by comparing
    /// the full key); for tests.
    pub fingerprint_bits: u32,
}

impl Default for HashedConfig {
    /// 16 m cells from the origin, up to 2^24 cells, eviction after 64
    /// empty frames, 1024 buckets at first, 32-bit fingerprints.
    fn default() -> Self {
        Self {
            origin: [0.0, 0.0],
            cell_size: 16.0,
            max_cells: DEFAULT_MAX_GRID_CELLS as u32,
            evict_after_frames: 64,
            initial_buckets: 1024,
            fingerprint_bits: 32,
        }
    }
}

/// One bucket of the open-addressing table (16 bytes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Bucket {
    /// 0 = empty; otherwise the cell key's fingerprint (never 0).
    fingerprint: u32,
    /// The cell's hitbox index.
    hitbox: u32,
    /// The cell `(cx, cz)`.
    key: [i32; 2],
}

/// One hitbox index: its cell while it holds one (24 bytes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Cell {
    key: [i32; 2],
    /// Instances in it ([`HitboxIndex::occupy`] minus [`HitboxIndex::vacate`]).
    occupants: u32,
    /// Whether the index holds a cell (false once evicted, until reused).
    live: bool,
    /// Frame of the last vacate that left it empty.
    empty_since: u64,
}

/// A sparse hashed grid of hitboxes; see the [module docs](self).
#[derive(Clone, Debug)]
pub struct HashedHitboxes {
    config: HashedConfig,
    /// `1 / cell_size`, for the first estimate only (fixed up exactly).
    inv_cell: f64,
    table: Vec<Bucket>,
    /// Live cells (filled buckets).
    live: u32,
    /// Per hitbox index, `0..len()`.
    cells: Vec<Cell>,
    /// Evicted indices, reused lowest first.
    free: BinaryHeap<Reverse<u32>>,
    /// `(frame it became empty, index)`, in frame order; entries whose cell
    /// was occupied again (or became empty later) are skipped.
    empty: VecDeque<(u64, u32)>,
    frame: u64,
    /// The tail of the bounds-change log ([`HitboxIndex::bounds_changes`]).
    changes: Vec<u32>,
    /// Changes logged ever.
    changes_total: u64,
    /// Entries of `changes` logged before the last `begin_frame` (dropped
    /// at the next).
    changes_before: usize,
}

/// SplitMix64's finaliser: a 64-bit mix of the two cell coordinates.
fn hash(key: [i32; 2]) -> u64 {
    let mut z = (u64::from(key[0] as u32) << 32 | u64::from(key[1] as u32))
        .wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl HashedHitboxes {
    /// An empty index, rejecting a non-finite origin, a cell size that is not
    /// finite and positive, `max_cells` of 0 or above 2^24, an
    /// `initial_buckets` that is not a power of two of at least 2 and
    /// `fingerprint_bits` outside 1..=32.
    pub fn new(config: HashedConfig) -> Result<Self, CoreError> {
        let invalid = |what: String| Err(CoreError::InvalidConfig { what });
        let HashedConfig {
            origin,
            cell_size,
            max_cells,
            initial_buckets,
            fingerprint_bits,
            ..
        } = config;
        if !origin.iter().all(|v| v.is_finite()) {
            return invalid(format!("hashed grid origin {origin:?} must be finite"));
        }
        if !cell_size.is_finite() || cell_size <= 0.0 {
            return invalid(format!(
                "hashed grid cell size {cell_size} must be finite and > 0"
            ));
        }
        if max_cells == 0 || u64::from(max_cells) > DEFAULT_MAX_GRID_CELLS {
            return invalid(format!(
                "hashed grid max_cells = {max_cells} must be in 1..={DEFAULT_MAX_GRID_CELLS}"
            ));
        }
        if initial_buckets < 2 || !initial_buckets.is_power_of_two() {
            return invalid(format!(
                "hashed grid initial_buckets = {initial_buckets} must be a power of two >= 2"
            ));
        }
        if !(1..=32).contains(&fingerprint_bits) {
            return invalid(format!(
                "hashed grid fingerprint_bits = {fingerprint_bits} must be in 1..=32"
            ));
        }
        let mut table = Vec::new();
        crate::memory::try_reserve_exact(
            &mut table,
            initial_buckets as usize,
            "hash table buckets",
        )?;
        table.resize(initial_buckets as usize, Bucket::default());
        Ok(Self {
            config,
            inv_cell: cell_size.recip(),
            table,
            live: 0,
            cells: Vec::new(),
            free: BinaryHeap::new(),
            empty: VecDeque::new(),
            frame: 0,
            changes: Vec::new(),
            changes_total: 0,
            changes_before: 0,
        })
    }

    /// The settings.
    pub fn config(&self) -> &HashedConfig {
        &self.config
    }

    /// Cells alive now (hitbox indices that hold a cell).
    pub fn live_cells(&self) -> u32 {
        self.live
    }

    /// Buckets of the hash table now.
    pub fn buckets(&self) -> usize {
        self.table.len()
    }

    /// GPU memory of the hitbox records: [`crate::grid::HITBOX_BYTES`] per index `0..len()`.
    pub fn memory_bytes(&self) -> u64 {
        u64::from(self.len()) * HITBOX_BYTES
    }

    /// CPU bytes held, from capacities (table, per-index cells, free list,
    /// empty queue).
    pub fn heap_bytes(&self) -> u64 {
        vec_bytes::<Bucket>(self.table.capacity())
            + vec_bytes::<Cell>(self.cells.capacity())
            + vec_bytes::<u32>(self.free.capacity())
            + vec_bytes::<(u64, u32)>(self.empty.capacity())
            + vec_bytes::<u32>(self.changes.capacity())
    }

    /// Logs that hitbox `index`'s bounds changed.
    fn log_change(&mut self, index: u32) {
        self.changes.push(index);
        self.changes_total += 1;
    }

    /// Instances in hitbox `index` (0 for an index without a cell).
    pub fn occupants(&self, index: u32) -> u32 {
        self.cells
            .get(index as usize)
            .filter(|c| c.live)
            .map_or(0, |c| c.occupants)
    }

    /// The cell `(cx, cz)` of hitbox `index`, or `None` if it holds none.
    pub fn cell(&self, index: u32) -> Option<(i32, i32)> {
        let c = self.cells.get(index as usize).filter(|c| c.live)?;
        Some((c.key[0], c.key[1]))
    }

    /// The hitbox of cell `(cx, cz)`, or `None` if the cell does not exist.
    pub fn index(&self, cx: i32, cz: i32) -> Option<u32> {
        self.find([cx, cz]).ok().map(|b| self.table[b].hitbox)
    }

    /// The cell `(cx, cz)` holding the point `(x, z)` (whether it exists or
    /// not), or `None` for non-finite input or beyond `i32` cell
    /// coordinates.
    pub fn cell_at(&self, x: f64, z: f64) -> Option<(i32, i32)> {
        Some((self.axis_cell(0, x, 0.0)?, self.axis_cell(1, z, 0.0)?))
    }

    /// The cell holding the exact centre of `aabb` in x/z (not rounded to
    /// `f32`; see [`crate::grid::HitboxGrid::cell_of_aabb_center`]), whether
    /// it exists or not; `None` as for [`HashedHitboxes::cell_at`].
    pub fn cell_of_aabb_center(&self, aabb: &Aabb) -> Option<(i32, i32)> {
        let (xh, xl) = exact_center(aabb.min.x, aabb.max.x);
        let (zh, zl) = exact_center(aabb.min.z, aabb.max.z);
        Some((self.axis_cell(0, xh, xl)?, self.axis_cell(1, zh, zl)?))
    }

    /// Exact (`f64`) bounds `([min x, min z], [max x, max z])` of hitbox
    /// `index`'s cell (half-open: `min <= p < max`), or `None`.
    pub fn bounds_f64(&self, index: u32) -> Option<([f64; 2], [f64; 2])> {
        let (cx, cz) = self.cell(index)?;
        Some((
            [self.border(0, cx.into()), self.border(1, cz.into())],
            [
                self.border(0, i64::from(cx) + 1),
                self.border(1, i64::from(cz) + 1),
            ],
        ))
    }

    /// Position of border `k` (between cells `k - 1` and `k`) on `axis`:
    /// the same expression as the grid's, so that cells match it exactly.
    fn border(&self, axis: usize, k: i64) -> f64 {
        self.config.origin[axis] + k as f64 * self.config.cell_size
    }

    /// The cell on `axis` holding the exact value `hi + lo` (an unevaluated
    /// sum, as [`exact_center`] returns).
    fn axis_cell(&self, axis: usize, hi: f64, lo: f64) -> Option<i32> {
        if !hi.is_finite() || !lo.is_finite() {
            return None;
        }
        let below = |b: f64| hi < b || (hi == b && lo < 0.0);
        let estimate = ((hi - self.config.origin[axis]) * self.inv_cell).floor();
        // Cells k in i32; the fix-up below moves at most a step or two.
        let (min, max) = (f64::from(i32::MIN), f64::from(i32::MAX));
        if !(min..=max).contains(&estimate) {
            return None;
        }
        let mut k = estimate as i64;
        while below(self.border(axis, k)) {
            k -= 1;
        }
        while !below(self.border(axis, k + 1)) {
            k += 1;
        }
        i32::try_from(k).ok()
    }

    fn mask(&self) -> usize {
        self.table.len() - 1
    }

    fn fingerprint(&self, h: u64) -> u32 {
        let bits = self.config.fingerprint_bits;
        let fp = (h >> 32) as u32;
        let fp = if bits >= 32 {
            fp
        } else {
            fp & ((1 << bits) - 1)
        };
        fp.max(1)
    }

    /// `Ok(bucket)` holding `key`, or `Err(bucket)`: the empty bucket that
    /// ends its probe sequence (where it would go).
    fn find(&self, key: [i32; 2]) -> Result<usize, usize> {
        let h = hash(key);
        let fp = self.fingerprint(h);
        let mask = self.mask();
        let mut b = h as usize & mask;
        // The table is never full (at most half), so an empty bucket ends
        // every probe sequence.
        loop {
            let bucket = &self.table[b];
            if bucket.fingerprint == 0 {
                return Err(b);
            }
            if bucket.fingerprint == fp && bucket.key == key {
                return Ok(b);
            }
            b = (b + 1) & mask;
        }
    }

    /// Doubles the table, reinserting every entry (indices unchanged).
    fn grow(&mut self) {
        let doubled = vec![Bucket::default(); self.table.len() * 2];
        let old = std::mem::replace(&mut self.table, doubled);
        for bucket in old.into_iter().filter(|b| b.fingerprint != 0) {
            if let Err(b) = self.find(bucket.key) {
                self.table[b] = bucket;
            }
        }
    }

    /// Removes the entry in bucket `b`, shifting the following entries of
    /// its probe run back so that every probe sequence stays unbroken.
    fn remove_bucket(&mut self, mut b: usize) {
        let mask = self.mask();
        let mut next = (b + 1) & mask;
        loop {
            let entry = self.table[next];
            if entry.fingerprint == 0 {
                break;
            }
            let home = hash(entry.key) as usize & mask;
            // Move `entry` into the hole at `b` unless its home lies
            // cyclically in (b, next], i.e. it would then be unreachable.
            let in_range = if b <= next {
                b < home && home <= next
            } else {
                b < home || home <= next
            };
            if !in_range {
                self.table[b] = entry;
                b = next;
            }
            next = (next + 1) & mask;
        }
        self.table[b] = Bucket::default();
    }

    /// [`HitboxIndex::occupy`] of cell `key` (found by the caller; `aabb`
    /// only names the instance in an error).
    pub(crate) fn occupy_key(&mut self, key: [i32; 2], aabb: &Aabb) -> Result<u32, CoreError> {
        let bucket = match self.find(key) {
            Ok(b) => {
                let cell = &mut self.cells[self.table[b].hitbox as usize];
                cell.occupants += 1;
                return Ok(self.table[b].hitbox);
            }
            Err(b) => b,
        };
        if self.live >= self.config.max_cells {
            return Err(CoreError::TooManyHitboxes {
                limit: self.config.max_cells,
                center: aabb.center(),
            });
        }
        let bucket = if (self.live as usize + 1) * 2 > self.table.len() {
            self.grow();
            // Absent before, so `Err`: its empty bucket in the new table.
            let (Ok(b) | Err(b)) = self.find(key);
            b
        } else {
            bucket
        };
        let index = match self.free.pop() {
            Some(Reverse(i)) => i,
            None => {
                self.cells.push(Cell::default());
                self.cells.len() as u32 - 1
            }
        };
        self.cells[index as usize] = Cell {
            key,
            occupants: 1,
            live: true,
            empty_since: 0,
        };
        self.table[bucket] = Bucket {
            fingerprint: self.fingerprint(hash(key)),
            hitbox: index,
            key,
        };
        self.live += 1;
        self.log_change(index);
        Ok(index)
    }

    /// Evicts hitbox `index` (its cell must be live and empty).
    fn evict(&mut self, index: u32) {
        let key = self.cells[index as usize].key;
        if let Ok(b) = self.find(key) {
            self.remove_bucket(b);
        }
        self.cells[index as usize] = Cell::default();
        self.live -= 1;
        self.free.push(Reverse(index));
        self.log_change(index);
    }
}

impl HitboxIndex for HashedHitboxes {
    /// Indices handed out so far (the most cells alive at once); indices
    /// of evicted cells stay in the range without a cell until reused.
    fn len(&self) -> u32 {
        self.cells.len() as u32
    }

    fn hitbox_at(&self, p: Vec3) -> Option<u32> {
        let (cx, cz) = self.cell_at(f64::from(p.x), f64::from(p.z))?;
        self.index(cx, cz)
    }

    /// The exact centre of `aabb`; see
    /// [`HashedHitboxes::cell_of_aabb_center`]. `None` if its cell does not
    /// exist.
    fn hitbox_of(&self, aabb: &Aabb) -> Option<u32> {
        let (cx, cz) = self.cell_of_aabb_center(aabb)?;
        self.index(cx, cz)
    }

    /// The cell's bounds rounded outwards to `f32`, as the grid's; `None`
    /// for an index without a cell (it then gets no counting box).
    fn xz_bounds(&self, index: u32) -> Option<(Vec2, Vec2)> {
        let (lo, hi) = self.bounds_f64(index)?;
        Some(outward_f32_bounds(lo, hi))
    }

    /// The hitbox of the cell holding `aabb`'s exact centre, created (with
    /// the lowest free index, or index `len()`) if it does not exist.
    /// Errors: [`CoreError::OutsideWorld`] for a non-finite centre or one
    /// beyond `i32` cell coordinates, [`CoreError::TooManyHitboxes`] for a
    /// new cell when [`HashedConfig::max_cells`] are alive.
    fn occupy(&mut self, aabb: &Aabb) -> Result<u32, CoreError> {
        let (cx, cz) = self
            .cell_of_aabb_center(aabb)
            .ok_or(CoreError::OutsideWorld {
                center: aabb.center(),
            })?;
        self.occupy_key([cx, cz], aabb)
    }

    /// One instance left hitbox `hitbox`; when it is the last, the cell's
    /// eviction countdown starts. An index without a cell or instances is
    /// ignored.
    fn vacate(&mut self, hitbox: u32) {
        let frame = self.frame;
        let Some(cell) = self.cells.get_mut(hitbox as usize) else {
            return;
        };
        if !cell.live || cell.occupants == 0 {
            return;
        }
        cell.occupants -= 1;
        if cell.occupants == 0 && self.config.evict_after_frames != u32::MAX {
            cell.empty_since = frame;
            self.empty.push_back((frame, hitbox));
        }
    }

    /// Evicts the cells empty since at least
    /// [`HashedConfig::evict_after_frames`] frames before `frame`.
    fn begin_frame(&mut self, frame: u64, evicted: &mut Vec<u32>) {
        self.frame = self.frame.max(frame);
        // Keep the changes since the previous frame start.
        self.changes.drain(..self.changes_before);
        self.changes_before = self.changes.len();
        let after = u64::from(self.config.evict_after_frames);
        while let Some(&(since, index)) = self.empty.front() {
            if since.saturating_add(after) > self.frame {
                break;
            }
            self.empty.pop_front();
            let c = self.cells[index as usize];
            if c.live && c.occupants == 0 && c.empty_since == since {
                self.evict(index);
                evicted.push(index);
            }
        }
    }

    /// Every index that got a cell ([`HitboxIndex::occupy`] of a new cell)
    /// or lost one (eviction), since the frame start before the last.
    fn bounds_changes(&self) -> BoundsChanges<'_> {
        BoundsChanges {
            total: self.changes_total,
            recent: &self.changes,
        }
    }
}

/// The hitbox structure a trace's world asks for: the dense
/// [`HitboxGrid`](crate::grid::HitboxGrid) for a bounded world of at most
/// [`WorldHitboxes::DENSE_MAX_CELLS`] cells, the
/// [`SparseGrid`](crate::sparse_grid::SparseGrid) of its cells for a larger
/// one (memory by the cells used, not declared), the sparse
/// [`HashedHitboxes`] for an unbounded one
/// ([`crate::trace::WorldInfo::unbounded`]). One type, so that a replay
/// holds one `Manager<WorldHitboxes>` whatever the trace.
#[derive(Clone, Debug)]
pub enum WorldHitboxes {
    /// A bounded world's grid.
    Grid(crate::grid::HitboxGrid),
    /// A large bounded world's grid, its occupied cells only.
    SparseGrid(crate::sparse_grid::SparseGrid),
    /// An unbounded world's hashed grid.
    Hashed(HashedHitboxes),
}

impl WorldHitboxes {
    /// The largest bounded world [`WorldHitboxes::for_world`] holds as a
    /// dense grid: 2^16 cells (a 256 x 256 grid, a few MB of per-cell
    /// state in a replay); a larger one is a
    /// [`SparseGrid`](crate::sparse_grid::SparseGrid).
    pub const DENSE_MAX_CELLS: u64 = 1 << 16;

    /// The structure for `world`: for a bounded world (at most
    /// `max_grid_cells` cells, see
    /// [`HitboxGrid::with_max_cells`](crate::grid::HitboxGrid::with_max_cells))
    /// its grid, dense up to [`WorldHitboxes::DENSE_MAX_CELLS`] cells,
    /// sparse above; else a hashed grid of its cells
    /// ([`crate::trace::WorldInfo::hashed_config`]).
    pub fn for_world(
        world: &crate::trace::WorldInfo,
        max_grid_cells: u64,
    ) -> Result<Self, CoreError> {
        Self::for_world_dense_up_to(world, max_grid_cells, Self::DENSE_MAX_CELLS)
    }

    /// [`WorldHitboxes::for_world`] with its own largest dense grid
    /// (`dense_max_cells`; 0: every bounded world sparse).
    pub fn for_world_dense_up_to(
        world: &crate::trace::WorldInfo,
        max_grid_cells: u64,
        dense_max_cells: u64,
    ) -> Result<Self, CoreError> {
        if world.is_bounded() {
            let grid =
                crate::grid::HitboxGrid::with_max_cells(world.grid_config(), max_grid_cells)?;
            if u64::from(grid.len()) <= dense_max_cells {
                Ok(Self::Grid(grid))
            } else {
                crate::sparse_grid::SparseGrid::new(grid).map(Self::SparseGrid)
            }
        } else {
            HashedHitboxes::new(world.hashed_config()).map(Self::Hashed)
        }
    }

    /// Hitboxes of the structure the world describes, as a GPU backend of
    /// the paper's design holds them: every cell of a bounded world's grid
    /// (also when held sparse here), the indices handed out for an
    /// unbounded one. For memory models, so that they do not depend on how
    /// the cells are held.
    pub fn modelled_hitboxes(&self) -> u64 {
        match self {
            Self::Grid(g) => u64::from(g.len()),
            Self::SparseGrid(s) => u64::from(s.grid().len()),
            Self::Hashed(h) => u64::from(h.len()),
        }
    }
}

/// Forwards to the structure held.
macro_rules! both {
    ($self:ident, $i:ident => $e:expr) => {
        match $self {
            WorldHitboxes::Grid($i) => $e,
            WorldHitboxes::SparseGrid($i) => $e,
            WorldHitboxes::Hashed($i) => $e,
        }
    };
}

impl HitboxIndex for WorldHitboxes {
    fn len(&self) -> u32 {
        both!(self, i => i.len())
    }
    fn hitbox_at(&self, p: Vec3) -> Option<u32> {
        both!(self, i => i.hitbox_at(p))
    }
    fn hitbox_of(&self, aabb: &Aabb) -> Option<u32> {
        both!(self, i => i.hitbox_of(aabb))
    }
    fn xz_bounds(&self, index: u32) -> Option<(Vec2, Vec2)> {
        both!(self, i => i.xz_bounds(index))
    }
    fn occupy(&mut self, aabb: &Aabb) -> Result<u32, CoreError> {
        both!(self, i => i.occupy(aabb))
    }
    fn vacate(&mut self, hitbox: u32) {
        both!(self, i => i.vacate(hitbox))
    }
    fn begin_frame(&mut self, frame: u64, evicted: &mut Vec<u32>) {
        both!(self, i => i.begin_frame(frame, evicted))
    }
    fn bounds_changes(&self) -> BoundsChanges<'_> {
        both!(self, i => i.bounds_changes())
    }
}

#[cfg(test)]
mod tests;
