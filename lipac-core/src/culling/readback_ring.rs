//! The CPU model of the GPU's read-back ring: [`Readback`] (one frame's
//! command words as the GPU left them) and [`ReadbackRing`] (they become
//! readable `latency` frames later). CPU backends and tests use it; a GPU
//! backend has its own ring of host-visible buffers with the same rule.

use std::collections::VecDeque;

use crate::error::CoreError;

#[cfg(doc)]
use super::Culling;

/// One frame's command words as the GPU left them: what a backend copies
/// into a read-back slot and hands to [`Culling::ingest_readback`] later.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Readback {
    /// The frame whose feedback wrote the commands.
    pub frame: u64,
    /// The GPU's atomic counter: commands requested, stored or not.
    pub counter: u32,
    /// The stored words (`min(counter, capacity)` of them).
    pub words: Vec<u32>,
}

/// A model of the GPU's read-back ring for CPU backends and tests: the
/// commands of frame `f` become readable at frame `f + latency`.
///
/// ```
/// use lipac_core::culling::{Readback, ReadbackRing};
/// let mut ring = ReadbackRing::new(2)?;
/// ring.push(Readback { frame: 5, counter: 1, words: vec![7] })?;
/// assert!(ring.pop_ready(6).is_none());
/// assert_eq!(ring.pop_ready(7).map(|r| r.words), Some(vec![7]));
/// # Ok::<(), lipac_core::error::CoreError>(())
/// ```
#[derive(Clone, Debug)]
pub struct ReadbackRing {
    latency: u32,
    slots: VecDeque<Readback>,
}

impl ReadbackRing {
    /// A ring of `latency` slots (at least 1).
    pub fn new(latency: u32) -> Result<Self, CoreError> {
        if latency == 0 {
            return Err(CoreError::InvalidConfig {
                what: "read-back ring latency 0: it must be at least 1 frame".into(),
            });
        }
        let mut slots = VecDeque::new();
        slots
            .try_reserve_exact(latency as usize)
            .map_err(|_| CoreError::OutOfMemory {
                what: "read-back ring slots",
                additional: latency as usize,
            })?;
        Ok(Self { latency, slots })
    }

    /// The latency in frames.
    pub fn latency(&self) -> u32 {
        self.latency
    }

    /// Stores a frame's read-back. Fails ([`CoreError::CallOrder`]) if all
    /// `latency` slots still hold unread read-backs (the GPU would overwrite
    /// one) or if `readback.frame` is not after the last stored frame.
    pub fn push(&mut self, readback: Readback) -> Result<(), CoreError> {
        if self.slots.len() >= self.latency as usize {
            return Err(CoreError::CallOrder {
                what: format!(
                    "read-back ring full: {} unread read-backs (pop_ready each frame)",
                    self.slots.len()
                ),
            });
        }
        if let Some(last) = self.slots.back() {
            if readback.frame <= last.frame {
                return Err(CoreError::CallOrder {
                    what: format!(
                        "read-back of frame {} after one of frame {}",
                        readback.frame, last.frame
                    ),
                });
            }
        }
        self.slots.push_back(readback);
        Ok(())
    }

    /// At frame `frame`: the oldest read-back written at or before
    /// `frame - latency`, if any. Call until `None`.
    pub fn pop_ready(&mut self, frame: u64) -> Option<Readback> {
        let ready = self
            .slots
            .front()?
            .frame
            .saturating_add(self.latency.into())
            <= frame;
        if ready {
            self.slots.pop_front()
        } else {
            None
        }
    }

    /// Read-backs waiting.
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    /// Whether nothing is waiting.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// The waiting read-backs, oldest first.
    pub fn iter(&self) -> impl Iterator<Item = &Readback> {
        self.slots.iter()
    }
}
