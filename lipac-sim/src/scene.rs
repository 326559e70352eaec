//! Seeded, deterministic procedural scenes: a terrain of heightfield tiles,
//! a street grid, thousands of buildings from a few dozen shared meshes,
//! terrain-adapted buildings (unique geometry), trees, optionally a large
//! mirror block, and animated units walking the streets.
//!
//! Instances are compact records ([`SceneInstance`]: transform, world AABB,
//! mesh, flags); meshes are shared through the [`MeshLibrary`], and unique
//! geometry (terrain tiles, terrain-adapted buildings, deformed units) is
//! produced on request by [`Scene::unique_geometry`], so a scene of a million
//! instances stays small.

use glam::{Affine3A, Quat, Vec2, Vec3};
use lipac_core::instance::InstanceFlags;
use lipac_core::math::Aabb;

use crate::error::SimError;
use crate::mesh::{self, BuildingParams, LodTriangles, MeshIndex, MeshLibrary, Roof, LOD_COUNT};
use crate::rng::SplitMix64;

/// Frames per second of scene time (units move `speed / FPS` per frame).
pub const FPS: f32 = 30.0;

/// `mesh` of terrain tiles, which have no library mesh.
pub const TERRAIN_MESH: MeshIndex = u32::MAX;

/// Bits of [`SceneInstance::flags`].
pub mod flags {
    /// Needs a BLAS of its own (terrain tile, terrain-adapted, animated).
    pub const UNIQUE: u8 = 1;
    /// Deformed every frame (an animated unit).
    pub const ANIMATED: u8 = 2;
    /// Alpha-tested vegetation.
    pub const VEGETATION: u8 = 4;
    /// A terrain tile.
    pub const TERRAIN: u8 = 8;
    /// A building whose foundation follows the terrain.
    pub const TERRAIN_ADAPTED: u8 = 16;
    /// Never moves.
    pub const STATIC: u8 = 32;
    /// The mirror block.
    pub const MIRROR: u8 = 64;
    /// Always traced: never culled (terrain tiles, as the paper does);
    /// lipac-core's [`lipac_core::instance::InstanceFlags::PINNED`].
    pub const PINNED: u8 = 128;
}

/// One instance of the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneInstance {
    /// Object-to-world transform.
    pub transform: Affine3A,
    /// World-space bounds (covering every LOD and animation pose).
    pub aabb: Aabb,
    /// Library mesh ([`TERRAIN_MESH`] for terrain tiles).
    pub mesh: MeshIndex,
    /// See [`flags`].
    pub flags: u8,
}

impl SceneInstance {
    /// Whether the instance needs a unique BLAS.
    pub fn is_unique(&self) -> bool {
        self.flags & flags::UNIQUE != 0
    }
    /// Whether it is alpha-tested vegetation.
    pub fn is_vegetation(&self) -> bool {
        self.flags & flags::VEGETATION != 0
    }
    /// Whether it is animated.
    pub fn is_animated(&self) -> bool {
        self.flags & flags::ANIMATED != 0
    }
    /// Whether it is pinned (always traced).
    pub fn is_pinned(&self) -> bool {
        self.flags & flags::PINNED != 0
    }
    /// Its lipac-core flags: the one conversion from the scene's [`flags`]
    /// for LiPaC's Manager and for recorded traces.
    pub fn instance_flags(&self) -> InstanceFlags {
        let mut f = InstanceFlags::empty();
        if self.is_unique() {
            f |= InstanceFlags::UNIQUE_BLAS;
        }
        if self.is_vegetation() {
            f |= InstanceFlags::VEGETATION;
        }
        if self.flags & flags::STATIC != 0 {
            f |= InstanceFlags::STATIC;
        }
        if self.is_pinned() {
            f |= InstanceFlags::PINNED;
        }
        f
    }
}

/// The optional large mirror block (paper Fig. 3).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MirrorConfig {
    /// Centre of its footprint as a fraction of the city extent (x, z).
    pub center: Vec2,
    /// Edge length (width, depth and height), metres.
    pub size: f32,
}

