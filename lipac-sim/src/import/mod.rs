//! `lipac import`: a glTF scene (`.gltf` or `.glb`) as a trace with
//! geometry, ready for `lipac replay` (geometry mode,
//! [`crate::trace_scene`]).
//!
//! * **Meshes** ([`gltf`]): every placed glTF mesh with triangles is a
//!   trace mesh (its triangle primitives merged). Its LODs are the file's
//!   where the placing node has `MSFT_lod` (the mesh, then the LOD nodes'
//!   meshes), else three: the file's triangles and two simplified by
//!   meshoptimizer ([`lod`]; glTF has no core LODs).
//! * **Instances**: every node with a mesh, at its world transform (the
//!   node hierarchy), and every instance of `EXT_mesh_gpu_instancing`
//!   (float TRANSLATION / ROTATION / SCALE). All are added in frame 0.
//! * **Flags** ([`FlagRules`]): by case-insensitive substrings of the
//!   node's, its ancestors' or the mesh's names, overridden by `extras`
//!   `{"lipac": {"vegetation": true, "animated": false, "static": true,
//!   "pinned": true}}` on the node or an ancestor (innermost wins).
//!   `vegetation` sets the trace flag; instances not animated are `static`;
//!   animated ones turn about their vertical axis (0.05 rad per frame), a
//!   pose update every frame (glTF animations are not read). `pinned` sets
//!   [`InstanceFlags::PINNED`] (always traced, never culled).
//! * **Cameras** ([`camera_path`]): the file's camera nodes, or a generated
//!   orbit or fly-through. Each frame records the LOD of every instance by
//!   its distance from the camera (LOD 0 within 10 bounding radii, 1
//!   within 30, else 2) as `update`s when it changes.
//! * **World**: the hitbox grid over the instances' bounds, 64 cells
//!   along the longer side.

pub mod camera_path;
pub mod gltf;
pub mod lod;

use std::io::Write;
use std::path::{Path, PathBuf};

use glam::{Affine3A, Quat, Vec3};
use lipac_core::instance::{InstanceFlags, MeshId};
use lipac_core::math::{affine_to_rows, Aabb};
use lipac_core::trace::{
    AddInstance, Frame, InstanceEvent, JsonlWriter, LodGeometry, LodInfo, MeshInfo, Pose,
    TraceFormat, TraceHeader, TraceWriter, UpdateInstance, WorldInfo,
};

use self::camera_path::CameraSource;
use self::gltf::{read_gltf, ImportedCamera, ImportedInstance, ImportedScene};
use crate::error::SimError;

/// Name patterns of the flag mapping (case-insensitive substrings).
#[derive(Clone, Debug, PartialEq)]
pub struct FlagRules {
    /// Vegetation (alpha-tested foliage).
    pub vegetation: Vec<String>,
    /// Animated (moving) instances.
    pub animated: Vec<String>,
    /// Pinned instances (see the module docs).
    pub pinned: Vec<String>,
}

impl Default for FlagRules {
    fn default() -> Self {
        let v = |s: &[&str]| s.iter().map(|x| x.to_string()).collect();
        Self {
            vegetation: v(&[
                "tree", "veg", "foliage", "leaf", "leaves", "grass", "bush", "plant",
            ]),
            animated: v(&["anim", "character", "npc", "vehicle"]),
            pinned: v(&["pinned"]),
        }
    }
}

/// Flags of one instance after the mapping.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MappedFlags {
    /// Vegetation.
    pub vegetation: bool,
    /// Animated.
    pub animated: bool,
    /// Pinned.
    pub pinned: bool,
}

impl FlagRules {
    /// The flags of an instance with `names` and `extras` (raw JSON),
    /// innermost first.
    pub fn map<'a>(
        &self,
        names: impl IntoIterator<Item = &'a str> + Clone,
        extras: impl IntoIterator<Item = &'a str>,
    ) -> MappedFlags {
        let has = |pats: &[String]| {
            names.clone().into_iter().any(|n| {
                let n = n.to_lowercase();
                pats.iter()
                    .any(|p| !p.is_empty() && n.contains(&p.to_lowercase()))
            })
        };
        let mut f = MappedFlags {
            vegetation: has(&self.vegetation),
            animated: has(&self.animated),
            pinned: has(&self.pinned),
        };
        let (mut veg, mut anim, mut pin, mut stat) = (None, None, None, None);
        for e in extras {
            let Ok(v) = serde_json::from_str::<serde_json::Value>(e) else {
                continue;
            };
            let Some(l) = v.get("lipac") else { continue };
            let b = |k: &str| l.get(k).and_then(serde_json::Value::as_bool);
            veg = veg.or(b("vegetation"));
            anim = anim.or(b("animated"));
            pin = pin.or(b("pinned"));
            stat = stat.or(b("static"));
        }
        if let Some(v) = veg {
            f.vegetation = v;
        }
        if let Some(v) = anim {
            f.animated = v;
        }
        if let Some(s) = stat {
            f.animated = !s;
        }
        if let Some(p) = pin {
            f.pinned = p;
        }
        f
    }
}

