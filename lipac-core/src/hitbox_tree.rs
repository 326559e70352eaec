//! Adaptive hitboxes: merged counting boxes for cold regions of the dense
//! grid (the paper's future work, "advanced spatial data structures").
//!
//! A quadtree over the (x, z) cells of a [`crate::grid::HitboxGrid`]: node
//! `(level, i, j)` covers the leaf cells `cx in i·2^level .. (i+1)·2^level`,
//! `cz in j·2^level .. (j+1)·2^level` (clipped to the grid). Level 0 are the
//! hitboxes themselves. Only the TLAS representation changes: the hitbox
//! records, Algorithm 2 and every decision stay per leaf.
//!
//! # The merge rule (recomputed every frame, bottom-up)
//!
//! A node is **merged** when every leaf hitbox under it is inactive (the
//! active bit Algorithm 2 left; empty cells are inactive too). Algorithm 1's
//! pass 2 then emits, for every *maximal* merged node (merged, its parent
//! not, levels `1..=levels`), one counting box instead of one per leaf:
//!
//! * no leaf with inactive instances: nothing (as for an empty hitbox);
//! * one: that leaf's own box, exactly as without adaptive hitboxes;
//! * two or more: a **merged box** spanning the union of their boxes (each
//!   as the hardware evaluates its unit-cube transform, [`box_extent`]: the
//!   merged box contains every leaf box, padding and rounding included),
//!   instance custom index = the node id ([`HitboxTree::node_id`]), SBT
//!   record offset [`AdaptiveHitboxes::merged_box_sbt_offset`].
//!
//! Leaves outside merged nodes get their box as without the option. A leaf
//! whose hits activate it splits every node above it in the next frame's
//! assembly: merge and split need no state of their own.
//!
//! # Hits on a merged box
//!
//! A tracer that meets a merged box tests the ray against the boxes its
//! leaves would have had ([`HitboxTree::leaf_boxes`]: the same transforms)
//! and takes the nearest leaf box the ray enters as the box it met (its
//! entry distance, its leaf index); a ray that enters no leaf box met no
//! box there. So a ray counts exactly the hitbox it would have counted with
//! one box per leaf: the hit counts, Algorithm 2 and the latency are those
//! of the leaf-only TLAS; only the number of TLAS records changes (and the
//! tracer's work per merged-box candidate, at most `4^levels` box tests).
//! `docs/ADAPTIVE_HITBOXES.md` has the reasoning and the figures.
//!
//! Only dense grids merge ([`HitboxIndex::dense_dims`]); the hashed index
//! stays leaf-only.

use glam::Vec3;

use crate::assembly::{
    emit_leaf_box, leaf_box_transform, unit_cube_transform, AssemblyConfig, AssemblyStats,
    COUNTING_BOX_FLAGS,
};
use crate::error::CoreError;
use crate::hitbox_index::HitboxIndex;
use crate::layout::{HitboxRecord, TlasInstance, MAX_SLOTS};

/// Most merge levels: a merged box spans up to `2^4 × 2^4` hitboxes.
pub const MAX_MERGE_LEVELS: u8 = 4;

/// The option ([`crate::culling::CullingConfig::adaptive_hitboxes`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AdaptiveHitboxes {
    /// Merge levels (0 = off: one box per inactive hitbox, the paper's
    /// rule; `k`: merged boxes span up to `2^k × 2^k` hitboxes), at most
    /// [`MAX_MERGE_LEVELS`].
    pub levels: u8,
    /// SBT record offset of merged boxes (24 bits; differs from the other
    /// counting offsets). Default 3.
    pub merged_box_sbt_offset: u32,
}

impl AdaptiveHitboxes {
    /// Off: exactly the leaf-only behaviour.
    pub const OFF: Self = Self {
        levels: 0,
        merged_box_sbt_offset: 3,
    };

    /// On with `levels` merge levels and SBT offset 3.
    pub const fn with_levels(levels: u8) -> Self {
        Self {
            levels,
            merged_box_sbt_offset: 3,
        }
    }

    /// Whether merging is on.
    pub const fn is_on(&self) -> bool {
        self.levels > 0
    }
}

impl Default for AdaptiveHitboxes {
    fn default() -> Self {
        Self::OFF
    }
}

/// A node of the tree: level `1..=levels`, coordinates `(i, j)` at that
/// level.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TreeNode {
    /// Level (1: 2 × 2 leaves).
    pub level: u8,
    /// x coordinate at the level.
    pub i: u32,
    /// z coordinate at the level.
    pub j: u32,
}

