//! The instance registry: handles, dense GPU slots and the CPU mirror of the
//! GPU instance buffer.
//!
//! **Low-level**: a part of [`crate::Manager`] (through
//! [`crate::culling::Culling`]); engines change instances through the
//! manager, which keeps commands, BLASes and geometry data consistent.
//!
//! Engines address instances by [`InstanceHandle`] (a `slotmap` key that goes
//! stale on removal, plus the id of the registry that issued it, so that a
//! handle of another registry or [`crate::manager::Manager`] is refused
//! rather than taken for one of this registry's instances); the GPU
//! addresses them by *slot*, a dense `u32` index
//! into the instance buffer ([`InstanceArrays`]: hot, heights and cold parts
//! per slot, [`InstanceRecord`] the joined view of one) and the hit
//! feedback buffer. A slot is stable while its instance lives.
//!
//! # Slot reuse and quarantine
//!
//! Commands written by the GPU name slots and reach the CPU frames later
//! (readback latency). A removed instance's slot therefore stays *quarantined*
//! for [`RegistryConfig::quarantine_frames`] frames: it is reused only from
//! [`InstanceRegistry::begin_frame`]`(removal frame + quarantine_frames)` on,
//! so a late command for the old instance finds a dead slot
//! ([`InstanceRegistry::handle_at`] is `None`) instead of a new instance.
//! Choose it at least as large as the readback latency in frames. Free slots
//! are reused lowest first, which keeps the live slots (and the dispatch
//! range `0..slot_count()`) compact.
//!
//! # Uploads
//!
//! Every change marks its slot dirty; [`InstanceRegistry::take_dirty`]
//! returns the slot ranges whose records must be uploaded. Dead slots hold a
//! zeroed record ([`instance_bits::ALIVE`] clear, no BLAS).
//!
//! Note that the GPU's Algorithm 2 also writes the state bits of its copy of a
//! record; the mirror here follows them through
//! [`InstanceRegistry::set_state`] as commands are processed.

use crate::dirty::DirtySet;
use crate::error::CoreError;
use crate::grid::HitboxGrid;
use crate::hitbox_index::HitboxIndex;
use crate::instance::{InstanceDesc, InstanceFlags, MeshId};
use crate::layout::{instance_bits, InstanceArrays, InstanceRecord, InstanceState, MAX_SLOTS};
use crate::math::{affine_to_rows, rows_to_affine, Aabb};
use crate::slot_table::SlotTable;
use glam::{Affine3A, Vec3};
use slotmap::{Key, SlotMap};
use std::cmp::Reverse;
use std::collections::{BinaryHeap, VecDeque};
use std::ops::Range;
use std::sync::atomic::{AtomicU32, Ordering};

slotmap::new_key_type! {
    /// The registry-internal key of an instance (index and version).
    struct EntryKey;
}

/// Handle of a registered instance. It goes stale when the instance is
/// removed; every use of a stale handle, and of a handle issued by another
/// registry, is a [`CoreError::StaleHandle`].
///
/// 12 bytes (`Option<InstanceHandle>` too): the 8-byte slot-map key and the
/// 4-byte id of the issuing registry, which costs one `u32` compare per
/// lookup. A clone of a registry keeps its id, so handles stay valid in
/// both copies. `InstanceHandle::default()` names no instance of any
/// registry.
#[derive(Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct InstanceHandle {
    key: EntryKey,
    registry: u32,
}

impl std::fmt::Debug for InstanceHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "InstanceHandle({:?}@{})", self.key.data(), self.registry)
    }
}

/// Source of registry ids (0 is never issued: it marks default handles).
static NEXT_REGISTRY_ID: AtomicU32 = AtomicU32::new(1);

fn next_registry_id() -> u32 {
    loop {
        // Skips 0 when the counter wraps (after 2^32 registries).
        let id = NEXT_REGISTRY_ID.fetch_add(1, Ordering::Relaxed);
        if id != 0 {
            return id;
        }
    }
}

/// Largest SBT record offset (24 bits in a TLAS instance).
pub const MAX_SBT_OFFSET: u32 = (1 << 24) - 1;

/// Settings of an [`InstanceRegistry`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RegistryConfig {
    /// Frames a removed instance's slot waits before reuse. Must be at least
    /// the readback latency in frames. Default 4.
    pub quarantine_frames: u32,
    /// Largest AABB extent (metres, per axis) accepted; larger boxes are
    /// rejected as corrupt input. Default 1e6 (1000 km).
    pub max_aabb_extent: f32,
    /// Number of GPU slots available, at most [`MAX_SLOTS`] (the 24-bit TLAS
    /// custom index). Default [`MAX_SLOTS`].
    pub max_slots: u32,
}

