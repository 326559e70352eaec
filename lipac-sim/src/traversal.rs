//! Two-level ray traversal: closest hit over a [`CpuTlas`] with masks,
//! alpha-tested vegetation and pass-through counting boxes; an any-hit
//! occlusion query; and the hit counters.
//!
//! # Counting boxes
//!
//! The paper gives counting boxes a closest-hit shader that counts the hit
//! and *continues* the ray along its direction, masking all counting boxes
//! out after the first one, so a ray counts at most one box and boxes never
//! occlude. With boxes masked out after the first, the continued ray finds
//! exactly the closest real hit of the whole segment. So the outcome of the
//! continue-trace loop is:
//!
//! * the closest real hit `t_hit` over the segment (boxes ignored), and
//! * the *nearest* box whose entry `t_box <= t_hit` (it is the first thing
//!   the ray meets), or no box when the nearest box lies beyond the real hit
//!   (occluded boxes do not count).
//!
//! Closest hits at exactly the same distance in two instances (coplanar
//! faces) go to the lower custom index, so the hit of a ray depends only on
//! the set of records in the TLAS, never on their order or on the BVH built
//! over them: a strategy tracing a subset that holds the ground truth's hit
//! instance finds the same hit (the oracle's error is exactly 0).
//!
//! [`trace`] computes exactly that in **one** traversal: real hits shrink
//! the ray's `tmax` as usual; boxes never shrink it and only update the
//! nearest box entry; at the end the box counts if `t_box <= t_hit`. Boxes
//! beyond the current `tmax` are culled by the TLAS nodes, which is safe
//! because they could not count anyway. A ray starting inside a box enters
//! it at `tmin` (and so counts it, as the AABB intersection shader reporting
//! `max(tmin, t_entry)` does).
//!
//! # Shadow rays
//!
//! "Shadow rays must also continue through boxes": a box never occludes.
//! We trace shadow rays with [`trace`] too, so they count the first box they
//! meet before any occluder with the same rule; [`TraceResult::hit`] tells
//! whether the light is blocked. Whether real hits of shadow rays count is
//! the caller's choice (the path tracer does not count them, as a shadow ray
//! with `SkipClosestHitShader` would not). [`occluded`] and [`occluded_by`]
//! are cheaper any-hit queries that ignore boxes entirely, for tests that
//! must not count (the rasterized-shadow fallback, or a TLAS without boxes).

use glam::{UVec2, Vec3, Vec3A};
use obvhs::cwbvh::Traversal;
use obvhs::ray::Ray as BvhRay;
use obvhs::traverse;

use crate::blas::{BlasStore, BvhBlas};
use crate::error::SimError;
use crate::mesh::leaf_opaque;
use crate::tlas::{CpuTlas, EntryKind};
use lipac_core::layout::TlasInstance;

pub use crate::tlas::{masks, CountingBoxes};

/// A ray segment `origin + t * direction`, `t` in `[tmin, tmax]`, with an
/// 8-bit mask matched against instance masks (`ray.mask & inst.mask != 0`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub(crate) origin: Vec3A,
    pub(crate) direction: Vec3A,
    pub(crate) tmin: f32,
    pub(crate) tmax: f32,
    pub(crate) mask: u8,
}

