//! Recording a [`Manager`] as a trace (`docs/trace-format.md`): attach a
//! [`TraceRecorder`] and every instance change the engine makes through the
//! manager, the camera it passes ([`Manager::record_camera`]) and optionally
//! the hit counts of each frame are written as a lipac trace, so that an
//! engine gets a trace of its game with one call.
//!
//! ```
//! use glam::{Affine3A, Quat, Vec3};
//! use lipac_core::manager::{RecorderOptions, TraceRecorder};
//! use lipac_core::trace::{Camera, InstanceEvent, TraceReader};
//! use lipac_core::{Aabb, BuildEstimate, FrameBudgets, GridConfig, HitboxGrid, InstanceDesc};
//! use lipac_core::{Manager, ManagerConfig, MeshCatalog, MeshId, MeshLod};
//!
//! let mut catalog = MeshCatalog::new();
//! let estimate = BuildEstimate { primitives: 12, result_bytes: 1024,
//!                                build_scratch_bytes: 256, update_scratch_bytes: 0 };
//! catalog.insert(MeshId(1), vec![MeshLod { estimate, data_bytes: 64 }])?;
//! let grid = HitboxGrid::new(GridConfig { min: [0.0, 0.0], max: [64.0, 64.0], cell_size: 16.0 })?;
//! let mut manager = Manager::new(grid, ManagerConfig::new(0xC0BE), catalog)?;
//!
//! manager.attach_recorder(TraceRecorder::new(Vec::new(), RecorderOptions::default()))?;
//! let aabb = Aabb::new(Vec3::splat(7.0), Vec3::splat(9.0));
//! let house = manager.register(InstanceDesc::new(MeshId(1), Affine3A::IDENTITY, aabb))?;
//! manager.begin_frame(0)?;
//! manager.record_camera(Camera::look_to(Vec3::Y, Vec3::X, Vec3::Y, 1.0, 1.5))?;
//! manager.plan(&FrameBudgets::default())?;
//! manager.remove(house)?; // after frame 0's plan: part of frame 1
//! manager.begin_frame(1)?;
//! manager.plan(&FrameBudgets::default())?;
//! let bytes: Vec<u8> = manager.detach_recorder()?.into_writer().expect("a Vec<u8>");
//!
//! let mut reader = TraceReader::new(bytes.as_slice())?;
//! let f0 = reader.next_frame()?.expect("frame 0");
//! assert!(matches!(f0.events[..], [InstanceEvent::Add(ref a)] if a.id == 0));
//! let f1 = reader.next_frame()?.expect("frame 1");
//! assert_eq!(f1.events, [InstanceEvent::Remove { id: 0 }]);
//! assert_eq!(f1.camera, f0.camera); // no new camera: the last one is kept
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! # What goes into which frame
//!
//! Frame `n`'s record holds the changes made after the previous frame's
//! [`Manager::plan`] and up to frame `n`'s plan (the changes that frame `n`
//! uploads and renders; changes before the first plan go into the first
//! frame), the last camera passed by then, and — with
//! [`RecorderOptions::record_hits`] — the hits of frame `n`'s
//! [`Manager::process_feedback`] (CPU backends) or [`Manager::record_hits`]
//! (GPU backends: the read-back hits handed in during frame `n`). Frame `n`
//! is written when frame `n + 1` begins, or at [`Manager::detach_recorder`].
//! Changes made after the last plan are not written (counted in
//! [`FinishedTrace::unwritten_events`]).
//!
//! Hits: an instance's own hits; the hits of the counting box of a hitbox
//! (its inactive instances, and those in an inactive hitbox, which are not
//! traced: `crate::assembly`) are split evenly over those of them without
//! hits of their own, so that a hits-only replay feeds Algorithm 2 the same
//! hitbox totals. Instances registered after the frame's plan belong to
//! the next frame and get no hits in this one.
//!
//! The trace is format version 2: every `add` carries the instance's GPU
//! slot ([`AddInstance::slot`]) and a frame's hits are written by slot
//! ([`SlotHits`]: a copy of the per-slot hit counters, plus the counting
//! boxes of the inactive hitboxes by hitbox index), so recording costs no
//! pass over the instance records; readers split each box's hits over its
//! instances by the same rule and give back per-instance hits
//! ([`Frame::hits`]). That needs the trace's world to be the manager's
//! [`HitboxGrid`]; with a hashed index (or another
//! [`RecorderOptions::world`]) the recorder splits the boxes itself and
//! lists the hits by id, as in version 1. The recorder's ids and slots are
//! consistent by construction, so the writer does not track live
//! instances (values, meshes, LODs and limits are still checked). Cost at
//! 100k instances: `docs/BENCHMARKS.md`.
//!
//! # Header
//!
//! The header is written with the first frame: the scene name, the world
//! (the manager's [`HitboxGrid`], or [`RecorderOptions::world`]) and every
//! mesh of the [`MeshCatalog`] then (triangle counts per LOD), with the
//! bounds and geometry given by [`TraceRecorder::set_mesh_bounds`] and
//! [`TraceRecorder::set_geometry`] (default bounds: those of the geometry,
//! else the unit cube `[-0.5, 0.5]³`). A mesh registered later is an error.
//!
//! # Ids
//!
//! Trace ids count registrations from 0, so a slot reused after a removal
//! gets a new id ([`TraceRecorder::slot_id`], [`Manager::trace_id`]).
//!
//! # Errors
//!
//! The manager's state never depends on the recorder. A failed write (I/O,
//! limits, the trace validator) stops the recorder: it keeps the error,
//! drops what it buffered, and reports the error from every later
//! [`Manager::record_camera`], [`Manager::recorder_error`] and from
//! [`Manager::detach_recorder`]. Nothing panics.