/// The quadtree over a dense grid of `nx × nz` leaf hitboxes: node
/// numbering and Algorithm 1's adaptive pass 2.
///
/// Node ids are dense per level, levels in order: level `l` has
/// `ceil(nx / 2^l) × ceil(nz / 2^l)` nodes, node `(l, i, j)` has id
/// `offset(l) + i + j · ceil(nx / 2^l)`, `offset(1) = 0`. Ids fit the
/// 24-bit custom index.
///
/// ```
/// use lipac_core::hitbox_tree::{AdaptiveHitboxes, HitboxTree, TreeNode};
/// let tree = HitboxTree::new(5, 3, AdaptiveHitboxes::with_levels(2))?;
/// // level 1: 3 x 2 nodes (ids 0..6), level 2: 2 x 1 (ids 6..8)
/// assert_eq!(tree.node_count(), 8);
/// let n = TreeNode { level: 2, i: 1, j: 0 };
/// assert_eq!(tree.node_id(n), Some(7));
/// assert_eq!(tree.node(7), Some(n));
/// assert_eq!(tree.leaf_rect(n), ([4, 0], [5, 3])); // clipped to the grid
/// # Ok::<(), lipac_core::error::CoreError>(())
/// ```
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct HitboxTree {
    nx: u32,
    nz: u32,
    config: AdaptiveHitboxes,
    /// `offsets[l - 1]` = first id of level `l`; `offsets[levels]` = count.
    offsets: Vec<u32>,
}

/// One node's summary in pass 2 (CPU).
#[derive(Clone, Copy, Debug)]
struct Summary {
    all_inactive: bool,
    nonempty: u32,
    /// A leaf with inactive instances (the only one when `nonempty == 1`).
    first: u32,
    /// Union of the leaves' boxes as the hardware evaluates them:
    /// `[t, fl(t + s)]` per axis of each leaf's unit-cube transform.
    lo: Vec3,
    hi: Vec3,
}

impl Summary {
    const EMPTY: Self = Self {
        all_inactive: true,
        nonempty: 0,
        first: u32::MAX,
        lo: Vec3::splat(f32::INFINITY),
        hi: Vec3::splat(f32::NEG_INFINITY),
    };

    fn absorb(&mut self, o: &Summary) {
        self.all_inactive &= o.all_inactive;
        if o.nonempty > 0 {
            if self.nonempty == 0 {
                self.first = o.first;
            }
            self.nonempty += o.nonempty;
            self.lo = self.lo.min(o.lo);
            self.hi = self.hi.max(o.hi);
        }
    }
}

/// Whether a hitbox holds inactive instances this frame (pass 2's test).
pub(crate) fn has_inactive(h: &HitboxRecord) -> bool {
    // Written as pass 2 does (`min_y > max_y` means empty).
    #[allow(clippy::neg_cmp_op_on_partial_ord)]
    let nonempty = !(h.min_y > h.max_y);
    nonempty
}

impl HitboxTree {
    /// The tree over a dense `nx × nz` grid with `config.levels` levels.
    /// Fails for `levels` 0 or above [`MAX_MERGE_LEVELS`], an empty grid,
    /// an SBT offset beyond 24 bits, or more node ids than 24-bit custom
    /// indices.
    pub fn new(nx: u32, nz: u32, config: AdaptiveHitboxes) -> Result<Self, CoreError> {
        let invalid = |what: String| Err(CoreError::InvalidConfig { what });
        if config.levels == 0 || config.levels > MAX_MERGE_LEVELS {
            return invalid(format!(
                "adaptive_hitboxes.levels = {} must be in 1..={MAX_MERGE_LEVELS}",
                config.levels
            ));
        }
        if config.merged_box_sbt_offset >= 1 << 24 {
            return invalid(format!(
                "adaptive_hitboxes.merged_box_sbt_offset = {} does not fit 24 bits",
                config.merged_box_sbt_offset
            ));
        }
        if nx == 0 || nz == 0 {
            return invalid(format!("adaptive hitboxes over an empty {nx} x {nz} grid"));
        }
        let mut offsets = vec![0u32];
        let mut total = 0u64;
        for l in 1..=config.levels {
            let (w, h) = level_dims(nx, nz, l);
            total += u64::from(w) * u64::from(h);
            if total > u64::from(MAX_SLOTS) {
                return invalid(format!(
                    "adaptive hitboxes over a {nx} x {nz} grid: {total} tree nodes exceed \
                     the 24-bit custom index"
                ));
            }
            offsets.push(total as u32);
        }
        Ok(Self {
            nx,
            nz,
            config,
            offsets,
        })
    }