impl Default for RegistryConfig {
    fn default() -> Self {
        Self {
            quarantine_frames: 4,
            max_aabb_extent: 1.0e6,
            max_slots: MAX_SLOTS,
        }
    }
}

/// What [`InstanceRegistry::remove`] hands back: everything the caller must
/// release (its BLAS reference, by mesh/LOD or unique).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RemovedInstance {
    /// The slot it occupied (now quarantined).
    pub slot: u32,
    /// Its last description (mesh, LOD, flags, ...).
    pub desc: InstanceDesc,
    /// The BLAS address its record held (0 = none).
    pub blas: u64,
    /// Its state at removal.
    pub state: InstanceState,
    /// The hitbox it belonged to.
    pub hitbox: u32,
}

impl SlotOccupant {
    /// The (current or last) occupant's mesh.
    pub(crate) fn mesh(&self) -> MeshId {
        self.mesh
    }
}

/// What the handle map keeps per instance: its slot (the rest is in the
/// slot's row of the [`SlotTable`] and its [`InstanceRecord`], from which
/// the [`InstanceDesc`] is rebuilt, see [`desc_from_record`]).
#[derive(Clone, Copy, Debug)]
struct Entry {
    slot: u32,
}

/// The registry's column of the [`SlotTable`]: who lives in the slot.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct SlotOccupant {
    handle: Option<EntryKey>,
    /// Registration serial of the current (or last) occupant.
    serial: u64,
    /// The occupant's mesh (the one field of its description its record
    /// does not hold).
    mesh: MeshId,
}

/// All instances of a scene with their GPU slots and records.
///
/// `H` is the hitbox structure (the paper's [`HitboxGrid`] by default); the
/// registry stores each instance's hitbox (the one holding its AABB centre,
/// [`HitboxIndex::hitbox_of`]; exact for [`HitboxGrid`]) in its record.
///
/// ```
/// use glam::{Affine3A, Vec3};
/// use lipac_core::error::CoreError;
/// use lipac_core::grid::{GridConfig, HitboxGrid};
/// use lipac_core::instance::{InstanceDesc, MeshId};
/// use lipac_core::layout::InstanceState;
/// use lipac_core::math::Aabb;
/// use lipac_core::registry::{InstanceRegistry, RegistryConfig};
///
/// let grid = HitboxGrid::new(GridConfig::default())?; // 8 x 8 km, 16 m cells
/// let mut reg = InstanceRegistry::new(grid, RegistryConfig::default())?;
///
/// let at = |x: f32| {
///     let aabb = Aabb::new(Vec3::new(x - 1.0, 0.0, -1.0), Vec3::new(x + 1.0, 3.0, 1.0));
///     InstanceDesc::new(MeshId(7), Affine3A::from_translation(Vec3::new(x, 0.0, 0.0)), aabb)
/// };
/// let a = reg.register(at(20.0))?;
/// let b = reg.register(at(40.0))?;
/// assert_eq!((reg.slot(a)?, reg.slot(b)?), (0, 1));
/// assert_eq!(reg.record(a)?.state(), InstanceState::Inactive);
/// assert!(reg.record(a)?.is_alive());
/// assert_eq!(reg.take_dirty(), vec![0..2]); // upload slots 0 and 1
///
/// // The command loop gives the instance a BLAS and activates it.
/// reg.set_blas(a, 0xB1A5)?;
/// reg.set_state(0, InstanceState::Active)?;
///
/// let removed = reg.remove(a)?; // release removed.blas
/// assert_eq!((removed.slot, removed.blas), (0, 0xB1A5));
/// assert!(matches!(reg.slot(a), Err(CoreError::StaleHandle { .. })));
///
/// // Slot 0 is quarantined for 4 frames: a new instance gets slot 2 ...
/// let c = reg.register(at(60.0))?;
/// assert_eq!(reg.slot(c)?, 2);
/// // ... and slot 0 is reused from frame 4 on.
/// reg.begin_frame(4)?;
/// let d = reg.register(at(80.0))?;
/// assert_eq!(reg.slot(d)?, 0);
/// # Ok::<(), CoreError>(())
/// ```
#[derive(Clone, Debug)]
pub struct InstanceRegistry<H: HitboxIndex = HitboxGrid> {
    config: RegistryConfig,
    index: H,
    /// Stamped into every handle this registry issues.
    id: u32,
    instances: SlotMap<EntryKey, Entry>,
    records: InstanceArrays,
    /// The one per-slot table ([`crate::slot_table`]), as long as
    /// `records`; the registry writes its occupant column.
    table: SlotTable,
    free: BinaryHeap<Reverse<u32>>,
    /// `(frame from which the slot may be reused, slot)`, in frame order.
    quarantine: VecDeque<(u64, u32)>,
    frame: u64,
    registrations: u64,
    dirty: DirtySet,
    /// The slots written since the last [`InstanceRegistry::take_touched`]:
    /// the same marks as `dirty`, taken separately by the hitbox extents
    /// ([`crate::hitbox_extents`]).
    touched: DirtySet,
    /// Hitboxes the index evicted at the last [`InstanceRegistry::begin_frame`].
    evicted: Vec<u32>,
}

