use super::*;
use proptest::prelude::*;

/// `min(127, floor(log2(x^4)))` in u128, x = hits + 1.
fn oracle(hits: u32) -> u8 {
    let x = u128::from(hits) + 1;
    match x.checked_mul(x).and_then(|x2| x2.checked_mul(x2)) {
        Some(x4) => (127 - x4.leading_zeros()).min(127) as u8,
        None => 127,
    }
}

fn cmd(slot: u32, kind: CommandKind, priority: u8) -> Command {
    Command::new(slot, kind, priority).unwrap()
}

proptest! {
    #[test]
    fn encode_decode_round_trip(slot in 0..MAX_SLOTS, remove: bool, priority in 0u8..=PRIORITY_MAX) {
        let kind = if remove { CommandKind::Remove } else { CommandKind::Add };
        let c = cmd(slot, kind, priority);
        prop_assert_eq!(Command::decode(c.encode(), MAX_SLOTS), Ok(c));
    }

    #[test]
    fn every_word_decodes_or_errors_without_panic(word: u32, limit: u32) {
        match Command::decode(word, limit) {
            Ok(c) => {
                prop_assert!(c.slot < limit);
                prop_assert_eq!(c.encode(), word);
            }
            Err(CommandError::SlotOutOfRange { slot, .. }) => prop_assert!(slot >= limit.min(MAX_SLOTS)),
            Err(e) => prop_assert!(false, "unexpected {e}"),
        }
    }

    #[test]
    fn priority_matches_exact_oracle(hits in 0u32..=u32::MAX, near_pow in 0u32..32, delta in 0u32..8) {
        prop_assert_eq!(priority_from_hits(hits), oracle(hits));
        // Also right at the quarter-power boundaries of every octave.
        for t in QUARTER_STEPS {
            let b = ((u64::from(t) << near_pow) >> 31).saturating_sub(1 + u64::from(delta)) as u32;
            for h in b.saturating_sub(2)..=b.saturating_add(2) {
                prop_assert_eq!(priority_from_hits(h), oracle(h), "hits {}", h);
            }
        }
    }

    #[test]
    fn priority_is_monotonic_and_matches_float(hits in 0u32..=u32::MAX) {
        let p = priority_from_hits(hits);
        prop_assert!(priority_from_hits(hits.saturating_add(1)) >= p);
        let f = (4.0 * (f64::from(hits) + 1.0).log2()).floor().min(127.0) as u8;
        // f64 log2 may be off by one step exactly at a boundary.
        prop_assert!(p.abs_diff(f) <= 1, "hits {} exact {} float {}", hits, p, f);
    }
}

#[test]
fn priority_exact_values() {
    // floor(4·log2(x)): x = 2 -> 4, x = 3 -> floor(6.34) = 6, x = 4 -> 8.
    assert_eq!(priority_from_hits(1), 4);
    assert_eq!(priority_from_hits(2), 6);
    assert_eq!(priority_from_hits(3), 8);
    // 2^24 hits (a saturated hitbox) -> 96.
    assert_eq!(priority_from_hits((1 << 24) - 1), 96);
    // x = hits + 1 = 2^k gives exactly 4k; one less falls just below it.
    assert_eq!(priority_from_hits((1 << 31) - 1), 124);
    assert_eq!(priority_from_hits((1 << 31) - 2), 123);
}

#[test]
fn new_rejects_wide_fields() {
    assert!(Command::new(MAX_SLOTS, CommandKind::Add, 0).is_err());
    assert!(Command::new(0, CommandKind::Add, 128).is_err());
}

#[test]
fn buffer_counts_past_capacity() {
    let mut b = CommandBuffer::new(2);
    for s in 0..5 {
        let fitted = b.push(cmd(s, CommandKind::Add, 0));
        assert_eq!(fitted, s < 2);
    }
    assert_eq!((b.stored(), b.requested(), b.overflowed()), (2, 5, 3));
    assert!(b.is_full());
    b.clear();
    assert_eq!((b.stored(), b.requested()), (0, 0));
    assert!(b.push(cmd(9, CommandKind::Remove, 3)));
}

