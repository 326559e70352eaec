//! Procedural meshes with three levels of detail (triangle lists), the
//! material table, the vegetation alpha function and the unit animation.
//!
//! Every mesh has [`LOD_COUNT`] LODs: LOD 0 is the most detailed, LOD 2 the
//! coarsest (for buildings a plain box). Meshes live in a [`MeshLibrary`] and
//! are shared by many instances; geometry that differs per instance
//! (terrain tiles, terrain-adapted buildings, animated units) is produced by
//! [`crate::scene::Scene::unique_geometry`] from these meshes.

use glam::{Vec3, Vec3A};
use lipac_core::math::Aabb;
use obvhs::triangle::Triangle;

use crate::error::SimError;

/// Number of LODs every mesh has.
pub const LOD_COUNT: usize = 3;

/// Material indices used by the procedural meshes (index into [`MATERIALS`]).
pub mod material {
    /// Terrain.
    pub const GROUND: u8 = 0;
    /// Building walls.
    pub const WALL: u8 = 1;
    /// Window panes (dark).
    pub const WINDOW: u8 = 2;
    /// Roofs.
    pub const ROOF: u8 = 3;
    /// Tree trunks.
    pub const BARK: u8 = 4;
    /// Alpha-tested leaves.
    pub const LEAF: u8 = 5;
    /// Animated units.
    pub const UNIT: u8 = 6;
    /// A perfect mirror.
    pub const MIRROR: u8 = 7;
}

/// A surface: diffuse albedo, or a perfect mirror reflecting `albedo`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// Diffuse albedo (or mirror reflectance), linear RGB in `[0, 1)`.
    pub albedo: Vec3,
    /// Reflects specularly instead of diffusely.
    pub mirror: bool,
}

/// The material table, indexed by the per-triangle material byte.
pub const MATERIALS: [Material; 8] = [
    Material {
        albedo: Vec3::new(0.30, 0.32, 0.25),
        mirror: false,
    },
    Material {
        albedo: Vec3::new(0.62, 0.58, 0.52),
        mirror: false,
    },
    Material {
        albedo: Vec3::new(0.08, 0.10, 0.12),
        mirror: false,
    },
    Material {
        albedo: Vec3::new(0.45, 0.25, 0.20),
        mirror: false,
    },
    Material {
        albedo: Vec3::new(0.25, 0.18, 0.12),
        mirror: false,
    },
    Material {
        albedo: Vec3::new(0.20, 0.45, 0.15),
        mirror: false,
    },
    Material {
        albedo: Vec3::new(0.70, 0.35, 0.30),
        mirror: false,
    },
    Material {
        albedo: Vec3::new(0.90, 0.90, 0.92),
        mirror: true,
    },
];

/// Looks a material up, falling back to the wall material for unknown bytes.
pub fn material(index: u8) -> Material {
    MATERIALS
        .get(usize::from(index))
        .copied()
        .unwrap_or(MATERIALS[1])
}

/// What a mesh represents.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MeshKind {
    /// A building (boxes with setbacks and a roof).
    Building,
    /// A tall tower with setbacks and a spire.
    Tower,
    /// Vegetation: a trunk and alpha-tested crossed quads.
    Tree,
    /// A small animated character.
    Unit,
    /// A large mirroring block (paper Fig. 3).
    MirrorBlock,
    /// A heightfield terrain tile.
    Terrain,
}

/// One LOD of a mesh: triangles in object space and per-triangle attributes.
#[derive(Clone, Debug, Default)]
pub struct LodTriangles {
    /// Triangles in object space.
    pub triangles: Vec<Triangle>,
    /// Material byte per triangle (see [`mod@material`]).
    pub materials: Vec<u8>,
    /// Whether the triangle is alpha tested with [`leaf_opaque`].
    pub alpha_tested: Vec<bool>,
    /// Animation part per triangle (units only; empty otherwise).
    pub parts: Vec<u8>,
}

