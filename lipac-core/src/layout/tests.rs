use super::*;

#[test]
fn tlas_instance_bitfields_round_trip() {
    let t = TlasInstance::new([0.0; 12], 0x12_3456, 0xAB, 0x65_4321, 0x05, 42);
    assert_eq!(t.custom_index(), 0x12_3456);
    assert_eq!(t.mask(), 0xAB);
    assert_eq!(t.sbt_offset(), 0x65_4321);
    assert_eq!(t.flags(), 0x05);
    let bytes = bytemuck::bytes_of(&t);
    // VkAccelerationStructureInstanceKHR: custom index in the low 24 bits of byte 48..52.
    assert_eq!(&bytes[48..52], &[0x56, 0x34, 0x12, 0xAB]);
    assert_eq!(&bytes[52..56], &[0x21, 0x43, 0x65, 0x05]);
    assert_eq!(&bytes[56..64], &42u64.to_le_bytes());
}

#[test]
fn tlas_multiset_is_order_free_and_bit_exact() {
    let t = TlasInstance::new([0.5; 12], 7, 0xFF, 1, 0x04, 0x1234_5678_9ABC_DEF0);
    let bits = t.to_bits();
    assert_eq!(bits[0], 0.5f32.to_bits());
    assert_eq!(bits[12], t.custom_index_and_mask);
    assert_eq!(bits[13], t.sbt_offset_and_flags);
    assert_eq!((bits[14], bits[15]), (0x9ABC_DEF0, 0x1234_5678));
    let mut u = t;
    u.transform[5] = 1.0;
    assert_eq!(tlas_multiset(&[t, u, t]), tlas_multiset(&[u, t, t]));
    assert_ne!(tlas_multiset(&[t, u]), tlas_multiset(&[t, t]));
    // Bit-exact: -0.0 is not 0.0 (PartialEq on f32 would say equal).
    let (mut zero, mut negative) = (t, t);
    zero.transform[3] = 0.0;
    negative.transform[3] = -0.0;
    assert_eq!(zero, negative);
    assert_ne!(tlas_multiset(&[zero]), tlas_multiset(&[negative]));
    // Every field takes part: only the BLAS reference's high word differs.
    let mut far = t;
    far.acceleration_structure_reference ^= 1 << 40;
    assert_ne!(tlas_multiset(&[t]), tlas_multiset(&[far]));
}

#[test]
fn hitbox_hits_saturate() {
    let mut h = HitboxRecord {
        packed: hitbox_bits::ACTIVE | (3 << 1),
        ..Default::default()
    };
    h.add_hits(hitbox_bits::HITS_MAX - 1);
    h.add_hits(10);
    assert_eq!(h.hits(), hitbox_bits::HITS_MAX);
    assert!(h.is_active());
    assert_eq!(h.streak(), 3);
}

#[test]
fn instance_state_bits() {
    let mut r = InstanceRecord {
        packed: instance_bits::ALIVE | (0x81 << 8),
        ..Default::default()
    };
    r.set_state(InstanceState::Omitted);
    assert_eq!(r.state(), InstanceState::Omitted);
    assert!(r.is_alive());
    assert_eq!(r.mask(), 0x81);
    r.set_state(InstanceState::Active);
    assert_eq!(r.state(), InstanceState::Active);
}