#[test]
fn queue_keeps_the_newest_command_per_slot() {
    let mut q = CommandQueue::new(100);
    let s = q.ingest(
        2,
        &[
            cmd(1, CommandKind::Add, 3).encode(),
            cmd(1, CommandKind::Add, 9).encode(),
        ],
    );
    assert_eq!((s.accepted, s.superseded, s.replaced), (2, 1, 0));
    assert_eq!(q.len(), 1);
    assert_eq!(q.pending(1), Some(cmd(1, CommandKind::Add, 9)));

    // Add then remove: the remove is pending (the slot still needs a
    // look: reconciliation decides against the current state).
    let s = q.ingest(1, &[cmd(1, CommandKind::Remove, 0).encode()]);
    assert_eq!((s.replaced, s.superseded), (1, 0));
    assert_eq!(q.drain(10), vec![cmd(1, CommandKind::Remove, 0)]);
    assert!(q.is_empty());

    // Remove then add: the add, with its priority, in the order set once.
    q.ingest(1, &[cmd(2, CommandKind::Remove, 1).encode()]);
    q.ingest(1, &[cmd(2, CommandKind::Add, 5).encode()]);
    assert_eq!(q.len(), 1);
    assert_eq!(q.drain(10), vec![cmd(2, CommandKind::Add, 5)]);

    // Add, remove, add in one read-back: one add pending, never two.
    let w = [
        cmd(3, CommandKind::Add, 1).encode(),
        cmd(3, CommandKind::Remove, 1).encode(),
        cmd(3, CommandKind::Add, 2).encode(),
    ];
    q.ingest(3, &w);
    assert_eq!(q.drain(10), vec![cmd(3, CommandKind::Add, 2)]);
}

#[test]
fn queue_drains_by_priority_then_slot_and_keeps_the_rest() {
    let mut q = CommandQueue::new(100);
    let words: Vec<u32> = [(5, 1), (6, 50), (7, 50), (2, 10), (9, 0)]
        .iter()
        .map(|&(s, p)| cmd(s, CommandKind::Add, p).encode())
        .collect();
    q.ingest(words.len() as u32, &words);
    let slots = |v: Vec<Command>| v.iter().map(|c| c.slot).collect::<Vec<_>>();
    assert_eq!(slots(q.drain(3)), [6, 7, 2]);
    assert_eq!(q.len(), 2);
    // Undrained ones stay; a new higher-priority one goes first next frame.
    q.ingest(1, &[cmd(40, CommandKind::Remove, 3).encode()]);
    assert_eq!(slots(q.drain(2)), [40, 5]);
    assert_eq!(slots(q.drain(2)), [9]);
    assert!(q.is_empty());
}

#[test]
fn queue_rejects_bad_words_and_honours_counter() {
    let mut q = CommandQueue::new(10);
    let words = [
        cmd(3, CommandKind::Add, 0).encode(),
        cmd(10, CommandKind::Add, 0).encode(),
        0xFFFF_FFFF,
    ];
    let s = q.ingest(7, &words);
    assert_eq!((s.accepted, s.rejected, s.overflowed), (1, 2, 4));
    // Counter below the word count: the tail is stale and ignored.
    let mut q = CommandQueue::new(10);
    let s = q.ingest(
        1,
        &[
            cmd(1, CommandKind::Add, 0).encode(),
            cmd(2, CommandKind::Add, 0).encode(),
        ],
    );
    assert_eq!(s.accepted, 1);
    assert!(q.pending(2).is_none());
}

#[test]
fn cancel_slot_and_shrinking_limit_drop_pending() {
    let mut q = CommandQueue::new(100);
    q.ingest(
        2,
        &[
            cmd(4, CommandKind::Add, 7).encode(),
            cmd(60, CommandKind::Remove, 1).encode(),
        ],
    );
    assert_eq!(q.cancel_slot(4), Some(cmd(4, CommandKind::Add, 7)));
    assert_eq!(q.cancel_slot(4), None);
    q.set_slot_limit(50);
    assert!(q.is_empty());
    assert!(q.drain(5).is_empty());
}
