//! The spatial structure that maps world positions to hitboxes.
//!
//! Algorithms 1 and 2 only need three things from it, so the regular grid of
//! the paper ([`crate::grid::HitboxGrid`]) can be replaced by another structure
//! (a sparse hashed grid for unbounded worlds, say) behind this trait.

use crate::math::Aabb;
use glam::{Vec2, Vec3};

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
    /// `None` for an index out of range.
    fn xz_bounds(&self, index: u32) -> Option<(Vec2, Vec2)>;
}
