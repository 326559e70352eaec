//! The in-memory form of a trace: header, frames, events, and the checks
//! every reader and writer applies to them.

use super::error::TraceErrorKind;
use crate::grid::{GridConfig, HitboxGrid, DEFAULT_MAX_GRID_CELLS};
use crate::instance::{InstanceDesc, InstanceFlags, MeshId};
use crate::math::{rows_to_affine, Aabb};
use glam::{Mat3, Quat, Vec3};
use std::collections::HashMap;

/// Bounds on what a reader accepts (and a writer produces), so that no
/// untrusted count or length can make it allocate or loop without bound.
///
/// Besides these limits, a binary reader caps every count by the bytes left
/// in its length-prefixed record.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TraceLimits {
    /// Largest header record in bytes (binary) or header line (JSON).
    /// Default 1 GiB (geometry lives in the header).
    pub max_header_bytes: u64,
    /// Largest frame record in bytes (binary) or frame line (JSON).
    /// Default 256 MiB.
    pub max_frame_bytes: u32,
    /// JSON lines: a frame line of up to this many bytes is read whole and
    /// parsed from memory; a longer one is parsed as it is read after its
    /// first this many bytes (several times slower per byte, but a line
    /// never costs more than this plus what was parsed of it). Default
    /// 16 MiB.
    pub max_buffered_line_bytes: u32,
    /// Largest scene name in bytes. Default 4096.
    pub max_scene_name_bytes: u32,
    /// Most meshes in the header. Default 2^20.
    pub max_meshes: u32,
    /// Most LODs per mesh. Default 32.
    pub max_lods: u32,
    /// Most vertices in one LOD's geometry. Default 2^26.
    pub max_vertices_per_lod: u32,
    /// Most triangles in one LOD. Default 2^26.
    pub max_triangles_per_lod: u32,
    /// Most instance events in one frame. Default 2^22.
    pub max_events_per_frame: u32,
    /// Most hit counts in one frame. Default 2^24.
    pub max_hits_per_frame: u32,
    /// Most instances live at once. Default 2^24
    /// ([`MAX_SLOTS`](crate::layout::MAX_SLOTS)).
    pub max_live_instances: u32,
    /// Largest AABB extent per axis, metres (as
    /// [`RegistryConfig::max_aabb_extent`](crate::registry::RegistryConfig::max_aabb_extent)).
    /// Default 1e6.
    pub max_aabb_extent: f32,
    /// Most cells in the header's world grid (replay allocates state per
    /// cell: 12 bytes of hitbox record and more per LiPaC strategy).
    /// Default [`DEFAULT_MAX_GRID_CELLS`] = 2^24 (a 4096 × 4096 grid).
    pub max_grid_cells: u64,
}

impl Default for TraceLimits {
    fn default() -> Self {
        Self {
            max_header_bytes: 1 << 30,
            max_frame_bytes: 256 << 20,
            max_buffered_line_bytes: 16 << 20,
            max_scene_name_bytes: 4096,
            max_meshes: 1 << 20,
            max_lods: 32,
            max_vertices_per_lod: 1 << 26,
            max_triangles_per_lod: 1 << 26,
            max_events_per_frame: 1 << 22,
            max_hits_per_frame: 1 << 24,
            max_live_instances: crate::layout::MAX_SLOTS,
            max_aabb_extent: 1.0e6,
            max_grid_cells: DEFAULT_MAX_GRID_CELLS,
        }
    }
}

/// Everything a trace says once, before its frames.
#[derive(Clone, Debug, PartialEq)]
pub struct TraceHeader {
    /// Free-form scene name (UTF-8).
    pub scene_name: String,
    /// Hitbox grid of the world.
    pub world: WorldInfo,
    /// The meshes instances may use; ids are unique.
    pub meshes: Vec<MeshInfo>,
}