use std::any::Any;
use std::collections::BTreeMap;
use std::fmt;
use std::io::Write;

use glam::{Quat, Vec3};

use super::{Manager, MeshCatalog};
use crate::grid::HitboxGrid;
use crate::hitbox_index::HitboxIndex;
use crate::instance::{InstanceDesc, MeshId};
use crate::layout::{HitboxRecord, InstanceHot, InstanceState};
use crate::math::{affine_to_rows, Aabb};
use crate::registry::InstanceHandle;
use crate::trace::{
    AddInstance, BoxHits, Camera, Frame, InstanceEvent, InstanceHits, JsonlWriter, LodGeometry,
    LodInfo, MeshInfo, Pose, SlotHits, TraceError, TraceErrorKind, TraceHeader, TraceLimits,
    TraceWriter, UpdateInstance, WorldInfo,
};

/// Settings of a [`TraceRecorder`].
#[derive(Clone, Debug, PartialEq)]
pub struct RecorderOptions {
    /// The header's scene name. Default `"recorded"`.
    pub scene_name: String,
    /// Record every frame's hit counts (see the [module docs](self)).
    /// Default `true`.
    pub record_hits: bool,
    /// The header's world; `None` (default) takes the manager's
    /// [`HitboxGrid`] (required for another hitbox structure). A world
    /// other than the manager's grid has no hitbox indices for counting
    /// boxes: the hits are then split here and listed by id.
    pub world: Option<WorldInfo>,
    /// The limits the writer checks against. Default [`TraceLimits::default`].
    pub limits: TraceLimits,
}

impl Default for RecorderOptions {
    fn default() -> Self {
        Self {
            scene_name: "recorded".into(),
            record_hits: true,
            world: None,
            limits: TraceLimits::default(),
        }
    }
}

/// What went wrong while recording.
#[derive(Clone, Debug, PartialEq)]
pub enum RecorderError {
    /// [`Manager::detach_recorder`] without a recorder.
    NotAttached,
    /// [`Manager::attach_recorder`] while one is attached.
    AlreadyAttached,
    /// The header cannot be made: what is wrong.
    Header {
        /// What is wrong.
        what: String,
    },
    /// A camera failed the trace's checks (nothing was recorded).
    InvalidCamera(TraceErrorKind),
    /// Writing the trace failed (I/O, limits or the validator); the recorder
    /// stopped at that point.
    Write(TraceError),
}

impl fmt::Display for RecorderError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NotAttached => write!(f, "no trace recorder is attached"),
            Self::AlreadyAttached => write!(f, "a trace recorder is already attached"),
            Self::Header { what } => write!(f, "trace recorder: header: {what}"),
            Self::InvalidCamera(k) => write!(f, "trace recorder: invalid camera: {k}"),
            Self::Write(e) => write!(f, "trace recorder stopped: {e}"),
        }
    }
}

impl std::error::Error for RecorderError {}

/// A finished recording, from [`Manager::detach_recorder`].
pub struct FinishedTrace {
    /// Frames written.
    pub frames: u64,
    /// Instance events written.
    pub events: u64,
    /// Changes made after the last plan, not written.
    pub unwritten_events: usize,
    writer: Box<dyn Any + Send + Sync>,
}

impl fmt::Debug for FinishedTrace {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("FinishedTrace")
            .field("frames", &self.frames)
            .field("events", &self.events)
            .field("unwritten_events", &self.unwritten_events)
            .finish_non_exhaustive()
    }
}

impl FinishedTrace {
    /// The writer given to [`TraceRecorder::new`] (flushed, the trace
    /// closed); `None` if `W` is not its type.
    pub fn into_writer<W: Any>(self) -> Option<W> {
        let any: Box<dyn Any> = self.writer;
        any.downcast::<W>().ok().map(|w| *w)
    }
}

/// The encoder behind a recorder, with its writer's type erased.
trait Sink: Send + Sync {
    fn start(&mut self, header: &TraceHeader, limits: TraceLimits) -> Result<(), TraceError>;
    fn write_frame(&mut self, frame: &Frame) -> Result<(), TraceError>;
    fn finish(self: Box<Self>) -> Result<Box<dyn Any + Send + Sync>, TraceError>;
}

enum SinkState<W: Write> {
    Pending(W),
    Binary(TraceWriter<W>),
    Jsonl(JsonlWriter<W>),
    Gone,
}

struct WriterSink<W: Write> {
    state: SinkState<W>,
    jsonl: bool,
}

