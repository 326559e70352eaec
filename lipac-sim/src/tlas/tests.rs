use super::*;
use crate::blas::box_transform;
use crate::mesh;
use glam::Vec3;
use lipac_core::math::Aabb;

const ID: [f32; 12] = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];

#[test]
fn bad_records_are_errors() {
    let mut store = BlasStore::new();
    let b = store
        .build(&mesh::unit().lods[2], BuildQuality::Fast, false)
        .unwrap();
    let c = CountingBoxes::default();
    let mut nan = ID;
    nan[3] = f32::NAN;
    let r = [
        TlasInstance::new(ID, 0, 1, 0, 0, b.reference()),
        TlasInstance::new(nan, 1, 1, 0, 0, b.reference()),
    ];
    assert_eq!(
        CpuTlas::build(&store, &r, &c).unwrap_err(),
        SimError::BadTransform { record: 1 }
    );
    let mut flat = ID;
    flat[5] = 0.0;
    let r = [TlasInstance::new(flat, 0, 1, 0, 0, b.reference())];
    assert_eq!(
        CpuTlas::build(&store, &r, &c).unwrap_err(),
        SimError::BadTransform { record: 0 }
    );
    let stale = b.reference();
    store.remove(b).unwrap();
    let r = [TlasInstance::new(ID, 0, 1, 0, 0, stale)];
    assert_eq!(
        CpuTlas::build(&store, &r, &c).unwrap_err(),
        SimError::UnknownBlasReference {
            record: 0,
            reference: stale
        }
    );
    let cube = store.unit_cube().reference();
    let r = [TlasInstance::new(ID, 0, 1, 0, 0, cube)];
    assert!(CpuTlas::build(&store, &r, &c).is_err());
}

#[test]
fn boxes_are_classified_by_sbt_and_mask_zero_dropped() {
    let store = BlasStore::new();
    let c = CountingBoxes::default();
    let cube = store.unit_cube().reference();
    let t = box_transform(&Aabb::new(Vec3::ZERO, Vec3::splat(2.0)));
    let r = [
        TlasInstance::new(t, 0, masks::COUNTING, c.instance_box_sbt, 0, cube),
        TlasInstance::new(t, 1, masks::COUNTING, c.hitbox_box_sbt, 0, cube),
        TlasInstance::new(t, 2, 0, c.hitbox_box_sbt, 0, cube),
    ];
    let tlas = CpuTlas::build(&store, &r, &c).unwrap();
    assert_eq!(
        (tlas.len(), tlas.box_count(), tlas.record_count()),
        (2, 2, 3)
    );
}