impl LodTriangles {
    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.triangles.len()
    }
    /// Whether it holds no triangle.
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }
    /// Object-space bounds (an empty LOD gives a zero box at the origin).
    pub fn bounds(&self) -> Aabb {
        let mut min = Vec3::splat(f32::INFINITY);
        let mut max = Vec3::splat(f32::NEG_INFINITY);
        for t in &self.triangles {
            for v in [t.v0, t.v1, t.v2] {
                min = min.min(v.into());
                max = max.max(v.into());
            }
        }
        if self.triangles.is_empty() {
            Aabb::new(Vec3::ZERO, Vec3::ZERO)
        } else {
            Aabb::new(min, max)
        }
    }
    /// Empties it, keeping the allocations.
    pub fn clear(&mut self) {
        self.triangles.clear();
        self.materials.clear();
        self.alpha_tested.clear();
        self.parts.clear();
    }
    fn tri(&mut self, a: Vec3, b: Vec3, c: Vec3, mat: u8, alpha: bool, part: Option<u8>) {
        self.triangles.push(Triangle {
            v0: a.into(),
            v1: b.into(),
            v2: c.into(),
        });
        self.materials.push(mat);
        self.alpha_tested.push(alpha);
        if let Some(p) = part {
            self.parts.push(p);
        }
    }
    fn quad(&mut self, q: [Vec3; 4], mat: u8, alpha: bool, part: Option<u8>) {
        self.tri(q[0], q[1], q[2], mat, alpha, part);
        self.tri(q[0], q[2], q[3], mat, alpha, part);
    }
    /// A closed prism standing on `base` (centre of its bottom), `height`
    /// tall, elliptical with radii `radii` (x, z) at the bottom and
    /// `taper` times them at the top, `sides` around and `rings` bands up:
    /// `2 * sides * (rings + 1) - 4` triangles.
    #[allow(clippy::too_many_arguments)]
    fn prism(
        &mut self,
        base: Vec3,
        height: f32,
        radii: (f32, f32),
        taper: f32,
        sides: u32,
        rings: u32,
        mat: u8,
        part: u8,
    ) {
        let ring = |r: u32| {
            let f = r as f32 / rings as f32;
            let scale = 1.0 + (taper - 1.0) * f;
            (0..sides)
                .map(|i| {
                    let a = std::f32::consts::TAU * i as f32 / sides as f32;
                    base + Vec3::new(
                        radii.0 * scale * a.cos(),
                        height * f,
                        radii.1 * scale * a.sin(),
                    )
                })
                .collect::<Vec<_>>()
        };
        let rings_v: Vec<Vec<Vec3>> = (0..=rings).map(ring).collect();
        let n = sides as usize;
        for w in rings_v.windows(2) {
            for i in 0..n {
                let j = (i + 1) % n;
                self.quad([w[0][i], w[0][j], w[1][j], w[1][i]], mat, false, Some(part));
            }
        }
        let (bottom, top) = (&rings_v[0], &rings_v[rings as usize]);
        for i in 1..n - 1 {
            self.tri(bottom[0], bottom[i + 1], bottom[i], mat, false, Some(part));
            self.tri(top[0], top[i], top[i + 1], mat, false, Some(part));
        }
    }
    fn cuboid(&mut self, min: Vec3, max: Vec3, mat: u8, part: Option<u8>) {
        let c = |x: bool, y: bool, z: bool| {
            Vec3::new(
                if x { max.x } else { min.x },
                if y { max.y } else { min.y },
                if z { max.z } else { min.z },
            )
        };
        let (f, t) = (false, true);
        self.quad(
            [c(f, f, t), c(t, f, t), c(t, t, t), c(f, t, t)],
            mat,
            false,
            part,
        ); // +z
        self.quad(
            [c(t, f, f), c(f, f, f), c(f, t, f), c(t, t, f)],
            mat,
            false,
            part,
        ); // -z
        self.quad(
            [c(t, f, t), c(t, f, f), c(t, t, f), c(t, t, t)],
            mat,
            false,
            part,
        ); // +x
        self.quad(
            [c(f, f, f), c(f, f, t), c(f, t, t), c(f, t, f)],
            mat,
            false,
            part,
        ); // -x
        self.quad(
            [c(f, t, t), c(t, t, t), c(t, t, f), c(f, t, f)],
            mat,
            false,
            part,
        ); // +y
        self.quad(
            [c(f, f, f), c(t, f, f), c(t, f, t), c(f, f, t)],
            mat,
            false,
            part,
        ); // -y
    }
}

/// A mesh: its kind, three LODs and bounds covering all of them.
#[derive(Clone, Debug)]
pub struct Mesh {
    /// What it represents.
    pub kind: MeshKind,
    /// LOD 0 (finest) to LOD 2 (coarsest).
    pub lods: [LodTriangles; LOD_COUNT],
    /// Object-space bounds of the union of all LODs (for units: of the
    /// whole animation).
    pub bounds: Aabb,
}

impl Mesh {
    fn from_lods(kind: MeshKind, lods: [LodTriangles; LOD_COUNT]) -> Self {
        let mut b = lods[0].bounds();
        for l in &lods[1..] {
            if !l.is_empty() {
                let o = l.bounds();
                b = Aabb::new(b.min.min(o.min), b.max.max(o.max));
            }
        }
        if kind == MeshKind::Unit {
            b = Aabb::new(b.min - UNIT_ANIMATION_PAD, b.max + UNIT_ANIMATION_PAD);
        }
        Self {
            kind,
            lods,
            bounds: b,
        }
    }
}

/// Identifier of a mesh in a [`MeshLibrary`].
pub type MeshIndex = u32;