fn stale(h: InstanceHandle) -> CoreError {
    CoreError::StaleHandle {
        kind: "instance",
        key: h.key.data().as_ffi(),
    }
}

fn foreign(h: InstanceHandle) -> CoreError {
    CoreError::StaleHandle {
        kind: "instance of another registry",
        key: h.key.data().as_ffi(),
    }
}

fn validate_transform(t: &Affine3A) -> Result<[f32; 12], CoreError> {
    let rows = affine_to_rows(t);
    match rows.iter().position(|v| !v.is_finite()) {
        Some(element) => Err(CoreError::NonFiniteTransform {
            element,
            value: rows[element],
        }),
        None => Ok(rows),
    }
}

fn validate_aabb(aabb: &Aabb, max_extent: f32) -> Result<(), CoreError> {
    let fail = |reason: String| {
        Err(CoreError::InvalidAabb {
            min: aabb.min,
            max: aabb.max,
            reason,
        })
    };
    if !aabb.min.is_finite() || !aabb.max.is_finite() {
        return fail("corners must be finite".into());
    }
    let (lo, hi) = (aabb.min.to_array(), aabb.max.to_array());
    for (axis, name) in ["x", "y", "z"].into_iter().enumerate() {
        if lo[axis] > hi[axis] {
            return fail(format!(
                "min.{name} = {} > max.{name} = {}",
                lo[axis], hi[axis]
            ));
        }
        let extent = hi[axis] - lo[axis];
        if extent.is_nan() || extent > max_extent {
            return fail(format!(
                "extent along {name} is {extent} m, more than the maximum {max_extent} m"
            ));
        }
    }
    Ok(())
}

fn pack(desc: &InstanceDesc, state: InstanceState) -> u32 {
    state as u32
        | instance_bits::ALIVE
        | desc.flags.bits()
        | (u32::from(desc.mask) << instance_bits::MASK_SHIFT)
        | (u32::from(desc.vk_flags) << instance_bits::VK_FLAGS_SHIFT)
}

/// The description a live record was built from by [`build_record`]: every
/// field but the mesh is stored in the record bit for bit (the transform as
/// its rows, which [`rows_to_affine`] inverts exactly).
fn desc_from_record(record: &InstanceRecord, mesh: MeshId) -> InstanceDesc {
    InstanceDesc {
        mesh,
        lod: record.lod,
        transform: rows_to_affine(&record.transform),
        aabb: Aabb::new(
            Vec3::from_array(record.aabb_min),
            Vec3::from_array(record.aabb_max),
        ),
        flags: InstanceFlags::from_bits_truncate(record.packed),
        mask: record.mask(),
        sbt_offset: record.sbt_offset,
        vk_flags: record.vk_flags(),
    }
}

fn build_record(
    desc: &InstanceDesc,
    rows: [f32; 12],
    hitbox: u32,
    state: InstanceState,
    blas: u64,
) -> InstanceRecord {
    InstanceRecord {
        transform: rows,
        aabb_min: desc.aabb.min.to_array(),
        hitbox,
        aabb_max: desc.aabb.max.to_array(),
        packed: pack(desc, state),
        blas,
        sbt_offset: desc.sbt_offset,
        lod: desc.lod,
    }
}

