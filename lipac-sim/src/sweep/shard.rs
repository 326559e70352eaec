//! A sweep in parts, for more machines than one: `lipac sweep --shard K/N`
//! and `lipac sweep --merge DIR...`.
//!
//! A sweep's work is the list of (scene, variant) pairs, scene-major, in
//! report order ([`SweepPlan`]). Shard `K/N` ([`Shard`], K from 1 to N)
//! runs the K-th of N contiguous, disjoint slices of that list
//! ([`run_shard`]): for each scene its slice touches it renders the ground
//! truth and runs the slice's variants against it. A variant's figures
//! depend only on its scene, its settings and the frames (the ground truth
//! and the random numbers do not depend on which other variants share the
//! run), so [`merge`] of all N shards is the report of one run, figure for
//! figure, apart from timings (trace, TLAS build, BLAS build and refit,
//! frame, strategy and ground-truth milliseconds, wall times, and the
//! frame-time fronts computed from them; the modelled GPU times follow from
//! counts and merge bit-identically).
//! [`crate::sweep::run`] is shard 1/1, merged.
//!
//! The shards of one sweep must be run with the same settings (checked:
//! every shard file carries them) by the same lipac build. A scene cut
//! between two shards renders its ground truth in both.
//!
//! ```no_run
//! use lipac_sim::sweep::shard::{merge, read_shards, run_shard, write_shard, Shard};
//! use lipac_sim::sweep::{write_sweep, SweepConfig};
//! # fn main() -> Result<(), lipac_sim::SimError> {
//! let config = SweepConfig::default();
//! for k in 1..=3 {
//!     // Normally one per machine: `lipac sweep --shard K/3 --out part-K`.
//!     let part = run_shard(&config, Shard::new(k, 3)?, &mut |_, _, _, _| {})?;
//!     write_shard(&part, format!("part-{k}").as_ref())?;
//! }
//! let shards = read_shards(&["part-1".into(), "part-2".into(), "part-3".into()])?;
//! write_sweep(&merge(&shards)?, "lipac-sweep".as_ref())?;
//! # Ok(()) }
//! ```

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::variants::make_contender;
use super::{mark_fronts, SweepConfig, SweepPoint, SweepReport, SweepScene};
use crate::camera::CameraPath;
use crate::compare::{run_contenders, CompareConfig, CompareReport, LipacStart};
use crate::device_profile::DeviceProfile;
use crate::error::SimError;
use crate::replay::{ReplayConfig, ReplayMode};
use crate::scene::Scene;
use crate::strategy::lipac::LipacConfig;
use crate::trace_scene::replay_path;

/// Part `index` of `count` (1 ≤ index ≤ count) of a sweep.
///
/// ```
/// use lipac_sim::sweep::shard::Shard;
/// let s: Shard = "2/3".parse().unwrap();
/// assert_eq!((s.index(), s.count()), (2, 3));
/// // 10 (scene, variant) pairs: 3 + 3 + 4.
/// assert_eq!(s.range(10), 3..6);
/// assert_eq!(Shard::new(3, 3).unwrap().range(10), 6..10);
/// assert!("0/3".parse::<Shard>().is_err() && "4/3".parse::<Shard>().is_err());
/// assert!("1-3".parse::<Shard>().is_err());
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    index: u32,
    count: u32,
}

impl Shard {
    /// The whole sweep (shard 1/1).
    pub const WHOLE: Shard = Shard { index: 1, count: 1 };

    /// Shard `index` of `count`; an error unless 1 ≤ index ≤ count.
    pub fn new(index: u32, count: u32) -> Result<Self, SimError> {
        if index == 0 || index > count {
            return Err(SimError::BadConfig("a shard is K/N with 1 <= K <= N"));
        }
        Ok(Self { index, count })
    }

    /// K, from 1.
    pub fn index(self) -> u32 {
        self.index
    }

    /// N.
    pub fn count(self) -> u32 {
        self.count
    }

    /// The slice of `len` work items this shard runs: the K-th of N
    /// contiguous slices whose lengths differ by at most one. The slices of
    /// 1/N … N/N are disjoint and cover `0..len`; with N > len some are
    /// empty.
    pub fn range(self, len: usize) -> Range<usize> {
        let at = |k: u32| (k as u128 * len as u128 / self.count as u128) as usize;
        at(self.index - 1)..at(self.index)
    }

    /// The shard file's name, `sweep-shard-K-of-N.json`.
    pub fn file_name(self) -> String {
        format!("sweep-shard-{}-of-{}.json", self.index, self.count)
    }

