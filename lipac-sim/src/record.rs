//! Recording a built-in scene and camera path as a trace
//! ([`lipac_core::trace`]), and the naming convention that lets
//! [`crate::replay`] regenerate its geometry.
//!
//! A recorded trace holds:
//!
//! * **header**: scene name [`SceneRef::name`] (`lipac-sim:<scene>:seed=<S>:camera=<path>`),
//!   the hitbox grid LiPaC uses for the scene (16 m cells over the frame-0
//!   bounds), every library mesh with its LODs' triangle counts and bounds
//!   (and, with `geometry`, its triangles as indexed positions, 3 indices per
//!   triangle), plus one mesh [`TERRAIN_MESH`] for the terrain tiles (their
//!   geometry is per tile and not written);
//! * **frame 0**: the camera and an `add` per instance in slot order (id =
//!   slot, distance LOD, flags, mask, transform, AABB);
//! * **later frames**: the camera and one `update` per instance whose pose
//!   (animated units) or distance LOD ([`LodPolicy`]) changed.
//!
//! Instances are never removed (the built-in scenes keep their instance
//! set). No hit counts are recorded.

use std::io::Write;

use glam::Vec3;
use lipac_core::grid::GridConfig;
use lipac_core::instance::InstanceFlags;
use lipac_core::math::{affine_to_rows, Aabb};
use lipac_core::trace::{
    self, AddInstance, Frame, InstanceEvent, JsonlWriter, LodGeometry, LodInfo, MeshInfo, Pose,
    TraceFormat, TraceHeader, TraceWriter, UpdateInstance, WorldInfo,
};

use crate::camera::{CameraPath, FlyCamera};
use crate::compare::SceneChoice;
use crate::error::SimError;
use crate::mesh::{LOD_COUNT, TERRAIN_RESOLUTION};
use crate::scene::{flags, LodPolicy, Scene, SceneInstance, TERRAIN_MESH};
use crate::scene_blas::instance_mask;

/// Prefix of the scene name of traces recorded from built-in scenes.
pub const SCENE_PREFIX: &str = "lipac-sim:";

/// Hitbox cell size of recorded traces (LiPaC's, metres).
pub const CELL_SIZE: f64 = 16.0;

/// A built-in camera path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraChoice {
    /// [`CameraPath::flythrough`] (270 frames).
    Flythrough,
    /// [`CameraPath::city_jump`] (120 frames, a cut at 60).
    Jump,
    /// The fly-through's first camera, standing still for 270 frames.
    Static,
}

impl CameraChoice {
    /// Name (as in the trace's scene name and on the command line).
    pub fn name(self) -> &'static str {
        match self {
            Self::Flythrough => "flythrough",
            Self::Jump => "jump",
            Self::Static => "static",
        }
    }
    /// The choice named `name`.
    pub fn from_name(name: &str) -> Option<Self> {
        [Self::Flythrough, Self::Jump, Self::Static]
            .into_iter()
            .find(|c| c.name() == name)
    }
    /// The path through `scene` with `aspect`.
    pub fn path(self, scene: &Scene, aspect: f32) -> CameraPath {
        match self {
            Self::Flythrough => CameraPath::flythrough(scene, aspect),
            Self::Jump => CameraPath::city_jump(scene, aspect),
            Self::Static => {
                let fly = CameraPath::flythrough(scene, aspect);
                CameraPath::fixed(fly.camera_at(0), fly.frames())
            }
        }
    }
}

/// A built-in scene, seed and camera path: what a trace's scene name says
/// when [`crate::replay`] can regenerate its geometry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SceneRef {
    /// The scene.
    pub scene: SceneChoice,
    /// Its seed.
    pub seed: u64,
    /// The camera path.
    pub camera: CameraChoice,
}

impl SceneRef {
    /// `lipac-sim:<scene>:seed=<seed>:camera=<path>`.
    ///
    /// ```
    /// use lipac_sim::compare::SceneChoice;
    /// use lipac_sim::record::{CameraChoice, SceneRef};
    /// let r = SceneRef { scene: SceneChoice::Small, seed: 7, camera: CameraChoice::Jump };
    /// assert_eq!(r.name(), "lipac-sim:small:seed=7:camera=jump");
    /// assert_eq!(SceneRef::parse(&r.name()), Some(r));
    /// assert_eq!(SceneRef::parse("my engine level 3"), None);
    /// ```
    pub fn name(&self) -> String {
        format!(
            "{SCENE_PREFIX}{}:seed={}:camera={}",
            self.scene.name(),
            self.seed,
            self.camera.name()
        )
    }
    /// The reference a scene name holds, if it is one.
    pub fn parse(name: &str) -> Option<Self> {
        let rest = name.strip_prefix(SCENE_PREFIX)?;
        let mut parts = rest.split(':');
        let scene = SceneChoice::from_name(parts.next()?)?;
        let seed = parts.next()?.strip_prefix("seed=")?.parse().ok()?;
        let camera = CameraChoice::from_name(parts.next()?.strip_prefix("camera=")?)?;
        if parts.next().is_some() {
            return None;
        }
        Some(Self {
            scene,
            seed,
            camera,
        })
    }
}

