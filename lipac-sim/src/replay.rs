//! Replaying a recorded trace ([`lipac_core::trace`]): the strategies run on
//! its frames and produce the same [`CompareReport`] as
//! [`crate::compare`].
//!
//! Two modes ([`ReplayMode`]):
//!
//! * **Geometry**: the trace names a built-in scene ([`SceneRef`], written
//!   by [`crate::record`]). The scene is regenerated from its seed (the
//!   header's meshes are checked against it) and every frame goes through
//!   the CPU path tracer exactly as in `compare` ([`Comparison`]): ground
//!   truth, every strategy, error included. Cameras come from the trace;
//!   where a recorded camera equals the named path's camera bit for bit, the
//!   path's camera is used, so a recording replays to exactly `compare`'s
//!   numbers. Instance poses are the scene's animation at the recorded frame
//!   number; a recorded pose that differs from it, or instances added or
//!   removed after the first frame, are refused (the tracer's geometry and
//!   materials come from the generator, not from the trace). LODs are the
//!   distance policy's, as recorded.
//! * **Hits only** ([`hits`]): any trace whose frames all carry hit counts.
//!   No geometry is traced: LiPaC's state machine (a
//!   [`lipac_core::manager::Manager`] in [`crate::cpu_backend`]) is driven
//!   by the recorded hits, and
//!   the full scene serves as the baseline. Memory, builds, state changes and
//!   latency are reported; the error is not available (`NaN` in the
//!   report, `null` in its JSON).
//!
//! A trace of any other scene whose header carries geometry replays in
//! geometry mode through [`crate::trace_scene`] (`trace_scene::replay_path`
//! picks the mode for a trace file; `lipac replay` goes through it).
//!
//! The trace is read frame by frame ([`TraceInput::next_frame_into`] reuses
//! one [`Frame`]); apart from the per-frame metrics kept for the report (see
//! [`ReplayConfig::keep_frames`]), memory follows the live instances, not the
//! trace's length. Every error names where: the trace's own errors their
//! byte offset or line, frame and event; any other error the frame read
//! last ([`TraceInput::position`]).

pub mod hits;

use std::fs::File;
use std::io::Read;
use std::path::Path;

use glam::{Quat, Vec3};
use lipac_core::grid::HitboxGrid;
use lipac_core::hitbox_index::HitboxIndex;
use lipac_core::trace::{
    self, Frame, InstanceEvent, JsonlReader, Peeked, TraceError, TraceErrorKind, TraceFormat,
    TraceHeader, TraceLocation, TraceReader,
};

use crate::camera::FlyCamera;
use crate::compare::{CompareConfig, CompareReport, Comparison, Contender, LipacStart};
use crate::device_profile::DeviceProfile;
use crate::error::SimError;
use crate::record::{from_trace_camera, header, same_pose, to_trace_camera, SceneRef};
use crate::scene::Scene;
use crate::snapshot::Snapshot;
use crate::strategy::hindsight::Hindsight;
use crate::strategy::lipac::{Lipac, LipacConfig};
use crate::strategy::StrategyKind;

/// How a trace is replayed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReplayMode {
    /// Through the CPU path tracer (built-in scene regenerated).
    Geometry,
    /// Through the state machine, driven by recorded hit counts.
    HitsOnly,
}

/// Settings of a replay.
#[derive(Clone, Debug, PartialEq)]
pub struct ReplayConfig {
    /// Strategies, in report order (empty: every strategy the mode supports).
    pub strategies: Vec<StrategyKind>,
    /// Image width (geometry mode).
    pub width: u32,
    /// Image height (geometry mode).
    pub height: u32,
    /// Render threads (0 = all cores).
    pub threads: usize,
    /// The mode (`None`: geometry if the trace names a built-in scene,
    /// otherwise hits only).
    pub mode: Option<ReplayMode>,
    /// Keep every frame's metrics in the report (hits-only mode; geometry
    /// mode always keeps them). Without it the summaries still cover every
    /// frame, and the per-frame series (plots, `frames.csv`) is down-sampled
    /// evenly to at most [`hits::MAX_SERIES_FRAMES`] frames, so memory does
    /// not grow with the trace's length.
    pub keep_frames: bool,
    /// Frame numbers to take [`Snapshot`]s of (geometry mode only; see
    /// [`replay_with_snapshots`]).
    pub snapshots: Vec<u32>,
    /// How LiPaC starts ([`CompareConfig::lipac_start`]).
    pub lipac_start: LipacStart,
    /// LiPaC warm-starts again at each camera cut
    /// ([`CompareConfig::lipac_warm_start_at_cuts`]); a geometry replay
    /// finds the cuts from the recorded cameras
    /// ([`crate::camera::FlyCamera::is_cut_from`]: traces do not mark
    /// them).
    pub warm_start_at_cuts: bool,
    /// Frames LiPaC holds what a warm start activates
    /// ([`CompareConfig::lipac_warm_start_hold`]).
    pub warm_start_hold: Option<u32>,
    /// Further LiPaC configurations run beside `strategies`, each under
    /// its report name (geometry mode; `lipac sweep --trace` puts its
    /// LiPaC variants here). Names must differ from each other and from
    /// the strategies'.
    pub lipac_variants: Vec<(String, LipacConfig)>,
    /// Hindsight references run beside `strategies`, each under its report
    /// name with its window in frames (geometry mode; `lipac sweep
    /// --trace` puts its hindsight windows here). Names as for
    /// `lipac_variants`.
    pub hindsight_variants: Vec<(String, u32)>,
    /// The device profile of the memory axis and the modelled GPU time
    /// ([`CompareConfig::device`]; both modes).
    pub device: DeviceProfile,
}

