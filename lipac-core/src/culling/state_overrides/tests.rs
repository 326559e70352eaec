use super::*;
use InstanceState::{Active, Inactive, Omitted};

#[test]
fn last_write_wins_removal_cancels_and_output_is_sorted() {
    let mut o = StateOverrides::default();
    o.insert(9, Inactive);
    o.insert(2, Inactive);
    o.insert(9, Active);
    o.insert(5, Omitted);
    o.remove(5);
    o.remove(40); // never written: nothing
    o.insert(7, Active);
    o.remove(7);
    o.insert(7, Inactive); // a new instance in the slot
    assert_eq!(o.take(), vec![(2, Inactive), (7, Inactive), (9, Active)]);
    assert_eq!(o.take(), vec![]);
    o.insert(5, Active);
    assert_eq!(o.take(), vec![(5, Active)]);
}

#[test]
fn churn_without_take_stays_bounded_by_the_slot_count() {
    let mut o = StateOverrides::default();
    for round in 0..1000u32 {
        for slot in 0..8 {
            o.insert(slot, Inactive);
            if round % 2 == 0 {
                o.remove(slot);
            }
        }
    }
    assert_eq!(o.slots.len(), 8);
    assert_eq!(o.take().len(), 8); // the last round kept its writes
}
