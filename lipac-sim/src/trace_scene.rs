//! Geometry replay of any trace whose header carries geometry: the trace
//! becomes a [`Scene`] and goes through [`Comparison`] exactly as in
//! `compare` (ground truth, every strategy, the error).
//!
//! * **Meshes**: one shared BLAS per (mesh, LOD) from the header's indexed
//!   geometry. The tracer holds [`LOD_COUNT`] LODs per mesh: a trace mesh
//!   with `k` LODs maps to `[0, min(1, k - 1), k - 1]`, and a recorded LOD
//!   `l` traces as 0 if `l = 0`, as the coarsest if `l = k - 1 ≥ 2`, else as
//!   the second (traces with more than three LODs trace their middle LODs as
//!   the second). A LOD without geometry is an error naming the mesh, or,
//!   with [`TraceSceneOptions::box_proxy`], a box over the mesh's bounds,
//!   listed in [`TraceReplay::box_proxies`] and in the report's scene name.
//! * **Materials** from flags: a mesh any of whose instances is flagged
//!   `vegetation` is leaves (traced with the vegetation mask, so shadow
//!   rays skip it as they skip the built-in trees), alpha-tested by default
//!   with the built-in trees' leaf pattern: the mesh's bounds are mapped
//!   into the trees' crown (the scene mesh holds the triangles in crown
//!   space and every instance's transform the inverse map, so the world
//!   geometry is the trace's), so the pattern covers the whole mesh (about
//!   55 % of its surface opaque, in cells that scale with the mesh).
//!   [`TraceSceneOptions::vegetation_alpha`] `false` (the scene file's
//!   `"vegetation_alpha": false`, `lipac replay --no-vegetation-alpha`)
//!   traces vegetation opaque. Everything else is wall: the non-vegetation
//!   instances of a mesh used both ways trace as a second, wall copy of the
//!   mesh (slots are per mesh and material), and an update that flips
//!   `vegetation` moves the instance to a slot of the other copy (the old
//!   one is parked), so the material and the vegetation mask follow the
//!   flag from that frame on.
//! * **Sun and sky**: [`crate::pathtrace::PathTraceConfig`]'s defaults,
//!   overridden by [`Lighting`] (a small JSON scene file,
//!   [`TraceSceneOptions::with_json`]).
//! * **Instances** from the events, at any frame: adds, updates (pose, LOD,
//!   flags: `pinned` reaches LiPaC's Manager in that frame, a changed
//!   `static` makes the slot animated), removes; cameras as recorded. The trace is read twice: a first
//!   pass ([`TracePlan::scan`]) assigns every instance a scene slot, reusing
//!   the slots of removed instances of the same mesh, so the scene holds as
//!   many slots as instances of each mesh are live at once, not as many as
//!   the trace ever adds. A slot not live in a frame is parked 100 km below
//!   the world (no ray reaches it). Slots whose occupant moves, comes or
//!   goes after the first frame are animated for the strategies (LiPaC
//!   follows their poses; their BLASes are accounted as refit per frame).
//!   A parked slot still counts for strategies that keep it (the full
//!   scene's TLAS records and modelled memory include parked slots).
//! * `unique_blas` is not modelled (every trace mesh is a shared BLAS).
//!
//! Memory follows the live instances (slots, one map entry per live id) and
//! the header's geometry; apart from the per-frame metrics kept for the
//! report, not the trace's length.

use std::cell::RefCell;
use std::collections::{HashMap, HashSet};
use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::sync::atomic::{AtomicU64, Ordering};

use glam::{Affine3A, Vec3};
use lipac_core::instance::{InstanceFlags, MeshId};
use lipac_core::math::{rows_to_affine, Aabb};
use lipac_core::trace::{Frame, InstanceEvent, LodInfo, MeshInfo, TraceHeader};
use obvhs::triangle::Triangle;
use serde::Deserialize;

use crate::camera::FlyCamera;
use crate::compare::{CompareReport, Comparison};
use crate::error::SimError;
use crate::mesh::{
    material, LodTriangles, Mesh, MeshKind, MeshLibrary, CROWN_CENTER, CROWN_RADII, LOD_COUNT,
};
use crate::pathtrace::PathTraceConfig;
use crate::record::{from_trace_camera, SceneRef};
use crate::replay::{empty_frame, replay_with_snapshots, ReplayConfig, ReplayMode, TraceInput};
use crate::scene::{flags, Scene, SceneConfig, SceneInstance};
use crate::snapshot::Snapshot;

/// How far below the world a slot that is not live waits, metres.
pub const PARK_DEPTH: f32 = 1.0e5;

/// Sun and sky of a trace replay.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lighting {
    /// Direction towards the sun (finite, non-zero).
    pub sun_direction: Vec3,
    /// Sun irradiance, linear RGB.
    pub sun_irradiance: Vec3,
    /// Constant sky radiance, linear RGB.
    pub sky_radiance: Vec3,
}

