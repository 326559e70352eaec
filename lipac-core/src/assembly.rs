//! Algorithm 1 (thesis Algorithm 4): build the TLAS instance buffer, CPU
//! reference.
//!
//! Runs once per frame before the TLAS build, over exactly the buffers a GPU
//! backend holds: the instance arrays ([`InstanceArrays`]: hot, TLAS
//! records and bounds, one of each per slot), the hitbox records and
//! the output array of [`TlasInstance`]s. Every slot's hot part is read; an
//! active slot's TLAS record (64 bytes, one cache line, copied as it is)
//! and an omitted slot's bounds only where they are emitted. The GPU
//! version appends with an atomic counter, so its output order is
//! arbitrary; compare with [`sort_canonical`] applied to both sides.
//!
//! The hitbox records' **extents** — the counting box's height range and the
//! cost word — are an input: the CPU keeps them where instances change
//! ([`crate::hitbox_extents`]; [`crate::culling::Culling`] does, a caller
//! with its own arrays runs [`crate::hitbox_extents::write_extents`] after
//! changing records). Algorithm 1 no longer reduces them over the slots.
//!
//! The passes, in short: [`begin_frame`] resets every hitbox's hit count
//! (active bit, streak, rate and extent kept); then every live *active*
//! instance with a BLAS gets its own TLAS record (custom index = slot; active
//! without a BLAS yet is left out and counted), every *omitted* one a
//! unit-cube counting box onto its AABB, and an *inactive* one nothing;
//! finally every **inactive** hitbox with a non-empty extent gets a
//! counting box over its cell and the extent's heights (custom index =
//! hitbox index). An active or omitted instance in an inactive hitbox
//! counts as inactive ([`AssemblyStats::in_inactive_hitbox`]). A *pinned*
//! instance ([`crate::layout::instance_bits::PINNED`]) counts as active
//! whatever its state bits and its hitbox: its own record once its BLAS
//! exists, never a counting box, never in a hitbox's extent. The backend
//! clears the per-instance hit buffer before tracing.
//!
//! Counting boxes contain their target box in f32 at any distance from the
//! origin ([`unit_cube_transform`]; bounds in `docs/PRECISION.md`). Every pass
//! line by line, the deviations from the pseudocode and why:
//! `docs/ALGORITHMS.md`.

use std::fmt;

use glam::Vec3;

use crate::hitbox_index::HitboxIndex;
use crate::hitbox_tree::HitboxTree;
use crate::layout::{
    hitbox_bits, instance_bits, HitboxRecord, InstanceArrays, InstanceBounds, InstanceHot,
    InstanceState, InstanceTlas, TlasInstance, MAX_SLOTS, VK_INSTANCE_CULL_DISABLE,
    VK_INSTANCE_FORCE_OPAQUE,
};

/// Instance flags of every counting box.
pub const COUNTING_BOX_FLAGS: u8 = VK_INSTANCE_FORCE_OPAQUE | VK_INSTANCE_CULL_DISABLE;

/// Backend-specific constants of Algorithm 1.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AssemblyConfig {
    /// Device address of the static unit-cube BLAS (`[0,1]^3`).
    pub unit_cube_blas: u64,
    /// TLAS visibility mask of counting boxes (hitboxes and omitted
    /// instances); a ray masks these out after its first counting hit.
    pub counting_mask: u8,
    /// SBT record offset of the hit group that counts hits into the
    /// per-instance hit buffer (omitted instances' boxes; custom index = slot).
    pub omitted_box_sbt_offset: u32,
    /// SBT record offset of the hit group that counts hits into the hitbox
    /// records (custom index = hitbox index).
    pub hitbox_sbt_offset: u32,
    /// Smallest extent of a counting box along any axis, in world units;
    /// flat targets are padded symmetrically to this. Non-finite or
    /// non-positive values are treated as 0 (boxes are then still at least
    /// one f32 step thick).
    pub min_box_extent: f32,
}

impl AssemblyConfig {
    /// A config with the given unit-cube BLAS, `counting_mask = 0x80`, SBT
    /// offsets 1 (omitted boxes) and 2 (hitboxes), and a 1 mm minimum box
    /// extent. Backends set the fields to their pipeline's values.
    pub fn new(unit_cube_blas: u64) -> Self {
        Self {
            unit_cube_blas,
            counting_mask: 0x80,
            omitted_box_sbt_offset: 1,
            hitbox_sbt_offset: 2,
            min_box_extent: 1e-3,
        }
    }
}