/// Parameters of a procedural city. All sizes in metres.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneConfig {
    /// Seed of every random choice.
    pub seed: u64,
    /// Side length of the square city/terrain.
    pub extent: f32,
    /// Side length of a block between streets.
    pub block: f32,
    /// Street width.
    pub street_width: f32,
    /// Lots per block side (a block holds `lots^2` buildings).
    pub lots_per_side: u32,
    /// Number of shared ordinary building meshes.
    pub building_meshes: u32,
    /// Number of shared tower meshes.
    pub tower_meshes: u32,
    /// Terrain tile size.
    pub terrain_tile: f32,
    /// Amplitude of the terrain hills.
    pub hill_height: f32,
    /// Fraction of buildings adapted to the terrain (unique BLAS).
    pub terrain_adapted_fraction: f32,
    /// Number of animated units.
    pub units: u32,
    /// Fraction of units on the two busy central streets.
    pub busy_fraction: f32,
    /// Distance between trees along each street side (0 = no trees).
    pub tree_spacing: f32,
    /// The mirror block, if any.
    pub mirror: Option<MirrorConfig>,
    /// The units' mesh.
    pub unit_mesh: UnitMesh,
}

/// The mesh of a scene's animated units.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum UnitMesh {
    /// Boxes ([`mesh::unit`]: 72, 36 and 12 triangles per LOD).
    #[default]
    Boxes,
    /// A character of rounded limbs ([`mesh::character`]: 552, 120 and 60
    /// triangles per LOD), as a game's units are.
    Character,
}

impl Default for SceneConfig {
    fn default() -> Self {
        Self::city()
    }
}