impl ReplayConfig {
    /// The [`CompareConfig`] a geometry replay runs with: every frame the
    /// trace has, these strategies (all when none are named and there are
    /// no [`ReplayConfig::lipac_variants`]), image size and threads, one
    /// ground truth shared by the strategies.
    pub fn compare_config(&self) -> CompareConfig {
        CompareConfig {
            frames: None,
            width: self.width,
            height: self.height,
            strategies: if self.strategies.is_empty()
                && self.lipac_variants.is_empty()
                && self.hindsight_variants.is_empty()
            {
                StrategyKind::DEFAULT.to_vec()
            } else {
                self.strategies.clone()
            },
            share_ground_truth: true,
            threads: self.threads,
            adaptive_levels: None,
            lipac_cell_size: None,
            lipac_rise_shift: None,
            lipac_start: self.lipac_start,
            lipac_warm_start_at_cuts: self.warm_start_at_cuts,
            lipac_warm_start_hold: self.warm_start_hold,
            device: self.device.clone(),
        }
    }

    /// The comparison of a geometry replay on `scene` named `name`: the
    /// strategies of [`ReplayConfig::compare_config`], then the
    /// [`ReplayConfig::lipac_variants`] and the
    /// [`ReplayConfig::hindsight_variants`].
    pub(crate) fn comparison(&self, name: &str, scene: &Scene) -> Result<Comparison, SimError> {
        let cc = self.compare_config();
        let memory = cc.device.memory_model();
        let mut contenders = crate::compare::contenders_of(scene, &cc)?;
        for (variant, config) in &self.lipac_variants {
            contenders.push(Contender {
                name: variant.clone(),
                strategy: Box::new(Lipac::new(scene, config.clone())?),
            });
        }
        for (variant, frames) in &self.hindsight_variants {
            contenders.push(Contender {
                name: variant.clone(),
                strategy: Box::new(Hindsight::with_memory(scene, *frames, &memory)?),
            });
        }
        Comparison::with_contenders(name, scene, &cc, contenders)
    }
}

impl Default for ReplayConfig {
    /// 128 x 72 (as `compare`), all strategies, automatic mode, frames kept.
    fn default() -> Self {
        Self {
            strategies: Vec::new(),
            width: 128,
            height: 72,
            threads: 0,
            mode: None,
            keep_frames: true,
            snapshots: Vec::new(),
            lipac_start: LipacStart::Default,
            warm_start_at_cuts: false,
            warm_start_hold: None,
            lipac_variants: Vec::new(),
            hindsight_variants: Vec::new(),
            device: DeviceProfile::builtin(),
        }
    }
}

/// A trace reader of either encoding.
#[derive(Debug)]
pub enum TraceInput<R: Read> {
    /// Binary.
    Binary(TraceReader<R>),
    /// JSON lines.
    Jsonl(JsonlReader<R>),
}

impl TraceInput<Peeked<File>> {
    /// Opens the trace at `path` (once: FIFOs work), detecting its
    /// encoding.
    pub fn open(path: &Path) -> Result<Self, SimError> {
        let io = |e: std::io::Error| SimError::Io(format!("{}: {e}", path.display()));
        Self::detect(File::open(path).map_err(io)?)
    }
}

