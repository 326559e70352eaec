//! A synthetic backend for tests of the `Manager` and the `BuildScheduler`:
//! acceleration structures exist from the acknowledgement of their build
//! until the plan that frees them, at fresh addresses, and every plan is
//! checked against what exists.
//!
//! [`SyntheticDevice`] executes plans: it asserts that every free names a
//! live structure of the freed size not used by a frame still in flight,
//! that updates and compaction sources are live, and (for a
//! [`ManagerPlan`]) that data growth and uploads stay within the buffer; it
//! returns what the device then owes ([`Owed`]). The test decides when and
//! with which sizes that is acknowledged ([`SyntheticDevice::acknowledge`],
//! to a `Manager` or a `BuildScheduler` through [`AckSink`]);
//! [`AckQueue`] holds acknowledgements until the frame they arrive in;
//! [`LateAcks`] is a device whose acknowledgements arrive a few frames late.
//! [`ImmediateAcks`] is the simplest backend: every build done at its
//! estimated size, acknowledged as planned.
//!
//! ```
//! use lipac_test_support::synthetic::{Owed, SyntheticDevice};
//! use lipac_core::build_plan::FramePlan;
//!
//! let mut device = SyntheticDevice::new(2, 0);
//! let owed = device.execute_blas(&FramePlan::default());
//! assert!(owed.is_empty() && device.live.is_empty());
//! ```

use std::collections::HashMap;

use lipac_core::build_plan::{BuildScheduler, FramePlan};
use lipac_core::manager::{Ack, Manager, ManagerError, ManagerPlan};
use lipac_core::{BuildId, BuildPlanError, HitboxIndex};

use crate::Rng64;

/// Where acknowledgements go: a `Manager` ([`Manager::handle_ack`]) or a
/// bare `BuildScheduler` (`BuildScheduler::handle_ack`).
pub trait AckSink {
    /// The refusal.
    type Error: std::fmt::Debug;
    /// Hands over one acknowledgement.
    fn ack(&mut self, ack: Ack) -> Result<(), Self::Error>;
}

impl<H: HitboxIndex> AckSink for Manager<H> {
    type Error = ManagerError;
    fn ack(&mut self, ack: Ack) -> Result<(), ManagerError> {
        self.handle_ack(ack)
    }
}

impl AckSink for BuildScheduler {
    type Error = BuildPlanError;
    fn ack(&mut self, ack: Ack) -> Result<(), BuildPlanError> {
        self.handle_ack(ack)
    }
}

/// An acknowledgement the device owes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Owed {
    /// A build: `bytes` is the structure's size (the plan's estimate when
    /// [`SyntheticDevice::execute_blas`] hands it out; a test may change it).
    Built {
        /// The build.
        id: BuildId,
        /// The structure's size, bytes.
        bytes: u64,
        /// The plan allowed compaction (a compacted-size answer may follow).
        compactable: bool,
    },
    /// The compacted-size answer of build `id`.
    Size {
        /// The build.
        id: BuildId,
        /// The compacted size, bytes.
        bytes: u64,
    },
    /// A compaction copy.
    Compacted {
        /// The compaction.
        id: BuildId,
        /// The compacted structure's size, bytes.
        bytes: u64,
    },
}

impl Owed {
    /// The build or compaction it acknowledges.
    pub fn id(&self) -> BuildId {
        match *self {
            Owed::Built { id, .. } | Owed::Size { id, .. } | Owed::Compacted { id, .. } => id,
        }
    }
}

/// The device's acceleration structures and geometry-data buffer, checked
/// against every plan (panics with a message on a violation: it is for
/// tests).
#[derive(Clone, Debug, Default)]
pub struct SyntheticDevice {
    next_address: u64,
    /// Address → bytes of every acceleration structure that exists.
    pub live: HashMap<u64, u64>,
    /// Address → the last frame whose TLAS used it ([`SyntheticDevice::traced`]).
    pub last_used: HashMap<u64, u64>,
    /// Frames in flight: a structure used by frame `u` may be freed from
    /// frame `u + frames_in_flight` on.
    pub frames_in_flight: u64,
    /// Bytes of the geometry-data buffer (follows `ManagerPlan::data_growth`).
    pub data_capacity: u64,
    /// Builds handed out.
    pub builds: u64,
    /// Compactions handed out.
    pub compactions: u64,
    /// Structures freed.
    pub frees: u64,
}

impl SyntheticDevice {
    /// A device with nothing allocated, `frames_in_flight` frames in flight
    /// and a data buffer of `data_capacity` bytes (the manager's
    /// `DataConfig::initial_capacity`).
    pub fn new(frames_in_flight: u32, data_capacity: u64) -> Self {
        Self {
            frames_in_flight: frames_in_flight.into(),
            data_capacity,
            ..Self::default()
        }
    }