impl SceneConfig {
    /// The default city: 2 km x 2 km (4 km^2), ~3.6k buildings from 32
    /// shared meshes, 5,000 units, ~14k trees, 256 terrain tiles.
    pub fn city() -> Self {
        Self {
            seed: 1,
            extent: 2048.0,
            block: 80.0,
            street_width: 16.0,
            lots_per_side: 3,
            building_meshes: 24,
            tower_meshes: 8,
            terrain_tile: 128.0,
            hill_height: 12.0,
            terrain_adapted_fraction: 0.1,
            units: 5000,
            busy_fraction: 0.4,
            tree_spacing: 12.0,
            mirror: None,
            unit_mesh: UnitMesh::Boxes,
        }
    }
    /// The paper-scale city: the kind of scene the paper evaluates on (§4:
    /// a city-building game's city with more than a hundred thousand
    /// instances and more than six thousand animated units, many
    /// buildings deformed to fit the terrain they stand on, vegetation in
    /// the streets). 4 km x 4 km (16 km^2) of hills twice the city's,
    /// 16 lots per block, half the buildings fitted to the terrain (a
    /// BLAS of their own each), 8,000 units, trees every 10 m: about
    /// 120k instances (119,885 at seed 1: 41,457 buildings of which
    /// 20,785 fitted to the terrain, 69,404 trees, 1,024 terrain tiles).
    /// Memory of the full scene is dominated by unique BLASes, as in the
    /// paper's Fig. 7; [`SceneConfig::paper_city_lite`] is the same city
    /// at a sixteenth of the area for tests. Its units
    /// are characters ([`UnitMesh::Character`]) rather than the city's
    /// boxes: the paper's unique BLASes are "for all the allocated units"
    /// of a game, whose units are meshes of hundreds of triangles.
    pub fn paper_city() -> Self {
        Self {
            seed: 1,
            extent: 4096.0,
            block: 64.0,
            street_width: 12.0,
            lots_per_side: 4,
            building_meshes: 48,
            tower_meshes: 8,
            terrain_tile: 128.0,
            hill_height: 24.0,
            terrain_adapted_fraction: 0.5,
            units: 8000,
            busy_fraction: 0.4,
            tree_spacing: 10.0,
            mirror: None,
            unit_mesh: UnitMesh::Character,
        }
    }
    /// [`SceneConfig::paper_city`] on a sixteenth of its area (1 km x 1
    /// km: the same densities and meshes, 500 units), for tests of its
    /// properties.
    pub fn paper_city_lite() -> Self {
        Self {
            extent: 1024.0,
            units: 500,
            ..Self::paper_city()
        }
    }
    /// A small scene for tests: 256 m, a handful of meshes, 40 units.
    pub fn small() -> Self {
        Self {
            seed: 7,
            extent: 256.0,
            block: 48.0,
            street_width: 12.0,
            lots_per_side: 2,
            building_meshes: 4,
            tower_meshes: 2,
            terrain_tile: 64.0,
            hill_height: 4.0,
            terrain_adapted_fraction: 0.2,
            units: 40,
            busy_fraction: 0.5,
            tree_spacing: 20.0,
            mirror: None,
            unit_mesh: UnitMesh::Boxes,
        }
    }
    /// The city with a mirror block of `size` metres near its centre.
    pub fn with_mirror(mut self, size: f32) -> Self {
        self.mirror = Some(MirrorConfig {
            center: Vec2::new(0.55, 0.5),
            size,
        });
        self
    }
    /// Scales extent and unit count so the scene holds about `instances`
    /// instances (density and meshes unchanged).
    pub fn scaled_to(mut self, instances: u64) -> Self {
        let now = self.estimated_instances().max(1) as f64;
        let f = (instances as f64 / now).max(1e-6);
        self.extent = (f64::from(self.extent) * f.sqrt()) as f32;
        self.units = (f64::from(self.units) * f).round() as u32;
        self
    }
    /// A quick estimate of the instance count this configuration produces.
    pub fn estimated_instances(&self) -> u64 {
        let pitch = self.block + self.street_width;
        let blocks = (self.extent / pitch).floor().max(0.0) as u64;
        let lines = blocks + 1;
        let buildings = blocks * blocks * u64::from(self.lots_per_side.pow(2)) * 92 / 100;
        let trees = if self.tree_spacing > 0.0 {
            (lines as f32 * 4.0 * self.extent / self.tree_spacing * 0.85) as u64
        } else {
            0
        };
        let tiles = ((self.extent / self.terrain_tile).ceil() as u64).pow(2);
        buildings + trees + tiles + u64::from(self.units)
    }
    fn validate(&self) -> Result<(), SimError> {
        let finite = [
            self.extent,
            self.block,
            self.street_width,
            self.terrain_tile,
            self.hill_height,
            self.terrain_adapted_fraction,
            self.busy_fraction,
            self.tree_spacing,
        ];
        if finite.iter().any(|v| !v.is_finite()) {
            return Err(SimError::NonFinite("scene configuration values"));
        }
        if self.extent <= 0.0 || self.block <= 4.0 || self.street_width <= 0.0 {
            return Err(SimError::BadConfig(
                "extent, block (> 4 m) and street width must be positive",
            ));
        }
        if self.terrain_tile < 4.0 {
            return Err(SimError::BadConfig("terrain tiles must be at least 4 m"));
        }
        if self.lots_per_side == 0 || self.building_meshes == 0 {
            return Err(SimError::BadConfig(
                "need at least one lot and one building mesh",
            ));
        }
        if self.tree_spacing < 0.0 || (self.tree_spacing > 0.0 && self.tree_spacing < 1.0) {
            return Err(SimError::BadConfig(
                "tree spacing must be 0 or at least 1 m",
            ));
        }
        if let Some(m) = self.mirror {
            if !m.center.is_finite() || !m.size.is_finite() || m.size <= 0.0 {
                return Err(SimError::BadConfig(
                    "mirror block needs a finite centre and positive size",
                ));
            }
        }
        Ok(())
    }
}

/// The terrain height at world `(x, z)`: smooth hills of amplitude `hill`.
pub fn terrain_height(hill: f32, x: f32, z: f32) -> f32 {
    hill * (0.5 * (x * 0.0021 + 1.3).sin() * (z * 0.0017).cos()
        + 0.3 * (x * 0.0053 + z * 0.0041).sin()
        + 0.2 * (z * 0.0069 - x * 0.0011).cos())
}

/// A unit walking along a street.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UnitPath {
    /// Instance slot of the unit.
    pub slot: u32,
    /// 0: walks along x; 1: along z.
    pub axis: u8,
    /// Fixed coordinate of its lane (z when walking along x).
    pub lane: f32,
    /// Signed speed in m/s.
    pub speed: f32,
    /// Position along the street at frame 0.
    pub start: f32,
    /// Walk-cycle phase at frame 0, radians.
    pub phase: f32,
}

