use super::*;

#[test]
fn building_lods_decrease_and_lod2_is_a_box() {
    let m = building(BuildingParams {
        width: 20.0,
        depth: 14.0,
        height: 30.0,
        tiers: 2,
        roof: Roof::Parapet,
    });
    let n: Vec<usize> = m.lods.iter().map(LodTriangles::len).collect();
    assert!(n[0] > n[1] && n[1] > n[2], "{n:?}");
    assert_eq!(n[2], 12);
    // LOD 0 has window panes, LOD 1 none.
    assert!(m.lods[0].materials.contains(&material::WINDOW));
    assert!(!m.lods[1].materials.contains(&material::WINDOW));
    let b = m.bounds;
    assert!((b.max.y - 31.0).abs() < 1e-4 && (b.min.y + FOUNDATION_DEPTH).abs() < 1e-4);
    assert!((b.max.x - 10.0).abs() < 1e-4 && (b.min.z + 7.0).abs() < 1e-4);
    for l in &m.lods {
        assert_eq!(l.triangles.len(), l.materials.len());
        assert_eq!(l.triangles.len(), l.alpha_tested.len());
    }
}

#[test]
fn leaf_alpha_has_holes_inside_the_crown() {
    let mut opaque = 0;
    let n = 2000;
    for i in 0..n {
        let a = i as f32 * 0.0031;
        let p = CROWN_CENTER
            + Vec3::new(
                (a * 7.0).sin() * 1.5,
                (a * 3.0).cos() * 1.5,
                (a * 5.0).sin(),
            );
        opaque += leaf_opaque(p) as u32;
    }
    assert!(opaque > n / 4 && opaque < 3 * n / 4, "{opaque}");
}

#[test]
fn unit_deformation_keeps_order_and_stays_in_bounds() {
    let m = unit();
    let mut out = LodTriangles::default();
    for mesh in [unit(), character()] {
        for lod in &mesh.lods {
            for k in 0..16 {
                let phase = k as f32 * 0.4;
                deform_unit(lod, phase, &mut out);
                assert_eq!(out.len(), lod.len());
                let b = out.bounds();
                assert!(
                    b.min.cmpge(mesh.bounds.min).all() && b.max.cmple(mesh.bounds.max).all(),
                    "{b:?} {:?}",
                    mesh.bounds
                );
            }
        }
    }
    deform_unit(&m.lods[0], 1.0, &mut out);
    assert_ne!(
        out.triangles[30].v0, m.lods[0].triangles[30].v0,
        "a leg moved"
    );
    let bob = out.triangles[0].v0.y - m.lods[0].triangles[0].v0.y;
    assert!((bob - 0.03 * 1f32.sin()).abs() < 1e-5, "{bob}");
}

#[test]
fn library_rejects_unknown_ids() {
    let mut lib = MeshLibrary::new();
    let id = lib.add(tree());
    assert_eq!(lib.triangle_count(id, 0).unwrap(), 12 + 10);
    assert_eq!(lib.mesh(id + 1).unwrap_err(), SimError::UnknownMesh(id + 1));
    assert_eq!(lib.lod(id, 3).unwrap_err(), SimError::BadLod(3));
}

#[test]
fn the_character_walks_like_the_box_unit_with_more_triangles() {
    let c = character();
    let u = unit();
    assert_eq!(
        [c.lods[0].len(), c.lods[1].len(), c.lods[2].len()],
        [552, 120, 60]
    );
    for l in &c.lods {
        // Every triangle belongs to an animation part.
        assert_eq!(l.parts.len(), l.len());
        assert!(l.parts.iter().all(|&p| p <= 4));
        assert!((1..=4).all(|p| l.parts.contains(&p)));
    }
    // Same height and animation padding as the box unit.
    assert!((c.bounds.max.y - u.bounds.max.y).abs() < 0.06);
    assert!(c.bounds.min.x >= u.bounds.min.x - 1e-4 && c.bounds.max.x <= u.bounds.max.x + 1e-4);
    // Walking moves its legs and keeps the triangle order for refits.
    let mut a = LodTriangles::default();
    let mut b = LodTriangles::default();
    deform_unit(&c.lods[0], 0.0, &mut a);
    deform_unit(&c.lods[0], 1.2, &mut b);
    assert_eq!(a.len(), b.len());
    assert_eq!(a.parts, b.parts);
    assert_ne!(a.triangles[200].v0, b.triangles[200].v0);
    // Closed prisms: every edge is shared by two triangles.
    let mut edges = std::collections::HashMap::new();
    for t in &c.lods[1].triangles {
        for (p, q) in [(t.v0, t.v1), (t.v1, t.v2), (t.v2, t.v0)] {
            let key = |v: Vec3A| v.to_array().map(f32::to_bits);
            let (k0, k1) = (key(p), key(q));
            *edges
                .entry(if k0 < k1 { (k0, k1) } else { (k1, k0) })
                .or_insert(0) += 1;
        }
    }
    assert!(edges.values().all(|&n| n == 2));
}
