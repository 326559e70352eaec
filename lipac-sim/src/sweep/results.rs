//! What a sweep reports: one [`SweepPoint`] per (scene, variant), one
//! [`SweepScene`] per scene, all in a [`SweepReport`].

use serde::{Deserialize, Serialize};

use super::Family;
use crate::device_profile::DeviceProfile;
use crate::metrics::Summary;

/// One configuration on one scene.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SweepPoint {
    /// Scene name.
    pub scene: String,
    /// Variant name.
    pub name: String,
    /// What the variant varies.
    pub family: Family,
    /// Strategy name.
    pub strategy: String,
    /// Threshold factor (LiPaC variants).
    pub factor: Option<f64>,
    /// Hitbox cell size, metres (LiPaC variants).
    pub cell_size: Option<f64>,
    /// `[θa, θd, σa, σo, n_a, n_d]` (LiPaC variants).
    pub thresholds: Option<[u32; 6]>,
    /// Latency-mitigation heuristic `[max distance, min projected size]`.
    pub latency: Option<[f32; 2]>,
    /// The comparison's summary.
    pub summary: Summary,
    /// Mean BLAS builds per frame.
    pub builds_per_frame: f64,
    /// Error per frame.
    #[serde(with = "crate::json_float::vec")]
    pub frame_errors: Vec<f64>,
    /// On the (frame time, error) Pareto front of its scene (frame time
    /// measured on the CPU: BLAS builds and refits, TLAS build, trace).
    pub front_time: bool,
    /// On the (modelled GPU frame time, error) Pareto front of its scene.
    #[serde(default)]
    pub front_gpu_time: bool,
    /// On the (memory, error) Pareto front of its scene.
    pub front_memory: bool,
    /// On the (builds, error) Pareto front of its scene.
    pub front_builds: bool,
}

impl SweepPoint {
    /// Whether it is on the front of cost `cost` (an index into
    /// [`super::COSTS`]; false past its end).
    pub fn on_front(&self, cost: usize) -> bool {
        self.fronts().get(cost).copied().unwrap_or(false)
    }

    /// Its front flags in [`super::COSTS`] order.
    pub fn fronts(&self) -> [bool; 4] {
        [
            self.front_time,
            self.front_gpu_time,
            self.front_memory,
            self.front_builds,
        ]
    }

    /// Sets its front flags from `fronts` ([`super::COSTS`] order).
    pub fn set_fronts(&mut self, fronts: [bool; 4]) {
        [
            self.front_time,
            self.front_gpu_time,
            self.front_memory,
            self.front_builds,
        ] = fronts;
    }
}

/// Ground truth and timing of one scene of a sweep.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SweepScene {
    /// Scene name.
    pub name: String,
    /// Scene instances.
    pub instances: u64,
    /// Mean ground-truth render time, ms (merged shards: the mean over the
    /// shards that rendered it).
    pub ground_truth_ms: f64,
    /// Mean bounce plus shadow rays of the ground truth per frame.
    pub traced_rays_per_frame: f64,
    /// Wall time of the scene's runs, s (merged shards: the sum over the
    /// shards that ran the scene).
    pub wall_s: f64,
}

/// A sweep's results.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SweepReport {
    /// Frames per scene.
    pub frames: u32,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Camera rays per frame.
    pub rays_per_frame: u64,
    /// Per scene.
    pub scenes: Vec<SweepScene>,
    /// Every variant on every scene (scene-major, variants in order).
    pub points: Vec<SweepPoint>,
    /// Variants dropped as duplicates of an earlier one.
    pub skipped: Vec<String>,
    /// Wall time, s (merged shards: the sum of theirs).
    pub wall_s: f64,
    /// The device profile of the memory axis and the modelled GPU time
    /// (the built-in one in reports that predate profiles).
    #[serde(default)]
    pub device_profile: DeviceProfile,
}

impl SweepReport {
    /// The point of variant `name` on `scene`.
    pub fn point(&self, scene: &str, name: &str) -> Option<&SweepPoint> {
        self.points
            .iter()
            .find(|p| p.scene == scene && p.name == name)
    }
}