/// Chooses a LOD from the distance between the camera and an instance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LodPolicy {
    /// Below this distance: LOD 0.
    pub near: f32,
    /// Below this distance: LOD 1; beyond: LOD 2.
    pub far: f32,
}

impl Default for LodPolicy {
    fn default() -> Self {
        Self {
            near: 120.0,
            far: 400.0,
        }
    }
}

impl LodPolicy {
    /// LOD for an instance with bounds `aabb` seen from `eye`.
    pub fn lod(&self, eye: Vec3, aabb: &Aabb) -> usize {
        let d = (eye.clamp(aabb.min, aabb.max) - eye).length();
        if d < self.near {
            0
        } else if d < self.far {
            1
        } else {
            LOD_COUNT - 1
        }
    }
}

/// A generated scene: its meshes, instances and unit paths.
#[derive(Clone, Debug)]
pub struct Scene {
    config: SceneConfig,
    library: MeshLibrary,
    instances: Vec<SceneInstance>,
    units: Vec<UnitPath>,
    unit_mesh: MeshIndex,
    frame: u32,
    busy: (u8, f32),
}

fn transform_aabb(t: &Affine3A, b: &Aabb) -> Aabb {
    let c = t.transform_point3(b.center());
    let h = 0.5 * b.size();
    let m = t.matrix3;
    let e = Vec3::new(
        m.x_axis.x.abs() * h.x + m.y_axis.x.abs() * h.y + m.z_axis.x.abs() * h.z,
        m.x_axis.y.abs() * h.x + m.y_axis.y.abs() * h.y + m.z_axis.y.abs() * h.z,
        m.x_axis.z.abs() * h.x + m.y_axis.z.abs() * h.y + m.z_axis.z.abs() * h.z,
    );
    Aabb::new(c - e, c + e)
}

