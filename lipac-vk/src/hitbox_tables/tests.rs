use super::*;

#[test]
fn runs_coalesce_sorted_distinct_indices_below_the_count() {
    assert_eq!(runs(vec![], 10), vec![]);
    assert_eq!(
        runs(vec![3, 1, 2, 2, 7, 9, 12], 10),
        vec![(1, 3), (7, 1), (9, 1)]
    );
    assert_eq!(runs((0..5).rev().collect(), 5), vec![(0, 5)]);
    assert_eq!(runs(vec![5, 6], 5), vec![]);
}
