//! Commands from hit feedback processing (Algorithm 2) to the CPU, and the
//! one read-back rule ([`CommandQueue`]). Low-level: backends hand read-backs
//! to [`crate::Manager::ingest_readback`].
//!
//! On the GPU, Algorithm 2 appends one `u32` per state change that needs CPU
//! work (lines 17, 25, 31, 34) to a bounded readback buffer through an atomic
//! counter. [`CommandBuffer`] is the CPU mirror of that buffer, and
//! [`CommandQueue`] is what the CPU does with it after read-back: keep at most
//! one pending command per slot and hand them out by priority under a
//! per-frame budget.
//!
//! # Word layout
//!
//! ```text
//!  31            25 24 23                                             0
//! +----------------+--+-----------------------------------------------+
//! | priority (7 b) |K |                 slot (24 b)                   |
//! +----------------+--+-----------------------------------------------+
//! K = kind: 0 = add (build / ensure a BLAS), 1 = remove (free resources)
//! ```
//!
//! * **slot** (bits 0..24): the instance's GPU slot, below
//!   [`MAX_SLOTS`] = 2^24 (the TLAS custom index
//!   width).
//! * **kind** (bit 24): [`CommandKind`]. All 32 bits are in use; a future
//!   third kind would take bit 25 and shrink the priority to 6 bits
//!   (`floor(2·log2(hits + 1))` still fits), which is why decoding goes through
//!   [`Command::decode`] and never by hand.
//! * **priority** (bits 25..32): [`priority_from_hits`]`(hits)` =
//!   `min(127, floor(4·log2(hits + 1)))` of the hit count behind the
//!   transition, so the CPU can order work by hits without another buffer.
//!   Four steps per doubling; 24-bit hitbox counts reach at most 96.
//!
//! The quantisation is integer-exact (no `log2` in floating point), so a
//! shader following [`priority_from_hits`] produces the same words as this
//! reference.

use std::cmp::Reverse;
use std::collections::{BTreeSet, HashMap};
use std::fmt;

use crate::layout::MAX_SLOTS;

const SLOT_MASK: u32 = MAX_SLOTS - 1;
const KIND_SHIFT: u32 = 24;
const PRIORITY_SHIFT: u32 = 25;
/// Largest priority a command word holds (7 bits).
pub const PRIORITY_MAX: u8 = 127;

/// What the CPU has to do for an instance.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum CommandKind {
    /// The instance became active: make sure it has a BLAS (lines 25, 31).
    Add,
    /// The instance left the active state: its BLAS may be freed (lines 17, 34).
    Remove,
}

/// One decoded command.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Command {
    /// GPU slot of the instance (below [`MAX_SLOTS`]).
    pub slot: u32,
    /// Add or remove.
    pub kind: CommandKind,
    /// Quantised hit count, see [`priority_from_hits`] (0..=127).
    pub priority: u8,
}

/// A command word that does not describe a valid command.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum CommandError {
    /// The slot is at or above the limit (the queue's slot count or
    /// [`MAX_SLOTS`]).
    SlotOutOfRange {
        /// The decoded slot.
        slot: u32,
        /// The exclusive limit it was checked against.
        limit: u32,
    },
    /// A command was built with a slot that does not fit 24 bits or a
    /// priority above 127.
    FieldOutOfRange {
        /// The slot given.
        slot: u32,
        /// The priority given.
        priority: u8,
    },
}

impl fmt::Display for CommandError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::SlotOutOfRange { slot, limit } => {
                write!(f, "command slot {slot} out of range (limit {limit})")
            }
            Self::FieldOutOfRange { slot, priority } => write!(
                f,
                "command fields out of range: slot {slot} (max {}), priority {priority} (max {PRIORITY_MAX})",
                MAX_SLOTS - 1
            ),
        }
    }
}

impl std::error::Error for CommandError {}

/// `ceil(2^31 · 2^(j/4))` for j = 1, 2, 3: a mantissa normalised to
/// `[2^31, 2^32)` at or above `QUARTER_STEPS[j - 1]` has `log2` fraction ≥ j/4.
const QUARTER_STEPS: [u32; 3] = [2_553_802_834, 3_037_000_500, 3_611_622_603];

