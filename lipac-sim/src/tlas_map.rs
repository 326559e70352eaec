//! A top-down map of one strategy's TLAS in one frame (the paper's Fig. 1
//! right and Fig. 3): every instance's footprint coloured by what the TLAS
//! holds for it, the counting boxes of inactive hitboxes shaded by their
//! hits, and the camera with the horizontal extent of its view frustum.
//!
//! What the map shows is read from the TLAS records alone, so it works for
//! every strategy:
//!
//! * **active**: the instance's geometry is in the TLAS;
//! * **omitted**: a counting box stands for the instance (a hit counts for it);
//! * **inactive**: nothing in the TLAS names it (it lies in an inactive
//!   hitbox, or the strategy culled it outright);
//! * **inactive hitbox**: a counting box standing for a whole cell, pale
//!   without hits this frame, darker the more hits it counted.
//!
//! Active hitboxes have no TLAS record of their own: a strategy with
//! hitboxes (LiPaC) hands its cells to [`TlasMap::new`] ([`HitboxCell`],
//! from [`crate::strategy::Strategy::hitbox_cells`]) and its **active
//! hitboxes** are drawn as blue outlines over a light blue fill; without
//! cells (the baselines) none are drawn. Terrain
//! tiles are drawn as outlines. **Pinned** instances (the scene's
//! [`flags::PINNED`], e.g. lipac-sim's terrain tiles: always resident, never
//! culled) are drawn in their own colour whatever the TLAS holds (terrain
//! tiles as an outline), counted apart ([`TlasMap::pinned`]) and left out of
//! [`TlasMap::count`].
//!
//! The map is a PNG ([`TlasMap::png`]: seen from above, x to the right,
//! z down, the scene's footprint); [`TlasMap::legend`] names its colours.

use glam::{Vec2, Vec3, Vec3A};
use lipac_core::layout::TlasInstance;
use lipac_core::math::rows_to_affine;

use crate::blas::UNIT_CUBE;
use crate::camera::FlyCamera;
use crate::error::SimError;
use crate::scene::{flags, Scene};
use crate::snapshot::encode_png;
use crate::tlas::CountingBoxes;
use crate::traversal::Counters;

/// What the TLAS holds for an instance.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MapState {
    /// Its geometry.
    Active,
    /// A counting box for it.
    Omitted,
    /// Nothing.
    Inactive,
}

/// One instance on the map.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapInstance {
    /// Footprint minimum corner (x, z), m.
    pub min: Vec2,
    /// Footprint maximum corner (x, z), m.
    pub max: Vec2,
    /// What the TLAS holds.
    pub state: MapState,
    /// Hits counted for it this frame (real hits and box hits).
    pub hits: u32,
    /// A terrain tile (drawn as an outline).
    pub terrain: bool,
    /// Pinned (the scene's [`flags::PINNED`]: always resident, never
    /// culled); drawn in its own colour whatever the TLAS holds.
    pub pinned: bool,
}

/// One inactive hitbox's counting box on the map.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapHitbox {
    /// Hitbox index (the record's custom index), or for a merged box
    /// (`merged`) the id of its tree node, which is no hitbox index.
    pub index: u32,
    /// A merged counting box of adaptive hitboxes (a cold region of
    /// several inactive hitboxes drawn as one box).
    pub merged: bool,
    /// Footprint minimum corner (x, z), m.
    pub min: Vec2,
    /// Footprint maximum corner (x, z), m.
    pub max: Vec2,
    /// Hits counted into it this frame.
    pub hits: u32,
}

/// One hitbox cell as a strategy with hitboxes holds it (the optional
/// input of [`TlasMap::new`], from [`crate::strategy::Strategy::hitbox_cells`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HitboxCell {
    /// Hitbox index.
    pub index: u32,
    /// Cell minimum corner (x, z), m.
    pub min: Vec2,
    /// Cell maximum corner (x, z), m.
    pub max: Vec2,
    /// Whether the hitbox is active (its instances may be in the TLAS).
    pub active: bool,
    /// The hit count its record holds when the map is taken.
    pub hits: u32,
}

