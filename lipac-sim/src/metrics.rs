//! Per-frame metrics of a strategy and their summary.
//!
//! * **Instances in the TLAS**: records traced (real instances plus counting
//!   boxes).
//! * **Memory**: modelled BLAS and TLAS bytes ([`crate::memory`]) plus
//!   LiPaC's own buffers.
//! * **BLAS work**: builds (new and periodic rebuilds), refits, primitives.
//! * **State changes**: instances entering or leaving the TLAS as real
//!   geometry. A **cycle** is an instance re-entering within
//!   [`CYCLE_WINDOW`] frames of leaving (active → inactive → active).
//! * **Latency**: for every instance the ground-truth paths hit, frames from
//!   the first frame they hit it to the first frame (from then on) it is in
//!   the strategy's TLAS as real geometry; instances never in it by the end
//!   are counted as `never_active` instead.
//! * **Needed but missing**: instances the ground-truth paths hit this frame
//!   that the strategy's TLAS lacks.
//! * **Error**: relative RMSE of the indirect light against the ground truth.

use serde::{Deserialize, Serialize};

use crate::strategy::{BlasWork, StrategyFrame};

/// Frames within which leaving and re-entering the TLAS counts as a cycle.
pub const CYCLE_WINDOW: u32 = 30;

/// One strategy, one frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FrameMetrics {
    /// Frame number.
    pub frame: u32,
    /// TLAS records traced (real instances plus counting boxes).
    pub tlas_instances: u64,
    /// Of those, counting boxes.
    pub counting_boxes: u64,
    /// Modelled BLAS bytes held.
    pub blas_bytes: u64,
    /// Modelled TLAS bytes.
    pub tlas_bytes: u64,
    /// LiPaC's hitbox records and hit counters, bytes.
    pub overhead_bytes: u64,
    /// BLAS builds (new and rebuilds).
    pub builds: u64,
    /// BLAS refits.
    pub refits: u64,
    /// Triangles built.
    pub primitives_built: u64,
    /// Triangles refit.
    pub primitives_refit: u64,
    /// Instances entering or leaving the TLAS as real geometry.
    pub state_changes: u64,
    /// Of the entries, re-entries within [`CYCLE_WINDOW`] frames.
    pub cycles: u64,
    /// Latency samples completed this frame.
    pub latency_samples: u64,
    /// Sum of those latencies, frames.
    pub latency_sum: u64,
    /// Instances hit by this frame's ground-truth paths missing from the TLAS.
    pub needed_missing: u64,
    /// Relative RMSE of the indirect light against the ground truth.
    pub error: f64,
    /// CPU time (summed over threads) of the bounce and shadow rays traced
    /// against the strategy's TLAS, ms. Primary hits and the rasterized-shadow
    /// fallback stand in for rasterization, which every strategy pays alike,
    /// and are excluded (see `pathtrace::FrameOutput::traced_ns`).
    pub trace_ms: f64,
    /// Wall time of its TLAS build, ms.
    pub tlas_build_ms: f64,
    /// Wall time of the strategy's own frame logic, ms.
    pub strategy_ms: f64,
    /// LiPaC: escape fraction of the hits the Manager counted this frame
    /// (those of the previous frame's trace; [`lipac_core::controller`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub escape_fraction: Option<f64>,
    /// LiPaC: the scale on the thresholds (1 without a closed-loop target).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub threshold_scale: Option<f64>,
    /// LiPaC: the bytes a memory budget holds, as the Manager accounts them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub controlled_bytes: Option<u64>,
    /// LiPaC with a closed-loop target: the target (bytes or fraction).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub control_target: Option<f64>,
    /// LiPaC with a target: the controller reports it unreachable.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub control_unreachable: bool,
}

impl FrameMetrics {
    /// BLAS + TLAS + overhead bytes.
    pub fn total_bytes(&self) -> u64 {
        self.blas_bytes + self.tlas_bytes + self.overhead_bytes
    }
    /// The same metrics with the wall-clock timings zeroed (for
    /// determinism checks).
    pub fn without_timings(&self) -> Self {
        Self {
            trace_ms: 0.0,
            tlas_build_ms: 0.0,
            strategy_ms: 0.0,
            ..self.clone()
        }
    }
}

