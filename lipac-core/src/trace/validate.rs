//! [`TraceValidator`]: the rules that span events and frames.

use super::error::TraceErrorKind;
use super::model::{
    check_camera, check_event, check_event_count, check_header, check_hit_count, check_slot_count,
    Camera, Frame, InstanceEvent, InstanceHits, MeshTable, SlotHits, TraceHeader, TraceLimits,
    WorldInfo,
};
use crate::grid::HitboxGrid;
use crate::hitbox_index::HitboxIndex;
use crate::instance::{InstanceFlags, MeshId};
use crate::math::Aabb;
use std::collections::{BTreeMap, HashMap, HashSet};

// foldhash's seeded fast hasher: the validator looks up every event's and
// hit count's id, and std's SipHash dominated recording 100k hits a frame;
// the per-process random seed keeps crafted ids from colliding on purpose.
type IdMap<V> = HashMap<u64, V, foldhash::fast::RandomState>;
type IdSet = HashSet<u64, foldhash::fast::RandomState>;

/// A problem found in one frame: the event it concerns (if any) and what is
/// wrong. Readers and writers turn it into a
/// [`TraceError`](super::TraceError) with the location.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameFault {
    /// Index of the offending event in [`Frame::events`]; `None` for the
    /// frame number, the camera and hit counts.
    pub event: Option<u32>,
    /// What is wrong.
    pub kind: TraceErrorKind,
}

impl FrameFault {
    fn frame(kind: TraceErrorKind) -> Self {
        Self { event: None, kind }
    }
}

/// Checks frames in stream order against a header and the instances live so
/// far.
///
/// Per frame: the frame number increases; the camera is finite with a unit
/// quaternion, a field of view in `(0, π)` and a positive aspect; every
/// event names a declared mesh and existing LOD, has finite transforms and
/// valid boxes; an `add` names an id that is not live, an `update` or
/// `remove` one that is; hit counts name ids live after the frame's events,
/// each at most once.
///
/// Version 2: an `add` may carry a slot (below
/// [`TraceLimits::max_live_instances`], not held by a live instance), and
/// hits by slot ([`crate::trace::SlotHits`]) name held slots, with counting
/// boxes of the world grid in increasing order; readers derive
/// [`Frame::hits`] from them.
///
/// Memory grows with the number of *live* instances (one map entry each,
/// two with a slot), never with the length of the trace. After an error the validator's state
/// is unspecified; a stream with an error is not read further.
///
/// ```
/// use glam::{Quat, Vec3};
/// use lipac_core::instance::MeshId;
/// use lipac_core::math::Aabb;
/// use lipac_core::trace::{
///     Camera, Frame, InstanceEvent, LodInfo, MeshInfo, TraceErrorKind, TraceHeader,
///     TraceLimits, TraceValidator, WorldInfo,
/// };
///
/// let header = TraceHeader {
///     scene_name: "doc".into(),
///     world: WorldInfo { min: [-64.0, -64.0], max: [64.0, 64.0], cell_size: 16.0 },
///     meshes: vec![MeshInfo {
///         id: MeshId(1),
///         bounds: Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0)),
///         lods: vec![LodInfo { triangles: 12, geometry: None }],
///     }],
/// };
/// let mut v = TraceValidator::new(&header, TraceLimits::default())?;
/// let camera = Camera { position: Vec3::ZERO, orientation: Quat::IDENTITY, vertical_fov: 1.0, aspect: 1.5 };
/// let frame = Frame { number: 0, camera, events: vec![InstanceEvent::Remove { id: 9 }], hits: None, slot_hits: None };
/// let fault = v.check_frame(&frame).unwrap_err();
/// assert_eq!(fault.event, Some(0));
/// assert_eq!(fault.kind, TraceErrorKind::UnknownInstance { op: "remove", id: 9 });
/// # Ok::<(), TraceErrorKind>(())
/// ```
#[derive(Clone, Debug)]
pub struct TraceValidator {
    limits: TraceLimits,
    meshes: MeshTable,
    version: u16,
    /// The header's world grid (bounded worlds): counting-box hitboxes of
    /// [`SlotHits::boxes`] and the hitbox of each slotted instance.
    grid: Option<HitboxGrid>,
    live: IdMap<Live>,
    /// Live instances with a slot (version 2), by slot.
    slots: BTreeMap<u32, SlotEntry>,
    track_live: bool,
    last_frame: Option<u64>,
    frames: u64,
    hit_ids: IdSet,
    /// Per counting box of a frame: (culled instances, share, one more for
    /// the first, given out) while hits are derived.
    shares: Vec<[u32; 4]>,
}

/// A live instance: its mesh and its slot ([`NO_SLOT`]: none).
#[derive(Clone, Copy, Debug)]
struct Live {
    mesh: MeshId,
    slot: u32,
}