fn gone() -> TraceError {
    TraceError {
        location: crate::trace::TraceLocation::Byte(0),
        frame_index: None,
        frame_number: None,
        event: None,
        kind: TraceErrorKind::InvalidValue {
            what: "trace recorder".into(),
            reason: "the writer was lost in an earlier error".into(),
        },
    }
}

impl<W: Write + Send + Sync + 'static> Sink for WriterSink<W> {
    fn start(&mut self, header: &TraceHeader, limits: TraceLimits) -> Result<(), TraceError> {
        let SinkState::Pending(w) = std::mem::replace(&mut self.state, SinkState::Gone) else {
            return Err(gone());
        };
        // Ids and slots come from the recorder's own table: consistent by
        // construction, so the writer does not track them (values, meshes,
        // LODs, limits are still checked).
        self.state = if self.jsonl {
            let mut w = JsonlWriter::with_limits(w, header, limits)?;
            w.trust_instance_ids();
            SinkState::Jsonl(w)
        } else {
            let mut w = TraceWriter::with_limits(w, header, limits)?;
            w.trust_instance_ids();
            SinkState::Binary(w)
        };
        Ok(())
    }
    fn write_frame(&mut self, frame: &Frame) -> Result<(), TraceError> {
        match &mut self.state {
            // The recorder's hits are consistent by construction (`on_hits`);
            // events, cameras and limits are checked as always.
            SinkState::Binary(w) => w.write_frame_trusted_hits(frame),
            SinkState::Jsonl(w) => w.write_frame_trusted_hits(frame),
            _ => Err(gone()),
        }
    }
    fn finish(self: Box<Self>) -> Result<Box<dyn Any + Send + Sync>, TraceError> {
        Ok(match self.state {
            SinkState::Binary(w) => Box::new(w.finish()?),
            SinkState::Jsonl(w) => Box::new(w.finish()?),
            SinkState::Pending(_) | SinkState::Gone => return Err(gone()),
        })
    }
}

/// Geometry and bounds the engine gave for one mesh.
#[derive(Clone, Debug, Default)]
struct MeshNotes {
    bounds: Option<Aabb>,
    geometry: BTreeMap<u32, LodGeometry>,
}

/// Records a [`Manager`] as a trace; see the [module docs](self).
pub struct TraceRecorder {
    options: RecorderOptions,
    sink: Option<Box<dyn Sink>>,
    notes: BTreeMap<MeshId, MeshNotes>,
    world: Option<WorldInfo>,
    header_meshes: Option<usize>,
    /// Trace id per GPU slot ([`NO_ID`]: none).
    ids: Vec<u64>,
    /// Per GPU slot: `u32::MAX` if its trace instance is live in the open
    /// frame, else 0 (none, removed, or added after the plan): the mask of
    /// the slot hits, one AND per slot.
    live_mask: Vec<u32>,
    /// Slots registered after the open frame's plan (live from the next
    /// frame on).
    post_plan: Vec<u32>,
    next_id: u64,
    /// `next_id` at the open frame's plan: ids from it on were added after
    /// the plan (in the next frame's events), so not live in this frame.
    split_id: u64,
    /// The frame begun last, not yet written.
    open: Option<u64>,
    /// Events not yet written; `events[..split]` belong to the open frame.
    events: Vec<InstanceEvent>,
    split: Option<usize>,
    camera: Camera,
    hits: Option<HitsOut>,
    /// Hits of a [`Manager::process_feedback`] that has not returned yet:
    /// they become `hits` only if it succeeds ([`TraceRecorder::settle_hits`]).
    pending: Option<HitsOut>,
    /// The hits list's allocation between frames.
    hits_buf: Vec<InstanceHits>,
    /// The slot hits' allocations between frames.
    slots_buf: SlotHits,
    /// The trace's world is the manager's [`HitboxGrid`]: counting-box hits
    /// are written by hitbox index ([`SlotHits::boxes`]); otherwise (a
    /// hashed index, or another world given) they are split here.
    boxes_by_grid: bool,
    /// Per hitbox: its culled instances' shares (scratch).
    per_hitbox: Vec<BoxShare>,
    /// Slots whose hits are their counting box's share, in slot order
    /// (scratch).
    culled: Vec<u32>,
    frame: Frame,
    frames: u64,
    written_events: u64,
    error: Option<RecorderError>,
}

impl fmt::Debug for TraceRecorder {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("TraceRecorder")
            .field("options", &self.options)
            .field("frames", &self.frames)
            .field("open", &self.open)
            .field("buffered_events", &self.events.len())
            .field("error", &self.error)
            .finish_non_exhaustive()
    }
}

/// The camera of frames before the engine passed one: at the origin,
/// looking along −Z, 60° vertical field of view, aspect 16:9.
pub const DEFAULT_CAMERA: Camera = Camera {
    position: Vec3::ZERO,
    orientation: Quat::IDENTITY,
    vertical_fov: std::f32::consts::FRAC_PI_3,
    aspect: 16.0 / 9.0,
};