impl Default for Lighting {
    /// The path tracer's defaults (those of `compare`).
    fn default() -> Self {
        let p = PathTraceConfig::default();
        Self {
            sun_direction: p.sun_direction,
            sun_irradiance: p.sun_irradiance,
            sky_radiance: p.sky_radiance,
        }
    }
}

/// Options of a trace-backed geometry replay.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TraceSceneOptions {
    /// Trace a box over the mesh bounds for a LOD without geometry (instead
    /// of failing). Default `false`.
    pub box_proxy: bool,
    /// Sun and sky. Default [`Lighting::default`].
    pub lighting: Lighting,
    /// Alpha-test vegetation with the built-in trees' leaf pattern.
    /// Default `true` (the issue's "vegetation alpha-tested").
    pub vegetation_alpha: bool,
}

impl Default for TraceSceneOptions {
    fn default() -> Self {
        Self {
            box_proxy: false,
            lighting: Lighting::default(),
            vegetation_alpha: true,
        }
    }
}

/// The JSON scene file: every field optional.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    sun_direction: Option<[f32; 3]>,
    sun_irradiance: Option<[f32; 3]>,
    sky_radiance: Option<[f32; 3]>,
    vegetation_alpha: Option<bool>,
    box_proxy: Option<bool>,
}

impl TraceSceneOptions {
    /// `self` overridden by a JSON scene file, e.g.
    /// `{"sun_direction": [0.3, 0.9, 0.2], "sun_irradiance": [3, 3, 3],
    /// "sky_radiance": [0.3, 0.4, 0.6], "vegetation_alpha": false,
    /// "box_proxy": false}`; every field is optional, unknown fields are
    /// refused.
    ///
    /// ```
    /// use lipac_sim::trace_scene::TraceSceneOptions;
    /// let o = TraceSceneOptions::default().with_json(r#"{"sky_radiance":[1,1,1]}"#).unwrap();
    /// assert_eq!(o.lighting.sky_radiance, glam::Vec3::ONE);
    /// assert!(TraceSceneOptions::default().with_json(r#"{"sky":1}"#).is_err());
    /// ```
    pub fn with_json(mut self, json: &str) -> Result<Self, SimError> {
        let f: SceneFile =
            serde_json::from_str(json).map_err(|e| SimError::Replay(format!("scene file: {e}")))?;
        let l = &mut self.lighting;
        if let Some(v) = f.sun_direction {
            l.sun_direction = Vec3::from(v);
        }
        if let Some(v) = f.sun_irradiance {
            l.sun_irradiance = Vec3::from(v);
        }
        if let Some(v) = f.sky_radiance {
            l.sky_radiance = Vec3::from(v);
        }
        if !l.sun_direction.is_finite() || l.sun_direction.length_squared() < 1e-12 {
            return Err(SimError::Replay(
                "scene file: the sun direction must be finite and non-zero".into(),
            ));
        }
        if !l.sun_irradiance.is_finite() || !l.sky_radiance.is_finite() {
            return Err(SimError::Replay(
                "scene file: sun and sky must be finite".into(),
            ));
        }
        if let Some(v) = f.vegetation_alpha {
            self.vegetation_alpha = v;
        }
        if let Some(v) = f.box_proxy {
            self.box_proxy = v;
        }
        Ok(self)
    }
}

/// Scene slots of trace instances: a removed instance's slot goes to the
/// next added instance of the same key ([`slot_key`]: header mesh and
/// vegetation flag).
#[derive(Clone, Debug, Default)]
struct SlotAlloc {
    live: HashMap<u64, u32>,
    free: HashMap<u32, Vec<u32>>,
    /// The key of every slot.
    mesh: Vec<u32>,
}

/// The slot key of an instance of header mesh `mesh` (index) with flags
/// `f`: vegetation and other instances of one mesh trace with different
/// materials, so they hold different slots (an update that flips the
/// vegetation flag moves the instance to a slot of the other key).
fn slot_key(mesh: u32, f: InstanceFlags) -> u32 {
    mesh * 2 + u32::from(f.contains(InstanceFlags::VEGETATION))
}

fn key_is_vegetation(key: u32) -> bool {
    key & 1 == 1
}

impl SlotAlloc {
    /// The slot of a new instance `id` of scene mesh `mesh`, and whether it
    /// is a new slot.
    fn add(&mut self, id: u64, mesh: u32) -> (u32, bool) {
        let (slot, new) = match self.free.get_mut(&mesh).and_then(Vec::pop) {
            Some(s) => (s, false),
            None => {
                self.mesh.push(mesh);
                ((self.mesh.len() - 1) as u32, true)
            }
        };
        self.live.insert(id, slot);
        (slot, new)
    }
    fn remove(&mut self, id: u64) -> Option<u32> {
        let slot = self.live.remove(&id)?;
        self.free
            .entry(self.mesh[slot as usize])
            .or_default()
            .push(slot);
        Some(slot)
    }
    fn slot(&self, id: u64) -> Option<u32> {
        self.live.get(&id).copied()
    }
}