/// Quantises a hit count to a 7-bit priority: `min(127, floor(4·log2(hits + 1)))`.
///
/// Exact integer arithmetic, written so a shader can do the same with 32-bit
/// integers and get identical words: with `x = hits + 1`, `k = findMSB(x)`
/// and the mantissa `mn = x << (31 - k)`, the result is
/// `4k + (mn >= 2553802834) + (mn >= 3037000500) + (mn >= 3611622603)`
/// (the constants are `ceil(2^31 · 2^(j/4))`), clamped to 127; `hits =
/// 0xFFFFFFFF` (where `x` overflows) gives 127.
///
/// ```
/// use lipac_core::command::priority_from_hits;
/// assert_eq!(priority_from_hits(0), 0);
/// assert_eq!(priority_from_hits(1), 4); // 4·log2(2)
/// assert_eq!(priority_from_hits(15), 16); // 4·log2(16)
/// assert_eq!(priority_from_hits(u32::MAX), 127); // 4·32 = 128, clamped
/// ```
pub fn priority_from_hits(hits: u32) -> u8 {
    let Some(x) = hits.checked_add(1) else {
        return PRIORITY_MAX;
    };
    let k = 31 - x.leading_zeros();
    let mn = x << (31 - k);
    let q = QUARTER_STEPS.iter().filter(|&&t| mn >= t).count() as u32;
    (4 * k + q).min(u32::from(PRIORITY_MAX)) as u8
}

impl Command {
    /// A command, checking that `slot` fits 24 bits and `priority` 7 bits.
    pub fn new(slot: u32, kind: CommandKind, priority: u8) -> Result<Self, CommandError> {
        if slot >= MAX_SLOTS || priority > PRIORITY_MAX {
            return Err(CommandError::FieldOutOfRange { slot, priority });
        }
        Ok(Self {
            slot,
            kind,
            priority,
        })
    }

    /// Packs the command into its word (see the [module docs](self)). Fields
    /// out of range (only possible by building the struct by hand) are
    /// truncated to their widths.
    pub fn encode(self) -> u32 {
        let kind = match self.kind {
            CommandKind::Add => 0,
            CommandKind::Remove => 1,
        };
        (self.slot & SLOT_MASK)
            | (kind << KIND_SHIFT)
            | (u32::from(self.priority.min(PRIORITY_MAX)) << PRIORITY_SHIFT)
    }

    /// Unpacks a word. Every 32-bit word has a decoding; `slot_limit` (the
    /// number of GPU slots in use, at most [`MAX_SLOTS`]) rejects words naming
    /// slots that cannot hold an instance, which is how a corrupt or stale
    /// readback shows up.
    ///
    /// ```
    /// use lipac_core::command::{Command, CommandKind};
    /// let c = Command::new(42, CommandKind::Remove, 9).unwrap();
    /// assert_eq!(Command::decode(c.encode(), 100), Ok(c));
    /// assert!(Command::decode(c.encode(), 42).is_err());
    /// ```
    pub fn decode(word: u32, slot_limit: u32) -> Result<Self, CommandError> {
        let slot = word & SLOT_MASK;
        let limit = slot_limit.min(MAX_SLOTS);
        if slot >= limit {
            return Err(CommandError::SlotOutOfRange { slot, limit });
        }
        let kind = if (word >> KIND_SHIFT) & 1 == 0 {
            CommandKind::Add
        } else {
            CommandKind::Remove
        };
        Ok(Self {
            slot,
            kind,
            priority: (word >> PRIORITY_SHIFT) as u8,
        })
    }
}

/// CPU mirror of the GPU's bounded command buffer and its atomic counter.
///
/// The GPU does `i = atomicAdd(counter, 1); if (i < capacity) words[i] = cmd;`
/// so the counter may run past the capacity. [`CommandBuffer::requested`] is
/// that counter (saturating instead of wrapping), [`CommandBuffer::stored`]
/// the number of words actually written. A push that does not fit returns
/// `false`, and Algorithm 2 then leaves the instance's state unchanged so the
/// transition is retried next frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CommandBuffer {
    words: Vec<u32>,
    capacity: u32,
    requested: u32,
}

impl CommandBuffer {
    /// An empty buffer holding at most `capacity` commands, its words
    /// allocated up front where the memory can be had (else as commands
    /// come; [`CommandBuffer::try_new`] refuses instead).
    pub fn new(capacity: u32) -> Self {
        Self::try_new(capacity).unwrap_or(Self {
            words: Vec::new(),
            capacity,
            requested: 0,
        })
    }

    /// [`CommandBuffer::new`], an error
    /// ([`CoreError::OutOfMemory`](crate::error::CoreError::OutOfMemory))
    /// when the words for `capacity` commands cannot be had.
    pub fn try_new(capacity: u32) -> Result<Self, crate::error::CoreError> {
        let mut words = Vec::new();
        crate::memory::try_reserve_exact(&mut words, capacity as usize, "command words")?;
        Ok(Self {
            words,
            capacity,
            requested: 0,
        })
    }