/// Shared meshes, addressed by [`MeshIndex`].
#[derive(Clone, Debug, Default)]
pub struct MeshLibrary {
    meshes: Vec<Mesh>,
}

impl MeshLibrary {
    /// An empty library.
    pub fn new() -> Self {
        Self::default()
    }
    /// Adds a mesh, returning its id.
    pub fn add(&mut self, mesh: Mesh) -> MeshIndex {
        self.meshes.push(mesh);
        (self.meshes.len() - 1) as MeshIndex
    }
    /// Number of meshes.
    pub fn len(&self) -> usize {
        self.meshes.len()
    }
    /// Whether it holds no mesh.
    pub fn is_empty(&self) -> bool {
        self.meshes.is_empty()
    }
    /// The mesh `id`.
    pub fn mesh(&self, id: MeshIndex) -> Result<&Mesh, SimError> {
        self.meshes
            .get(id as usize)
            .ok_or(SimError::UnknownMesh(id))
    }
    /// LOD `lod` of mesh `id`.
    pub fn lod(&self, id: MeshIndex, lod: usize) -> Result<&LodTriangles, SimError> {
        self.mesh(id)?.lods.get(lod).ok_or(SimError::BadLod(lod))
    }
    /// Triangle count of LOD `lod` of mesh `id`.
    pub fn triangle_count(&self, id: MeshIndex, lod: usize) -> Result<usize, SimError> {
        Ok(self.lod(id, lod)?.len())
    }
    /// Object-space bounds of mesh `id` (all LODs).
    pub fn bounds(&self, id: MeshIndex) -> Result<Aabb, SimError> {
        Ok(self.mesh(id)?.bounds)
    }
    /// All meshes in id order.
    pub fn iter(&self) -> impl Iterator<Item = (MeshIndex, &Mesh)> {
        self.meshes
            .iter()
            .enumerate()
            .map(|(i, m)| (i as MeshIndex, m))
    }
}

/// Roof shapes of [`building`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Roof {
    /// A flat top.
    Flat,
    /// A flat top with a low wall around it.
    Parapet,
    /// A pitched roof along the longer side (single-tier buildings).
    Gable,
    /// A pyramid spire (towers).
    Spire,
}

/// Shape of a procedural building.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BuildingParams {
    /// Footprint along x, metres.
    pub width: f32,
    /// Footprint along z, metres.
    pub depth: f32,
    /// Height of the top tier's roof line, metres.
    pub height: f32,
    /// Number of stacked tiers (1..=3), each set back from the one below.
    pub tiers: u32,
    /// Roof shape.
    pub roof: Roof,
}

/// How far buildings reach below their base (so they sit into slopes).
pub const FOUNDATION_DEPTH: f32 = 2.0;
const FLOOR_HEIGHT: f32 = 3.5;
const WINDOW_SPACING: f32 = 3.0;
const WINDOW_RECESS: f32 = 0.25;

struct Tier {
    min: Vec3,
    max: Vec3,
}

fn tiers_of(p: &BuildingParams) -> Vec<Tier> {
    let n = p.tiers.clamp(1, 3);
    let fractions: &[f32] = match n {
        1 => &[1.0],
        2 => &[0.65, 1.0],
        _ => &[0.5, 0.8, 1.0],
    };
    let mut y0 = 0.0;
    fractions
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let shrink = 1.0 - 0.18 * i as f32;
            let hx = 0.5 * p.width * shrink;
            let hz = 0.5 * p.depth * shrink;
            let y1 = p.height * f;
            let t = Tier {
                min: Vec3::new(-hx, y0, -hz),
                max: Vec3::new(hx, y1, hz),
            };
            y0 = y1;
            t
        })
        .collect()
}