/// What the first pass over a trace learns: its slots and which meshes are
/// vegetation.
#[derive(Clone, Debug, PartialEq)]
pub struct TracePlan {
    /// Slot key ([`slot_key`]) of every slot.
    slot_mesh: Vec<u32>,
    /// Whether the slot's occupant moves, comes or goes after frame 0.
    slot_dynamic: Vec<bool>,
    /// Header meshes used by a vegetation instance.
    vegetation: HashSet<u32>,
    /// Header meshes used by vegetation and by other instances: they get a
    /// second scene mesh (wall) after the header's, in header order.
    mixed: Vec<u32>,
    /// Frames in the trace.
    frames: u64,
}

impl TracePlan {
    /// The scene mesh of slot key `key`: the header mesh's own index (its
    /// material leaves if any of its instances is vegetation, else wall),
    /// or, for the non-vegetation instances of a mesh used both ways, its
    /// wall variant after the header's meshes.
    fn scene_mesh_of(&self, key: u32, meshes: usize) -> u32 {
        let mesh = key / 2;
        if key_is_vegetation(key) == self.vegetation.contains(&mesh) {
            return mesh;
        }
        let rank = self.mixed.binary_search(&mesh).unwrap_or(self.mixed.len());
        (meshes + rank) as u32
    }
}

/// Header mesh id → (scene mesh index, LOD count).
fn mesh_index(header: &TraceHeader) -> HashMap<MeshId, (u32, u32)> {
    header
        .meshes
        .iter()
        .enumerate()
        .map(|(i, m)| (m.id, (i as u32, m.lods.len() as u32)))
        .collect()
}

fn scene_mesh(index: &HashMap<MeshId, (u32, u32)>, mesh: MeshId) -> Result<u32, SimError> {
    index
        .get(&mesh)
        .map(|&(i, _)| i)
        .ok_or_else(|| SimError::Replay(format!("mesh {} is not in the header", mesh.0)))
}

impl TracePlan {
    /// Reads every frame of `input` (whose header is `header`), assigning
    /// slots as [`TraceScene`] will.
    pub fn scan<R: Read>(
        header: &TraceHeader,
        input: &mut TraceInput<R>,
    ) -> Result<Self, SimError> {
        let index = mesh_index(header);
        let mut alloc = SlotAlloc::default();
        let mut dynamic = Vec::new();
        let mut vegetation = HashSet::new();
        let mut plain = HashSet::new();
        // The static flag of every slot's occupant.
        let mut is_static: Vec<bool> = Vec::new();
        let mut frame = empty_frame();
        let mut frames = 0u64;
        let add = |alloc: &mut SlotAlloc,
                   dynamic: &mut Vec<bool>,
                   is_static: &mut Vec<bool>,
                   (id, key): (u64, u32),
                   later: bool,
                   st: bool| {
            let (slot, new) = alloc.add(id, key);
            if new {
                dynamic.push(later);
                is_static.push(st);
            } else {
                dynamic[slot as usize] = true;
                is_static[slot as usize] = st;
            }
            slot
        };
        while input.next_frame_into(&mut frame)? {
            let later = frames > 0;
            for e in &frame.events {
                match e {
                    InstanceEvent::Add(a) => {
                        let mesh = scene_mesh(&index, a.mesh)?;
                        let key = slot_key(mesh, a.flags);
                        let st = a.flags.contains(InstanceFlags::STATIC);
                        add(
                            &mut alloc,
                            &mut dynamic,
                            &mut is_static,
                            (a.id, key),
                            later,
                            st,
                        );
                        if key_is_vegetation(key) {
                            vegetation.insert(mesh);
                        } else {
                            plain.insert(mesh);
                        }
                    }
                    InstanceEvent::Update(u) => {
                        let mut slot = alloc.slot(u.id).ok_or_else(|| {
                            SimError::Replay(format!("update of instance {}, not live", u.id))
                        })?;
                        if let Some(f) = u.flags {
                            let key = alloc.mesh[slot as usize];
                            let new_key = slot_key(key / 2, f);
                            if new_key != key {
                                // Vegetation flipped: to a slot of the other
                                // material (the old one is parked).
                                alloc.remove(u.id);
                                dynamic[slot as usize] = true;
                                let st = f.contains(InstanceFlags::STATIC);
                                let ids = (u.id, new_key);
                                slot =
                                    add(&mut alloc, &mut dynamic, &mut is_static, ids, later, st);
                            }
                            if key_is_vegetation(new_key) {
                                vegetation.insert(new_key / 2);
                            } else {
                                plain.insert(new_key / 2);
                            }
                            // A static flag that changes: animated for the
                            // strategies (their BLAS kind cannot change).
                            let st = f.contains(InstanceFlags::STATIC);
                            if later && is_static[slot as usize] != st {
                                dynamic[slot as usize] = true;
                            }
                            is_static[slot as usize] = st;
                        }
                        if u.pose.is_some() {
                            dynamic[slot as usize] = true;
                        }
                    }
                    InstanceEvent::Remove { id } => {
                        let slot = alloc.remove(*id).ok_or_else(|| {
                            SimError::Replay(format!("remove of instance {id}, not live"))
                        })?;
                        dynamic[slot as usize] = true;
                    }
                }
            }
            frames += 1;
        }
        let mut mixed: Vec<u32> = vegetation.intersection(&plain).copied().collect();
        mixed.sort_unstable();
        Ok(Self {
            slot_mesh: alloc.mesh,
            slot_dynamic: dynamic,
            vegetation,
            mixed,
            frames,
        })
    }
    /// Scene slots the trace needs.
    pub fn slots(&self) -> usize {
        self.slot_mesh.len()
    }
    /// Frames in the trace.
    pub fn frames(&self) -> u64 {
        self.frames
    }
}

