//! The JSON-lines trace format: [`JsonlWriter`] and the streaming
//! [`JsonlReader`]. Schema: `docs/trace-format.md`.
//!
//! Floats are written so that parsing gives back the identical `f32` bits:
//! the shortest decimal that round-trips, or, in the rare case where a
//! correctly rounded parse through `f64` would land on a neighbouring
//! `f32`, the exact decimal of the value widened to `f64`.

use super::error::{TraceError, TraceErrorKind, TraceLocation};
use super::model::{
    check_header, AddInstance, BoxHits, Camera, Frame, InstanceEvent, InstanceHits, LodGeometry,
    LodInfo, MeshInfo, MeshTable, Pose, SlotHits, TraceHeader, TraceLimits, UpdateInstance,
    WorldInfo,
};
use super::validate::{check_version, FrameFault, TraceValidator};
use super::TRACE_VERSION;
use crate::instance::{InstanceFlags, MeshId};
use crate::math::Aabb;
use glam::{Quat, Vec3};
use serde::{Deserialize, Serialize};
use std::io::{self, BufRead, BufReader, Read, Write};

/// The `"format"` value of a JSON-lines trace header.
pub const JSONL_FORMAT_NAME: &str = "lipac-trace";

// ---------------------------------------------------------------------------
// Schema (private: the public model is in `model.rs`)

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct HeaderDto {
    format: String,
    version: u64,
    scene: String,
    world: WorldDto,
    meshes: Vec<MeshDto>,
}

