//! The binary trace format: [`TraceWriter`] and the streaming
//! [`TraceReader`]. Layout: `docs/trace-format.md`.

use super::error::{TraceError, TraceErrorKind, TraceLocation};
use super::model::{
    check_aabb, check_event_count, check_flags, check_geometry, check_header, check_hit_count,
    check_lod_count, check_mesh_count, check_scene_name, check_slot_count, check_triangles,
    check_vertex_count, check_world, AddInstance, BoxHits, Camera, Frame, InstanceEvent,
    InstanceHits, LodGeometry, LodInfo, MeshInfo, MeshTable, Pose, SlotHits, TraceHeader,
    TraceLimits, UpdateInstance, WorldInfo,
};
use super::validate::{check_version, FrameFault, TraceValidator};
use super::{TRACE_MAGIC, TRACE_VERSION};
use crate::instance::MeshId;
use crate::math::Aabb;
use glam::{Quat, Vec3};
use std::io::{self, BufReader, Read, Write};

/// Bytes before the header payload: magic, version, reserved, header length.
pub const PREAMBLE_BYTES: u64 = 20;

pub(crate) const TAG_ADD: u8 = 1;
pub(crate) const TAG_UPDATE: u8 = 2;
pub(crate) const TAG_REMOVE: u8 = 3;

const ADD_HAS_MASK: u8 = 1;
/// Version 2: a `u32` slot follows the mask.
const ADD_HAS_SLOT: u8 = 2;
/// Hits flag values: none, by id (both versions), by slot (version 2).
const HITS_NONE: u8 = 0;
const HITS_BY_ID: u8 = 1;
const HITS_BY_SLOT: u8 = 2;
const BOX_BYTES: u64 = 4 + 4;
const UPDATE_POSE: u8 = 1;
const UPDATE_LOD: u8 = 2;
const UPDATE_FLAGS: u8 = 4;
const UPDATE_MASK: u8 = 8;

/// Smallest encoded sizes, used to cap counts by the bytes left in a record.
const MIN_MESH_BYTES: u64 = 4 + 24 + 4 + MIN_LOD_BYTES;
const MIN_LOD_BYTES: u64 = 4 + 1;
const MIN_EVENT_BYTES: u64 = 1 + 8; // remove
const HIT_BYTES: u64 = 8 + 4;
const POSE_BYTES: usize = 48 + 24;
/// Frame payload before the event list: number, camera, event count.
const FRAME_FIXED_BYTES: u64 = 8 + 36 + 4;
/// Bytes read from the source per step, so that a length field never makes
/// the reader allocate more than the input actually holds (plus this much).
const READ_CHUNK: usize = 64 * 1024;

// ---------------------------------------------------------------------------
// Encoding

fn put_u32(b: &mut Vec<u8>, v: u32) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn put_u64(b: &mut Vec<u8>, v: u64) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn put_f32(b: &mut Vec<u8>, v: f32) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn put_f64(b: &mut Vec<u8>, v: f64) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn put_vec3(b: &mut Vec<u8>, v: Vec3) {
    for x in v.to_array() {
        put_f32(b, x);
    }
}
fn put_aabb(b: &mut Vec<u8>, a: &Aabb) {
    put_vec3(b, a.min);
    put_vec3(b, a.max);
}
fn put_pose(b: &mut Vec<u8>, p: &Pose) {
    // One append of the 18 floats (a recorded frame holds ~1k poses).
    let mut e = [0u8; POSE_BYTES];
    let (lo, hi) = (p.aabb.min.to_array(), p.aabb.max.to_array());
    let floats = p.transform.iter().chain(&lo).chain(&hi);
    for (d, x) in e.chunks_exact_mut(4).zip(floats) {
        d.copy_from_slice(&x.to_le_bytes());
    }
    b.extend_from_slice(&e);
}

/// Appends `v` as little-endian `u32`s through a small stack buffer: no
/// zero-filled growth and no single huge copy (a recorded frame holds a
/// count per slot, 100k and more).
fn put_u32s(b: &mut Vec<u8>, v: &[u32]) {
    const CHUNK: usize = 256;
    b.reserve(4 * v.len());
    let mut e = [0u8; 4 * CHUNK];
    for c in v.chunks(CHUNK) {
        for (d, x) in e.chunks_exact_mut(4).zip(c) {
            d.copy_from_slice(&x.to_le_bytes());
        }
        b.extend_from_slice(&e[..4 * c.len()]);
    }
}

/// Appends the header payload (without the preamble).
pub(crate) fn encode_header(h: &TraceHeader, b: &mut Vec<u8>) {
    put_u32(b, h.scene_name.len() as u32);
    b.extend_from_slice(h.scene_name.as_bytes());
    let w = &h.world;
    for x in [w.min[0], w.min[1], w.max[0], w.max[1], w.cell_size] {
        put_f64(b, x);
    }
    put_u32(b, h.meshes.len() as u32);
    for m in &h.meshes {
        put_u32(b, m.id.0);
        put_aabb(b, &m.bounds);
        put_u32(b, m.lods.len() as u32);
        for lod in &m.lods {
            put_u32(b, lod.triangles);
            match &lod.geometry {
                None => b.push(0),
                Some(g) => {
                    b.push(1);
                    put_u32(b, g.positions.len() as u32);
                    for p in &g.positions {
                        for x in p {
                            put_f32(b, *x);
                        }
                    }
                    put_u32(b, g.indices.len() as u32);
                    for i in &g.indices {
                        put_u32(b, *i);
                    }
                }
            }
        }
    }
}