    /// The address the next structure created gets (addresses are never
    /// reused).
    pub fn next_address(&self) -> u64 {
        self.next_address + 0x100
    }

    /// Creates a structure of `bytes` at [`next_address`](Self::next_address).
    pub fn create(&mut self, bytes: u64) -> u64 {
        self.next_address += 0x100;
        self.live.insert(self.next_address, bytes);
        self.next_address
    }

    /// Records that frame `frame`'s TLAS references `address` (which must
    /// be live).
    pub fn traced(&mut self, address: u64, frame: u64) {
        assert!(self.live.contains_key(&address), "TLAS uses a dead BLAS");
        self.last_used.insert(address, frame);
    }

    /// Executes a manager's plan: data growth and uploads, then
    /// [`execute_blas`](Self::execute_blas).
    pub fn execute(&mut self, plan: &ManagerPlan) -> Vec<Owed> {
        if let Some(g) = plan.data_growth {
            assert_eq!(
                g.from, self.data_capacity,
                "growth from a capacity we never had"
            );
            assert!(g.to > g.from, "growth that shrinks");
            self.data_capacity = g.to;
        }
        for u in &plan.data_uploads {
            assert!(
                u.offset + u.bytes <= self.data_capacity,
                "upload past the buffer"
            );
        }
        self.execute_blas(&plan.blas)
    }

    /// Executes a BLAS plan: frees (of live structures of that size, none
    /// used by a frame in flight), updates of live structures, then hands
    /// out its builds (in batch order, at their estimated size) and its
    /// compactions (of live sources), in that order.
    pub fn execute_blas(&mut self, plan: &FramePlan) -> Vec<Owed> {
        let f = plan.frame;
        self.frees += plan.frees.len() as u64;
        for free in &plan.frees {
            assert_eq!(
                self.live.remove(&free.address),
                Some(free.bytes),
                "free of a dead or mis-sized structure"
            );
            if let Some(used) = self.last_used.remove(&free.address) {
                assert!(
                    used + self.frames_in_flight <= f,
                    "freed at {f}, used by frame {used}, {} in flight",
                    self.frames_in_flight
                );
            }
        }
        let mut owed = Vec::new();
        for b in &plan.batches {
            for u in &b.updates {
                assert!(self.live.contains_key(&u.address), "update of a dead BLAS");
            }
            for x in &b.builds {
                owed.push(Owed::Built {
                    id: x.id,
                    bytes: x.result_bytes,
                    compactable: x.allow_compaction,
                });
            }
        }
        for c in &plan.compactions {
            assert!(
                self.live.contains_key(&c.src_address),
                "compaction of a dead BLAS"
            );
            owed.push(Owed::Compacted {
                id: c.id,
                bytes: c.compacted_bytes,
            });
        }
        self.builds += plan.builds().count() as u64;
        self.compactions += plan.compactions.len() as u64;
        owed
    }

    /// Acknowledges `owed` to `sink`: a build or compaction creates its
    /// structure (of `bytes`) at [`next_address`](Self::next_address) if
    /// the sink accepts it; a size answer is passed on.
    pub fn acknowledge<S: AckSink + ?Sized>(
        &mut self,
        sink: &mut S,
        owed: Owed,
    ) -> Result<(), S::Error> {
        let address = self.next_address();
        match owed {
            Owed::Built { id, bytes, .. } => {
                sink.ack(Ack::Built {
                    build: id,
                    result_bytes: bytes,
                    address,
                })?;
                self.create(bytes);
            }
            Owed::Size { id, bytes } => sink.ack(Ack::CompactedSize {
                build: id,
                compacted_bytes: bytes,
            })?,
            Owed::Compacted { id, bytes } => {
                sink.ack(Ack::Compacted { op: id, address })?;
                self.create(bytes);
            }
        }
        Ok(())
    }
}

/// Acknowledgements on their way back, each with the frame it arrives in.
#[derive(Clone, Debug, Default)]
pub struct AckQueue {
    pending: Vec<(u64, Owed)>,
}

impl AckQueue {
    /// An empty queue.
    pub fn new() -> Self {
        Self::default()
    }
    /// `owed` arrives in frame `at` (or later, see [`take_due`](Self::take_due)).
    pub fn push(&mut self, at: u64, owed: Owed) {
        self.pending.push((at, owed));
    }
    /// Nothing on its way.
    pub fn is_empty(&self) -> bool {
        self.pending.is_empty()
    }
    /// Acknowledgements on their way.
    pub fn len(&self) -> usize {
        self.pending.len()
    }
    /// Removes and returns those due by `frame` for which `arrives()` says
    /// yes (asked once per due acknowledgement, in queue order; the rest
    /// stay for a later frame). The order of what remains is not kept.
    pub fn take_due(&mut self, frame: u64, mut arrives: impl FnMut() -> bool) -> Vec<Owed> {
        let mut due = Vec::new();
        let mut i = 0;
        while i < self.pending.len() {
            if self.pending[i].0 <= frame && arrives() {
                due.push(self.pending.swap_remove(i).1);
            } else {
                i += 1;
            }
        }
        due
    }
}