/// One facade with recessed windows: origin `o` (left bottom), horizontal
/// axis `u` (unit), outward normal `n`, `width` along `u`, heights `y0..y1`.
fn facade(out: &mut LodTriangles, o: Vec3, u: Vec3, n: Vec3, width: f32, y0: f32, y1: f32) {
    let p = |a: f32, v: f32, d: f32| o + u * a + Vec3::Y * v - n * d;
    let wall = material::WALL;
    let floors = ((y1 - y0) / FLOOR_HEIGHT).floor().max(0.0) as usize;
    let cols = ((width / WINDOW_SPACING).floor() as usize).max(1);
    let cw = width / cols as f32;
    for f in 0..floors {
        let b = y0 + f as f32 * FLOOR_HEIGHT;
        let (s, l, t) = (
            b + 0.3 * FLOOR_HEIGHT,
            b + 0.85 * FLOOR_HEIGHT,
            b + FLOOR_HEIGHT,
        );
        out.quad(
            [
                p(0.0, b, 0.0),
                p(width, b, 0.0),
                p(width, s, 0.0),
                p(0.0, s, 0.0),
            ],
            wall,
            false,
            None,
        );
        out.quad(
            [
                p(0.0, l, 0.0),
                p(width, l, 0.0),
                p(width, t, 0.0),
                p(0.0, t, 0.0),
            ],
            wall,
            false,
            None,
        );
        let mut prev = 0.0;
        for c in 0..cols {
            let (a0, a1) = (c as f32 * cw + 0.2 * cw, c as f32 * cw + 0.8 * cw);
            out.quad(
                [
                    p(prev, s, 0.0),
                    p(a0, s, 0.0),
                    p(a0, l, 0.0),
                    p(prev, l, 0.0),
                ],
                wall,
                false,
                None,
            );
            let d = WINDOW_RECESS;
            out.quad(
                [p(a0, s, d), p(a1, s, d), p(a1, l, d), p(a0, l, d)],
                material::WINDOW,
                false,
                None,
            );
            out.quad(
                [p(a0, s, 0.0), p(a1, s, 0.0), p(a1, s, d), p(a0, s, d)],
                wall,
                false,
                None,
            );
            out.quad(
                [p(a0, l, d), p(a1, l, d), p(a1, l, 0.0), p(a0, l, 0.0)],
                wall,
                false,
                None,
            );
            out.quad(
                [p(a0, s, d), p(a0, l, d), p(a0, l, 0.0), p(a0, s, 0.0)],
                wall,
                false,
                None,
            );
            out.quad(
                [p(a1, s, 0.0), p(a1, l, 0.0), p(a1, l, d), p(a1, s, d)],
                wall,
                false,
                None,
            );
            prev = a1;
        }
        out.quad(
            [
                p(prev, s, 0.0),
                p(width, s, 0.0),
                p(width, l, 0.0),
                p(prev, l, 0.0),
            ],
            wall,
            false,
            None,
        );
    }
    let top = y0 + floors as f32 * FLOOR_HEIGHT;
    if y1 > top + 1e-3 {
        out.quad(
            [
                p(0.0, top, 0.0),
                p(width, top, 0.0),
                p(width, y1, 0.0),
                p(0.0, y1, 0.0),
            ],
            wall,
            false,
            None,
        );
    }
}

fn plain_sides(out: &mut LodTriangles, min: Vec3, max: Vec3, mat: u8) {
    let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    out.quad(
        [
            c(min.x, min.y, max.z),
            c(max.x, min.y, max.z),
            c(max.x, max.y, max.z),
            c(min.x, max.y, max.z),
        ],
        mat,
        false,
        None,
    );
    out.quad(
        [
            c(max.x, min.y, min.z),
            c(min.x, min.y, min.z),
            c(min.x, max.y, min.z),
            c(max.x, max.y, min.z),
        ],
        mat,
        false,
        None,
    );
    out.quad(
        [
            c(max.x, min.y, max.z),
            c(max.x, min.y, min.z),
            c(max.x, max.y, min.z),
            c(max.x, max.y, max.z),
        ],
        mat,
        false,
        None,
    );
    out.quad(
        [
            c(min.x, min.y, min.z),
            c(min.x, min.y, max.z),
            c(min.x, max.y, max.z),
            c(min.x, max.y, min.z),
        ],
        mat,
        false,
        None,
    );
}

fn top_quad(out: &mut LodTriangles, min: Vec3, max: Vec3, mat: u8) {
    let y = max.y;
    out.quad(
        [
            Vec3::new(min.x, y, max.z),
            Vec3::new(max.x, y, max.z),
            Vec3::new(max.x, y, min.z),
            Vec3::new(min.x, y, min.z),
        ],
        mat,
        false,
        None,
    );
}