impl<H: HitboxIndex> InstanceRegistry<H> {
    /// An empty registry over the hitbox structure `index`, at frame 0.
    ///
    /// Rejects `max_slots` of 0 or above [`MAX_SLOTS`] and a non-positive or
    /// NaN `max_aabb_extent`.
    pub fn new(index: H, config: RegistryConfig) -> Result<Self, CoreError> {
        if config.max_slots == 0 || config.max_slots > MAX_SLOTS {
            return Err(CoreError::InvalidConfig {
                what: format!(
                    "max_slots = {} must be in 1..={MAX_SLOTS}",
                    config.max_slots
                ),
            });
        }
        if config.max_aabb_extent.is_nan() || config.max_aabb_extent <= 0.0 {
            return Err(CoreError::InvalidConfig {
                what: format!("max_aabb_extent = {} must be > 0", config.max_aabb_extent),
            });
        }
        Ok(Self {
            config,
            index,
            id: next_registry_id(),
            instances: SlotMap::with_key(),
            records: InstanceArrays::new(),
            table: SlotTable::default(),
            free: BinaryHeap::new(),
            quarantine: VecDeque::new(),
            frame: 0,
            registrations: 0,
            dirty: DirtySet::default(),
            touched: DirtySet::default(),
            evicted: Vec::new(),
        })
    }

    /// The settings it was created with.
    pub fn config(&self) -> &RegistryConfig {
        &self.config
    }

    /// The hitbox structure.
    pub fn hitbox_index(&self) -> &H {
        &self.index
    }

    /// Replaces the hitbox structure, recomputing every instance's hitbox,
    /// and returns the old one. If any live instance's centre lies outside
    /// the new structure, fails with [`CoreError::OutsideWorld`] and changes
    /// nothing.
    /// The live instances are placed in it with [`HitboxIndex::occupy`]
    /// (in slot order), as registration would.
    pub fn set_hitbox_index(&mut self, mut index: H) -> Result<H, CoreError> {
        let mut slots: Vec<u32> = self.instances.values().map(|e| e.slot).collect();
        slots.sort_unstable();
        let mut hitboxes = Vec::with_capacity(slots.len());
        for slot in slots {
            let r = &self.records.bounds()[slot as usize];
            let aabb = Aabb::new(Vec3::from_array(r.aabb_min), Vec3::from_array(r.aabb_max));
            hitboxes.push((slot, index.occupy(&aabb)?));
        }
        for (slot, hitbox) in hitboxes {
            if self.records.set_hitbox(slot as usize, hitbox) != Some(hitbox) {
                self.touch(slot);
            }
        }
        Ok(std::mem::replace(&mut self.index, index))
    }

    /// Reserves room for at least `additional` more instances, so that
    /// registering a scene of known size allocates each container once
    /// instead of growing it by doubling (which copies it and leaves up to
    /// half of it unused). Dead slots free for reuse count towards it;
    /// nothing is reserved beyond [`RegistryConfig::max_slots`].
    ///
    /// ```
    /// use lipac_core::grid::{GridConfig, HitboxGrid};
    /// use lipac_core::registry::{InstanceRegistry, RegistryConfig};
    /// let grid = HitboxGrid::new(GridConfig::default())?;
    /// let mut reg = InstanceRegistry::new(grid, RegistryConfig::default())?;
    /// reg.reserve(1000)?;
    /// assert!(reg.capacity() >= 1000);
    /// # Ok::<(), lipac_core::error::CoreError>(())
    /// ```
    pub fn reserve(&mut self, additional: usize) -> Result<(), CoreError> {
        self.reserve_slots(additional).map(|_| ())
    }

    /// [`InstanceRegistry::reserve`]; returns the number of slots the
    /// reservation covers (for per-slot buffers elsewhere).
    pub(crate) fn reserve_slots(&mut self, additional: usize) -> Result<usize, CoreError> {
        let max = self.config.max_slots as usize;
        let additional = additional.min(max.saturating_sub(self.instances.len()));
        let new_slots = additional
            .saturating_sub(self.free.len())
            .min(max.saturating_sub(self.records.len()));
        let slots = self.records.len() + new_slots;
        self.instances
            .try_reserve(additional)
            .map_err(|_| CoreError::OutOfMemory {
                what: "instance handles",
                additional,
            })?;
        self.records.reserve_exact(new_slots)?;
        self.table.reserve_exact(new_slots)?;
        self.dirty.reserve(slots, additional)?;
        self.touched.reserve(slots, additional)?;
        Ok(slots)
    }

    /// Live instances the registry can hold now without reallocating its
    /// handle map or slot buffers (quarantined slots not counted).
    pub fn capacity(&self) -> usize {
        let unused = self
            .records
            .capacity()
            .min(self.table.capacity())
            .saturating_sub(self.records.len());
        let slots =
            (self.instances.len() + self.free.len() + unused).min(self.config.max_slots as usize);
        self.instances.capacity().min(slots)
    }