/// Settings of an import.
#[derive(Clone, Debug, PartialEq)]
pub struct ImportConfig {
    /// Frames to write.
    pub frames: u32,
    /// Camera path.
    pub camera: CameraSource,
    /// Aspect of generated cameras and file cameras without one.
    pub aspect: f32,
    /// Flag mapping.
    pub rules: FlagRules,
}

impl Default for ImportConfig {
    /// 120 frames, automatic camera, 16:9, default rules.
    fn default() -> Self {
        Self {
            frames: 120,
            camera: CameraSource::Auto,
            aspect: 16.0 / 9.0,
            rules: FlagRules::default(),
        }
    }
}

/// What an import produced.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ImportSummary {
    /// Trace meshes.
    pub meshes: usize,
    /// Triangles of all meshes' LOD 0 / 1 / last.
    pub triangles: [u64; 3],
    /// Meshes whose LODs came from the file (`MSFT_lod`), not generated.
    pub file_lods: usize,
    /// Instances.
    pub instances: usize,
    /// Of which from `EXT_mesh_gpu_instancing`.
    pub gpu_instanced: usize,
    /// Flagged vegetation.
    pub vegetation: usize,
    /// Animated.
    pub animated: usize,
    /// Flagged pinned ([`InstanceFlags::PINNED`]).
    pub pinned: usize,
    /// Whether the cameras came from the file.
    pub file_cameras: bool,
    /// Primitives skipped (not triangles).
    pub skipped_primitives: usize,
    /// Frames.
    pub frames: u32,
}

/// An imported scene as a trace: the header, and the frames generated one
/// at a time ([`Imported::frames`]), so that memory follows the scene, not
/// the number of frames asked for.
#[derive(Clone, Debug, PartialEq)]
pub struct Imported {
    /// The header (meshes with geometry, world).
    pub header: TraceHeader,
    /// What it holds.
    pub summary: ImportSummary,
    /// The external buffer files the glTF named and the import read (a
    /// command writing the trace must not write over one of them).
    pub files_read: Vec<PathBuf>,
    placed: Vec<Placed>,
    bounds_of: Vec<Aabb>,
    bounds: Aabb,
    cameras: CameraPlan,
    frames: u32,
    aspect: f32,
}

/// One placed instance of the scene.
#[derive(Clone, Debug, PartialEq)]
struct Placed {
    base: Affine3A,
    mesh: usize,
    flags: MappedFlags,
    aabb: Aabb,
}

/// Where the frames' cameras come from.
#[derive(Clone, Debug, PartialEq)]
enum CameraPlan {
    File(Vec<ImportedCamera>),
    Flythrough,
    Orbit,
}

impl Imported {
    /// The frames, in order, each made when it is reached.
    pub fn frames(&self) -> ImportFrames<'_> {
        ImportFrames {
            imported: self,
            next: 0,
            lods: vec![0; self.placed.len()],
        }
    }
}

/// The frames of an [`Imported`] scene ([`Imported::frames`]).
#[derive(Clone, Debug)]
pub struct ImportFrames<'a> {
    imported: &'a Imported,
    next: u32,
    /// Every instance's LOD in the frame before.
    lods: Vec<u32>,
}