#[derive(Deserialize)]
struct HeaderProbe {
    format: Option<String>,
    version: Option<u64>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct WorldDto {
    /// Absent for an unbounded world (`WorldInfo::unbounded`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    min: Option<[f64; 2]>,
    /// Absent for an unbounded world.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    max: Option<[f64; 2]>,
    cell_size: f64,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct AabbDto {
    min: [f32; 3],
    max: [f32; 3],
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct MeshDto {
    id: u32,
    bounds: AabbDto,
    lods: Vec<LodDto>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct LodDto {
    triangles: u32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    geometry: Option<GeometryDto>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct GeometryDto {
    positions: Vec<[f32; 3]>,
    indices: Vec<u32>,
}

/// A frame or end line as written (reading goes through [`LineSeed`], which
/// checks counts while it parses).
#[derive(Serialize, Default)]
struct LineDto {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    frame: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    camera: Option<CameraDto>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    events: Option<Vec<EventDto>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    hits: Option<Vec<HitDto>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    slot_hits: Option<SlotHitsDto>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    end: Option<EndDto>,
}

/// Version 2's hits by slot: `{"slots":[h0,h1,...],"boxes":[[hitbox,hits],...]}`.
#[derive(Serialize)]
struct SlotHitsDto {
    slots: Vec<u32>,
    boxes: Vec<[u32; 2]>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct EndDto {
    frames: u64,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraDto {
    position: [f32; 3],
    orientation: [f32; 4],
    vertical_fov: f32,
    aspect: f32,
}

#[derive(Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
enum EventDto {
    Add(AddDto),
    Update(UpdateDto),
    Remove(RemoveDto),
}

#[derive(Serialize, Deserialize, Clone, Copy)]
#[serde(rename_all = "snake_case")]
enum FlagName {
    UniqueBlas,
    Vegetation,
    Static,
    Pinned,
}

const FLAG_NAMES: [(FlagName, InstanceFlags); 4] = [
    (FlagName::UniqueBlas, InstanceFlags::UNIQUE_BLAS),
    (FlagName::Vegetation, InstanceFlags::VEGETATION),
    (FlagName::Static, InstanceFlags::STATIC),
    (FlagName::Pinned, InstanceFlags::PINNED),
];

fn flags_to_names(f: InstanceFlags) -> Vec<FlagName> {
    FLAG_NAMES
        .iter()
        .filter(|(_, bit)| f.contains(*bit))
        .map(|(n, _)| *n)
        .collect()
}

fn names_to_flags(names: &[FlagName]) -> InstanceFlags {
    let mut f = InstanceFlags::empty();
    for n in names {
        for (name, bit) in FLAG_NAMES {
            if name as u8 == *n as u8 {
                f.insert(bit);
            }
        }
    }
    f
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct AddDto {
    id: u64,
    mesh: u32,
    lod: u32,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    flags: Vec<FlagName>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    mask: Option<u8>,
    /// Version 2.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    slot: Option<u32>,
    transform: [f32; 12],
    aabb: AabbDto,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct UpdateDto {
    id: u64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    transform: Option<[f32; 12]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    aabb: Option<AabbDto>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    lod: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    flags: Option<Vec<FlagName>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    mask: Option<u8>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RemoveDto {
    id: u64,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct HitDto {
    id: u64,
    hits: u32,
}

fn aabb_dto(a: &Aabb) -> AabbDto {
    AabbDto {
        min: a.min.to_array(),
        max: a.max.to_array(),
    }
}

fn aabb_of(a: &AabbDto) -> Aabb {
    Aabb::new(Vec3::from_array(a.min), Vec3::from_array(a.max))
}

fn header_dto(h: &TraceHeader, version: u16) -> HeaderDto {
    HeaderDto {
        format: JSONL_FORMAT_NAME.into(),
        version: version.into(),
        scene: h.scene_name.clone(),
        world: WorldDto {
            min: h.world.is_bounded().then_some(h.world.min),
            max: h.world.is_bounded().then_some(h.world.max),
            cell_size: h.world.cell_size,
        },
        meshes: h
            .meshes
            .iter()
            .map(|m| MeshDto {
                id: m.id.0,
                bounds: aabb_dto(&m.bounds),
                lods: m
                    .lods
                    .iter()
                    .map(|l| LodDto {
                        triangles: l.triangles,
                        geometry: l.geometry.as_ref().map(|g| GeometryDto {
                            positions: g.positions.clone(),
                            indices: g.indices.clone(),
                        }),
                    })
                    .collect(),
            })
            .collect(),
    }
}

fn header_of(d: HeaderDto) -> TraceHeader {
    TraceHeader {
        scene_name: d.scene,
        world: WorldInfo {
            min: d.world.min.unwrap_or([f64::NEG_INFINITY; 2]),
            max: d.world.max.unwrap_or([f64::INFINITY; 2]),
            cell_size: d.world.cell_size,
        },
        meshes: d
            .meshes
            .into_iter()
            .map(|m| MeshInfo {
                id: MeshId(m.id),
                bounds: aabb_of(&m.bounds),
                lods: m
                    .lods
                    .into_iter()
                    .map(|l| LodInfo {
                        triangles: l.triangles,
                        geometry: l.geometry.map(|g| LodGeometry {
                            positions: g.positions,
                            indices: g.indices,
                        }),
                    })
                    .collect(),
            })
            .collect(),
    }
}

fn frame_dto(f: &Frame) -> LineDto {
    let c = &f.camera;
    LineDto {
        frame: Some(f.number),
        camera: Some(CameraDto {
            position: c.position.to_array(),
            orientation: c.orientation.to_array(),
            vertical_fov: c.vertical_fov,
            aspect: c.aspect,
        }),
        events: Some(
            f.events
                .iter()
                .map(|e| match e {
                    InstanceEvent::Add(a) => EventDto::Add(AddDto {
                        id: a.id,
                        mesh: a.mesh.0,
                        lod: a.lod,
                        flags: flags_to_names(a.flags),
                        mask: a.mask,
                        slot: a.slot,
                        transform: a.pose.transform,
                        aabb: aabb_dto(&a.pose.aabb),
                    }),
                    InstanceEvent::Update(u) => EventDto::Update(UpdateDto {
                        id: u.id,
                        transform: u.pose.map(|p| p.transform),
                        aabb: u.pose.map(|p| aabb_dto(&p.aabb)),
                        lod: u.lod,
                        flags: u.flags.map(flags_to_names),
                        mask: u.mask,
                    }),
                    InstanceEvent::Remove { id } => EventDto::Remove(RemoveDto { id: *id }),
                })
                .collect(),
        ),
        hits: f.hits.as_ref().filter(|_| f.slot_hits.is_none()).map(|hs| {
            hs.iter()
                .map(|h| HitDto {
                    id: h.id,
                    hits: h.hits,
                })
                .collect()
        }),
        slot_hits: f.slot_hits.as_ref().map(|sh| SlotHitsDto {
            slots: sh.slots.clone(),
            boxes: sh.boxes.iter().map(|b| [b.hitbox, b.hits]).collect(),
        }),
        end: None,
    }
}

/// Event `i` of a frame line, or the fault that keeps it from being one.
fn event_of(i: u32, e: EventDto) -> Result<InstanceEvent, FrameFault> {
    Ok(match e {
        EventDto::Add(a) => InstanceEvent::Add(AddInstance {
            id: a.id,
            mesh: MeshId(a.mesh),
            lod: a.lod,
            flags: names_to_flags(&a.flags),
            mask: a.mask,
            pose: Pose {
                transform: a.transform,
                aabb: aabb_of(&a.aabb),
            },
            slot: a.slot,
        }),
        EventDto::Update(u) => {
            let pose = match (u.transform, u.aabb) {
                (Some(transform), Some(aabb)) => Some(Pose {
                    transform,
                    aabb: aabb_of(&aabb),
                }),
                (None, None) => None,
                _ => {
                    return Err(FrameFault {
                        event: Some(i),
                        kind: TraceErrorKind::InvalidValue {
                            what: "update".into(),
                            reason: "\"transform\" and \"aabb\" must be given together".into(),
                        },
                    })
                }
            };
            InstanceEvent::Update(UpdateInstance {
                id: u.id,
                pose,
                lod: u.lod,
                flags: u.flags.as_deref().map(names_to_flags),
                mask: u.mask,
            })
        }
        EventDto::Remove(r) => InstanceEvent::Remove { id: r.id },
    })
}

// ---------------------------------------------------------------------------
// Line parsing with limits checked while parsing

/// The keys of a frame or end line.
#[derive(Deserialize)]
#[serde(field_identifier, rename_all = "snake_case")]
enum LineKey {
    Frame,
    Camera,
    Events,
    Hits,
    SlotHits,
    End,
}

/// What a line held, with its events and hits already converted.
#[derive(Default)]
struct LineParts {
    frame: Option<u64>,
    camera: Option<CameraDto>,
    has_events: bool,
    hits: Option<Vec<InstanceHits>>,
    slot_hits: Option<SlotHits>,
    end: Option<EndDto>,
}

/// Parses one line, converting events and hit counts as they are parsed and
/// stopping at the first one past its limit (or the first event that cannot
/// be converted): memory stays at the line's bytes plus the events allowed,
/// however many the line holds. The fault that stopped parsing is left in
/// `stop` (serde's error then only says parsing was stopped).
struct LineSeed<'a> {
    limits: &'a TraceLimits,
    events: &'a mut Vec<InstanceEvent>,
    stop: &'a mut Option<FrameFault>,
    /// The `"frame"` number once parsed (for the error of a line stopped
    /// later).
    number: &'a mut Option<u64>,
}

impl<'de> serde::de::DeserializeSeed<'de> for LineSeed<'_> {
    type Value = LineParts;
    fn deserialize<D: serde::Deserializer<'de>>(self, d: D) -> Result<LineParts, D::Error> {
        d.deserialize_map(self)
    }
}

impl<'de> serde::de::Visitor<'de> for LineSeed<'_> {
    type Value = LineParts;
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a frame line or the end line (a JSON object)")
    }
    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut m: A) -> Result<LineParts, A::Error> {
        use serde::de::Error;
        let mut parts = LineParts::default();
        let (mut seen_frame, mut seen_camera, mut seen_hits, mut seen_end) =
            (false, false, false, false);
        let mut seen_slot_hits = false;
        let once = |seen: &mut bool, name: &'static str| {
            if std::mem::replace(seen, true) {
                Err(A::Error::duplicate_field(name))
            } else {
                Ok(())
            }
        };
        while let Some(key) = m.next_key::<LineKey>()? {
            match key {
                LineKey::Frame => {
                    once(&mut seen_frame, "frame")?;
                    parts.frame = m.next_value()?;
                    *self.number = parts.frame;
                }
                LineKey::Camera => {
                    once(&mut seen_camera, "camera")?;
                    parts.camera = m.next_value()?;
                }
                LineKey::Events => {
                    once(&mut parts.has_events, "events")?;
                    m.next_value_seed(EventsSeed {
                        limit: self.limits.max_events_per_frame,
                        events: &mut *self.events,
                        stop: &mut *self.stop,
                    })?;
                }
                LineKey::Hits => {
                    once(&mut seen_hits, "hits")?;
                    parts.hits = m.next_value_seed(HitsSeed {
                        limit: self.limits.max_hits_per_frame,
                        stop: &mut *self.stop,
                    })?;
                }
                LineKey::SlotHits => {
                    once(&mut seen_slot_hits, "slot_hits")?;
                    parts.slot_hits = Some(m.next_value_seed(SlotHitsSeed {
                        limits: self.limits,
                        stop: &mut *self.stop,
                    })?);
                }
                LineKey::End => {
                    once(&mut seen_end, "end")?;
                    parts.end = m.next_value()?;
                }
            }
        }
        Ok(parts)
    }
}

/// The fault for a count past its limit while parsing (`value` is the count
/// reached when parsing stopped: the line holds at least that many).
fn over_limit(what: &'static str, limit: u32) -> FrameFault {
    FrameFault {
        event: None,
        kind: TraceErrorKind::LimitExceeded {
            what,
            value: u64::from(limit) + 1,
            limit: limit.into(),
        },
    }
}

struct EventsSeed<'a> {
    limit: u32,
    events: &'a mut Vec<InstanceEvent>,
    stop: &'a mut Option<FrameFault>,
}

impl<'de> serde::de::DeserializeSeed<'de> for EventsSeed<'_> {
    type Value = ();
    fn deserialize<D: serde::Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
        d.deserialize_option(self)
    }
}

impl<'de> serde::de::Visitor<'de> for EventsSeed<'_> {
    type Value = ();
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("an array of events")
    }
    fn visit_none<E>(self) -> Result<(), E> {
        Ok(())
    }
    fn visit_unit<E>(self) -> Result<(), E> {
        Ok(())
    }
    fn visit_some<D: serde::Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
        d.deserialize_seq(self)
    }
    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
        use serde::de::Error;
        while let Some(dto) = seq.next_element::<EventDto>()? {
            let i = self.events.len();
            if i as u64 >= u64::from(self.limit) {
                *self.stop = Some(over_limit("events in frame", self.limit));
                return Err(A::Error::custom("stopped: too many events"));
            }
            match event_of(i as u32, dto) {
                Ok(e) => self.events.push(e),
                Err(f) => {
                    *self.stop = Some(f);
                    return Err(A::Error::custom("stopped: invalid event"));
                }
            }
        }
        Ok(())
    }
}

