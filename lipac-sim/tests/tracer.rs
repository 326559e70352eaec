//! The two-level tracer against brute force, counting-box semantics, masks,
//! alpha testing.

use glam::{Affine3A, Quat, Vec3, Vec3A};
use lipac_core::layout::{TlasInstance, VK_INSTANCE_FORCE_OPAQUE};
use lipac_core::math::{affine_to_rows, rows_to_affine, Aabb};
use lipac_sim::blas::{box_transform, BlasStore, BuildQuality, BvhBlasId};
use lipac_sim::mesh::{self, leaf_opaque, LodTriangles};
use lipac_sim::rng::SplitMix64;
use lipac_sim::tlas::{masks, CountingBoxes, CpuTlas};
use lipac_sim::traversal::{occluded, trace, BoxKind, Counters, Ray};
use obvhs::ray::Ray as BvhRay;
use obvhs::rt_triangle::RtTriangle;
use obvhs::triangle::Triangle;

const ID: [f32; 12] = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];

fn translate(v: Vec3) -> [f32; 12] {
    affine_to_rows(&Affine3A::from_translation(v))
}

/// A 10 x 10 wall in the plane z = 0 (object space), centred on x/y = 0.
fn wall() -> LodTriangles {
    let mut m = LodTriangles::default();
    let p = |x: f32, y: f32| Vec3A::new(x, y, 0.0);
    m.triangles.push(Triangle {
        v0: p(-5.0, -5.0),
        v1: p(5.0, -5.0),
        v2: p(5.0, 5.0),
    });
    m.triangles.push(Triangle {
        v0: p(-5.0, -5.0),
        v1: p(5.0, 5.0),
        v2: p(-5.0, 5.0),
    });
    m.materials = vec![1, 1];
    m.alpha_tested = vec![false, false];
    m
}

/// Brute force: every triangle of every record, transformed exactly as the
/// TLAS does, alpha tested; returns (t, custom index).
fn brute_force(
    records: &[TlasInstance],
    geoms: &[(BvhBlasId, LodTriangles)],
    ray: &Ray,
) -> Option<(f32, u32)> {
    let mut best: Option<(f32, u32)> = None;
    for r in records {
        if r.acceleration_structure_reference == 0 || r.mask() & ray.mask() == 0 {
            continue;
        }
        let (_, g) = geoms
            .iter()
            .find(|(id, _)| id.reference() == r.acceleration_structure_reference)
            .unwrap();
        let w2o = rows_to_affine(&r.transform).inverse();
        let o = w2o.transform_point3a(ray.origin().into());
        let d = w2o.transform_vector3a(ray.direction().into());
        let local = BvhRay::new(o, d, ray.tmin(), ray.tmax());
        for (i, t) in g.triangles.iter().enumerate() {
            let tt = RtTriangle::from(t).intersect(&local);
            if tt.is_finite()
                && (!g.alpha_tested[i]
                    || r.flags() & VK_INSTANCE_FORCE_OPAQUE != 0
                    || leaf_opaque((o + d * tt).into()))
                && best.is_none_or(|b| tt < b.0)
            {
                best = Some((tt, r.custom_index()));
            }
        }
    }
    best
}