/// Appends a frame payload (without its length prefix).
pub(crate) fn encode_frame(f: &Frame, b: &mut Vec<u8>) {
    put_u64(b, f.number);
    put_vec3(b, f.camera.position);
    for x in f.camera.orientation.to_array() {
        put_f32(b, x);
    }
    put_f32(b, f.camera.vertical_fov);
    put_f32(b, f.camera.aspect);
    put_u32(b, f.events.len() as u32);
    for e in &f.events {
        match e {
            InstanceEvent::Add(a) => {
                b.push(TAG_ADD);
                put_u64(b, a.id);
                put_u32(b, a.mesh.0);
                put_u32(b, a.lod);
                put_u32(b, a.flags.bits());
                let opts = (a.mask.is_some() as u8 * ADD_HAS_MASK)
                    | (a.slot.is_some() as u8 * ADD_HAS_SLOT);
                b.push(opts);
                if let Some(m) = a.mask {
                    b.push(m);
                }
                if let Some(slot) = a.slot {
                    put_u32(b, slot);
                }
                put_pose(b, &a.pose);
            }
            InstanceEvent::Update(u) => {
                b.push(TAG_UPDATE);
                put_u64(b, u.id);
                let opts = (u.pose.is_some() as u8 * UPDATE_POSE)
                    | (u.lod.is_some() as u8 * UPDATE_LOD)
                    | (u.flags.is_some() as u8 * UPDATE_FLAGS)
                    | (u.mask.is_some() as u8 * UPDATE_MASK);
                b.push(opts);
                if let Some(p) = &u.pose {
                    put_pose(b, p);
                }
                if let Some(l) = u.lod {
                    put_u32(b, l);
                }
                if let Some(f) = u.flags {
                    put_u32(b, f.bits());
                }
                if let Some(m) = u.mask {
                    b.push(m);
                }
            }
            InstanceEvent::Remove { id } => {
                b.push(TAG_REMOVE);
                put_u64(b, *id);
            }
        }
    }
    if let Some(sh) = &f.slot_hits {
        b.push(HITS_BY_SLOT);
        put_u32(b, sh.slots.len() as u32);
        put_u32s(b, &sh.slots);
        put_u32(b, sh.boxes.len() as u32);
        b.reserve(BOX_BYTES as usize * sh.boxes.len());
        for x in &sh.boxes {
            put_u32(b, x.hitbox);
            put_u32(b, x.hits);
        }
        return;
    }
    match &f.hits {
        None => b.push(HITS_NONE),
        Some(hits) => {
            b.push(HITS_BY_ID);
            put_u32(b, hits.len() as u32);
            // Reserved once, 12 bytes per store: a recorded frame may list
            // 100k hit counts.
            b.reserve(HIT_BYTES as usize * hits.len());
            for h in hits {
                let mut e = [0u8; HIT_BYTES as usize];
                e[..8].copy_from_slice(&h.id.to_le_bytes());
                e[8..].copy_from_slice(&h.hits.to_le_bytes());
                b.extend_from_slice(&e);
            }
        }
    }
}

fn io_err(at: u64, e: &io::Error) -> TraceError {
    TraceError::at(TraceLocation::Byte(at), TraceErrorKind::io(e))
}

/// Writes a binary trace frame by frame.
///
/// Everything written is checked exactly as a reader checks it (same
/// [`TraceLimits`], same [`TraceValidator`]), so a finished trace always
/// reads back. Call [`TraceWriter::finish`] at the end: it writes the
/// end-of-trace marker, without which readers report the trace as cut short.
///
/// ```
/// use glam::{Quat, Vec3};
/// use lipac_core::instance::{InstanceFlags, MeshId};
/// use lipac_core::math::Aabb;
/// use lipac_core::trace::*;
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
/// let camera = Camera::look_to(Vec3::new(0.0, 2.0, 10.0), Vec3::NEG_Z, Vec3::Y, 1.0, 16.0 / 9.0);
/// let pose = Pose {
///     transform: [1.0, 0.0, 0.0, 5.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
///     aabb: Aabb::new(Vec3::new(4.0, -1.0, -1.0), Vec3::new(6.0, 1.0, 1.0)),
/// };
/// let add = AddInstance {
///     id: 42, mesh: MeshId(1), lod: 0, flags: InstanceFlags::STATIC, mask: None, pose,
///     slot: None,
/// };
///
/// let mut w = TraceWriter::new(Vec::new(), &header)?;
/// w.write_frame(&Frame {
///     number: 0, camera, events: vec![InstanceEvent::Add(add)], hits: None, slot_hits: None,
/// })?;
/// w.write_frame(&Frame {
///     number: 1,
///     camera,
///     events: vec![InstanceEvent::Remove { id: 42 }],
///     hits: Some(vec![]),
///     slot_hits: None,
/// })?;
/// let bytes: Vec<u8> = w.finish()?;
///
/// let mut r = TraceReader::new(bytes.as_slice())?;
/// assert_eq!(r.header(), &header);
/// let f0 = r.next_frame()?.expect("frame 0");
/// assert_eq!(f0.events, vec![InstanceEvent::Add(add)]);
/// assert_eq!(r.next_frame()?.map(|f| f.number), Some(1));
/// assert_eq!(r.next_frame()?, None); // end marker reached
///
/// // Removing an instance twice is caught, naming frame, event and byte offset.
/// let mut w = TraceWriter::new(Vec::new(), &header)?;
/// let bad = Frame {
///     number: 0, camera, events: vec![InstanceEvent::Remove { id: 7 }], hits: None, slot_hits: None,
/// };
/// let err = w.write_frame(&bad).unwrap_err();
/// assert_eq!(err.kind, TraceErrorKind::UnknownInstance { op: "remove", id: 7 });
/// assert_eq!((err.frame_number, err.event), (Some(0), Some(0)));
/// # Ok::<(), TraceError>(())
/// ```
#[derive(Debug)]
pub struct TraceWriter<W: Write> {
    w: W,
    offset: u64,
    buf: Vec<u8>,
    validator: TraceValidator,
    limits: TraceLimits,
}