struct HitsSeed<'a> {
    limit: u32,
    stop: &'a mut Option<FrameFault>,
}

impl<'de> serde::de::DeserializeSeed<'de> for HitsSeed<'_> {
    type Value = Option<Vec<InstanceHits>>;
    fn deserialize<D: serde::Deserializer<'de>>(
        self,
        d: D,
    ) -> Result<Option<Vec<InstanceHits>>, D::Error> {
        d.deserialize_option(self)
    }
}

impl<'de> serde::de::Visitor<'de> for HitsSeed<'_> {
    type Value = Option<Vec<InstanceHits>>;
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("an array of hit counts")
    }
    fn visit_none<E>(self) -> Result<Self::Value, E> {
        Ok(None)
    }
    fn visit_unit<E>(self) -> Result<Self::Value, E> {
        Ok(None)
    }
    fn visit_some<D: serde::Deserializer<'de>>(self, d: D) -> Result<Self::Value, D::Error> {
        d.deserialize_seq(self)
    }
    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
        use serde::de::Error;
        let mut hits = Vec::new();
        while let Some(h) = seq.next_element::<HitDto>()? {
            if hits.len() as u64 >= u64::from(self.limit) {
                *self.stop = Some(over_limit("hit counts in frame", self.limit));
                return Err(A::Error::custom("stopped: too many hit counts"));
            }
            hits.push(InstanceHits {
                id: h.id,
                hits: h.hits,
            });
        }
        Ok(Some(hits))
    }
}

