use super::*;

#[test]
fn flags_algebra_and_bits() {
    let f = InstanceFlags::UNIQUE_BLAS | InstanceFlags::STATIC;
    assert!(f.contains(InstanceFlags::STATIC));
    assert!(!f.contains(InstanceFlags::VEGETATION));
    assert_eq!(f.bits(), instance_bits::UNIQUE_BLAS | instance_bits::STATIC);
    assert_eq!(!f, InstanceFlags::VEGETATION | InstanceFlags::PINNED);
    assert_eq!(InstanceFlags::PINNED.bits(), 1 << 6);
    assert_eq!(
        format!("{:?}", InstanceFlags::STATIC | InstanceFlags::PINNED),
        "InstanceFlags(STATIC | PINNED)"
    );
    assert_eq!(InstanceFlags::from_bits(1), None);
    assert_eq!(InstanceFlags::from_bits_truncate(f.bits() | 1), f);
    let mut g = f;
    g.remove(InstanceFlags::UNIQUE_BLAS);
    assert_eq!(g, InstanceFlags::STATIC);
    assert_eq!(format!("{f:?}"), "InstanceFlags(UNIQUE_BLAS | STATIC)");
    assert_eq!(
        format!("{:?}", InstanceFlags::empty()),
        "InstanceFlags(empty)"
    );
}