/// What to record.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordConfig {
    /// Scene.
    pub scene: SceneChoice,
    /// Seed (`None`: the scene's own).
    pub seed: Option<u64>,
    /// Camera path.
    pub camera: CameraChoice,
    /// Frames (`None`: the whole path; at most the path's length).
    pub frames: Option<u32>,
    /// Camera aspect (width / height of the images it is meant for).
    pub aspect: f32,
    /// Write the library meshes' triangles into the header.
    pub geometry: bool,
}

/// The trace camera of a laboratory camera (looking along its forward
/// vector with +Y up).
pub fn to_trace_camera(c: &FlyCamera) -> trace::Camera {
    trace::Camera::look_to(c.position, c.forward(), Vec3::Y, c.vfov, c.aspect)
}

/// The laboratory camera closest to a trace camera: yaw and pitch of its
/// forward vector (roll is dropped).
pub fn from_trace_camera(c: &trace::Camera) -> Result<FlyCamera, SimError> {
    let f = c.forward();
    let camera = FlyCamera::new(
        c.position,
        f.x.atan2(f.z),
        f.y.clamp(-1.0, 1.0).asin(),
        c.vertical_fov,
        c.aspect,
    )?;
    // Valid trace values can still make no usable projection (an aspect of
    // 1e-45 overflows it): say which values, as given.
    if !camera.view_proj().is_finite() {
        return Err(SimError::BadValue(format!(
            "camera (position {:?}, vertical_fov {:?}, aspect {:?}) gives a non-finite \
             view-projection matrix",
            c.position.to_array(),
            c.vertical_fov,
            c.aspect
        )));
    }
    Ok(camera)
}

/// The hitbox grid LiPaC uses for a scene with `bounds`
/// ([`crate::strategy::lipac::Lipac::new`]).
pub fn hitbox_grid(bounds: &Aabb, cell: f64) -> GridConfig {
    GridConfig {
        min: [
            (f64::from(bounds.min.x) / cell).floor() * cell,
            (f64::from(bounds.min.z) / cell).floor() * cell,
        ],
        max: [
            ((f64::from(bounds.max.x) / cell).floor() + 1.0) * cell,
            ((f64::from(bounds.max.z) / cell).floor() + 1.0) * cell,
        ],
        cell_size: cell,
    }
}

/// The trace flags of a scene instance.
pub fn instance_flags(inst: &SceneInstance) -> InstanceFlags {
    inst.instance_flags()
}

fn pose(inst: &SceneInstance) -> Pose {
    Pose {
        transform: affine_to_rows(&inst.transform),
        aabb: inst.aabb,
    }
}

/// The header of a trace of `scene` (at frame 0) named by `scene_ref`.
pub fn header(
    scene: &Scene,
    scene_ref: &SceneRef,
    geometry: bool,
) -> Result<TraceHeader, SimError> {
    let lib = scene.library();
    let mut meshes = Vec::with_capacity(lib.len() + 1);
    for (id, _) in lib.iter() {
        let mut lods = Vec::with_capacity(LOD_COUNT);
        for lod in 0..LOD_COUNT {
            let m = lib.lod(id, lod)?;
            let geometry = geometry.then(|| LodGeometry {
                positions: m
                    .triangles
                    .iter()
                    .flat_map(|t| [t.v0, t.v1, t.v2])
                    .map(|v| v.to_array())
                    .collect(),
                indices: (0..3 * m.triangles.len() as u32).collect(),
            });
            lods.push(LodInfo {
                triangles: m.len() as u32,
                geometry,
            });
        }
        meshes.push(MeshInfo {
            id: lipac_core::instance::MeshId(id),
            bounds: lib.bounds(id)?,
            lods,
        });
    }
    // Terrain tiles: local bounds over every tile.
    let tiles = scene
        .instances()
        .iter()
        .filter(|i| i.flags & flags::TERRAIN != 0);
    let mut tile_bounds: Option<Aabb> = None;
    for t in tiles {
        let o = Vec3::from(t.transform.translation);
        let b = Aabb::new(t.aabb.min - o, t.aabb.max - o);
        tile_bounds = Some(match tile_bounds {
            None => b,
            Some(a) => Aabb::new(a.min.min(b.min), a.max.max(b.max)),
        });
    }
    if let Some(bounds) = tile_bounds {
        meshes.push(MeshInfo {
            id: lipac_core::instance::MeshId(TERRAIN_MESH),
            bounds,
            lods: TERRAIN_RESOLUTION
                .iter()
                .map(|r| LodInfo {
                    triangles: 2 * r * r,
                    geometry: None,
                })
                .collect(),
        });
    }
    Ok(TraceHeader {
        scene_name: scene_ref.name(),
        world: WorldInfo::from(hitbox_grid(&scene.bounds(), CELL_SIZE)),
        meshes,
    })
}

