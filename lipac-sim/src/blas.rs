//! Bottom-level acceleration structures on `obvhs`: one compressed wide BVH
//! (CWBVH) per triangle set, a store that hands out generation-checked
//! handles, and the one static unit-cube BLAS that counting boxes use.
//!
//! A [`BvhBlasId`] maps to the `acceleration_structure_reference` of a
//! [`lipac_core::layout::TlasInstance`] as `((generation << 32) | index) + 1`
//! ([`BvhBlasId::reference`]); reference 0 marks an inactive record.
//!
//! BLASes built with `refittable = true` keep their binary BVH so that
//! [`BlasStore::refit`] can update node bounds for moved vertices (same
//! topology, cheap, quality degrades with large motion) instead of a full
//! [`BlasStore::rebuild`]. Both are counted in [`BuildStats`].
//!
//! [`BuildThroughput`] measures what an obvhs build and refit cost per
//! triangle on given geometry, so that counted BLAS work (triangles built
//! and refit) can be charged in milliseconds.

use std::time::Instant;

use glam::{Vec3, Vec3A};
use lipac_core::math::Aabb;
use obvhs::bvh2::reinsertion::ReinsertionOptimizer;
use obvhs::bvh2::Bvh2;
use obvhs::cwbvh::bvh2_to_cwbvh::bvh2_to_cwbvh;
use obvhs::cwbvh::CwBvh;
use obvhs::ploc::PlocBuilder;
use obvhs::rt_triangle::RtTriangle;
use obvhs::BvhBuildParams;

use crate::error::SimError;
use crate::mesh::LodTriangles;

/// The unit cube that counting boxes are made of: `[0, 1]^3` in object space.
/// A box instance's transform maps it onto the box it stands for
/// (see [`box_transform`]).
pub const UNIT_CUBE: Aabb = Aabb::new(Vec3::ZERO, Vec3::ONE);

/// Row-major 3x4 transform mapping [`UNIT_CUBE`] onto `aabb`
/// (scale by the size, translate to the minimum corner).
///
/// ```
/// use lipac_sim::blas::box_transform;
/// use lipac_core::math::Aabb;
/// use glam::Vec3;
/// let t = box_transform(&Aabb::new(Vec3::new(1.0, 2.0, 3.0), Vec3::new(3.0, 6.0, 4.0)));
/// assert_eq!(t, [2.0, 0.0, 0.0, 1.0, 0.0, 4.0, 0.0, 2.0, 0.0, 0.0, 1.0, 3.0]);
/// ```
pub fn box_transform(aabb: &Aabb) -> [f32; 12] {
    let s = aabb.size();
    let m = aabb.min;
    [s.x, 0.0, 0.0, m.x, 0.0, s.y, 0.0, m.y, 0.0, 0.0, s.z, m.z]
}

/// Handle of a BLAS in a [`BlasStore`]; stale handles are rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct BvhBlasId {
    index: u32,
    generation: u32,
}

impl BvhBlasId {
    /// The TLAS `acceleration_structure_reference` naming this BLAS (never 0).
    pub fn reference(self) -> u64 {
        ((u64::from(self.generation) << 32) | u64::from(self.index)) + 1
    }
    /// The handle a reference names; `None` for 0 (inactive record).
    pub fn from_reference(reference: u64) -> Option<Self> {
        let r = reference.checked_sub(1)?;
        Some(Self {
            index: r as u32,
            generation: (r >> 32) as u32,
        })
    }
    /// Slot index in the store.
    pub fn index(self) -> u32 {
        self.index
    }
}

/// Build quality presets (mapped onto `obvhs::BvhBuildParams`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BuildQuality {
    /// Fastest build (animated BLASes).
    Fast,
    /// Better trees for static shared geometry.
    Good,
    /// TLAS: good tree, one instance per leaf (instances are expensive to
    /// enter, so leaves should not group them).
    CpuTlas,
}

impl BuildQuality {
    fn params(self) -> BvhBuildParams {
        match self {
            Self::Fast => BvhBuildParams::very_fast_build(),
            Self::Good => BvhBuildParams::fast_build(),
            Self::CpuTlas => BvhBuildParams {
                max_prims_per_leaf: 1,
                ..BvhBuildParams::fast_build()
            },
        }
    }
}