impl<R: Read> TraceInput<Peeked<R>> {
    /// Reads the header of the trace `r` (a file, a pipe, standard input),
    /// detecting its encoding from its first bytes: the stream is read
    /// once, from the start (no second open, no seek). Input that is
    /// neither encoding is read as binary, whose error names the bytes found.
    pub fn detect(r: R) -> Result<Self, SimError> {
        let (format, r) = TraceFormat::detect_stream(r).map_err(|e| {
            SimError::Trace(Box::new(TraceError::at(
                TraceLocation::Byte(0),
                io_kind(&e),
            )))
        })?;
        Self::new(format.unwrap_or(TraceFormat::Binary), r)
    }
}

fn io_kind(e: &std::io::Error) -> TraceErrorKind {
    TraceErrorKind::Io {
        kind: e.kind(),
        message: e.to_string(),
    }
}

impl<R: Read> TraceInput<R> {
    /// Reads the header of a trace in `format`.
    pub fn new(format: TraceFormat, r: R) -> Result<Self, SimError> {
        Ok(match format {
            TraceFormat::Binary => Self::Binary(TraceReader::new(r)?),
            TraceFormat::Jsonl => Self::Jsonl(JsonlReader::new(r)?),
        })
    }
    /// The header.
    pub fn header(&self) -> &TraceHeader {
        match self {
            Self::Binary(r) => r.header(),
            Self::Jsonl(r) => r.header(),
        }
    }
    /// Reads the next frame into `frame` (reusing its buffers for binary
    /// traces); `false` after the end.
    ///
    /// Besides the readers' checks, every instance's AABB centre must lie in
    /// the header's world grid (replay registers each instance with it):
    /// an error names the event, its location and the box as given.
    pub fn next_frame_into(&mut self, frame: &mut Frame) -> Result<bool, TraceError> {
        let more = match self {
            Self::Binary(r) => r.next_frame_into(frame)?,
            Self::Jsonl(r) => match r.next_frame()? {
                Some(f) => {
                    *frame = f;
                    true
                }
                None => false,
            },
        };
        if more {
            self.check_in_world(frame)?;
        }
        Ok(more)
    }
    fn check_in_world(&self, frame: &Frame) -> Result<(), TraceError> {
        let Ok(grid) = HitboxGrid::new(self.header().world.grid_config()) else {
            return Ok(()); // (the readers checked the grid)
        };
        for (i, e) in frame.events.iter().enumerate() {
            let pose = match e {
                InstanceEvent::Add(a) => &a.pose,
                InstanceEvent::Update(u) => match &u.pose {
                    Some(p) => p,
                    None => continue,
                },
                InstanceEvent::Remove { .. } => continue,
            };
            if grid.hitbox_of(&pose.aabb).is_some() {
                continue;
            }
            let (lo, hi) = (pose.aabb.min, pose.aabb.max);
            let centre = |a: f32, b: f32| (f64::from(a) + f64::from(b)) / 2.0;
            let (min, max) = (grid.min(), grid.max());
            return Err(TraceError {
                location: match self {
                    Self::Binary(r) => {
                        TraceLocation::Byte(r.event_offset(i).unwrap_or(r.record_offset()))
                    }
                    Self::Jsonl(r) => TraceLocation::Line(r.line()),
                },
                frame_index: Some(self.frames_read().saturating_sub(1)),
                frame_number: Some(frame.number),
                event: Some(i as u32),
                kind: TraceErrorKind::InvalidAabb {
                    what: "instance AABB",
                    min: lo.to_array(),
                    max: hi.to_array(),
                    reason: format!(
                        "instance {}: its centre (x {:?}, z {:?}) lies outside the world grid \
                         x {:?}..{:?}, z {:?}..{:?} of the header; replay needs every instance \
                         inside it",
                        e.id(),
                        centre(lo.x, hi.x),
                        centre(lo.z, hi.z),
                        min[0],
                        max[0],
                        min[1],
                        max[1]
                    ),
                },
            });
        }
        Ok(())
    }
    /// Instances live after the frames read (the validator's set).
    pub fn live_instances(&self) -> usize {
        match self {
            Self::Binary(r) => r.validator().live_instances(),
            Self::Jsonl(r) => r.validator().live_instances(),
        }
    }
    /// Frames read so far.
    pub fn frames_read(&self) -> u64 {
        match self {
            Self::Binary(r) => r.frames_read(),
            Self::Jsonl(r) => r.frames_read(),
        }
    }
    /// Where the last frame read is (binary: the offset of its record;
    /// JSON lines: its line), and its frame number, as text for errors:
    /// `"frame record 3 (frame number 7) at byte 1234"`, `"before the
    /// first frame (…)"`, or, once the end was read, `"after the last frame
    /// (…)"`.
    pub fn position(&self) -> String {
        let (at, number) = match self {
            Self::Binary(r) => (
                TraceLocation::Byte(r.record_offset()),
                r.validator().last_frame_number(),
            ),
            Self::Jsonl(r) => (
                TraceLocation::Line(r.line()),
                r.validator().last_frame_number(),
            ),
        };
        let finished = match self {
            Self::Binary(r) => r.is_finished(),
            Self::Jsonl(r) => r.is_finished(),
        };
        match (self.frames_read(), number) {
            (0, _) | (_, None) if finished => format!("after the end of the trace ({at})"),
            (0, _) | (_, None) => format!("before the first frame ({at})"),
            (n, Some(number)) if finished => format!(
                "after the last frame (frame record {}, frame number {number}; end of the \
                 trace at {at})",
                n - 1
            ),
            (n, Some(number)) => {
                format!("frame record {} (frame number {number}) at {at}", n - 1)
            }
        }
    }
}