/// Counts of what one run of [`assemble_tlas`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AssemblyStats {
    /// Active instances emitted with their BLAS.
    pub active: u32,
    /// Active instances left out because their BLAS does not exist yet.
    pub active_without_blas: u32,
    /// Omitted instances emitted as counting boxes.
    pub omitted_boxes: u32,
    /// Live instances that count as inactive (inactive ones and those
    /// counted in [`AssemblyStats::in_inactive_hitbox`]): their hitbox's
    /// counting box stands for them.
    pub inactive: u32,
    /// Active or omitted instances whose hitbox is inactive, treated as
    /// inactive (not emitted: the hitbox's counting box stands for them).
    pub in_inactive_hitbox: u32,
    /// Counting boxes emitted for inactive hitboxes.
    pub hitbox_boxes: u32,
    /// Of those, boxes padded because all instances were flat.
    pub flat_hitbox_boxes: u32,
    /// Live instances skipped for bad data: hitbox index out of range
    /// (inactive) or non-finite AABB (omitted). The GPU skips them too.
    pub invalid_instances: u32,
    /// Hitboxes skipped because the index has no bounds for them.
    pub invalid_hitboxes: u32,
    /// Adaptive hitboxes: merged counting boxes emitted (each standing for
    /// two or more hitboxes with inactive instances; not in
    /// [`AssemblyStats::hitbox_boxes`]).
    pub merged_boxes: u32,
    /// Adaptive hitboxes: hitboxes with inactive instances represented by
    /// those merged boxes.
    pub merged_hitboxes: u32,
}

/// Inputs of [`assemble_tlas`] that do not fit together.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum AssemblyError {
    /// The hitbox index and the hitbox records disagree on the hitbox count.
    HitboxCountMismatch {
        /// `index.len()`.
        index: u32,
        /// `hitboxes.len()`.
        records: usize,
    },
    /// More instance records than 24-bit custom indices.
    TooManySlots(usize),
    /// The adaptive hitbox tree was built for another grid than the index
    /// (or the index is not a dense grid: `index` is `None`).
    TreeMismatch {
        /// The tree's leaf grid `(nx, nz)`.
        tree: (u32, u32),
        /// [`HitboxIndex::dense_dims`] of the index.
        index: Option<(u32, u32)>,
    },
}

impl fmt::Display for AssemblyError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::HitboxCountMismatch { index, records } => write!(
                f,
                "hitbox index has {index} hitboxes but {records} hitbox records were given"
            ),
            Self::TooManySlots(n) => {
                write!(
                    f,
                    "{n} instance slots exceed the 24-bit custom index limit {MAX_SLOTS}"
                )
            }
            Self::TreeMismatch { tree, index } => write!(
                f,
                "adaptive hitbox tree over a {} x {} grid, but the hitbox index is {}",
                tree.0,
                tree.1,
                match index {
                    Some((nx, nz)) => format!("a {nx} x {nz} grid"),
                    None => "not a dense grid (adaptive hitboxes need HitboxGrid)".into(),
                }
            ),
        }
    }
}

impl std::error::Error for AssemblyError {}

/// Pass 0: resets every hitbox's hit count to 0, keeping the active bit,
/// streak, rate and extent (heights and cost word: the CPU's,
/// [`crate::hitbox_extents`]). [`assemble_tlas`] calls it first.
pub fn begin_frame(hitboxes: &mut [HitboxRecord]) {
    const KEEP: u32 = (1 << hitbox_bits::HITS_SHIFT) - 1;
    for h in hitboxes {
        h.packed &= KEEP;
    }
}

/// Next representable f32 above a finite `x` (`f32::next_up` needs Rust 1.86;
/// MSRV is 1.85).
fn next_up(x: f32) -> f32 {
    if x == 0.0 {
        f32::from_bits(1)
    } else if x > 0.0 {
        f32::from_bits(x.to_bits() + 1)
    } else {
        f32::from_bits(x.to_bits() - 1)
    }
}