#[test]
fn two_level_tracer_matches_brute_force_on_random_scenes() {
    let mut rng = SplitMix64::new(42);
    let unit = mesh::unit();
    let tree = mesh::tree();
    let house = mesh::building(mesh::BuildingParams {
        width: 8.0,
        depth: 6.0,
        height: 9.0,
        tiers: 2,
        roof: mesh::Roof::Parapet,
    });
    let mut checked = 0;
    for scene in 0..6 {
        let mut store = BlasStore::new();
        let sources = [
            &unit.lods[0],
            &tree.lods[0],
            &tree.lods[1],
            &house.lods[0],
            &house.lods[1],
        ];
        let geoms: Vec<(BvhBlasId, LodTriangles)> = sources
            .iter()
            .map(|g| {
                (
                    store.build(g, BuildQuality::Good, false).unwrap(),
                    (*g).clone(),
                )
            })
            .collect();
        let mut records = Vec::new();
        for i in 0..40 {
            let (id, _) = &geoms[rng.below(geoms.len() as u32) as usize];
            let t = Affine3A::from_scale_rotation_translation(
                Vec3::new(
                    rng.range(0.5, 2.0),
                    rng.range(0.5, 2.0),
                    rng.range(0.5, 2.0),
                ),
                Quat::from_euler(
                    glam::EulerRot::YXZ,
                    rng.range(0.0, 6.3),
                    rng.range(-0.5, 0.5),
                    rng.range(-0.5, 0.5),
                ),
                Vec3::new(
                    rng.range(-30.0, 30.0),
                    rng.range(-5.0, 5.0),
                    rng.range(-30.0, 30.0),
                ),
            );
            let mask = [
                masks::GEOMETRY,
                masks::VEGETATION,
                masks::GEOMETRY | masks::VEGETATION,
            ][rng.below(3) as usize];
            let flags = if rng.below(5) == 0 {
                VK_INSTANCE_FORCE_OPAQUE
            } else {
                0
            };
            // A few inactive records, which must be skipped.
            let reference = if i % 13 == 5 { 0 } else { id.reference() };
            records.push(TlasInstance::new(
                affine_to_rows(&t),
                100 + i,
                mask,
                0,
                flags,
                reference,
            ));
        }
        let tlas = CpuTlas::build(&store, &records, &CountingBoxes::default()).unwrap();
        for _ in 0..600 {
            let origin = Vec3::new(
                rng.range(-45.0, 45.0),
                rng.range(-10.0, 25.0),
                rng.range(-45.0, 45.0),
            );
            let target = Vec3::new(
                rng.range(-25.0, 25.0),
                rng.range(-4.0, 8.0),
                rng.range(-25.0, 25.0),
            );
            let mask = [masks::ALL, masks::GEOMETRY, masks::VEGETATION][rng.below(3) as usize];
            let tmax = if rng.below(4) == 0 {
                rng.range(5.0, 40.0)
            } else {
                f32::INFINITY
            };
            let ray = Ray::new(origin, (target - origin).normalize(), 0.0, tmax, mask).unwrap();
            let got = trace(&tlas, &store, &ray, None);
            let want = brute_force(&records, &geoms, &ray);
            match (got.hit, want) {
                (None, None) => {}
                (Some(h), Some((t, ci))) => {
                    assert!(
                        (h.t - t).abs() <= 1e-4 * t.max(1.0),
                        "scene {scene}: t {} vs {t}",
                        h.t
                    );
                    if h.custom_index != ci {
                        // Only exact ties may pick a different instance.
                        assert!(
                            (h.t - t).abs() <= 1e-6 * t.max(1.0),
                            "scene {scene}: instance {} vs {ci}",
                            h.custom_index
                        );
                    }
                    assert!((h.normal.length() - 1.0).abs() < 1e-4);
                    checked += 1;
                }
                (g, w) => panic!("scene {scene}: tracer {g:?} vs brute force {w:?}"),
            }
            assert_eq!(
                occluded(&tlas, &store, &ray, None),
                want.is_some(),
                "any-hit agrees with closest hit"
            );
            assert!(got.counted_box.is_none());
        }
    }
    assert!(checked > 500, "too few hits to be meaningful: {checked}");
}

struct BoxScene {
    store: BlasStore,
    cfg: CountingBoxes,
    wall: BvhBlasId,
}

impl BoxScene {
    fn new() -> Self {
        let mut store = BlasStore::new();
        let wall = store.build(&wall(), BuildQuality::Good, false).unwrap();
        Self {
            store,
            cfg: CountingBoxes::default(),
            wall,
        }
    }
    fn wall_at(&self, z: f32, slot: u32) -> TlasInstance {
        TlasInstance::new(
            translate(Vec3::new(0.0, 0.0, z)),
            slot,
            masks::GEOMETRY,
            0,
            0,
            self.wall.reference(),
        )
    }
    fn counting_box(&self, min: Vec3, max: Vec3, index: u32, kind: BoxKind) -> TlasInstance {
        let sbt = if kind == BoxKind::Instance {
            self.cfg.instance_box_sbt
        } else {
            self.cfg.hitbox_box_sbt
        };
        TlasInstance::new(
            box_transform(&Aabb::new(min, max)),
            index,
            masks::COUNTING,
            sbt,
            0,
            self.store.unit_cube().reference(),
        )
    }
    fn tlas(&self, records: &[TlasInstance]) -> CpuTlas {
        CpuTlas::build(&self.store, records, &self.cfg).unwrap()
    }
}

fn z_ray(z0: f32, mask: u8) -> Ray {
    Ray::new(Vec3::new(0.3, 0.2, z0), Vec3::Z, 0.0, f32::INFINITY, mask).unwrap()
}