/// Summary of one strategy over a run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Strategy name.
    pub strategy: String,
    /// Frames.
    pub frames: u32,
    /// Mean TLAS records.
    pub mean_instances: f64,
    /// Peak TLAS records.
    pub peak_instances: u64,
    /// Mean total memory, MiB.
    pub mean_mib: f64,
    /// Peak total memory, MiB.
    pub peak_mib: f64,
    /// Mean BLAS memory, MiB.
    pub mean_blas_mib: f64,
    /// Total builds.
    pub builds: u64,
    /// Total refits.
    pub refits: u64,
    /// Total triangles built.
    pub primitives_built: u64,
    /// Total triangles refit.
    pub primitives_refit: u64,
    /// Total state changes.
    pub state_changes: u64,
    /// Total cycles.
    pub cycles: u64,
    /// Mean latency over completed samples, frames (0 without samples).
    pub mean_latency: f64,
    /// 95th percentile latency, frames.
    pub p95_latency: u32,
    /// Latency samples.
    pub latency_samples: u64,
    /// Needed instances never in the TLAS by the end.
    pub never_active: u64,
    /// Mean needed-but-missing instances per frame.
    pub mean_needed_missing: f64,
    /// Mean error.
    pub mean_error: f64,
    /// Largest error of a frame.
    pub max_error: f64,
    /// Mean trace time, ms.
    pub mean_trace_ms: f64,
    /// Mean TLAS build time, ms.
    pub mean_tlas_build_ms: f64,
    /// Mean strategy logic time, ms.
    pub mean_strategy_ms: f64,
}

const MIB: f64 = 1024.0 * 1024.0;

/// Tracks TLAS membership over frames: state changes, cycles, latency.
#[derive(Clone, Debug, Default)]
pub struct Tracker {
    in_tlas: Vec<bool>,
    now: Vec<bool>,
    last_exit: Vec<Option<u32>>,
    /// First frame the ground truth hit the instance while it was missing
    /// (an open latency sample); `Some(u32::MAX)` once sampled.
    need: Vec<Option<u32>>,
    latencies: Vec<u32>,
}

const SAMPLED: u32 = u32::MAX;

impl Tracker {
    /// For `instances` instances.
    pub fn new(instances: usize) -> Self {
        Self {
            in_tlas: vec![false; instances],
            now: vec![false; instances],
            last_exit: vec![None; instances],
            need: vec![None; instances],
            latencies: Vec::new(),
        }
    }

    /// Records frame `frame`: `geometry` are the custom indices of the real
    /// instances in the TLAS, `needed` the ground truth's hits per slot.
    /// Fills the membership fields of `m`.
    pub fn observe(
        &mut self,
        frame: u32,
        geometry: impl Iterator<Item = u32>,
        needed: &[u32],
        m: &mut FrameMetrics,
    ) {
        self.now.iter_mut().for_each(|v| *v = false);
        for s in geometry {
            if let Some(v) = self.now.get_mut(s as usize) {
                *v = true;
            }
        }
        for i in 0..self.now.len() {
            let (was, is) = (self.in_tlas[i], self.now[i]);
            if was != is {
                m.state_changes += 1;
                if is {
                    if self.last_exit[i].is_some_and(|e| frame - e <= CYCLE_WINDOW) {
                        m.cycles += 1;
                    }
                } else {
                    self.last_exit[i] = Some(frame);
                }
            }
            let hit = needed.get(i).is_some_and(|&h| h > 0);
            if hit && !is {
                m.needed_missing += 1;
            }
            match self.need[i] {
                None if hit => {
                    if is {
                        self.sample(0, m);
                        self.need[i] = Some(SAMPLED);
                    } else {
                        self.need[i] = Some(frame);
                    }
                }
                Some(f0) if f0 != SAMPLED && is => {
                    self.sample(frame - f0, m);
                    self.need[i] = Some(SAMPLED);
                }
                _ => {}
            }
        }
        std::mem::swap(&mut self.in_tlas, &mut self.now);
    }

    fn sample(&mut self, latency: u32, m: &mut FrameMetrics) {
        self.latencies.push(latency);
        m.latency_samples += 1;
        m.latency_sum += u64::from(latency);
    }

    /// Grows to `instances` slots (new slots start empty; never shrinks).
    pub fn resize(&mut self, instances: usize) {
        if instances > self.in_tlas.len() {
            self.in_tlas.resize(instances, false);
            self.now.resize(instances, false);
            self.last_exit.resize(instances, None);
            self.need.resize(instances, None);
        }
    }

    /// Forgets slot `slot` (its instance was removed and the slot now holds
    /// a new one): not in the TLAS, no open latency sample, no exit.
    pub fn reset(&mut self, slot: u32) {
        let i = slot as usize;
        if i < self.in_tlas.len() {
            self.in_tlas[i] = false;
            self.last_exit[i] = None;
            self.need[i] = None;
        }
    }

    /// Capacity of the per-slot tables, in elements (latency samples not
    /// counted).
    pub fn capacity(&self) -> usize {
        self.in_tlas.capacity()
            + self.now.capacity()
            + self.last_exit.capacity()
            + self.need.capacity()
    }

    /// All latency samples so far.
    pub fn latencies(&self) -> &[u32] {
        &self.latencies
    }

    /// Needed instances whose latency sample is still open.
    pub fn never_active(&self) -> u64 {
        self.need
            .iter()
            .filter(|n| matches!(n, Some(f) if *f != SAMPLED))
            .count() as u64
    }
}