impl Scene {
    /// Generates the scene of `config` at frame 0.
    ///
    /// ```
    /// use lipac_sim::scene::{Scene, SceneConfig};
    /// let a = Scene::generate(&SceneConfig::small()).unwrap();
    /// let b = Scene::generate(&SceneConfig::small()).unwrap();
    /// assert_eq!(a.instances(), b.instances());
    /// assert!(a.instances().len() > 100);
    /// ```
    pub fn generate(config: &SceneConfig) -> Result<Self, SimError> {
        config.validate()?;
        let c = config;
        let mut rng = SplitMix64::new(c.seed);
        let mut library = MeshLibrary::new();
        let pitch = c.block + c.street_width;
        let blocks = (c.extent / pitch).floor() as u32;
        let lot = c.block / c.lots_per_side as f32;

        let mut building_ids = Vec::new();
        for _ in 0..c.building_meshes {
            let tiers = 1 + rng.below(2);
            let roof = match rng.below(3) {
                0 => Roof::Flat,
                1 => Roof::Parapet,
                _ => Roof::Gable,
            };
            building_ids.push(library.add(mesh::building(BuildingParams {
                width: lot * rng.range(0.55, 0.85),
                depth: lot * rng.range(0.55, 0.85),
                height: rng.range(8.0, 35.0),
                tiers,
                roof,
            })));
        }
        let mut tower_ids = Vec::new();
        for _ in 0..c.tower_meshes {
            tower_ids.push(library.add(mesh::building(BuildingParams {
                width: lot * rng.range(0.6, 0.85),
                depth: lot * rng.range(0.6, 0.85),
                height: rng.range(60.0, 140.0),
                tiers: 3,
                roof: Roof::Spire,
            })));
        }
        let tree_id = library.add(mesh::tree());
        let unit_mesh = library.add(match c.unit_mesh {
            UnitMesh::Boxes => mesh::unit(),
            UnitMesh::Character => mesh::character(),
        });
        let mirror_id = c
            .mirror
            .map(|m| library.add(mesh::mirror_block(Vec3::splat(m.size))));

        let hill = c.hill_height;
        let h = |x: f32, z: f32| terrain_height(hill, x, z);
        let mut instances = Vec::with_capacity(c.estimated_instances() as usize + 16);

        // Terrain tiles.
        let tiles = (c.extent / c.terrain_tile).ceil() as u32;
        let res0 = mesh::TERRAIN_RESOLUTION[0];
        for tj in 0..tiles {
            for ti in 0..tiles {
                let (x0, z0) = (ti as f32 * c.terrain_tile, tj as f32 * c.terrain_tile);
                let step = c.terrain_tile / res0 as f32;
                let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                for j in 0..=res0 {
                    for i in 0..=res0 {
                        let y = h(x0 + i as f32 * step, z0 + j as f32 * step);
                        lo = lo.min(y);
                        hi = hi.max(y);
                    }
                }
                instances.push(SceneInstance {
                    transform: Affine3A::from_translation(Vec3::new(x0, 0.0, z0)),
                    aabb: Aabb::new(
                        Vec3::new(x0, lo, z0),
                        Vec3::new(x0 + c.terrain_tile, hi, z0 + c.terrain_tile),
                    ),
                    mesh: TERRAIN_MESH,
                    flags: flags::UNIQUE | flags::TERRAIN | flags::STATIC | flags::PINNED,
                });
            }
        }

        // Mirror footprint (buildings there are skipped).
        let mirror_box = c.mirror.map(|m| {
            let ctr = m.center * c.extent;
            (
                ctr - Vec2::splat(0.5 * m.size + 4.0),
                ctr + Vec2::splat(0.5 * m.size + 4.0),
                ctr,
            )
        });

        // Buildings.
        let centre = Vec2::splat(0.5 * c.extent);
        for bj in 0..blocks {
            for bi in 0..blocks {
                let bx = bi as f32 * pitch + 0.5 * c.street_width;
                let bz = bj as f32 * pitch + 0.5 * c.street_width;
                for lj in 0..c.lots_per_side {
                    for li in 0..c.lots_per_side {
                        let r = rng.next_f32();
                        let p =
                            Vec2::new(bx + (li as f32 + 0.5) * lot, bz + (lj as f32 + 0.5) * lot);
                        let dn = ((p - centre).length() / (0.5 * c.extent)).min(1.0);
                        let pick = rng.next_f32();
                        let yaw = rng.below(4) as f32 * std::f32::consts::FRAC_PI_2;
                        let adapted = rng.next_f32() < c.terrain_adapted_fraction;
                        if r < 0.08 {
                            continue;
                        }
                        if let Some((lo, hi, _)) = mirror_box {
                            if p.cmpge(lo - Vec2::splat(0.5 * lot)).all()
                                && p.cmple(hi + Vec2::splat(0.5 * lot)).all()
                            {
                                continue;
                            }
                        }
                        let tower = !tower_ids.is_empty() && pick < 0.3 * (1.0 - dn).powi(2);
                        let id = if tower {
                            tower_ids[rng.below(tower_ids.len() as u32) as usize]
                        } else {
                            building_ids[rng.below(building_ids.len() as u32) as usize]
                        };
                        let half = 0.5 * lot;
                        let base = [
                            (-1.0, -1.0),
                            (1.0, -1.0),
                            (1.0, 1.0),
                            (-1.0, 1.0),
                            (0.0, 0.0),
                        ]
                        .iter()
                        .map(|(a, b)| h(p.x + a * half * 0.8, p.y + b * half * 0.8))
                        .fold(f32::INFINITY, f32::min);
                        let t = Affine3A::from_rotation_translation(
                            Quat::from_rotation_y(yaw),
                            Vec3::new(p.x, base, p.y),
                        );
                        let mut f = flags::STATIC;
                        if adapted {
                            f |= flags::UNIQUE | flags::TERRAIN_ADAPTED;
                        }
                        let mut aabb = transform_aabb(&t, &library.bounds(id)?);
                        if adapted {
                            aabb.min.y -= 2.0 * hill + 1.0;
                        }
                        instances.push(SceneInstance {
                            transform: t,
                            aabb,
                            mesh: id,
                            flags: f,
                        });
                    }
                }
            }
        }

        if let (Some(id), Some((_, _, ctr))) = (mirror_id, mirror_box) {
            let t = Affine3A::from_translation(Vec3::new(ctr.x, h(ctr.x, ctr.y), ctr.y));
            instances.push(SceneInstance {
                transform: t,
                aabb: transform_aabb(&t, &library.bounds(id)?),
                mesh: id,
                flags: flags::STATIC | flags::MIRROR,
            });
        }

        // Trees along both sides of every street.
        if c.tree_spacing > 0.0 {
            let tree_bounds = library.bounds(tree_id)?;
            let side = 0.5 * c.street_width - 1.5;
            for axis in 0..2u8 {
                for line in 0..=blocks {
                    let s0 = line as f32 * pitch;
                    for sgn in [-1.0f32, 1.0] {
                        let lane = s0 + sgn * side;
                        let mut u = rng.range(0.0, c.tree_spacing);
                        while u < c.extent {
                            let jitter = rng.range(-0.25, 0.25) * c.tree_spacing;
                            let scale = rng.range(0.8, 1.25);
                            let yaw = rng.range(0.0, std::f32::consts::TAU);
                            let along = u + jitter;
                            u += c.tree_spacing;
                            // Skip crossings.
                            let off = along.rem_euclid(pitch);
                            if !(0.0..c.extent).contains(&along)
                                || off < 0.5 * c.street_width + 2.0
                                || off > pitch - 0.5 * c.street_width - 2.0
                                || !(0.0..c.extent).contains(&lane)
                            {
                                continue;
                            }
                            let (x, z) = if axis == 0 {
                                (along, lane)
                            } else {
                                (lane, along)
                            };
                            let t = Affine3A::from_scale_rotation_translation(
                                Vec3::splat(scale),
                                Quat::from_rotation_y(yaw),
                                Vec3::new(x, h(x, z), z),
                            );
                            instances.push(SceneInstance {
                                transform: t,
                                aabb: transform_aabb(&t, &tree_bounds),
                                mesh: tree_id,
                                flags: flags::VEGETATION | flags::STATIC,
                            });
                        }
                    }
                }
            }
        }

        // Units.
        let mid_line = (blocks / 2) as f32 * pitch;
        let busy = (0u8, mid_line);
        let mut units = Vec::with_capacity(c.units as usize);
        let unit_bounds = library.bounds(unit_mesh)?;
        for _ in 0..c.units {
            let on_busy = rng.next_f32() < c.busy_fraction;
            let axis = rng.below(2) as u8;
            let line = if on_busy {
                mid_line
            } else {
                rng.below(blocks + 1) as f32 * pitch
            };
            let lane = (line + rng.range(-0.5, 0.5) * (c.street_width - 3.0)).clamp(0.0, c.extent);
            let dir = if rng.next_f32() < 0.5 { -1.0 } else { 1.0 };
            let unit = UnitPath {
                slot: instances.len() as u32,
                axis,
                lane,
                speed: dir * rng.range(1.0, 1.8),
                start: rng.range(0.0, c.extent),
                phase: rng.range(0.0, std::f32::consts::TAU),
            };
            let t = unit_transform(&unit, c, 0);
            instances.push(SceneInstance {
                transform: t,
                aabb: transform_aabb(&t, &unit_bounds),
                mesh: unit_mesh,
                flags: flags::UNIQUE | flags::ANIMATED,
            });
            units.push(unit);
        }

        Ok(Self {
            config: c.clone(),
            library,
            instances,
            units,
            unit_mesh,
            frame: 0,
            busy,
        })
    }