/// The map of one strategy's TLAS in one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct TlasMap {
    /// Per instance slot.
    pub instances: Vec<MapInstance>,
    /// Inactive hitboxes (one per hitbox counting record).
    pub hitboxes: Vec<MapHitbox>,
    /// Active hitboxes (from the strategy's cells; empty without them).
    pub active_hitboxes: Vec<MapHitbox>,
    /// Camera position (x, z).
    pub camera: Vec2,
    /// Unit directions (x, z) of the frustum's left and right edges.
    pub frustum: [Vec2; 2],
    /// Scene footprint minimum corner (x, z).
    pub bounds_min: Vec2,
    /// Scene footprint maximum corner (x, z).
    pub bounds_max: Vec2,
}

fn xz(v: Vec3) -> Vec2 {
    Vec2::new(v.x, v.z)
}

impl TlasMap {
    /// The map of `records` (a strategy's TLAS) over `scene`, with the hit
    /// counts of the frame's render and `camera`. `cells`, where the
    /// strategy has hitboxes, adds the active ones (cells with infinite
    /// bounds are skipped); the inactive ones come from the records either
    /// way.
    pub fn new(
        scene: &Scene,
        records: &[TlasInstance],
        counting: &CountingBoxes,
        counters: &Counters,
        camera: &FlyCamera,
        cells: Option<&[HitboxCell]>,
    ) -> Result<Self, SimError> {
        let n = scene.instances().len();
        let mut state = vec![MapState::Inactive; n];
        let mut hitboxes = Vec::new();
        for r in records {
            if r.acceleration_structure_reference == 0 || r.mask() == 0 {
                continue;
            }
            let (sbt, custom) = (r.sbt_offset(), r.custom_index());
            // Merged boxes (adaptive hitboxes) are drawn as one box; their
            // hits are the leaves' (custom index = tree node id, no counter).
            let merged = sbt == counting.merged_box_sbt;
            if sbt == counting.hitbox_box_sbt || merged {
                let t = rows_to_affine(&r.transform);
                let (mut lo, mut hi) = (Vec3A::splat(f32::INFINITY), Vec3A::splat(-f32::INFINITY));
                for i in 0..8 {
                    let c = Vec3A::new(
                        if i & 1 == 0 {
                            UNIT_CUBE.min.x
                        } else {
                            UNIT_CUBE.max.x
                        },
                        if i & 2 == 0 {
                            UNIT_CUBE.min.y
                        } else {
                            UNIT_CUBE.max.y
                        },
                        if i & 4 == 0 {
                            UNIT_CUBE.min.z
                        } else {
                            UNIT_CUBE.max.z
                        },
                    );
                    let w = t.transform_point3a(c);
                    lo = lo.min(w);
                    hi = hi.max(w);
                }
                if !lo.is_finite() || !hi.is_finite() {
                    return Err(SimError::NonFinite("hitbox record transform"));
                }
                hitboxes.push(MapHitbox {
                    index: custom,
                    merged,
                    min: Vec2::new(lo.x, lo.z),
                    max: Vec2::new(hi.x, hi.z),
                    hits: if merged {
                        0
                    } else {
                        counters.hitboxes.get(custom as usize).copied().unwrap_or(0)
                    },
                });
                continue;
            }
            let Some(s) = state.get_mut(custom as usize) else {
                return Err(SimError::BadConfig(
                    "TLAS record names no instance of the scene",
                ));
            };
            if sbt == counting.instance_box_sbt {
                if *s == MapState::Inactive {
                    *s = MapState::Omitted;
                }
            } else {
                *s = MapState::Active;
            }
        }
        let instances = scene
            .instances()
            .iter()
            .zip(&state)
            .enumerate()
            .map(|(i, (inst, &state))| MapInstance {
                min: xz(inst.aabb.min),
                max: xz(inst.aabb.max),
                state,
                hits: counters.instances.get(i).copied().unwrap_or(0),
                terrain: inst.flags & flags::TERRAIN != 0,
                pinned: inst.is_pinned(),
            })
            .collect();
        let f = camera.forward();
        let (right, _) = camera.basis();
        let th = (0.5 * camera.vfov).tan() * camera.aspect;
        let edge = |s: f32| {
            let d = xz(f + right * (s * th));
            d.try_normalize().unwrap_or(Vec2::X)
        };
        let active_hitboxes = cells
            .unwrap_or_default()
            .iter()
            .filter(|c| c.active && c.min.is_finite() && c.max.is_finite())
            .map(|c| MapHitbox {
                index: c.index,
                merged: false,
                min: c.min,
                max: c.max,
                hits: c.hits,
            })
            .collect();
        let b = scene.bounds();
        Ok(Self {
            instances,
            hitboxes,
            active_hitboxes,
            camera: xz(camera.position),
            frustum: [edge(-1.0), edge(1.0)],
            bounds_min: xz(b.min),
            bounds_max: xz(b.max),
        })
    }