impl TraceRecorder {
    /// A recorder writing the binary encoding to `writer`.
    pub fn new<W: Write + Send + Sync + 'static>(writer: W, options: RecorderOptions) -> Self {
        Self::with_sink(writer, options, false)
    }

    /// A recorder writing the JSON-lines encoding to `writer`.
    pub fn jsonl<W: Write + Send + Sync + 'static>(writer: W, options: RecorderOptions) -> Self {
        Self::with_sink(writer, options, true)
    }

    fn with_sink<W: Write + Send + Sync + 'static>(
        writer: W,
        options: RecorderOptions,
        jsonl: bool,
    ) -> Self {
        Self {
            options,
            sink: Some(Box::new(WriterSink {
                state: SinkState::Pending(writer),
                jsonl,
            })),
            notes: BTreeMap::new(),
            world: None,
            header_meshes: None,
            ids: Vec::new(),
            live_mask: Vec::new(),
            post_plan: Vec::new(),
            next_id: 0,
            split_id: u64::MAX,
            open: None,
            events: Vec::new(),
            split: None,
            camera: DEFAULT_CAMERA,
            hits: None,
            pending: None,
            hits_buf: Vec::new(),
            slots_buf: SlotHits::default(),
            boxes_by_grid: false,
            per_hitbox: Vec::new(),
            culled: Vec::new(),
            frame: Frame {
                number: 0,
                camera: DEFAULT_CAMERA,
                events: Vec::new(),
                hits: None,
                slot_hits: None,
            },
            frames: 0,
            written_events: 0,
            error: None,
        }
    }

    /// Object-space bounds of `mesh` for the header (before the first frame
    /// is written). Fails for non-finite or inverted bounds, or once the
    /// header is written.
    pub fn set_mesh_bounds(&mut self, mesh: MeshId, bounds: Aabb) -> Result<(), RecorderError> {
        self.check_unwritten()?;
        crate::trace::check_aabb("mesh bounds", &bounds, f32::INFINITY).map_err(|k| {
            RecorderError::Header {
                what: k.to_string(),
            }
        })?;
        self.notes.entry(mesh).or_default().bounds = Some(bounds);
        Ok(())
    }

    /// Geometry of LOD `lod` of `mesh` for the header (before the first
    /// frame is written). Checked against the catalog's triangle count when
    /// the header is written.
    pub fn set_geometry(
        &mut self,
        mesh: MeshId,
        lod: u32,
        geometry: LodGeometry,
    ) -> Result<(), RecorderError> {
        self.check_unwritten()?;
        self.notes
            .entry(mesh)
            .or_default()
            .geometry
            .insert(lod, geometry);
        Ok(())
    }

    fn check_unwritten(&self) -> Result<(), RecorderError> {
        if self.header_meshes.is_some() {
            return Err(RecorderError::Header {
                what: "the header was already written with the first frame".into(),
            });
        }
        Ok(())
    }

    /// The trace id of the live instance in GPU slot `slot`.
    pub fn slot_id(&self, slot: u32) -> Option<u64> {
        self.ids
            .get(slot as usize)
            .copied()
            .filter(|&id| id != NO_ID)
    }

    /// Frames written so far.
    pub fn frames_written(&self) -> u64 {
        self.frames
    }

    /// The error that stopped the recorder, if any.
    pub fn error(&self) -> Option<&RecorderError> {
        self.error.as_ref()
    }

    // ---- hooks (called by the manager) ------------------------------------

    fn push(&mut self, e: InstanceEvent) {
        if self.error.is_some() {
            return;
        }
        // Consecutive updates of one instance in one frame merge (the later
        // fields win): the same state before the frame renders.
        let mergeable = self.events.len() > self.split.unwrap_or(0);
        if let (InstanceEvent::Update(new), Some(InstanceEvent::Update(old))) =
            (&e, self.events.last_mut())
        {
            if old.id == new.id && mergeable {
                old.pose = new.pose.or(old.pose);
                old.lod = new.lod.or(old.lod);
                old.flags = new.flags.or(old.flags);
                old.mask = new.mask.or(old.mask);
                return;
            }
        }
        self.events.push(e);
    }

    pub(super) fn on_register(&mut self, slot: u32, desc: &InstanceDesc) {
        let id = self.next_id;
        self.next_id += 1;
        let i = slot as usize;
        if self.ids.len() <= i {
            self.ids.resize(i + 1, NO_ID);
            self.live_mask.resize(i + 1, 0);
        }
        self.ids[i] = id;
        // Registered after the plan: in the next frame's events.
        self.live_mask[i] = if self.split.is_some() {
            self.post_plan.push(slot);
            0
        } else {
            u32::MAX
        };
        self.push(InstanceEvent::Add(AddInstance {
            id,
            mesh: desc.mesh,
            lod: desc.lod,
            flags: desc.flags,
            mask: (desc.mask != 0xFF).then_some(desc.mask),
            pose: pose(desc),
            slot: Some(slot),
        }));
    }

    pub(super) fn on_update(&mut self, slot: u32, desc: &InstanceDesc, old: &InstanceDesc) {
        if let Some(id) = self.slot_id(slot) {
            self.push(InstanceEvent::Update(UpdateInstance {
                id,
                pose: Some(pose(desc)),
                lod: (desc.lod != old.lod).then_some(desc.lod),
                flags: (desc.flags != old.flags).then_some(desc.flags),
                mask: (desc.mask != old.mask).then_some(desc.mask),
            }));
        }
    }

    pub(super) fn on_pose(&mut self, slot: u32, transform: &glam::Affine3A, aabb: Aabb) {
        if let Some(id) = self.slot_id(slot) {
            self.push(InstanceEvent::Update(UpdateInstance {
                id,
                pose: Some(Pose {
                    transform: affine_to_rows(transform),
                    aabb,
                }),
                lod: None,
                flags: None,
                mask: None,
            }));
        }
    }

    pub(super) fn on_lod(&mut self, slot: u32, lod: u32) {
        if let Some(id) = self.slot_id(slot) {
            self.push(InstanceEvent::Update(UpdateInstance {
                id,
                pose: None,
                lod: Some(lod),
                flags: None,
                mask: None,
            }));
        }
    }

    pub(super) fn on_remove(&mut self, slot: u32) {
        if let Some(m) = self.live_mask.get_mut(slot as usize) {
            *m = 0;
        }
        if let Some(id) = self.ids.get_mut(slot as usize) {
            let id = std::mem::replace(id, NO_ID);
            if id != NO_ID {
                self.push(InstanceEvent::Remove { id });
            }
        }
    }

    pub(super) fn on_plan(&mut self) {
        if self.open.is_some() && self.split.is_none() {
            self.split = Some(self.events.len());
            self.split_id = self.next_id;
        }
    }

    pub(super) fn on_begin_frame(&mut self, frame: u64, catalog: &MeshCatalog) {
        self.close_frame(catalog);
        self.open = Some(frame);
        if let Some(h) = self.hits.take() {
            self.recycle(h);
        }
        for slot in self.post_plan.drain(..) {
            let i = slot as usize;
            if self.ids.get(i).is_some_and(|&id| id != NO_ID) {
                self.live_mask[i] = u32::MAX;
            }
        }
    }

    /// Keeps the allocations of hits no longer needed.
    fn recycle(&mut self, h: HitsOut) {
        match h {
            HitsOut::List(v) => self.hits_buf = v,
            HitsOut::Slots(v) => self.slots_buf = v,
        }
    }

    /// Hits of the open frame, by slot (format version 2, [`SlotHits`]):
    /// each slot's own hits as they are (one copy; 0 for slots whose
    /// instance is not live in the open frame: not recorded, removed, or
    /// added after the plan), and with `boxes` the counting-box hits of
    /// every inactive hitbox that has some (an active hitbox has no
    /// counting box). A reader splits those over the box's instances as
    /// [`TraceRecorder::on_hits`] would (see [`SlotHits`]). No pass over
    /// the instance records: the cost is a copy of the hit counters and a
    /// pass over the hitboxes.
    fn slot_hits(&mut self, hits: &[u32], boxes: &[HitboxRecord]) -> SlotHits {
        let mut out = std::mem::take(&mut self.slots_buf);
        let n = hits.len().min(self.live_mask.len());
        out.slots.clear();
        // One AND per slot (vectorised): slots whose instance is not live
        // in the open frame get 0.
        out.slots.extend(
            hits[..n]
                .iter()
                .zip(&self.live_mask[..n])
                .map(|(&h, &m)| h & m),
        );
        out.boxes.clear();
        out.boxes.extend(
            boxes
                .iter()
                .enumerate()
                .filter(|(_, b)| !b.is_active() && b.hits() > 0)
                .map(|(i, b)| BoxHits {
                    hitbox: i as u32,
                    hits: b.hits(),
                }),
        );
        out
    }

    /// Hits of the open frame: per slot its own hits, or, for an instance
    /// without hits of its own that is reduced into its hitbox's counting
    /// box, its share of the box's hits (the first `total % k` of the `k`
    /// such instances of a box, by slot, take one more). Listed by slot,
    /// without zeros.
    ///
    /// Consistent by construction (so the writer does not look each id up):
    /// every listed id is a live slot's, each slot at most once, and ids
    /// added after the open frame's plan (not live in it) are left out.
    ///
    /// Cost: one pass over the hit counters and ids; an instance's record is
    /// read only when it has no hits of its own (a traced instance is not
    /// culled), and a second pass gives out the box shares.
    pub(super) fn on_hits(
        &mut self,
        hits: &[u32],
        records: Option<(&[InstanceHot], &[HitboxRecord])>,
    ) {
        if !self.options.record_hits || self.error.is_some() || self.open.is_none() {
            return;
        }
        match records {
            // Read-back hits ([`Manager::record_hits`]): nothing can refuse them.
            None => {
                let sh = self.slot_hits(hits, &[]);
                self.replace_hits(HitsOut::Slots(sh));
                return;
            }
            Some((_, boxes)) if self.boxes_by_grid => {
                if let Some(p) = self.pending.take() {
                    self.recycle(p);
                }
                let sh = self.slot_hits(hits, boxes);
                self.pending = Some(HitsOut::Slots(sh));
                return;
            }
            Some(_) => {}
        }
        let mut out = match self.pending.take() {
            Some(HitsOut::List(v)) => v,
            other => {
                if let Some(o) = other {
                    self.recycle(o);
                }
                std::mem::take(&mut self.hits_buf)
            }
        };
        out.clear();
        // Ids from `limit` on are not live in the open frame.
        let limit = if self.split.is_some() {
            self.split_id
        } else {
            self.next_id
        };
        let n = hits.len().min(self.ids.len());
        let (hits, ids) = (&hits[..n], &self.ids[..n]);
        let (records, boxes) = records.unwrap_or((&[], &[]));
        // Pass 1 (only slots without own hits): per hitbox with hits, its
        // culled instances (k); those slots, in order.
        let per = &mut self.per_hitbox;
        let culled = &mut self.culled;
        culled.clear();
        if !boxes.is_empty() {
            per.clear();
            per.resize(boxes.len(), BoxShare::default());
            for (slot, ((&own, &id), r)) in hits.iter().zip(ids).zip(records).enumerate() {
                if own != 0 || id >= limit {
                    continue;
                }
                let b = r.hitbox as usize;
                let Some(hb) = boxes.get(b) else { continue };
                // Reduced into the counting box (`crate::assembly`): not
                // pinned, and inactive or in an inactive hitbox.
                let reduced =
                    !r.is_pinned() && (r.state() == InstanceState::Inactive || !hb.is_active());
                if hb.hits() > 0 && reduced {
                    per[b].k += 1;
                    culled.push(slot as u32);
                }
            }
            for (p, hb) in per.iter_mut().zip(boxes) {
                if let (Some(share), Some(plus_one)) =
                    (hb.hits().checked_div(p.k), hb.hits().checked_rem(p.k))
                {
                    p.share = share;
                    p.plus_one = plus_one;
                }
            }
        }
        out.reserve(n.min(1 << 20));
        // Pass 2: own hits between the culled slots, then each culled
        // slot's share.
        let mut from = 0;
        for &slot in culled.iter().chain(std::iter::once(&(n as u32))) {
            let to = slot as usize;
            out.extend(
                hits[from..to]
                    .iter()
                    .zip(&ids[from..to])
                    .filter(|&(&own, &id)| own != 0 && id < limit)
                    .map(|(&own, &id)| InstanceHits { id, hits: own }),
            );
            if to < n {
                let p = &mut per[records[to].hitbox as usize];
                let h = p.share + u32::from(p.seen < p.plus_one);
                p.seen += 1;
                if h > 0 {
                    out.push(InstanceHits {
                        id: ids[to],
                        hits: h,
                    });
                }
            }
            from = to + 1;
        }
        self.pending = Some(HitsOut::List(out));
    }

    /// Makes `hits` the open frame's hit counts (its earlier ones, if any,
    /// are replaced and their buffers kept).
    fn replace_hits(&mut self, hits: HitsOut) {
        if let Some(old) = self.hits.replace(hits) {
            self.recycle(old);
        }
    }

    /// After [`Manager::process_feedback`]: its hits (taken before
    /// Algorithm 2 changed the states) count only if it `succeeded`; a
    /// refused call (call order) leaves the frame's hits as they were.
    pub(super) fn settle_hits(&mut self, succeeded: bool) {
        if let Some(p) = self.pending.take() {
            if succeeded && self.error.is_none() {
                self.replace_hits(p);
            } else {
                self.recycle(p);
            }
        }
    }

    /// Writes the open frame (and the header before the first one).
    fn close_frame(&mut self, catalog: &MeshCatalog) {
        let Some(number) = self.open.take() else {
            return;
        };
        if self.error.is_some() {
            return;
        }
        if let Err(e) = self.write_open(number, catalog) {
            self.fail(e);
        }
    }

    fn write_open(&mut self, number: u64, catalog: &MeshCatalog) -> Result<(), RecorderError> {
        self.ensure_header(catalog)?;
        let split = self.split.take().unwrap_or(self.events.len());
        let mut frame = std::mem::replace(
            &mut self.frame,
            Frame {
                number: 0,
                camera: DEFAULT_CAMERA,
                events: Vec::new(),
                hits: None,
                slot_hits: None,
            },
        );
        frame.number = number;
        frame.camera = self.camera;
        frame.events.clear();
        frame.events.extend(self.events.drain(..split));
        match self.hits.take() {
            Some(HitsOut::List(v)) => frame.hits = Some(v),
            Some(HitsOut::Slots(v)) => frame.slot_hits = Some(v),
            None => {}
        }
        let sink = self.sink.as_mut().ok_or(RecorderError::Write(gone()))?;
        let r = sink.write_frame(&frame);
        self.frames += u64::from(r.is_ok());
        self.written_events += frame.events.len() as u64;
        if let Some(v) = frame.hits.take() {
            self.hits_buf = v;
        }
        if let Some(v) = frame.slot_hits.take() {
            self.slots_buf = v;
        }
        self.frame = frame;
        r.map_err(RecorderError::Write)
    }

    fn ensure_header(&mut self, catalog: &MeshCatalog) -> Result<(), RecorderError> {
        if let Some(n) = self.header_meshes {
            if catalog.len() != n {
                return Err(RecorderError::Header {
                    what: format!(
                        "{} meshes registered after the trace header was written",
                        catalog.len() - n.min(catalog.len())
                    ),
                });
            }
            return Ok(());
        }
        let header = self.header(catalog)?;
        let sink = self.sink.as_mut().ok_or(RecorderError::Write(gone()))?;
        sink.start(&header, self.options.limits)
            .map_err(RecorderError::Write)?;
        self.header_meshes = Some(catalog.len());
        Ok(())
    }

    fn header(&mut self, catalog: &MeshCatalog) -> Result<TraceHeader, RecorderError> {
        let world = self.world.ok_or_else(|| RecorderError::Header {
            what: "no world: not a HitboxGrid manager and RecorderOptions::world unset".into(),
        })?;
        let mut meshes = Vec::with_capacity(catalog.len());
        for (mesh, lods) in catalog.iter() {
            let mut notes = self.notes.remove(&mesh).unwrap_or_default();
            let mut infos = Vec::with_capacity(lods.len());
            let mut geometry_bounds: Option<Aabb> = None;
            for (i, l) in lods.iter().enumerate() {
                let triangles =
                    u32::try_from(l.triangles()).map_err(|_| RecorderError::Header {
                        what: format!(
                            "mesh {}: LOD {i} has {} triangles, more than a trace holds",
                            mesh.0,
                            l.triangles()
                        ),
                    })?;
                let geometry = notes.geometry.remove(&(i as u32));
                if let Some(g) = &geometry {
                    for p in &g.positions {
                        let p = Vec3::from_array(*p);
                        geometry_bounds = Some(match geometry_bounds {
                            Some(b) => Aabb::new(b.min.min(p), b.max.max(p)),
                            None => Aabb::new(p, p),
                        });
                    }
                }
                infos.push(LodInfo {
                    triangles,
                    geometry,
                });
            }
            if let Some((&lod, _)) = notes.geometry.iter().next() {
                return Err(RecorderError::Header {
                    what: format!(
                        "geometry given for LOD {lod} of mesh {}, which has {} LODs",
                        mesh.0,
                        lods.len()
                    ),
                });
            }
            meshes.push(MeshInfo {
                id: mesh,
                bounds: notes
                    .bounds
                    .or(geometry_bounds)
                    .unwrap_or(Aabb::new(Vec3::splat(-0.5), Vec3::splat(0.5))),
                lods: infos,
            });
        }
        if let Some(mesh) = self.notes.keys().next() {
            return Err(RecorderError::Header {
                what: format!(
                    "bounds or geometry given for mesh {}, not in the catalog",
                    mesh.0
                ),
            });
        }
        meshes.sort_by_key(|m| m.id.0);
        Ok(TraceHeader {
            scene_name: self.options.scene_name.clone(),
            world,
            meshes,
        })
    }

    fn fail(&mut self, e: RecorderError) {
        self.error = Some(e);
        self.events = Vec::new();
        self.hits = None;
        self.pending = None;
        self.split = None;
    }

    /// Closes the open frame and the trace.
    fn finish(mut self, catalog: &MeshCatalog) -> Result<FinishedTrace, RecorderError> {
        let unwritten = if self.open.is_some() {
            self.events.len() - self.split.unwrap_or(self.events.len())
        } else {
            self.events.len()
        };
        self.close_frame(catalog);
        if let Some(e) = self.error.take() {
            return Err(e);
        }
        // An empty recording still gets its header.
        self.ensure_header(catalog)?;
        let sink = self.sink.take().ok_or(RecorderError::Write(gone()))?;
        let writer = sink.finish().map_err(RecorderError::Write)?;
        Ok(FinishedTrace {
            frames: self.frames,
            events: self.written_events,
            unwritten_events: unwritten,
            writer,
        })
    }
}