/// `"slot_hits"`: an object with `"slots"` (hit counts, at most
/// [`TraceLimits::max_live_instances`] and [`TraceLimits::max_hits_per_frame`])
/// and `"boxes"` (`[hitbox, hits]` pairs, at most `max_hits_per_frame`),
/// both required; parsing stops at the first element past its limit.
struct SlotHitsSeed<'a> {
    limits: &'a TraceLimits,
    stop: &'a mut Option<FrameFault>,
}

#[derive(Deserialize)]
#[serde(field_identifier, rename_all = "snake_case")]
enum SlotHitsKey {
    Slots,
    Boxes,
}

impl<'de> serde::de::DeserializeSeed<'de> for SlotHitsSeed<'_> {
    type Value = SlotHits;
    fn deserialize<D: serde::Deserializer<'de>>(self, d: D) -> Result<SlotHits, D::Error> {
        d.deserialize_map(self)
    }
}

impl<'de> serde::de::Visitor<'de> for SlotHitsSeed<'_> {
    type Value = SlotHits;
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str(r#"{"slots": [...], "boxes": [[hitbox, hits], ...]}"#)
    }
    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut m: A) -> Result<SlotHits, A::Error> {
        use serde::de::Error;
        let mut out = SlotHits::default();
        let (mut slots, mut boxes) = (false, false);
        let slot_limit = self
            .limits
            .max_live_instances
            .min(self.limits.max_hits_per_frame);
        while let Some(key) = m.next_key::<SlotHitsKey>()? {
            match key {
                SlotHitsKey::Slots => {
                    if std::mem::replace(&mut slots, true) {
                        return Err(A::Error::duplicate_field("slots"));
                    }
                    m.next_value_seed(LimitedSeq {
                        limit: slot_limit,
                        what: "slot hit counts in frame",
                        out: &mut out.slots,
                        stop: &mut *self.stop,
                    })?;
                }
                SlotHitsKey::Boxes => {
                    if std::mem::replace(&mut boxes, true) {
                        return Err(A::Error::duplicate_field("boxes"));
                    }
                    let mut pairs: Vec<[u32; 2]> = Vec::new();
                    m.next_value_seed(LimitedSeq {
                        limit: self.limits.max_hits_per_frame,
                        what: "counting-box hit counts in frame",
                        out: &mut pairs,
                        stop: &mut *self.stop,
                    })?;
                    out.boxes = pairs
                        .into_iter()
                        .map(|[hitbox, hits]| BoxHits { hitbox, hits })
                        .collect();
                }
            }
        }
        if !slots {
            return Err(A::Error::missing_field("slots"));
        }
        if !boxes {
            return Err(A::Error::missing_field("boxes"));
        }
        Ok(out)
    }
}

/// A JSON array into `out`, stopping at the first element past `limit`.
struct LimitedSeq<'a, T> {
    limit: u32,
    what: &'static str,
    out: &'a mut Vec<T>,
    stop: &'a mut Option<FrameFault>,
}

impl<'de, T: Deserialize<'de>> serde::de::DeserializeSeed<'de> for LimitedSeq<'_, T> {
    type Value = ();
    fn deserialize<D: serde::Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
        d.deserialize_seq(self)
    }
}

