//! The manager's error type: one enum over the errors of the parts it ties
//! together.

use std::fmt;

use crate::allocator::AllocError;
use crate::build_plan::BuildPlanError;
use crate::error::CoreError;
use crate::instance::MeshId;

/// Why a [`Manager`](super::Manager) call was refused.
///
/// Caller errors (stale handles, unknown meshes, bad descriptions, calls out
/// of order) leave the manager unchanged. [`ManagerError::Invariant`] would
/// be a bug in lipac, never the caller's fault.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum ManagerError {
    /// From the instance registry / command loop (stale handles, invalid
    /// transforms or AABBs, no slot left, call order, ...).
    Core(CoreError),
    /// From the build scheduler or the BLAS cache (unknown acknowledgements,
    /// invalid sizes, ...).
    Build(BuildPlanError),
    /// From the geometry-data allocator.
    Alloc(AllocError),
    /// The mesh was never registered in the [`MeshCatalog`](super::MeshCatalog).
    UnknownMesh(MeshId),
    /// The mesh has no such LOD.
    UnknownLod {
        /// The mesh.
        mesh: MeshId,
        /// The LOD asked for.
        lod: u32,
        /// How many LODs the mesh has (valid: `0..lods`).
        lods: usize,
    },
    /// A mesh description the catalog cannot use.
    InvalidMesh {
        /// The mesh.
        mesh: MeshId,
        /// What is wrong with it.
        what: String,
    },
    /// [`Manager::update`](super::Manager::update) tried to change what
    /// decides an instance's BLAS (its mesh, or the `UNIQUE_BLAS` / `STATIC`
    /// flags); remove the instance and register it again instead.
    GeometryChange {
        /// What changed.
        what: &'static str,
    },
    /// A configuration that cannot work.
    InvalidConfig {
        /// What is wrong, naming the offending value.
        what: String,
    },
    /// A per-frame step called out of order.
    CallOrder {
        /// What was out of order.
        what: String,
    },
    /// Internal bookkeeping disagrees (a bug in lipac, please report it).
    Invariant {
        /// What disagreed.
        what: String,
    },
}

impl fmt::Display for ManagerError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Core(e) => write!(f, "{e}"),
            Self::Build(e) => write!(f, "BLAS scheduling: {e}"),
            Self::Alloc(e) => write!(f, "geometry-data allocator: {e}"),
            Self::UnknownMesh(m) => write!(
                f,
                "mesh {} is not in the mesh catalog (register it first)",
                m.0
            ),
            Self::UnknownLod { mesh, lod, lods } => write!(
                f,
                "mesh {} has no LOD {lod} (it has {lods}: 0..{lods})",
                mesh.0
            ),
            Self::InvalidMesh { mesh, what } => write!(f, "mesh {}: {what}", mesh.0),
            Self::GeometryChange { what } => write!(
                f,
                "update cannot change {what}: remove the instance and register it again"
            ),
            Self::InvalidConfig { what } => write!(f, "invalid manager configuration: {what}"),
            Self::CallOrder { what } => write!(f, "call out of order: {what}"),
            Self::Invariant { what } => write!(f, "internal inconsistency (a lipac bug): {what}"),
        }
    }
}

impl std::error::Error for ManagerError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Core(e) => Some(e),
            Self::Build(e) => Some(e),
            Self::Alloc(e) => Some(e),
            _ => None,
        }
    }
}

impl From<CoreError> for ManagerError {
    fn from(e: CoreError) -> Self {
        Self::Core(e)
    }
}

impl From<BuildPlanError> for ManagerError {
    fn from(e: BuildPlanError) -> Self {
        Self::Build(e)
    }
}

impl From<AllocError> for ManagerError {
    fn from(e: AllocError) -> Self {
        Self::Alloc(e)
    }
}
