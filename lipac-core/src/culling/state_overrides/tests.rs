use super::*;
use InstanceState::{Active, Inactive, Omitted};

#[test]
fn last_write_wins_removal_cancels_and_output_is_sorted() {
    let mut rows = vec![SlotRow::default(); 64];
    let rows = rows.as_mut_slice();
    let mut o = StateOverrides::default();
    o.insert(rows, 9, Inactive);
    o.insert(rows, 2, Inactive);
    o.insert(rows, 9, Active);
    o.insert(rows, 5, Omitted);
    o.remove(rows, 5);
    o.remove(rows, 40); // never written: nothing
    o.insert(rows, 7, Active);
    o.remove(rows, 7);
    o.insert(rows, 7, Inactive); // a new instance in the slot
    assert_eq!(
        o.take(rows),
        vec![(2, Inactive), (7, Inactive), (9, Active)]
    );
    assert_eq!(o.take(rows), vec![]);
    assert!(rows.iter().all(|r| r.view.state_override == 0));
    o.insert(rows, 5, Active);
    assert_eq!(o.take(rows), vec![(5, Active)]);
    // A slot without a row (none exists past the slot count) is ignored.
    o.insert(rows, 64, Active);
    assert_eq!(o.take(rows), vec![]);
}

#[test]
fn churn_without_take_stays_bounded_by_the_slot_count() {
    let mut rows = vec![SlotRow::default(); 8];
    let mut o = StateOverrides::default();
    for round in 0..1000u32 {
        for slot in 0..8 {
            o.insert(&mut rows, slot, Inactive);
            if round % 2 == 0 {
                o.remove(&mut rows, slot);
            }
        }
    }
    assert_eq!(o.slots.len(), 8);
    assert_eq!(o.take(&mut rows).len(), 8); // the last round kept its writes
}
