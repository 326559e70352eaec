//! Seeded random scenes for `Manager` tests: instances with 2 m footprints
//! scattered over a [`WORLD`] × [`WORLD`] m square, random meshes, LODs and
//! flags, the hitbox grid over that square and cameras looking into it.
//!
//! ```
//! use lipac_core::{HitboxIndex, MeshId};
//! use lipac_test_support::scene::{random_scene, world_grid, WORLD};
//! use lipac_test_support::SplitMix64;
//!
//! let meshes = [(MeshId(0), 3), (MeshId(1), 1)];
//! let descs = random_scene(&mut SplitMix64::new(7), 100, &meshes);
//! assert_eq!(descs.len(), 100);
//! assert!(descs.iter().all(|d| d.aabb.max.x <= WORLD && d.lod < 3));
//! assert_eq!(world_grid().len(), 16);
//! ```

use glam::camera::rh::{proj, view};
use glam::{Affine3A, Vec3};
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::instance::{InstanceDesc, InstanceFlags, MeshId};
use lipac_core::latency::Frustum;
use lipac_core::math::Aabb;

use crate::Rng64;

/// Side of the square world, metres.
pub const WORLD: f32 = 64.0;

/// The hitbox grid over the world: 16 m cells, 4 × 4.
pub fn world_grid() -> HitboxGrid {
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [f64::from(WORLD), f64::from(WORLD)],
        cell_size: 16.0,
    });
    grid.expect("a valid grid")
}

/// One random instance: centre `(1 + below(62), 0, 1 + below(62))`, a 2 m
/// square footprint 1–4 m tall, a mesh picked from `meshes` (mesh, LOD
/// count) with a LOD below its count (`MeshId(0)`, LOD 0 if `meshes` is
/// empty), and flags: unique BLAS 1 in 6, static 2 in 6, else none.
pub fn random_instance<R: Rng64>(rng: &mut R, meshes: &[(MeshId, u32)]) -> InstanceDesc {
    let x = 1.0 + rng.below(62) as f32;
    let z = 1.0 + rng.below(62) as f32;
    let (mesh, lods) = rng.pick(meshes).unwrap_or((MeshId(0), 1));
    let aabb = Aabb::new(
        Vec3::new(x - 1.0, 0.0, z - 1.0),
        Vec3::new(x + 1.0, 1.0 + rng.below(4) as f32, z + 1.0),
    );
    let mut d = InstanceDesc::new(mesh, Affine3A::from_translation(Vec3::new(x, 0.0, z)), aabb);
    d.lod = rng.below(u64::from(lods)) as u32;
    d.flags = match rng.below(6) {
        0 => InstanceFlags::UNIQUE_BLAS,
        1 | 2 => InstanceFlags::STATIC,
        _ => InstanceFlags::empty(),
    };
    d
}

/// `n` instances from [`random_instance`].
pub fn random_scene<R: Rng64>(
    rng: &mut R,
    n: usize,
    meshes: &[(MeshId, u32)],
) -> Vec<InstanceDesc> {
    (0..n).map(|_| random_instance(rng, meshes)).collect()
}

/// Three cameras (eye, frustum; 70° square, 0.1–500 m) looking into the
/// world from its west, east and south sides, for latency mitigation.
pub fn frustums() -> Vec<(Vec3, Frustum)> {
    let p = proj::vulkan::perspective(70f32.to_radians(), 1.0, 0.1, 500.0);
    let at = |eye: Vec3, dir: Vec3| {
        let v = view::look_to_mat4(eye, dir, Vec3::Y);
        (
            eye,
            Frustum::from_view_projection(p * v).expect("a valid frustum"),
        )
    };
    vec![
        at(Vec3::new(-10.0, 5.0, 32.0), Vec3::X),
        at(Vec3::new(74.0, 5.0, 32.0), Vec3::NEG_X),
        at(Vec3::new(32.0, 5.0, -10.0), Vec3::Z),
    ]
}

#[cfg(test)]
mod tests;