const NO_SLOT: u32 = u32::MAX;

/// A live instance with a slot: what deriving its hits needs.
#[derive(Clone, Copy, Debug)]
struct SlotEntry {
    id: u64,
    pinned: bool,
    hitbox: Option<u32>,
}

impl TraceValidator {
    /// A validator for frames following `header`; checks the header first.
    /// Frames of the newest version ([`super::TRACE_VERSION`]).
    pub fn new(header: &TraceHeader, limits: TraceLimits) -> Result<Self, TraceErrorKind> {
        Self::for_version(header, limits, super::TRACE_VERSION)
    }

    /// As [`TraceValidator::new`] for frames of format `version` (1 or 2):
    /// version 1 has no slots and no [`SlotHits`].
    pub fn for_version(
        header: &TraceHeader,
        limits: TraceLimits,
        version: u16,
    ) -> Result<Self, TraceErrorKind> {
        check_version(version)?;
        let meshes = check_header(header, &limits)?;
        Ok(Self::with_meshes(meshes, limits, &header.world, version))
    }

    pub(crate) fn with_meshes(
        meshes: MeshTable,
        limits: TraceLimits,
        world: &WorldInfo,
        version: u16,
    ) -> Self {
        Self {
            limits,
            meshes,
            version,
            grid: world
                .is_bounded()
                .then(|| HitboxGrid::new(world.grid_config()).ok())
                .flatten(),
            live: IdMap::default(),
            slots: BTreeMap::new(),
            track_live: true,
            last_frame: None,
            frames: 0,
            hit_ids: IdSet::default(),
            shares: Vec::new(),
        }
    }

    /// The format version of the frames checked.
    pub fn version(&self) -> u16 {
        self.version
    }

    /// Stops tracking live instances (frames were skipped unread, so the set
    /// of live ids is unknown); later frames get only the checks that need
    /// no history: header references, values, frame order.
    pub fn stop_tracking_live(&mut self) {
        self.track_live = false;
        self.live = IdMap::default();
        self.slots = BTreeMap::new();
    }

    /// Whether live instances are tracked (see
    /// [`TraceValidator::stop_tracking_live`]).
    pub fn tracks_live(&self) -> bool {
        self.track_live
    }

    /// Records a frame number seen without checking the frame (a skipped
    /// frame); fails if it does not follow the previous one.
    pub fn note_skipped(&mut self, number: u64) -> Result<(), TraceErrorKind> {
        self.check_order(number)?;
        self.stop_tracking_live();
        Ok(())
    }

    fn check_order(&mut self, number: u64) -> Result<(), TraceErrorKind> {
        if let Some(previous) = self.last_frame {
            if number <= previous {
                return Err(TraceErrorKind::FrameOrder {
                    previous,
                    given: number,
                });
            }
        }
        self.last_frame = Some(number);
        self.frames += 1;
        Ok(())
    }

    /// Instances live after the frames checked so far (0 when not tracking).
    pub fn live_instances(&self) -> usize {
        self.live.len()
    }

    /// Whether instance `id` is live (always `false` when not tracking).
    pub fn is_live(&self, id: u64) -> bool {
        self.live.contains_key(&id)
    }

    /// The number of the last frame checked or skipped, if any.
    pub fn last_frame_number(&self) -> Option<u64> {
        self.last_frame
    }

    /// Frames checked or skipped so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Checks the next frame of the stream and applies its events.
    /// Checks the next frame of the stream and applies its events. With
    /// [`Frame::slot_hits`], those are checked and [`Frame::hits`] is not.
    pub fn check_frame(&mut self, frame: &Frame) -> Result<(), FrameFault> {
        self.check_frame_events(frame)?;
        match (&frame.slot_hits, &frame.hits) {
            (Some(sh), _) => self.check_slot_hits(sh),
            (None, Some(hits)) => self.check_hits(hits),
            (None, None) => Ok(()),
        }
    }

    /// As [`TraceValidator::check_frame`], but the hit counts are checked
    /// only against [`TraceLimits::max_hits_per_frame`], not id by id: for
    /// a writer whose hit counts are consistent by construction (the
    /// Manager's recorder lists each live slot's trace id at most once),
    /// where the per-id lookups were most of the cost of recording hits.
    pub(crate) fn check_frame_trusted_hits(&mut self, frame: &Frame) -> Result<(), FrameFault> {
        self.check_frame_events(frame)?;
        match (&frame.slot_hits, &frame.hits) {
            (Some(sh), _) => self.check_slot_hits(sh),
            (None, Some(hits)) => {
                check_hit_count(hits.len() as u64, &self.limits).map_err(FrameFault::frame)
            }
            (None, None) => Ok(()),
        }
    }