/// The sim LOD a recorded LOD `l` of a mesh with `k` LODs traces as.
pub fn sim_lod(l: u32, k: u32) -> u8 {
    if l == 0 {
        0
    } else if k >= 3 && l + 1 >= k {
        2
    } else {
        1
    }
}

/// The header LOD each sim LOD is made of, for a mesh with `k` LODs.
fn source_lods(k: usize) -> [usize; LOD_COUNT] {
    [0, 1.min(k - 1), k - 1]
}

/// The map from a vegetation mesh's object space (bounds `b`) onto the
/// built-in trees' crown, where [`crate::mesh::leaf_opaque`] is defined:
/// per axis, the bounds' half extent times √3 onto the crown's radius, so
/// that the crown's ellipsoid holds the whole box (an axis of zero extent,
/// a flat quad, takes the smallest scale of the others).
fn crown_map(b: &Aabb) -> Affine3A {
    let half = 0.5 * b.size() * 3f32.sqrt();
    let scale = |h: f32, r: f32| (h > 1e-6).then(|| r / h);
    let s = [
        scale(half.x, CROWN_RADII.x),
        scale(half.y, CROWN_RADII.y),
        scale(half.z, CROWN_RADII.z),
    ];
    let fallback = s.iter().flatten().copied().fold(f32::INFINITY, f32::min);
    let fallback = if fallback.is_finite() { fallback } else { 1.0 };
    let s = Vec3::new(
        s[0].unwrap_or(fallback),
        s[1].unwrap_or(fallback),
        s[2].unwrap_or(fallback),
    );
    Affine3A::from_translation(CROWN_CENTER)
        * Affine3A::from_scale(s)
        * Affine3A::from_translation(-b.center())
}

fn lod_geometry(
    mesh: &MeshInfo,
    lod: usize,
    info: &LodInfo,
    leaves: bool,
    alpha: bool,
    box_proxy: bool,
    map: &Affine3A,
) -> Result<(LodTriangles, bool), SimError> {
    let mat = if leaves {
        material::LEAF
    } else {
        material::WALL
    };
    let mut out = LodTriangles::default();
    let proxied = match &info.geometry {
        Some(g) => {
            for t in g.indices.chunks_exact(3) {
                let v = |i: u32| -> Result<Vec3, SimError> {
                    g.positions
                        .get(i as usize)
                        .map(|&p| map.transform_point3(Vec3::from(p)))
                        .ok_or_else(|| {
                            SimError::Replay(format!(
                                "mesh {} LOD {lod}: index {i} out of range",
                                mesh.id.0
                            ))
                        })
                };
                out.triangles.push(Triangle {
                    v0: v(t[0])?.into(),
                    v1: v(t[1])?.into(),
                    v2: v(t[2])?.into(),
                });
            }
            false
        }
        None if box_proxy => {
            let b = crate::mesh::cuboid(
                map.transform_point3(mesh.bounds.min),
                map.transform_point3(mesh.bounds.max),
                mat,
            );
            out = b.lods[0].clone();
            true
        }
        None => {
            return Err(SimError::Replay(format!(
                "mesh {} LOD {lod} has no geometry in the header (geometry replay needs \
                 every mesh's triangles; record them, or pass --box-proxy to trace a box \
                 over the mesh's bounds instead)",
                mesh.id.0
            )))
        }
    };
    if out.triangles.is_empty() {
        return Err(SimError::Replay(format!(
            "mesh {} LOD {lod} has no triangles",
            mesh.id.0
        )));
    }
    let n = out.triangles.len();
    out.materials = vec![mat; n];
    out.alpha_tested = vec![leaves && alpha; n];
    Ok((out, proxied))
}

/// A trace's scene, one frame at a time: [`TraceScene::apply`] a frame's
/// events, then render [`TraceScene::scene`] at [`TraceScene::lods`].
#[derive(Clone, Debug)]
pub struct TraceScene {
    scene: Scene,
    alloc: SlotAlloc,
    index: HashMap<MeshId, (u32, u32)>,
    /// Scene mesh of every slot key of the trace.
    key_mesh: HashMap<u32, u32>,
    /// The recorded transform of every slot's occupant (kept for a move to
    /// a slot of the other material).
    rows: Vec<[f32; 12]>,
    dynamic: Vec<bool>,
    lods: Vec<u8>,
    lod_counts: Vec<u32>,
    /// Per scene mesh: the inverse of its object-space map (identity, or
    /// the crown map of an alpha-tested vegetation mesh), applied after
    /// every recorded transform.
    unmap: Vec<Affine3A>,
    park_at: Vec3,
    box_proxies: Vec<u32>,
}