impl Iterator for ImportFrames<'_> {
    type Item = Frame;

    fn next(&mut self) -> Option<Frame> {
        let im = self.imported;
        let (f, n) = (self.next, im.frames);
        if f >= n {
            return None;
        }
        self.next += 1;
        let camera = match &im.cameras {
            CameraPlan::File(cams) => camera_path::file_camera(cams, f, n, im.aspect),
            CameraPlan::Flythrough => camera_path::flythrough(&im.bounds, f, n, im.aspect),
            CameraPlan::Orbit => camera_path::orbit(&im.bounds, f, n, im.aspect),
        };
        let eye = camera.position;
        let mut events = Vec::new();
        for (id, (p, last_lod)) in im.placed.iter().zip(&mut self.lods).enumerate() {
            let t = if p.flags.animated {
                p.base * Affine3A::from_quat(Quat::from_rotation_y(0.05 * f as f32))
            } else {
                p.base
            };
            let aabb = if p.flags.animated {
                world_aabb(&t, &im.bounds_of[p.mesh])
            } else {
                p.aabb
            };
            let lod = lod_by_distance(eye, &aabb);
            let pose = Pose {
                transform: affine_to_rows(&t),
                aabb,
            };
            if f == 0 {
                let mut fl = InstanceFlags::empty();
                if p.flags.vegetation {
                    fl |= InstanceFlags::VEGETATION;
                }
                if !p.flags.animated {
                    fl |= InstanceFlags::STATIC;
                }
                if p.flags.pinned {
                    fl |= InstanceFlags::PINNED;
                }
                events.push(InstanceEvent::Add(AddInstance {
                    id: id as u64,
                    mesh: MeshId(p.mesh as u32),
                    lod,
                    flags: fl,
                    mask: None,
                    pose,
                    slot: None,
                }));
            } else if p.flags.animated || lod != *last_lod {
                events.push(InstanceEvent::Update(UpdateInstance {
                    id: id as u64,
                    pose: p.flags.animated.then_some(pose),
                    lod: (lod != *last_lod).then_some(lod),
                    flags: None,
                    mask: None,
                }));
            }
            *last_lod = lod;
        }
        Some(Frame {
            number: u64::from(f),
            camera,
            events,
            hits: None,
            slot_hits: None,
        })
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let left = (self.imported.frames - self.next) as usize;
        (left, Some(left))
    }
}

impl ExactSizeIterator for ImportFrames<'_> {}

fn world_aabb(t: &Affine3A, b: &Aabb) -> Aabb {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for i in 0..8 {
        let p = t.transform_point3(Vec3::new(
            if i & 1 != 0 { b.max.x } else { b.min.x },
            if i & 2 != 0 { b.max.y } else { b.min.y },
            if i & 4 != 0 { b.max.z } else { b.min.z },
        ));
        lo = lo.min(p);
        hi = hi.max(p);
    }
    Aabb::new(lo, hi)
}

fn lod_by_distance(eye: Vec3, b: &Aabb) -> u32 {
    let r = (0.5 * b.size().length()).max(0.1);
    let d = (eye.clamp(b.min, b.max) - eye).length();
    if d < 10.0 * r {
        0
    } else if d < 30.0 * r {
        1
    } else {
        2
    }
}

/// Imports the glTF file `bytes` (`.gltf` JSON or `.glb`; external buffer
/// files looked up in `base`) as a trace (see the module docs).
pub fn import_gltf(
    bytes: &[u8],
    base: Option<&Path>,
    name: &str,
    config: &ImportConfig,
) -> Result<Imported, SimError> {
    if config.frames == 0 {
        return Err(SimError::Import("at least one frame".into()));
    }
    if !(config.aspect > 0.0 && config.aspect.is_finite()) {
        return Err(SimError::Import("the aspect must be positive".into()));
    }
    let scene = read_gltf(bytes, base)?;
    let mut imported = to_trace(&scene, name, config)?;
    imported.files_read = scene.files_read;
    Ok(imported)
}

