use super::*;

#[test]
fn coalesces_adjacent_and_merges_small_gaps() {
    let mut d = DirtySet::default();
    for i in [100, 0, 1, 2, 64, 63, 65, 103, 1] {
        d.mark(i);
    }
    assert_eq!(d.len(), 8);
    assert!(d.contains(63) && !d.contains(62) && !d.contains(10_000));
    let mut again = d.clone();
    assert_eq!(d.take(), vec![0..3, 63..66, 100..101, 103..104]);
    assert!(d.is_empty() && !d.contains(63));
    // Gaps of up to 2 clean records merge: 100..101 and 103..104 (gap 2).
    assert_eq!(again.take_merged(2), vec![0..3, 63..66, 100..104]);
    // Marking after a take starts afresh.
    d.mark(5);
    assert_eq!(d.take(), vec![5..6]);
}

#[test]
fn ignores_the_unrepresentable_index() {
    let mut d = DirtySet::default();
    d.mark(u32::MAX);
    assert!(d.is_empty());
}