    /// Checks `desc`; returns the transform rows. Touches nothing (the
    /// hitbox comes from [`HitboxIndex::occupy`] once the rest is known to
    /// succeed).
    fn check(&self, desc: &InstanceDesc) -> Result<[f32; 12], CoreError> {
        let rows = validate_transform(&desc.transform)?;
        validate_aabb(&desc.aabb, self.config.max_aabb_extent)?;
        if desc.sbt_offset > MAX_SBT_OFFSET {
            return Err(CoreError::FieldOutOfRange {
                field: "sbt_offset",
                value: desc.sbt_offset.into(),
                max: MAX_SBT_OFFSET.into(),
            });
        }
        Ok(rows)
    }

    /// Registers an instance. It starts [`InstanceState::Inactive`]
    /// ([`InstanceState::Active`] if [`InstanceFlags::PINNED`]) with no
    /// BLAS, in the lowest free slot (or a new slot at the end).
    ///
    /// Errors: non-finite transform, invalid AABB, SBT offset over 24 bits,
    /// no slot left, AABB centre outside the hitbox structure (or a new
    /// cell of a full one, [`HitboxIndex::occupy`]). On error nothing
    /// changes.
    pub fn register(&mut self, desc: InstanceDesc) -> Result<InstanceHandle, CoreError> {
        let rows = self.check(&desc)?;
        let slot = match self.free.peek() {
            Some(&Reverse(slot)) => slot,
            None if self.records.len() < self.config.max_slots as usize => {
                self.records.len() as u32
            }
            None => {
                return Err(CoreError::TooManyInstances {
                    limit: self.config.max_slots,
                    quarantined: self.quarantine.len() as u32,
                })
            }
        };
        let hitbox = self.index.occupy(&desc.aabb)?;
        // Nothing below fails.
        if self.free.peek().is_some() {
            self.free.pop();
        } else {
            self.records.push(&InstanceRecord::default());
            self.table.push_slot();
        }
        let key = self.instances.insert(Entry { slot });
        let handle = self.handle(key);
        let state = if desc.flags.contains(InstanceFlags::PINNED) {
            InstanceState::Active
        } else {
            InstanceState::Inactive
        };
        self.records
            .set(slot as usize, &build_record(&desc, rows, hitbox, state, 0));
        self.table[slot as usize].occupant = SlotOccupant {
            handle: Some(key),
            serial: self.registrations,
            mesh: desc.mesh,
        };
        self.registrations += 1;
        self.touch(slot);
        Ok(handle)
    }

    /// Replaces an instance's description and returns the previous one. Its
    /// slot, state and BLAS stay (a [`InstanceFlags::PINNED`] description
    /// makes the state [`InstanceState::Active`]; clearing the flag keeps
    /// the state); if the mesh, LOD or
    /// [`InstanceFlags::UNIQUE_BLAS`] changed, the caller acquires the new
    /// BLAS, calls [`InstanceRegistry::set_blas`] and releases the old one.
    /// On error nothing changes.
    pub fn update(
        &mut self,
        handle: InstanceHandle,
        desc: InstanceDesc,
    ) -> Result<InstanceDesc, CoreError> {
        let entry = self.entry(handle)?;
        let rows = self.check(&desc)?;
        let slot = entry.slot as usize;
        let record = self.records.get(slot).ok_or_else(|| stale(handle))?;
        let hitbox = self.index.occupy(&desc.aabb)?;
        self.index.vacate(record.hitbox);
        let occupant = &mut self.table[entry.slot as usize].occupant;
        let old = desc_from_record(&record, occupant.mesh);
        let state = if desc.flags.contains(InstanceFlags::PINNED) {
            InstanceState::Active
        } else {
            record.state()
        };
        self.records
            .set(slot, &build_record(&desc, rows, hitbox, state, record.blas));
        occupant.mesh = desc.mesh;
        self.touch(entry.slot);
        Ok(old)
    }

    /// Moves an instance: new transform and world-space AABB (its hitbox
    /// follows the AABB centre). On error nothing changes.
    pub fn set_transform(
        &mut self,
        handle: InstanceHandle,
        transform: Affine3A,
        aabb: Aabb,
    ) -> Result<(), CoreError> {
        let desc = InstanceDesc {
            transform,
            aabb,
            ..self.desc(handle)?
        };
        self.update(handle, desc).map(|_| ())
    }