impl<'de, T: Deserialize<'de>> serde::de::Visitor<'de> for LimitedSeq<'_, T> {
    type Value = ();
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("an array")
    }
    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
        use serde::de::Error;
        while let Some(x) = seq.next_element::<T>()? {
            if self.out.len() as u64 >= u64::from(self.limit) {
                *self.stop = Some(over_limit(self.what, self.limit));
                return Err(A::Error::custom("stopped: too many elements"));
            }
            self.out.push(x);
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------
// Float formatting

/// Compact JSON whose `f32`s parse back bit-exactly.
struct ExactFloats;

impl serde_json::ser::Formatter for ExactFloats {
    fn write_f32<W: ?Sized + Write>(&mut self, w: &mut W, v: f32) -> io::Result<()> {
        w.write_all(format_f32(v).as_bytes())
    }
}

/// The text written for `v`: parsing it as a correctly rounded `f64` and
/// narrowing to `f32` gives `v`'s exact bits (for finite `v`).
pub(crate) fn format_f32(v: f32) -> String {
    // `{:?}` is the shortest decimal that round-trips through a direct f32
    // parse, with an exponent for very large or small values ("1e-7").
    let s = format!("{v:?}");
    match s.parse::<f64>() {
        Ok(d) if (d as f32).to_bits() == v.to_bits() => s,
        // Double rounding (decimal -> f64 -> f32) would land elsewhere: write
        // the exact value instead (every f32 is exactly an f64).
        _ => format!("{:?}", f64::from(v)),
    }
}

fn to_line<T: Serialize>(v: &T, out: &mut Vec<u8>) -> io::Result<()> {
    let mut ser = serde_json::Serializer::with_formatter(&mut *out, ExactFloats);
    v.serialize(&mut ser).map_err(io::Error::other)?;
    out.push(b'\n');
    Ok(())
}

// ---------------------------------------------------------------------------
// Writer

/// Writes a JSON-lines trace frame by frame, checking everything exactly as
/// [`TraceWriter`](super::TraceWriter) does.
///
/// ```
/// use glam::Vec3;
/// use lipac_core::instance::MeshId;
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
/// let camera = Camera::look_to(Vec3::ZERO, Vec3::NEG_Z, Vec3::Y, 1.0, 1.5);
/// let mut w = JsonlWriter::new(Vec::new(), &header)?;
/// w.write_frame(&Frame { number: 3, camera, events: vec![], hits: None, slot_hits: None })?;
/// let text = String::from_utf8(w.finish()?).unwrap();
/// assert_eq!(text.lines().count(), 3); // header, frame, end
/// assert!(text.lines().last().unwrap() == r#"{"end":{"frames":1}}"#);
///
/// let mut r = JsonlReader::new(text.as_bytes())?;
/// assert_eq!(r.header().scene_name, "doc");
/// assert_eq!(r.next_frame()?.map(|f| f.number), Some(3));
/// assert_eq!(r.next_frame()?, None);
/// # Ok::<(), TraceError>(())
/// ```
#[derive(Debug)]
pub struct JsonlWriter<W: Write> {
    w: W,
    line: u64,
    buf: Vec<u8>,
    validator: TraceValidator,
    limits: TraceLimits,
}

fn line_err(line: u64, e: &io::Error) -> TraceError {
    TraceError::at(TraceLocation::Line(line), TraceErrorKind::io(e))
}

impl<W: Write> JsonlWriter<W> {
    /// Checks `header` against the default [`TraceLimits`] and writes line 1.
    pub fn new(w: W, header: &TraceHeader) -> Result<Self, TraceError> {
        Self::with_limits(w, header, TraceLimits::default())
    }

    /// As [`JsonlWriter::new`] with explicit limits.
    pub fn with_limits(
        w: W,
        header: &TraceHeader,
        limits: TraceLimits,
    ) -> Result<Self, TraceError> {
        Self::with_version(w, header, limits, TRACE_VERSION)
    }

    /// As [`JsonlWriter::with_limits`], writing format `version` (1 or 2),
    /// as [`TraceWriter::with_version`](super::TraceWriter::with_version).
    pub fn with_version(
        mut w: W,
        header: &TraceHeader,
        limits: TraceLimits,
        version: u16,
    ) -> Result<Self, TraceError> {
        let here = |kind| TraceError::at(TraceLocation::Line(1), kind);
        check_version(version).map_err(here)?;
        let meshes: MeshTable = check_header(header, &limits).map_err(here)?;
        let mut buf = Vec::new();
        to_line(&header_dto(header, version), &mut buf).map_err(|e| line_err(1, &e))?;
        if buf.len() as u64 > limits.max_header_bytes {
            return Err(here(TraceErrorKind::LimitExceeded {
                what: "header line bytes",
                value: buf.len() as u64,
                limit: limits.max_header_bytes,
            }));
        }
        w.write_all(&buf).map_err(|e| line_err(1, &e))?;
        buf.clear();
        Ok(Self {
            w,
            line: 1,
            buf,
            validator: TraceValidator::with_meshes(meshes, limits, &header.world, version),
            limits,
        })
    }

    /// As [`TraceWriter`](super::TraceWriter)'s: the recorder's ids are
    /// consistent by construction, live instances are not tracked.
    pub(crate) fn trust_instance_ids(&mut self) {
        self.validator.stop_tracking_live();
    }

    /// Checks `frame` (see [`TraceValidator`]) and appends its line.
    pub fn write_frame(&mut self, frame: &Frame) -> Result<(), TraceError> {
        self.write_checked(frame, false)
    }

    /// As [`JsonlWriter::write_frame`] for hit counts that are consistent by
    /// construction (see [`TraceValidator::check_frame_trusted_hits`]).
    pub(crate) fn write_frame_trusted_hits(&mut self, frame: &Frame) -> Result<(), TraceError> {
        self.write_checked(frame, true)
    }

    fn write_checked(&mut self, frame: &Frame, trusted_hits: bool) -> Result<(), TraceError> {
        let line = self.line + 1;
        let index = self.validator.frames();
        let err = |event: Option<u32>, kind| TraceError {
            location: TraceLocation::Line(line),
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
            return Err(err(event, kind));
        }
        self.buf.clear();
        to_line(&frame_dto(frame), &mut self.buf).map_err(|e| err(None, TraceErrorKind::io(&e)))?;
        if self.buf.len() as u64 > u64::from(self.limits.max_frame_bytes) {
            return Err(err(
                None,
                TraceErrorKind::LimitExceeded {
                    what: "frame line bytes",
                    value: self.buf.len() as u64,
                    limit: self.limits.max_frame_bytes.into(),
                },
            ));
        }
        self.w
            .write_all(&self.buf)
            .map_err(|e| err(None, TraceErrorKind::io(&e)))?;
        self.line = line;
        Ok(())
    }

    /// Frames written so far.
    pub fn frames_written(&self) -> u64 {
        self.validator.frames()
    }

    /// Writes the end line, flushes, and returns the sink.
    pub fn finish(mut self) -> Result<W, TraceError> {
        let line = self.line + 1;
        self.buf.clear();
        let end = LineDto {
            end: Some(EndDto {
                frames: self.validator.frames(),
            }),
            ..LineDto::default()
        };
        to_line(&end, &mut self.buf)
            .and_then(|()| self.w.write_all(&self.buf))
            .and_then(|()| self.w.flush())
            .map_err(|e| line_err(line, &e))?;
        Ok(self.w)
    }
}

// ---------------------------------------------------------------------------
// Reader

/// Reads one line of at most `max` bytes (without its `\n` / `\r\n`) into
/// `buf`. Returns `Ok(None)` at end of input, `Err(Ok(len))` when the line is
/// longer than `max`.
fn read_line<R: BufRead>(
    r: &mut R,
    buf: &mut Vec<u8>,
    max: u64,
) -> io::Result<Option<Result<(), u64>>> {
    buf.clear();
    let n = r.take(max.saturating_add(1)).read_until(b'\n', buf)?;
    if n == 0 {
        return Ok(None);
    }
    if buf.last() == Some(&b'\n') {
        buf.pop();
        if buf.last() == Some(&b'\r') {
            buf.pop();
        }
    } else if n as u64 > max {
        return Ok(Some(Err(n as u64)));
    }
    Ok(Some(Ok(())))
}

/// The longest JSON string a frame line may hold, bytes as written (field
/// names and flag names are a few bytes): a longer one is refused as it is
/// read, before a JSON parser copies it (and quotes it whole in its error).
pub(crate) const MAX_FRAME_LINE_STRING: u64 = 256;

/// Reads up to `limit` bytes of a line (its newline included, if within
/// them) into `buf` (cleared first), growing `buf` by doubling but never
/// beyond `limit` bytes; returns the bytes read (0 at end of input).
fn read_line_into<R: BufRead>(r: &mut R, buf: &mut Vec<u8>, limit: u64) -> io::Result<usize> {
    buf.clear();
    let limit = usize::try_from(limit).unwrap_or(usize::MAX);
    while buf.len() < limit {
        let chunk = r.fill_buf()?.len().min(limit - buf.len());
        if chunk == 0 {
            break;
        }
        // Room for the chunk first, so that `read_until` (memchr) never
        // grows `buf` past `limit`.
        if buf.capacity() - buf.len() < chunk {
            let want = (buf.len() + chunk).max(buf.capacity() * 2).min(limit);
            buf.reserve_exact(want - buf.len());
        }
        r.by_ref().take(chunk as u64).read_until(b'\n', buf)?;
        if buf.last() == Some(&b'\n') {
            break;
        }
    }
    Ok(buf.len())
}

/// The rest of a line as a [`Read`]: first `prefix` (the bytes of the line
/// read already), then the [`BufRead`]'s bytes up to (not including) the
/// newline, which it consumes; at most `left` bytes from the `BufRead`, and
/// no JSON string longer than [`MAX_FRAME_LINE_STRING`] (a tiny lexer
/// follows the strings over all the bytes). Past either limit it returns an
/// error and leaves the fault in [`LineReader::fault`].
struct LineReader<'a, R> {
    prefix: &'a [u8],
    r: &'a mut R,
    /// Bytes of the line still allowed from `r`.
    left: u64,
    /// The line's limit (for the error).
    max: u64,
    /// The newline (or the end of input) was reached.
    done: bool,
    in_string: bool,
    escaped: bool,
    /// Bytes of the string being read.
    string_len: u64,
    fault: Option<TraceErrorKind>,
}