/// The synthetic device with acknowledgements arriving late, as from a GPU
/// with frames in flight: a build arrives `0..build_delay` frames after its
/// plan with 75–100 % of its estimated size, a compaction
/// `0..compaction_delay` frames after, a compacted size (half the build
/// plus one byte) 1–3 frames after its build; of the due ones each arrives
/// with probability 3/4 unless all are asked for.
#[derive(Clone, Debug)]
pub struct LateAcks {
    /// The structures.
    pub device: SyntheticDevice,
    /// What is on its way.
    pub queue: AckQueue,
    /// Builds arrive `0..build_delay` frames after their plan.
    pub build_delay: u64,
    /// Compactions arrive `0..compaction_delay` frames after their plan.
    pub compaction_delay: u64,
}

impl LateAcks {
    /// A device (see [`SyntheticDevice::new`]) with delays of up to 3
    /// frames.
    pub fn new(frames_in_flight: u32, data_capacity: u64) -> Self {
        Self {
            device: SyntheticDevice::new(frames_in_flight, data_capacity),
            queue: AckQueue::new(),
            build_delay: 4,
            compaction_delay: 4,
        }
    }

    /// Executes a manager's plan ([`SyntheticDevice::execute`]) and queues
    /// what it owes.
    pub fn execute<R: Rng64>(&mut self, plan: &ManagerPlan, rng: &mut R) {
        let owed = self.device.execute(plan);
        self.queue_owed(plan.frame, owed, rng);
    }

    /// Executes a BLAS plan ([`SyntheticDevice::execute_blas`]) and queues
    /// what it owes.
    pub fn execute_blas<R: Rng64>(&mut self, plan: &FramePlan, rng: &mut R) {
        let owed = self.device.execute_blas(plan);
        self.queue_owed(plan.frame, owed, rng);
    }

    fn queue_owed<R: Rng64>(&mut self, frame: u64, owed: Vec<Owed>, rng: &mut R) {
        for o in owed {
            let (at, o) = match o {
                Owed::Built {
                    id,
                    bytes,
                    compactable,
                } => {
                    let bytes = (bytes - rng.below(bytes / 4 + 1)).max(1);
                    let at = frame + rng.below(self.build_delay);
                    let built = Owed::Built {
                        id,
                        bytes,
                        compactable,
                    };
                    (at, built)
                }
                other => (frame + rng.below(self.compaction_delay), other),
            };
            self.queue.push(at, o);
        }
    }

    /// Delivers to `sink` what is due at `frame` (everything due if `all`),
    /// panicking on a refusal; a delivered compactable build queues its
    /// compacted size.
    pub fn deliver<S: AckSink + ?Sized, R: Rng64>(
        &mut self,
        sink: &mut S,
        frame: u64,
        rng: &mut R,
        all: bool,
    ) {
        for owed in self.queue.take_due(frame, || all || rng.below(4) != 0) {
            if let Err(e) = self.device.acknowledge(sink, owed) {
                panic!("{owed:?} refused: {e:?}");
            }
            if let Owed::Built {
                id,
                bytes,
                compactable: true,
            } = owed
            {
                let at = frame + 1 + rng.below(3);
                let size = Owed::Size {
                    id,
                    bytes: bytes / 2 + 1,
                };
                self.queue.push(at, size);
            }
        }
    }
}

/// The simplest backend: every build of a plan done at its estimated size
/// at a fresh address, acknowledged whenever the test hands the
/// acknowledgements over (usually at the next frame's start).
#[derive(Clone, Debug)]
pub struct ImmediateAcks {
    next_address: u64,
    step: u64,
}

impl ImmediateAcks {
    /// Addresses `step`, `2 * step`, … (`step > 0`).
    pub fn new(step: u64) -> Self {
        Self::after(0, step)
    }
    /// Addresses `base + step`, `base + 2 * step`, ….
    pub fn after(base: u64, step: u64) -> Self {
        Self {
            next_address: base,
            step,
        }
    }
    /// The acknowledgements of `plan`'s builds, in plan order.
    pub fn acks(&mut self, plan: &FramePlan) -> Vec<Ack> {
        plan.builds()
            .map(|b| {
                self.next_address += self.step;
                Ack::Built {
                    build: b.id,
                    result_bytes: b.result_bytes,
                    address: self.next_address,
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests;