/// Per-axis translation and scale mapping `[0,1]` onto a range containing
/// `[lo, hi]` in f32: `t = lo` and the smallest `s` found with
/// `fl(t + s) >= hi`, padded symmetrically to `min_extent` and at least one
/// f32 step wide. Returns `None` for non-finite input.
fn axis_map(mut lo: f32, mut hi: f32, min_extent: f32) -> Option<(f32, f32)> {
    if !lo.is_finite() || !hi.is_finite() {
        return None;
    }
    if hi < lo {
        std::mem::swap(&mut lo, &mut hi);
    }
    let min_extent = if min_extent.is_finite() && min_extent > 0.0 {
        min_extent
    } else {
        0.0
    };
    if hi - lo < min_extent {
        let pad = (min_extent - (hi - lo)) * 0.5;
        lo -= pad;
        hi += pad;
    }
    // Far from the origin the padding may vanish in rounding: at least one step.
    hi = hi.max(next_up(lo));
    if !lo.is_finite() || !hi.is_finite() {
        return None;
    }
    let mut s = hi - lo;
    // Round the scale up until the far corner, as the hardware computes it
    // (1·s + t, one rounding), reaches hi. `hi - lo` is exact or off by half
    // an ulp of the result, so this takes at most a couple of steps; the bound
    // only guards against surprises.
    for _ in 0..32 {
        if !s.is_finite() {
            return None;
        }
        if lo + s >= hi {
            return Some((lo, s));
        }
        s = next_up(s);
    }
    None
}

/// Row-major 3x4 transform mapping the unit cube `[0,1]^3` onto a box that
/// contains `[min, max]` when evaluated in f32 (see the [module docs](self)),
/// each axis at least `min_extent` wide. `None` if a corner is not finite.
///
/// ```
/// use glam::Vec3;
/// use lipac_core::assembly::unit_cube_transform;
/// let m = unit_cube_transform(Vec3::new(1.0, 2.0, 3.0), Vec3::new(2.0, 6.0, 3.0), 0.5).unwrap();
/// assert_eq!([m[0], m[5], m[10]], [1.0, 4.0, 0.5]); // scales (z padded to 0.5)
/// assert_eq!([m[3], m[7], m[11]], [1.0, 2.0, 2.75]); // translations
/// ```
#[inline]
pub fn unit_cube_transform(min: Vec3, max: Vec3, min_extent: f32) -> Option<[f32; 12]> {
    // Common case, decided without a loop: on every axis `d = hi - lo` is
    // finite, positive and at least the (sanitised) minimum extent, and
    // `lo + d` reaches `hi`. Then `axis_map` neither swaps nor pads, the
    // one-step floor `next_up(lo) <= hi` holds, and its first iteration
    // returns `(lo, d)`: the same bits. `d` finite and positive also means
    // both corners are finite and `lo < hi`. Anything else takes `axis_map`.
    let floor = if (TINY..f32::INFINITY).contains(&min_extent) {
        min_extent
    } else {
        TINY // d >= TINY is d > 0
    };
    let d = max - min;
    let plain = |lo: f32, hi: f32, d: f32| d >= floor && d < f32::INFINITY && lo + d >= hi;
    if plain(min.x, max.x, d.x) & plain(min.y, max.y, d.y) & plain(min.z, max.z, d.z) {
        return Some([
            d.x, 0.0, 0.0, min.x, //
            0.0, d.y, 0.0, min.y, //
            0.0, 0.0, d.z, min.z,
        ]);
    }
    unit_cube_transform_general(min, max, min_extent)
}

/// Smallest positive f32 (a subnormal).
const TINY: f32 = f32::from_bits(1);

/// [`unit_cube_transform`] by `axis_map` on every axis, as the GLSL's
/// `lipacAppendCountingBox` computes it; the fast path returns the same.
#[cold]
#[inline(never)]
pub(crate) fn unit_cube_transform_general(
    min: Vec3,
    max: Vec3,
    min_extent: f32,
) -> Option<[f32; 12]> {
    let (tx, sx) = axis_map(min.x, max.x, min_extent)?;
    let (ty, sy) = axis_map(min.y, max.y, min_extent)?;
    let (tz, sz) = axis_map(min.z, max.z, min_extent)?;
    Some([
        sx, 0.0, 0.0, tx, //
        0.0, sy, 0.0, ty, //
        0.0, 0.0, sz, tz,
    ])
}