    /// A hand-made scene from a mesh library and static instances (no
    /// units, no terrain tiles): for tests that need a precise layout.
    /// `config` supplies the extent (camera paths) and hill height
    /// ([`Scene::height`]); its generation parameters are not used.
    ///
    /// Fails on an instance whose mesh is not in `library`, that is unique
    /// or animated (their geometry comes from the generator), or whose
    /// transform or bounds are not finite.
    ///
    /// ```
    /// use glam::{Affine3A, Vec3};
    /// use lipac_sim::mesh::{cuboid, material, MeshLibrary};
    /// use lipac_sim::scene::{flags, Scene, SceneConfig};
    /// let mut lib = MeshLibrary::new();
    /// let wall = lib.add(cuboid(Vec3::ZERO, Vec3::new(10.0, 5.0, 1.0), material::WALL));
    /// let s = Scene::custom(SceneConfig::small(), lib, &[(wall, Affine3A::IDENTITY, flags::STATIC)]).unwrap();
    /// assert_eq!(s.instances().len(), 1);
    /// assert_eq!(s.instances()[0].aabb.max, Vec3::new(10.0, 5.0, 1.0));
    /// ```
    pub fn custom(
        config: SceneConfig,
        library: MeshLibrary,
        placed: &[(MeshIndex, Affine3A, u8)],
    ) -> Result<Self, SimError> {
        let mut instances = Vec::with_capacity(placed.len());
        for (i, &(mesh, transform, f)) in placed.iter().enumerate() {
            if f & (flags::UNIQUE | flags::ANIMATED | flags::TERRAIN) != 0 {
                return Err(SimError::BadConfig(
                    "custom scenes hold only shared static instances",
                ));
            }
            if !transform.is_finite() {
                return Err(SimError::BadTransform { record: i });
            }
            let aabb = transform_aabb(&transform, &library.bounds(mesh)?);
            instances.push(SceneInstance {
                transform,
                aabb,
                mesh,
                flags: f,
            });
        }
        Ok(Self {
            config,
            library,
            instances,
            units: Vec::new(),
            unit_mesh: TERRAIN_MESH,
            frame: 0,
            busy: (0, 0.0),
        })
    }