impl<'a, R: BufRead> LineReader<'a, R> {
    fn new(prefix: &'a [u8], r: &'a mut R, left: u64) -> Self {
        Self {
            prefix,
            r,
            left,
            max: left + prefix.len() as u64,
            done: false,
            in_string: false,
            escaped: false,
            string_len: 0,
            fault: None,
        }
    }

    /// Reads to the end of the line (after a successful parse only
    /// whitespace is left; `end` has read it).
    fn finish(&mut self) -> io::Result<()> {
        let mut sink = [0u8; 64];
        while self.read(&mut sink)? > 0 {}
        Ok(())
    }

    fn fail(&mut self, kind: TraceErrorKind) -> io::Error {
        let e = io::Error::new(io::ErrorKind::InvalidData, kind.to_string());
        self.fault = Some(kind);
        e
    }

    /// Follows the JSON strings over `bytes`.
    fn lex(&mut self, bytes: &[u8]) -> io::Result<()> {
        for &b in bytes {
            if self.in_string {
                if self.escaped {
                    self.escaped = false;
                } else if b == b'\\' {
                    self.escaped = true;
                } else if b == b'"' {
                    self.in_string = false;
                }
                self.string_len += 1;
            } else if b == b'"' {
                self.in_string = true;
                self.string_len = 0;
            }
        }
        if self.in_string && self.string_len > MAX_FRAME_LINE_STRING {
            return Err(self.fail(TraceErrorKind::InvalidValue {
                what: "JSON string".into(),
                reason: format!(
                    "longer than {MAX_FRAME_LINE_STRING} bytes (a frame line holds only short \
                     names)"
                ),
            }));
        }
        Ok(())
    }
}

