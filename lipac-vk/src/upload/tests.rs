use super::*;

#[test]
fn last_wins_keeps_the_last_override_per_key() {
    let pairs = [[5, 1], [2, 0], [5, 2], [9, 1], [2, 1], [5, 0]];
    assert_eq!(
        last_wins(pairs.into_iter(), 9),
        vec![[2, 1], [5, 0]],
        "key 9 is outside the capacity"
    );
}

#[test]
fn max_wins_keeps_the_largest_floor_per_key() {
    let pairs = [(5, 1), (2, 7), (5, 9), (9, 1), (2, 3), (5, 0)];
    assert_eq!(
        max_wins(&pairs, 9),
        vec![[2, 7], [5, 9]],
        "key 9 is outside the capacity"
    );
}

#[test]
fn staged_slots_are_distinct_and_clamped() {
    let records = InstanceArrays::from_records(&[InstanceRecord::default(); 10]);
    #[allow(clippy::reversed_empty_ranges)] // apply_uploads treats it as empty
    let reversed = 8..7;
    let uploads = Uploads {
        records: vec![6..12, 1..3, 2..4, reversed],
        ..Uploads::default()
    };
    let (slots, staged) = stage_records(&uploads, &records, 10).unwrap();
    assert_eq!(slots, vec![1, 2, 3, 6, 7, 8, 9]);
    assert_eq!(staged.len(), slots.len());
    // A range inside the CPU records but past the GPU buffer is refused.
    assert!(stage_records(&uploads, &records, 8).is_err());
}
