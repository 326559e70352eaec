//! Algorithm 1 (thesis Algorithm 4): build the TLAS instance buffer, CPU
//! reference.
//!
//! Runs once per frame before the TLAS build, over exactly the buffers a GPU
//! backend holds: the instance records (one per slot), the hitbox records and
//! the output array of [`TlasInstance`]s. The GPU version appends with an
//! atomic counter, so its output order is arbitrary; compare with
//! [`sort_canonical`] applied to both sides.
//!
//! The passes, in short: [`begin_frame`] resets every hitbox's height bounds
//! and hit count (active bit and streak kept); then every live *active*
//! instance with a BLAS gets its own TLAS record (custom index = slot; active
//! without a BLAS yet is left out and counted), every *omitted* one a
//! unit-cube counting box onto its AABB, and every *inactive* one widens its
//! hitbox's height range; finally every **inactive** hitbox with an inactive
//! instance gets a counting box (custom index = hitbox index). An active or
//! omitted instance in an inactive hitbox counts as inactive
//! ([`AssemblyStats::in_inactive_hitbox`]). A *pinned* instance
//! ([`crate::layout::instance_bits::PINNED`]) counts as active whatever its
//! state bits and its hitbox: its own record once its BLAS exists, never a
//! counting box, never in a hitbox's height range. The backend clears the
//! per-instance hit buffer before tracing.
//!
//! Counting boxes contain their target box in f32 at any distance from the
//! origin ([`unit_cube_transform`]; bounds in `docs/PRECISION.md`). Every pass
//! line by line, the deviations from the pseudocode and why:
//! `docs/ALGORITHMS.md`.

use std::fmt;

use glam::Vec3;

use crate::hitbox_index::HitboxIndex;
use crate::layout::{
    hitbox_bits, HitboxRecord, InstanceRecord, InstanceState, TlasInstance, MAX_SLOTS,
    VK_INSTANCE_CULL_DISABLE, VK_INSTANCE_FORCE_OPAQUE,
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
    /// Instances reduced into their hitbox's height range (inactive ones and
    /// those counted in [`AssemblyStats::in_inactive_hitbox`]).
    pub inactive: u32,
    /// Active or omitted instances whose hitbox is inactive, treated as
    /// inactive (not emitted, reduced into the hitbox's counting box).
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
        }
    }
}

impl std::error::Error for AssemblyError {}