impl<W: Write> TraceWriter<W> {
    /// Checks `header` against the default [`TraceLimits`] and writes the
    /// preamble and header.
    pub fn new(w: W, header: &TraceHeader) -> Result<Self, TraceError> {
        Self::with_limits(w, header, TraceLimits::default())
    }

    /// As [`TraceWriter::new`] with explicit limits.
    pub fn with_limits(
        w: W,
        header: &TraceHeader,
        limits: TraceLimits,
    ) -> Result<Self, TraceError> {
        Self::with_version(w, header, limits, TRACE_VERSION)
    }

    /// As [`TraceWriter::with_limits`], writing format `version` (1 or 2;
    /// [`TRACE_VERSION`] by default): a version-1 trace refuses frames with
    /// slots or [`SlotHits`] ([`TraceErrorKind::NotInVersion`]).
    pub fn with_version(
        mut w: W,
        header: &TraceHeader,
        limits: TraceLimits,
        version: u16,
    ) -> Result<Self, TraceError> {
        check_version(version).map_err(|k| TraceError::at(TraceLocation::Byte(8), k))?;
        let here = |kind| TraceError::at(TraceLocation::Byte(PREAMBLE_BYTES), kind);
        let meshes: MeshTable = check_header(header, &limits).map_err(here)?;
        let mut buf = Vec::new();
        encode_header(header, &mut buf);
        if buf.len() as u64 > limits.max_header_bytes {
            return Err(here(TraceErrorKind::LimitExceeded {
                what: "header bytes",
                value: buf.len() as u64,
                limit: limits.max_header_bytes,
            }));
        }
        let mut pre = Vec::with_capacity(PREAMBLE_BYTES as usize);
        pre.extend_from_slice(&TRACE_MAGIC);
        pre.extend_from_slice(&version.to_le_bytes());
        pre.extend_from_slice(&0u16.to_le_bytes());
        put_u64(&mut pre, buf.len() as u64);
        w.write_all(&pre).map_err(|e| io_err(0, &e))?;
        w.write_all(&buf).map_err(|e| io_err(PREAMBLE_BYTES, &e))?;
        let offset = PREAMBLE_BYTES + buf.len() as u64;
        buf.clear();
        Ok(Self {
            w,
            offset,
            buf,
            validator: TraceValidator::with_meshes(meshes, limits, &header.world, version),
            limits,
        })
    }

    /// For the Manager's recorder, whose instance events are consistent by
    /// construction (ids from its own table): from now on the live
    /// instances are not tracked ([`TraceValidator::stop_tracking_live`]),
    /// every value, reference and limit is still checked.
    pub(crate) fn trust_instance_ids(&mut self) {
        self.validator.stop_tracking_live();
    }

    /// Checks `frame` (see [`TraceValidator`]) and appends it.
    pub fn write_frame(&mut self, frame: &Frame) -> Result<(), TraceError> {
        self.write_checked(frame, false)
    }

    /// As [`TraceWriter::write_frame`] for hit counts that are consistent by
    /// construction (see [`TraceValidator::check_frame_trusted_hits`]).
    pub(crate) fn write_frame_trusted_hits(&mut self, frame: &Frame) -> Result<(), TraceError> {
        self.write_checked(frame, true)
    }

    fn write_checked(&mut self, frame: &Frame, trusted_hits: bool) -> Result<(), TraceError> {
        let index = self.validator.frames();
        let err = |offset: u64, event: Option<u32>, kind| TraceError {
            location: TraceLocation::Byte(offset),
            frame_index: Some(index),
            frame_number: Some(frame.number),
            event,
            kind,
        };
        let checked = if trusted_hits {
            self.validator.check_frame_trusted_hits(frame)
        } else {
            self.validator.check_frame(frame)
        };
        if let Err(FrameFault { event, kind }) = checked {
            return Err(err(self.offset, event, kind));
        }
        self.buf.clear();
        encode_frame(frame, &mut self.buf);
        if self.buf.len() as u64 > u64::from(self.limits.max_frame_bytes) {
            return Err(err(
                self.offset,
                None,
                TraceErrorKind::LimitExceeded {
                    what: "frame record bytes",
                    value: self.buf.len() as u64,
                    limit: self.limits.max_frame_bytes.into(),
                },
            ));
        }
        let len = (self.buf.len() as u32).to_le_bytes();
        let at = self.offset;
        self.w
            .write_all(&len)
            .and_then(|()| self.w.write_all(&self.buf))
            .map_err(|e| err(at, None, TraceErrorKind::io(&e)))?;
        self.offset += 4 + self.buf.len() as u64;
        Ok(())
    }