/// No trace id (a slot without a recorded instance).
const NO_ID: u64 = u64::MAX;

/// A frame's recorded hits: listed by id with the box shares split here
/// (worlds other than the manager's grid), or by slot.
#[derive(Debug)]
enum HitsOut {
    List(Vec<InstanceHits>),
    Slots(SlotHits),
}

/// A counting box's hits split over its `k` culled instances: each gets
/// `share`, the first `plus_one` (by slot) one more.
#[derive(Clone, Copy, Debug, Default)]
struct BoxShare {
    k: u32,
    share: u32,
    plus_one: u32,
    seen: u32,
}

fn pose(desc: &InstanceDesc) -> Pose {
    Pose {
        transform: affine_to_rows(&desc.transform),
        aabb: desc.aabb,
    }
}

impl<H: HitboxIndex + 'static> Manager<H> {
    /// Attaches `recorder`: from now on every instance change, camera and
    /// (optionally) the hits are recorded (see [`recorder`](self)). Fails
    /// if one is attached, or if there is no world for the header (a hitbox
    /// structure other than [`HitboxGrid`] or a
    /// [`HashedHitboxes`](crate::hashed_hitboxes::HashedHitboxes) anchored
    /// at the origin, whose world is [`WorldInfo::unbounded`], without
    /// [`RecorderOptions::world`]). Instances registered before are not in
    /// the trace.
    pub fn attach_recorder(&mut self, mut recorder: TraceRecorder) -> Result<(), RecorderError> {
        if self.recorder.is_some() {
            return Err(RecorderError::AlreadyAttached);
        }
        let index = self.culling.registry().hitbox_index() as &dyn Any;
        let grid = index.downcast_ref::<HitboxGrid>();
        // A hashed index anchored at the origin records an unbounded world.
        let hashed = index
            .downcast_ref::<crate::hashed_hitboxes::HashedHitboxes>()
            .filter(|h| h.config().origin == [0.0, 0.0])
            .map(|h| WorldInfo::unbounded(h.config().cell_size));
        let world = recorder
            .options
            .world
            .or_else(|| {
                grid.map(|g| WorldInfo {
                    min: g.min(),
                    max: g.max(),
                    cell_size: g.cell_size(),
                })
            })
            .or(hashed)
            .ok_or_else(|| RecorderError::Header {
                what: "no world: not a HitboxGrid manager and RecorderOptions::world unset".into(),
            })?;
        recorder.boxes_by_grid = grid.is_some_and(|g| {
            world
                == WorldInfo {
                    min: g.min(),
                    max: g.max(),
                    cell_size: g.cell_size(),
                }
        });
        recorder.world = Some(world);
        if let Some(frame) = self.frame {
            recorder.open = Some(frame);
            if self.planned == Some(frame) {
                recorder.split = Some(0);
                recorder.split_id = recorder.next_id;
            }
        }
        self.recorder = Some(Box::new(recorder));
        Ok(())
    }
}