impl TraceScene {
    /// The scene of a trace with `header`, planned by `plan`, every slot
    /// parked until the first frame's events.
    pub fn new(
        header: &TraceHeader,
        plan: &TracePlan,
        options: &TraceSceneOptions,
    ) -> Result<Self, SimError> {
        if !header.world.is_bounded() {
            // The parking place and the scene extent come from the bounds.
            return Err(SimError::BadConfig(
                "a trace without world bounds replays hits-only (--mode hits-only), not with geometry",
            ));
        }
        let index = mesh_index(header);
        let mut library = MeshLibrary::new();
        let mut box_proxies = Vec::new();
        let mut unmap = Vec::with_capacity(header.meshes.len());
        // The header's meshes (leaves if any instance is vegetation), then
        // the wall variants of the meshes used both ways.
        let variants = (0..header.meshes.len())
            .map(|i| (i, plan.vegetation.contains(&(i as u32))))
            .chain(plan.mixed.iter().map(|&m| (m as usize, false)));
        let mut lod_counts = Vec::new();
        for (i, leaves) in variants {
            let m = &header.meshes[i];
            lod_counts.push(m.lods.len() as u32);
            let map = if leaves && options.vegetation_alpha {
                crown_map(&geometry_bounds(m))
            } else {
                Affine3A::IDENTITY
            };
            unmap.push(map.inverse());
            let mut lods: [LodTriangles; LOD_COUNT] = Default::default();
            let mut proxied = false;
            for (sim, &src) in source_lods(m.lods.len()).iter().enumerate() {
                let (g, p) = lod_geometry(
                    m,
                    src,
                    &m.lods[src],
                    leaves,
                    options.vegetation_alpha,
                    options.box_proxy,
                    &map,
                )?;
                lods[sim] = g;
                proxied |= p;
            }
            if proxied && !box_proxies.contains(&m.id.0) {
                box_proxies.push(m.id.0);
            }
            let mut bounds = Aabb::new(
                map.transform_point3(m.bounds.min),
                map.transform_point3(m.bounds.max),
            );
            for l in &lods {
                let b = l.bounds();
                bounds = Aabb::new(bounds.min.min(b.min), bounds.max.max(b.max));
            }
            library.add(Mesh {
                kind: if leaves {
                    MeshKind::Tree
                } else {
                    MeshKind::Building
                },
                lods,
                bounds,
            });
        }
        let w = header.world;
        let centre = Vec3::new(
            (0.5 * (w.min[0] + w.max[0])) as f32,
            -PARK_DEPTH,
            (0.5 * (w.min[1] + w.max[1])) as f32,
        );
        let extent = ((w.max[0] - w.min[0]).max(w.max[1] - w.min[1]) as f32).max(1.0);
        let key_mesh: HashMap<u32, u32> = plan
            .slot_mesh
            .iter()
            .map(|&k| (k, plan.scene_mesh_of(k, header.meshes.len())))
            .collect();
        let mut placed = Vec::with_capacity(plan.slots());
        for (slot, key) in plan.slot_mesh.iter().enumerate() {
            placed.push(parked(&library, key_mesh[key], centre, slot)?);
        }
        let config = SceneConfig {
            extent,
            hill_height: 0.0,
            ..SceneConfig::small()
        };
        let scene = Scene::from_instances(config, library, placed)?;
        Ok(Self {
            scene,
            alloc: SlotAlloc::default(),
            index,
            key_mesh,
            rows: vec![[0.0; 12]; plan.slots()],
            dynamic: plan.slot_dynamic.clone(),
            lods: vec![(LOD_COUNT - 1) as u8; plan.slots()],
            lod_counts,
            unmap,
            park_at: centre,
            box_proxies,
        })
    }

    /// Applies `frame`'s events (in order).
    pub fn apply(&mut self, frame: &Frame) -> Result<(), SimError> {
        for (i, e) in frame.events.iter().enumerate() {
            self.apply_event(e).map_err(|err| {
                let err = match err {
                    SimError::Replay(m) => m,
                    other => other.to_string(),
                };
                SimError::Replay(format!(
                    "frame number {}, event {i} ({} of instance {}): {err}",
                    frame.number,
                    match e {
                        InstanceEvent::Add(_) => "add",
                        InstanceEvent::Update(_) => "update",
                        InstanceEvent::Remove { .. } => "remove",
                    },
                    e.id()
                ))
            })?;
        }
        Ok(())
    }

    fn sim_flags(&self, slot: u32, f: InstanceFlags) -> u8 {
        let mut out = 0;
        if f.contains(InstanceFlags::VEGETATION) {
            out |= flags::VEGETATION;
        }
        if f.contains(InstanceFlags::PINNED) {
            out |= flags::PINNED;
        }
        if self.dynamic.get(slot as usize).copied().unwrap_or(true) {
            out |= flags::ANIMATED;
        } else if f.contains(InstanceFlags::STATIC) {
            out |= flags::STATIC;
        }
        out
    }

