use super::*;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

struct Counted(Arc<AtomicUsize>);
impl Drop for Counted {
    fn drop(&mut self) {
        self.0.fetch_add(1, Ordering::SeqCst);
    }
}

#[test]
fn objects_drop_only_after_their_value() {
    let dropped = Arc::new(AtomicUsize::new(0));
    let mut r = Retirement::new();
    for v in [5u64, 2, 9, 2, 7] {
        r.retire(v, Counted(dropped.clone()));
    }
    r.retire_opt::<Counted>(1, None);
    assert_eq!(r.pending(), 5);
    assert_eq!(r.oldest_pending(), Some(2));
    assert_eq!(r.collect(1), 0);
    assert_eq!(dropped.load(Ordering::SeqCst), 0);
    assert_eq!(r.collect(2), 2);
    assert_eq!(dropped.load(Ordering::SeqCst), 2);
    assert_eq!(r.collect(6), 1);
    assert_eq!(r.oldest_pending(), Some(7));
    assert_eq!(r.collect(u64::MAX), 2);
    assert_eq!(dropped.load(Ordering::SeqCst), 5);
    assert_eq!((r.pending(), r.destroyed()), (0, 5));
    assert_eq!(r.collect(u64::MAX), 0);
}
