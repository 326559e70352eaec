//! The dense instance table against a `BTreeMap`.

use super::*;
use std::collections::BTreeMap;

/// Random inserts and removals agree with a `BTreeMap`.
#[test]
fn agrees_with_a_map() {
    let mut t = Instances::<u64>::default();
    let mut m = BTreeMap::new();
    let mut x = 0x9E37_79B9_7F4A_7C15u64;
    for step in 0..20_000u64 {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        let k = InstanceKey((x % 300) as u32);
        if x % 3 == 0 {
            assert_eq!(t.remove(&k), m.remove(&k));
        } else {
            t.insert(k, step);
            m.insert(k, step);
        }
        assert_eq!(t.len(), m.len());
        assert_eq!(t.get(&k), m.get(&k));
    }
    let mut all: Vec<(InstanceKey, u64)> = t.iter().map(|(&k, &v)| (k, v)).collect();
    all.sort_unstable();
    assert_eq!(all, m.into_iter().collect::<Vec<_>>());
    assert!(Instances::<u64>::in_range(InstanceKey(MAX_SLOTS - 1)));
    assert!(!Instances::<u64>::in_range(InstanceKey(MAX_SLOTS)));
}