/// Builds an `obvhs` CWBVH over primitives with bounds (and keeps the
/// binary BVH it was converted from).
pub(crate) fn build_cwbvh<T: obvhs::Boundable>(
    prims: &[T],
    quality: BuildQuality,
) -> (CwBvh, Bvh2) {
    if prims.is_empty() {
        return (CwBvh::default(), Bvh2::default());
    }
    let p = quality.params();
    let mut bvh2 = PlocBuilder::with_capacity(prims.len()).build(
        p.ploc_search_distance,
        prims,
        (0..prims.len() as u32).collect(),
        p.sort_precision,
        p.search_depth_threshold,
    );
    if p.reinsertion_batch_ratio > 0.0 && prims.len() > 8 {
        ReinsertionOptimizer::default().run(&mut bvh2, p.reinsertion_batch_ratio, None);
    }
    let cw = bvh2_to_cwbvh(&bvh2, p.max_prims_per_leaf.clamp(1, 3), true, false);
    (cw, bvh2)
}

/// What a BLAS holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BvhBlasKind {
    /// Triangles.
    Triangles,
    /// The unit cube of counting boxes (no triangles; intersected as a box).
    UnitCube,
}

/// One BLAS: a CWBVH and its triangles in BVH order.
#[derive(Clone)]
pub struct BvhBlas {
    pub(crate) kind: BvhBlasKind,
    pub(crate) bvh: CwBvh,
    /// Triangles in BVH primitive order.
    pub(crate) tris: Vec<RtTriangle>,
    /// Original triangle index per BVH primitive.
    pub(crate) prim: Vec<u32>,
    /// Material byte per BVH primitive.
    pub(crate) material: Vec<u8>,
    /// Alpha-tested flag per BVH primitive.
    pub(crate) alpha: Vec<bool>,
    pub(crate) any_alpha: bool,
    pub(crate) bounds: Aabb,
    bvh2: Option<Bvh2>,
}

impl std::fmt::Debug for BvhBlas {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BvhBlas")
            .field("kind", &self.kind)
            .field("triangles", &self.tris.len())
            .field("nodes", &self.bvh.nodes.len())
            .field("bounds", &self.bounds)
            .field("refittable", &self.bvh2.is_some())
            .finish()
    }
}

impl BvhBlas {
    /// What it holds.
    pub fn kind(&self) -> BvhBlasKind {
        self.kind
    }
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }
    /// Object-space bounds.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }
    /// Whether [`BlasStore::refit`] works on it.
    pub fn is_refittable(&self) -> bool {
        self.bvh2.is_some()
    }
    /// Approximate memory held, bytes (nodes, triangles, attributes).
    pub fn memory_bytes(&self) -> usize {
        self.bvh.nodes.len() * 80
            + self.bvh.primitive_indices.len() * 4
            + self.tris.len() * (std::mem::size_of::<RtTriangle>() + 4 + 2)
            + self
                .bvh2
                .as_ref()
                .map_or(0, |b| b.nodes.len() * 48 + b.primitive_indices.len() * 8)
    }

    fn unit_cube() -> Self {
        Self {
            kind: BvhBlasKind::UnitCube,
            bvh: CwBvh::default(),
            tris: Vec::new(),
            prim: Vec::new(),
            material: Vec::new(),
            alpha: Vec::new(),
            any_alpha: false,
            bounds: UNIT_CUBE,
            bvh2: None,
        }
    }

    fn from_geometry(
        geom: &LodTriangles,
        quality: BuildQuality,
        refittable: bool,
    ) -> Result<Self, SimError> {
        check_geometry(geom)?;
        let (bvh, bvh2) = build_cwbvh(&geom.triangles, quality);
        let mut b = Self {
            kind: BvhBlasKind::Triangles,
            bvh,
            tris: Vec::new(),
            prim: Vec::new(),
            material: Vec::new(),
            alpha: Vec::new(),
            any_alpha: false,
            bounds: geom.bounds(),
            bvh2: refittable.then_some(bvh2),
        };
        b.reorder(geom);
        Ok(b)
    }

    /// Refits to moved vertices ([`BlasStore::refit`]).
    fn refit(&mut self, geom: &LodTriangles) -> Result<(), SimError> {
        check_geometry(geom)?;
        let expected = self.tris.len();
        let Some(bvh2) = self.bvh2.as_mut() else {
            return Err(SimError::BadConfig("BLAS was not built refittable"));
        };
        if geom.len() != expected {
            return Err(SimError::RefitCountMismatch {
                expected,
                got: geom.len(),
            });
        }
        if expected > 0 {
            bvh2.init_primitives_to_nodes_if_uninit();
            for (i, t) in geom.triangles.iter().enumerate() {
                let node = bvh2.primitives_to_nodes[i] as usize;
                bvh2.nodes[node].set_aabb(t.aabb());
            }
            bvh2.refit_all();
            self.bvh = bvh2_to_cwbvh(bvh2, 3, true, false);
        }
        self.reorder(geom);
        Ok(())
    }

    /// Lays triangles and attributes out in BVH primitive order.
    fn reorder(&mut self, geom: &LodTriangles) {
        let order = &self.bvh.primitive_indices;
        self.prim.clear();
        self.prim.extend_from_slice(order);
        self.tris.clear();
        self.tris.extend(
            order
                .iter()
                .map(|&i| RtTriangle::from(&geom.triangles[i as usize])),
        );
        self.material.clear();
        self.material.extend(
            order
                .iter()
                .map(|&i| geom.materials.get(i as usize).copied().unwrap_or(0)),
        );
        self.alpha.clear();
        self.alpha.extend(
            order
                .iter()
                .map(|&i| geom.alpha_tested.get(i as usize).copied().unwrap_or(false)),
        );
        self.any_alpha = self.alpha.iter().any(|&a| a);
        self.bounds = geom.bounds();
    }
}

