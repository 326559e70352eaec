//! The hindsight reference: what perfect memory of past hits buys.
//!
//! [`Hindsight`] traces every instance the ground-truth paths hit in any of
//! the last `k` frames (not this one), and the pinned ones (terrain), as
//! LiPaC and the [`super::Oracle`] do. It knows more than any strategy an
//! engine can run (the exact hits of every instance, culled or not, which
//! only tracing the full scene gives) but only of the past, as LiPaC does:
//! its memory and error at each window `k` say what an ideal causal
//! predictor driven by per-instance hits could reach, and so where a goal
//! asks for more than that (docs/EVALUATION.md, "Hindsight: what past hits
//! allow"). Like the oracle it is a reference, never on a sweep's fronts.

use super::{ground_truth_hits, FrameContext, SetStrategy, Strategy, StrategyFrame};
use crate::error::SimError;
use crate::memory::MemoryModel;
use crate::scene::Scene;
use crate::traversal::Counters;
use lipac_core::layout::TlasInstance;

/// Every instance the ground truth hit in the last [`Hindsight::frames`]
/// frames, plus the pinned ones ([module docs](self)).
#[derive(Debug)]
pub struct Hindsight {
    set: SetStrategy,
    frames: u32,
    /// Per slot, the last frame whose ground-truth paths hit it.
    last_hit: Vec<Option<u32>>,
}

impl Hindsight {
    /// The window `lipac compare --strategies hindsight` uses.
    pub const DEFAULT_FRAMES: u32 = 8;

    /// For the instances of `scene`, remembering `frames` past frames'
    /// hits (at least 1: with none it would trace only the pinned ones);
    /// the built-in memory model.
    pub fn new(scene: &Scene, frames: u32) -> Result<Self, SimError> {
        Self::with_memory(scene, frames, &MemoryModel::default())
    }

    /// As [`Hindsight::new`], its BLASes sized by `memory`.
    pub fn with_memory(scene: &Scene, frames: u32, memory: &MemoryModel) -> Result<Self, SimError> {
        if frames == 0 {
            return Err(SimError::BadConfig(
                "hindsight needs a window of at least one frame",
            ));
        }
        Ok(Self {
            set: SetStrategy::new(scene, memory)?,
            frames,
            last_hit: vec![None; scene.instances().len()],
        })
    }

    /// The window: how many past frames' hits it keeps.
    pub fn frames(&self) -> u32 {
        self.frames
    }
}

impl Strategy for Hindsight {
    fn name(&self) -> &str {
        "hindsight"
    }

    fn frame(
        &mut self,
        ctx: &FrameContext<'_>,
        _previous: Option<&Counters>,
        out: &mut Vec<TlasInstance>,
    ) -> Result<StrategyFrame, SimError> {
        let hits = ground_truth_hits(ctx)?;
        if self.last_hit.len() != hits.len() {
            return Err(SimError::SizeMismatch {
                a: self.last_hit.len(),
                b: hits.len(),
            });
        }
        let (now, window, last_hit) = (ctx.frame, self.frames, &self.last_hit);
        // Hit in one of the frames now-window .. now-1 (frames only rise; a
        // frame number at or past `now` would be a replay gone back, never
        // counted as the past).
        let recent = |f: u32| f < now && now - f <= window;
        let result = self.set.run_selected(ctx, out, |slot, inst| {
            inst.is_pinned() || last_hit[slot].is_some_and(recent)
        })?;
        // This frame's hits become the past only now.
        for (last, &h) in self.last_hit.iter_mut().zip(hits) {
            if h > 0 {
                *last = Some(now);
            }
        }
        Ok(result)
    }
}