/// The world's hitbox grid, as a [`GridConfig`] (x/z in metres), or an
/// unbounded world ([`WorldInfo::unbounded`]: no bounds declared, `min`
/// all `-inf` and `max` all `+inf`; replay then uses the sparse
/// [`HashedHitboxes`](crate::hashed_hitboxes::HashedHitboxes) with cells
/// anchored at the origin, [`WorldInfo::hashed_config`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorldInfo {
    /// Minimum world corner `[x, z]`.
    pub min: [f64; 2],
    /// Maximum world corner `[x, z]`.
    pub max: [f64; 2],
    /// Edge length of the square hitbox cells.
    pub cell_size: f64,
}

impl WorldInfo {
    /// A world without declared bounds: cells of `cell_size` anchored at the
    /// origin, as many as the instances occupy.
    pub fn unbounded(cell_size: f64) -> Self {
        Self {
            min: [f64::NEG_INFINITY; 2],
            max: [f64::INFINITY; 2],
            cell_size,
        }
    }

    /// Whether the world declares its bounds (else it is
    /// [`WorldInfo::unbounded`]).
    pub fn is_bounded(&self) -> bool {
        !(self.min == [f64::NEG_INFINITY; 2] && self.max == [f64::INFINITY; 2])
    }

    /// The sparse hashed index's settings for this world's cells: anchored
    /// at `min` (the origin for an unbounded world), so that a bounded
    /// world's cells are the grid's.
    pub fn hashed_config(&self) -> crate::hashed_hitboxes::HashedConfig {
        crate::hashed_hitboxes::HashedConfig {
            origin: if self.is_bounded() {
                self.min
            } else {
                [0.0, 0.0]
            },
            cell_size: self.cell_size,
            ..crate::hashed_hitboxes::HashedConfig::default()
        }
    }

    /// The grid configuration this describes (not a valid grid for an
    /// unbounded world).
    pub fn grid_config(&self) -> GridConfig {
        GridConfig {
            min: self.min,
            max: self.max,
            cell_size: self.cell_size,
        }
    }
}

impl From<GridConfig> for WorldInfo {
    fn from(g: GridConfig) -> Self {
        Self {
            min: g.min,
            max: g.max,
            cell_size: g.cell_size,
        }
    }
}

/// One mesh of the scene.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshInfo {
    /// The engine's mesh id (unique within the header).
    pub id: MeshId,
    /// Bounds of the mesh in its own (object) space, over all LODs.
    pub bounds: Aabb,
    /// Its levels of detail, finest first; at least one.
    pub lods: Vec<LodInfo>,
}

/// One level of detail of a mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct LodInfo {
    /// Triangle count (what BLAS build budgets are charged).
    pub triangles: u32,
    /// Optional triangle geometry in object space.
    pub geometry: Option<LodGeometry>,
}

/// Indexed triangle geometry of one LOD.
#[derive(Clone, Debug, PartialEq)]
pub struct LodGeometry {
    /// Vertex positions (finite).
    pub positions: Vec<[f32; 3]>,
    /// Three vertex indices per triangle; `indices.len() == 3 * triangles`
    /// and every index `< positions.len()`.
    pub indices: Vec<u32>,
}

/// One recorded frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// The engine's frame number; strictly increasing through a trace (gaps
    /// allowed).
    pub number: u64,
    /// The camera this frame was rendered from.
    pub camera: Camera,
    /// Instance changes, applied in order before the frame is rendered.
    pub events: Vec<InstanceEvent>,
    /// The engine's own hit counts per instance this frame (after the
    /// events), for replay through the state machine only; `None` when the
    /// engine did not record them.
    ///
    /// With [`Frame::slot_hits`] (version 2) this is what readers derive
    /// from it (own hits by slot, counting-box hits split over their
    /// instances, `docs/trace-format.md`); writers then encode `slot_hits`
    /// and ignore this field.
    pub hits: Option<Vec<InstanceHits>>,
    /// Version 2: the hit counts in the compact form the Manager's
    /// recorder writes (per slot, plus counting boxes per hitbox); `None`
    /// for traces that list [`Frame::hits`] by id (or have none).
    pub slot_hits: Option<SlotHits>,
}