fn roof(out: &mut LodTriangles, top: &Tier, roof: Roof) {
    let (min, max) = (top.min, top.max);
    match roof {
        Roof::Flat => top_quad(out, min, max, material::ROOF),
        Roof::Parapet => {
            top_quad(out, min, max, material::ROOF);
            let h = 1.0;
            let w = 0.3;
            let y0 = max.y;
            out.cuboid(
                Vec3::new(min.x, y0, min.z),
                Vec3::new(max.x, y0 + h, min.z + w),
                material::WALL,
                None,
            );
            out.cuboid(
                Vec3::new(min.x, y0, max.z - w),
                Vec3::new(max.x, y0 + h, max.z),
                material::WALL,
                None,
            );
            out.cuboid(
                Vec3::new(min.x, y0, min.z + w),
                Vec3::new(min.x + w, y0 + h, max.z - w),
                material::WALL,
                None,
            );
            out.cuboid(
                Vec3::new(max.x - w, y0, min.z + w),
                Vec3::new(max.x, y0 + h, max.z - w),
                material::WALL,
                None,
            );
        }
        Roof::Gable => {
            let y0 = max.y;
            let along_x = max.x - min.x >= max.z - min.z;
            let rise = 0.35
                * if along_x {
                    max.z - min.z
                } else {
                    max.x - min.x
                };
            let r = material::ROOF;
            if along_x {
                let zc = 0.5 * (min.z + max.z);
                let (a, b) = (
                    Vec3::new(min.x, y0 + rise, zc),
                    Vec3::new(max.x, y0 + rise, zc),
                );
                out.quad(
                    [
                        Vec3::new(min.x, y0, max.z),
                        Vec3::new(max.x, y0, max.z),
                        b,
                        a,
                    ],
                    r,
                    false,
                    None,
                );
                out.quad(
                    [
                        Vec3::new(max.x, y0, min.z),
                        Vec3::new(min.x, y0, min.z),
                        a,
                        b,
                    ],
                    r,
                    false,
                    None,
                );
                out.tri(
                    Vec3::new(min.x, y0, min.z),
                    Vec3::new(min.x, y0, max.z),
                    a,
                    material::WALL,
                    false,
                    None,
                );
                out.tri(
                    Vec3::new(max.x, y0, max.z),
                    Vec3::new(max.x, y0, min.z),
                    b,
                    material::WALL,
                    false,
                    None,
                );
            } else {
                let xc = 0.5 * (min.x + max.x);
                let (a, b) = (
                    Vec3::new(xc, y0 + rise, min.z),
                    Vec3::new(xc, y0 + rise, max.z),
                );
                out.quad(
                    [
                        Vec3::new(min.x, y0, min.z),
                        Vec3::new(min.x, y0, max.z),
                        b,
                        a,
                    ],
                    r,
                    false,
                    None,
                );
                out.quad(
                    [
                        Vec3::new(max.x, y0, max.z),
                        Vec3::new(max.x, y0, min.z),
                        a,
                        b,
                    ],
                    r,
                    false,
                    None,
                );
                out.tri(
                    Vec3::new(max.x, y0, min.z),
                    Vec3::new(min.x, y0, min.z),
                    a,
                    material::WALL,
                    false,
                    None,
                );
                out.tri(
                    Vec3::new(min.x, y0, max.z),
                    Vec3::new(max.x, y0, max.z),
                    b,
                    material::WALL,
                    false,
                    None,
                );
            }
        }
        Roof::Spire => {
            top_quad(out, min, max, material::ROOF);
            let c = 0.5 * (min + max);
            let h = 0.3 * (max.x - min.x);
            let s = 0.25 * (max.x - min.x).min(max.z - min.z);
            let y0 = max.y;
            let tip = Vec3::new(c.x, y0 + 2.5 * h, c.z);
            let q = [
                Vec3::new(c.x - s, y0, c.z - s),
                Vec3::new(c.x + s, y0, c.z - s),
                Vec3::new(c.x + s, y0, c.z + s),
                Vec3::new(c.x - s, y0, c.z + s),
            ];
            for i in 0..4 {
                out.tri(q[i], q[(i + 1) % 4], tip, material::ROOF, false, None);
            }
        }
    }
}

/// A building: LOD 0 with recessed windows on every facade, LOD 1 the tier
/// boxes and the roof, LOD 2 one box. All LODs reach [`FOUNDATION_DEPTH`]
/// below `y = 0`.
pub fn building(p: BuildingParams) -> Mesh {
    let kind = if p.roof == Roof::Spire {
        MeshKind::Tower
    } else {
        MeshKind::Building
    };
    let tiers = tiers_of(&p);
    let roof_kind = if p.roof == Roof::Gable && tiers.len() > 1 {
        Roof::Flat
    } else {
        p.roof
    };
    let base = tiers[0].min;
    let plinth_min = Vec3::new(base.x, -FOUNDATION_DEPTH, base.z);
    let plinth_max = Vec3::new(tiers[0].max.x, 0.0, tiers[0].max.z);

    let mut lod0 = LodTriangles::default();
    plain_sides(&mut lod0, plinth_min, plinth_max, material::WALL);
    for (i, t) in tiers.iter().enumerate() {
        let (a, b) = (t.min, t.max);
        let (w, d) = (b.x - a.x, b.z - a.z);
        facade(
            &mut lod0,
            Vec3::new(a.x, 0.0, b.z),
            Vec3::X,
            Vec3::Z,
            w,
            a.y,
            b.y,
        );
        facade(
            &mut lod0,
            Vec3::new(b.x, 0.0, a.z),
            -Vec3::X,
            -Vec3::Z,
            w,
            a.y,
            b.y,
        );
        facade(
            &mut lod0,
            Vec3::new(b.x, 0.0, b.z),
            -Vec3::Z,
            Vec3::X,
            d,
            a.y,
            b.y,
        );
        facade(
            &mut lod0,
            Vec3::new(a.x, 0.0, a.z),
            Vec3::Z,
            -Vec3::X,
            d,
            a.y,
            b.y,
        );
        if i + 1 < tiers.len() {
            top_quad(&mut lod0, a, b, material::ROOF);
        }
    }
    roof(&mut lod0, &tiers[tiers.len() - 1], roof_kind);

    let mut lod1 = LodTriangles::default();
    plain_sides(&mut lod1, plinth_min, plinth_max, material::WALL);
    for (i, t) in tiers.iter().enumerate() {
        plain_sides(&mut lod1, t.min, t.max, material::WALL);
        if i + 1 < tiers.len() {
            top_quad(&mut lod1, t.min, t.max, material::ROOF);
        }
    }
    roof(&mut lod1, &tiers[tiers.len() - 1], roof_kind);

    let mut lod2 = LodTriangles::default();
    let top = tiers[tiers.len() - 1].max.y;
    lod2.cuboid(
        plinth_min,
        Vec3::new(plinth_max.x, top, plinth_max.z),
        material::WALL,
        None,
    );
    Mesh::from_lods(kind, [lod0, lod1, lod2])
}