    /// Heap bytes held (the word buffer's capacity).
    pub(crate) fn heap_bytes(&self) -> u64 {
        crate::memory::vec_bytes::<u32>(self.words.capacity())
    }

    /// Appends a command if there is room; returns whether it was stored.
    /// The request is counted either way.
    ///
    /// ```
    /// use lipac_core::command::{Command, CommandBuffer, CommandKind};
    /// let mut b = CommandBuffer::new(1);
    /// let c = Command::new(3, CommandKind::Add, 0).unwrap();
    /// assert!(b.push(c));
    /// assert!(!b.push(c));
    /// assert_eq!((b.stored(), b.requested(), b.overflowed()), (1, 2, 1));
    /// ```
    pub fn push(&mut self, command: Command) -> bool {
        self.requested = self.requested.saturating_add(1);
        if self.words.len() < self.capacity as usize {
            self.words.push(command.encode());
            true
        } else {
            false
        }
    }

    /// Whether no further command fits.
    pub fn is_full(&self) -> bool {
        self.words.len() >= self.capacity as usize
    }

    /// Maximum number of stored commands.
    pub fn capacity(&self) -> u32 {
        self.capacity
    }

    /// The counter: commands requested this frame, stored or not.
    pub fn requested(&self) -> u32 {
        self.requested
    }

    /// Commands stored (`min(requested, capacity)`).
    pub fn stored(&self) -> u32 {
        self.words.len() as u32
    }

    /// Requests that did not fit.
    pub fn overflowed(&self) -> u32 {
        self.requested - self.stored()
    }

    /// The stored words, in append order.
    pub fn words(&self) -> &[u32] {
        &self.words
    }

    /// Resets the counter for the next frame (the GPU clears its counter).
    pub fn clear(&mut self) {
        self.words.clear();
        self.requested = 0;
    }
}

/// What one ingest of a read-back did ([`CommandQueue::ingest`],
/// [`crate::culling::Culling::ingest_readback`],
/// [`crate::manager::Manager::ingest_readback`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct IngestSummary {
    /// Commands queued.
    pub accepted: u32,
    /// Words naming a slot at or beyond the slot limit (corrupt read-back),
    /// skipped.
    pub rejected: u32,
    /// Commands for slots holding no live instance (removed since), dropped.
    /// Always 0 for a bare [`CommandQueue`], which knows no instances.
    pub dead: u32,
    /// Commands that replaced a pending one of the opposite kind.
    pub replaced: u32,
    /// Commands that replaced a pending one of the same kind.
    pub superseded: u32,
    /// `counter - stored`: transitions that did not fit the GPU's buffer;
    /// their instances kept their state and will ask again.
    pub overflowed: u32,
}

/// The CPU's pending commands: at most one per slot, drained by priority.
///
/// The one read-back rule of lipac (CPU and GPU paths alike): a new command
/// for a slot that already has one pending **replaces** it, whatever its
/// kind (counted in [`IngestSummary::superseded`] for the same kind,
/// [`IngestSummary::replaced`] for the opposite one). The newest command
/// wins because processing reconciles the instance's BLAS with its *current*
/// state ([`crate::culling`]), so only "this slot needs a look" matters; the
/// kind and priority are the newest hints. (Cancelling opposite kinds
/// pairwise, as an earlier version did, loses that look when the CPU changed
/// the state or the BLAS in between, e.g. latency mitigation.)
///
/// ```
/// use lipac_core::command::{Command, CommandKind, CommandQueue};
/// let mut q = CommandQueue::new(1000);
/// let add = |slot, p| Command::new(slot, CommandKind::Add, p).unwrap().encode();
/// let stats = q.ingest(3, &[add(7, 5), add(8, 20), add(9, 20)]);
/// assert_eq!(stats.accepted, 3);
/// let remove = Command::new(7, CommandKind::Remove, 1).unwrap().encode();
/// assert_eq!(q.ingest(1, &[remove]).replaced, 1); // the newest stays pending
/// let first: Vec<u32> = q.drain(2).iter().map(|c| c.slot).collect();
/// assert_eq!(first, [8, 9]); // priority 20 first, ties by slot
/// assert_eq!(q.len(), 1); // slot 7 waits for the next frame
/// ```
#[derive(Clone, Debug, Default)]
pub struct CommandQueue {
    slot_limit: u32,
    by_slot: HashMap<u32, (CommandKind, u8)>,
    order: BTreeSet<(Reverse<u8>, u32)>,
}

impl CommandQueue {
    /// An empty queue accepting slots below `slot_limit` (clamped to
    /// [`MAX_SLOTS`]); pass the number of GPU slots the registry uses.
    pub fn new(slot_limit: u32) -> Self {
        Self {
            slot_limit: slot_limit.min(MAX_SLOTS),
            ..Self::default()
        }
    }

