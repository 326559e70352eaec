use super::*;

fn good() -> TriangleGeometry {
    TriangleGeometry {
        vertex_address: 0x1000,
        vertex_stride: 12,
        vertex_count: 4,
        indices: Some((0x2000, IndexFormat::U16)),
        triangle_count: 2,
        opaque: true,
    }
}

#[test]
fn geometry_validation_rejects_bad_fields() {
    assert!(good().validate().is_ok());
    let bad = [
        TriangleGeometry {
            triangle_count: 0,
            ..good()
        },
        TriangleGeometry {
            vertex_count: 0,
            ..good()
        },
        TriangleGeometry {
            vertex_address: 0,
            ..good()
        },
        TriangleGeometry {
            vertex_address: 0x1002,
            ..good()
        },
        TriangleGeometry {
            vertex_stride: 8,
            ..good()
        },
        TriangleGeometry {
            vertex_stride: 14,
            ..good()
        },
        TriangleGeometry {
            indices: Some((0x2001, IndexFormat::U16)),
            ..good()
        },
        TriangleGeometry {
            indices: Some((0x2002, IndexFormat::U32)),
            ..good()
        },
        TriangleGeometry {
            indices: None,
            ..good()
        }, // 2 triangles need 6 vertices
    ];
    for g in bad {
        assert!(
            matches!(g.validate(), Err(VkError::InvalidArgument(_))),
            "{g:?}"
        );
    }
    let flat = TriangleGeometry {
        indices: None,
        vertex_count: 6,
        ..good()
    };
    assert!(flat.validate().is_ok());
}

#[test]
fn batch_push_rejects_empty_and_conflicting_flags() {
    let mut b = BlasBatch::new();
    assert!(b
        .push(&[], vk::BuildAccelerationStructureFlagsKHR::empty())
        .is_err());
    let both = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE
        | vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_BUILD;
    assert!(b.push(&[good()], both).is_err());
    assert_eq!(
        b.push(&[good()], vk::BuildAccelerationStructureFlagsKHR::empty())
            .unwrap(),
        0
    );
    assert_eq!(b.len(), 1);
}
