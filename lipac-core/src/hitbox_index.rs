//! The spatial structure that maps world positions to hitboxes.
//!
//! Algorithms 1 and 2 only need three things from it, so the regular grid of
//! the paper ([`crate::grid::HitboxGrid`]) can be replaced by another structure
//! (a sparse hashed grid for unbounded worlds, say) behind this trait.

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
    /// Horizontal bounds `(min (x, z), max (x, z))` of hitbox `index`, or
    /// `None` for an index out of range.
    fn xz_bounds(&self, index: u32) -> Option<(Vec2, Vec2)>;
}