    fn apply_event(&mut self, e: &InstanceEvent) -> Result<(), SimError> {
        match e {
            InstanceEvent::Add(a) => {
                let &(mesh, k) = self
                    .index
                    .get(&a.mesh)
                    .ok_or_else(|| SimError::Replay(format!("mesh {} unknown", a.mesh.0)))?;
                let key = slot_key(mesh, a.flags);
                let (slot, mesh) = self.add_slot(a.id, key)?;
                let inst = SceneInstance {
                    transform: traceable(&a.pose.transform)? * self.unmap[mesh as usize],
                    aabb: a.pose.aabb,
                    mesh,
                    flags: self.sim_flags(slot, a.flags),
                };
                self.scene.set_instance(slot, inst)?;
                self.rows[slot as usize] = a.pose.transform;
                self.lods[slot as usize] = sim_lod(a.lod, k);
            }
            InstanceEvent::Update(u) => {
                let mut slot = self
                    .alloc
                    .slot(u.id)
                    .ok_or_else(|| SimError::Replay("not live".into()))?;
                let mut inst = *self.scene.instance(slot)?;
                if let Some(f) = u.flags {
                    let key = self.alloc.mesh[slot as usize];
                    let new_key = slot_key(key / 2, f);
                    if new_key != key {
                        // Vegetation flipped: the instance moves to a slot
                        // of the other material (as the first pass did),
                        // the old slot is parked.
                        let old = slot;
                        self.alloc.remove(u.id);
                        let (s, mesh) = self.add_slot(u.id, new_key)?;
                        slot = s;
                        inst.mesh = mesh;
                        inst.transform =
                            traceable(&self.rows[old as usize])? * self.unmap[mesh as usize];
                        self.rows[slot as usize] = self.rows[old as usize];
                        self.lods[slot as usize] = self.lods[old as usize];
                        self.park(old)?;
                    }
                }
                if let Some(p) = &u.pose {
                    inst.transform = traceable(&p.transform)? * self.unmap[inst.mesh as usize];
                    inst.aabb = p.aabb;
                    self.rows[slot as usize] = p.transform;
                }
                if let Some(f) = u.flags {
                    inst.flags = self.sim_flags(slot, f);
                }
                if let Some(l) = u.lod {
                    let k = self
                        .lod_counts
                        .get(inst.mesh as usize)
                        .copied()
                        .unwrap_or(1);
                    self.lods[slot as usize] = sim_lod(l, k);
                }
                self.scene.set_instance(slot, inst)?;
            }
            InstanceEvent::Remove { id } => {
                let slot = self
                    .alloc
                    .remove(*id)
                    .ok_or_else(|| SimError::Replay("not live".into()))?;
                self.park(slot)?;
            }
        }
        Ok(())
    }

    /// A slot for instance `id` with slot key `key`, and its scene mesh.
    fn add_slot(&mut self, id: u64, key: u32) -> Result<(u32, u32), SimError> {
        let (slot, _) = self.alloc.add(id, key);
        let mesh = self.key_mesh.get(&key).copied();
        match mesh {
            Some(mesh) if self.alloc.mesh.len() <= self.scene.instances().len() => Ok((slot, mesh)),
            _ => Err(SimError::Replay(
                "the trace differs from its first read (more slots)".into(),
            )),
        }
    }

    /// Parks `slot` below the world (no live instance).
    fn park(&mut self, slot: u32) -> Result<(), SimError> {
        let mesh = self.scene.instance(slot)?.mesh;
        let p = parked(self.scene.library(), mesh, self.park_at, slot as usize)?;
        self.scene.set_instance(slot, p)?;
        self.lods[slot as usize] = (LOD_COUNT - 1) as u8;
        Ok(())
    }

    /// The scene at the events applied so far.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }
    /// The sim LOD of every slot ([`sim_lod`] of the recorded LOD).
    pub fn lods(&self) -> &[u8] {
        &self.lods
    }
    /// The slot of live instance `id`.
    pub fn slot_of(&self, id: u64) -> Option<u32> {
        self.alloc.slot(id)
    }
    /// Instances live now.
    pub fn live(&self) -> usize {
        self.alloc.live.len()
    }
    /// Header mesh ids traced as box proxies.
    pub fn box_proxies(&self) -> &[u32] {
        &self.box_proxies
    }
}

/// The bounds of a mesh's geometry over all its LODs (its declared bounds
/// where no LOD has geometry).
fn geometry_bounds(m: &MeshInfo) -> Aabb {
    let mut it = m
        .lods
        .iter()
        .filter_map(|l| l.geometry.as_ref())
        .flat_map(|g| g.positions.iter().map(|&p| Vec3::from(p)));
    match it.next() {
        None => m.bounds,
        Some(first) => {
            let (min, max) = it.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p)));
            Aabb::new(min, max)
        }
    }
}