    /// The tree for `index` with `config`, `None` when `config` is off;
    /// [`CoreError::InvalidConfig`] if `index` is not a dense grid (the
    /// hashed index is leaf-only).
    pub fn for_index(
        index: &impl HitboxIndex,
        config: AdaptiveHitboxes,
    ) -> Result<Option<Self>, CoreError> {
        if !config.is_on() {
            return Ok(None);
        }
        let Some((nx, nz)) = index.dense_dims() else {
            return Err(CoreError::InvalidConfig {
                what: "adaptive_hitboxes need a dense grid (HitboxGrid); the hashed hitbox \
                       index (HashedHitboxes) is leaf-only: set adaptive_hitboxes.levels = 0"
                    .into(),
            });
        };
        Self::new(nx, nz, config).map(Some)
    }

    /// The configuration.
    pub fn config(&self) -> AdaptiveHitboxes {
        self.config
    }

    /// Merge levels.
    pub fn levels(&self) -> u8 {
        self.config.levels
    }

    /// The leaf grid `(nx, nz)`.
    pub fn leaf_dims(&self) -> (u32, u32) {
        (self.nx, self.nz)
    }

    /// Nodes of level `level` along x and z (`(nx, nz)` at level 0).
    pub fn dims_at(&self, level: u8) -> (u32, u32) {
        level_dims(self.nx, self.nz, level)
    }

    /// First node id of each level `1..=levels`, then the node count: what
    /// a shader needs to decode ids.
    pub fn level_offsets(&self) -> &[u32] {
        &self.offsets
    }

    /// Number of node ids (all levels).
    pub fn node_count(&self) -> u32 {
        self.offsets[usize::from(self.config.levels)]
    }

    /// The id of `node`, or `None` outside the tree.
    pub fn node_id(&self, node: TreeNode) -> Option<u32> {
        if node.level == 0 || node.level > self.config.levels {
            return None;
        }
        let (w, h) = self.dims_at(node.level);
        (node.i < w && node.j < h)
            .then(|| self.offsets[usize::from(node.level) - 1] + node.i + node.j * w)
    }

    /// The node with id `id`, or `None` out of range.
    pub fn node(&self, id: u32) -> Option<TreeNode> {
        let l = self.offsets.iter().skip(1).position(|&end| id < end)?;
        let level = l as u8 + 1;
        let (w, _) = self.dims_at(level);
        let k = id - self.offsets[l];
        Some(TreeNode {
            level,
            i: k % w,
            j: k / w,
        })
    }

    /// The leaf cells `[cx0, cz0]..[cx1, cz1]` (exclusive ends, clipped to
    /// the grid) under `node`.
    pub fn leaf_rect(&self, node: TreeNode) -> ([u32; 2], [u32; 2]) {
        let s = u32::from(node.level);
        let lo = [
            node.i.saturating_mul(1 << s).min(self.nx),
            node.j.saturating_mul(1 << s).min(self.nz),
        ];
        let hi = [
            (node.i.saturating_add(1))
                .saturating_mul(1 << s)
                .min(self.nx),
            (node.j.saturating_add(1))
                .saturating_mul(1 << s)
                .min(self.nz),
        ];
        (lo, hi)
    }

    /// The leaf hitboxes under node `id` that hold inactive instances and
    /// are inactive, each with the unit-cube transform of the box it would
    /// have had without merging (Algorithm 1's, bit for bit), appended to
    /// `out` in row-major order: what a tracer tests a ray against when it
    /// meets merged box `id`. Nothing for an unknown id.
    pub fn leaf_boxes(
        &self,
        id: u32,
        hitboxes: &[HitboxRecord],
        index: &impl HitboxIndex,
        cfg: &AssemblyConfig,
        out: &mut Vec<(u32, [f32; 12])>,
    ) {
        let Some(node) = self.node(id) else {
            return;
        };
        let (lo, hi) = self.leaf_rect(node);
        for cz in lo[1]..hi[1] {
            for cx in lo[0]..hi[0] {
                let leaf = cx + cz * self.nx;
                let Some(h) = hitboxes.get(leaf as usize) else {
                    continue;
                };
                if h.is_active() || !has_inactive(h) {
                    continue;
                }
                if let Some(t) = leaf_box_transform(leaf, h, index, cfg) {
                    out.push((leaf, t));
                }
            }
        }
    }