/// A frame's hit counts by slot (trace format version 2): what a
/// renderer's hit buffers hold, written without a per-instance pass.
///
/// Instances are named by the slot of their `add` ([`AddInstance::slot`]).
/// `slots[s]` is the hits of the instance in slot `s` (0 past the end); a
/// non-zero entry needs a live instance in that slot. `boxes` are the hits
/// of counting boxes of the header's world grid (bounded worlds only), in
/// increasing hitbox order, each hitbox at most once: a reader splits a
/// box's hits evenly over the live instances in that hitbox (AABB centre)
/// that are not pinned and have no hits of their own, in slot order, the
/// first `hits % k` of the `k` taking one more.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SlotHits {
    /// Hits per slot (index = slot).
    pub slots: Vec<u32>,
    /// Counting-box hits per hitbox, by increasing hitbox index.
    pub boxes: Vec<BoxHits>,
}

/// The hits of one hitbox's counting box ([`SlotHits::boxes`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BoxHits {
    /// Hitbox index in the header's world grid (`cx + cz * columns`,
    /// [`HitboxGrid::index`]).
    pub hitbox: u32,
    /// Hits of its counting box.
    pub hits: u32,
}

/// A pinhole camera. It looks along its local `-Z` with `+Y` up
/// (right-handed); `orientation` rotates local into world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position in world space.
    pub position: Vec3,
    /// Local-to-world rotation, unit length (within 1e-3).
    pub orientation: Quat,
    /// Vertical field of view in radians, in `(0, π)`.
    pub vertical_fov: f32,
    /// Width / height, `> 0`.
    pub aspect: f32,
}

impl Camera {
    /// A camera at `position` looking along `forward` with `up` roughly up.
    /// `forward` and `up` need not be unit length but must not be parallel
    /// (then the orientation is not finite and the camera fails validation).
    pub fn look_to(
        position: Vec3,
        forward: Vec3,
        up: Vec3,
        vertical_fov: f32,
        aspect: f32,
    ) -> Self {
        let back = -forward.normalize_or_zero();
        let right = up.cross(back).normalize_or_zero();
        let up = back.cross(right);
        let orientation = Quat::from_mat3(&Mat3::from_cols(right, up, back));
        Self {
            position,
            orientation,
            vertical_fov,
            aspect,
        }
    }
    /// World-space view direction.
    pub fn forward(&self) -> Vec3 {
        self.orientation * Vec3::NEG_Z
    }
    /// World-space up direction.
    pub fn up(&self) -> Vec3 {
        self.orientation * Vec3::Y
    }
}

/// A change to the set of instances. Instances are named by the engine's
/// own id (a `u32` engine id widens losslessly).
#[derive(Clone, Debug, PartialEq)]
pub enum InstanceEvent {
    /// A new instance.
    Add(AddInstance),
    /// A change to a live instance.
    Update(UpdateInstance),
    /// A live instance goes away.
    Remove {
        /// The engine's instance id.
        id: u64,
    },
}

impl InstanceEvent {
    /// The instance the event is about.
    pub fn id(&self) -> u64 {
        match self {
            Self::Add(a) => a.id,
            Self::Update(u) => u.id,
            Self::Remove { id } => *id,
        }
    }
}

/// Transform and world bounds of an instance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Object-to-world transform, row-major 3x4 (`VkTransformMatrixKHR`,
    /// see [`crate::math::affine_to_rows`]); finite.
    pub transform: [f32; 12],
    /// World-space bounds; finite, `min <= max`.
    pub aabb: Aabb,
}

/// An `add` event.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AddInstance {
    /// The engine's instance id; must not be live.
    pub id: u64,
    /// Its mesh (declared in the header).
    pub mesh: MeshId,
    /// Its LOD (below the mesh's LOD count).
    pub lod: u32,
    /// Instance flags.
    pub flags: InstanceFlags,
    /// TLAS visibility mask; `None` means the default `0xFF`.
    pub mask: Option<u8>,
    /// Transform and bounds.
    pub pose: Pose,
    /// Version 2: the instance's slot (the index of its hits in
    /// [`SlotHits::slots`]), below [`TraceLimits::max_live_instances`] and
    /// not held by another live instance; `None`: the instance has no slot
    /// (its hits can only be listed by id).
    pub slot: Option<u32>,
}

