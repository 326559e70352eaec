//! What the engine tells the manager about its meshes: per LOD, the BLAS
//! build sizes and the bytes of geometry-instance data an instance needs.

use std::collections::HashMap;

use super::error::ManagerError;
use crate::blas_cache::MAX_BLAS_BYTES;
use crate::build_plan::BuildEstimate;
use crate::instance::MeshId;

/// Most LODs per mesh ([`crate::blas_ids::Lod`] is a `u8`).
pub const MAX_LODS: usize = 256;

/// The largest [`MeshLod::data_bytes`] accepted: 2^32 bytes (4 GiB) of
/// geometry-instance data per instance.
pub const MAX_LOD_DATA_BYTES: u64 = 1 << 32;

/// One level of detail of a mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MeshLod {
    /// BLAS build sizes at this LOD (the engine's build-sizes query);
    /// `estimate.primitives` is the triangle count.
    pub estimate: BuildEstimate,
    /// Bytes of geometry-instance data one instance of this LOD needs (e.g.
    /// per-geometry material and vertex/index offsets the hit shaders read),
    /// at least 1. Each live instance owns a range of this size in the
    /// manager's geometry-data buffer.
    pub data_bytes: u64,
}

impl MeshLod {
    /// The triangle count (`estimate.primitives`).
    pub fn triangles(&self) -> u64 {
        self.estimate.primitives
    }
}

/// The meshes an engine registered, each with its LODs (`Lod(0)` finest).
///
/// ```
/// use lipac_core::build_plan::BuildEstimate;
/// use lipac_core::instance::MeshId;
/// use lipac_core::manager::{ManagerError, MeshCatalog, MeshLod};
///
/// let lod = |tris: u64| MeshLod {
///     estimate: BuildEstimate { primitives: tris, result_bytes: tris * 64,
///                               build_scratch_bytes: tris * 32, update_scratch_bytes: 0 },
///     data_bytes: 256,
/// };
/// let mut catalog = MeshCatalog::new();
/// catalog.insert(MeshId(1), vec![lod(1000), lod(250)])?;
/// assert_eq!(catalog.lod(MeshId(1), 1)?.triangles(), 250);
/// assert!(matches!(catalog.lod(MeshId(1), 2), Err(ManagerError::UnknownLod { lods: 2, .. })));
/// assert_eq!(catalog.lod(MeshId(9), 0), Err(ManagerError::UnknownMesh(MeshId(9))));
/// # Ok::<(), ManagerError>(())
/// ```
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct MeshCatalog {
    meshes: HashMap<MeshId, Vec<MeshLod>>,
}

impl MeshCatalog {
    /// An empty catalog.
    pub fn new() -> Self {
        Self::default()
    }

    /// Registers `mesh` with its LODs (1..=[`MAX_LODS`], each with
    /// `estimate.result_bytes` in `1..=`[`MAX_BLAS_BYTES`], both scratch
    /// sizes at most [`MAX_BLAS_BYTES`] and `data_bytes` in
    /// `1..=`[`MAX_LOD_DATA_BYTES`]). A mesh is registered once: its sizes
    /// decide live allocations and BLASes. On error nothing changes.
    pub fn insert(&mut self, mesh: MeshId, lods: Vec<MeshLod>) -> Result<(), ManagerError> {
        let invalid = |what: String| Err(ManagerError::InvalidMesh { mesh, what });
        if self.meshes.contains_key(&mesh) {
            return invalid("already registered".into());
        }
        if lods.is_empty() || lods.len() > MAX_LODS {
            return invalid(format!("{} LODs; 1..={MAX_LODS} are allowed", lods.len()));
        }
        for (i, l) in lods.iter().enumerate() {
            if l.estimate.result_bytes == 0 {
                return invalid(format!("LOD {i}: estimate.result_bytes is 0"));
            }
            if l.data_bytes == 0 {
                return invalid(format!("LOD {i}: data_bytes is 0"));
            }
            if l.data_bytes > MAX_LOD_DATA_BYTES {
                return invalid(format!(
                    "LOD {i}: data_bytes = {} is above the limit {MAX_LOD_DATA_BYTES}",
                    l.data_bytes
                ));
            }
            let e = &l.estimate;
            for (what, bytes) in [
                ("result_bytes", e.result_bytes),
                ("build_scratch_bytes", e.build_scratch_bytes),
                ("update_scratch_bytes", e.update_scratch_bytes),
            ] {
                if bytes > MAX_BLAS_BYTES {
                    return invalid(format!(
                        "LOD {i}: estimate.{what} = {bytes} is above the limit {MAX_BLAS_BYTES}"
                    ));
                }
            }
        }
        self.meshes.insert(mesh, lods);
        Ok(())
    }

    /// LOD `lod` of `mesh`.
    pub fn lod(&self, mesh: MeshId, lod: u32) -> Result<&MeshLod, ManagerError> {
        let lods = self
            .meshes
            .get(&mesh)
            .ok_or(ManagerError::UnknownMesh(mesh))?;
        lods.get(lod as usize).ok_or(ManagerError::UnknownLod {
            mesh,
            lod,
            lods: lods.len(),
        })
    }

    /// The LODs of `mesh`, if registered.
    pub fn lods(&self, mesh: MeshId) -> Option<&[MeshLod]> {
        self.meshes.get(&mesh).map(Vec::as_slice)
    }

    /// Every mesh with its LODs, in no particular order.
    pub fn iter(&self) -> impl Iterator<Item = (MeshId, &[MeshLod])> {
        self.meshes.iter().map(|(m, l)| (*m, l.as_slice()))
    }

    /// Whether `mesh` is registered.
    pub fn contains(&self, mesh: MeshId) -> bool {
        self.meshes.contains_key(&mesh)
    }

    /// Number of meshes.
    pub fn len(&self) -> usize {
        self.meshes.len()
    }

    /// Whether no mesh is registered.
    pub fn is_empty(&self) -> bool {
        self.meshes.is_empty()
    }
}