/// Centre of the tree crown used by [`leaf_opaque`] (object space).
pub const CROWN_CENTER: Vec3 = Vec3::new(0.0, 5.5, 0.0);
/// Radii of the tree crown used by [`leaf_opaque`].
pub const CROWN_RADII: Vec3 = Vec3::new(2.6, 3.0, 2.6);

/// The procedural alpha function of vegetation, evaluated at an
/// object-space point on a leaf quad: `true` where the leaf is opaque.
///
/// Opaque texels are 0.35 m cells (centred on the planes of the leaf quads)
/// inside an ellipsoidal crown, about half of them (hash of the cell), so
/// rays pass through holes.
///
/// ```
/// use lipac_sim::mesh::leaf_opaque;
/// use glam::Vec3;
/// // Far outside the crown: always transparent.
/// assert!(!leaf_opaque(Vec3::new(10.0, 0.0, 0.0)));
/// ```
pub fn leaf_opaque(p: Vec3) -> bool {
    let q = (p - CROWN_CENTER) / CROWN_RADII;
    if q.length_squared() > 1.0 {
        return false;
    }
    // Cell centres (not boundaries) on the quads' planes x = 0 and z = 0, so
    // rounding of the hit point cannot flip the cell.
    let c = (p * (1.0 / 0.35) + 0.5).floor();
    let h = crate::rng::pcg_hash(
        (c.x as i32 as u32).wrapping_mul(73_856_093)
            ^ (c.y as i32 as u32).wrapping_mul(19_349_663)
            ^ (c.z as i32 as u32).wrapping_mul(83_492_791),
    );
    h & 0xFF < 140
}

/// A tree: trunk plus alpha-tested crossed quads (LOD 0: four vertical and
/// one horizontal quad; LOD 1: two; LOD 2: two, no trunk).
pub fn tree() -> Mesh {
    let trunk = |l: &mut LodTriangles| {
        l.cuboid(
            Vec3::new(-0.2, -0.5, -0.2),
            Vec3::new(0.2, 3.5, 0.2),
            material::BARK,
            None,
        )
    };
    let crossed = |l: &mut LodTriangles, n: usize| {
        let (r, y0, y1) = (
            CROWN_RADII.x,
            CROWN_CENTER.y - CROWN_RADII.y,
            CROWN_CENTER.y + CROWN_RADII.y,
        );
        for i in 0..n {
            let a = std::f32::consts::PI * i as f32 / n as f32;
            let d = Vec3::new(a.cos(), 0.0, a.sin()) * r;
            l.quad(
                [
                    Vec3::new(-d.x, y0, -d.z),
                    Vec3::new(d.x, y0, d.z),
                    Vec3::new(d.x, y1, d.z),
                    Vec3::new(-d.x, y1, -d.z),
                ],
                material::LEAF,
                true,
                None,
            );
        }
    };
    let mut lod0 = LodTriangles::default();
    trunk(&mut lod0);
    crossed(&mut lod0, 4);
    let (r, y) = (CROWN_RADII.x, CROWN_CENTER.y);
    lod0.quad(
        [
            Vec3::new(-r, y, -r),
            Vec3::new(r, y, -r),
            Vec3::new(r, y, r),
            Vec3::new(-r, y, r),
        ],
        material::LEAF,
        true,
        None,
    );
    let mut lod1 = LodTriangles::default();
    trunk(&mut lod1);
    crossed(&mut lod1, 2);
    let mut lod2 = LodTriangles::default();
    crossed(&mut lod2, 2);
    Mesh::from_lods(MeshKind::Tree, [lod0, lod1, lod2])
}

