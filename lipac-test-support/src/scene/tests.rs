use lipac_core::{HitboxIndex, InstanceFlags, MeshId};

use super::*;
use crate::SplitMix64;

#[test]
fn scenes_are_seeded_and_inside_the_world() {
    let meshes = [(MeshId(4), 3), (MeshId(9), 1)];
    let a = random_scene(&mut SplitMix64::new(1), 500, &meshes);
    let b = random_scene(&mut SplitMix64::new(1), 500, &meshes);
    let c = random_scene(&mut SplitMix64::new(2), 500, &meshes);
    assert_eq!(a, b);
    assert_ne!(a, c);
    let grid = world_grid();
    assert_eq!(grid.len(), 16);
    for d in &a {
        assert!(d.aabb.min.x >= 0.0 && d.aabb.max.x <= WORLD);
        assert!(d.aabb.min.z >= 0.0 && d.aabb.max.z <= WORLD);
        let lods = meshes
            .iter()
            .find(|m| m.0 == d.mesh)
            .expect("a listed mesh")
            .1;
        assert!(d.lod < lods);
    }
    // Every kind of flag and both meshes occur.
    let unique = a
        .iter()
        .filter(|d| d.flags == InstanceFlags::UNIQUE_BLAS)
        .count();
    let fixed = a
        .iter()
        .filter(|d| d.flags == InstanceFlags::STATIC)
        .count();
    assert!((40..130).contains(&unique), "{unique}");
    assert!((110..230).contains(&fixed), "{fixed}");
    assert!(a.iter().any(|d| d.mesh == MeshId(9)) && a.iter().any(|d| d.mesh == MeshId(4)));
}

#[test]
fn without_meshes_every_instance_is_mesh_0_lod_0() {
    let d = random_scene(&mut SplitMix64::new(3), 20, &[]);
    assert!(d.iter().all(|d| d.mesh == MeshId(0) && d.lod == 0));
}

#[test]
fn the_cameras_look_into_the_world() {
    let centre = Aabb::new(Vec3::splat(31.0), Vec3::splat(33.0));
    for (eye, f) in frustums() {
        assert!(eye.x < 0.0 || eye.x > WORLD || eye.z < 0.0, "{eye}");
        assert!(f.intersects_aabb(&centre), "{eye}");
    }
}