/// Pass 0: resets every hitbox's height range to `(+∞, −∞)`, its hit count
/// and its cost word to 0, keeping the active bit, streak and rate.
/// [`assemble_tlas`] calls it first.
pub fn begin_frame(hitboxes: &mut [HitboxRecord]) {
    const KEEP: u32 = (1 << crate::layout::hitbox_bits::HITS_SHIFT) - 1;
    for h in hitboxes {
        h.min_y = f32::INFINITY;
        h.max_y = f32::NEG_INFINITY;
        h.packed &= KEEP;
        h.cost = 0;
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
pub fn unit_cube_transform(min: Vec3, max: Vec3, min_extent: f32) -> Option<[f32; 12]> {
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
/// records, in slot order then hitbox index order, and rebuilds the hitboxes'
/// height ranges. See the [module docs](self) for the passes and deviations.
///
/// ```
/// use glam::{Vec2, Vec3};
/// use lipac_core::assembly::{assemble_tlas, AssemblyConfig};
/// use lipac_core::hitbox_index::HitboxIndex;
/// use lipac_core::layout::{instance_bits, HitboxRecord, InstanceRecord, InstanceState};
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
/// let stats = assemble_tlas(&[inst], &mut hitboxes, &OneCell, &AssemblyConfig::new(7), &mut out).unwrap();
/// assert_eq!((stats.inactive, stats.hitbox_boxes, out.len()), (1, 1, 1));
/// assert_eq!((hitboxes[0].min_y, hitboxes[0].max_y), (0.0, 5.0));
/// assert_eq!(out[0].acceleration_structure_reference, 7);
/// ```
pub fn assemble_tlas(
    instances: &[InstanceRecord],
    hitboxes: &mut [HitboxRecord],
    index: &impl HitboxIndex,
    cfg: &AssemblyConfig,
    out: &mut Vec<TlasInstance>,
) -> Result<AssemblyStats, AssemblyError> {
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

    // Pass 1: one GPU thread per slot.
    for (slot, m) in instances.iter().enumerate() {
        if !m.is_alive() {
            continue;
        }
        let slot = slot as u32;
        // A pinned instance is active whatever its state bits and hitbox say.
        let pinned = m.is_pinned();
        let mut state = if pinned {
            InstanceState::Active
        } else {
            m.state()
        };
        // An active or omitted instance whose hitbox is inactive counts as
        // inactive here (see the module docs, "in an inactive hitbox").
        if !pinned
            && state != InstanceState::Inactive
            && hitboxes
                .get(m.hitbox as usize)
                .is_some_and(|h| !h.is_active())
        {
            stats.in_inactive_hitbox += 1;
            state = InstanceState::Inactive;
        }
        match state {
            InstanceState::Active => {
                if m.blas == 0 {
                    stats.active_without_blas += 1;
                    continue;
                }
                out.push(TlasInstance::new(
                    m.transform,
                    slot,
                    m.mask(),
                    m.sbt_offset,
                    m.vk_flags(),
                    m.blas,
                ));
                stats.active += 1;
            }
            InstanceState::Omitted => {
                let Some(transform) = unit_cube_transform(
                    Vec3::from_array(m.aabb_min),
                    Vec3::from_array(m.aabb_max),
                    cfg.min_box_extent,
                ) else {
                    stats.invalid_instances += 1;
                    continue;
                };
                out.push(TlasInstance::new(
                    transform,
                    slot,
                    cfg.counting_mask,
                    cfg.omitted_box_sbt_offset,
                    COUNTING_BOX_FLAGS,
                    cfg.unit_cube_blas,
                ));
                stats.omitted_boxes += 1;
            }
            InstanceState::Inactive => {
                let Some(h) = hitboxes.get_mut(m.hitbox as usize) else {
                    stats.invalid_instances += 1;
                    continue;
                };
                // atomicMin / atomicMax on the GPU (f32 as ordered ints).
                h.min_y = h.min_y.min(m.aabb_min[1]);
                h.max_y = h.max_y.max(m.aabb_max[1]);
                // atomicAdd on the GPU: what activating the hitbox brings in.
                h.cost = h.cost.wrapping_add(if m.needs_unique_blas() {
                    hitbox_bits::COST_UNIQUE
                } else {
                    hitbox_bits::COST_SHARED
                });
                stats.inactive += 1;
            }
        }
    }

    // Pass 2: one GPU thread per hitbox.
    for (i, h) in hitboxes.iter().enumerate() {
        // Inactive (not active: see the module docs) and holding at least one
        // inactive instance.
        if h.is_active() || h.min_y > h.max_y {
            continue;
        }
        let i = i as u32;
        let Some((lo, hi)) = index.xz_bounds(i) else {
            stats.invalid_hitboxes += 1;
            continue;
        };
        let min = Vec3::new(lo.x, h.min_y, lo.y);
        let max = Vec3::new(hi.x, h.max_y, hi.y);
        let Some(transform) = unit_cube_transform(min, max, cfg.min_box_extent) else {
            stats.invalid_hitboxes += 1;
            continue;
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
    Ok(stats)
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
mod tests {
    use super::*;
    use crate::layout::{hitbox_bits, instance_bits};
    use glam::Vec2;

    /// A row of `n` cells of `size` along x, spanning z in [0, size).
    pub(crate) struct Row {
        pub n: u32,
        pub size: f32,
        pub origin: f32,
    }

    impl HitboxIndex for Row {
        fn len(&self) -> u32 {
            self.n
        }
        fn hitbox_at(&self, p: Vec3) -> Option<u32> {
            let i = ((p.x - self.origin) / self.size).floor();
            (i >= 0.0 && i < self.n as f32).then_some(i as u32)
        }
        fn xz_bounds(&self, i: u32) -> Option<(Vec2, Vec2)> {
            (i < self.n).then(|| {
                let x0 = self.origin + i as f32 * self.size;
                (Vec2::new(x0, 0.0), Vec2::new(x0 + self.size, self.size))
            })
        }
    }

    const CUBE: u64 = 0xC0BE;

    fn cfg() -> AssemblyConfig {
        AssemblyConfig {
            unit_cube_blas: CUBE,
            counting_mask: 0x40,
            omitted_box_sbt_offset: 5,
            hitbox_sbt_offset: 6,
            min_box_extent: 0.01,
        }
    }

    fn inst(state: InstanceState, hitbox: u32, min: [f32; 3], max: [f32; 3]) -> InstanceRecord {
        let mut r = InstanceRecord {
            transform: [
                1.0, 0.0, 0.0, min[0], 0.0, 1.0, 0.0, min[1], 0.0, 0.0, 1.0, min[2],
            ],
            aabb_min: min,
            aabb_max: max,
            hitbox,
            packed: instance_bits::ALIVE
                | (0x0F << instance_bits::MASK_SHIFT)
                | (u32::from(crate::layout::VK_INSTANCE_FLIP_FACING)
                    << instance_bits::VK_FLAGS_SHIFT),
            blas: 0,
            sbt_offset: 3,
            lod: 0,
        };
        r.set_state(state);
        r
    }

    fn active_hitbox() -> HitboxRecord {
        HitboxRecord {
            packed: hitbox_bits::ACTIVE,
            ..Default::default()
        }
    }

    /// Transforms the unit cube's corners as the hardware would (f32, row-major).
    fn cube_bounds(m: &[f32; 12]) -> (Vec3, Vec3) {
        let lo = Vec3::new(m[3], m[7], m[11]);
        let hi = Vec3::new(m[0] + m[3], m[5] + m[7], m[10] + m[11]);
        (lo, hi)
    }

    fn run(
        instances: &[InstanceRecord],
        hitboxes: &mut [HitboxRecord],
    ) -> (AssemblyStats, Vec<TlasInstance>) {
        let index = Row {
            n: hitboxes.len() as u32,
            size: 16.0,
            origin: 0.0,
        };
        let mut out = vec![TlasInstance::default(); 3]; // stale content must be cleared
        let stats = assemble_tlas(instances, hitboxes, &index, &cfg(), &mut out).unwrap();
        (stats, out)
    }

    #[test]
    fn active_with_blas_is_emitted_with_its_own_fields() {
        let mut m = inst(InstanceState::Active, 0, [1.0, 0.0, 1.0], [2.0, 1.0, 2.0]);
        m.blas = 0xABCD;
        let mut hb = [active_hitbox()];
        let (stats, out) = run(&[InstanceRecord::default(), m], &mut hb);
        assert_eq!(stats.active, 1);
        assert_eq!(
            out,
            vec![TlasInstance::new(
                m.transform,
                1,
                0x0F,
                3,
                crate::layout::VK_INSTANCE_FLIP_FACING,
                0xABCD
            )]
        );
    }

    #[test]
    fn active_without_blas_is_left_out_and_counted() {
        let m = inst(InstanceState::Active, 0, [1.0, 0.0, 1.0], [2.0, 1.0, 2.0]);
        let mut hb = [active_hitbox()];
        let (stats, out) = run(&[m], &mut hb);
        assert_eq!((stats.active, stats.active_without_blas), (0, 1));
        assert!(out.is_empty());
        // It does not feed the hitbox's height range either.
        assert!(hb[0].min_y > hb[0].max_y);
    }

    #[test]
    fn omitted_becomes_counting_box_over_its_aabb() {
        let m = inst(InstanceState::Omitted, 0, [1.0, -2.0, 3.0], [4.0, 5.0, 3.5]);
        let mut hb = [active_hitbox()];
        let (stats, out) = run(&[m, m], &mut hb);
        assert_eq!(stats.omitted_boxes, 2);
        assert_eq!(out.len(), 2);
        let r = out[1];
        assert_eq!(r.custom_index(), 1);
        assert_eq!(r.mask(), 0x40);
        assert_eq!(r.sbt_offset(), 5);
        assert_eq!(
            r.flags(),
            VK_INSTANCE_FORCE_OPAQUE | VK_INSTANCE_CULL_DISABLE
        );
        assert_eq!(r.acceleration_structure_reference, CUBE);
        let (lo, hi) = cube_bounds(&r.transform);
        assert_eq!(lo, Vec3::new(1.0, -2.0, 3.0));
        assert_eq!(hi, Vec3::new(4.0, 5.0, 3.5)); // exactly representable: no growth
    }

    #[test]
    fn inactive_instances_reduce_their_hitbox_height() {
        let a = inst(
            InstanceState::Inactive,
            1,
            [17.0, 2.0, 1.0],
            [18.0, 3.0, 2.0],
        );
        let b = inst(
            InstanceState::Inactive,
            1,
            [20.0, -1.0, 1.0],
            [21.0, 2.5, 2.0],
        );
        let c = inst(InstanceState::Inactive, 0, [1.0, 7.0, 1.0], [2.0, 9.0, 2.0]);
        // Stale heights from last frame must not survive.
        let mut hb = [HitboxRecord {
            min_y: -100.0,
            max_y: 100.0,
            packed: 0,
            rate: 0,
            cost: 0x0303_0303,
        }; 3];
        hb[2].packed = hitbox_bits::ACTIVE;
        let (stats, out) = run(&[a, b, c], &mut hb);
        assert_eq!(stats.inactive, 3);
        // The cost words are rebuilt: one shared-BLAS inactive instance in
        // hitbox 0, two in 1, none in 2.
        assert_eq!(hb.map(|h| h.cost), [1, 2, 0]);
        assert_eq!((hb[1].inactive_shared(), hb[1].inactive_unique()), (2, 0));
        assert_eq!((hb[0].min_y, hb[0].max_y), (7.0, 9.0));
        assert_eq!((hb[1].min_y, hb[1].max_y), (-1.0, 3.0));
        assert!(hb[2].min_y > hb[2].max_y);
        assert!(out
            .iter()
            .all(|r| r.acceleration_structure_reference == CUBE));
    }

    #[test]
    fn inactive_hitbox_gets_box_over_cell_and_height() {
        let a = inst(
            InstanceState::Inactive,
            1,
            [17.0, 2.0, 1.0],
            [18.0, 3.0, 2.0],
        );
        let b = inst(
            InstanceState::Inactive,
            1,
            [20.0, -1.0, 1.0],
            [21.0, 2.5, 2.0],
        );
        let mut hb = [HitboxRecord::default(); 2];
        let (stats, out) = run(&[a, b], &mut hb);
        assert_eq!((stats.hitbox_boxes, stats.flat_hitbox_boxes), (1, 0));
        assert_eq!(out.len(), 1, "hitbox 0 has no inactive instance: no box");
        let r = out[0];
        assert_eq!((r.custom_index(), r.mask(), r.sbt_offset()), (1, 0x40, 6));
        assert_eq!(r.flags(), COUNTING_BOX_FLAGS);
        let (lo, hi) = cube_bounds(&r.transform);
        assert_eq!(lo, Vec3::new(16.0, -1.0, 0.0));
        assert_eq!(hi, Vec3::new(32.0, 3.0, 16.0));
    }

    #[test]
    fn active_hitbox_gets_no_box() {
        let a = inst(InstanceState::Inactive, 0, [1.0, 2.0, 1.0], [2.0, 3.0, 2.0]);
        let mut hb = [active_hitbox()];
        let (stats, out) = run(&[a], &mut hb);
        assert_eq!(stats.inactive, 1);
        assert_eq!(stats.hitbox_boxes, 0);
        assert!(out.is_empty());
        // The reduction still ran (the GPU does not look at the hitbox state there).
        assert_eq!((hb[0].min_y, hb[0].max_y), (2.0, 3.0));
    }

    #[test]
    fn active_and_omitted_in_inactive_hitbox_fold_into_its_box() {
        let mut a = inst(InstanceState::Active, 0, [1.0, 1.0, 1.0], [2.0, 6.0, 2.0]);
        a.blas = 0xABCD;
        let o = inst(InstanceState::Omitted, 0, [3.0, -2.0, 1.0], [4.0, 0.0, 2.0]);
        let mut b = inst(InstanceState::Active, 1, [17.0, 0.0, 1.0], [18.0, 1.0, 2.0]);
        b.blas = 0xBEEF;
        let mut hb = [HitboxRecord::default(), active_hitbox()];
        let (stats, out) = run(&[a, o, b], &mut hb);
        assert_eq!((stats.in_inactive_hitbox, stats.inactive), (2, 2));
        assert_eq!(
            (stats.active, stats.omitted_boxes, stats.hitbox_boxes),
            (1, 0, 1)
        );
        // Only b's own record and hitbox 0's box, which spans both folded instances.
        assert_eq!(out.len(), 2);
        assert_eq!(out[0].acceleration_structure_reference, 0xBEEF);
        assert_eq!((out[1].custom_index(), out[1].sbt_offset()), (0, 6));
        assert_eq!((hb[0].min_y, hb[0].max_y), (-2.0, 6.0));
    }

    #[test]
    fn pinned_is_traced_whatever_its_state_and_hitbox() {
        let pinned = |state| {
            let mut m = inst(state, 0, [1.0, 0.0, 1.0], [2.0, 9.0, 2.0]);
            m.packed |= instance_bits::PINNED;
            m.blas = 0xABCD;
            m
        };
        let mut no_blas = pinned(InstanceState::Inactive);
        no_blas.blas = 0;
        let other = inst(InstanceState::Inactive, 0, [3.0, 1.0, 1.0], [4.0, 2.0, 2.0]);
        let mut hb = [HitboxRecord::default()]; // inactive
        let instances = [
            pinned(InstanceState::Active),
            pinned(InstanceState::Omitted),
            pinned(InstanceState::Inactive),
            no_blas,
            other,
        ];
        let (stats, out) = run(&instances, &mut hb);
        assert_eq!((stats.active, stats.active_without_blas), (3, 1));
        assert_eq!((stats.omitted_boxes, stats.in_inactive_hitbox), (0, 0));
        assert_eq!((stats.inactive, stats.hitbox_boxes), (1, 1));
        // Own records for slots 0..3, then the hitbox's box over `other` only.
        let own: Vec<u32> = out[..3].iter().map(TlasInstance::custom_index).collect();
        assert_eq!(own, vec![0, 1, 2]);
        assert!(out[..3]
            .iter()
            .all(|r| r.acceleration_structure_reference == 0xABCD));
        assert_eq!(out[3].acceleration_structure_reference, CUBE);
        assert_eq!((hb[0].min_y, hb[0].max_y), (1.0, 2.0));
    }

    #[test]
    fn flat_hitbox_still_gets_a_padded_box() {
        let a = inst(InstanceState::Inactive, 0, [1.0, 4.0, 1.0], [2.0, 4.0, 2.0]);
        let mut hb = [HitboxRecord::default()];
        let (stats, out) = run(&[a], &mut hb);
        assert_eq!((stats.hitbox_boxes, stats.flat_hitbox_boxes), (1, 1));
        let (lo, hi) = cube_bounds(&out[0].transform);
        assert!(lo.y < 4.0 && hi.y > 4.0);
        assert!((hi.y - lo.y - cfg().min_box_extent).abs() < 1e-5);
    }

    #[test]
    fn dead_slots_are_skipped() {
        let mut dead = inst(InstanceState::Active, 0, [1.0, 0.0, 1.0], [2.0, 1.0, 2.0]);
        dead.blas = 99;
        dead.packed &= !instance_bits::ALIVE;
        let mut dead_inactive = inst(InstanceState::Inactive, 0, [1.0, 0.0, 1.0], [2.0, 1.0, 2.0]);
        dead_inactive.packed &= !instance_bits::ALIVE;
        let mut hb = [HitboxRecord::default()];
        let (stats, out) = run(&[dead, dead_inactive], &mut hb);
        assert_eq!(stats, AssemblyStats::default());
        assert!(out.is_empty());
        assert!(hb[0].min_y > hb[0].max_y);
    }

    #[test]
    fn frame_reset_clears_hits_keeps_state() {
        let mut hb = [HitboxRecord {
            min_y: 1.0,
            max_y: 2.0,
            packed: hitbox_bits::ACTIVE | (5 << 1),
            rate: 0xDEAD,
            cost: 77,
        }];
        hb[0].add_hits(1234);
        begin_frame(&mut hb);
        assert_eq!(hb[0].hits(), 0);
        assert_eq!(
            (hb[0].rate, hb[0].cost),
            (0xDEAD, 0),
            "rate kept, cost reset"
        );
        assert!(hb[0].is_active());
        assert_eq!(hb[0].streak(), 5);
        assert_eq!(
            (hb[0].min_y, hb[0].max_y),
            (f32::INFINITY, f32::NEG_INFINITY)
        );
    }

    #[test]
    fn bad_inputs_are_errors_or_counted() {
        let mut hb = [HitboxRecord::default()];
        let index = Row {
            n: 2,
            size: 16.0,
            origin: 0.0,
        };
        let mut out = Vec::new();
        assert!(matches!(
            assemble_tlas(&[], &mut hb, &index, &cfg(), &mut out),
            Err(AssemblyError::HitboxCountMismatch {
                index: 2,
                records: 1
            })
        ));
        let bad_hitbox = inst(InstanceState::Inactive, 7, [1.0, 0.0, 1.0], [2.0, 1.0, 2.0]);
        let nan_box = inst(
            InstanceState::Omitted,
            0,
            [f32::NAN, 0.0, 1.0],
            [2.0, 1.0, 2.0],
        );
        hb[0] = active_hitbox(); // the omitted NaN box is judged, not folded into an inactive hitbox
        let (stats, out) = run(&[bad_hitbox, nan_box], &mut hb);
        assert_eq!(stats.invalid_instances, 2);
        assert!(out.is_empty());
    }

    /// Exhaustive-ish containment check of the conservative transform, near
    /// and far (±100 km) from the origin, with awkward non-representable sizes.
    #[test]
    fn unit_cube_transform_contains_target_far_from_origin() {
        let mut rng = 0x1234_5678_9ABC_DEF0u64;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 11) as f64 / (1u64 << 53) as f64
        };
        for &centre in &[0.0f64, 1.0, -3.3, 1.0e5, -1.0e5, 99_999.99, -65_536.0] {
            for _ in 0..2000 {
                let c = Vec3::new(
                    (centre + next() * 10.0) as f32,
                    (centre * 0.5 + next()) as f32,
                    (-centre + next() * 10.0) as f32,
                );
                let size = Vec3::new(
                    (next() * 20.0) as f32,
                    (next() * 0.1) as f32,
                    (next() * 1e-3) as f32,
                );
                let min = c;
                let max = c + size; // rounded in f32: still min <= max
                let m = unit_cube_transform(min, max, 1e-3).unwrap();
                let (lo, hi) = cube_bounds(&m);
                assert!(
                    lo.cmple(min).all() && hi.cmpge(max).all(),
                    "{min} {max} -> {lo} {hi}"
                );
                // Never degenerate, and not grossly larger than needed.
                assert!(hi.cmpgt(lo).all());
                let slack = (max - min).max(Vec3::splat(1e-3)) * 1.001 + Vec3::splat(0.02);
                assert!((hi - lo).cmple(slack).all(), "{min} {max} -> {lo} {hi}");
                // Also with FMA-style evaluation (exact 1·s + t, one rounding).
                assert_eq!(1.0f32.mul_add(m[0], m[3]), hi.x);
            }
        }
    }

    #[test]
    fn tiny_extent_far_away_is_at_least_one_step_thick() {
        let y = 100_000.0f32; // f32 step here is 1/128
        let m = unit_cube_transform(Vec3::splat(y), Vec3::splat(y), 1e-4).unwrap();
        let (lo, hi) = cube_bounds(&m);
        assert!(lo.cmple(Vec3::splat(y)).all() && hi.cmpge(Vec3::splat(y)).all());
        assert!(hi.cmpgt(lo).all());
    }

    #[test]
    fn canonical_sort_makes_order_irrelevant() {
        let a = inst(InstanceState::Omitted, 0, [1.0, 0.0, 1.0], [2.0, 1.0, 2.0]);
        let b = inst(
            InstanceState::Inactive,
            1,
            [17.0, 0.0, 1.0],
            [18.0, 1.0, 2.0],
        );
        let mut hb = [active_hitbox(), HitboxRecord::default()];
        let (_, mut out) = run(&[a, b, a], &mut hb);
        let mut shuffled = out.clone();
        shuffled.reverse();
        shuffled.swap(0, 1);
        assert_ne!(shuffled, out);
        sort_canonical(&mut out);
        sort_canonical(&mut shuffled);
        assert_eq!(shuffled, out);
    }
}
