//! The top-level acceleration structure: a CWBVH over the world bounds of a
//! slice of [`TlasInstance`] records, rebuilt from scratch every frame like
//! the paper's GPU-assembled TLAS.
//!
//! Each record names its BLAS by `acceleration_structure_reference`
//! ([`crate::blas::BvhBlasId::reference`]; 0 = inactive, skipped). Records
//! whose SBT offset is one of [`CountingBoxes`]'s counting offsets
//! become *counting boxes* (the BLAS's bounds, normally the unit cube, under
//! the record's transform); all others are real geometry. Records with mask 0
//! can never be hit and are dropped.
//!
//! Adaptive hitboxes' *merged boxes* ([`lipac_core::hitbox_tree`]; SBT
//! offset [`CountingBoxes::merged_box_sbt`], custom index = tree node id)
//! need [`CpuTlas::rebuild_with`] and a [`MergedBoxes`] resolver: the TLAS
//! keeps each merged box's leaf boxes, and a ray that enters a merged box
//! meets the nearest leaf box it enters there (or none), exactly as with
//! one box per leaf.

use glam::{Affine3A, Vec3A};
use lipac_core::layout::{TlasInstance, VK_INSTANCE_FORCE_NO_OPAQUE, VK_INSTANCE_FORCE_OPAQUE};
use lipac_core::math::rows_to_affine;
use obvhs::aabb::Aabb as BvhAabb;
use obvhs::cwbvh::CwBvh;

use crate::blas::{build_cwbvh, BlasStore, BuildQuality, BvhBlasKind};
use crate::error::SimError;

/// Visibility mask bits used by the laboratory.
pub mod masks {
    /// Opaque scene geometry.
    pub const GEOMETRY: u8 = 0x01;
    /// Alpha-tested vegetation.
    pub const VEGETATION: u8 = 0x02;
    /// Counting boxes (omitted-instance boxes and inactive hitboxes).
    pub const COUNTING: u8 = 0x80;
    /// Everything.
    pub const ALL: u8 = 0xFF;
}

/// Which SBT offsets mark counting boxes, and their mask bit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CountingBoxes {
    /// SBT offset of boxes standing for *omitted* instances: a hit counts
    /// into the instance counter at the record's custom index.
    pub instance_box_sbt: u32,
    /// SBT offset of *inactive hitbox* boxes: a hit counts into the hitbox
    /// counter at the record's custom index.
    pub hitbox_box_sbt: u32,
    /// Mask bit that counting boxes carry (rays clear it to ignore boxes).
    pub counting_mask: u8,
    /// SBT offset of adaptive hitboxes' *merged* boxes: a hit counts into
    /// the hitbox counter of the leaf box it enters
    /// ([`lipac_core::hitbox_tree`]).
    pub merged_box_sbt: u32,
}

impl CountingBoxes {
    /// Whether `sbt` marks a counting box of any kind.
    pub fn is_box(&self, sbt: u32) -> bool {
        sbt == self.instance_box_sbt || sbt == self.hitbox_box_sbt || sbt == self.merged_box_sbt
    }
}

/// Resolves a merged box (custom index = tree node id) to the leaf hitbox
/// boxes it stands for: [`lipac_core::hitbox_tree::HitboxTree::leaf_boxes`]
/// over the frame's hitbox records.
pub trait MergedBoxes {
    /// Appends `(leaf hitbox, unit-cube transform)` of node `node`'s leaf
    /// boxes to `out`.
    fn leaf_boxes(&self, node: u32, out: &mut Vec<(u32, [f32; 12])>);
}

impl Default for CountingBoxes {
    fn default() -> Self {
        Self {
            instance_box_sbt: 1,
            hitbox_box_sbt: 2,
            counting_mask: masks::COUNTING,
            merged_box_sbt: 3,
        }
    }
}

/// What a TLAS entry is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum EntryKind {
    Geometry,
    InstanceBox,
    HitboxBox,
    /// A merged box: its leaves are `leaves` in [`CpuTlas::merged_leaves`].
    MergedBox,
}