impl Ray {
    /// A validated ray: finite origin and direction, non-zero direction,
    /// `0 <= tmin <= tmax` (`tmax` may be infinite), no NaN.
    pub fn new(
        origin: Vec3,
        direction: Vec3,
        tmin: f32,
        tmax: f32,
        mask: u8,
    ) -> Result<Self, SimError> {
        if !origin.is_finite() || !direction.is_finite() {
            return Err(SimError::NonFinite("ray origin and direction"));
        }
        if direction.length_squared() == 0.0 || !direction.length_squared().is_normal() {
            return Err(SimError::BadConfig("ray direction must be non-zero"));
        }
        if tmin.is_nan() || tmax.is_nan() || !tmin.is_finite() || tmin < 0.0 || tmax < tmin {
            return Err(SimError::BadConfig("ray needs 0 <= tmin <= tmax, no NaN"));
        }
        Ok(Self::unchecked(
            origin.into(),
            direction.into(),
            tmin,
            tmax,
            mask,
        ))
    }
    pub(crate) fn unchecked(
        origin: Vec3A,
        direction: Vec3A,
        tmin: f32,
        tmax: f32,
        mask: u8,
    ) -> Self {
        Self {
            origin,
            direction,
            tmin,
            tmax,
            mask,
        }
    }
    /// Origin.
    pub fn origin(&self) -> Vec3 {
        self.origin.into()
    }
    /// Direction (not necessarily normalized; `t` is in its units).
    pub fn direction(&self) -> Vec3 {
        self.direction.into()
    }
    /// Segment start.
    pub fn tmin(&self) -> f32 {
        self.tmin
    }
    /// Segment end.
    pub fn tmax(&self) -> f32 {
        self.tmax
    }
    /// Ray mask.
    pub fn mask(&self) -> u8 {
        self.mask
    }
    /// The same ray with another mask.
    pub fn with_mask(mut self, mask: u8) -> Self {
        self.mask = mask;
        self
    }
}

/// The closest real hit of a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the ray (in units of its direction).
    pub t: f32,
    /// Custom index of the TLAS record that was hit.
    pub custom_index: u32,
    /// Index of that record in the slice the TLAS was built from.
    pub record: u32,
    /// Triangle index in the BLAS's input geometry.
    pub primitive: u32,
    /// Material byte of the triangle.
    pub material: u8,
    /// Unit geometric normal in world space (not oriented to the ray).
    pub normal: Vec3,
}

/// Which counter a counting box feeds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BoxKind {
    /// The box of an omitted instance: instance counter.
    Instance,
    /// An inactive hitbox: hitbox counter.
    Hitbox,
}

/// A counting box a ray passed through before its closest hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoxHit {
    /// Which counter it feeds.
    pub kind: BoxKind,
    /// The counter's index: the box record's custom index (instance slot
    /// or hitbox index), or for a merged box the leaf hitbox whose box the
    /// ray entered.
    pub custom_index: u32,
    /// Index of the record in the TLAS input slice.
    pub record: u32,
    /// Entry distance (`tmin` when the ray started inside).
    pub t: f32,
}

/// Outcome of [`trace`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TraceResult {
    /// The closest real hit, if any.
    pub hit: Option<Hit>,
    /// The counting box the ray met first, if it met one before the hit.
    pub counted_box: Option<BoxHit>,
}

/// A set of custom indices (bit set), e.g. the instance slots whose
/// geometry is in the traced TLAS.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SlotSet {
    bits: Vec<u64>,
}

impl SlotSet {
    /// An empty set.
    pub fn new() -> Self {
        Self::default()
    }
    /// Adds `slot`.
    pub fn insert(&mut self, slot: u32) {
        let w = (slot / 64) as usize;
        if w >= self.bits.len() {
            self.bits.resize(w + 1, 0);
        }
        self.bits[w] |= 1 << (slot % 64);
    }
    /// Whether `slot` is in.
    #[inline]
    pub fn contains(&self, slot: u32) -> bool {
        self.bits
            .get((slot / 64) as usize)
            .is_some_and(|w| w & (1 << (slot % 64)) != 0)
    }
    /// Empties it.
    pub fn clear(&mut self) {
        self.bits.iter_mut().for_each(|w| *w = 0);
    }
    /// Number of slots in the set.
    pub fn len(&self) -> usize {
        self.bits.iter().map(|w| w.count_ones() as usize).sum()
    }
    /// Whether it is empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Custom indices of the real-geometry records (active, non-box) in
    /// `records`: the instances a TLAS built from them traces.
    pub fn from_geometry_records(records: &[TlasInstance], counting: &CountingBoxes) -> Self {
        let mut s = Self::new();
        for r in records {
            let sbt = r.sbt_offset();
            if r.acceleration_structure_reference != 0 && r.mask() != 0 && !counting.is_box(sbt) {
                s.insert(r.custom_index());
            }
        }
        s
    }
}