/// Padding of unit bounds that covers every animation pose.
pub const UNIT_ANIMATION_PAD: Vec3 = Vec3::new(0.1, 0.05, 0.5);
const HIP: Vec3 = Vec3::new(0.0, 0.9, 0.0);
const SHOULDER: Vec3 = Vec3::new(0.0, 1.45, 0.0);

/// A small character facing +z, 1.8 m tall: parts 0 body/head, 1/2 legs,
/// 3/4 arms (LOD 0: six boxes; LOD 1: body, two legs; LOD 2: one box).
pub fn unit() -> Mesh {
    let m = material::UNIT;
    let mut lod0 = LodTriangles::default();
    lod0.cuboid(
        Vec3::new(-0.25, 0.9, -0.15),
        Vec3::new(0.25, 1.5, 0.15),
        m,
        Some(0),
    );
    lod0.cuboid(
        Vec3::new(-0.13, 1.5, -0.13),
        Vec3::new(0.13, 1.8, 0.13),
        m,
        Some(0),
    );
    lod0.cuboid(
        Vec3::new(-0.22, 0.0, -0.1),
        Vec3::new(-0.03, 0.9, 0.1),
        m,
        Some(1),
    );
    lod0.cuboid(
        Vec3::new(0.03, 0.0, -0.1),
        Vec3::new(0.22, 0.9, 0.1),
        m,
        Some(2),
    );
    lod0.cuboid(
        Vec3::new(-0.37, 0.85, -0.08),
        Vec3::new(-0.26, 1.48, 0.08),
        m,
        Some(3),
    );
    lod0.cuboid(
        Vec3::new(0.26, 0.85, -0.08),
        Vec3::new(0.37, 1.48, 0.08),
        m,
        Some(4),
    );
    let mut lod1 = LodTriangles::default();
    lod1.cuboid(
        Vec3::new(-0.3, 0.9, -0.15),
        Vec3::new(0.3, 1.8, 0.15),
        m,
        Some(0),
    );
    lod1.cuboid(
        Vec3::new(-0.22, 0.0, -0.1),
        Vec3::new(-0.03, 0.9, 0.1),
        m,
        Some(1),
    );
    lod1.cuboid(
        Vec3::new(0.03, 0.0, -0.1),
        Vec3::new(0.22, 0.9, 0.1),
        m,
        Some(2),
    );
    let mut lod2 = LodTriangles::default();
    lod2.cuboid(
        Vec3::new(-0.3, 0.0, -0.15),
        Vec3::new(0.3, 1.8, 0.15),
        m,
        Some(0),
    );
    Mesh::from_lods(MeshKind::Unit, [lod0, lod1, lod2])
}

/// A character unit as a game draws one (the paper's city-building game:
/// villagers, workers): [`unit`]'s proportions and animation parts (0
/// body and head, 1/2 legs, 3/4 arms, so [`deform_unit`] walks it) from
/// rounded limbs. LOD 0: 12-sided torso and head, 10-sided legs and
/// 8-sided arms in several rings (552 triangles); LOD 1: hexagonal
/// prisms (120); LOD 2: five boxes (60).
pub fn character() -> Mesh {
    let m = material::UNIT;
    // (part, centre x, y0, y1, radius x, radius z, taper at the top).
    let parts: [(u8, f32, f32, f32, f32, f32, f32); 6] = [
        (0, 0.0, 0.9, 1.5, 0.25, 0.15, 0.9),
        (0, 0.0, 1.5, 1.8, 0.13, 0.13, 0.6),
        (1, -0.125, 0.0, 0.9, 0.09, 0.1, 1.1),
        (2, 0.125, 0.0, 0.9, 0.09, 0.1, 1.1),
        (3, -0.31, 0.85, 1.48, 0.05, 0.08, 1.2),
        (4, 0.31, 0.85, 1.48, 0.05, 0.08, 1.2),
    ];
    let lod = |sides: [u32; 6], rings: [u32; 6]| {
        let mut l = LodTriangles::default();
        for (k, &(part, x, y0, y1, rx, rz, taper)) in parts.iter().enumerate() {
            l.prism(
                Vec3::new(x, y0, 0.0),
                y1 - y0,
                (rx, rz),
                taper,
                sides[k],
                rings[k],
                m,
                part,
            );
        }
        l
    };
    let lod0 = lod([12, 12, 10, 10, 8, 8], [3, 4, 4, 4, 4, 4]);
    let lod1 = lod([6; 6], [1; 6]);
    let mut lod2 = LodTriangles::default();
    lod2.cuboid(
        Vec3::new(-0.25, 0.9, -0.15),
        Vec3::new(0.25, 1.8, 0.15),
        m,
        Some(0),
    );
    for (part, x0, x1) in [(1, -0.22, -0.03), (2, 0.03, 0.22)] {
        lod2.cuboid(
            Vec3::new(x0, 0.0, -0.1),
            Vec3::new(x1, 0.9, 0.1),
            m,
            Some(part),
        );
    }
    for (part, x0, x1) in [(3, -0.37, -0.26), (4, 0.26, 0.37)] {
        lod2.cuboid(
            Vec3::new(x0, 0.85, -0.08),
            Vec3::new(x1, 1.48, 0.08),
            m,
            Some(part),
        );
    }
    Mesh::from_lods(MeshKind::Unit, [lod0, lod1, lod2])
}