impl<H: HitboxIndex> Manager<H> {
    /// Detaches the recorder: writes the open frame, closes the trace and
    /// returns the writer ([`FinishedTrace::into_writer`]). Errors: none
    /// attached, or the error that stopped it.
    pub fn detach_recorder(&mut self) -> Result<FinishedTrace, RecorderError> {
        let r = self.recorder.take().ok_or(RecorderError::NotAttached)?;
        r.finish(&self.catalog)
    }

    /// The attached recorder.
    pub fn recorder(&self) -> Option<&TraceRecorder> {
        self.recorder.as_deref()
    }

    /// The attached recorder, e.g. to add geometry before the first frame
    /// is written.
    pub fn recorder_mut(&mut self) -> Option<&mut TraceRecorder> {
        self.recorder.as_deref_mut()
    }

    /// The error that stopped the attached recorder, if any.
    pub fn recorder_error(&self) -> Option<&RecorderError> {
        self.recorder.as_ref().and_then(|r| r.error())
    }

    /// The trace id of a live instance, if a recorder is attached and
    /// recorded its registration.
    pub fn trace_id(&self, handle: InstanceHandle) -> Option<u64> {
        let slot = self.culling.registry().slot(handle).ok()?;
        self.recorder.as_ref()?.slot_id(slot)
    }