    fn valid(self) -> bool {
        self.index >= 1 && self.index <= self.count
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl FromStr for Shard {
    type Err = SimError;

    /// `K/N`, e.g. `2/3`.
    fn from_str(s: &str) -> Result<Self, SimError> {
        let bad = SimError::BadConfig("a shard is K/N, e.g. 2/3");
        let (k, n) = s.split_once('/').ok_or(bad.clone())?;
        match (k.trim().parse(), n.trim().parse()) {
            (Ok(k), Ok(n)) => Self::new(k, n),
            _ => Err(bad),
        }
    }
}

/// What a sweep runs, in report order: every variant on every scene.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SweepPlan {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Camera rays per frame.
    pub rays_per_frame: u64,
    /// Scene names.
    pub scenes: Vec<String>,
    /// Variant names (after dropping duplicates).
    pub variants: Vec<String>,
    /// Variants dropped as duplicates of an earlier one.
    pub skipped: Vec<String>,
    /// The device profile of the memory axis and the modelled GPU time
    /// (the built-in one in shards that predate profiles).
    #[serde(default)]
    pub device_profile: DeviceProfile,
}

impl SweepPlan {
    /// Work items: (scene, variant) indices, scene-major.
    pub fn units(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        (0..self.scenes.len()).flat_map(move |s| (0..self.variants.len()).map(move |v| (s, v)))
    }

    /// Number of work items.
    pub fn len(&self) -> usize {
        self.scenes.len() * self.variants.len()
    }

    /// No work at all (never for a valid [`SweepConfig`]).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A scene one shard ran (some of) its variants on.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShardScene {
    /// Ground truth and timing.
    pub scene: SweepScene,
    /// Frames rendered.
    pub frames: u32,
}

/// Format tag of shard files.
pub const SHARD_FORMAT: &str = "lipac-sweep-shard 1";

/// The results of one shard: what [`write_shard`] writes and [`merge`]
/// combines.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SweepShard {
    /// [`SHARD_FORMAT`].
    pub format: String,
    /// Which part.
    pub shard: Shard,
    /// The sweep's settings (render threads left out), for [`merge`] to
    /// check that all shards belong to one sweep.
    pub settings: String,
    /// The whole sweep's work.
    pub plan: SweepPlan,
    /// Scenes this shard rendered, in plan order.
    pub scenes: Vec<ShardScene>,
    /// Its (scene, variant) points, in plan order; Pareto flags unset.
    pub points: Vec<SweepPoint>,
    /// Wall time of the shard, s.
    pub wall_s: f64,
}

fn validate(config: &SweepConfig) -> Result<(), SimError> {
    if config.trace.is_some() {
        if !config.scenes.is_empty() {
            return Err(SimError::BadConfig("sweep scenes or a trace, not both"));
        }
        if config.seed.is_some() || config.frames.is_some() {
            return Err(SimError::BadConfig(
                "a trace has its own scene and frames: no seed or frame count",
            ));
        }
        return Ok(());
    }
    if config.scenes.is_empty() {
        return Err(SimError::BadConfig("no scene to sweep"));
    }
    for (i, s) in config.scenes.iter().enumerate() {
        if config.scenes[..i].contains(s) {
            return Err(SimError::BadConfig("a scene is listed twice"));
        }
    }
    Ok(())
}

/// The settings string of a shard: the configuration without its render
/// threads (they change timings only).
fn settings(config: &SweepConfig) -> String {
    format!(
        "{:?}",
        SweepConfig {
            threads: 0,
            ..config.clone()
        }
    )
}