#[test]
fn a_box_before_the_hit_counts_and_passes_the_ray_through() {
    let s = BoxScene::new();
    let recs = [
        s.wall_at(20.0, 7),
        s.counting_box(Vec3::splat(-1.0), Vec3::splat(1.0), 3, BoxKind::Instance),
    ];
    let tlas = s.tlas(&recs);
    let r = trace(&tlas, &s.store, &z_ray(-10.0, masks::ALL), None);
    let h = r.hit.expect("the wall behind the box is hit");
    assert_eq!(h.custom_index, 7);
    assert!((h.t - 30.0).abs() < 1e-4);
    let b = r.counted_box.expect("box before the wall counts");
    assert_eq!((b.kind, b.custom_index), (BoxKind::Instance, 3));
    assert!((b.t - 9.0).abs() < 1e-4);
    let mut c = Counters::new(10, 10);
    c.count_box(&b);
    c.count_instance(h.custom_index);
    assert_eq!(
        (c.instances[3], c.instances[7], c.hitbox_total()),
        (1, 1, 0)
    );
    // Boxes never occlude shadow queries either.
    assert!(occluded(
        &tlas,
        &s.store,
        &Ray::new(Vec3::new(0.3, 0.2, -10.0), Vec3::Z, 0.0, 35.0, masks::ALL).unwrap(),
        None
    ));
    assert!(!occluded(
        &tlas,
        &s.store,
        &Ray::new(Vec3::new(0.3, 0.2, -10.0), Vec3::Z, 0.0, 15.0, masks::ALL).unwrap(),
        None
    ));
}

#[test]
fn a_box_behind_the_hit_does_not_count() {
    let s = BoxScene::new();
    let recs = [
        s.wall_at(0.0, 7),
        s.counting_box(
            Vec3::new(-1.0, -1.0, 5.0),
            Vec3::new(1.0, 1.0, 7.0),
            3,
            BoxKind::Hitbox,
        ),
    ];
    let r = trace(&s.tlas(&recs), &s.store, &z_ray(-10.0, masks::ALL), None);
    assert_eq!(r.hit.map(|h| h.custom_index), Some(7));
    assert_eq!(r.counted_box, None);
    // Without the wall the same ray counts it.
    let r = trace(
        &s.tlas(&recs[1..]),
        &s.store,
        &z_ray(-10.0, masks::ALL),
        None,
    );
    assert_eq!(r.hit, None);
    assert_eq!(
        r.counted_box.map(|b| (b.kind, b.custom_index)),
        Some((BoxKind::Hitbox, 3))
    );
}

#[test]
fn a_ray_counts_only_the_first_of_several_boxes() {
    let s = BoxScene::new();
    let recs = [
        s.counting_box(
            Vec3::new(-1.0, -1.0, 8.0),
            Vec3::new(1.0, 1.0, 9.0),
            2,
            BoxKind::Hitbox,
        ),
        s.counting_box(
            Vec3::new(-1.0, -1.0, 2.0),
            Vec3::new(1.0, 1.0, 3.0),
            1,
            BoxKind::Hitbox,
        ),
        s.counting_box(
            Vec3::new(-1.0, -1.0, 5.0),
            Vec3::new(1.0, 1.0, 6.0),
            0,
            BoxKind::Instance,
        ),
        s.wall_at(30.0, 9),
    ];
    let tlas = s.tlas(&recs);
    let r = trace(&tlas, &s.store, &z_ray(-10.0, masks::ALL), None);
    assert_eq!(
        r.counted_box.map(|b| (b.kind, b.custom_index)),
        Some((BoxKind::Hitbox, 1))
    );
    assert_eq!(r.hit.map(|h| h.custom_index), Some(9));
    // Starting between the boxes: the next one ahead counts.
    let r = trace(&tlas, &s.store, &z_ray(4.0, masks::ALL), None);
    assert_eq!(r.counted_box.map(|b| b.custom_index), Some(0));
    // Starting inside a box counts that box, entered at tmin.
    let r = trace(&tlas, &s.store, &z_ray(8.5, masks::ALL), None);
    let b = r.counted_box.unwrap();
    assert_eq!((b.custom_index, b.t), (2, 0.0));
}