impl AddInstance {
    /// The registry description of this instance (SBT offset and Vulkan
    /// instance flags 0, mask `0xFF` unless given).
    pub fn desc(&self) -> InstanceDesc {
        InstanceDesc {
            lod: self.lod,
            flags: self.flags,
            mask: self.mask.unwrap_or(0xFF),
            ..InstanceDesc::new(
                self.mesh,
                rows_to_affine(&self.pose.transform),
                self.pose.aabb,
            )
        }
    }
}

/// An `update` event: each `Some` field replaces the instance's value.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UpdateInstance {
    /// The engine's instance id; must be live.
    pub id: u64,
    /// New transform and bounds.
    pub pose: Option<Pose>,
    /// New LOD (below the LOD count of the instance's mesh).
    pub lod: Option<u32>,
    /// New flags.
    pub flags: Option<InstanceFlags>,
    /// New visibility mask.
    pub mask: Option<u8>,
}

/// The engine's hit count of one instance in one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InstanceHits {
    /// The engine's instance id; must be live after the frame's events.
    pub id: u64,
    /// Light-path hits counted.
    pub hits: u32,
}

// ---------------------------------------------------------------------------
// Checks shared by every reader and writer. They return the kind only; the
// caller knows the location.

pub(crate) fn check_finite(what: impl FnOnce() -> String, v: f32) -> Result<(), TraceErrorKind> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(TraceErrorKind::NonFinite {
            what: what(),
            value: f64::from(v),
        })
    }
}

pub(crate) fn check_aabb(
    what: &'static str,
    aabb: &Aabb,
    max_extent: f32,
) -> Result<(), TraceErrorKind> {
    let (lo, hi) = (aabb.min.to_array(), aabb.max.to_array());
    let fail = |reason: String| {
        Err(TraceErrorKind::InvalidAabb {
            what,
            min: lo,
            max: hi,
            reason,
        })
    };
    if !aabb.min.is_finite() || !aabb.max.is_finite() {
        return fail("corners must be finite".into());
    }
    for (axis, name) in ["x", "y", "z"].into_iter().enumerate() {
        if lo[axis] > hi[axis] {
            return fail(format!(
                "inverted: min.{name} = {} > max.{name} = {}",
                lo[axis], hi[axis]
            ));
        }
        let extent = hi[axis] - lo[axis];
        if extent.is_nan() || extent > max_extent {
            return fail(format!(
                "extent along {name} is {extent}, more than the limit {max_extent}"
            ));
        }
    }
    Ok(())
}

pub(crate) fn check_pose(pose: &Pose, limits: &TraceLimits) -> Result<(), TraceErrorKind> {
    // Fast path (every recorded move): all finite, box not inverted and
    // within the extent limit; the element-wise checks below name a fault.
    let (lo, hi) = (pose.aabb.min, pose.aabb.max);
    let extent = hi - lo;
    if pose.transform.iter().all(|v| v.is_finite())
        && lo.is_finite()
        && hi.is_finite()
        && lo.cmple(hi).all()
        && extent.cmple(Vec3::splat(limits.max_aabb_extent)).all()
    {
        return Ok(());
    }
    for (i, v) in pose.transform.iter().enumerate() {
        check_finite(
            || format!("transform element {i} (row {}, column {})", i / 4, i % 4),
            *v,
        )?;
    }
    check_aabb("instance AABB", &pose.aabb, limits.max_aabb_extent)
}

pub(crate) fn check_flags(bits: u32) -> Result<InstanceFlags, TraceErrorKind> {
    InstanceFlags::from_bits(bits).ok_or(TraceErrorKind::InvalidTag {
        what: "instance flags (undefined bits set)",
        value: bits.into(),
    })
}

