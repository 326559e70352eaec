//! The BLASes of a [`Scene`]: one shared BLAS per (mesh, LOD), built on
//! demand and cached, and one unique BLAS per unique instance (terrain
//! tiles, terrain-adapted buildings, animated units), updated by refit or
//! rebuild on request. Also builds the full-scene TLAS records that stand in
//! for rasterization and ground truth.

use std::collections::HashMap;

use glam::Vec3;
use lipac_core::layout::TlasInstance;
use lipac_core::math::affine_to_rows;

use crate::blas::{BlasStore, BuildQuality, BvhBlasId};
use crate::error::SimError;
use crate::mesh::{LodTriangles, MeshIndex, MeshLibrary, LOD_COUNT};
use crate::scene::{LodPolicy, Scene, SceneInstance};
use crate::tlas::masks;

/// How an existing unique BLAS of an animated instance follows a new frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UniqueUpdate {
    /// Keep it as built (stale pose).
    Keep,
    /// Re-deform and refit (same topology).
    Refit,
    /// Re-deform and rebuild.
    Rebuild,
}

#[derive(Clone, Copy, Debug)]
struct UniqueBlas {
    id: BvhBlasId,
    lod: usize,
    frame: u32,
}

/// The BLASes of one scene in a [`BlasStore`].
#[derive(Clone, Debug, Default)]
pub struct SceneBlases {
    shared: HashMap<MeshIndex, [Option<BvhBlasId>; LOD_COUNT]>,
    unique: HashMap<u32, UniqueBlas>,
    scratch: LodTriangles,
}

impl SceneBlases {
    /// Nothing built yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// The shared BLAS of (`mesh`, `lod`), built on first use.
    pub fn shared(
        &mut self,
        store: &mut BlasStore,
        library: &MeshLibrary,
        mesh: MeshIndex,
        lod: usize,
    ) -> Result<BvhBlasId, SimError> {
        let geom = library.lod(mesh, lod)?;
        let entry = self.shared.entry(mesh).or_insert([None; LOD_COUNT]);
        if let Some(id) = entry[lod] {
            if store.get(id).is_ok() {
                return Ok(id);
            }
        }
        let id = store.build(geom, BuildQuality::Good, false)?;
        entry[lod] = Some(id);
        Ok(id)
    }

    /// The unique BLAS of instance `slot` at `lod` for `frame`: built if
    /// missing or at another LOD; for animated instances at another frame,
    /// updated as `update` says (static unique geometry never changes).
    pub fn unique(
        &mut self,
        store: &mut BlasStore,
        scene: &Scene,
        slot: u32,
        lod: usize,
        frame: u32,
        update: UniqueUpdate,
    ) -> Result<BvhBlasId, SimError> {
        let inst = *scene.instance(slot)?;
        if !inst.is_unique() {
            return Err(SimError::NotUnique(slot));
        }
        if lod >= LOD_COUNT {
            return Err(SimError::BadLod(lod));
        }
        let animated = inst.is_animated();
        if let Some(u) = self.unique.get(&slot).copied() {
            if store.get(u.id).is_ok() {
                if u.lod == lod && (!animated || u.frame == frame || update == UniqueUpdate::Keep) {
                    return Ok(u.id);
                }
                scene.unique_geometry(slot, lod, frame, &mut self.scratch)?;
                if u.lod == lod && update == UniqueUpdate::Refit {
                    store.refit(u.id, &self.scratch)?;
                } else {
                    store.rebuild(u.id, &self.scratch, BuildQuality::Fast)?;
                }
                self.unique.insert(
                    slot,
                    UniqueBlas {
                        id: u.id,
                        lod,
                        frame,
                    },
                );
                return Ok(u.id);
            }
        }
        scene.unique_geometry(slot, lod, frame, &mut self.scratch)?;
        let quality = if animated {
            BuildQuality::Fast
        } else {
            BuildQuality::Good
        };
        let id = store.build(&self.scratch, quality, animated)?;
        self.unique.insert(slot, UniqueBlas { id, lod, frame });
        Ok(id)
    }

