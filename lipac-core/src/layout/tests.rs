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