pub(crate) fn check_camera(c: &Camera) -> Result<(), TraceErrorKind> {
    for (i, v) in c.position.to_array().into_iter().enumerate() {
        check_finite(|| format!("camera position[{i}]"), v)?;
    }
    for (i, v) in c.orientation.to_array().into_iter().enumerate() {
        check_finite(|| format!("camera orientation[{i}]"), v)?;
    }
    let len2 = c.orientation.length_squared();
    if (len2 - 1.0).abs() > 2.0e-3 {
        return Err(TraceErrorKind::InvalidValue {
            what: "camera orientation".into(),
            reason: format!("quaternion has length {}, must be 1", len2.sqrt()),
        });
    }
    check_finite(|| "camera vertical_fov".into(), c.vertical_fov)?;
    if !(c.vertical_fov > 0.0 && c.vertical_fov < std::f32::consts::PI) {
        return Err(TraceErrorKind::InvalidValue {
            what: "camera vertical_fov".into(),
            reason: format!("{} rad is outside (0, pi)", c.vertical_fov),
        });
    }
    check_finite(|| "camera aspect".into(), c.aspect)?;
    if c.aspect <= 0.0 {
        return Err(TraceErrorKind::InvalidValue {
            what: "camera aspect".into(),
            reason: format!("{} must be > 0", c.aspect),
        });
    }
    Ok(())
}

pub(crate) fn check_world(w: &WorldInfo, limits: &TraceLimits) -> Result<(), TraceErrorKind> {
    if !w.is_bounded() {
        return crate::hashed_hitboxes::HashedHitboxes::new(w.hashed_config())
            .map(|_| ())
            .map_err(|e| TraceErrorKind::InvalidValue {
                what: "unbounded world".into(),
                reason: e.to_string(),
            });
    }
    HitboxGrid::with_max_cells(w.grid_config(), limits.max_grid_cells)
        .map(|_| ())
        .map_err(|e| TraceErrorKind::InvalidValue {
            what: "world grid".into(),
            reason: e.to_string(),
        })
}

fn limit(what: &'static str, value: u64, limit: u32) -> Result<(), TraceErrorKind> {
    if value > u64::from(limit) {
        Err(TraceErrorKind::LimitExceeded {
            what,
            value,
            limit: limit.into(),
        })
    } else {
        Ok(())
    }
}

pub(crate) fn check_scene_name(len: u64, limits: &TraceLimits) -> Result<(), TraceErrorKind> {
    limit("scene name bytes", len, limits.max_scene_name_bytes)
}

pub(crate) fn check_mesh_count(n: u64, limits: &TraceLimits) -> Result<(), TraceErrorKind> {
    limit("mesh count", n, limits.max_meshes)
}

pub(crate) fn check_lod_count(n: u64, limits: &TraceLimits) -> Result<(), TraceErrorKind> {
    if n == 0 {
        return Err(TraceErrorKind::InvalidValue {
            what: "LOD count".into(),
            reason: "a mesh needs at least one LOD".into(),
        });
    }
    limit("LOD count", n, limits.max_lods)
}

pub(crate) fn check_triangles(n: u64, limits: &TraceLimits) -> Result<(), TraceErrorKind> {
    limit("triangles in LOD", n, limits.max_triangles_per_lod)
}

pub(crate) fn check_vertex_count(n: u64, limits: &TraceLimits) -> Result<(), TraceErrorKind> {
    limit("vertices in LOD", n, limits.max_vertices_per_lod)
}

pub(crate) fn check_event_count(n: u64, limits: &TraceLimits) -> Result<(), TraceErrorKind> {
    limit("events in frame", n, limits.max_events_per_frame)
}

pub(crate) fn check_hit_count(n: u64, limits: &TraceLimits) -> Result<(), TraceErrorKind> {
    limit("hit counts in frame", n, limits.max_hits_per_frame)
}

/// The length of [`SlotHits::slots`]: at most one entry per possible slot
/// and at most [`TraceLimits::max_hits_per_frame`].
pub(crate) fn check_slot_count(n: u64, limits: &TraceLimits) -> Result<(), TraceErrorKind> {
    limit("slot hit counts in frame", n, limits.max_live_instances)?;
    limit("slot hit counts in frame", n, limits.max_hits_per_frame)
}