    /// Changes the accepted slot range (when the registry grows its slot
    /// buffer). Pending commands at or above the new limit are dropped.
    pub fn set_slot_limit(&mut self, slot_limit: u32) {
        self.slot_limit = slot_limit.min(MAX_SLOTS);
        let limit = self.slot_limit;
        let stale: Vec<u32> = self
            .by_slot
            .keys()
            .copied()
            .filter(|&s| s >= limit)
            .collect();
        for s in stale {
            self.cancel_slot(s);
        }
    }

    /// Ingests one read-back: `counter` is the GPU's atomic counter value and
    /// `words` the buffer's stored words (`words.len()` = its capacity or
    /// fewer). Words beyond `counter` are ignored; malformed words are counted
    /// and skipped, never a panic. Every slot below the limit counts as live.
    pub fn ingest(&mut self, counter: u32, words: &[u32]) -> IngestSummary {
        self.ingest_live(counter, words, self.slot_limit, |_| true)
    }

    /// [`CommandQueue::ingest`] against `slot_limit` (the registry's slot
    /// count) dropping commands for slots `live` says hold no instance. The
    /// one implementation of the read-back rule.
    pub(crate) fn ingest_live(
        &mut self,
        counter: u32,
        words: &[u32],
        slot_limit: u32,
        live: impl Fn(u32) -> bool,
    ) -> IngestSummary {
        let stored = (counter as usize).min(words.len());
        let mut s = IngestSummary {
            overflowed: counter.saturating_sub(stored as u32),
            ..IngestSummary::default()
        };
        let limit = slot_limit.min(self.slot_limit);
        for &w in &words[..stored] {
            let Ok(c) = Command::decode(w, limit) else {
                s.rejected += 1;
                continue;
            };
            if !live(c.slot) {
                s.dead += 1;
                continue;
            }
            s.accepted += 1;
            self.push(c, &mut s);
        }
        s
    }

    /// Ingests a [`CommandBuffer`] (the CPU reference's read-back).
    pub fn ingest_buffer(&mut self, buffer: &CommandBuffer) -> IngestSummary {
        self.ingest(buffer.requested(), buffer.words())
    }

    /// Queues `c`, replacing whatever is pending for its slot (the read-back
    /// rule, see [`CommandQueue`]).
    pub(crate) fn push(&mut self, c: Command, s: &mut IngestSummary) {
        if let Some((kind, prio)) = self.by_slot.insert(c.slot, (c.kind, c.priority)) {
            self.order.remove(&(Reverse(prio), c.slot));
            if kind == c.kind {
                s.superseded += 1;
            } else {
                s.replaced += 1;
            }
        }
        self.order.insert((Reverse(c.priority), c.slot));
    }

    /// Removes and returns up to `budget` commands, highest priority first,
    /// ties by ascending slot. The rest stay pending for later frames.
    pub fn drain(&mut self, budget: usize) -> Vec<Command> {
        let mut out = Vec::with_capacity(budget.min(self.order.len()));
        while out.len() < budget {
            let Some((Reverse(priority), slot)) = self.order.pop_first() else {
                break;
            };
            if let Some((kind, _)) = self.by_slot.remove(&slot) {
                out.push(Command {
                    slot,
                    kind,
                    priority,
                });
            }
        }
        out
    }

    /// Drops the pending command for `slot` (e.g. the instance was removed
    /// from the registry and its slot will be reused); returns it.
    pub fn cancel_slot(&mut self, slot: u32) -> Option<Command> {
        let (kind, priority) = self.by_slot.remove(&slot)?;
        self.order.remove(&(Reverse(priority), slot));
        Some(Command {
            slot,
            kind,
            priority,
        })
    }

    /// The pending command for `slot`, if any.
    pub fn pending(&self, slot: u32) -> Option<Command> {
        self.by_slot.get(&slot).map(|&(kind, priority)| Command {
            slot,
            kind,
            priority,
        })
    }

    /// Heap bytes held (estimated for the ordered set; see
    /// [`crate::memory`]).
    pub(crate) fn heap_bytes(&self) -> u64 {
        crate::memory::hash_map_bytes(&self.by_slot) + crate::memory::btree_set_bytes(&self.order)
    }

    /// Number of pending commands.
    pub fn len(&self) -> usize {
        self.by_slot.len()
    }

    /// Whether nothing is pending.
    pub fn is_empty(&self) -> bool {
        self.by_slot.is_empty()
    }
}

#[cfg(test)]
mod tests;