    /// Instances in `state` (terrain tiles and pinned instances excluded).
    pub fn count(&self, state: MapState) -> usize {
        self.instances
            .iter()
            .filter(|i| !i.terrain && !i.pinned && i.state == state)
            .count()
    }

    /// Pinned instances (terrain tiles included).
    pub fn pinned(&self) -> usize {
        self.instances.iter().filter(|i| i.pinned).count()
    }

    /// The map's legend: name, colour and number of each kind of mark (in
    /// drawing order).
    pub fn legend(&self) -> Vec<(&'static str, [u8; 3], usize)> {
        let hot = self.hitboxes.iter().filter(|h| h.hits > 0).count();
        vec![
            (
                "terrain tile (outline)",
                TERRAIN,
                self.instances
                    .iter()
                    .filter(|i| i.terrain && !i.pinned)
                    .count(),
            ),
            (
                "active hitbox (outline)",
                HITBOX_ACTIVE,
                self.active_hitboxes.len(),
            ),
            (
                "inactive hitbox, no hits",
                HITBOX_COLD,
                self.hitboxes.len() - hot,
            ),
            ("inactive hitbox, hit (darker: more hits)", HITBOX_HOT, hot),
            (
                "inactive instance",
                INACTIVE,
                self.count(MapState::Inactive),
            ),
            (
                "omitted instance (counting box)",
                OMITTED,
                self.count(MapState::Omitted),
            ),
            (
                "active instance (geometry)",
                ACTIVE,
                self.count(MapState::Active),
            ),
            (
                "pinned instance (always resident; terrain: outline)",
                PINNED,
                self.pinned(),
            ),
            (
                "instance hit this frame",
                HIT,
                self.instances
                    .iter()
                    .filter(|i| !i.terrain && i.hits > 0)
                    .count(),
            ),
            ("camera and frustum", [0, 0, 0], 1),
        ]
    }

    /// Side of the square the map covers, m (the scene's larger extent).
    pub fn side(&self) -> f32 {
        (self.bounds_max - self.bounds_min).max_element().max(1.0)
    }

    /// The map as `size` x `size` 8-bit RGB pixels (seen from above: x to
    /// the right, z down),
    /// drawn in [`TlasMap::legend`]'s order.
    pub fn pixels(&self, size: u32) -> Vec<u8> {
        let n = size.max(16) as usize;
        let mut img = Raster {
            n,
            px: vec![255u8; n * n * 3],
        };
        let side = self.side();
        let c = (self.bounds_min + self.bounds_max) * 0.5;
        let origin = c - Vec2::splat(0.5 * side);
        let k = n as f32 / side;
        // World (x, z) to pixel (column, row): seen from above (y up), x to
        // the right and z down.
        let to = |p: Vec2| Vec2::new((p.x - origin.x) * k, (p.y - origin.y) * k);
        let rect =
            |img: &mut Raster, lo: Vec2, hi: Vec2, color: [u8; 3], alpha: f32, fill: bool| {
                let (a, b) = (to(lo), to(hi));
                img.rect(
                    a.x.min(b.x),
                    a.y.min(b.y),
                    a.x.max(b.x),
                    a.y.max(b.y),
                    color,
                    alpha,
                    fill,
                );
            };
        for i in self.instances.iter().filter(|i| i.terrain && !i.pinned) {
            rect(&mut img, i.min, i.max, TERRAIN, 1.0, false);
        }
        for h in &self.active_hitboxes {
            rect(&mut img, h.min, h.max, HITBOX_ACTIVE, 0.12, true);
            rect(&mut img, h.min, h.max, HITBOX_ACTIVE, 1.0, false);
        }
        // Hit hitboxes darken with their share of the frame's most hit one.
        let most = self
            .hitboxes
            .iter()
            .map(|h| h.hits)
            .max()
            .unwrap_or(0)
            .max(1);
        for h in &self.hitboxes {
            let (color, alpha) = if h.hits > 0 {
                (HITBOX_HOT, 0.4 + 0.55 * h.hits as f32 / most as f32)
            } else {
                (HITBOX_COLD, 0.35)
            };
            rect(&mut img, h.min, h.max, color, alpha, true);
        }
        for (state, color) in [
            (MapState::Inactive, INACTIVE),
            (MapState::Omitted, OMITTED),
            (MapState::Active, ACTIVE),
        ] {
            for i in self
                .instances
                .iter()
                .filter(|i| !i.terrain && !i.pinned && i.state == state)
            {
                rect(&mut img, i.min, i.max, color, 1.0, true);
            }
        }
        for i in self.instances.iter().filter(|i| i.pinned) {
            rect(&mut img, i.min, i.max, PINNED, 1.0, !i.terrain);
        }
        for i in self.instances.iter().filter(|i| !i.terrain && i.hits > 0) {
            let m = to((i.min + i.max) * 0.5);
            img.rect(m.x - 1.0, m.y - 1.0, m.x + 2.0, m.y + 2.0, HIT, 1.0, true);
        }
        let cam = to(self.camera);
        for d in self.frustum {
            let end = to(self.camera + d * (0.3 * side));
            img.line(cam, end, [0, 0, 0]);
        }
        img.rect(
            cam.x - 3.0,
            cam.y - 3.0,
            cam.x + 4.0,
            cam.y + 4.0,
            [0, 0, 0],
            1.0,
            true,
        );
        img.px
    }