fn check_geometry(geom: &LodTriangles) -> Result<(), SimError> {
    let finite = geom
        .triangles
        .iter()
        .all(|t| Vec3A::is_finite(t.v0) && Vec3A::is_finite(t.v1) && Vec3A::is_finite(t.v2));
    if finite {
        Ok(())
    } else {
        Err(SimError::NonFinite("triangle vertices"))
    }
}

/// Counts of BLAS work done, for cost models.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BuildStats {
    /// Full builds (including rebuilds).
    pub builds: u64,
    /// Refits.
    pub refits: u64,
    /// Triangles processed by builds.
    pub primitives_built: u64,
    /// Triangles processed by refits.
    pub primitives_refit: u64,
}

/// What an obvhs BLAS build and refit cost per triangle, measured on given
/// geometry ([`BuildThroughput::measure`]), and the charge of counted work
/// at those rates ([`BuildThroughput::build_ms`],
/// [`BuildThroughput::refit_ms`]).
///
/// Builds are measured at [`BuildQuality::Good`] without the binary BVH
/// kept (how shared BLASes, most builds, are built); refits on BLASes built
/// [`BuildQuality::Fast`] and refittable (how animated unique BLASes are),
/// refit to unchanged vertices (a refit's cost does not depend on how far
/// they moved).
///
/// ```
/// use lipac_sim::blas::BuildThroughput;
/// use lipac_sim::mesh;
/// let tree = mesh::tree();
/// let t = BuildThroughput::measure(tree.lods.iter(), 1.0).unwrap();
/// assert!(t.build_ns_per_triangle > 0.0 && t.refit_ns_per_triangle > 0.0);
/// assert_eq!(t.build_ms(0), 0.0);
/// let none = BuildThroughput::measure(std::iter::empty(), 1.0).unwrap();
/// assert_eq!(none.build_ms(1000), 0.0);
/// assert!(BuildThroughput::measure(tree.lods.iter(), f64::NAN).is_err());
/// assert!((t.refit_ms(2_000_000) - t.refit_ns_per_triangle * 2.0).abs() < 1e-9);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BuildThroughput {
    /// Wall time of a build per triangle, ns.
    pub build_ns_per_triangle: f64,
    /// Wall time of a refit per triangle, ns.
    pub refit_ns_per_triangle: f64,
    /// Triangles built while measuring.
    pub triangles_built: u64,
    /// Triangles refit while measuring.
    pub triangles_refit: u64,
}

impl BuildThroughput {
    /// Builds and refits every triangle set of `geoms` in turn, passes over
    /// all of them until builds and refits have each taken at least
    /// `min_ms` (at most 1000 passes), and divides the time by the
    /// triangles. Empty sets are skipped; with no triangle at all there is
    /// no BLAS work to charge, and both rates are 0. An error if `min_ms`
    /// is not finite, or for non-finite vertices.
    pub fn measure<'a>(
        geoms: impl Iterator<Item = &'a LodTriangles> + Clone,
        min_ms: f64,
    ) -> Result<Self, SimError> {
        if !min_ms.is_finite() {
            return Err(SimError::BadConfig("measuring time must be finite"));
        }
        if geoms.clone().all(|g| g.is_empty()) {
            return Ok(Self::default());
        }
        let (mut build_ns, mut refit_ns) = (0u128, 0u128);
        let mut out = Self::default();
        let goal = (min_ms.max(0.0) * 1e6) as u128;
        for _ in 0..1000 {
            for g in geoms.clone().filter(|g| !g.is_empty()) {
                let t = Instant::now();
                let b = BvhBlas::from_geometry(g, BuildQuality::Good, false)?;
                build_ns += t.elapsed().as_nanos();
                std::hint::black_box(&b);
                let mut store = BlasStore::new();
                let id = store.build(g, BuildQuality::Fast, true)?;
                let t = Instant::now();
                store.refit(id, g)?;
                refit_ns += t.elapsed().as_nanos();
                out.triangles_built += g.len() as u64;
                out.triangles_refit += g.len() as u64;
            }
            if build_ns >= goal && refit_ns >= goal {
                break;
            }
        }
        // A clock too coarse to see a pass still gives a positive rate.
        out.build_ns_per_triangle = build_ns.max(1) as f64 / out.triangles_built as f64;
        out.refit_ns_per_triangle = refit_ns.max(1) as f64 / out.triangles_refit as f64;
        Ok(out)
    }

    /// Milliseconds `triangles` built cost at this rate.
    pub fn build_ms(&self, triangles: u64) -> f64 {
        triangles as f64 * self.build_ns_per_triangle * 1e-6
    }

    /// Milliseconds `triangles` refit cost at this rate.
    pub fn refit_ms(&self, triangles: u64) -> f64 {
        triangles as f64 * self.refit_ns_per_triangle * 1e-6
    }
}