/// The transform of `rows`, if the path tracer can trace it (finite, with
/// an invertible linear part, as [`crate::tlas::Tlas`] requires).
fn traceable(rows: &[f32; 12]) -> Result<Affine3A, SimError> {
    let t = rows_to_affine(rows);
    let det = t.matrix3.determinant();
    if !t.is_finite() || !det.is_finite() || det.abs() < 1e-12 {
        return Err(SimError::Replay(format!(
            "the transform is singular (determinant {det:e}); the path tracer cannot trace it"
        )));
    }
    Ok(t)
}

/// Slot `slot` of mesh `mesh`, parked below the world at `at`.
fn parked(
    library: &MeshLibrary,
    mesh: u32,
    at: Vec3,
    slot: usize,
) -> Result<SceneInstance, SimError> {
    let b = library.bounds(mesh)?;
    // Spread parked slots a little so their boxes do not all coincide.
    let at = at - Vec3::new(0.0, (slot % 64) as f32 * 1.0e3, 0.0);
    let transform = Affine3A::from_translation(at - b.center());
    Ok(SceneInstance {
        transform,
        aabb: Aabb::new(at - 0.5 * b.size(), at + 0.5 * b.size()),
        mesh,
        flags: flags::ANIMATED,
    })
}

/// A trace-backed geometry replay's results.
#[derive(Clone, Debug, PartialEq)]
pub struct TraceReplay {
    /// The comparison's report (as `compare`'s).
    pub report: CompareReport,
    /// Scene slots used (at most the sum over meshes of their instances
    /// live at once).
    pub slots: usize,
    /// Header mesh ids traced as box proxies.
    pub box_proxies: Vec<u32>,
    /// The snapshots of `ReplayConfig::snapshots`, in frame order.
    pub snapshots: Vec<Snapshot>,
}

/// Replays a trace in geometry mode through a [`TraceScene`] (see the
/// module docs). `open` opens the trace from its start; it is called twice
/// and must give the same trace both times. `progress(frames_done)` is
/// called after every rendered frame.
pub fn replay_trace<R: Read>(
    mut open: impl FnMut() -> Result<TraceInput<R>, SimError>,
    config: &ReplayConfig,
    options: &TraceSceneOptions,
    progress: &mut dyn FnMut(u64),
) -> Result<TraceReplay, SimError> {
    let mut input = open()?;
    let header = input.header().clone();
    let plan = TracePlan::scan(&header, &mut input)?;
    drop(input);
    replay_planned(&header, &plan, open()?, config, options, progress)
}

/// The second pass of [`replay_trace`]: `input` from its start, planned by
/// `plan` (its first pass over the same trace).
fn replay_planned<R: Read>(
    header: &TraceHeader,
    plan: &TracePlan,
    mut input: TraceInput<R>,
    config: &ReplayConfig,
    options: &TraceSceneOptions,
    progress: &mut dyn FnMut(u64),
) -> Result<TraceReplay, SimError> {
    if plan.slots() == 0 {
        return Err(SimError::Replay("the trace adds no instance".into()));
    }
    if input.header() != header {
        return Err(SimError::Replay(
            "the trace changed between its two reads".into(),
        ));
    }
    let mut ts = TraceScene::new(header, plan, options)?;
    let name = if ts.box_proxies().is_empty() {
        header.scene_name.clone()
    } else {
        let ids: Vec<String> = ts.box_proxies().iter().map(u32::to_string).collect();
        format!(
            "{} (box proxies for meshes {})",
            header.scene_name,
            ids.join(", ")
        )
    };
    let mut cmp: Option<Comparison> = None;
    let mut previous = None;
    let mut frame = empty_frame();
    let mut read = 0u64;
    while input.next_frame_into(&mut frame)? {
        ts.apply(&frame)?;
        let number = u32::try_from(frame.number).map_err(|_| {
            SimError::Replay(format!(
                "frame record {read}: frame number {} above 2^32 - 1",
                frame.number
            ))
        })?;
        let camera = from_trace_camera(&frame.camera)?;
        let cut = previous.is_some_and(|p: FlyCamera| camera.is_cut_from(&p));
        previous = Some(camera);
        let c = match &mut cmp {
            Some(c) => c,
            None => {
                let mut c = config.comparison(&name, ts.scene())?;
                c.capture_frames(&config.snapshots);
                let l = options.lighting;
                c.set_lighting(l.sun_direction, l.sun_irradiance, l.sky_radiance)?;
                cmp.insert(c)
            }
        };
        if cut {
            c.mark_camera_cut(number);
        }
        c.frame_with_lods(ts.scene(), number, &camera, ts.lods())?;
        read += 1;
        progress(read);
    }
    if read != plan.frames() {
        return Err(SimError::Replay(
            "the trace changed between its two reads (frame count)".into(),
        ));
    }
    let (report, snapshots) = cmp
        .ok_or_else(|| SimError::Replay("the trace has no frames".into()))?
        .finish_with_snapshots()?;
    Ok(TraceReplay {
        report,
        slots: plan.slots(),
        box_proxies: ts.box_proxies,
        snapshots,
    })
}