/// Runs shard `shard` of the sweep `config` (see the module docs).
/// `progress(scene index, scenes, frame, frames)` is called after every
/// frame of every scene the shard touches.
pub fn run_shard(
    config: &SweepConfig,
    shard: Shard,
    progress: &mut dyn FnMut(usize, usize, u32, u32),
) -> Result<SweepShard, SimError> {
    let start = Instant::now();
    validate(config)?;
    let (variants, skipped) = config.variants()?;
    let plan = SweepPlan {
        width: config.width,
        height: config.height,
        rays_per_frame: config.rays_per_frame(),
        scenes: config.scene_names(),
        variants: variants.iter().map(|v| v.name.clone()).collect(),
        skipped,
        device_profile: config.device.clone(),
    };
    let range = shard.range(plan.len());
    let mine: Vec<(usize, usize)> = plan
        .units()
        .enumerate()
        .filter(|(i, _)| range.contains(i))
        .map(|(_, u)| u)
        .collect();
    let base = LipacConfig::for_rays_per_frame(config.rays_per_frame())?
        .with_memory(config.device.memory_model());
    let compare = CompareConfig {
        frames: config.frames,
        width: config.width,
        height: config.height,
        strategies: Vec::new(),
        share_ground_truth: true,
        threads: config.threads,
        adaptive_levels: None,
        lipac_cell_size: None,
        lipac_rise_shift: None,
        lipac_start: LipacStart::Default,
        lipac_warm_start_at_cuts: false,
        lipac_warm_start_hold: None,
        device: config.device.clone(),
    };
    let mut scenes = Vec::new();
    let mut points = Vec::new();
    let count = plan.scenes.len();
    for si in 0..count {
        let here: Vec<&super::Variant> = mine
            .iter()
            .filter(|u| u.0 == si)
            .map(|u| &variants[u.1])
            .collect();
        if here.is_empty() {
            continue;
        }
        let mut r = match &config.trace {
            Some(file) => {
                replay_variants(file, config, &here, &mut |d, t| progress(si, count, d, t))?
            }
            None => {
                let choice = config.scenes[si];
                let mut scene = Scene::generate(&choice.config(config.seed))?;
                let aspect = config.width as f32 / config.height.max(1) as f32;
                let path = CameraPath::flythrough(&scene, aspect);
                let contenders = here
                    .iter()
                    .map(|v| make_contender(v, &scene, &base))
                    .collect::<Result<Vec<_>, _>>()?;
                run_contenders(
                    choice.name(),
                    &mut scene,
                    &path,
                    &compare,
                    contenders,
                    &mut |d, t| progress(si, count, d, t),
                )?
            }
        };
        r.scene.clone_from(&plan.scenes[si]);
        points.extend(here.iter().zip(&r.strategies).map(|(v, run)| {
            let th = v.lipac.as_ref().map(|c| {
                let t = c.thresholds;
                [t.theta_a, t.theta_d, t.sigma_a, t.sigma_o, t.n_a, t.n_d]
            });
            SweepPoint {
                scene: r.scene.clone(),
                name: v.name.clone(),
                family: v.family,
                strategy: v.kind.name().to_string(),
                factor: v.factor,
                cell_size: v.lipac.as_ref().map(|c| c.cell_size),
                thresholds: th,
                latency: v
                    .lipac
                    .as_ref()
                    .and_then(|c| c.latency)
                    .map(|h| [h.max_distance, h.min_projected_size]),
                builds_per_frame: run.summary.builds as f64 / f64::from(r.frames.max(1)),
                frame_errors: run.frames.iter().map(|m| m.error).collect(),
                summary: run.summary.clone(),
                front_time: false,
                front_gpu_time: false,
                front_memory: false,
                front_builds: false,
            }
        }));
        scenes.push(ShardScene {
            scene: SweepScene {
                name: r.scene.clone(),
                instances: r.instances,
                ground_truth_ms: r.ground_truth_ms,
                traced_rays_per_frame: r.traced_rays_per_frame,
                wall_s: r.wall_s,
            },
            frames: r.frames,
        });
    }
    Ok(SweepShard {
        format: SHARD_FORMAT.to_string(),
        shard,
        settings: settings(config),
        plan,
        scenes,
        points,
        wall_s: start.elapsed().as_secs_f64(),
    })
}

/// The variants `here` on the trace `file`, replayed in geometry mode
/// (`lipac replay`'s choice of scene: built-in or the trace's own): the
/// baselines as the replay's strategies, the LiPaC variants as its
/// [`ReplayConfig::lipac_variants`], the hindsight references as its
/// [`ReplayConfig::hindsight_variants`]; the report's runs in the order of
/// `here`.
fn replay_variants(
    file: &Path,
    config: &SweepConfig,
    here: &[&super::Variant],
    progress: &mut dyn FnMut(u32, u32),
) -> Result<CompareReport, SimError> {
    let replay = ReplayConfig {
        strategies: here
            .iter()
            .filter(|v| v.lipac.is_none() && v.hindsight.is_none())
            .map(|v| v.kind)
            .collect(),
        width: config.width,
        height: config.height,
        threads: config.threads,
        mode: Some(ReplayMode::Geometry),
        warm_start_at_cuts: config.warm_start_at_cuts,
        lipac_variants: here
            .iter()
            .filter_map(|v| v.lipac.clone().map(|c| (v.name.clone(), c)))
            .collect(),
        hindsight_variants: here
            .iter()
            .filter_map(|v| v.hindsight.map(|k| (v.name.clone(), k)))
            .collect(),
        device: config.device.clone(),
        ..ReplayConfig::default()
    };
    // A trace does not say its length up front: the total is 0 (unknown).
    let (mut report, _) = replay_path(file, &replay, &config.trace_options, &mut |done| {
        progress(u32::try_from(done).unwrap_or(u32::MAX), 0)
    })
    .map_err(|e| SimError::Replay(format!("{}: {e}", file.display())))?;
    let mut runs = Vec::with_capacity(here.len());
    for v in here {
        let i = report
            .strategies
            .iter()
            .position(|s| s.name == v.name)
            .ok_or_else(|| SimError::Replay(format!("the replay has no run {}", v.name)))?;
        runs.push(report.strategies.swap_remove(i));
    }
    report.strategies = runs;
    Ok(report)
}

