use super::*;

#[test]
fn cube_triangles_face_outwards_and_cover_six_faces() {
    let v = |i: u32| glam::Vec3::from(UNIT_CUBE_VERTICES[i as usize]);
    let centre = glam::Vec3::splat(0.5);
    let mut area = 0.0;
    for t in UNIT_CUBE_INDICES.chunks(3) {
        let (a, b, c) = (v(t[0]), v(t[1]), v(t[2]));
        let n = (b - a).cross(c - a);
        area += n.length() / 2.0;
        let outward = (a + b + c) / 3.0 - centre;
        assert!(n.dot(outward) > 0.0, "triangle {t:?} faces inwards");
    }
    assert!((area - 6.0).abs() < 1e-6);
}

#[test]
fn box_instance_maps_cube_onto_aabb() {
    let cfg = CountingBoxConfig::default();
    let t = counting_box_instance(
        [1.0, 2.0, 3.0],
        [3.0, 6.0, 4.0],
        CountingBoxKind::Hitbox,
        7,
        &cfg,
        0x1000,
    )
    .unwrap();
    assert_eq!(t.custom_index(), 7);
    assert_eq!(t.sbt_offset(), 2);
    assert_eq!(t.mask(), 0x80);
    let m = lipac_core::math::rows_to_affine(&t.transform);
    assert!(
        (m.transform_point3(glam::Vec3::ZERO) - glam::Vec3::new(1.0, 2.0, 3.0)).length() < 1e-6
    );
    assert!((m.transform_point3(glam::Vec3::ONE) - glam::Vec3::new(3.0, 6.0, 4.0)).length() < 1e-6);
    assert!(counting_box_instance(
        [0.0; 3],
        [f32::NAN, 1.0, 1.0],
        CountingBoxKind::Hitbox,
        0,
        &cfg,
        1
    )
    .is_err());
    assert!(
        counting_box_instance([1.0; 3], [0.0; 3], CountingBoxKind::Hitbox, 0, &cfg, 1).is_err()
    );
    assert!(counting_box_instance(
        [0.0; 3],
        [1.0; 3],
        CountingBoxKind::Hitbox,
        1 << 24,
        &cfg,
        1
    )
    .is_err());
}