    /// Frames written so far.
    pub fn frames_written(&self) -> u64 {
        self.validator.frames()
    }

    /// Bytes written so far.
    pub fn bytes_written(&self) -> u64 {
        self.offset
    }

    /// Writes the end-of-trace marker, flushes, and returns the sink.
    pub fn finish(mut self) -> Result<W, TraceError> {
        let mut end = Vec::with_capacity(12);
        put_u32(&mut end, 0);
        put_u64(&mut end, self.validator.frames());
        self.w
            .write_all(&end)
            .and_then(|()| self.w.flush())
            .map_err(|e| io_err(self.offset, &e))?;
        Ok(self.w)
    }
}

// ---------------------------------------------------------------------------
// Decoding

type Fault = (u64, TraceErrorKind);

/// A bounds-checked little-endian cursor over one buffered record.
struct Cur<'a> {
    data: &'a [u8],
    pos: usize,
    base: u64,
}

impl<'a> Cur<'a> {
    fn at(&self) -> u64 {
        self.base + self.pos as u64
    }
    fn rest(&self) -> usize {
        self.data.len() - self.pos
    }
    fn fail<T>(&self, kind: TraceErrorKind) -> Result<T, Fault> {
        Err((self.at(), kind))
    }
    fn bytes(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], Fault> {
        if self.rest() < n {
            return self.fail(TraceErrorKind::Truncated {
                what,
                needed: n as u64,
                available: self.rest() as u64,
            });
        }
        let s = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    fn arr<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], Fault> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.bytes(N, what)?);
        Ok(a)
    }
    fn u8(&mut self, what: &'static str) -> Result<u8, Fault> {
        Ok(self.arr::<1>(what)?[0])
    }
    fn u32(&mut self, what: &'static str) -> Result<u32, Fault> {
        self.arr(what).map(u32::from_le_bytes)
    }
    fn u64(&mut self, what: &'static str) -> Result<u64, Fault> {
        self.arr(what).map(u64::from_le_bytes)
    }
    fn f32(&mut self, what: &'static str) -> Result<f32, Fault> {
        self.arr(what).map(f32::from_le_bytes)
    }
    fn f64(&mut self, what: &'static str) -> Result<f64, Fault> {
        self.arr(what).map(f64::from_le_bytes)
    }
    fn vec3(&mut self, what: &'static str) -> Result<Vec3, Fault> {
        Ok(Vec3::new(self.f32(what)?, self.f32(what)?, self.f32(what)?))
    }
    fn aabb(&mut self, what: &'static str) -> Result<Aabb, Fault> {
        Ok(Aabb::new(self.vec3(what)?, self.vec3(what)?))
    }
    fn pose(&mut self) -> Result<Pose, Fault> {
        let raw = self.bytes(POSE_BYTES, "pose (transform + AABB)")?;
        let f = |i: usize| {
            f32::from_le_bytes([raw[4 * i], raw[4 * i + 1], raw[4 * i + 2], raw[4 * i + 3]])
        };
        let transform = std::array::from_fn(f);
        let aabb = Aabb::new(
            Vec3::new(f(12), f(13), f(14)),
            Vec3::new(f(15), f(16), f(17)),
        );
        Ok(Pose { transform, aabb })
    }
    /// Runs `check` on a value read at the current position, reporting a
    /// failure at the value's offset.
    fn check<T>(&self, start: u64, r: Result<T, TraceErrorKind>) -> Result<T, Fault> {
        r.map_err(|k| (start, k))
    }
    /// A `u32` count: at most its limit, and at most what the rest of the
    /// record can hold at `min_element_bytes` each.
    fn count(
        &mut self,
        what: &'static str,
        min_element_bytes: u64,
        limit: impl FnOnce(u64) -> Result<(), TraceErrorKind>,
    ) -> Result<usize, Fault> {
        let start = self.at();
        let n = u64::from(self.u32(what)?);
        self.check(start, limit(n))?;
        let remaining = self.rest() as u64;
        if n.saturating_mul(min_element_bytes) > remaining {
            return Err((
                start,
                TraceErrorKind::CountExceedsRecord {
                    what,
                    count: n,
                    min_element_bytes,
                    remaining,
                },
            ));
        }
        Ok(n as usize)
    }
    fn finish(&self, what: &'static str) -> Result<(), Fault> {
        if self.rest() != 0 {
            return self.fail(TraceErrorKind::TrailingBytes {
                what,
                count: self.rest() as u64,
            });
        }
        Ok(())
    }
}