/// A trace writer of either encoding.
#[derive(Debug)]
pub enum AnyWriter<W: Write> {
    /// Binary.
    Binary(TraceWriter<W>),
    /// JSON lines.
    Jsonl(JsonlWriter<W>),
}

impl<W: Write> AnyWriter<W> {
    /// A writer of `format` for `header`.
    pub fn new(format: TraceFormat, w: W, header: &TraceHeader) -> Result<Self, SimError> {
        Ok(match format {
            TraceFormat::Binary => Self::Binary(TraceWriter::new(w, header)?),
            TraceFormat::Jsonl => Self::Jsonl(JsonlWriter::new(w, header)?),
        })
    }
    /// Writes a frame.
    pub fn write_frame(&mut self, f: &Frame) -> Result<(), SimError> {
        match self {
            Self::Binary(w) => w.write_frame(f)?,
            Self::Jsonl(w) => w.write_frame(f)?,
        }
        Ok(())
    }
    /// Writes the end and returns the sink.
    pub fn finish(self) -> Result<W, SimError> {
        Ok(match self {
            Self::Binary(w) => w.finish()?,
            Self::Jsonl(w) => w.finish()?,
        })
    }
}

/// What [`record`] wrote.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RecordSummary {
    /// Frames.
    pub frames: u32,
    /// Instances added (frame 0).
    pub instances: u64,
    /// `update` events over all frames.
    pub updates: u64,
}

/// Records `config`'s scene and camera path into `out` in `format`;
/// returns the sink and what was written.
pub fn record<W: Write>(
    config: &RecordConfig,
    format: TraceFormat,
    out: W,
) -> Result<(W, RecordSummary), SimError> {
    let seed = config.seed.unwrap_or(config.scene.config(None).seed);
    let scene_ref = SceneRef {
        scene: config.scene,
        seed,
        camera: config.camera,
    };
    let mut scene = Scene::generate(&config.scene.config(Some(seed)))?;
    if !(config.aspect.is_finite() && config.aspect > 0.0) {
        return Err(SimError::BadConfig("aspect must be finite and > 0"));
    }
    let path = config.camera.path(&scene, config.aspect);
    let frames = config.frames.unwrap_or(path.frames()).min(path.frames());
    if frames == 0 {
        return Err(SimError::BadConfig("no frames to record"));
    }
    let header = header(&scene, &scene_ref, config.geometry)?;
    let mut w = AnyWriter::new(format, out, &header)?;
    let policy = LodPolicy::default();
    let n = scene.instances().len();
    let mut lods = vec![0u32; n];
    let mut poses: Vec<Pose> = Vec::with_capacity(n);
    let mut summary = RecordSummary {
        frames,
        instances: n as u64,
        updates: 0,
    };
    let mut frame = Frame {
        number: 0,
        camera: to_trace_camera(&path.camera_at(0)),
        events: Vec::new(),
        hits: None,
        slot_hits: None,
    };
    for f in 0..frames {
        scene.set_frame(f);
        let camera = path.camera_at(f);
        frame.number = u64::from(f);
        frame.camera = to_trace_camera(&camera);
        frame.events.clear();
        for (slot, inst) in scene.instances().iter().enumerate() {
            let lod = policy.lod(camera.position, &inst.aabb) as u32;
            let p = pose(inst);
            if f == 0 {
                let mask = instance_mask(inst);
                frame.events.push(InstanceEvent::Add(AddInstance {
                    id: slot as u64,
                    mesh: lipac_core::instance::MeshId(inst.mesh),
                    lod,
                    flags: instance_flags(inst),
                    mask: (mask != 0xFF).then_some(mask),
                    pose: p,
                    slot: None,
                }));
                poses.push(p);
                lods[slot] = lod;
                continue;
            }
            let moved = !same_pose(&poses[slot], &p);
            let relod = lods[slot] != lod;
            if moved || relod {
                frame.events.push(InstanceEvent::Update(UpdateInstance {
                    id: slot as u64,
                    pose: moved.then_some(p),
                    lod: relod.then_some(lod),
                    flags: None,
                    mask: None,
                }));
                poses[slot] = p;
                lods[slot] = lod;
                summary.updates += 1;
            }
        }
        w.write_frame(&frame)?;
    }
    Ok((w.finish()?, summary))
}

/// Whether two poses are equal bit for bit.
pub fn same_pose(a: &Pose, b: &Pose) -> bool {
    let bits = |p: &Pose| {
        let mut v = [0u32; 18];
        for (o, x) in v.iter_mut().zip(
            p.transform
                .iter()
                .chain(p.aabb.min.to_array().iter())
                .chain(p.aabb.max.to_array().iter()),
        ) {
            *o = x.to_bits();
        }
        v
    };
    bits(a) == bits(b)
}