/// Deforms a unit LOD into `out` for walk-cycle phase `phase` (radians):
/// legs and arms swing about the x axis, the body bobs. Triangle order and
/// attributes are kept, so a deformed LOD can refit the rest pose's BVH.
pub fn deform_unit(rest: &LodTriangles, phase: f32, out: &mut LodTriangles) {
    out.clear();
    let swing = 0.5 * phase.sin();
    let bob = Vec3A::new(0.0, 0.03 * phase.sin().abs(), 0.0);
    let rot = |v: Vec3A, pivot: Vec3, angle: f32| {
        let p = v - Vec3A::from(pivot);
        let (s, c) = angle.sin_cos();
        Vec3A::new(p.x, p.y * c - p.z * s, p.y * s + p.z * c) + Vec3A::from(pivot)
    };
    for (i, t) in rest.triangles.iter().enumerate() {
        let part = rest.parts.get(i).copied().unwrap_or(0);
        let f = |v: Vec3A| {
            bob + match part {
                1 => rot(v, HIP, swing),
                2 => rot(v, HIP, -swing),
                3 => rot(v, SHOULDER, -0.8 * swing),
                4 => rot(v, SHOULDER, 0.8 * swing),
                _ => v,
            }
        };
        out.triangles.push(Triangle {
            v0: f(t.v0),
            v1: f(t.v1),
            v2: f(t.v2),
        });
    }
    out.materials.extend_from_slice(&rest.materials);
    out.alpha_tested.extend_from_slice(&rest.alpha_tested);
    out.parts.extend_from_slice(&rest.parts);
}

/// A mirroring block: a box `size` wide/deep/high standing on `y = 0`
/// (reaching [`FOUNDATION_DEPTH`] below); identical at every LOD.
pub fn mirror_block(size: Vec3) -> Mesh {
    let mut l = LodTriangles::default();
    l.cuboid(
        Vec3::new(-0.5 * size.x, -FOUNDATION_DEPTH, -0.5 * size.z),
        Vec3::new(0.5 * size.x, size.y, 0.5 * size.z),
        material::MIRROR,
        None,
    );
    Mesh::from_lods(MeshKind::MirrorBlock, [l.clone(), l.clone(), l])
}

/// A plain box from `min` to `max` in object space, all faces of
/// `material`, identical at every LOD (walls and ground slabs of hand-made
/// test scenes).
///
/// ```
/// use glam::Vec3;
/// use lipac_sim::mesh::{cuboid, material};
/// let m = cuboid(Vec3::ZERO, Vec3::new(4.0, 2.0, 1.0), material::WALL);
/// assert_eq!(m.lods[0].len(), 12);
/// assert_eq!(m.bounds.max, Vec3::new(4.0, 2.0, 1.0));
/// ```
pub fn cuboid(min: Vec3, max: Vec3, material: u8) -> Mesh {
    let mut l = LodTriangles::default();
    l.cuboid(min, max, material, None);
    Mesh::from_lods(MeshKind::Building, [l.clone(), l.clone(), l])
}

/// Grid resolution (quads per side) of terrain tiles per LOD.
pub const TERRAIN_RESOLUTION: [u32; LOD_COUNT] = [24, 12, 6];

/// A heightfield tile in object space: `size` x `size` metres starting at
/// the object origin, `res` quads per side, heights from `height(x, z)` at
/// world position `(origin_x + x, origin_z + z)`.
pub fn terrain_tile(
    origin_x: f32,
    origin_z: f32,
    size: f32,
    res: u32,
    height: impl Fn(f32, f32) -> f32,
    out: &mut LodTriangles,
) {
    out.clear();
    let res = res.max(1);
    let step = size / res as f32;
    let p = |i: u32, j: u32| {
        let (x, z) = (i as f32 * step, j as f32 * step);
        Vec3::new(x, height(origin_x + x, origin_z + z), z)
    };
    for j in 0..res {
        for i in 0..res {
            out.quad(
                [p(i, j), p(i, j + 1), p(i + 1, j + 1), p(i + 1, j)],
                material::GROUND,
                false,
                None,
            );
        }
    }
}

#[cfg(test)]
mod tests;