/// Algorithm 1: fills `out` (cleared first) with this frame's TLAS instance
/// records, in slot order then hitbox index order, and resets the hitboxes'
/// hit counts. The hitboxes' extents must be current
/// ([`crate::hitbox_extents::write_extents`]). See the [module docs](self)
/// for the passes and deviations.
///
/// ```
/// use glam::{Vec2, Vec3};
/// use lipac_core::assembly::{assemble_tlas, AssemblyConfig};
/// use lipac_core::hitbox_extents::write_extents;
/// use lipac_core::hitbox_index::HitboxIndex;
/// use lipac_core::layout::{instance_bits, HitboxRecord, InstanceArrays, InstanceRecord, InstanceState};
///
/// struct OneCell;
/// impl HitboxIndex for OneCell {
///     fn len(&self) -> u32 { 1 }
///     fn hitbox_at(&self, _: Vec3) -> Option<u32> { Some(0) }
///     fn xz_bounds(&self, i: u32) -> Option<(Vec2, Vec2)> {
///         (i == 0).then_some((Vec2::ZERO, Vec2::splat(16.0)))
///     }
/// }
/// let mut inst = InstanceRecord {
///     aabb_min: [1.0, 0.0, 1.0], aabb_max: [2.0, 5.0, 2.0],
///     packed: instance_bits::ALIVE, ..Default::default()
/// };
/// inst.set_state(InstanceState::Inactive);
/// let mut hitboxes = [HitboxRecord::default()];
/// let mut out = Vec::new();
/// let instances = InstanceArrays::from_records(&[inst]);
/// write_extents(&instances, &mut hitboxes); // the box's heights: 0 to 5
/// let stats = assemble_tlas(&instances, &mut hitboxes, &OneCell, &AssemblyConfig::new(7), &mut out).unwrap();
/// assert_eq!((stats.inactive, stats.hitbox_boxes, out.len()), (1, 1, 1));
/// assert_eq!((hitboxes[0].min_y, hitboxes[0].max_y), (0.0, 5.0));
/// assert_eq!(out[0].acceleration_structure_reference, 7);
/// ```
pub fn assemble_tlas(
    instances: &InstanceArrays,
    hitboxes: &mut [HitboxRecord],
    index: &impl HitboxIndex,
    cfg: &AssemblyConfig,
    out: &mut Vec<TlasInstance>,
) -> Result<AssemblyStats, AssemblyError> {
    assemble_tlas_adaptive(instances, hitboxes, index, cfg, None, out)
}