    /// Frame order, camera and every event of `frame`.
    fn check_frame_events(&mut self, frame: &Frame) -> Result<(), FrameFault> {
        self.begin_frame(frame.number, &frame.camera)?;
        check_event_count(frame.events.len() as u64, &self.limits).map_err(FrameFault::frame)?;
        for (i, e) in frame.events.iter().enumerate() {
            self.check_next_event(i as u32, e)?;
        }
        Ok(())
    }

    /// The first step of [`TraceValidator::check_frame`], for a reader that
    /// checks a frame while decoding it: frame order and camera.
    pub(crate) fn begin_frame(&mut self, number: u64, camera: &Camera) -> Result<(), FrameFault> {
        self.check_order(number).map_err(FrameFault::frame)?;
        check_camera(camera).map_err(FrameFault::frame)
    }

    /// Checks and applies event `i` of the frame begun last, so that a
    /// reader rejects a bad event before decoding the ones after it.
    pub(crate) fn check_next_event(&mut self, i: u32, e: &InstanceEvent) -> Result<(), FrameFault> {
        let at = |kind| FrameFault {
            event: Some(i),
            kind,
        };
        check_event(e, &self.meshes, &self.limits).map_err(at)?;
        if self.version < 2 && matches!(e, InstanceEvent::Add(a) if a.slot.is_some()) {
            return Err(at(TraceErrorKind::NotInVersion {
                what: "add slot",
                version: self.version,
            }));
        }
        if self.track_live {
            self.apply(e).map_err(at)?;
        }
        Ok(())
    }

    /// The last step of [`TraceValidator::check_frame`]: the frame's hit
    /// counts, after all its events.
    pub(crate) fn check_hits(&mut self, hits: &[InstanceHits]) -> Result<(), FrameFault> {
        check_hit_count(hits.len() as u64, &self.limits).map_err(FrameFault::frame)?;
        self.hit_ids.clear();
        for h in hits {
            if self.track_live && !self.live.contains_key(&h.id) {
                return Err(FrameFault::frame(TraceErrorKind::UnknownInstance {
                    op: "hits",
                    id: h.id,
                }));
            }
            if !self.hit_ids.insert(h.id) {
                return Err(FrameFault::frame(TraceErrorKind::DuplicateHits {
                    id: h.id,
                }));
            }
        }
        // Keep memory bounded by the largest frame, not the whole trace.
        if self.hit_ids.capacity() > 4 * hits.len().max(1024) {
            self.hit_ids = IdSet::default();
        }
        Ok(())
    }

    fn apply(&mut self, e: &InstanceEvent) -> Result<(), TraceErrorKind> {
        match e {
            InstanceEvent::Add(a) => {
                if self.live.contains_key(&a.id) {
                    return Err(TraceErrorKind::DuplicateInstance { id: a.id });
                }
                if self.live.len() >= self.limits.max_live_instances as usize {
                    return Err(TraceErrorKind::TooManyLiveInstances {
                        limit: self.limits.max_live_instances.into(),
                    });
                }
                if let Some(slot) = a.slot {
                    if let Some(holder) = self.slots.get(&slot) {
                        return Err(TraceErrorKind::SlotInUse {
                            slot,
                            id: holder.id,
                        });
                    }
                    let entry = SlotEntry {
                        id: a.id,
                        pinned: a.flags.contains(InstanceFlags::PINNED),
                        hitbox: self.hitbox_of(&a.pose.aabb),
                    };
                    self.slots.insert(slot, entry);
                }
                let slot = a.slot.unwrap_or(NO_SLOT);
                self.live.insert(a.id, Live { mesh: a.mesh, slot });
            }
            InstanceEvent::Update(u) => {
                let live = *self
                    .live
                    .get(&u.id)
                    .ok_or(TraceErrorKind::UnknownInstance {
                        op: "update",
                        id: u.id,
                    })?;
                if let Some(lod) = u.lod {
                    self.meshes.check_lod(live.mesh, lod)?;
                }
                if live.slot != NO_SLOT && (u.pose.is_some() || u.flags.is_some()) {
                    let hitbox = u.pose.map(|p| self.hitbox_of(&p.aabb));
                    if let Some(e) = self.slots.get_mut(&live.slot) {
                        if let Some(h) = hitbox {
                            e.hitbox = h;
                        }
                        if let Some(f) = u.flags {
                            e.pinned = f.contains(InstanceFlags::PINNED);
                        }
                    }
                }
            }
            InstanceEvent::Remove { id } => {
                let Some(live) = self.live.remove(id) else {
                    return Err(TraceErrorKind::UnknownInstance {
                        op: "remove",
                        id: *id,
                    });
                };
                if live.slot != NO_SLOT {
                    self.slots.remove(&live.slot);
                }
            }
        }
        Ok(())
    }

    fn hitbox_of(&self, aabb: &Aabb) -> Option<u32> {
        self.grid.as_ref().and_then(|g| g.hitbox_of(aabb))
    }