    /// [`TlasMap::pixels`] as a PNG.
    pub fn png(&self, size: u32) -> Result<Vec<u8>, SimError> {
        let n = size.max(16);
        encode_png(n, n, &self.pixels(size))
    }
}

const TERRAIN: [u8; 3] = [0xc8, 0xc8, 0xc8];
const HITBOX_COLD: [u8; 3] = [0xf2, 0xc9, 0x4c];
const HITBOX_HOT: [u8; 3] = [0xe0, 0x6c, 0x00];
const INACTIVE: [u8; 3] = [0x9a, 0x9a, 0x9a];
const OMITTED: [u8; 3] = [0x2c, 0xa0, 0x2c];
const ACTIVE: [u8; 3] = [0x1f, 0x4e, 0xb4];
const HIT: [u8; 3] = [0xd6, 0x27, 0x28];
const PINNED: [u8; 3] = [0x8e, 0x44, 0xad];
const HITBOX_ACTIVE: [u8; 3] = [0x4a, 0x90, 0xd9];

/// A square RGB canvas.
struct Raster {
    n: usize,
    px: Vec<u8>,
}

impl Raster {
    fn blend(&mut self, x: i64, y: i64, c: [u8; 3], alpha: f32) {
        if x < 0 || y < 0 || x >= self.n as i64 || y >= self.n as i64 {
            return;
        }
        let i = (y as usize * self.n + x as usize) * 3;
        for (p, &c) in self.px[i..i + 3].iter_mut().zip(&c) {
            let old = f32::from(*p);
            *p = (old + (f32::from(c) - old) * alpha + 0.5) as u8;
        }
    }

    /// Pixels whose centres lie in `[x0, x1) x [y0, y1)` (at least one).
    #[allow(clippy::too_many_arguments)]
    fn rect(&mut self, x0: f32, y0: f32, x1: f32, y1: f32, c: [u8; 3], alpha: f32, fill: bool) {
        if !(x0.is_finite() && y0.is_finite() && x1.is_finite() && y1.is_finite()) {
            return;
        }
        let lim = self.n as f32 + 1.0;
        let (a, b) = (
            x0.clamp(-1.0, lim).round() as i64,
            y0.clamp(-1.0, lim).round() as i64,
        );
        let (c1, d) = (
            (x1.clamp(-1.0, lim).round() as i64).max(a + 1),
            (y1.clamp(-1.0, lim).round() as i64).max(b + 1),
        );
        for y in b..d {
            for x in a..c1 {
                if fill || y == b || y == d - 1 || x == a || x == c1 - 1 {
                    self.blend(x, y, c, alpha);
                }
            }
        }
    }

    fn line(&mut self, a: Vec2, b: Vec2, c: [u8; 3]) {
        let steps = (b - a)
            .abs()
            .max_element()
            .ceil()
            .clamp(1.0, 4.0 * self.n as f32) as i64;
        for s in 0..=steps {
            let p = a + (b - a) * (s as f32 / steps as f32);
            for (dx, dy) in [(0, 0), (1, 0), (0, 1)] {
                self.blend(p.x as i64 + dx, p.y as i64 + dy, c, 1.0);
            }
        }
    }
}

#[cfg(test)]
mod tests;