/// [`assemble_tlas`] with adaptive hitboxes: with `tree`, pass 2 emits one
/// counting box per maximal merged quadtree node of inactive hitboxes
/// instead of one per hitbox ([`crate::hitbox_tree`]); with `None` it is
/// [`assemble_tlas`] exactly.
pub fn assemble_tlas_adaptive(
    instances: &InstanceArrays,
    hitboxes: &mut [HitboxRecord],
    index: &impl HitboxIndex,
    cfg: &AssemblyConfig,
    tree: Option<&HitboxTree>,
    out: &mut Vec<TlasInstance>,
) -> Result<AssemblyStats, AssemblyError> {
    if let Some(tree) = tree {
        if index.dense_dims() != Some(tree.leaf_dims()) {
            return Err(AssemblyError::TreeMismatch {
                tree: tree.leaf_dims(),
                index: index.dense_dims(),
            });
        }
    }
    if index.len() as usize != hitboxes.len() {
        return Err(AssemblyError::HitboxCountMismatch {
            index: index.len(),
            records: hitboxes.len(),
        });
    }
    if instances.len() > MAX_SLOTS as usize {
        return Err(AssemblyError::TooManySlots(instances.len()));
    }
    out.clear();
    begin_frame(hitboxes);
    let mut stats = AssemblyStats::default();

    // Pass 1: one GPU thread per slot, over the hot array. An instance that
    // counts as inactive does nothing: its hitbox's extent (the counting
    // box's heights, the cost word) is the CPU's, kept where instances
    // change (crate::hitbox_extents), not reduced here.
    //
    // In two sweeps over the slots. First, per chunk of slots, the
    // classification of every slot, noting the slots that emit a record;
    // the noted slots of all chunks are collected. Then those slots'
    // records, appended to `out` in slot order (reserved once). The same
    // records in the same order, the same bits as one loop. Two whole
    // sweeps rather than the records after each chunk: at 1M slots, where
    // the arrays do not fit in the cache, the first sweep then streams only
    // the hot records, the second only the emitted slots' TLAS records or
    // bounds and `out`
    // (`docs/HOT_COLD.md`, "Algorithm 1 in two sweeps").
    let hot = instances.hot();
    let n = hot.len();
    let (tlas, bounds) = (&instances.tlas()[..n], &instances.bounds()[..n]);
    let mut counts = Pass1Counts::default();
    let mut emit = [0u32; PASS1_CHUNK];
    let mut emitted: Vec<u32> = Vec::new();
    for start in (0..n).step_by(PASS1_CHUNK) {
        let end = n.min(start + PASS1_CHUNK);
        let emitting = classify_chunk(&hot[start..end], hitboxes, &mut emit, &mut counts);
        // n <= MAX_SLOTS: slot numbers fit in u32.
        let base = start as u32;
        emitted.extend(emit[..emitting].iter().map(|&offset| base + offset));
    }
    build_records(hot, tlas, bounds, &emitted, cfg, out, &mut counts);
    let Pass1Counts {
        active,
        without_blas,
        omitted,
        inactive,
        in_inactive_hitbox,
        invalid,
    } = counts;
    stats.active = active;
    stats.active_without_blas = without_blas;
    stats.omitted_boxes = omitted;
    stats.inactive = inactive;
    stats.in_inactive_hitbox = in_inactive_hitbox;
    stats.invalid_instances = invalid;

    // Pass 2: one GPU thread per hitbox (adaptive: see `crate::hitbox_tree`),
    // on the extents the CPU keeps.
    match tree {
        Some(tree) => tree.emit_boxes(hitboxes, index, cfg, out, &mut stats),
        None => {
            for (i, h) in hitboxes.iter().enumerate() {
                emit_leaf_box(i as u32, h, index, cfg, out, &mut stats);
            }
        }
    }
    Ok(stats)
}

/// Slots per chunk of pass 1 (the emitting slots' offsets of one chunk are
/// kept on the stack).
const PASS1_CHUNK: usize = 256;

/// Pass 1's counters, summed over the chunks.
#[derive(Default)]
struct Pass1Counts {
    active: u32,
    without_blas: u32,
    omitted: u32,
    inactive: u32,
    in_inactive_hitbox: u32,
    invalid: u32,
}

/// Pass 1, first sweep, for one chunk of at most [`PASS1_CHUNK`] slots:
/// counts every live instance that counts as inactive and notes the offsets
/// (within the chunk) of the others, the slots that emit a record (or are
/// left out: active without a BLAS, non-finite omitted AABB), in `emit`;
/// returns how many. Dead slots are skipped.
#[inline(never)]
fn classify_chunk(
    hot: &[InstanceHot],
    hitboxes: &[HitboxRecord],
    emit: &mut [u32; PASS1_CHUNK],
    counts: &mut Pass1Counts,
) -> usize {
    let nh = hitboxes.len();
    let (mut inactive, mut folded, mut invalid) = (0u32, 0u32, 0u32);
    let mut emitting = 0;
    for (j, m) in (0u32..).zip(&hot[..hot.len().min(PASS1_CHUNK)]) {
        let p = m.packed;
        let hb = m.hitbox as usize;
        let key = p & (instance_bits::ALIVE | instance_bits::PINNED | instance_bits::STATE_MASK);
        if key == instance_bits::ALIVE || key == instance_bits::ALIVE | 3 {
            // Live, not pinned, state bits 0 or 3 (Inactive, see
            // InstanceState::from_bits).
            if hb < nh {
                inactive += 1;
            } else {
                invalid += 1;
            }
        } else if p & instance_bits::ALIVE != 0 {
            // Active or omitted (or pinned). An active or omitted instance
            // whose hitbox is inactive counts as inactive (module docs, "in
            // an inactive hitbox"); a pinned one is active whatever its state
            // bits and hitbox say.
            if p & instance_bits::PINNED == 0 && hb < nh && !hitboxes[hb].is_active() {
                inactive += 1;
                folded += 1;
            } else {
                // emitting < len <= PASS1_CHUNK: the mask only spares a check.
                emit[emitting & (PASS1_CHUNK - 1)] = j;
                emitting += 1;
            }
        }
    }
    counts.inactive += inactive;
    counts.in_inactive_hitbox += folded;
    counts.invalid += invalid;
    emitting
}