/// Fills the strategy-reported fields of `m`.
pub fn apply_strategy_frame(m: &mut FrameMetrics, f: &StrategyFrame) {
    let BlasWork {
        builds,
        refits,
        primitives_built,
        primitives_refit,
        ..
    } = f.work;
    m.builds = builds;
    m.refits = refits;
    m.primitives_built = primitives_built;
    m.primitives_refit = primitives_refit;
    m.blas_bytes = f.blas_bytes;
    m.overhead_bytes = f.overhead_bytes;
    if let Some(c) = f.control {
        m.escape_fraction = c.escape_fraction;
        m.threshold_scale = Some(c.threshold_scale);
        m.controlled_bytes = Some(c.controlled_bytes);
        m.control_target = c.target;
        m.control_unreachable = c.unreachable;
    }
}

/// Nearest-rank percentile `p` (0..=100) of `v` (0 for none).
///
/// ```
/// use lipac_sim::metrics::percentile;
/// assert_eq!(percentile(&[5, 1, 3, 2, 4], 95.0), 5);
/// assert_eq!(percentile(&[5, 1, 3, 2, 4], 50.0), 3);
/// assert_eq!(percentile(&[], 95.0), 0);
/// ```
pub fn percentile(v: &[u32], p: f64) -> u32 {
    if v.is_empty() {
        return 0;
    }
    let mut s = v.to_vec();
    s.sort_unstable();
    let rank = ((p / 100.0) * s.len() as f64).ceil().max(1.0) as usize;
    s[rank.min(s.len()) - 1]
}

/// Summarises a strategy's frames.
pub fn summarize(strategy: &str, frames: &[FrameMetrics], tracker: &Tracker) -> Summary {
    let n = frames.len().max(1) as f64;
    let mean = |f: &dyn Fn(&FrameMetrics) -> f64| frames.iter().map(f).sum::<f64>() / n;
    let lat = tracker.latencies();
    Summary {
        strategy: strategy.to_string(),
        frames: frames.len() as u32,
        mean_instances: mean(&|m| m.tlas_instances as f64),
        peak_instances: frames.iter().map(|m| m.tlas_instances).max().unwrap_or(0),
        mean_mib: mean(&|m| m.total_bytes() as f64 / MIB),
        peak_mib: frames
            .iter()
            .map(|m| m.total_bytes() as f64 / MIB)
            .fold(0.0, f64::max),
        mean_blas_mib: mean(&|m| m.blas_bytes as f64 / MIB),
        builds: frames.iter().map(|m| m.builds).sum(),
        refits: frames.iter().map(|m| m.refits).sum(),
        primitives_built: frames.iter().map(|m| m.primitives_built).sum(),
        primitives_refit: frames.iter().map(|m| m.primitives_refit).sum(),
        state_changes: frames.iter().map(|m| m.state_changes).sum(),
        cycles: frames.iter().map(|m| m.cycles).sum(),
        mean_latency: if lat.is_empty() {
            0.0
        } else {
            lat.iter().map(|&l| f64::from(l)).sum::<f64>() / lat.len() as f64
        },
        p95_latency: percentile(lat, 95.0),
        latency_samples: lat.len() as u64,
        never_active: tracker.never_active(),
        mean_needed_missing: mean(&|m| m.needed_missing as f64),
        mean_error: mean(&|m| m.error),
        max_error: frames.iter().map(|m| m.error).fold(0.0, f64::max),
        mean_trace_ms: mean(&|m| m.trace_ms),
        mean_tlas_build_ms: mean(&|m| m.tlas_build_ms),
        mean_strategy_ms: mean(&|m| m.strategy_ms),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cycles_and_latency_follow_membership() {
        let mut t = Tracker::new(3);
        let mut frames = Vec::new();
        // Slot 0: needed from frame 0, enters at frame 2 (latency 2), leaves
        // at 3, re-enters at 5 (a cycle). Slot 1: needed and present at
        // frame 1 (latency 0). Slot 2: needed at 4, never present.
        let present: [&[u32]; 6] = [&[], &[1], &[0, 1], &[1], &[1], &[0, 1]];
        let needed: [[u32; 3]; 6] = [
            [1, 0, 0],
            [0, 1, 0],
            [0, 0, 0],
            [0, 0, 0],
            [0, 0, 5],
            [0; 3],
        ];
        for f in 0..6u32 {
            let mut m = FrameMetrics {
                frame: f,
                ..Default::default()
            };
            t.observe(
                f,
                present[f as usize].iter().copied(),
                &needed[f as usize],
                &mut m,
            );
            frames.push(m);
        }
        assert_eq!(t.latencies(), &[0, 2]);
        assert_eq!(t.never_active(), 1);
        assert_eq!(frames.iter().map(|m| m.cycles).sum::<u64>(), 1);
        // Changes: f1 +1, f2 +0, f3 -0, f5 +0.
        assert_eq!(frames.iter().map(|m| m.state_changes).sum::<u64>(), 4);
        assert_eq!(frames[0].needed_missing, 1);
        assert_eq!(frames[4].needed_missing, 1);
        let s = summarize("x", &frames, &t);
        assert_eq!((s.p95_latency, s.mean_latency), (2, 1.0));
    }
}