/// Turns a read glTF scene into a trace (see the module docs).
pub fn to_trace(
    scene: &ImportedScene,
    name: &str,
    config: &ImportConfig,
) -> Result<Imported, SimError> {
    if scene.instances.is_empty() {
        return Err(SimError::Import(
            "the file places no mesh with triangles".into(),
        ));
    }
    let mut summary = ImportSummary {
        meshes: scene.meshes.len(),
        instances: scene.instances.len(),
        skipped_primitives: scene.skipped_primitives,
        frames: config.frames,
        ..ImportSummary::default()
    };
    let mut meshes = Vec::with_capacity(scene.meshes.len());
    let mut bounds_of = Vec::with_capacity(scene.meshes.len());
    for (i, m) in scene.meshes.iter().enumerate() {
        // (positions, indices) per LOD: the file's, else generated.
        let mut levels: Vec<(&[[f32; 3]], Vec<u32>)> = vec![(&m.positions, m.indices.clone())];
        if m.lods.is_empty() {
            let [l1, l2] = lod::generate_lods(&m.positions, &m.indices)?;
            levels.push((&m.positions, l1));
            levels.push((&m.positions, l2));
        } else {
            summary.file_lods += 1;
            levels.extend(
                m.lods
                    .iter()
                    .map(|l| (l.positions.as_slice(), l.indices.clone())),
            );
        }
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for (pos, ix) in &levels {
            for &k in ix {
                let p = Vec3::from(pos[k as usize]);
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
        let bounds = Aabb::new(lo, hi);
        bounds_of.push(bounds);
        let last = levels.len() - 1;
        let lods = levels
            .into_iter()
            .enumerate()
            .map(|(k, (pos, ix))| {
                let slot = if k == last { 2 } else { k.min(1) };
                summary.triangles[slot] += (ix.len() / 3) as u64;
                LodInfo {
                    triangles: (ix.len() / 3) as u32,
                    geometry: Some(LodGeometry {
                        positions: pos.to_vec(),
                        indices: ix,
                    }),
                }
            })
            .collect();
        meshes.push(MeshInfo {
            id: MeshId(i as u32),
            bounds,
            lods,
        });
    }

    let mut placed = Vec::with_capacity(scene.instances.len());
    let mut world_lo = Vec3::splat(f32::INFINITY);
    let mut world_hi = Vec3::splat(f32::NEG_INFINITY);
    // The instances of one node (GPU instancing) share its flags: mapped
    // once, not once per instance.
    let mut last: Option<(&ImportedInstance, MappedFlags)> = None;
    for inst in &scene.instances {
        let flags = match last {
            Some((prev, f))
                if std::sync::Arc::ptr_eq(&prev.node, &inst.node)
                    && std::sync::Arc::ptr_eq(&prev.mesh_name, &inst.mesh_name) =>
            {
                f
            }
            _ => config.rules.map(inst.names(), inst.extras()),
        };
        last = Some((inst, flags));
        summary.vegetation += usize::from(flags.vegetation);
        summary.animated += usize::from(flags.animated);
        summary.pinned += usize::from(flags.pinned);
        summary.gpu_instanced += usize::from(inst.gpu_instanced);
        let mut aabb = world_aabb(&inst.transform, &bounds_of[inst.mesh]);
        if flags.animated {
            // A turn about the vertical axis stays within this box.
            let c = inst.transform.translation;
            let r = (Vec3::from(c) - aabb.min)
                .abs()
                .max((aabb.max - Vec3::from(c)).abs())
                .truncate()
                .length();
            aabb = Aabb::new(
                aabb.min.min(Vec3::new(c.x - r, aabb.min.y, c.z - r)),
                aabb.max.max(Vec3::new(c.x + r, aabb.max.y, c.z + r)),
            );
        }
        if !aabb.min.is_finite() || !aabb.max.is_finite() {
            return Err(SimError::Import(
                "an instance's bounds are not finite".into(),
            ));
        }
        world_lo = world_lo.min(aabb.min);
        world_hi = world_hi.max(aabb.max);
        placed.push(Placed {
            base: inst.transform,
            mesh: inst.mesh,
            flags,
            aabb,
        });
    }
    let bounds = Aabb::new(world_lo, world_hi);
    let side = f64::from((world_hi.x - world_lo.x).max(world_hi.z - world_lo.z)).max(1.0);
    let cell = (side / 64.0).max(0.25);
    let world = WorldInfo {
        min: [f64::from(world_lo.x) - cell, f64::from(world_lo.z) - cell],
        max: [f64::from(world_hi.x) + cell, f64::from(world_hi.z) + cell],
        cell_size: cell,
    };
    let header = TraceHeader {
        scene_name: name.to_string(),
        world,
        meshes,
    };

    let cameras = match config.camera {
        CameraSource::Auto if !scene.cameras.is_empty() => CameraPlan::File(scene.cameras.clone()),
        CameraSource::File => {
            if scene.cameras.is_empty() {
                return Err(SimError::Import("the file has no camera".into()));
            }
            CameraPlan::File(scene.cameras.clone())
        }
        CameraSource::Flythrough => CameraPlan::Flythrough,
        CameraSource::Auto | CameraSource::Orbit => CameraPlan::Orbit,
    };
    summary.file_cameras = matches!(cameras, CameraPlan::File(_));
    Ok(Imported {
        header,
        summary,
        files_read: Vec::new(),
        placed,
        bounds_of,
        bounds,
        cameras,
        frames: config.frames,
        aspect: config.aspect,
    })
}

/// Writes `imported` as a trace in `format` to `w` (every frame checked by
/// the writer's validator).
pub fn write_trace<W: Write>(
    imported: &Imported,
    format: TraceFormat,
    w: W,
) -> Result<W, SimError> {
    Ok(match format {
        TraceFormat::Binary => {
            let mut t = TraceWriter::new(w, &imported.header)?;
            for f in imported.frames() {
                t.write_frame(&f)?;
            }
            t.finish()?
        }
        TraceFormat::Jsonl => {
            let mut t = JsonlWriter::new(w, &imported.header)?;
            for f in imported.frames() {
                t.write_frame(&f)?;
            }
            t.finish()?
        }
    })
}