    /// A scene of caller-made instances over `library`, for scenes that come
    /// from elsewhere than the generator (a recorded trace:
    /// [`crate::trace_scene`]). Instances share their library mesh (no
    /// unique or terrain instances); [`flags::ANIMATED`] marks those whose
    /// pose the caller changes between frames ([`Scene::set_instance`]),
    /// with no generator animation. `config` supplies the extent and hill
    /// height only.
    ///
    /// Fails on an instance whose mesh is not in `library`, that is unique
    /// or terrain, or whose transform or bounds are not finite.
    pub fn from_instances(
        config: SceneConfig,
        library: MeshLibrary,
        instances: Vec<SceneInstance>,
    ) -> Result<Self, SimError> {
        for (i, inst) in instances.iter().enumerate() {
            check_placed(&library, inst, i)?;
        }
        Ok(Self {
            config,
            library,
            instances,
            units: Vec::new(),
            unit_mesh: TERRAIN_MESH,
            frame: 0,
            busy: (0, 0.0),
        })
    }

    /// Replaces instance `slot` of a scene made by [`Scene::from_instances`]
    /// (the same checks; a generated scene's unique instances and units
    /// cannot be replaced).
    pub fn set_instance(&mut self, slot: u32, inst: SceneInstance) -> Result<(), SimError> {
        if !self.units.is_empty() {
            return Err(SimError::BadConfig(
                "instances of a generated scene with units cannot be replaced",
            ));
        }
        check_placed(&self.library, &inst, slot as usize)?;
        let old = self
            .instances
            .get_mut(slot as usize)
            .ok_or(SimError::UnknownInstance(slot))?;
        if old.is_unique() {
            return Err(SimError::NotUnique(slot));
        }
        *old = inst;
        Ok(())
    }