/// Checks one LOD's geometry against its triangle count.
pub(crate) fn check_geometry(triangles: u32, g: &LodGeometry) -> Result<(), TraceErrorKind> {
    if g.indices.len() as u64 != 3 * u64::from(triangles) {
        return Err(TraceErrorKind::InvalidValue {
            what: "geometry index count".into(),
            reason: format!(
                "{} indices for {triangles} triangles (need {})",
                g.indices.len(),
                3 * u64::from(triangles)
            ),
        });
    }
    for (v, p) in g.positions.iter().enumerate() {
        for (axis, x) in p.iter().enumerate() {
            check_finite(|| format!("geometry position {v}[{axis}]"), *x)?;
        }
    }
    if let Some((i, &bad)) = g
        .indices
        .iter()
        .enumerate()
        .find(|(_, &ix)| ix as usize >= g.positions.len())
    {
        return Err(TraceErrorKind::InvalidValue {
            what: format!("geometry index {i}"),
            reason: format!("{bad} >= vertex count {}", g.positions.len()),
        });
    }
    Ok(())
}

/// The per-mesh facts events are checked against.
#[derive(Clone, Debug, Default)]
pub(crate) struct MeshTable {
    lods: HashMap<u32, u32>,
}

impl MeshTable {
    pub(crate) fn insert(&mut self, mesh: MeshId, lods: u32) -> Result<(), TraceErrorKind> {
        if self.lods.insert(mesh.0, lods).is_some() {
            return Err(TraceErrorKind::DuplicateMesh { mesh: mesh.0 });
        }
        Ok(())
    }
    pub(crate) fn set_lods(&mut self, mesh: MeshId, lods: u32) {
        self.lods.insert(mesh.0, lods);
    }
    pub(crate) fn check_lod(&self, mesh: MeshId, lod: u32) -> Result<(), TraceErrorKind> {
        let lods = *self
            .lods
            .get(&mesh.0)
            .ok_or(TraceErrorKind::UnknownMesh { mesh: mesh.0 })?;
        if lod >= lods {
            return Err(TraceErrorKind::LodOutOfRange {
                mesh: mesh.0,
                lod,
                lods,
            });
        }
        Ok(())
    }
}

/// Checks a whole header (the writers' path; the binary reader checks field
/// by field as it parses). Returns the mesh table.
pub(crate) fn check_header(
    h: &TraceHeader,
    limits: &TraceLimits,
) -> Result<MeshTable, TraceErrorKind> {
    check_scene_name(h.scene_name.len() as u64, limits)?;
    check_world(&h.world, limits)?;
    check_mesh_count(h.meshes.len() as u64, limits)?;
    let mut table = MeshTable::default();
    for m in &h.meshes {
        check_mesh(m, limits)?;
        table.insert(m.id, m.lods.len() as u32)?;
    }
    Ok(table)
}

pub(crate) fn check_mesh(m: &MeshInfo, limits: &TraceLimits) -> Result<(), TraceErrorKind> {
    check_aabb("mesh bounds", &m.bounds, f32::INFINITY)?;
    check_lod_count(m.lods.len() as u64, limits)?;
    for lod in &m.lods {
        check_triangles(lod.triangles.into(), limits)?;
        if let Some(g) = &lod.geometry {
            check_vertex_count(g.positions.len() as u64, limits)?;
            check_geometry(lod.triangles, g)?;
        }
    }
    Ok(())
}

/// Context-free checks of one event against the header (mesh, LOD, finite
/// values, boxes, flags). Live-instance rules are the validator's.
pub(crate) fn check_event(
    e: &InstanceEvent,
    meshes: &MeshTable,
    limits: &TraceLimits,
) -> Result<(), TraceErrorKind> {
    match e {
        InstanceEvent::Add(a) => {
            meshes.check_lod(a.mesh, a.lod)?;
            if let Some(slot) = a.slot {
                if slot >= limits.max_live_instances {
                    return Err(TraceErrorKind::LimitExceeded {
                        what: "instance slot",
                        value: slot.into(),
                        limit: u64::from(limits.max_live_instances).saturating_sub(1),
                    });
                }
            }
            check_pose(&a.pose, limits)
        }
        InstanceEvent::Update(u) => match &u.pose {
            Some(p) => check_pose(p, limits),
            None => Ok(()),
        },
        InstanceEvent::Remove { .. } => Ok(()),
    }
}