impl<R: BufRead> Read for LineReader<'_, R> {
    fn read(&mut self, out: &mut [u8]) -> io::Result<usize> {
        if !self.prefix.is_empty() {
            let n = self.prefix.len().min(out.len());
            out[..n].copy_from_slice(&self.prefix[..n]);
            self.prefix = &self.prefix[n..];
            self.lex(&out[..n])?;
            return Ok(n);
        }
        if self.done || out.is_empty() {
            return Ok(0);
        }
        let avail = self.r.fill_buf()?;
        if avail.is_empty() {
            self.done = true;
            return Ok(0);
        }
        // At most one byte past the limit: reading it tells the line is
        // longer.
        let allowed = usize::try_from(self.left.saturating_add(1)).unwrap_or(usize::MAX);
        let n = avail.len().min(out.len()).min(allowed);
        let taken = avail[..n].iter().position(|&b| b == b'\n').unwrap_or(n);
        let newline = taken < n;
        out[..taken].copy_from_slice(&avail[..taken]);
        self.r.consume(taken + usize::from(newline));
        self.done = newline;
        if taken as u64 > self.left {
            return Err(self.fail(TraceErrorKind::LimitExceeded {
                what: "frame line bytes",
                value: self.max + 1,
                limit: self.max,
            }));
        }
        self.left -= taken as u64;
        self.lex(&out[..taken])?;
        Ok(taken)
    }
}

#[derive(Debug)]
enum ReadState {
    Frames,
    Done,
    Failed(Box<TraceError>),
}

/// Reads a JSON-lines trace frame by frame, with the same checks, limits
/// and guarantees as [`TraceReader`](super::TraceReader); errors name the
/// 1-based line (and the column for JSON syntax or schema errors).
///
/// See [`JsonlWriter`] for an example.
#[derive(Debug)]
pub struct JsonlReader<R: Read> {
    r: BufReader<R>,
    limits: TraceLimits,
    header: TraceHeader,
    validator: TraceValidator,
    line: u64,
    /// The line being parsed (up to
    /// [`TraceLimits::max_buffered_line_bytes`] of it).
    buf: Vec<u8>,
    state: ReadState,
}

fn json_err(e: &serde_json::Error) -> TraceErrorKind {
    TraceErrorKind::Json {
        column: e.column() as u64,
        message: e.to_string(),
    }
}

impl<R: Read> JsonlReader<R> {
    /// Reads and checks the header line with the default [`TraceLimits`].
    pub fn new(r: R) -> Result<Self, TraceError> {
        Self::with_limits(r, TraceLimits::default())
    }

