use super::*;

#[test]
fn words_are_two_64_bit_sums() {
    let s = sample_of([5, 0, 7, 0]);
    assert_eq!((s.box_hits, s.total_hits), (5, 12));
    let s = sample_of([1, 2, u32::MAX, 1]);
    assert_eq!(s.box_hits, (2 << 32) | 1);
    assert_eq!(
        s.total_hits,
        (2 << 32) + 1 + (1 << 32) + u64::from(u32::MAX)
    );
    assert_eq!(sample_of([u32::MAX; 4]).total_hits, u64::MAX);
}