/// Closest hit in one BLAS; alpha-tested triangles are skipped where
/// [`leaf_opaque`] says transparent (the any-hit test), unless `force_opaque`.
#[inline]
fn blas_closest(
    blas: &BvhBlas,
    ray: &BvhRay,
    force_opaque: bool,
    state: &mut Traversal,
) -> Option<(f32, usize)> {
    let mut r = *ray;
    let mut best = None;
    if blas.bvh.nodes.is_empty() {
        return None;
    }
    let alpha = blas.any_alpha && !force_opaque;
    state.reinit(r.direction);
    let mut node;
    traverse!(
        blas.bvh,
        node,
        state,
        node.intersect_ray(&r, state.oct_inv4),
        {
            let p = state.primitive_id as usize;
            let t = blas.tris[p].intersect(&r);
            if t < r.tmax
                && (!alpha || !blas.alpha[p] || leaf_opaque((r.origin + r.direction * t).into()))
            {
                r.tmax = t;
                best = Some(p);
            }
        }
    );
    best.map(|p| (r.tmax, p))
}

/// Whether anything opaque lies in one BLAS along the ray.
#[inline]
fn blas_any(blas: &BvhBlas, r: &BvhRay, force_opaque: bool, state: &mut Traversal) -> bool {
    if blas.bvh.nodes.is_empty() {
        return false;
    }
    let alpha = blas.any_alpha && !force_opaque;
    state.reinit(r.direction);
    let mut node;
    let mut found = false;
    'outer: {
        traverse!(
            blas.bvh,
            node,
            state,
            node.intersect_ray(r, state.oct_inv4),
            {
                let p = state.primitive_id as usize;
                let t = blas.tris[p].intersect(r);
                if t < f32::INFINITY
                    && (!alpha
                        || !blas.alpha[p]
                        || leaf_opaque((r.origin + r.direction * t).into()))
                {
                    found = true;
                    break 'outer;
                }
            }
        );
    }
    found
}

/// The next `f32` above `t >= 0` (`t` itself if infinite): searching up to
/// it finds hits at exactly `t` (`f32::next_up` needs Rust 1.86).
#[inline]
fn next_up(t: f32) -> f32 {
    if t.is_finite() {
        f32::from_bits(t.to_bits() + 1)
    } else {
        t
    }
}

/// Entry distance of a ray into a box, clipped to `[tmin, tmax]`; infinity
/// on a miss.
#[inline]
fn box_entry(min: Vec3A, max: Vec3A, r: &BvhRay) -> f32 {
    let t1 = (min - r.origin) * r.inv_direction;
    let t2 = (max - r.origin) * r.inv_direction;
    let near = t1.min(t2).max_element().max(r.tmin);
    let far = t1.max(t2).min_element().min(r.tmax);
    if near <= far {
        near
    } else {
        f32::INFINITY
    }
}

