//! [`MergedBoxes`]: what a tracer needs, per frame, to resolve adaptive
//! hitboxes' merged counting boxes (`lipac_core::hitbox_tree`) to their leaf
//! hitboxes' boxes: the values of `lipac_counting.glsl`'s `LIPAC_GRID_NX`,
//! `LIPAC_GRID_NZ`, `LIPAC_ADAPTIVE_LEVELS`, `LIPAC_SBT_MERGED_BOX` and
//! `LIPAC_MIN_BOX_EXTENT`. Push it as five 32-bit words in this order
//! (`bytemuck::bytes_of`); [`crate::LipacVk::merged_boxes`] gives the frame's.

use bytemuck::{Pod, Zeroable};
use lipac_core::assembly::AssemblyConfig;
use lipac_core::hitbox_tree::HitboxTree;

/// The merged-box parameters of a frame: the values of
/// `lipac_counting.glsl`'s `LIPAC_GRID_NX`, `LIPAC_GRID_NZ`,
/// `LIPAC_ADAPTIVE_LEVELS`, `LIPAC_SBT_MERGED_BOX` and
/// `LIPAC_MIN_BOX_EXTENT`, pushable as is (five 32-bit words in this order).
/// [`MergedBoxes::OFF`] (all zero, `levels == 0`): the TLAS has no merged
/// boxes and the include takes its leaf-only path.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct MergedBoxes {
    /// The dense grid's cells along x (`LIPAC_GRID_NX`).
    pub grid_nx: u32,
    /// The dense grid's cells along z (`LIPAC_GRID_NZ`).
    pub grid_nz: u32,
    /// Merge levels, 0 = off (`LIPAC_ADAPTIVE_LEVELS`).
    pub levels: u32,
    /// SBT record offset of merged boxes (`LIPAC_SBT_MERGED_BOX`).
    pub merged_sbt_offset: u32,
    /// [`AssemblyConfig::min_box_extent`], sanitised as Algorithm 1 uses it
    /// (finite and positive, else 0; `LIPAC_MIN_BOX_EXTENT`).
    pub min_box_extent: f32,
}

impl MergedBoxes {
    /// No merged boxes (adaptive hitboxes off).
    pub const OFF: Self = Self {
        grid_nx: 0,
        grid_nz: 0,
        levels: 0,
        merged_sbt_offset: 0,
        min_box_extent: 0.0,
    };

    /// The parameters of a TLAS assembled with `tree` (`None`: off) and
    /// `assembly`.
    pub fn new(tree: Option<&HitboxTree>, assembly: &AssemblyConfig) -> Self {
        let Some(tree) = tree.filter(|t| t.levels() > 0) else {
            return Self::OFF;
        };
        let (grid_nx, grid_nz) = tree.leaf_dims();
        Self {
            grid_nx,
            grid_nz,
            levels: u32::from(tree.levels()),
            merged_sbt_offset: tree.config().merged_box_sbt_offset,
            min_box_extent: if assembly.min_box_extent.is_finite() && assembly.min_box_extent > 0.0
            {
                assembly.min_box_extent
            } else {
                0.0
            },
        }
    }

    /// Whether the TLAS may hold merged boxes (`levels > 0`).
    pub fn is_on(&self) -> bool {
        self.levels > 0
    }

    /// Hitbox records (and bounds) the tracer reads: `grid_nx · grid_nz`
    /// when on, else 0.
    pub fn hitboxes_read(&self) -> u64 {
        if self.is_on() {
            u64::from(self.grid_nx) * u64::from(self.grid_nz)
        } else {
            0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lipac_core::hitbox_tree::AdaptiveHitboxes;

    #[test]
    fn parameters_of_a_tree_and_off() {
        let mut cfg = AssemblyConfig::new(0x1000);
        cfg.min_box_extent = f32::NAN;
        assert_eq!(MergedBoxes::new(None, &cfg), MergedBoxes::OFF);
        let tree = HitboxTree::new(5, 3, AdaptiveHitboxes::with_levels(2)).unwrap();
        let m = MergedBoxes::new(Some(&tree), &cfg);
        assert_eq!(
            (m.grid_nx, m.grid_nz, m.levels, m.min_box_extent),
            (5, 3, 2, 0.0)
        );
        assert_eq!(m.merged_sbt_offset, tree.config().merged_box_sbt_offset);
        assert!(m.is_on() && m.hitboxes_read() == 15);
        cfg.min_box_extent = 0.25;
        assert_eq!(MergedBoxes::new(Some(&tree), &cfg).min_box_extent, 0.25);
        assert_eq!(std::mem::size_of::<MergedBoxes>(), 20);
        assert!(!MergedBoxes::OFF.is_on() && MergedBoxes::OFF.hitboxes_read() == 0);
    }
}