#[test]
fn instance_arrays_split_join_and_keep_has_blas_with_the_address() {
    let rec = InstanceRecord {
        transform: [1.5; 12],
        aabb_min: [1.0, -2.0, 3.0],
        hitbox: 7,
        aabb_max: [4.0, 5.0, 6.0],
        // A stale HAS_BLAS bit: the arrays take it from the address.
        packed: instance_bits::ALIVE | instance_bits::HAS_BLAS | (0xAB << 8) | 2,
        blas: 0,
        sbt_offset: 9,
        lod: 2,
    };
    let mut a = InstanceArrays::from_records(&[InstanceRecord::default(), rec]);
    assert_eq!(a.len(), 2);
    assert!(!a.hot()[1].has_blas());
    assert_eq!(a.hot()[1].hitbox, 7);
    assert_eq!(a.hot()[1].mask(), 0xAB);
    assert_eq!(a.hot()[1].state(), InstanceState::Active);
    assert_eq!(a.bounds()[1].aabb_min, rec.aabb_min);
    // The slot's TLAS record, ready to copy: custom index = slot, the
    // packed mask and flags, the SBT offset and the address.
    let t = a.tlas()[1].record;
    assert_eq!(
        (t.custom_index(), t.mask(), t.sbt_offset(), t.flags()),
        (1, 0xAB, 9, 0)
    );
    assert_eq!(
        (t.transform, t.acceleration_structure_reference),
        (rec.transform, 0)
    );
    let joined = a.get(1).unwrap();
    assert_eq!(joined.packed, rec.packed & !instance_bits::HAS_BLAS);
    assert_eq!(
        (joined.transform, joined.sbt_offset, joined.lod),
        (rec.transform, 9, 2)
    );
    assert_eq!(a.set_blas(1, 0x1000), Some(0));
    assert!(a.hot()[1].has_blas() && a.get(1).unwrap().blas == 0x1000);
    assert_eq!(a.tlas()[1].record.acceleration_structure_reference, 0x1000);
    assert_eq!(
        a.set_state(1, InstanceState::Omitted),
        Some(InstanceState::Active)
    );
    assert_eq!(a.set_hitbox(1, 3), Some(7));
    assert_eq!(a.iter().len(), 2);
    assert_eq!(a.to_vec()[1], a.get(1).unwrap());
    assert_eq!(a.take(1).unwrap().blas, 0x1000);
    assert_eq!(a.get(1), Some(InstanceRecord::default()));
    // Past the end: nothing changes, nothing panics.
    assert_eq!(a.get(2), None);
    assert!(!a.set(2, &rec));
    assert_eq!(
        (a.set_blas(5, 1), a.set_state(5, InstanceState::Active)),
        (None, None)
    );
    a.resize(4);
    assert_eq!(a.len(), 4);
    // Grown slots are all zero (a GPU buffer grows with a fill); a written
    // one, dead or not, holds its slot.
    assert_eq!(a.tlas()[3], InstanceTlas::default());
    assert!(a.set(3, &InstanceRecord::default()));
    assert_eq!(a.tlas()[3].record.custom_index(), 3);
    assert!(a.set(2, &InstanceRecord::default())); // every slot written: the join round-trips
    assert!(a.capacity() >= 4 && a.heap_bytes() >= 4 * INSTANCE_SLOT_BYTES);
    assert_eq!(
        InstanceArrays::from_parts(vec![InstanceHot::default()], vec![], vec![]),
        None
    );
    let collected: InstanceArrays = a.iter().collect();
    assert_eq!(collected, a);
}

#[test]
fn instance_tlas_and_bounds_have_the_glsl_offsets() {
    // lipac_layout.glsl's LipacInstanceTlas (= LipacTlasInstance, std430
    // stride 64) and LipacInstanceBounds (stride 28).
    let t = InstanceRecord {
        transform: [0.5; 12],
        packed: (0x12 << instance_bits::MASK_SHIFT) | (0x34 << instance_bits::VK_FLAGS_SHIFT),
        blas: 0x0102_0304_0506_0708,
        sbt_offset: 0xAAAA,
        ..Default::default()
    }
    .tlas(0x65_4321);
    let w: &[u32] = bytemuck::cast_slice(bytemuck::bytes_of(&t));
    assert_eq!(w.len(), 16);
    assert_eq!(f32::from_bits(w[11]), 0.5);
    assert_eq!(w[12], 0x1265_4321);
    assert_eq!(w[13], 0x3400_AAAA);
    assert_eq!((w[14], w[15]), (0x0506_0708, 0x0102_0304));
    let b = InstanceBounds {
        aabb_min: [1.0, 2.0, 3.0],
        aabb_max: [4.0, 5.0, 6.0],
        lod: 0xBBBB,
    };
    let w: &[u32] = bytemuck::cast_slice(bytemuck::bytes_of(&b));
    assert_eq!(w.len(), 7);
    assert_eq!(f32::from_bits(w[0]), 1.0);
    assert_eq!(f32::from_bits(w[5]), 6.0);
    assert_eq!(w[6], 0xBBBB);
    let h = InstanceHot {
        hitbox: 5,
        packed: 6,
    };
    assert_eq!(bytemuck::cast::<_, [u32; 2]>(h), [5, 6]);
    assert_eq!(INSTANCE_SLOT_BYTES, 100);
}