/// One usable record, in BVH primitive order.
#[derive(Clone, Copy, Debug)]
pub(crate) struct TlasEntry {
    pub(crate) world_to_object: Affine3A,
    pub(crate) blas: u32,
    pub(crate) custom_index: u32,
    pub(crate) record: u32,
    pub(crate) mask: u8,
    pub(crate) kind: EntryKind,
    /// 0: alpha test as the BLAS says; 1: force opaque; 2: force alpha test.
    pub(crate) opacity: u8,
    /// Merged boxes: `start..end` in [`CpuTlas::merged_leaves`].
    pub(crate) leaves: (u32, u32),
}

/// A TLAS over a slice of [`TlasInstance`] records.
///
/// ```
/// use lipac_core::layout::TlasInstance;
/// use lipac_sim::blas::{BlasStore, BuildQuality};
/// use lipac_sim::tlas::{CountingBoxes, CpuTlas};
/// use lipac_sim::mesh;
/// let mut store = BlasStore::new();
/// let b = store.build(&mesh::unit().lods[2], BuildQuality::Fast, false).unwrap();
/// let id = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
/// let records = [
///     TlasInstance::new(id, 7, 0xFF, 0, 0, b.reference()),
///     TlasInstance::new(id, 8, 0xFF, 0, 0, 0), // inactive record: skipped
/// ];
/// let tlas = CpuTlas::build(&store, &records, &CountingBoxes::default()).unwrap();
/// assert_eq!(tlas.len(), 1);
/// ```
#[derive(Clone, Debug, Default)]
pub struct CpuTlas {
    pub(crate) bvh: CwBvh,
    pub(crate) entries: Vec<TlasEntry>,
    /// Leaf boxes of merged boxes: `(leaf hitbox, world to object)`.
    pub(crate) merged_leaves: Vec<(u32, Affine3A)>,
    records: usize,
    boxes: usize,
    merged: usize,
}

impl CpuTlas {
    /// Builds a TLAS over `records`. Fails on a reference to a removed or
    /// unknown BLAS, a non-finite or singular transform, or a unit-cube BLAS
    /// used without a counting SBT offset.
    pub fn build(
        store: &BlasStore,
        records: &[TlasInstance],
        counting: &CountingBoxes,
    ) -> Result<Self, SimError> {
        let mut t = Self::default();
        t.rebuild(store, records, counting)?;
        Ok(t)
    }

    /// Rebuilds in place (same rules as [`Self::build`]); on error the TLAS
    /// is left empty.
    pub fn rebuild(
        &mut self,
        store: &BlasStore,
        records: &[TlasInstance],
        counting: &CountingBoxes,
    ) -> Result<(), SimError> {
        self.rebuild_with(store, records, counting, None)
    }