/// An empty frame to read into.
pub fn empty_frame() -> Frame {
    Frame {
        number: 0,
        camera: trace::Camera {
            position: Vec3::ZERO,
            orientation: Quat::IDENTITY,
            vertical_fov: 1.0,
            aspect: 1.0,
        },
        events: Vec::new(),
        hits: None,
        slot_hits: None,
    }
}

/// The mode `config` asks for on a trace with `header`.
pub fn mode_for(header: &TraceHeader, config: &ReplayConfig) -> ReplayMode {
    config
        .mode
        .unwrap_or(if SceneRef::parse(&header.scene_name).is_some() {
            ReplayMode::Geometry
        } else {
            ReplayMode::HitsOnly
        })
}

/// Replays `input` (see the module docs). `progress(frames_done)` is called
/// after every frame.
pub fn replay<R: Read>(
    input: TraceInput<R>,
    config: &ReplayConfig,
    progress: &mut dyn FnMut(u64),
) -> Result<CompareReport, SimError> {
    replay_with_snapshots(input, config, progress).map(|(r, _)| r)
}

/// [`replay`], also returning the snapshots of `config.snapshots` (frame
/// numbers the trace does not reach are ignored). Only geometry mode
/// renders; asking a hits-only replay for snapshots is an error.
pub fn replay_with_snapshots<R: Read>(
    mut input: TraceInput<R>,
    config: &ReplayConfig,
    progress: &mut dyn FnMut(u64),
) -> Result<(CompareReport, Vec<Snapshot>), SimError> {
    crate::compare::check_image_size(config.width, config.height)?;
    let result = match mode_for(input.header(), config) {
        ReplayMode::Geometry => replay_geometry(&mut input, config, progress),
        ReplayMode::HitsOnly if !config.snapshots.is_empty() => Err(SimError::Replay(
            "snapshots need geometry mode: a hits-only replay renders no images".into(),
        )),
        ReplayMode::HitsOnly if config.warm_start_at_cuts => Err(SimError::Replay(
            "a warm start at cuts needs geometry mode: a hits-only replay's LiPaC follows \
             the recorded hits"
                .into(),
        )),
        ReplayMode::HitsOnly if config.warm_start_hold.is_some_and(|f| f > 0) => {
            Err(SimError::Replay(
                "a held warm start needs geometry mode: a hits-only replay's LiPaC follows \
                 the recorded hits"
                    .into(),
            ))
        }
        ReplayMode::HitsOnly if !config.hindsight_variants.is_empty() => Err(SimError::Replay(
            "hindsight references need geometry mode: they read the ground truth's hits, \
             which a hits-only replay does not render"
                .into(),
        )),
        ReplayMode::HitsOnly if !config.lipac_variants.is_empty() => Err(SimError::Replay(
            "LiPaC variants need geometry mode: a hits-only replay runs LiPaC's own \
             configuration against the recorded hits"
                .into(),
        )),
        ReplayMode::HitsOnly => {
            hits::replay_hits(&mut input, config, progress).map(|r| (r, Vec::new()))
        }
    };
    // Errors of the trace name their own location; any other comes from the
    // frame read last: say which, and where.
    result.map_err(|e| match e {
        SimError::Trace(_) => e,
        SimError::Replay(what) => SimError::Replay(format!("{}: {what}", input.position())),
        other => SimError::Replay(format!("{}: {other}", input.position())),
    })
}