/// Closest hit with pass-through counting boxes (see the module docs).
///
/// `skip`: custom indices to ignore (e.g. instances handled elsewhere).
pub fn trace(tlas: &CpuTlas, store: &BlasStore, ray: &Ray, skip: Option<&SlotSet>) -> TraceResult {
    let (o, d) = (ray.origin, ray.direction);
    let mut tray = BvhRay::new(o, d, ray.tmin, ray.tmax);
    let mut best: Option<(usize, usize)> = None;
    // (entry, entry distance, leaf hitbox for a merged box)
    let mut best_box: Option<(usize, f32, u32)> = None;
    let mut blas_state = Traversal::default();
    let mut state = tlas.bvh.new_traversal(d);
    let mut node;
    traverse!(
        tlas.bvh,
        node,
        state,
        node.intersect_ray(&tray, state.oct_inv4),
        {
            let ei = state.primitive_id as usize;
            let e = &tlas.entries[ei];
            if e.mask & ray.mask != 0 && skip.is_none_or(|s| !s.contains(e.custom_index)) {
                if let Some(blas) = store.slot(e.blas) {
                    let geometry = e.kind == EntryKind::Geometry;
                    // Geometry is searched up to and including the best hit
                    // so far, so that a tie can go to the lower custom index.
                    let lray = BvhRay::new(
                        e.world_to_object.transform_point3a(o),
                        e.world_to_object.transform_vector3a(d),
                        tray.tmin,
                        if geometry {
                            next_up(tray.tmax)
                        } else {
                            tray.tmax
                        },
                    );
                    if geometry {
                        if let Some((t, p)) =
                            blas_closest(blas, &lray, e.opacity == 1, &mut blas_state)
                        {
                            // Ties between instances go to the lower custom
                            // index: the hit depends on the set of records,
                            // not on their order or the TLAS built over them.
                            let wins = t < tray.tmax
                                || (t == tray.tmax
                                    && best.is_some_and(|(b, _)| {
                                        e.custom_index < tlas.entries[b].custom_index
                                    }));
                            if wins {
                                tray.tmax = t;
                                best = Some((ei, p));
                            }
                        }
                    } else if e.kind == EntryKind::MergedBox {
                        // The nearest leaf box the ray enters, each tested
                        // as its own entry would be (same inverse, same
                        // arithmetic): the count of the leaf-only TLAS.
                        let (min, max) = (blas.bounds.min.into(), blas.bounds.max.into());
                        let leaves = &tlas.merged_leaves[e.leaves.0 as usize..e.leaves.1 as usize];
                        for (leaf, w2o) in leaves {
                            let leaf_ray = BvhRay::new(
                                w2o.transform_point3a(o),
                                w2o.transform_vector3a(d),
                                tray.tmin,
                                tray.tmax,
                            );
                            let t = box_entry(min, max, &leaf_ray);
                            if t < best_box.map_or(f32::INFINITY, |b| b.1) {
                                best_box = Some((ei, t, *leaf));
                            }
                        }
                    } else {
                        let t = box_entry(blas.bounds.min.into(), blas.bounds.max.into(), &lray);
                        if t < best_box.map_or(f32::INFINITY, |b| b.1) {
                            best_box = Some((ei, t, e.custom_index));
                        }
                    }
                }
            }
        }
    );
    let hit = best.and_then(|(ei, p)| {
        let e = &tlas.entries[ei];
        let blas = store.slot(e.blas)?;
        let n_obj = blas.tris[p].compute_normal();
        let n = (e.world_to_object.matrix3.transpose() * n_obj).normalize_or_zero();
        Some(Hit {
            t: tray.tmax,
            custom_index: e.custom_index,
            record: e.record,
            primitive: blas.prim[p],
            material: blas.material[p],
            normal: n.into(),
        })
    });
    let t_hit = hit.map_or(f32::INFINITY, |h| h.t);
    let counted_box = best_box.filter(|b| b.1 <= t_hit).map(|(ei, t, index)| {
        let e = &tlas.entries[ei];
        BoxHit {
            kind: if e.kind == EntryKind::InstanceBox {
                BoxKind::Instance
            } else {
                BoxKind::Hitbox
            },
            custom_index: index,
            record: e.record,
            t,
        }
    });
    TraceResult { hit, counted_box }
}

/// Any-hit occlusion: whether real geometry (not boxes) blocks the segment.
/// Counts nothing.
pub fn occluded(tlas: &CpuTlas, store: &BlasStore, ray: &Ray, skip: Option<&SlotSet>) -> bool {
    let mask = ray.mask;
    occluded_by(tlas, store, ray, |custom, m| {
        m & mask != 0 && skip.is_none_or(|s| !s.contains(custom))
    })
}