    /// [`Self::rebuild`] for records that may hold merged boxes, resolved
    /// by `merged`; a merged box without a resolver is an error.
    pub fn rebuild_with(
        &mut self,
        store: &BlasStore,
        records: &[TlasInstance],
        counting: &CountingBoxes,
        merged: Option<&dyn MergedBoxes>,
    ) -> Result<(), SimError> {
        self.entries.clear();
        self.merged_leaves.clear();
        self.bvh = CwBvh::default();
        self.records = records.len();
        self.boxes = 0;
        self.merged = 0;
        let mut leaf_scratch = Vec::new();
        let mut entries = Vec::with_capacity(records.len());
        let mut aabbs: Vec<BvhAabb> = Vec::with_capacity(records.len());
        for (i, r) in records.iter().enumerate() {
            let reference = r.acceleration_structure_reference;
            if reference == 0 || r.mask() == 0 {
                continue;
            }
            let (blas_index, blas) =
                store
                    .resolve(reference)
                    .ok_or(SimError::UnknownBlasReference {
                        record: i,
                        reference,
                    })?;
            if !r.transform.iter().all(|v| v.is_finite()) {
                return Err(SimError::BadTransform { record: i });
            }
            let object_to_world = rows_to_affine(&r.transform);
            let det = object_to_world.matrix3.determinant();
            if !det.is_finite() || det.abs() < 1e-12 {
                return Err(SimError::BadTransform { record: i });
            }
            let sbt = r.sbt_offset();
            let kind = if sbt == counting.instance_box_sbt {
                EntryKind::InstanceBox
            } else if sbt == counting.hitbox_box_sbt {
                EntryKind::HitboxBox
            } else if sbt == counting.merged_box_sbt {
                EntryKind::MergedBox
            } else if blas.kind() == BvhBlasKind::UnitCube {
                return Err(SimError::BadConfig(
                    "the unit-cube BLAS needs a counting SBT offset",
                ));
            } else {
                EntryKind::Geometry
            };
            if kind == EntryKind::Geometry && blas.triangle_count() == 0 {
                continue;
            }
            if kind != EntryKind::Geometry {
                self.boxes += 1;
            }
            let mut leaves = (0, 0);
            if kind == EntryKind::MergedBox {
                let resolver = merged.ok_or(SimError::BadConfig(
                    "a merged counting box needs a MergedBoxes resolver (rebuild_with)",
                ))?;
                leaf_scratch.clear();
                resolver.leaf_boxes(r.custom_index(), &mut leaf_scratch);
                let start = self.merged_leaves.len() as u32;
                for (leaf, t) in &leaf_scratch {
                    // As a leaf box's own entry: the same inverse.
                    self.merged_leaves
                        .push((*leaf, rows_to_affine(t).inverse()));
                }
                leaves = (start, self.merged_leaves.len() as u32);
                self.merged += 1;
            }
            let b = blas.bounds();
            aabbs.push(world_bounds(&object_to_world, b.min.into(), b.max.into()));
            let flags = r.flags();
            let opacity = if flags & VK_INSTANCE_FORCE_OPAQUE != 0 {
                1
            } else if flags & VK_INSTANCE_FORCE_NO_OPAQUE != 0 {
                2
            } else {
                0
            };
            entries.push(TlasEntry {
                world_to_object: object_to_world.inverse(),
                blas: blas_index,
                custom_index: r.custom_index(),
                record: i as u32,
                mask: r.mask(),
                kind,
                opacity,
                leaves,
            });
        }
        let (bvh, _) = build_cwbvh(&aabbs, BuildQuality::CpuTlas);
        self.entries
            .extend(bvh.primitive_indices.iter().map(|&p| entries[p as usize]));
        self.bvh = bvh;
        Ok(())
    }

    /// Entries in the TLAS (records that can be hit).
    pub fn len(&self) -> usize {
        self.entries.len()
    }
    /// Whether nothing can be hit.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
    /// Entries that are counting boxes.
    pub fn box_count(&self) -> usize {
        self.boxes
    }
    /// Of [`Self::box_count`], the merged boxes of adaptive hitboxes.
    pub fn merged_box_count(&self) -> usize {
        self.merged
    }
    /// Length of the record slice it was built from.
    pub fn record_count(&self) -> usize {
        self.records
    }
    /// Approximate memory held, bytes.
    pub fn memory_bytes(&self) -> usize {
        self.bvh.nodes.len() * 80
            + self.bvh.primitive_indices.len() * 4
            + self.entries.len() * std::mem::size_of::<TlasEntry>()
            + self.merged_leaves.len() * std::mem::size_of::<(u32, Affine3A)>()
    }
}

fn world_bounds(t: &Affine3A, min: Vec3A, max: Vec3A) -> BvhAabb {
    let c = t.transform_point3a(0.5 * (min + max));
    let h = 0.5 * (max - min);
    let m = t.matrix3;
    let e = m.x_axis.abs() * h.x + m.y_axis.abs() * h.y + m.z_axis.abs() * h.z;
    BvhAabb::new(c - e, c + e)
}

#[cfg(test)]
mod tests;