fn decode_header(c: &mut Cur<'_>, limits: &TraceLimits) -> Result<(TraceHeader, MeshTable), Fault> {
    let start = c.at();
    let name_len = c.u32("scene name length")?;
    c.check(start, check_scene_name(name_len.into(), limits))?;
    let name_at = c.at();
    let name = c.bytes(name_len as usize, "scene name")?;
    let scene_name = c.check(
        name_at,
        String::from_utf8(name.to_vec()).map_err(|e| TraceErrorKind::InvalidValue {
            what: "scene name".into(),
            reason: e.to_string(),
        }),
    )?;
    let world_at = c.at();
    let mut w = [0f64; 5];
    for x in &mut w {
        *x = c.f64("world grid")?;
    }
    let world = WorldInfo {
        min: [w[0], w[1]],
        max: [w[2], w[3]],
        cell_size: w[4],
    };
    c.check(world_at, check_world(&world, limits))?;
    let n = c.count("mesh count", MIN_MESH_BYTES, |n| {
        check_mesh_count(n, limits)
    })?;
    let mut meshes = Vec::with_capacity(n);
    let mut table = MeshTable::default();
    for _ in 0..n {
        let mesh_at = c.at();
        let id = MeshId(c.u32("mesh id")?);
        c.check(mesh_at, table.insert(id, 0).map(|_| ()))?;
        let bounds_at = c.at();
        let bounds = c.aabb("mesh bounds")?;
        c.check(bounds_at, check_aabb("mesh bounds", &bounds, f32::INFINITY))?;
        let nl = c.count("LOD count", MIN_LOD_BYTES, |n| check_lod_count(n, limits))?;
        let mut lods = Vec::with_capacity(nl);
        for _ in 0..nl {
            let tri_at = c.at();
            let triangles = c.u32("LOD triangle count")?;
            c.check(tri_at, check_triangles(triangles.into(), limits))?;
            let flag_at = c.at();
            let geometry = match c.u8("geometry flag")? {
                0 => None,
                1 => {
                    let nv = c.count("vertex count", 12, |n| check_vertex_count(n, limits))?;
                    let mut positions = Vec::with_capacity(nv);
                    for _ in 0..nv {
                        positions.push(c.vec3("vertex position")?.to_array());
                    }
                    let ni = c.count("index count", 4, |n| check_triangles(n / 3, limits))?;
                    let mut indices = Vec::with_capacity(ni);
                    for _ in 0..ni {
                        indices.push(c.u32("vertex index")?);
                    }
                    let g = LodGeometry { positions, indices };
                    c.check(flag_at, check_geometry(triangles, &g))?;
                    Some(g)
                }
                v => {
                    return Err((
                        flag_at,
                        TraceErrorKind::InvalidTag {
                            what: "geometry flag",
                            value: v.into(),
                        },
                    ))
                }
            };
            lods.push(LodInfo {
                triangles,
                geometry,
            });
        }
        table.set_lods(id, lods.len() as u32);
        meshes.push(MeshInfo { id, bounds, lods });
    }
    c.finish("header")?;
    Ok((
        TraceHeader {
            scene_name,
            world,
            meshes,
        },
        table,
    ))
}

/// Where the parts of the last frame record start, for error locations.
#[derive(Debug, Default)]
struct FrameOffsets {
    payload: u64,
    camera: u64,
    hits: u64,
    events: Vec<u64>,
    /// The event being decoded, if any.
    in_event: Option<u32>,
}