/// Any-hit occlusion over the real-geometry entries that `keep(custom
/// index, mask)` accepts (the ray's own mask is not applied).
pub fn occluded_by(
    tlas: &CpuTlas,
    store: &BlasStore,
    ray: &Ray,
    keep: impl Fn(u32, u8) -> bool,
) -> bool {
    let (o, d) = (ray.origin, ray.direction);
    let tray = BvhRay::new(o, d, ray.tmin, ray.tmax);
    let mut blas_state = Traversal::default();
    let mut state = tlas.bvh.new_traversal(d);
    let mut node;
    let mut found = false;
    'outer: {
        traverse!(
            tlas.bvh,
            node,
            state,
            node.intersect_ray(&tray, state.oct_inv4),
            {
                let e = &tlas.entries[state.primitive_id as usize];
                if e.kind == EntryKind::Geometry && keep(e.custom_index, e.mask) {
                    if let Some(blas) = store.slot(e.blas) {
                        let lray = BvhRay::new(
                            e.world_to_object.transform_point3a(o),
                            e.world_to_object.transform_vector3a(d),
                            tray.tmin,
                            tray.tmax,
                        );
                        if blas_any(blas, &lray, e.opacity == 1, &mut blas_state) {
                            found = true;
                            break 'outer;
                        }
                    }
                }
            }
        );
    }
    found
}

/// Saturating hit counters indexed by custom index.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    /// Per instance slot: real hits plus omitted-instance box hits.
    pub instances: Vec<u32>,
    /// Per hitbox: inactive-hitbox box hits.
    pub hitboxes: Vec<u32>,
    /// Counts whose index was outside the vectors (dropped).
    pub dropped: u64,
}

impl Counters {
    /// Zeroed counters for `instances` slots and `hitboxes` hitboxes.
    pub fn new(instances: usize, hitboxes: usize) -> Self {
        Self {
            instances: vec![0; instances],
            hitboxes: vec![0; hitboxes],
            dropped: 0,
        }
    }
    /// Adds one to instance `slot`.
    #[inline]
    pub fn count_instance(&mut self, slot: u32) {
        match self.instances.get_mut(slot as usize) {
            Some(c) => *c = c.saturating_add(1),
            None => self.dropped += 1,
        }
    }
    /// Adds one to hitbox `index`.
    #[inline]
    pub fn count_hitbox(&mut self, index: u32) {
        match self.hitboxes.get_mut(index as usize) {
            Some(c) => *c = c.saturating_add(1),
            None => self.dropped += 1,
        }
    }
    /// Counts a box into the counter its kind names.
    #[inline]
    pub fn count_box(&mut self, b: &BoxHit) {
        match b.kind {
            BoxKind::Instance => self.count_instance(b.custom_index),
            BoxKind::Hitbox => self.count_hitbox(b.custom_index),
        }
    }
    /// Adds `other` (saturating; sizes grow to the larger).
    pub fn merge(&mut self, other: &Counters) {
        merge_vec(&mut self.instances, &other.instances);
        merge_vec(&mut self.hitboxes, &other.hitboxes);
        self.dropped += other.dropped;
    }
    /// Zeroes all counters (keeps the sizes).
    pub fn clear(&mut self) {
        self.instances.iter_mut().for_each(|c| *c = 0);
        self.hitboxes.iter_mut().for_each(|c| *c = 0);
        self.dropped = 0;
    }
    /// Sum of all instance counters.
    pub fn instance_total(&self) -> u64 {
        self.instances.iter().map(|&c| u64::from(c)).sum()
    }
    /// Sum of all hitbox counters.
    pub fn hitbox_total(&self) -> u64 {
        self.hitboxes.iter().map(|&c| u64::from(c)).sum()
    }
}

fn merge_vec(a: &mut Vec<u32>, b: &[u32]) {
    if a.len() < b.len() {
        a.resize(b.len(), 0);
    }
    for (x, y) in a.iter_mut().zip(b) {
        *x = x.saturating_add(*y);
    }
}