    /// Selects another LOD and returns the previous one (see
    /// [`InstanceRegistry::update`] for the BLAS).
    pub fn set_lod(&mut self, handle: InstanceHandle, lod: u32) -> Result<u32, CoreError> {
        let desc = InstanceDesc {
            lod,
            ..self.desc(handle)?
        };
        self.update(handle, desc).map(|old| old.lod)
    }

    /// Replaces the instance flags and returns the previous ones.
    pub fn set_flags(
        &mut self,
        handle: InstanceHandle,
        flags: InstanceFlags,
    ) -> Result<InstanceFlags, CoreError> {
        let desc = InstanceDesc {
            flags,
            ..self.desc(handle)?
        };
        self.update(handle, desc).map(|old| old.flags)
    }

    /// Removes an instance. Its slot is zeroed (dead), marked dirty and
    /// quarantined; the returned [`RemovedInstance`] says what to release.
    pub fn remove(&mut self, handle: InstanceHandle) -> Result<RemovedInstance, CoreError> {
        let key = self.key(handle)?;
        let entry = self.instances.remove(key).ok_or_else(|| stale(handle))?;
        let slot = entry.slot;
        let record = self.records.take(slot as usize).unwrap_or_default();
        self.index.vacate(record.hitbox);
        let mesh = self.table[slot as usize].occupant.mesh;
        self.table[slot as usize].occupant.handle = None;
        self.touch(slot);
        if self.config.quarantine_frames == 0 {
            self.free.push(Reverse(slot));
        } else {
            let release = self
                .frame
                .saturating_add(self.config.quarantine_frames.into());
            self.quarantine.push_back((release, slot));
        }
        Ok(RemovedInstance {
            slot,
            desc: desc_from_record(&record, mesh),
            blas: record.blas,
            state: record.state(),
            hitbox: record.hitbox,
        })
    }

    /// Starts frame `frame` and releases the slots whose quarantine has
    /// ended; returns how many. Frames must not go backwards
    /// ([`CoreError::FrameOrder`]); repeating the current frame is allowed.
    pub fn begin_frame(&mut self, frame: u64) -> Result<u32, CoreError> {
        if frame < self.frame {
            return Err(CoreError::FrameOrder {
                current: self.frame,
                given: frame,
            });
        }
        self.frame = frame;
        self.evicted.clear();
        self.index.begin_frame(frame, &mut self.evicted);
        let mut released = 0;
        while let Some(&(release, slot)) = self.quarantine.front() {
            if release > frame {
                break;
            }
            self.quarantine.pop_front();
            self.free.push(Reverse(slot));
            released += 1;
        }
        Ok(released)
    }

    /// The hitboxes the index evicted at the last
    /// [`InstanceRegistry::begin_frame`] ([`HitboxIndex::begin_frame`]):
    /// empty cells dropped, whose indices may be handed out again. Their
    /// hitbox records must be reset ([`crate::culling::Culling`] does).
    pub fn evicted_hitboxes(&self) -> &[u32] {
        &self.evicted
    }

    /// The current frame (last [`InstanceRegistry::begin_frame`]).
    pub fn frame(&self) -> u64 {
        self.frame
    }

    /// Number of live instances.
    pub fn len(&self) -> usize {
        self.instances.len()
    }

    /// Whether there are no live instances.
    pub fn is_empty(&self) -> bool {
        self.instances.is_empty()
    }

    /// Whether `handle` refers to a live instance.
    pub fn contains(&self, handle: InstanceHandle) -> bool {
        handle.registry == self.id && self.instances.contains_key(handle.key)
    }

    /// Number of slots in use, dead ones included: the length of the GPU
    /// instance and hit feedback buffers and of the dispatch range.
    pub fn slot_count(&self) -> u32 {
        self.records.len() as u32
    }

    /// Slots waiting in quarantine.
    pub fn quarantined_slots(&self) -> u32 {
        self.quarantine.len() as u32
    }

    /// Dead slots free for reuse right now.
    pub fn free_slots(&self) -> u32 {
        self.free.len() as u32
    }

    /// The GPU slot of an instance.
    pub fn slot(&self, handle: InstanceHandle) -> Result<u32, CoreError> {
        self.entry(handle).map(|e| e.slot)
    }

    fn entry(&self, handle: InstanceHandle) -> Result<Entry, CoreError> {
        self.instances
            .get(self.key(handle)?)
            .copied()
            .ok_or_else(|| stale(handle))
    }