fn replay_geometry<R: Read>(
    input: &mut TraceInput<R>,
    config: &ReplayConfig,
    progress: &mut dyn FnMut(u64),
) -> Result<(CompareReport, Vec<Snapshot>), SimError> {
    let h = input.header().clone();
    let scene_ref = SceneRef::parse(&h.scene_name).ok_or_else(|| {
        SimError::Replay(format!(
            "geometry mode needs a trace recorded from a built-in scene (scene name \
             `lipac-sim:<scene>:seed=<S>:camera=<path>`); this one is `{}` \
             (replay it in hits-only mode if its frames carry hit counts)",
            h.scene_name
        ))
    })?;
    let mut scene = Scene::generate(&scene_ref.scene.config(Some(scene_ref.seed)))?;
    let expected = header(&scene, &scene_ref, false)?;
    check_meshes(&h, &expected)?;
    let mut cmp = config.comparison(scene_ref.scene.name(), &scene)?;
    cmp.capture_frames(&config.snapshots);
    let n = scene.instances().len();
    let mut frame = empty_frame();
    let mut path = None;
    let mut previous: Option<FlyCamera> = None;
    let mut read = 0u64;
    while input.next_frame_into(&mut frame)? {
        // (`replay` adds the frame and its location.)
        let bad = SimError::Replay;
        let number =
            u32::try_from(frame.number).map_err(|_| bad("frame number above 2^32 - 1".into()))?;
        scene.set_frame(number);
        if read == 0 {
            check_first_frame(&frame, &scene).map_err(bad)?;
        } else {
            for (i, e) in frame.events.iter().enumerate() {
                match e {
                    InstanceEvent::Update(u) => {
                        if let Some(p) = &u.pose {
                            let inst = scene
                                .instances()
                                .get(u.id as usize)
                                .ok_or_else(|| bad(format!("event {i}: unknown instance")))?;
                            let now = lipac_core::trace::Pose {
                                transform: lipac_core::math::affine_to_rows(&inst.transform),
                                aabb: inst.aabb,
                            };
                            if !same_pose(p, &now) {
                                return Err(bad(format!(
                                    "event {i}: the recorded pose of instance {} differs \
                                     from the built-in scene's animation",
                                    u.id
                                )));
                            }
                        }
                    }
                    _ => {
                        return Err(bad(format!(
                            "event {i}: instances are added only on the first frame and \
                             never removed in geometry mode ({n} instances)"
                        )))
                    }
                }
            }
        }
        let path = path
            .get_or_insert_with(|| scene_ref.camera.path(&scene, frame.camera.aspect))
            .camera_at(number);
        let camera = if to_trace_camera(&path) == frame.camera {
            path
        } else {
            from_trace_camera(&frame.camera)?
        };
        if previous.is_some_and(|p| camera.is_cut_from(&p)) {
            cmp.mark_camera_cut(number);
        }
        previous = Some(camera);
        cmp.frame(&scene, number, &camera)?;
        read += 1;
        progress(read);
    }
    cmp.finish_with_snapshots()
}

fn check_meshes(got: &TraceHeader, expected: &TraceHeader) -> Result<(), SimError> {
    let same = got.meshes.len() == expected.meshes.len()
        && got.meshes.iter().zip(&expected.meshes).all(|(a, b)| {
            a.id == b.id
                && a.bounds == b.bounds
                && a.lods.len() == b.lods.len()
                && a.lods
                    .iter()
                    .zip(&b.lods)
                    .all(|(x, y)| x.triangles == y.triangles)
        });
    if same && got.world == expected.world {
        Ok(())
    } else {
        Err(SimError::Replay(format!(
            "the header's meshes or world differ from the built-in scene `{}`",
            got.scene_name
        )))
    }
}

fn check_first_frame(frame: &Frame, scene: &Scene) -> Result<(), String> {
    let n = scene.instances().len();
    if frame.events.len() != n {
        return Err(format!(
            "{} events; the built-in scene's first frame adds its {n} instances",
            frame.events.len()
        ));
    }
    for (slot, (e, inst)) in frame.events.iter().zip(scene.instances()).enumerate() {
        let ok = match e {
            InstanceEvent::Add(a) => {
                a.id == slot as u64
                    && a.mesh.0 == inst.mesh
                    && same_pose(
                        &a.pose,
                        &lipac_core::trace::Pose {
                            transform: lipac_core::math::affine_to_rows(&inst.transform),
                            aabb: inst.aabb,
                        },
                    )
            }
            _ => false,
        };
        if !ok {
            return Err(format!(
                "event {slot} is not the add of the built-in scene's instance {slot}"
            ));
        }
    }
    Ok(())
}