#[test]
fn masks_select_instances_and_boxes() {
    let s = BoxScene::new();
    let recs = [
        s.counting_box(Vec3::splat(-1.0), Vec3::splat(1.0), 3, BoxKind::Hitbox),
        s.wall_at(20.0, 7),
    ];
    let tlas = s.tlas(&recs);
    // Counting bit cleared: boxes are invisible.
    let r = trace(&tlas, &s.store, &z_ray(-10.0, masks::GEOMETRY), None);
    assert_eq!(
        (r.counted_box, r.hit.map(|h| h.custom_index)),
        (None, Some(7))
    );
    // Only the counting bit: the wall is invisible.
    let r = trace(&tlas, &s.store, &z_ray(-10.0, masks::COUNTING), None);
    assert_eq!(r.hit, None);
    assert_eq!(r.counted_box.map(|b| b.custom_index), Some(3));
    // Vegetation-only ray misses everything here.
    let r = trace(&tlas, &s.store, &z_ray(-10.0, masks::VEGETATION), None);
    assert_eq!((r.hit, r.counted_box), (None, None));
    // A skip set hides an instance by custom index.
    let mut skip = lipac_sim::traversal::SlotSet::new();
    skip.insert(7);
    assert_eq!(
        trace(&tlas, &s.store, &z_ray(-10.0, masks::ALL), Some(&skip)).hit,
        None
    );
}

#[test]
fn alpha_tested_vegetation_lets_rays_through_holes() {
    let mut s = BoxScene::new();
    let tree = s
        .store
        .build(&mesh::tree().lods[2], BuildQuality::Good, false)
        .unwrap();
    let tree_rec =
        |flags: u8| TlasInstance::new(ID, 5, masks::VEGETATION, 0, flags, tree.reference());
    let back = TlasInstance::new(
        translate(Vec3::new(0.0, 5.0, 10.0)),
        7,
        masks::GEOMETRY,
        0,
        0,
        s.wall.reference(),
    );
    let alpha = s.tlas(&[tree_rec(0), back]);
    let opaque = s.tlas(&[tree_rec(VK_INSTANCE_FORCE_OPAQUE), back]);
    let (mut through, mut on_leaf, mut n) = (0, 0, 0);
    for i in 0..40 {
        for j in 0..40 {
            // Rays along +z through the crown region (x/y grid).
            let o = Vec3::new(
                -2.0 + 0.1 * i as f32 + 0.013,
                3.5 + 0.1 * j as f32 + 0.007,
                -10.0,
            );
            let ray = Ray::new(o, Vec3::Z, 0.0, f32::INFINITY, masks::ALL).unwrap();
            let a = trace(&alpha, &s.store, &ray, None).hit.unwrap();
            let b = trace(&opaque, &s.store, &ray, None).hit.unwrap();
            n += 1;
            if b.custom_index == 5 {
                if a.custom_index == 7 {
                    through += 1;
                    assert!(!leaf_opaque(o + Vec3::Z * b.t), "passed an opaque texel");
                } else {
                    on_leaf += 1;
                    assert!(leaf_opaque(o + Vec3::Z * a.t), "stopped on a hole");
                }
            }
        }
    }
    assert!(
        through > n / 10 && on_leaf > n / 10,
        "through {through}, leaf {on_leaf} of {n}"
    );
}

#[test]
fn bad_rays_are_rejected() {
    assert!(Ray::new(Vec3::NAN, Vec3::Z, 0.0, 1.0, 1).is_err());
    assert!(Ray::new(Vec3::ZERO, Vec3::ZERO, 0.0, 1.0, 1).is_err());
    assert!(Ray::new(Vec3::ZERO, Vec3::Z, 2.0, 1.0, 1).is_err());
    assert!(Ray::new(Vec3::ZERO, Vec3::Z, f32::NAN, 1.0, 1).is_err());
    assert!(Ray::new(Vec3::ZERO, Vec3::Z, 0.0, f32::INFINITY, 1).is_ok());
}

#[test]
fn counters_saturate_and_merge() {
    let mut a = Counters::new(2, 1);
    a.instances[0] = u32::MAX - 1;
    a.count_instance(0);
    a.count_instance(0);
    a.count_instance(9);
    assert_eq!((a.instances[0], a.dropped), (u32::MAX, 1));
    let mut b = Counters::new(3, 1);
    b.count_instance(0);
    b.count_instance(2);
    b.count_hitbox(0);
    a.merge(&b);
    assert_eq!(a.instances, vec![u32::MAX, 0, 1]);
    assert_eq!(a.hitboxes, vec![1]);
}
