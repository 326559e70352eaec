//! Small identifiers shared by the BLAS cache ([`crate::blas_cache`]) and the
//! build scheduler ([`crate::build_plan`]).
//!
//! They are plain newtypes so that a `Manager` tying the instance registry,
//! the cache and the allocator together can map its own ids onto them.

use std::fmt;

pub(crate) use crate::instance::MeshId;

/// A mesh level of detail. `Lod(0)` is the finest; a larger number is coarser.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Lod(pub u8);

impl Lod {
    /// Whether `self` is coarser (less detailed) than `other`.
    pub fn is_coarser_than(self, other: Lod) -> bool {
        self.0 > other.0
    }
}

/// Opaque identity of a model instance (e.g. its registry or GPU slot).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct InstanceKey(pub u32);

/// Key of a shared BLAS: one BLAS per (mesh, LOD, geometry variant).
///
/// `variant` distinguishes geometry variants of the same mesh LOD, e.g. the
/// opaque / non-opaque split of thesis §3.2.4 or different geometry flags.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct BlasKey {
    /// Source mesh.
    pub mesh: MeshId,
    /// Level of detail.
    pub lod: Lod,
    /// Geometry variant.
    pub variant: u32,
}

/// Identifies one GPU operation handed to the backend (a build or a
/// compaction copy); the backend quotes it back in its acknowledgement.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct BuildId(pub u64);

impl fmt::Display for BuildId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "build #{}", self.0)
    }
}

slotmap::new_key_type! {
    /// Handle of one BLAS entry in the cache (shared or unique). Handles are
    /// versioned: a handle of a removed entry never names a later one.
    pub struct BlasId;
}