    /// The slot-map key of a handle this registry issued.
    #[inline]
    fn key(&self, handle: InstanceHandle) -> Result<EntryKey, CoreError> {
        if handle.registry == self.id {
            Ok(handle.key)
        } else {
            Err(foreign(handle))
        }
    }

    /// The handle of slot-map key `key`.
    #[inline]
    fn handle(&self, key: EntryKey) -> InstanceHandle {
        InstanceHandle {
            key,
            registry: self.id,
        }
    }

    /// The live instance in `slot`, or `None` for a dead, quarantined or
    /// out-of-range slot (e.g. a late command for a removed instance).
    pub fn handle_at(&self, slot: u32) -> Option<InstanceHandle> {
        self.table
            .get(slot as usize)?
            .occupant
            .handle
            .map(|k| self.handle(k))
    }

    /// The GPU record of an instance (joined from the instance arrays, by
    /// value).
    pub fn record(&self, handle: InstanceHandle) -> Result<InstanceRecord, CoreError> {
        let slot = self.slot(handle)?;
        self.records.get(slot as usize).ok_or_else(|| stale(handle))
    }

    /// The record in `slot`, dead or alive, or `None` past
    /// [`InstanceRegistry::slot_count`].
    pub fn record_at(&self, slot: u32) -> Option<InstanceRecord> {
        self.records.get(slot as usize)
    }

    /// The CPU mirror of the GPU instance buffer: hot, heights and cold
    /// arrays, one entry of each per slot.
    pub fn records(&self) -> &InstanceArrays {
        &self.records
    }

    /// The hot array for Algorithm 2 ([`crate::culling`]), which writes its
    /// state bits. Not marked dirty: the state bits are GPU-owned, so those
    /// writes are never uploaded.
    pub(crate) fn records_hot_mut(&mut self) -> &mut [crate::layout::InstanceHot] {
        self.records.hot_mut()
    }

    /// An instance's description, as last registered or updated. It is
    /// rebuilt from the instance's record (which holds every field but the
    /// mesh, bit for bit), so it is returned by value.
    pub fn desc(&self, handle: InstanceHandle) -> Result<InstanceDesc, CoreError> {
        let e = self.entry(handle)?;
        let slot = e.slot as usize;
        let record = self.records.get(slot).ok_or_else(|| stale(handle))?;
        Ok(desc_from_record(&record, self.table[slot].occupant.mesh))
    }

    /// An instance's mesh.
    pub fn mesh(&self, handle: InstanceHandle) -> Result<MeshId, CoreError> {
        self.entry(handle)
            .map(|e| self.table[e.slot as usize].occupant.mesh)
    }

    /// An instance's LOD.
    pub fn lod(&self, handle: InstanceHandle) -> Result<u32, CoreError> {
        self.record(handle).map(|r| r.lod)
    }

    /// An instance's flags.
    pub fn flags(&self, handle: InstanceHandle) -> Result<InstanceFlags, CoreError> {
        self.record(handle)
            .map(|r| InstanceFlags::from_bits_truncate(r.packed))
    }

    /// An instance's state (as the CPU mirror knows it).
    pub fn state(&self, handle: InstanceHandle) -> Result<InstanceState, CoreError> {
        self.record(handle).map(|r| r.state())
    }

    /// Sets the BLAS address of an instance (0 = none) and returns the
    /// previous one.
    pub fn set_blas(&mut self, handle: InstanceHandle, address: u64) -> Result<u64, CoreError> {
        let slot = self.slot(handle)?;
        Ok(self.write_blas(slot, address))
    }

    /// [`InstanceRegistry::set_blas`] by slot; a dead slot is
    /// [`CoreError::NoInstanceAtSlot`].
    pub fn set_blas_at(&mut self, slot: u32, address: u64) -> Result<u64, CoreError> {
        self.live_slot(slot)?;
        Ok(self.write_blas(slot, address))
    }

    /// Sets the state of the instance in `slot` (as the command loop does)
    /// and returns the previous state; a dead slot is
    /// [`CoreError::NoInstanceAtSlot`].
    pub fn set_state(
        &mut self,
        slot: u32,
        state: InstanceState,
    ) -> Result<InstanceState, CoreError> {
        self.live_slot(slot)?;
        let old = self
            .records
            .set_state(slot as usize, state)
            .ok_or(CoreError::NoInstanceAtSlot { slot })?;
        if old != state {
            self.touch(slot);
        }
        Ok(old)
    }