/// Whether every LOD of every mesh of `header` carries geometry.
pub fn has_geometry(header: &TraceHeader) -> bool {
    header
        .meshes
        .iter()
        .all(|m| m.lods.iter().all(|l| l.geometry.is_some()))
}

/// Replays the trace file at `path`: built-in scenes and hits-only mode as
/// [`crate::replay::replay`]; any other trace in geometry mode (asked for,
/// or by default when its header carries every mesh's geometry or
/// `options.box_proxy` is set) through a [`TraceScene`]. Returns the report
/// and the snapshots of `config.snapshots`.
pub fn replay_path(
    path: &Path,
    config: &ReplayConfig,
    options: &TraceSceneOptions,
    progress: &mut dyn FnMut(u64),
) -> Result<(CompareReport, Vec<Snapshot>), SimError> {
    let input = TraceInput::open(path)?;
    if !trace_backed(input.header(), config, options) {
        return replay_with_snapshots(input, config, progress);
    }
    drop(input);
    let r = replay_trace(|| TraceInput::open(path), config, options, progress)?;
    Ok((r.report, r.snapshots))
}

/// Whether a trace with `header` replays through a [`TraceScene`]: not a
/// built-in scene, and geometry mode asked for, or by default when the
/// header carries every mesh's geometry or `options.box_proxy` is set.
fn trace_backed(header: &TraceHeader, config: &ReplayConfig, options: &TraceSceneOptions) -> bool {
    SceneRef::parse(&header.scene_name).is_none()
        && match config.mode {
            Some(ReplayMode::Geometry) => true,
            Some(ReplayMode::HitsOnly) => false,
            None => options.box_proxy || has_geometry(header),
        }
}

/// Replays a trace read once from `r` (standard input, a pipe, a FIFO),
/// choosing the mode as [`replay_path`]. Built-in scenes and hits-only
/// mode stream frame by frame. A trace of another scene in geometry mode
/// needs two passes (slot planning, then rendering): its first pass reads
/// the stream, checks it and plans the slots while writing the bytes to a
/// temporary spool file (in [`std::env::temp_dir`], removed at the end,
/// also on error), and the second pass renders from that file. Memory
/// follows the live instances (the plan's slots), never the trace's
/// length; the spool file holds the trace's bytes.
pub fn replay_stream<R: Read>(
    r: R,
    config: &ReplayConfig,
    options: &TraceSceneOptions,
    progress: &mut dyn FnMut(u64),
) -> Result<(CompareReport, Vec<Snapshot>), SimError> {
    let spool = Spool::create()?;
    let writer = Rc::new(RefCell::new(Some(BufWriter::new(spool.file()?))));
    let tee = Tee {
        inner: r,
        spool: Rc::clone(&writer),
        path: spool.path.clone(),
    };
    let mut input = TraceInput::detect(tee)?;
    let header = input.header().clone();
    if !trace_backed(&header, config, options) {
        // One pass: stop spooling, stream.
        writer.borrow_mut().take();
        drop(spool);
        return replay_with_snapshots(input, config, progress);
    }
    let plan = TracePlan::scan(&header, &mut input)?;
    drop(input);
    let mut w = writer
        .borrow_mut()
        .take()
        .ok_or_else(|| SimError::Replay("the spool file was lost".into()))?;
    w.flush().map_err(|e| spool.io(&e))?;
    drop(w);
    let r = replay_planned(
        &header,
        &plan,
        TraceInput::open(&spool.path)?,
        config,
        options,
        progress,
    )?;
    Ok((r.report, r.snapshots))
}

/// A temporary file, removed on drop.
struct Spool {
    path: PathBuf,
}

impl Spool {
    fn create() -> Result<Self, SimError> {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let path =
            std::env::temp_dir().join(format!("lipac-replay-{}-{n}.spool", std::process::id()));
        let spool = Self { path };
        // create_new: never an existing file (or a link planted there).
        OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&spool.path)
            .map_err(|e| spool.io(&e))?;
        Ok(spool)
    }
    fn file(&self) -> Result<File, SimError> {
        OpenOptions::new()
            .write(true)
            .open(&self.path)
            .map_err(|e| self.io(&e))
    }
    fn io(&self, e: &std::io::Error) -> SimError {
        SimError::Io(format!("spool file {}: {e}", self.path.display()))
    }
}

impl Drop for Spool {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// A reader that copies what it reads to the spool while one is set.
struct Tee<R> {
    inner: R,
    spool: Rc<RefCell<Option<BufWriter<File>>>>,
    path: PathBuf,
}

impl<R: Read> Read for Tee<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        if let Some(w) = self.spool.borrow_mut().as_mut() {
            w.write_all(&buf[..n]).map_err(|e| {
                std::io::Error::new(
                    e.kind(),
                    format!("spooling the trace to {}: {e}", self.path.display()),
                )
            })?;
        }
        Ok(n)
    }
}