fn io(path: &Path, e: impl std::fmt::Display) -> SimError {
    SimError::Io(format!("{}: {e}", path.display()))
}

/// Writes `shard` as `dir/sweep-shard-K-of-N.json` (`dir` created if
/// missing); returns the path.
pub fn write_shard(shard: &SweepShard, dir: &Path) -> Result<PathBuf, SimError> {
    std::fs::create_dir_all(dir).map_err(|e| io(dir, e))?;
    let path = dir.join(shard.shard.file_name());
    let json = serde_json::to_string(shard).map_err(|e| io(&path, e))?;
    std::fs::write(&path, json).map_err(|e| io(&path, e))?;
    Ok(path)
}

fn is_shard_file(name: &str) -> bool {
    name.starts_with("sweep-shard-") && name.ends_with(".json")
}

/// Reads shard files: each path is a shard file or a folder whose
/// `sweep-shard-*.json` files are read (a folder without one is an error).
pub fn read_shards(paths: &[PathBuf]) -> Result<Vec<SweepShard>, SimError> {
    let mut files = Vec::new();
    for p in paths {
        if p.is_dir() {
            let mut found: Vec<PathBuf> = std::fs::read_dir(p)
                .map_err(|e| io(p, e))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|f| {
                    f.is_file()
                        && f.file_name()
                            .and_then(|n| n.to_str())
                            .is_some_and(is_shard_file)
                })
                .collect();
            if found.is_empty() {
                return Err(io(p, "no sweep-shard-*.json in this folder"));
            }
            found.sort();
            files.extend(found);
        } else {
            files.push(p.clone());
        }
    }
    files
        .iter()
        .map(|f| {
            let text = std::fs::read_to_string(f).map_err(|e| io(f, e))?;
            let shard: SweepShard = serde_json::from_str(&text).map_err(|e| io(f, e))?;
            if shard.format != SHARD_FORMAT {
                return Err(io(f, format!("not a {SHARD_FORMAT} file")));
            }
            Ok(shard)
        })
        .collect()
}

fn shard_err(what: String) -> SimError {
    SimError::Shard(what)
}