    /// [`InstanceRegistry::set_state`] by handle.
    pub fn set_state_of(
        &mut self,
        handle: InstanceHandle,
        state: InstanceState,
    ) -> Result<InstanceState, CoreError> {
        let slot = self.slot(handle)?;
        self.set_state(slot, state)
    }

    fn live_slot(&self, slot: u32) -> Result<(), CoreError> {
        match self.handle_at(slot) {
            Some(_) => Ok(()),
            None => Err(CoreError::NoInstanceAtSlot { slot }),
        }
    }

    /// The one place a BLAS address is written: [`InstanceArrays::set_blas`]
    /// keeps [`instance_bits::HAS_BLAS`] with it.
    fn write_blas(&mut self, slot: u32, address: u64) -> u64 {
        let old = self.records.set_blas(slot as usize, address).unwrap_or(0);
        if old != address {
            self.touch(slot);
        }
        old
    }

    /// Live instances as `(handle, slot)`, in no particular order.
    pub fn iter(&self) -> impl Iterator<Item = (InstanceHandle, u32)> + '_ {
        self.instances.iter().map(|(k, e)| (self.handle(k), e.slot))
    }

    /// Takes the slot ranges changed since the last call (sorted, disjoint,
    /// adjacent ranges coalesced): upload those slots of `records()` for each.
    pub fn take_dirty(&mut self) -> Vec<Range<u32>> {
        self.dirty.take()
    }

    /// Like [`InstanceRegistry::take_dirty`], also merging ranges separated
    /// by at most `max_gap` clean slots.
    pub fn take_dirty_merged(&mut self, max_gap: u32) -> Vec<Range<u32>> {
        self.dirty.take_merged(max_gap)
    }

    /// Marks a written slot for the upload and for the hitbox extents.
    fn touch(&mut self, slot: u32) {
        self.dirty.mark(slot);
        self.touched.mark(slot);
    }

    /// Takes the slots written since the last call (as
    /// [`InstanceRegistry::take_dirty`], but a separate set: the hitbox
    /// extents' input, [`crate::hitbox_extents`]).
    pub(crate) fn take_touched(&mut self) -> Vec<Range<u32>> {
        self.touched.take()
    }

    /// Whether any slot changed since the last take.
    pub fn has_dirty(&self) -> bool {
        !self.dirty.is_empty()
    }

    /// The one per-slot table ([`crate::slot_table`]), a row per slot.
    pub(crate) fn table(&self) -> &SlotTable {
        &self.table
    }

    /// The per-slot table, for the command loop's and the Manager's
    /// columns (the occupant column is the registry's alone).
    pub(crate) fn table_mut(&mut self) -> &mut SlotTable {
        &mut self.table
    }

    /// CPU bytes held, from capacities: `(records, handles, the slot table
    /// (every part's column), free lists, dirty set)`; see [`crate::memory`].
    pub(crate) fn heap_bytes(&self) -> (u64, u64, u64, u64, u64) {
        use crate::memory::vec_bytes;
        // slotmap 1.x: a slot is a union of the value and the free-list
        // link, plus a u32 version, rounded up to the value's alignment.
        let align = std::mem::align_of::<Entry>();
        let slot = (std::mem::size_of::<Entry>() + 4).div_ceil(align) * align;
        (
            self.records.heap_bytes(),
            (self.instances.capacity() * slot) as u64,
            self.table.heap_bytes(),
            vec_bytes::<u32>(self.free.capacity())
                + vec_bytes::<(u64, u32)>(self.quarantine.capacity()),
            self.dirty.heap_bytes() + self.touched.heap_bytes(),
        )
    }

    /// Number of [`InstanceRegistry::register`] calls that succeeded so far.
    /// Registrations are numbered `0, 1, ...` in order (their *serial*).
    pub fn registration_count(&self) -> u64 {
        self.registrations
    }

    /// Serial of the live instance in `slot` (see
    /// [`InstanceRegistry::registration_count`]), or `None` for a dead slot.
    /// A slot that was reused has a larger serial than before, which is how
    /// per-slot caches (e.g. [`crate::latency::LatencyMitigation`]) notice
    /// that it holds another instance.
    pub fn serial_at(&self, slot: u32) -> Option<u64> {
        let o = &self.table.get(slot as usize)?.occupant;
        o.handle.map(|_| o.serial)
    }
}

#[cfg(test)]
mod tests;