/// Decodes a frame record into `frame`, passing each part through
/// `validator` as soon as it is decoded: a bad event is reported before the
/// events after it are decoded, so rejecting a record never costs more than
/// its bytes and the events before the fault.
fn decode_frame(
    c: &mut Cur<'_>,
    limits: &TraceLimits,
    validator: &mut TraceValidator,
    frame: &mut Frame,
    offsets: &mut FrameOffsets,
) -> Result<(), Fault> {
    offsets.payload = c.at();
    offsets.in_event = None;
    let v2 = validator.version() >= 2;
    frame.number = c.u64("frame number")?;
    offsets.camera = c.at();
    let position = c.vec3("camera position")?;
    let q = [
        c.f32("camera orientation")?,
        c.f32("camera orientation")?,
        c.f32("camera orientation")?,
        c.f32("camera orientation")?,
    ];
    frame.camera = Camera {
        position,
        orientation: Quat::from_array(q),
        vertical_fov: c.f32("camera vertical_fov")?,
        aspect: c.f32("camera aspect")?,
    };
    validator
        .begin_frame(frame.number, &frame.camera)
        .map_err(|FrameFault { kind, .. }| {
            let at = match kind {
                TraceErrorKind::FrameOrder { .. } => offsets.payload,
                _ => offsets.camera,
            };
            (at, kind)
        })?;
    let n = c.count("event count", MIN_EVENT_BYTES, |n| {
        check_event_count(n, limits)
    })?;
    frame.events.clear();
    offsets.events.clear();
    for i in 0..n {
        let at = c.at();
        offsets.events.push(at);
        offsets.in_event = Some(i as u32);
        let e = match c.u8("event tag")? {
            TAG_ADD => {
                let id = c.u64("instance id")?;
                let mesh = MeshId(c.u32("mesh id")?);
                let lod = c.u32("LOD")?;
                let flags_at = c.at();
                let bits = c.u32("flags")?;
                let flags = c.check(flags_at, check_flags(bits))?;
                let opts_at = c.at();
                let opts = c.u8("add options")?;
                let known = if v2 {
                    ADD_HAS_MASK | ADD_HAS_SLOT
                } else {
                    ADD_HAS_MASK
                };
                if opts & !known != 0 {
                    return Err((
                        opts_at,
                        TraceErrorKind::InvalidTag {
                            what: "add options",
                            value: opts.into(),
                        },
                    ));
                }
                let mask = if opts & ADD_HAS_MASK != 0 {
                    Some(c.u8("mask")?)
                } else {
                    None
                };
                let slot = if opts & ADD_HAS_SLOT != 0 {
                    Some(c.u32("slot")?)
                } else {
                    None
                };
                let pose = c.pose()?;
                InstanceEvent::Add(AddInstance {
                    id,
                    mesh,
                    lod,
                    flags,
                    mask,
                    pose,
                    slot,
                })
            }
            TAG_UPDATE => {
                let id = c.u64("instance id")?;
                let opts_at = c.at();
                let opts = c.u8("update options")?;
                if opts & !(UPDATE_POSE | UPDATE_LOD | UPDATE_FLAGS | UPDATE_MASK) != 0 {
                    return Err((
                        opts_at,
                        TraceErrorKind::InvalidTag {
                            what: "update options",
                            value: opts.into(),
                        },
                    ));
                }
                let pose = if opts & UPDATE_POSE != 0 {
                    Some(c.pose()?)
                } else {
                    None
                };
                let lod = if opts & UPDATE_LOD != 0 {
                    Some(c.u32("LOD")?)
                } else {
                    None
                };
                let flags = if opts & UPDATE_FLAGS != 0 {
                    let flags_at = c.at();
                    let bits = c.u32("flags")?;
                    Some(c.check(flags_at, check_flags(bits))?)
                } else {
                    None
                };
                let mask = if opts & UPDATE_MASK != 0 {
                    Some(c.u8("mask")?)
                } else {
                    None
                };
                InstanceEvent::Update(UpdateInstance {
                    id,
                    pose,
                    lod,
                    flags,
                    mask,
                })
            }
            TAG_REMOVE => InstanceEvent::Remove {
                id: c.u64("instance id")?,
            },
            v => {
                return Err((
                    at,
                    TraceErrorKind::InvalidTag {
                        what: "event tag",
                        value: v.into(),
                    },
                ))
            }
        };
        validator
            .check_next_event(i as u32, &e)
            .map_err(|f| (at, f.kind))?;
        frame.events.push(e);
    }
    offsets.in_event = None;
    offsets.hits = c.at();
    frame.slot_hits = None;
    match c.u8("hits flag")? {
        HITS_NONE => frame.hits = None,
        HITS_BY_SLOT if v2 => {
            let sh = frame.slot_hits.get_or_insert_with(SlotHits::default);
            let n = c.count("slot hit count", 4, |n| check_slot_count(n, limits))?;
            let bytes = c.bytes(4 * n, "slot hits")?;
            sh.slots.clear();
            sh.slots.extend(
                bytes
                    .chunks_exact(4)
                    .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            );
            let n = c.count("counting-box hit count", BOX_BYTES, |n| {
                check_hit_count(n, limits)
            })?;
            sh.boxes.clear();
            for _ in 0..n {
                sh.boxes.push(BoxHits {
                    hitbox: c.u32("counting-box hitbox")?,
                    hits: c.u32("counting-box hits")?,
                });
            }
        }
        HITS_BY_ID => {
            let n = c.count("hit count", HIT_BYTES, |n| check_hit_count(n, limits))?;
            let hits = frame.hits.get_or_insert_with(Vec::new);
            hits.clear();
            for _ in 0..n {
                hits.push(InstanceHits {
                    id: c.u64("hit instance id")?,
                    hits: c.u32("hits")?,
                });
            }
        }
        v => {
            return Err((
                offsets.hits,
                TraceErrorKind::InvalidTag {
                    what: "hits flag",
                    value: v.into(),
                },
            ))
        }
    }
    c.finish("frame")?;
    if let Some(sh) = &frame.slot_hits {
        validator
            .check_slot_hits(sh)
            .map_err(|f| (offsets.hits, f.kind))?;
        let hits = frame.hits.get_or_insert_with(Vec::new);
        if !validator.derive_hits(sh, hits) {
            frame.hits = None;
        }
    } else if let Some(hits) = &frame.hits {
        validator
            .check_hits(hits)
            .map_err(|f| (offsets.hits, f.kind))?;
    }
    Ok(())
}

/// Reads up to `n` more bytes from `r` onto `buf`, in bounded steps so that
/// `buf` grows only with bytes actually present. Returns the bytes read.
fn read_up_to<R: Read>(r: &mut R, buf: &mut Vec<u8>, n: u64) -> io::Result<u64> {
    let mut got = 0u64;
    while got < n {
        let step = (n - got).min(READ_CHUNK as u64) as usize;
        let start = buf.len();
        buf.resize(start + step, 0);
        let mut filled = 0;
        while filled < step {
            match r.read(&mut buf[start + filled..start + step]) {
                Ok(0) => break,
                Ok(k) => filled += k,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => {
                    buf.truncate(start + filled);
                    return Err(e);
                }
            }
        }
        buf.truncate(start + filled);
        got += filled as u64;
        if filled < step {
            break;
        }
    }
    Ok(got)
}

#[derive(Debug)]
enum ReadState {
    Frames,
    Done,
    Failed(Box<TraceError>),
}

/// Reads a binary trace frame by frame.
///
/// [`TraceReader::new`] reads and checks the preamble and header;
/// [`TraceReader::next_frame`] then yields one frame per call and `None`
/// after the end marker. Memory is bounded by the largest frame record (its
/// byte buffer is reused) plus the live-instance set of the
/// [`TraceValidator`] every frame passes through; the input is never read
/// whole. Every error names the byte offset, the frame and what was wrong;
/// after an error every later call returns the same error.
///
/// See [`TraceWriter`] for an example.
#[derive(Debug)]
pub struct TraceReader<R: Read> {
    r: BufReader<R>,
    limits: TraceLimits,
    header: TraceHeader,
    validator: TraceValidator,
    offset: u64,
    record_at: u64,
    buf: Vec<u8>,
    offsets: FrameOffsets,
    state: ReadState,
}