    /// Checks a frame's [`SlotHits`] (after its events): version 2; at most
    /// [`TraceLimits::max_live_instances`] (and
    /// [`TraceLimits::max_hits_per_frame`]) slots; counting boxes only in a
    /// bounded world, each a hitbox of its grid, in increasing order;
    /// while live instances are tracked, every non-zero slot held by one.
    pub(crate) fn check_slot_hits(&mut self, sh: &SlotHits) -> Result<(), FrameFault> {
        let fail = |kind| Err(FrameFault::frame(kind));
        if self.version < 2 {
            return fail(TraceErrorKind::NotInVersion {
                what: "slot hit counts",
                version: self.version,
            });
        }
        check_slot_count(sh.slots.len() as u64, &self.limits).map_err(FrameFault::frame)?;
        if !sh.boxes.is_empty() {
            let Some(grid) = &self.grid else {
                return fail(TraceErrorKind::InvalidValue {
                    what: "counting-box hits".into(),
                    reason: "an unbounded world has no hitbox grid to name them by".into(),
                });
            };
            let cells = grid.len();
            if sh.boxes.len() as u64 > u64::from(cells) {
                return fail(TraceErrorKind::LimitExceeded {
                    what: "counting-box hit counts in frame",
                    value: sh.boxes.len() as u64,
                    limit: cells.into(),
                });
            }
            let mut previous: Option<u32> = None;
            for b in &sh.boxes {
                if b.hitbox >= cells {
                    return fail(TraceErrorKind::InvalidValue {
                        what: format!("counting-box hitbox {}", b.hitbox),
                        reason: format!("the world grid has {cells} hitboxes"),
                    });
                }
                if previous.is_some_and(|p| b.hitbox <= p) {
                    return fail(TraceErrorKind::InvalidValue {
                        what: format!("counting-box hitbox {}", b.hitbox),
                        reason: "hitboxes must be listed in increasing order, each once".into(),
                    });
                }
                previous = Some(b.hitbox);
            }
        }
        if self.track_live {
            for (slot, &hits) in sh.slots.iter().enumerate() {
                if hits != 0 && !self.slots.contains_key(&(slot as u32)) {
                    return fail(TraceErrorKind::UnknownSlot {
                        slot: slot as u32,
                        hits,
                    });
                }
            }
        }
        Ok(())
    }

    /// The per-instance hits of a checked [`SlotHits`] (see its docs), in
    /// slot order, into `out`; `false` (and `out` empty) when live
    /// instances are not tracked (after a skipped frame), so slots cannot
    /// be named.
    pub(crate) fn derive_hits(&mut self, sh: &SlotHits, out: &mut Vec<InstanceHits>) -> bool {
        out.clear();
        if !self.track_live {
            return false;
        }
        let own = |slot: u32| sh.slots.get(slot as usize).copied().unwrap_or(0);
        if sh.boxes.is_empty() {
            for (slot, &hits) in sh.slots.iter().enumerate() {
                if hits != 0 {
                    if let Some(e) = self.slots.get(&(slot as u32)) {
                        out.push(InstanceHits { id: e.id, hits });
                    }
                }
            }
            return true;
        }
        let box_of = |e: &SlotEntry, slot: u32| -> Option<usize> {
            if e.pinned || own(slot) != 0 {
                return None;
            }
            let h = e.hitbox?;
            sh.boxes.binary_search_by_key(&h, |b| b.hitbox).ok()
        };
        self.shares.clear();
        self.shares.resize(sh.boxes.len(), [0; 4]);
        for (&slot, e) in &self.slots {
            if let Some(b) = box_of(e, slot) {
                self.shares[b][0] += 1;
            }
        }
        for (s, b) in self.shares.iter_mut().zip(&sh.boxes) {
            if let (Some(share), Some(rest)) = (b.hits.checked_div(s[0]), b.hits.checked_rem(s[0]))
            {
                s[1] = share;
                s[2] = rest;
            }
        }
        for (&slot, e) in &self.slots {
            let hits = match box_of(e, slot) {
                Some(b) => {
                    let s = &mut self.shares[b];
                    let h = s[1] + u32::from(s[3] < s[2]);
                    s[3] += 1;
                    h
                }
                None => own(slot),
            };
            if hits != 0 {
                out.push(InstanceHits { id: e.id, hits });
            }
        }
        true
    }
}

/// A version this crate reads and writes.
pub(crate) fn check_version(version: u16) -> Result<(), TraceErrorKind> {
    if (super::OLDEST_TRACE_VERSION..=super::TRACE_VERSION).contains(&version) {
        Ok(())
    } else {
        Err(TraceErrorKind::UnsupportedVersion {
            found: version.into(),
            supported: super::TRACE_VERSION,
        })
    }
}