/// Owns every BLAS; hands out generation-checked [`BvhBlasId`]s.
///
/// ```
/// use lipac_sim::blas::{BlasStore, BuildQuality, BvhBlasId};
/// use lipac_sim::mesh;
/// let mut store = BlasStore::new();
/// let tree = mesh::tree();
/// let id = store.build(&tree.lods[0], BuildQuality::Good, false).unwrap();
/// assert_eq!(BvhBlasId::from_reference(id.reference()), Some(id));
/// assert_eq!(store.get(id).unwrap().triangle_count(), tree.lods[0].len());
/// store.remove(id).unwrap();
/// assert!(store.get(id).is_err());
/// ```
#[derive(Clone, Debug)]
pub struct BlasStore {
    slots: Vec<(u32, Option<BvhBlas>)>,
    free: Vec<u32>,
    stats: BuildStats,
}

impl Default for BlasStore {
    fn default() -> Self {
        Self::new()
    }
}

impl BlasStore {
    /// A store holding only the unit cube (at [`BlasStore::unit_cube`]).
    pub fn new() -> Self {
        Self {
            slots: vec![(0, Some(BvhBlas::unit_cube()))],
            free: Vec::new(),
            stats: BuildStats::default(),
        }
    }
    /// The static unit-cube BLAS of counting boxes.
    pub fn unit_cube(&self) -> BvhBlasId {
        BvhBlasId {
            index: 0,
            generation: 0,
        }
    }
    /// Builds a BLAS over `geom` (triangles, materials, alpha flags).
    /// `refittable` keeps the binary BVH so that [`Self::refit`] works.
    pub fn build(
        &mut self,
        geom: &LodTriangles,
        quality: BuildQuality,
        refittable: bool,
    ) -> Result<BvhBlasId, SimError> {
        let blas = BvhBlas::from_geometry(geom, quality, refittable)?;
        self.stats.builds += 1;
        self.stats.primitives_built += geom.len() as u64;
        Ok(self.insert(blas))
    }
    fn insert(&mut self, blas: BvhBlas) -> BvhBlasId {
        if let Some(index) = self.free.pop() {
            let slot = &mut self.slots[index as usize];
            slot.0 = (slot.0 + 1) & 0x7FFF_FFFF;
            slot.1 = Some(blas);
            BvhBlasId {
                index,
                generation: slot.0,
            }
        } else {
            self.slots.push((0, Some(blas)));
            BvhBlasId {
                index: (self.slots.len() - 1) as u32,
                generation: 0,
            }
        }
    }
    /// The BLAS `id`.
    pub fn get(&self, id: BvhBlasId) -> Result<&BvhBlas, SimError> {
        match self.slots.get(id.index as usize) {
            Some((g, Some(b))) if *g == id.generation => Ok(b),
            _ => Err(SimError::StaleBlas),
        }
    }
    fn get_mut(&mut self, id: BvhBlasId) -> Result<&mut BvhBlas, SimError> {
        match self.slots.get_mut(id.index as usize) {
            Some((g, Some(b))) if *g == id.generation => Ok(b),
            _ => Err(SimError::StaleBlas),
        }
    }
    /// Resolves a TLAS reference (0 and stale references give `None`).
    pub(crate) fn resolve(&self, reference: u64) -> Option<(u32, &BvhBlas)> {
        let id = BvhBlasId::from_reference(reference)?;
        self.get(id).ok().map(|b| (id.index, b))
    }
    /// The BLAS in slot `index` (used by traversal after a TLAS build has
    /// validated the handles).
    pub(crate) fn slot(&self, index: u32) -> Option<&BvhBlas> {
        self.slots.get(index as usize).and_then(|s| s.1.as_ref())
    }
    /// Rebuilds `id` from new geometry (any triangle count).
    pub fn rebuild(
        &mut self,
        id: BvhBlasId,
        geom: &LodTriangles,
        quality: BuildQuality,
    ) -> Result<(), SimError> {
        let refittable = self.get(id)?.is_refittable();
        if self.get(id)?.kind == BvhBlasKind::UnitCube {
            return Err(SimError::BadConfig("the unit cube BLAS is static"));
        }
        let blas = BvhBlas::from_geometry(geom, quality, refittable)?;
        *self.get_mut(id)? = blas;
        self.stats.builds += 1;
        self.stats.primitives_built += geom.len() as u64;
        Ok(())
    }
    /// Refits `id` to moved vertices: same triangle count and order as the
    /// build; node bounds are recomputed, the tree topology is kept.
    pub fn refit(&mut self, id: BvhBlasId, geom: &LodTriangles) -> Result<(), SimError> {
        self.get_mut(id)?.refit(geom)?;
        self.stats.refits += 1;
        self.stats.primitives_refit += geom.len() as u64;
        Ok(())
    }
    /// [`Self::refit`] of many BLASes at once, in parallel (in the current
    /// rayon pool): `geometry(i, out)` writes the new geometry of `ids[i]`
    /// into `out`. The same BLASes as refitting them one by one; on an
    /// error (a stale or repeated id, a failed refit) the first error in
    /// `ids` order, and the BLASes refit before it stay refit.
    pub fn refit_many<F>(&mut self, ids: &[BvhBlasId], geometry: F) -> Result<(), SimError>
    where
        F: Fn(usize, &mut LodTriangles) -> Result<(), SimError> + Sync,
    {
        use rayon::prelude::*;
        // Which of `ids` each store slot takes (disjoint mutable borrows).
        let mut job = vec![u32::MAX; self.slots.len()];
        for (i, id) in ids.iter().enumerate() {
            self.get(*id)?;
            let j = &mut job[id.index as usize];
            if *j != u32::MAX {
                return Err(SimError::BadConfig("a BLAS refit twice in one batch"));
            }
            *j = i as u32;
        }
        let done: Vec<(u32, Result<u64, SimError>)> = self
            .slots
            .par_iter_mut()
            .zip(job.par_iter())
            .filter(|(_, &i)| i != u32::MAX)
            .map_init(LodTriangles::default, |geom, ((_, blas), &i)| {
                let r = match blas {
                    Some(blas) => geometry(i as usize, geom)
                        .and_then(|()| blas.refit(geom))
                        .map(|()| geom.len() as u64),
                    None => Err(SimError::StaleBlas),
                };
                (i, r)
            })
            .collect();
        let mut first: Option<(u32, SimError)> = None;
        for (i, r) in done {
            match r {
                Ok(triangles) => {
                    self.stats.refits += 1;
                    self.stats.primitives_refit += triangles;
                }
                Err(e) => {
                    if first.as_ref().is_none_or(|(j, _)| i < *j) {
                        first = Some((i, e));
                    }
                }
            }
        }
        match first {
            Some((_, e)) => Err(e),
            None => Ok(()),
        }
    }
    /// Frees `id`; the handle becomes stale. The unit cube cannot be removed.
    pub fn remove(&mut self, id: BvhBlasId) -> Result<(), SimError> {
        if id == self.unit_cube() {
            return Err(SimError::BadConfig("the unit cube BLAS is static"));
        }
        self.get(id)?;
        self.slots[id.index as usize].1 = None;
        self.free.push(id.index);
        Ok(())
    }
    /// Number of live BLASes (including the unit cube).
    pub fn len(&self) -> usize {
        self.slots.iter().filter(|s| s.1.is_some()).count()
    }
    /// Whether no BLAS is live (never true: the unit cube is static).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Approximate memory of all live BLASes, bytes.
    pub fn memory_bytes(&self) -> usize {
        self.slots
            .iter()
            .filter_map(|s| s.1.as_ref())
            .map(BvhBlas::memory_bytes)
            .sum()
    }
    /// Work counted since creation or the last [`Self::reset_stats`].
    pub fn stats(&self) -> BuildStats {
        self.stats
    }
    /// Zeroes the work counters.
    pub fn reset_stats(&mut self) {
        self.stats = BuildStats::default();
    }
}

#[cfg(test)]
mod tests;