impl<R: Read> TraceReader<R> {
    /// Reads the preamble and header with the default [`TraceLimits`].
    pub fn new(r: R) -> Result<Self, TraceError> {
        Self::with_limits(r, TraceLimits::default())
    }

    /// As [`TraceReader::new`] with explicit limits.
    pub fn with_limits(r: R, limits: TraceLimits) -> Result<Self, TraceError> {
        let mut r = BufReader::new(r);
        let byte = |at: u64, kind| TraceError::at(TraceLocation::Byte(at), kind);
        let mut pre = Vec::with_capacity(PREAMBLE_BYTES as usize);
        let got = read_up_to(&mut r, &mut pre, PREAMBLE_BYTES).map_err(|e| io_err(0, &e))?;
        let magic_len = pre.len().min(TRACE_MAGIC.len());
        if pre[..magic_len] != TRACE_MAGIC[..magic_len] {
            return Err(byte(
                0,
                TraceErrorKind::BadMagic {
                    found: pre[..magic_len].to_vec(),
                },
            ));
        }
        if got < PREAMBLE_BYTES {
            return Err(byte(
                got,
                TraceErrorKind::Truncated {
                    what: "preamble",
                    needed: PREAMBLE_BYTES,
                    available: got,
                },
            ));
        }
        let version = u16::from_le_bytes([pre[8], pre[9]]);
        check_version(version).map_err(|k| byte(8, k))?;
        let reserved = u16::from_le_bytes([pre[10], pre[11]]);
        if reserved != 0 {
            return Err(byte(
                10,
                TraceErrorKind::InvalidTag {
                    what: "reserved preamble field (must be 0)",
                    value: reserved.into(),
                },
            ));
        }
        let mut len = [0u8; 8];
        len.copy_from_slice(&pre[12..20]);
        let header_len = u64::from_le_bytes(len);
        if header_len > limits.max_header_bytes {
            return Err(byte(
                12,
                TraceErrorKind::LimitExceeded {
                    what: "header bytes",
                    value: header_len,
                    limit: limits.max_header_bytes,
                },
            ));
        }
        let mut buf = Vec::new();
        let got =
            read_up_to(&mut r, &mut buf, header_len).map_err(|e| io_err(PREAMBLE_BYTES, &e))?;
        if got < header_len {
            return Err(byte(
                PREAMBLE_BYTES + got,
                TraceErrorKind::Truncated {
                    what: "header record",
                    needed: header_len,
                    available: got,
                },
            ));
        }
        let mut c = Cur {
            data: &buf,
            pos: 0,
            base: PREAMBLE_BYTES,
        };
        let (header, meshes) = decode_header(&mut c, &limits).map_err(|(at, k)| byte(at, k))?;
        let validator = TraceValidator::with_meshes(meshes, limits, &header.world, version);
        buf.clear();
        buf.shrink_to(READ_CHUNK);
        Ok(Self {
            r,
            limits,
            header,
            validator,
            offset: PREAMBLE_BYTES + header_len,
            record_at: PREAMBLE_BYTES + header_len,
            buf,
            offsets: FrameOffsets::default(),
            state: ReadState::Frames,
        })
    }

    /// The trace header.
    pub fn header(&self) -> &TraceHeader {
        &self.header
    }

    /// The trace's format version (1 or 2).
    pub fn version(&self) -> u16 {
        self.validator.version()
    }

    /// The limits in force.
    pub fn limits(&self) -> &TraceLimits {
        &self.limits
    }

    /// The validator every frame passes through (live instances so far).
    pub fn validator(&self) -> &TraceValidator {
        &self.validator
    }

    /// Frames read (or skipped) so far.
    pub fn frames_read(&self) -> u64 {
        self.validator.frames()
    }

    /// Bytes consumed so far (the offset of the next record).
    pub fn offset(&self) -> u64 {
        self.offset
    }

    /// Offset of the last frame record read (its length field), for
    /// errors found by the caller in the frame it got; the first record's
    /// offset before any was read.
    pub fn record_offset(&self) -> u64 {
        self.record_at
    }

    /// Whether the end marker was read (every frame is out).
    pub fn is_finished(&self) -> bool {
        matches!(self.state, ReadState::Done)
    }

    /// Offset of event `i` of the last frame decoded, if it has one.
    pub fn event_offset(&self, i: usize) -> Option<u64> {
        self.offsets.events.get(i).copied()
    }

    /// The next frame, or `None` after the end marker.
    pub fn next_frame(&mut self) -> Result<Option<Frame>, TraceError> {
        let mut frame = Frame {
            number: 0,
            camera: Camera {
                position: Vec3::ZERO,
                orientation: Quat::IDENTITY,
                vertical_fov: 1.0,
                aspect: 1.0,
            },
            events: Vec::new(),
            hits: None,
            slot_hits: None,
        };
        Ok(self.next_frame_into(&mut frame)?.then_some(frame))
    }

    /// Reads the next frame into `frame`, reusing its allocations; `false`
    /// after the end marker (then `frame` is unspecified).
    pub fn next_frame_into(&mut self, frame: &mut Frame) -> Result<bool, TraceError> {
        self.step(Some(frame)).map(|n| n.is_some())
    }