/// Combines the N shards of one sweep (in any order) into its report (see
/// the module docs): points and scenes in plan order, Pareto fronts marked.
/// Timings: a scene's ground-truth time is the mean over the shards that
/// rendered it, its wall time and the report's the sum over shards. An
/// error if shards are missing, repeated, from another sweep, or do not
/// hold exactly their slice of the plan.
pub fn merge(shards: &[SweepShard]) -> Result<SweepReport, SimError> {
    let first = shards
        .first()
        .ok_or_else(|| shard_err("no shards to merge".into()))?;
    let n = first.shard.count;
    let plan = &first.plan;
    // Counts read from the files are checked against what the files hold
    // before anything is allocated by them: a sweep of N parts needs N
    // shard files (and, below, its plan's (scene, variant) pairs are the
    // points the shards carry).
    if u64::from(n) > shards.len() as u64 {
        let given: std::collections::BTreeSet<u32> = shards
            .iter()
            .filter(|s| s.shard.count == n && s.shard.valid())
            .map(|s| s.shard.index)
            .collect();
        let missing: Vec<String> = (1..=n)
            .filter(|k| !given.contains(k))
            .take(8)
            .map(|k| format!("{k}/{n}"))
            .collect();
        let more = u64::from(n)
            .saturating_sub(given.len() as u64)
            .saturating_sub(missing.len() as u64);
        return Err(shard_err(format!(
            "missing shards {}{}: shard {} is one of {n} parts, {} shard file(s) given",
            missing.join(", "),
            if more > 0 {
                format!(" and {more} more")
            } else {
                String::new()
            },
            first.shard,
            shards.len()
        )));
    }
    let mut by_index: Vec<Option<&SweepShard>> = vec![None; n as usize];
    for s in shards {
        if s.format != SHARD_FORMAT {
            return Err(shard_err(format!("shard {}: not {SHARD_FORMAT}", s.shard)));
        }
        if !s.shard.valid() || s.shard.count != n {
            return Err(shard_err(format!(
                "shard {} is not one of {n} parts (shard {} is)",
                s.shard, first.shard
            )));
        }
        if s.settings != first.settings || s.plan != *plan {
            return Err(shard_err(format!(
                "shard {} was run with other settings than shard {}",
                s.shard, first.shard
            )));
        }
        let slot = &mut by_index[s.shard.index as usize - 1];
        if slot.is_some() {
            return Err(shard_err(format!("shard {} given twice", s.shard)));
        }
        *slot = Some(s);
    }
    let missing: Vec<String> = (1..=n)
        .filter(|k| by_index[*k as usize - 1].is_none())
        .map(|k| format!("{k}/{n}"))
        .collect();
    if !missing.is_empty() {
        return Err(shard_err(format!("missing shards {}", missing.join(", "))));
    }
    // The plan's pairs are listed only when the shards carry them all.
    let carried: usize = shards.iter().map(|s| s.points.len()).sum();
    if plan.scenes.len().checked_mul(plan.variants.len()) != Some(carried) {
        return Err(shard_err(format!(
            "the plan of shard {} has {} scenes x {} configurations, the shards hold {carried} results",
            first.shard,
            plan.scenes.len(),
            plan.variants.len()
        )));
    }
    let units: Vec<(usize, usize)> = plan.units().collect();
    let mut points = Vec::with_capacity(units.len());
    // Per plan scene: (scene, frames, ground-truth ms summed, renders).
    let mut scenes: Vec<Option<(SweepScene, u32, f64, u32)>> = vec![None; plan.scenes.len()];
    let mut wall_s = 0.0;
    for s in by_index.into_iter().flatten() {
        wall_s += s.wall_s;
        let want = &units[s.shard.range(units.len())];
        let got: Vec<(&str, &str)> = s
            .points
            .iter()
            .map(|p| (p.scene.as_str(), p.name.as_str()))
            .collect();
        let expected: Vec<(&str, &str)> = want
            .iter()
            .map(|&(sc, v)| (plan.scenes[sc].as_str(), plan.variants[v].as_str()))
            .collect();
        if got != expected {
            return Err(shard_err(format!(
                "shard {} does not hold its part of the sweep",
                s.shard
            )));
        }
        points.extend(s.points.iter().cloned());
        for sc in &s.scenes {
            let i = plan
                .scenes
                .iter()
                .position(|n| *n == sc.scene.name)
                .filter(|i| want.iter().any(|u| u.0 == *i))
                .ok_or_else(|| {
                    shard_err(format!(
                        "shard {} reports scene {} it did not run",
                        s.shard, sc.scene.name
                    ))
                })?;
            match &mut scenes[i] {
                None => {
                    scenes[i] = Some((sc.scene.clone(), sc.frames, sc.scene.ground_truth_ms, 1))
                }
                Some((m, frames, gt_ms, renders)) => {
                    if m.instances != sc.scene.instances
                        || *frames != sc.frames
                        || m.traced_rays_per_frame.to_bits()
                            != sc.scene.traced_rays_per_frame.to_bits()
                    {
                        return Err(shard_err(format!(
                            "shard {} rendered another ground truth of {}",
                            s.shard, sc.scene.name
                        )));
                    }
                    m.wall_s += sc.scene.wall_s;
                    *gt_ms += sc.scene.ground_truth_ms;
                    *renders += 1;
                }
            }
        }
    }
    let mut out = Vec::with_capacity(scenes.len());
    let mut frames = 0;
    for (i, s) in scenes.into_iter().enumerate() {
        let (mut scene, f, gt_ms, renders) =
            s.ok_or_else(|| shard_err(format!("no shard reports scene {}", plan.scenes[i])))?;
        scene.ground_truth_ms = gt_ms / f64::from(renders);
        // As one run: the frames of the last scene.
        frames = f;
        out.push(scene);
    }
    let mut report = SweepReport {
        frames,
        width: plan.width,
        height: plan.height,
        rays_per_frame: plan.rays_per_frame,
        scenes: out,
        points,
        skipped: plan.skipped.clone(),
        wall_s,
        device_profile: plan.device_profile.clone(),
    };
    mark_fronts(&mut report);
    Ok(report)
}
