use super::*;

fn props(handle: u32, handle_align: u32, base_align: u32) -> RayTracingPipelineProperties {
    RayTracingPipelineProperties {
        handle_size: handle,
        handle_alignment: handle_align,
        base_alignment: base_align,
        max_stride: 4096,
        max_recursion_depth: 1,
    }
}

#[test]
fn lavapipe_like_layout() {
    // lavapipe: 32-byte handles, 16-byte handle alignment, 32-byte base.
    let l = SbtLayout::new(
        &props(32, 16, 32),
        &SbtRecords {
            miss: 1,
            hit: 6,
            hit_data: 4,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(
        l.raygen,
        SbtRegion {
            offset: 0,
            stride: 32,
            count: 1
        }
    );
    assert_eq!(
        l.miss,
        SbtRegion {
            offset: 32,
            stride: 32,
            count: 1
        }
    );
    assert_eq!(
        l.hit,
        SbtRegion {
            offset: 64,
            stride: 48,
            count: 6
        }
    );
    assert_eq!(l.callable.count, 0);
    assert_eq!(l.size(), 64 + 6 * 48);
    let r = l.device_regions(0x1000);
    assert_eq!(
        (r[2].device_address, r[2].stride, r[2].size),
        (0x1040, 48, 288)
    );
    assert_eq!((r[3].device_address, r[3].stride, r[3].size), (0, 0, 0));
    // The raygen region's size equals its stride.
    assert_eq!(r[0].size, r[0].stride);
}

#[test]
fn regions_start_at_the_base_alignment() {
    let l = SbtLayout::new(
        &props(32, 32, 64),
        &SbtRecords {
            miss: 3,
            hit: 1,
            callable: 2,
            miss_data: 40,
            ..Default::default()
        },
    )
    .unwrap();
    for r in [l.raygen, l.miss, l.hit, l.callable] {
        assert_eq!(r.offset % 64, 0, "{r:?}");
        assert_eq!(r.stride % 32, 0, "{r:?}");
    }
    assert_eq!(l.miss.stride, 96);
    assert_eq!(l.hit.offset, 64 + 3 * 96 + 32); // 352 rounded up to 384
    assert_eq!(l.base_offset(0x1010), 0x30);
    assert_eq!(l.base_offset(0x1040), 0);
    assert_eq!(l.allocation_size(16), l.size() + 48);
    assert_eq!(l.allocation_size(256), l.size());
}

#[test]
fn write_places_handles_and_data() {
    let l = SbtLayout::new(
        &props(8, 4, 16),
        &SbtRecords {
            miss: 1,
            hit: 2,
            hit_data: 4,
            ..Default::default()
        },
    )
    .unwrap();
    let handles: Vec<u8> = (0..4u8).flat_map(|g| [g; 8]).collect();
    let d0 = 7u32.to_le_bytes();
    let d1 = 9u32.to_le_bytes();
    let bytes = l
        .write(
            &handles,
            [&[(0, &[])], &[(1, &[])], &[(2, &d0), (3, &d1)], &[]],
        )
        .unwrap();
    assert_eq!(&bytes[0..8], &[0; 8]);
    assert_eq!(&bytes[16..24], &[1; 8]);
    assert_eq!(&bytes[32..40], &[2; 8]);
    assert_eq!(&bytes[40..44], &d0);
    assert_eq!(&bytes[44..52], &[3; 8]);
    assert_eq!(&bytes[52..56], &d1);
    // Wrong record counts, unknown groups and oversized data are refused.
    assert!(l.write(&handles, [&[(0, &[])], &[], &[], &[]]).is_err());
    assert!(l
        .write(
            &handles,
            [&[(9, &[])], &[(1, &[])], &[(2, &d0), (3, &d1)], &[]]
        )
        .is_err());
    let long = [0u8; 5];
    assert!(l
        .write(
            &handles,
            [&[(0, &[])], &[(1, &[])], &[(2, &long), (3, &d1)], &[]]
        )
        .is_err());
}

#[test]
fn bad_properties_and_strides_are_refused() {
    let recs = SbtRecords {
        miss: 1,
        hit: 1,
        ..Default::default()
    };
    assert!(SbtLayout::new(&props(32, 24, 64), &recs).is_err());
    assert!(SbtLayout::new(&props(0, 32, 64), &recs).is_err());
    let mut p = props(32, 32, 64);
    p.max_stride = 32;
    let big = SbtRecords {
        hit_data: 1,
        ..recs
    };
    assert!(SbtLayout::new(&p, &big).is_err());
    assert!(SbtLayout::new(&p, &recs).is_ok());
}