    /// Skips the next frame record without decoding its events; returns its
    /// frame number, or `None` after the end marker. From then on the
    /// validator no longer tracks live instances (it cannot know them), so
    /// later frames get only the checks that need no history.
    pub fn skip_frame(&mut self) -> Result<Option<u64>, TraceError> {
        self.step(None)
    }

    fn step(&mut self, frame: Option<&mut Frame>) -> Result<Option<u64>, TraceError> {
        match &self.state {
            ReadState::Frames => {}
            ReadState::Done => return Ok(None),
            ReadState::Failed(e) => return Err((**e).clone()),
        }
        match self.read_record(frame) {
            Ok(Some(n)) => Ok(Some(n)),
            Ok(None) => {
                self.state = ReadState::Done;
                Ok(None)
            }
            Err(e) => {
                self.state = ReadState::Failed(Box::new(e.clone()));
                Err(e)
            }
        }
    }

    fn read_record(&mut self, frame: Option<&mut Frame>) -> Result<Option<u64>, TraceError> {
        let record_at = self.offset;
        self.record_at = record_at;
        let index = self.validator.frames();
        let mut number = None;
        let err = |at: u64, number: Option<u64>, event: Option<u32>, kind| TraceError {
            location: TraceLocation::Byte(at),
            frame_index: Some(index),
            frame_number: number,
            event,
            kind,
        };
        self.buf.clear();
        let got = read_up_to(&mut self.r, &mut self.buf, 4)
            .map_err(|e| err(record_at, None, None, TraceErrorKind::io(&e)))?;
        if got == 0 {
            return Err(err(
                record_at,
                None,
                None,
                TraceErrorKind::MissingEnd { frames: index },
            ));
        }
        if got < 4 {
            return Err(err(
                record_at,
                None,
                None,
                TraceErrorKind::Truncated {
                    what: "frame record length",
                    needed: 4,
                    available: got,
                },
            ));
        }
        let len = u32::from_le_bytes([self.buf[0], self.buf[1], self.buf[2], self.buf[3]]);
        let payload_at = record_at + 4;
        if len == 0 {
            return self.read_end(record_at, index).map(|()| None);
        }
        if len > self.limits.max_frame_bytes {
            return Err(err(
                record_at,
                None,
                None,
                TraceErrorKind::LimitExceeded {
                    what: "frame record bytes",
                    value: len.into(),
                    limit: self.limits.max_frame_bytes.into(),
                },
            ));
        }
        self.buf.clear();
        let got = read_up_to(&mut self.r, &mut self.buf, len.into())
            .map_err(|e| err(payload_at, None, None, TraceErrorKind::io(&e)))?;
        if self.buf.len() >= 8 {
            let mut b = [0u8; 8];
            b.copy_from_slice(&self.buf[..8]);
            number = Some(u64::from_le_bytes(b));
        }
        if got < u64::from(len) {
            return Err(err(
                payload_at + got,
                number,
                None,
                TraceErrorKind::Truncated {
                    what: "frame record",
                    needed: len.into(),
                    available: got,
                },
            ));
        }
        self.offset = payload_at + u64::from(len);
        let Some(frame) = frame else {
            let Some(n) = number else {
                return Err(err(
                    payload_at,
                    None,
                    None,
                    TraceErrorKind::Truncated {
                        what: "frame number",
                        needed: 8,
                        available: len.into(),
                    },
                ));
            };
            if len < FRAME_FIXED_BYTES as u32 {
                return Err(err(
                    payload_at,
                    number,
                    None,
                    TraceErrorKind::Truncated {
                        what: "frame record",
                        needed: FRAME_FIXED_BYTES,
                        available: len.into(),
                    },
                ));
            }
            self.validator
                .note_skipped(n)
                .map_err(|k| err(payload_at, number, None, k))?;
            return Ok(Some(n));
        };
        let mut c = Cur {
            data: &self.buf,
            pos: 0,
            base: payload_at,
        };
        decode_frame(
            &mut c,
            &self.limits,
            &mut self.validator,
            frame,
            &mut self.offsets,
        )
        .map_err(|(at, k)| err(at, number, self.offsets.in_event, k))?;
        Ok(Some(frame.number))
    }

    fn read_end(&mut self, record_at: u64, frames: u64) -> Result<(), TraceError> {
        let at = record_at + 4;
        let e = |at, kind| TraceError::at(TraceLocation::Byte(at), kind);
        self.buf.clear();
        let got =
            read_up_to(&mut self.r, &mut self.buf, 8).map_err(|x| e(at, TraceErrorKind::io(&x)))?;
        if got < 8 {
            return Err(e(
                at + got,
                TraceErrorKind::Truncated {
                    what: "end marker frame count",
                    needed: 8,
                    available: got,
                },
            ));
        }
        let mut b = [0u8; 8];
        b.copy_from_slice(&self.buf[..8]);
        let recorded = u64::from_le_bytes(b);
        if recorded != frames {
            return Err(e(
                at,
                TraceErrorKind::FrameCountMismatch {
                    recorded,
                    read: frames,
                },
            ));
        }
        self.offset = at + 8;
        self.buf.clear();
        let extra = read_up_to(&mut self.r, &mut self.buf, 1)
            .map_err(|x| e(self.offset, TraceErrorKind::io(&x)))?;
        if extra != 0 {
            return Err(e(self.offset, TraceErrorKind::TrailingData));
        }
        Ok(())
    }
}