    /// Algorithm 1's pass 2 with merging (see the [module docs](self)):
    /// appends the counting boxes of the inactive hitboxes to `out`.
    /// `hitboxes` must be the `nx · nz` records of the tree's grid.
    pub(crate) fn emit_boxes(
        &self,
        hitboxes: &[HitboxRecord],
        index: &impl HitboxIndex,
        cfg: &AssemblyConfig,
        out: &mut Vec<TlasInstance>,
        stats: &mut AssemblyStats,
    ) {
        // Leaf summaries, then each level from the one below.
        let leaf = |k: u32| -> Summary {
            let h = &hitboxes[k as usize];
            let mut s = Summary {
                all_inactive: !h.is_active(),
                ..Summary::EMPTY
            };
            if !h.is_active() && has_inactive(h) {
                if let Some(t) = leaf_box_transform(k, h, index, cfg) {
                    (s.lo, s.hi) = box_extent(&t);
                    s.nonempty = 1;
                    s.first = k;
                }
            }
            s
        };
        let levels = self.config.levels;
        let mut all: Vec<Vec<Summary>> = Vec::with_capacity(usize::from(levels));
        for l in 1..=levels {
            let (w, h) = self.dims_at(l);
            let (cw, ch) = self.dims_at(l - 1);
            let mut cur = vec![Summary::EMPTY; w as usize * h as usize];
            for j in 0..h {
                for i in 0..w {
                    let s = &mut cur[(i + j * w) as usize];
                    for cj in 2 * j..(2 * j + 2).min(ch) {
                        for ci in 2 * i..(2 * i + 2).min(cw) {
                            let c = match all.last() {
                                None => leaf(ci + cj * cw),
                                Some(below) => below[(ci + cj * cw) as usize],
                            };
                            s.absorb(&c);
                        }
                    }
                }
            }
            all.push(cur);
        }

        // Top-down: maximal merged nodes, leaf boxes elsewhere.
        let (tw, th) = self.dims_at(levels);
        let mut stack: Vec<(u8, u32, u32)> = Vec::new();
        for j in (0..th).rev() {
            for i in (0..tw).rev() {
                stack.push((levels, i, j));
            }
        }
        while let Some((l, i, j)) = stack.pop() {
            if l == 0 {
                let k = i + j * self.nx;
                emit_leaf_box(k, &hitboxes[k as usize], index, cfg, out, stats);
                continue;
            }
            let (w, _) = self.dims_at(l);
            let s = all[usize::from(l) - 1][(i + j * w) as usize];
            if s.all_inactive {
                let id = self.offsets[usize::from(l) - 1] + i + j * w;
                self.emit_merged(id, &s, hitboxes, index, cfg, out, stats);
                continue;
            }
            let (cw, ch) = self.dims_at(l - 1);
            for cj in (2 * j..(2 * j + 2).min(ch)).rev() {
                for ci in (2 * i..(2 * i + 2).min(cw)).rev() {
                    stack.push((l - 1, ci, cj));
                }
            }
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn emit_merged(
        &self,
        id: u32,
        s: &Summary,
        hitboxes: &[HitboxRecord],
        index: &impl HitboxIndex,
        cfg: &AssemblyConfig,
        out: &mut Vec<TlasInstance>,
        stats: &mut AssemblyStats,
    ) {
        match s.nonempty {
            0 => {}
            1 => emit_leaf_box(s.first, &hitboxes[s.first as usize], index, cfg, out, stats),
            n => {
                let Some(transform) = unit_cube_transform(s.lo, s.hi, cfg.min_box_extent) else {
                    stats.invalid_hitboxes += n;
                    return;
                };
                out.push(TlasInstance::new(
                    transform,
                    id,
                    cfg.counting_mask,
                    self.config.merged_box_sbt_offset,
                    COUNTING_BOX_FLAGS,
                    cfg.unit_cube_blas,
                ));
                stats.merged_boxes += 1;
                stats.merged_hitboxes += n;
            }
        }
    }
}

/// The box a unit-cube transform maps `[0,1]^3` onto, as the hardware
/// evaluates its far corner (`1 · s + t`, one rounding): `(t, fl(t + s))`.
pub fn box_extent(t: &[f32; 12]) -> (Vec3, Vec3) {
    let lo = Vec3::new(t[3], t[7], t[11]);
    (lo, lo + Vec3::new(t[0], t[5], t[10]))
}

/// Nodes of level `level` over an `nx × nz` grid: `ceil(n / 2^level)`.
fn level_dims(nx: u32, nz: u32, level: u8) -> (u32, u32) {
    let up = |n: u32| -> u32 { ((u64::from(n) + (1u64 << level) - 1) >> level) as u32 };
    (up(nx), up(nz))
}

#[cfg(test)]
mod tests;
