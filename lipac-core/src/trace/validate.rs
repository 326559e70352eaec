//! [`TraceValidator`]: the rules that span events and frames.

use super::error::TraceErrorKind;
use super::model::{
    check_camera, check_event, check_event_count, check_header, check_hit_count, Camera, Frame,
    InstanceEvent, InstanceHits, MeshTable, TraceHeader, TraceLimits,
};
use crate::instance::MeshId;
use std::collections::{HashMap, HashSet};

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
/// Memory grows with the number of *live* instances (one map entry each),
/// never with the length of the trace. After an error the validator's state
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
/// let frame = Frame { number: 0, camera, events: vec![InstanceEvent::Remove { id: 9 }], hits: None };
/// let fault = v.check_frame(&frame).unwrap_err();
/// assert_eq!(fault.event, Some(0));
/// assert_eq!(fault.kind, TraceErrorKind::UnknownInstance { op: "remove", id: 9 });
/// # Ok::<(), TraceErrorKind>(())
/// ```
#[derive(Clone, Debug)]
pub struct TraceValidator {
    limits: TraceLimits,
    meshes: MeshTable,
    live: IdMap<MeshId>,
    track_live: bool,
    last_frame: Option<u64>,
    frames: u64,
    hit_ids: IdSet,
}

impl TraceValidator {
    /// A validator for frames following `header`; checks the header first.
    pub fn new(header: &TraceHeader, limits: TraceLimits) -> Result<Self, TraceErrorKind> {
        let meshes = check_header(header, &limits)?;
        Ok(Self::with_meshes(meshes, limits))
    }

    pub(crate) fn with_meshes(meshes: MeshTable, limits: TraceLimits) -> Self {
        Self {
            limits,
            meshes,
            live: IdMap::default(),
            track_live: true,
            last_frame: None,
            frames: 0,
            hit_ids: IdSet::default(),
        }
    }

    /// Stops tracking live instances (frames were skipped unread, so the set
    /// of live ids is unknown); later frames get only the checks that need
    /// no history: header references, values, frame order.
    pub fn stop_tracking_live(&mut self) {
        self.track_live = false;
        self.live = IdMap::default();
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
    pub fn check_frame(&mut self, frame: &Frame) -> Result<(), FrameFault> {
        self.check_frame_events(frame)?;
        match &frame.hits {
            Some(hits) => self.check_hits(hits),
            None => Ok(()),
        }
    }

    /// As [`TraceValidator::check_frame`], but the hit counts are checked
    /// only against [`TraceLimits::max_hits_per_frame`], not id by id: for
    /// a writer whose hit counts are consistent by construction (the
    /// Manager's recorder lists each live slot's trace id at most once),
    /// where the per-id lookups were most of the cost of recording hits.
    pub(crate) fn check_frame_trusted_hits(&mut self, frame: &Frame) -> Result<(), FrameFault> {
        self.check_frame_events(frame)?;
        match &frame.hits {
            Some(hits) => {
                check_hit_count(hits.len() as u64, &self.limits).map_err(FrameFault::frame)
            }
            None => Ok(()),
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
                self.live.insert(a.id, a.mesh);
            }
            InstanceEvent::Update(u) => {
                let mesh = *self
                    .live
                    .get(&u.id)
                    .ok_or(TraceErrorKind::UnknownInstance {
                        op: "update",
                        id: u.id,
                    })?;
                if let Some(lod) = u.lod {
                    self.meshes.check_lod(mesh, lod)?;
                }
            }
            InstanceEvent::Remove { id } => {
                if self.live.remove(id).is_none() {
                    return Err(TraceErrorKind::UnknownInstance {
                        op: "remove",
                        id: *id,
                    });
                }
            }
        }
        Ok(())
    }
}