    /// The configuration it was generated from.
    pub fn config(&self) -> &SceneConfig {
        &self.config
    }
    /// The shared meshes.
    pub fn library(&self) -> &MeshLibrary {
        &self.library
    }
    /// All instances at the current frame, indexed by slot.
    pub fn instances(&self) -> &[SceneInstance] {
        &self.instances
    }
    /// One instance.
    pub fn instance(&self, slot: u32) -> Result<&SceneInstance, SimError> {
        self.instances
            .get(slot as usize)
            .ok_or(SimError::UnknownInstance(slot))
    }
    /// The animated units' paths.
    pub fn units(&self) -> &[UnitPath] {
        &self.units
    }
    /// The frame the instances are at.
    pub fn frame(&self) -> u32 {
        self.frame
    }
    /// The busy street: `(axis, coordinate)` — axis 0 runs along x at
    /// `z = coordinate`; many units walk there.
    pub fn busy_street(&self) -> (u8, f32) {
        self.busy
    }
    /// World bounds of the whole scene.
    pub fn bounds(&self) -> Aabb {
        self.instances.iter().fold(
            Aabb::new(Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |a, i| Aabb::new(a.min.min(i.aabb.min), a.max.max(i.aabb.max)),
        )
    }
    /// The terrain height at world `(x, z)`.
    pub fn height(&self, x: f32, z: f32) -> f32 {
        terrain_height(self.config.hill_height, x, z)
    }

    /// Moves the animated units to `frame` (deterministic: a function of
    /// the frame number only, so frames may be visited in any order).
    pub fn set_frame(&mut self, frame: u32) {
        self.frame = frame;
        let b = match self.library.bounds(self.unit_mesh) {
            Ok(b) => b,
            Err(_) => return,
        };
        for u in &self.units {
            let t = unit_transform(u, &self.config, frame);
            if let Some(inst) = self.instances.get_mut(u.slot as usize) {
                inst.transform = t;
                inst.aabb = transform_aabb(&t, &b);
            }
        }
    }

    /// Walk-cycle phase of unit instance `slot` at `frame`.
    pub fn unit_phase(&self, slot: u32, frame: u32) -> Option<f32> {
        let first = self.units.first()?.slot;
        let u = self.units.get(slot.checked_sub(first)? as usize)?;
        Some(u.phase + frame as f32 / FPS * u.speed.abs() * 4.5)
    }

    /// Object-space geometry of LOD `lod` of a unique instance at `frame`
    /// into `out`: a terrain tile, a terrain-adapted building (foundation
    /// lowered to the terrain) or a unit deformed for its walk phase.
    pub fn unique_geometry(
        &self,
        slot: u32,
        lod: usize,
        frame: u32,
        out: &mut LodTriangles,
    ) -> Result<(), SimError> {
        if lod >= LOD_COUNT {
            return Err(SimError::BadLod(lod));
        }
        let inst = *self.instance(slot)?;
        if !inst.is_unique() {
            return Err(SimError::NotUnique(slot));
        }
        let hill = self.config.hill_height;
        if inst.flags & flags::TERRAIN != 0 {
            let o = inst.transform.translation;
            mesh::terrain_tile(
                o.x,
                o.z,
                self.config.terrain_tile,
                mesh::TERRAIN_RESOLUTION[lod],
                |x, z| terrain_height(hill, x, z),
                out,
            );
            return Ok(());
        }
        let rest = self.library.lod(inst.mesh, lod)?;
        if inst.is_animated() {
            let phase = self.unit_phase(slot, frame).unwrap_or(0.0);
            mesh::deform_unit(rest, phase, out);
            return Ok(());
        }
        // Terrain-adapted: vertices at or below the base follow the terrain.
        out.clone_from(rest);
        let base = inst.transform.translation.y;
        for t in &mut out.triangles {
            for v in [&mut t.v0, &mut t.v1, &mut t.v2] {
                if v.y <= 0.0 {
                    let w = inst.transform.transform_point3a(*v);
                    v.y = terrain_height(hill, w.x, w.z) - base - 0.5;
                }
            }
        }
        Ok(())
    }
}

/// The checks of [`Scene::from_instances`] on instance `index`.
fn check_placed(library: &MeshLibrary, inst: &SceneInstance, index: usize) -> Result<(), SimError> {
    if inst.flags & (flags::UNIQUE | flags::TERRAIN) != 0 {
        return Err(SimError::BadConfig(
            "placed instances share their library mesh (no unique or terrain instances)",
        ));
    }
    library.mesh(inst.mesh)?;
    if !inst.transform.is_finite() || !inst.aabb.min.is_finite() || !inst.aabb.max.is_finite() {
        return Err(SimError::BadTransform { record: index });
    }
    Ok(())
}

fn unit_transform(u: &UnitPath, c: &SceneConfig, frame: u32) -> Affine3A {
    let s = (u.start + u.speed * frame as f32 / FPS).rem_euclid(c.extent.max(1.0));
    let (x, z) = if u.axis == 0 {
        (s, u.lane)
    } else {
        (u.lane, s)
    };
    let yaw = match (u.axis, u.speed >= 0.0) {
        (0, true) => std::f32::consts::FRAC_PI_2,
        (0, false) => -std::f32::consts::FRAC_PI_2,
        (_, true) => 0.0,
        (_, false) => std::f32::consts::PI,
    };
    Affine3A::from_rotation_translation(
        Quat::from_rotation_y(yaw),
        Vec3::new(x, terrain_height(c.hill_height, x, z), z),
    )
}

#[cfg(test)]
mod tests;
