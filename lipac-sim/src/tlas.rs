//! The top-level acceleration structure: a CWBVH over the world bounds of a
//! slice of [`TlasInstance`] records, rebuilt from scratch every frame like
//! the paper's GPU-assembled TLAS.
//!
//! Each record names its BLAS by `acceleration_structure_reference`
//! ([`crate::blas::BvhBlasId::reference`]; 0 = inactive, skipped). Records
//! whose SBT offset is one of [`CountingBoxes`]'s two counting offsets
//! become *counting boxes* (the BLAS's bounds, normally the unit cube, under
//! the record's transform); all others are real geometry. Records with mask 0
//! can never be hit and are dropped.

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
}

impl Default for CountingBoxes {
    fn default() -> Self {
        Self {
            instance_box_sbt: 1,
            hitbox_box_sbt: 2,
            counting_mask: masks::COUNTING,
        }
    }
}

/// What a TLAS entry is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum EntryKind {
    Geometry,
    InstanceBox,
    HitboxBox,
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
    records: usize,
    boxes: usize,
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
        self.entries.clear();
        self.bvh = CwBvh::default();
        self.records = records.len();
        self.boxes = 0;
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
    /// Length of the record slice it was built from.
    pub fn record_count(&self) -> usize {
        self.records
    }
    /// Approximate memory held, bytes.
    pub fn memory_bytes(&self) -> usize {
        self.bvh.nodes.len() * 80
            + self.bvh.primitive_indices.len() * 4
            + self.entries.len() * std::mem::size_of::<TlasEntry>()
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