    /// As [`JsonlReader::new`] with explicit limits.
    pub fn with_limits(r: R, limits: TraceLimits) -> Result<Self, TraceError> {
        let mut r = BufReader::new(r);
        let here = |kind| TraceError::at(TraceLocation::Line(1), kind);
        let mut buf = Vec::new();
        match read_line(&mut r, &mut buf, limits.max_header_bytes).map_err(|e| line_err(1, &e))? {
            None => {
                return Err(here(TraceErrorKind::BadMagic { found: Vec::new() }));
            }
            Some(Err(len)) => {
                return Err(here(TraceErrorKind::LimitExceeded {
                    what: "header line bytes",
                    value: len,
                    limit: limits.max_header_bytes,
                }))
            }
            Some(Ok(())) => {}
        }
        let probe: HeaderProbe = serde_json::from_slice(&buf).map_err(|_| {
            here(TraceErrorKind::BadMagic {
                found: buf.iter().take(8).copied().collect(),
            })
        })?;
        if probe.format.as_deref() != Some(JSONL_FORMAT_NAME) {
            return Err(here(TraceErrorKind::BadMagic {
                found: buf.iter().take(8).copied().collect(),
            }));
        }
        let version = match probe.version.and_then(|v| u16::try_from(v).ok()) {
            Some(v) if check_version(v).is_ok() => v,
            _ => {
                return Err(here(TraceErrorKind::UnsupportedVersion {
                    found: probe.version.unwrap_or(0),
                    supported: TRACE_VERSION,
                }))
            }
        };
        let dto: HeaderDto = serde_json::from_slice(&buf).map_err(|e| here(json_err(&e)))?;
        let header = header_of(dto);
        let meshes = check_header(&header, &limits).map_err(here)?;
        let validator = TraceValidator::with_meshes(meshes, limits, &header.world, version);
        buf.clear();
        buf.shrink_to(64 * 1024);
        Ok(Self {
            r,
            limits,
            header,
            validator,
            line: 1,
            buf,
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

    /// The validator every frame passes through.
    pub fn validator(&self) -> &TraceValidator {
        &self.validator
    }

    /// Frames read so far.
    pub fn frames_read(&self) -> u64 {
        self.validator.frames()
    }

    /// The last line read (1 = header).
    pub fn line(&self) -> u64 {
        self.line
    }

    /// Whether the end line was read (every frame is out).
    pub fn is_finished(&self) -> bool {
        matches!(self.state, ReadState::Done)
    }

    /// The next frame, or `None` after the end line.
    pub fn next_frame(&mut self) -> Result<Option<Frame>, TraceError> {
        match &self.state {
            ReadState::Frames => {}
            ReadState::Done => return Ok(None),
            ReadState::Failed(e) => return Err((**e).clone()),
        }
        match self.read() {
            Ok(Some(f)) => Ok(Some(f)),
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

    fn read(&mut self) -> Result<Option<Frame>, TraceError> {
        let line = self.line + 1;
        let index = self.validator.frames();
        let err = |number: Option<u64>, event: Option<u32>, kind| TraceError {
            location: TraceLocation::Line(line),
            frame_index: Some(index),
            frame_number: number,
            event,
            kind,
        };
        let max = u64::from(self.limits.max_frame_bytes);
        let io_err = |e: io::Error| err(None, None, TraceErrorKind::io(&e));
        // A line of up to max_buffered_line_bytes is read whole and parsed
        // from memory (fast); a longer one is parsed as it is read after
        // those bytes, so a line refused at byte k has cost at most
        // max_buffered_line_bytes and what was parsed of its first k bytes.
        let held = max.min(u64::from(self.limits.max_buffered_line_bytes));
        let n = read_line_into(&mut self.r, &mut self.buf, held + 1).map_err(io_err)?;
        if n == 0 {
            return Err(err(
                None,
                None,
                TraceErrorKind::MissingEnd { frames: index },
            ));
        }
        self.line = line;
        let whole = self.buf.last() == Some(&b'\n') || (n as u64) <= held;
        if self.buf.last() == Some(&b'\n') {
            self.buf.pop();
            if self.buf.last() == Some(&b'\r') {
                self.buf.pop();
            }
        }
        if self.buf.is_empty() {
            return Err(err(
                None,
                None,
                TraceErrorKind::InvalidValue {
                    what: "line".into(),
                    reason: "empty line".into(),
                },
            ));
        }
        if !whole && n as u64 > max {
            return Err(err(
                None,
                None,
                TraceErrorKind::LimitExceeded {
                    what: "frame line bytes",
                    value: n as u64,
                    limit: max,
                },
            ));
        }
        let mut events = Vec::new();
        let mut stop = None;
        let mut number = None;
        let seed = LineSeed {
            limits: &self.limits,
            events: &mut events,
            stop: &mut stop,
            number: &mut number,
        };
        let parsed = if whole {
            let mut de = serde_json::Deserializer::from_slice(&self.buf);
            serde::de::DeserializeSeed::deserialize(seed, &mut de)
                .and_then(|parts| de.end().map(|()| parts))
        } else {
            let mut reader = LineReader::new(&self.buf, &mut self.r, max - n as u64);
            let parsed = {
                let mut de = serde_json::Deserializer::from_reader(&mut reader);
                serde::de::DeserializeSeed::deserialize(seed, &mut de)
                    .and_then(|parts| de.end().map(|()| parts))
            };
            if let Some(fault) = reader.fault.take() {
                return Err(err(number, None, fault));
            }
            if parsed.is_ok() {
                // The rest of the line (serde stops at the end of the value;
                // `end` read the whitespace after it up to the newline).
                reader.finish().map_err(io_err)?;
            }
            parsed
        };
        let parts = match (parsed, stop) {
            (Ok(parts), _) => parts,
            (Err(_), Some(FrameFault { event, kind })) => {
                return Err(err(number, event, kind));
            }
            (Err(e), None) => return Err(err(number, None, json_err(&e))),
        };
        let shape_err = |number, reason: &str| {
            err(
                number,
                None,
                TraceErrorKind::InvalidValue {
                    what: "line".into(),
                    reason: reason.into(),
                },
            )
        };
        match parts {
            LineParts {
                end: Some(end),
                frame: None,
                camera: None,
                has_events: false,
                hits: None,
                slot_hits: None,
            } => {
                let e = |kind| TraceError::at(TraceLocation::Line(line), kind);
                if end.frames != index {
                    return Err(e(TraceErrorKind::FrameCountMismatch {
                        recorded: end.frames,
                        read: index,
                    }));
                }
                let more = !self
                    .r
                    .fill_buf()
                    .map_err(|x| e(TraceErrorKind::io(&x)))?
                    .is_empty();
                if more {
                    return Err(TraceError::at(
                        TraceLocation::Line(line + 1),
                        TraceErrorKind::TrailingData,
                    ));
                }
                Ok(None)
            }
            LineParts {
                end: Some(_),
                frame,
                ..
            } => Err(shape_err(frame, "an end line holds only \"end\"")),
            LineParts {
                frame: Some(number),
                camera: Some(camera),
                hits,
                slot_hits,
                end: None,
                ..
            } => {
                if hits.is_some() && slot_hits.is_some() {
                    return Err(shape_err(
                        Some(number),
                        "a frame line holds \"hits\" or \"slot_hits\", not both",
                    ));
                }
                let mut frame = Frame {
                    number,
                    camera: Camera {
                        position: Vec3::from_array(camera.position),
                        orientation: Quat::from_array(camera.orientation),
                        vertical_fov: camera.vertical_fov,
                        aspect: camera.aspect,
                    },
                    events,
                    hits,
                    slot_hits,
                };
                self.validator
                    .check_frame(&frame)
                    .map_err(|FrameFault { event, kind }| err(Some(number), event, kind))?;
                if let Some(sh) = &frame.slot_hits {
                    let mut hits = Vec::new();
                    self.validator.derive_hits(sh, &mut hits);
                    frame.hits = Some(hits);
                }
                Ok(Some(frame))
            }
            LineParts { frame, .. } => Err(shape_err(
                frame,
                "a frame line needs \"frame\" and \"camera\" (or the line is {\"end\": ...})",
            )),
        }
    }
}

#[cfg(test)]
mod tests;
