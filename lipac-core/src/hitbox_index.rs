//! The spatial structure that maps world positions to hitboxes.
//!
//! Algorithms 1 and 2 only need three things from it, so the regular grid of
//! the paper ([`crate::grid::HitboxGrid`]) can be replaced by another structure
//! (the sparse hashed grid [`crate::hashed_hitboxes::HashedHitboxes`] for
//! unbounded worlds) behind this trait.
//!
//! A structure whose hitboxes are fixed (the grid) implements the three
//! queries only. One that creates hitboxes as cells get occupied and drops
//! them when they stay empty (the hashed grid) also implements the
//! registration hooks [`HitboxIndex::occupy`], [`HitboxIndex::vacate`] and
//! [`HitboxIndex::begin_frame`], which the registry calls for every
//! registration, move or removal and at every frame start; their defaults do
//! nothing beyond [`HitboxIndex::hitbox_of`]. Such a structure also reports
//! which indices got new bounds ([`HitboxIndex::bounds_changes`]), so that a
//! GPU backend that keeps a copy of the bounds rewrites only those; the
//! default reports none.

use crate::error::CoreError;
use crate::math::Aabb;
use glam::{Vec2, Vec3};

/// The newest changes of a [`HitboxIndex`]'s bounds
/// ([`HitboxIndex::bounds_changes`]): a log of the indices whose
/// [`HitboxIndex::xz_bounds`] changed (a cell created, evicted or given to a
/// reused index), of which the index keeps only the tail.
///
/// A consumer remembers the `total` it last saw (`seen`); the indices
/// changed since are the last `total - seen` entries of `recent`, or, when
/// `total - seen > recent.len()`, more than the log kept (re-read every
/// bound then). Indices may repeat; read their bounds now, not at the time
/// of the change.
///
/// ```
/// use lipac_core::hitbox_index::BoundsChanges;
///
/// let log = BoundsChanges { total: 7, recent: &[4, 2, 9] };
/// assert_eq!(log.since(5), Some(&[2, 9][..])); // seen 5 of 7: the last 2
/// assert_eq!(log.since(7), Some(&[][..])); // up to date
/// assert_eq!(log.since(3), None); // 4 changes, only 3 kept: re-read all
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BoundsChanges<'a> {
    /// Changes logged since the structure was created.
    pub total: u64,
    /// The last changes, oldest first: at least those logged since the
    /// [`HitboxIndex::begin_frame`] before the last one, i.e. everything a
    /// consumer that reads the log once per frame has not seen yet.
    pub recent: &'a [u32],
}

impl<'a> BoundsChanges<'a> {
    /// The indices changed after the first `seen` changes, or `None` when
    /// the log no longer holds all of them (or `seen` is ahead of `total`,
    /// i.e. it came from another structure): re-read every bound.
    pub fn since(&self, seen: u64) -> Option<&'a [u32]> {
        let new = self.total.checked_sub(seen)?;
        let new = usize::try_from(new)
            .ok()
            .filter(|&n| n <= self.recent.len())?;
        Some(&self.recent[self.recent.len() - new..])
    }
}

/// Maps positions to dense hitbox indices `0..len()` and back to their
/// horizontal (x, z) bounds. Heights come from the instances (Algorithm 1).
pub trait HitboxIndex {
    /// Number of hitboxes; indices are `0..len()`.
    fn len(&self) -> u32;
    /// Whether there are no hitboxes.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// The hitbox holding `p` (an instance's AABB centre), or `None` outside
    /// the indexed region.
    fn hitbox_at(&self, p: Vec3) -> Option<u32>;
    /// The hitbox an instance with world bounds `aabb` belongs to: the one
    /// holding the AABB's centre, or `None` outside the indexed region.
    ///
    /// The default evaluates [`HitboxIndex::hitbox_at`] at
    /// [`Aabb::center`], i.e. at the centre rounded to `f32` (within half an
    /// `f32` step of the exact centre, so the cell found holds the exact
    /// centre or touches the border it lies next to). Structures with
    /// borders that are not `f32` values should override it with an exact
    /// test, as [`crate::grid::HitboxGrid`] does; otherwise a centre just
    /// inside the far border of the region may round outside it.
    fn hitbox_of(&self, aabb: &Aabb) -> Option<u32> {
        self.hitbox_at(aabb.center())
    }
    /// Horizontal bounds `(min (x, z), max (x, z))` of hitbox `index`, or
    /// `None` for an index out of range (or one that holds no cell now).
    fn xz_bounds(&self, index: u32) -> Option<(Vec2, Vec2)>;

    /// `Some((nx, nz))` if the structure is a dense grid whose index `i` is
    /// cell `(i % nx, i / nx)` ([`crate::grid::HitboxGrid`]): what adaptive
    /// hitboxes ([`crate::hitbox_tree`]) merge over. The default is `None`
    /// (adaptive hitboxes are then refused).
    fn dense_dims(&self) -> Option<(u32, u32)> {
        None
    }

    /// Registration hook: an instance with world bounds `aabb` is added to
    /// (or moved into) the structure; returns its hitbox, creating it if the
    /// structure creates hitboxes on demand ([`HitboxIndex::len`] may grow).
    /// Every successful call is matched by one [`HitboxIndex::vacate`] of
    /// the returned hitbox when the instance leaves it.
    ///
    /// The default is [`HitboxIndex::hitbox_of`], with
    /// [`CoreError::OutsideWorld`] for `None`. On error nothing changes.
    fn occupy(&mut self, aabb: &Aabb) -> Result<u32, CoreError> {
        self.hitbox_of(aabb).ok_or(CoreError::OutsideWorld {
            center: aabb.center(),
        })
    }

    /// Registration hook: an instance that [`HitboxIndex::occupy`] placed in
    /// `hitbox` left it (removed, or moved to another hitbox). The default
    /// does nothing.
    fn vacate(&mut self, hitbox: u32) {
        let _ = hitbox;
    }

    /// Frame hook, at the registry's frame start: a structure may drop
    /// hitboxes that stayed empty (their indices can then be handed out
    /// again by [`HitboxIndex::occupy`]); it appends the dropped indices to
    /// `evicted`, whose hitbox records the caller resets. The default drops
    /// nothing.
    fn begin_frame(&mut self, frame: u64, evicted: &mut Vec<u32>) {
        let _ = (frame, evicted);
    }

    /// The log of indices whose [`HitboxIndex::xz_bounds`] changed, for
    /// backends that keep a copy of the bounds (lipac-vk): see
    /// [`BoundsChanges`]. Growth of [`HitboxIndex::len`] counts as a change
    /// of the new indices. The default, for structures whose hitboxes are
    /// fixed (the grid), is no change ever.
    fn bounds_changes(&self) -> BoundsChanges<'_> {
        BoundsChanges::default()
    }
}
