use super::*;
use crate::mesh;
use obvhs::triangle::Triangle;

#[test]
fn references_round_trip_and_zero_is_inactive() {
    assert_eq!(BvhBlasId::from_reference(0), None);
    let id = BvhBlasId {
        index: 5,
        generation: 3,
    };
    assert_eq!(BvhBlasId::from_reference(id.reference()), Some(id));
    assert_ne!(id.reference(), 0);
}

#[test]
fn stale_handles_are_errors_after_reuse() {
    let mut s = BlasStore::new();
    let g = mesh::unit().lods[2].clone();
    let a = s.build(&g, BuildQuality::Fast, false).unwrap();
    s.remove(a).unwrap();
    let b = s.build(&g, BuildQuality::Fast, false).unwrap();
    assert_eq!(a.index(), b.index());
    assert_eq!(s.get(a).unwrap_err(), SimError::StaleBlas);
    assert!(s.get(b).is_ok());
    assert!(s.remove(s.unit_cube()).is_err());
    assert_eq!(s.stats().builds, 2);
    assert_eq!(s.stats().primitives_built, 24);
}

#[test]
fn refit_checks_counts_and_tracks_moved_vertices() {
    let mut s = BlasStore::new();
    let rest = mesh::unit().lods[0].clone();
    let id = s.build(&rest, BuildQuality::Fast, true).unwrap();
    let mut moved = rest.clone();
    for t in &mut moved.triangles {
        t.v0 += Vec3A::new(0.0, 5.0, 0.0);
        t.v1 += Vec3A::new(0.0, 5.0, 0.0);
        t.v2 += Vec3A::new(0.0, 5.0, 0.0);
    }
    s.refit(id, &moved).unwrap();
    let b = s.get(id).unwrap().bounds();
    assert!((b.min.y - 5.0).abs() < 1e-5);
    // Root node bounds of the CWBVH follow too.
    assert!(s.get(id).unwrap().bvh.nodes[0].p.y >= 4.99);
    assert_eq!(s.stats().refits, 1);
    assert_eq!(s.stats().primitives_refit, rest.len() as u64);
    let mut fewer = moved.clone();
    fewer.triangles.pop();
    assert_eq!(
        s.refit(id, &fewer).unwrap_err(),
        SimError::RefitCountMismatch {
            expected: rest.len(),
            got: rest.len() - 1
        }
    );
    let shared = s.build(&rest, BuildQuality::Fast, false).unwrap();
    assert!(s.refit(shared, &moved).is_err());
}

#[test]
fn non_finite_geometry_is_rejected() {
    let mut g = LodTriangles::default();
    g.triangles.push(Triangle {
        v0: Vec3A::ZERO,
        v1: Vec3A::X,
        v2: Vec3A::new(f32::NAN, 0.0, 0.0),
    });
    g.materials.push(0);
    g.alpha_tested.push(false);
    let mut s = BlasStore::new();
    assert_eq!(
        s.build(&g, BuildQuality::Fast, false).unwrap_err(),
        SimError::NonFinite("triangle vertices")
    );
}