    /// The camera of the current frame for the recorder (kept for later
    /// frames until the next call). Without a recorder it does nothing.
    /// Errors: a camera the trace format rejects (nothing recorded), or the
    /// error that stopped the recorder.
    pub fn record_camera(&mut self, camera: Camera) -> Result<(), RecorderError> {
        let Some(r) = self.recorder.as_mut() else {
            return Ok(());
        };
        if let Some(e) = &r.error {
            return Err(e.clone());
        }
        crate::trace::check_camera(&camera).map_err(RecorderError::InvalidCamera)?;
        r.camera = camera;
        Ok(())
    }

    /// Hook: runs `f` on the attached recorder.
    pub(super) fn record(&mut self, f: impl FnOnce(&mut TraceRecorder)) {
        if let Some(r) = self.recorder.as_deref_mut() {
            f(r);
        }
    }

    /// Hook: runs `f` on the attached recorder with `handle`'s slot.
    pub(super) fn record_slot(
        &mut self,
        handle: InstanceHandle,
        f: impl FnOnce(&mut TraceRecorder, u32),
    ) {
        if let Some(r) = self.recorder.as_deref_mut() {
            if let Ok(slot) = self.culling.registry().slot(handle) {
                f(r, slot);
            }
        }
    }

    /// Hook: the frame begins (the previous one is written).
    pub(super) fn record_begin(&mut self, frame: u64) {
        if let Some(r) = self.recorder.as_deref_mut() {
            r.on_begin_frame(frame, &self.catalog);
        }
    }

    /// Hook: this frame's hits (`None`: the manager's own per-slot hits of
    /// Algorithm 2 with the counting boxes; `Some`: read-back hits).
    pub(super) fn record_frame_hits(&mut self, hits: Option<&[u32]>) {
        if let Some(r) = self.recorder.as_deref_mut() {
            match hits {
                Some(h) => r.on_hits(h, None),
                None => {
                    let reg = self.culling.registry();
                    r.on_hits(
                        self.culling.instance_hits(),
                        Some((reg.records().hot(), self.culling.hitboxes())),
                    );
                }
            }
        }
    }
}
