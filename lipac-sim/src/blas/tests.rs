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

#[test]
fn refit_many_equals_refits_one_by_one_and_refuses_bad_batches() {
    let rest = mesh::unit().lods[0].clone();
    let phases = [0.1f32, 0.7, 1.9, 3.0];
    let mut serial = BlasStore::new();
    let mut batch = BlasStore::new();
    let ids: Vec<BvhBlasId> = phases
        .iter()
        .map(|_| serial.build(&rest, BuildQuality::Fast, true).unwrap())
        .collect();
    let ids_b: Vec<BvhBlasId> = phases
        .iter()
        .map(|_| batch.build(&rest, BuildQuality::Fast, true).unwrap())
        .collect();
    assert_eq!(ids, ids_b);
    let mut g = LodTriangles::default();
    for (id, &p) in ids.iter().zip(&phases) {
        mesh::deform_unit(&rest, p, &mut g);
        serial.refit(*id, &g).unwrap();
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .unwrap();
    pool.install(|| {
        batch.refit_many(&ids, |i, out| {
            mesh::deform_unit(&rest, phases[i], out);
            Ok(())
        })
    })
    .unwrap();
    assert_eq!(serial.stats(), batch.stats());
    for id in &ids {
        let (a, b) = (serial.get(*id).unwrap(), batch.get(*id).unwrap());
        assert_eq!(a.bvh.nodes, b.bvh.nodes);
        assert!(a.tris == b.tris);
        assert_eq!(a.prim, b.prim);
        assert_eq!(a.bounds, b.bounds);
    }
    // A repeated or stale id, or a failed geometry, is an error.
    let twice = [ids[0], ids[0]];
    assert!(batch
        .refit_many(&twice, |_, out| {
            out.clone_from(&rest);
            Ok(())
        })
        .is_err());
    batch.remove(ids[1]).unwrap();
    assert_eq!(
        batch.refit_many(&ids[1..2], |_, out| {
            out.clone_from(&rest);
            Ok(())
        }),
        Err(SimError::StaleBlas)
    );
    let failed = batch.refit_many(&[ids[2], ids[3]], |i, out| {
        out.clone_from(&rest);
        if i == 1 {
            out.triangles.pop();
        }
        Ok(())
    });
    assert!(matches!(failed, Err(SimError::RefitCountMismatch { .. })));
}