    /// Brings every animated unique BLAS held at its instance's LOD in
    /// `lods` to `frame` by refit, in parallel (in the current rayon pool):
    /// what [`Self::unique`] with [`UniqueUpdate::Refit`] would do for each
    /// of them one by one, leaving the others (another LOD, none held yet)
    /// to it.
    pub fn refit_animated(
        &mut self,
        store: &mut BlasStore,
        scene: &Scene,
        lods: &[u8],
        frame: u32,
    ) -> Result<(), SimError> {
        if lods.len() != scene.instances().len() {
            return Err(SimError::SizeMismatch {
                a: lods.len(),
                b: scene.instances().len(),
            });
        }
        let mut due: Vec<(u32, UniqueBlas)> = self
            .unique
            .iter()
            .filter(|(&slot, u)| {
                u.frame != frame
                    && lods.get(slot as usize).map(|&l| usize::from(l)) == Some(u.lod)
                    && scene.instance(slot).is_ok_and(|i| i.is_animated())
                    && store.get(u.id).is_ok()
            })
            .map(|(&slot, &u)| (slot, u))
            .collect();
        due.sort_unstable_by_key(|&(slot, _)| slot);
        let ids: Vec<BvhBlasId> = due.iter().map(|(_, u)| u.id).collect();
        store.refit_many(&ids, |i, out| {
            let (slot, u) = due[i];
            scene.unique_geometry(slot, u.lod, frame, out)
        })?;
        for (slot, u) in due {
            self.unique.insert(slot, UniqueBlas { frame, ..u });
        }
        Ok(())
    }

    /// The BLAS for instance `slot` (shared or unique, see [`Self::unique`]).
    pub fn blas_for(
        &mut self,
        store: &mut BlasStore,
        scene: &Scene,
        slot: u32,
        lod: usize,
        frame: u32,
        update: UniqueUpdate,
    ) -> Result<BvhBlasId, SimError> {
        let inst = scene.instance(slot)?;
        if inst.is_unique() {
            self.unique(store, scene, slot, lod, frame, update)
        } else {
            self.shared(store, scene.library(), inst.mesh, lod)
        }
    }

    /// Frees the unique BLAS of `slot`; `Ok(false)` if it had none.
    pub fn release_unique(&mut self, store: &mut BlasStore, slot: u32) -> Result<bool, SimError> {
        match self.unique.remove(&slot) {
            Some(u) => store.remove(u.id).map(|_| true),
            None => Ok(false),
        }
    }

    /// Number of unique BLASes held.
    pub fn unique_count(&self) -> usize {
        self.unique.len()
    }
}

/// The TLAS mask of a scene instance: vegetation or opaque geometry.
pub fn instance_mask(inst: &SceneInstance) -> u8 {
    if inst.is_vegetation() {
        masks::VEGETATION
    } else {
        masks::GEOMETRY
    }
}

/// The TLAS record of instance `slot` as real geometry with BLAS `blas`
/// (custom index = slot, SBT offset 0).
pub fn geometry_record(inst: &SceneInstance, slot: u32, blas: BvhBlasId) -> TlasInstance {
    TlasInstance::new(
        affine_to_rows(&inst.transform),
        slot,
        instance_mask(inst),
        0,
        0,
        blas.reference(),
    )
}

/// Records of the full scene at `frame` (every instance as real geometry,
/// LOD chosen by `policy` from `eye`), building BLASes as needed. This is
/// the unculled TLAS: the rasterization stand-in and the ground truth.
#[allow(clippy::too_many_arguments)]
pub fn full_scene_records(
    scene: &Scene,
    blases: &mut SceneBlases,
    store: &mut BlasStore,
    eye: Vec3,
    policy: &LodPolicy,
    frame: u32,
    update: UniqueUpdate,
    out: &mut Vec<TlasInstance>,
) -> Result<(), SimError> {
    out.clear();
    out.reserve(scene.instances().len());
    for (slot, inst) in scene.instances().iter().enumerate() {
        let slot = slot as u32;
        let lod = policy.lod(eye, &inst.aabb);
        let id = blases.blas_for(store, scene, slot, lod, frame, update)?;
        out.push(geometry_record(inst, slot, id));
    }
    Ok(())
}

/// Like [`full_scene_records`] with each instance's LOD given
/// (`lods[slot]`) instead of chosen by a policy: a recorded trace's LODs.
pub fn full_scene_records_at(
    scene: &Scene,
    blases: &mut SceneBlases,
    store: &mut BlasStore,
    lods: &[u8],
    frame: u32,
    update: UniqueUpdate,
    out: &mut Vec<TlasInstance>,
) -> Result<(), SimError> {
    if lods.len() != scene.instances().len() {
        return Err(SimError::SizeMismatch {
            a: lods.len(),
            b: scene.instances().len(),
        });
    }
    if update == UniqueUpdate::Refit {
        blases.refit_animated(store, scene, lods, frame)?;
    }
    out.clear();
    out.reserve(scene.instances().len());
    for (slot, (inst, &lod)) in scene.instances().iter().zip(lods).enumerate() {
        let slot = slot as u32;
        let id = blases.blas_for(store, scene, slot, usize::from(lod), frame, update)?;
        out.push(geometry_record(inst, slot, id));
    }
    Ok(())
}