/// Pass 1, second sweep: the records of the slots noted by [`reduce_chunk`]
/// (`slots`, ascending), in slot order, appended to `out`. Active: its own
/// record once its BLAS exists; omitted: a counting box over its AABB unless
/// that is not finite.
#[inline(never)]
fn build_records(
    hot: &[InstanceHot],
    tlas: &[InstanceTlas],
    bounds: &[InstanceBounds],
    slots: &[u32],
    cfg: &AssemblyConfig,
    out: &mut Vec<TlasInstance>,
    counts: &mut Pass1Counts,
) {
    let (mut active, mut without_blas, mut omitted, mut invalid) = (0u32, 0u32, 0u32, 0u32);
    out.reserve(slots.len());
    for &slot in slots {
        let s = slot as usize;
        let m = hot[s];
        let p = m.packed;
        let record = if p & instance_bits::PINNED != 0
            || p & instance_bits::STATE_MASK == InstanceState::Active as u32
        {
            if p & instance_bits::HAS_BLAS == 0 {
                without_blas += 1;
                continue;
            }
            active += 1;
            tlas[s].record
        } else {
            let c = &bounds[s];
            let Some(transform) = unit_cube_transform(
                Vec3::from_array(c.aabb_min),
                Vec3::from_array(c.aabb_max),
                cfg.min_box_extent,
            ) else {
                invalid += 1;
                continue;
            };
            omitted += 1;
            TlasInstance::new(
                transform,
                slot,
                cfg.counting_mask,
                cfg.omitted_box_sbt_offset,
                COUNTING_BOX_FLAGS,
                cfg.unit_cube_blas,
            )
        };
        out.push(record);
    }
    counts.active += active;
    counts.without_blas += without_blas;
    counts.omitted += omitted;
    counts.invalid += invalid;
}

/// Pass 2 for one hitbox: a counting box for hitbox `i` if it is inactive
/// (not active: see the module docs) and holds at least one inactive
/// instance.
pub(crate) fn emit_leaf_box(
    i: u32,
    h: &HitboxRecord,
    index: &impl HitboxIndex,
    cfg: &AssemblyConfig,
    out: &mut Vec<TlasInstance>,
    stats: &mut AssemblyStats,
) {
    if h.is_active() || h.min_y > h.max_y {
        return;
    }
    let Some(transform) = leaf_box_transform(i, h, index, cfg) else {
        stats.invalid_hitboxes += 1;
        return;
    };
    out.push(TlasInstance::new(
        transform,
        i,
        cfg.counting_mask,
        cfg.hitbox_sbt_offset,
        COUNTING_BOX_FLAGS,
        cfg.unit_cube_blas,
    ));
    stats.hitbox_boxes += 1;
    if h.min_y == h.max_y {
        stats.flat_hitbox_boxes += 1;
    }
}

/// The unit-cube transform of hitbox `i`'s counting box: its x/z bounds and
/// this frame's height range (`None` without bounds or for non-finite ones).
pub(crate) fn leaf_box_transform(
    i: u32,
    h: &HitboxRecord,
    index: &impl HitboxIndex,
    cfg: &AssemblyConfig,
) -> Option<[f32; 12]> {
    let (lo, hi) = index.xz_bounds(i)?;
    let min = Vec3::new(lo.x, h.min_y, lo.y);
    let max = Vec3::new(hi.x, h.max_y, hi.y);
    unit_cube_transform(min, max, cfg.min_box_extent)
}

/// Sorts TLAS records into a canonical order (by reference, custom index and
/// mask, SBT offset and flags, then transform bits) so that the CPU
/// reference's output and a GPU's atomically appended output can be compared
/// as multisets with `==`.
pub fn sort_canonical(records: &mut [TlasInstance]) {
    records.sort_unstable_by_key(|r| {
        (
            r.acceleration_structure_reference,
            r.custom_index_and_mask,
            r.sbt_offset_and_flags,
            r.transform.map(f32::to_bits),
        )
    });
}

#[cfg(test)]
mod tests;
