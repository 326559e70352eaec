//! Sweeps: run time, memory and BLAS builds against error over many
//! strategy configurations.
//!
//! A sweep is one comparison per scene ([`crate::compare::run_contenders`])
//! whose contenders are [`Variant`]s: the baselines, LiPaC with its
//! thresholds scaled by factors, LiPaC with latency mitigation (several
//! heuristics), other hitbox cell sizes and other streak lengths. Every
//! contender of a scene renders against the same ground truth, rendered once
//! per frame, with the same random numbers, so its error is exactly the
//! error `lipac compare` reports for the same configuration.
//!
//! **Threshold factors.** Factor `f` gives LiPaC the thresholds
//! [`Thresholds::for_rays_per_frame`]`(f · rays)`: θa, θd, σa, σo all scale
//! by `f`, keeping the paper's 10:1 ratio of activation to deactivation,
//! with the same rounding (at least 1, lower below upper). At small images
//! low factors round to the same thresholds; such duplicates are run once
//! (the later names are listed in [`SweepReport::skipped`]).
//!
//! For each scene and each cost (trace time, memory, builds) the points not
//! dominated in (cost, error) form the Pareto front ([`pareto_front`]). The
//! oracle is plotted as a reference but kept off the fronts: it reads the
//! ground truth's hits, no renderer can do that, and its zero error would
//! dominate every costlier configuration.
//!
//! **On many machines.** [`shard`] splits a sweep into disjoint parts
//! (`lipac sweep --shard K/N`) and merges their results into the report of
//! one run (`lipac sweep --merge DIR...`); docs/SCALING_OUT.md shows Slurm,
//! Kubernetes and GNU parallel set-ups.

pub mod shard;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use lipac_core::latency::ActivationHeuristic;
use lipac_core::thresholds::Thresholds;
use serde::{Deserialize, Serialize};

use crate::compare::{make_strategy, Contender, SceneChoice};
use crate::error::SimError;
use crate::metrics::Summary;
use crate::plots::pareto_plot;
use crate::scene::Scene;
use crate::strategy::lipac::{Lipac, LipacConfig};
use crate::strategy::StrategyKind;

/// What a variant varies.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Family {
    /// A baseline strategy (full, frustum, heuristic, oracle).
    Baseline,
    /// LiPaC with its thresholds scaled by a factor.
    Thresholds,
    /// LiPaC with latency mitigation.
    Latency,
    /// LiPaC with another hitbox cell size.
    CellSize,
    /// LiPaC with other streak lengths n_a / n_d.
    Streaks,
}

impl Family {
    /// Name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Baseline => "baseline",
            Self::Thresholds => "thresholds",
            Self::Latency => "latency",
            Self::CellSize => "cell size",
            Self::Streaks => "streaks",
        }
    }
}

/// One configuration of a sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct Variant {
    /// Report name (unique).
    pub name: String,
    /// What it varies.
    pub family: Family,
    /// The strategy.
    pub kind: StrategyKind,
    /// LiPaC's settings (`None` for the baselines).
    pub lipac: Option<LipacConfig>,
    /// Threshold factor (LiPaC variants).
    pub factor: Option<f64>,
}

/// Settings of a sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepConfig {
    /// Scenes, each with its fly-through.
    pub scenes: Vec<SceneChoice>,
    /// Scene seed (`None`: each scene's own).
    pub seed: Option<u64>,
    /// Frames per scene (`None`: the whole fly-through).
    pub frames: Option<u32>,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Baseline strategies.
    pub baselines: Vec<StrategyKind>,
    /// Threshold factors of plain LiPaC (default cells, n_a = 4, n_d = 15).
    pub factors: Vec<f64>,
    /// Latency-mitigation heuristics, each run as LiPaC + latency
    /// mitigation at factor 1.
    pub latency: Vec<ActivationHeuristic>,
    /// Further hitbox cell sizes (metres), at factor 1.
    pub cell_sizes: Vec<f64>,
    /// Further `(n_a, n_d)` streak lengths, at factor 1.
    pub streaks: Vec<(u32, u32)>,
    /// Render threads (0 = all cores).
    pub threads: usize,
}

impl Default for SweepConfig {
    /// City and mirror scenes, the whole fly-through at 128 x 72; full,
    /// frustum, heuristic and oracle; factors 0.5, 1, 2, 4; latency
    /// mitigation with the default heuristic and a wider one (100 m, 0.05);
    /// 16 m (the paper's) and 64 m cells besides the default 32 m;
    /// `(n_a, n_d)` = (1, 15) and (4, 30).
    fn default() -> Self {
        Self {
            scenes: vec![SceneChoice::City, SceneChoice::Mirror],
            seed: None,
            frames: None,
            width: 128,
            height: 72,
            baselines: vec![
                StrategyKind::Full,
                StrategyKind::Frustum,
                StrategyKind::Heuristic,
                StrategyKind::Oracle,
            ],
            factors: vec![0.5, 1.0, 2.0, 4.0],
            latency: vec![
                ActivationHeuristic::default(),
                ActivationHeuristic {
                    max_distance: 100.0,
                    min_projected_size: 0.05,
                },
            ],
            cell_sizes: vec![16.0, 64.0],
            streaks: vec![(1, 15), (4, 30)],
            threads: 0,
        }
    }
}

/// LiPaC's thresholds for `rays_per_frame` camera rays scaled by `factor`
/// (see the module docs).
///
/// ```
/// use lipac_sim::sweep::scaled_thresholds;
/// let t = scaled_thresholds(1920 * 1080, 0.5).unwrap();
/// assert_eq!((t.theta_a, t.theta_d, t.sigma_a, t.sigma_o), (500, 50, 500, 50));
/// assert!(scaled_thresholds(9216, f64::NAN).is_err());
/// ```
pub fn scaled_thresholds(rays_per_frame: u64, factor: f64) -> Result<Thresholds, SimError> {
    if !factor.is_finite() || factor <= 0.0 {
        return Err(SimError::BadConfig(
            "threshold factors must be finite and positive",
        ));
    }
    Thresholds::for_rays_per_frame(rays_per_frame as f64 * factor).map_err(SimError::core)
}

fn fmt_factor(f: f64) -> String {
    format!("×{f}")
}

impl SweepConfig {
    /// Camera rays per frame.
    pub fn rays_per_frame(&self) -> u64 {
        u64::from(self.width) * u64::from(self.height)
    }

    /// The variants, in report order, and the names of variants dropped as
    /// duplicates of an earlier one (same strategy, same settings).
    pub fn variants(&self) -> Result<(Vec<Variant>, Vec<String>), SimError> {
        let rays = self.rays_per_frame();
        if rays == 0 {
            return Err(SimError::BadConfig("image size must be positive"));
        }
        let base = LipacConfig::for_rays_per_frame(rays)?;
        let mut all = Vec::new();
        for &k in &self.baselines {
            if matches!(k, StrategyKind::Lipac | StrategyKind::LipacLatency) {
                return Err(SimError::BadConfig(
                    "LiPaC is swept by factors, not as a baseline",
                ));
            }
            all.push(Variant {
                name: k.name().to_string(),
                family: Family::Baseline,
                kind: k,
                lipac: None,
                factor: None,
            });
        }
        let lipac = |name: String, family, kind, config: LipacConfig, factor| Variant {
            name,
            family,
            kind,
            lipac: Some(config),
            factor: Some(factor),
        };
        for &f in &self.factors {
            let c = LipacConfig {
                thresholds: scaled_thresholds(rays, f)?,
                ..base.clone()
            };
            all.push(lipac(
                format!("lipac {}", fmt_factor(f)),
                Family::Thresholds,
                StrategyKind::Lipac,
                c,
                f,
            ));
        }
        for (i, h) in self.latency.iter().enumerate() {
            let c = LipacConfig {
                latency: Some(*h),
                ..base.clone()
            };
            let name = if i == 0 && *h == ActivationHeuristic::default() {
                "lipac-latency".to_string()
            } else {
                format!(
                    "lipac-latency {} m / {}",
                    h.max_distance, h.min_projected_size
                )
            };
            all.push(lipac(
                name,
                Family::Latency,
                StrategyKind::LipacLatency,
                c,
                1.0,
            ));
        }
        for &cell in &self.cell_sizes {
            if !cell.is_finite() || cell <= 0.0 {
                return Err(SimError::BadConfig(
                    "cell sizes must be finite and positive",
                ));
            }
            let c = LipacConfig {
                cell_size: cell,
                ..base.clone()
            };
            all.push(lipac(
                format!("lipac {cell} m cells"),
                Family::CellSize,
                StrategyKind::Lipac,
                c,
                1.0,
            ));
        }
        for &(n_a, n_d) in &self.streaks {
            let thresholds = Thresholds {
                n_a,
                n_d,
                ..base.thresholds
            };
            thresholds.validate().map_err(SimError::core)?;
            let c = LipacConfig {
                thresholds,
                ..base.clone()
            };
            all.push(lipac(
                format!("lipac n_a {n_a} n_d {n_d}"),
                Family::Streaks,
                StrategyKind::Lipac,
                c,
                1.0,
            ));
        }
        let mut kept: Vec<Variant> = Vec::new();
        let mut skipped = Vec::new();
        for v in all {
            if kept.iter().any(|k| k.kind == v.kind && k.lipac == v.lipac) {
                skipped.push(v.name);
            } else if kept.iter().any(|k| k.name == v.name) {
                return Err(SimError::BadConfig("two sweep variants share a name"));
            } else {
                kept.push(v);
            }
        }
        if kept.is_empty() {
            return Err(SimError::BadConfig("nothing to sweep"));
        }
        Ok((kept, skipped))
    }
}

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
    /// On the (trace time, error) Pareto front of its scene.
    pub front_time: bool,
    /// On the (memory, error) Pareto front of its scene.
    pub front_memory: bool,
    /// On the (builds, error) Pareto front of its scene.
    pub front_builds: bool,
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
}

impl SweepReport {
    /// The point of variant `name` on `scene`.
    pub fn point(&self, scene: &str, name: &str) -> Option<&SweepPoint> {
        self.points
            .iter()
            .find(|p| p.scene == scene && p.name == name)
    }
}

/// Which of `points` (cost, error), both minimised, are on the Pareto
/// front: no other point is at most as large in both and smaller in one.
/// Points with a NaN coordinate are never on it; equal points are both on
/// it.
///
/// ```
/// use lipac_sim::sweep::pareto_front;
/// let front = pareto_front(&[(1.0, 5.0), (2.0, 2.0), (3.0, 3.0), (4.0, 1.0)]);
/// assert_eq!(front, [true, true, false, true]);
/// ```
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<bool> {
    points
        .iter()
        .map(|&(x, y)| {
            !x.is_nan()
                && !y.is_nan()
                && !points
                    .iter()
                    .any(|&(a, b)| a <= x && b <= y && (a < x || b < y))
        })
        .collect()
}

fn make_contender(v: &Variant, scene: &Scene, base: &LipacConfig) -> Result<Contender, SimError> {
    let strategy = match &v.lipac {
        Some(c) => Box::new(Lipac::new(scene, c.clone())?) as _,
        None => make_strategy(v.kind, scene, base)?,
    };
    Ok(Contender {
        name: v.name.clone(),
        strategy,
    })
}

/// Recomputes the Pareto flags of every point, per scene (see the module
/// docs; the oracle is never on a front).
pub fn mark_fronts(report: &mut SweepReport) {
    let names: Vec<String> = report.scenes.iter().map(|s| s.name.clone()).collect();
    for name in names {
        let mut idx = Vec::new();
        let mut pts = Vec::new();
        for (i, p) in report.points.iter().enumerate() {
            if p.scene == name && p.strategy != StrategyKind::Oracle.name() {
                idx.push(i);
                pts.push(p.clone());
            }
        }
        mark_scene_fronts(&mut pts);
        for p in report.points.iter_mut().filter(|p| p.scene == name) {
            p.front_time = false;
            p.front_memory = false;
            p.front_builds = false;
        }
        for (i, p) in idx.into_iter().zip(pts) {
            report.points[i] = p;
        }
    }
}

fn mark_scene_fronts(points: &mut [SweepPoint]) {
    let fronts = [
        |p: &SweepPoint| p.summary.mean_trace_ms,
        |p: &SweepPoint| p.summary.mean_mib,
        |p: &SweepPoint| p.builds_per_frame,
    ]
    .map(|cost| {
        pareto_front(
            &points
                .iter()
                .map(|p| (cost(p), p.summary.mean_error))
                .collect::<Vec<_>>(),
        )
    });
    for (i, p) in points.iter_mut().enumerate() {
        p.front_time = fronts[0][i];
        p.front_memory = fronts[1][i];
        p.front_builds = fronts[2][i];
    }
}

/// Runs the sweep. `progress(scene index, scenes, frame, frames)` is called
/// after every frame. The same as [`shard::run_shard`] of shard 1/1,
/// [`shard::merge`]d; `lipac sweep --shard K/N` runs a part of it.
pub fn run(
    config: &SweepConfig,
    progress: &mut dyn FnMut(usize, usize, u32, u32),
) -> Result<SweepReport, SimError> {
    shard::merge(&[shard::run_shard(config, shard::Shard::WHOLE, progress)?])
}

/// The three costs plotted against error: file name, title, axis label,
/// value.
type Cost = (
    &'static str,
    &'static str,
    &'static str,
    fn(&SweepPoint) -> f64,
);

/// Plot files [`write_sweep`] writes, with their cost axis.
pub const COSTS: [Cost; 3] = [
    (
        "sweep_time.svg",
        "Trace time against error",
        "mean trace time per frame, ms",
        |p| p.summary.mean_trace_ms,
    ),
    (
        "sweep_memory.svg",
        "Acceleration-structure memory against error",
        "mean memory, MiB",
        |p| p.summary.mean_mib,
    ),
    (
        "sweep_builds.svg",
        "BLAS builds against error",
        "mean BLAS builds per frame",
        |p| p.builds_per_frame,
    ),
];

/// CSV header of [`sweep_csv`].
pub const SWEEP_CSV_HEADER: &str = "scene,name,family,strategy,factor,cell_size,theta_a,theta_d,sigma_a,sigma_o,n_a,n_d,latency_distance,latency_size,mean_instances,mean_mib,peak_mib,mean_blas_mib,builds,builds_per_frame,refits,primitives_built,primitives_refit,state_changes,cycles,mean_latency,p95_latency,never_active,mean_needed_missing,mean_error,max_error,mean_trace_ms,mean_tlas_build_ms,mean_strategy_ms,front_time,front_memory,front_builds";

fn opt<T: std::fmt::Display>(v: Option<T>) -> String {
    v.map(|v| v.to_string()).unwrap_or_default()
}

/// One row per scene and variant.
pub fn sweep_csv(r: &SweepReport) -> String {
    let mut s = String::from(SWEEP_CSV_HEADER);
    s.push('\n');
    for p in &r.points {
        let m = &p.summary;
        let th = |i: usize| opt(p.thresholds.map(|t| t[i]));
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.1},{:.4},{:.4},{:.4},{},{:.3},{},{},{},{},{},{:.3},{},{},{:.2},{:.6},{:.6},{:.3},{:.3},{:.3},{},{},{}",
            p.scene,
            p.name,
            p.family.name(),
            p.strategy,
            opt(p.factor),
            opt(p.cell_size),
            th(0),
            th(1),
            th(2),
            th(3),
            th(4),
            th(5),
            opt(p.latency.map(|l| l[0])),
            opt(p.latency.map(|l| l[1])),
            m.mean_instances,
            m.mean_mib,
            m.peak_mib,
            m.mean_blas_mib,
            m.builds,
            p.builds_per_frame,
            m.refits,
            m.primitives_built,
            m.primitives_refit,
            m.state_changes,
            m.cycles,
            m.mean_latency,
            m.p95_latency,
            m.never_active,
            m.mean_needed_missing,
            m.mean_error,
            m.max_error,
            m.mean_trace_ms,
            m.mean_tlas_build_ms,
            m.mean_strategy_ms,
            p.front_time,
            p.front_memory,
            p.front_builds
        );
    }
    s
}

/// The Markdown report: per scene a table of every variant, fronts marked.
pub fn sweep_markdown(r: &SweepReport) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# lipac sweep: run time, memory and builds against error\n"
    );
    let _ = writeln!(
        s,
        "{} frames of the fly-through per scene at {}x{} ({} camera rays per frame). \
         Wall time {:.1} s. Every configuration of a scene renders against the same ground \
         truth (rendered once per frame). Front columns: T = on the (trace time, error) Pareto \
         front, M = (memory, error), B = (builds, error); the oracle (it reads the ground truth's \
         hits) is a reference, never on a front.\n",
        r.frames, r.width, r.height, r.rays_per_frame, r.wall_s
    );
    if !r.skipped.is_empty() {
        let _ = writeln!(
            s,
            "Dropped as duplicates of an earlier configuration (same thresholds after rounding): {}.\n",
            r.skipped.join(", ")
        );
    }
    for sc in &r.scenes {
        let _ = writeln!(
            s,
            "## {} ({} instances)\n\nGround truth {:.1} ms per frame; it traces {:.0} bounce + shadow \
             rays per frame ({:.2} per camera ray). Scene wall time {:.1} s.\n",
            sc.name,
            sc.instances,
            sc.ground_truth_ms,
            sc.traced_rays_per_frame,
            sc.traced_rays_per_frame / r.rays_per_frame.max(1) as f64,
            sc.wall_s
        );
        let _ = writeln!(
            s,
            "| configuration | θa θd σa σo n_a n_d | cell m | memory MiB mean (BLAS) | builds / frame | refits | \
             cycles | latency mean | error mean | max | trace ms | front |"
        );
        let _ = writeln!(
            s,
            "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"
        );
        for p in r.points.iter().filter(|p| p.scene == sc.name) {
            let m = &p.summary;
            let th = p
                .thresholds
                .map(|t| t.map(|v| v.to_string()).join(" "))
                .unwrap_or_else(|| "–".into());
            let front: String = [
                (p.front_time, 'T'),
                (p.front_memory, 'M'),
                (p.front_builds, 'B'),
            ]
            .iter()
            .filter(|(on, _)| *on)
            .map(|(_, c)| *c)
            .collect();
            let _ = writeln!(
                s,
                "| {} | {} | {} | {:.2} ({:.2}) | {:.1} | {} | {} | {:.1} | {:.4} | {:.4} | {:.1} | {} |",
                p.name,
                th,
                p.cell_size.map(|c| c.to_string()).unwrap_or_else(|| "–".into()),
                m.mean_mib,
                m.mean_blas_mib,
                p.builds_per_frame,
                m.refits,
                m.cycles,
                m.mean_latency,
                m.mean_error,
                m.max_error,
                m.mean_trace_ms,
                front
            );
        }
        s.push('\n');
    }
    let _ = writeln!(s, "## Plots\n");
    for (file, title, _, _) in COSTS {
        let _ = writeln!(s, "- [{title}]({file})\n\n  ![{title}]({file})\n");
    }
    let _ = writeln!(
        s,
        "Data: [sweep.csv](sweep.csv); everything, with per-frame errors: [sweep.json](sweep.json).\n\n\
         Memory is modelled on lavapipe's acceleration-structure sizes (docs/MEMORY_MODEL.md). \
         Trace times are the CPU time (summed over threads) of the bounce and shadow rays traced \
         against each configuration's TLAS, on whatever else the machine ran; primary hits and the \
         rasterized-shadow fallback stand in for rasterization and are excluded. The full-scene \
         strategy's is the ground truth's (its render is reused)."
    );
    s
}

/// Names of every file [`write_sweep`] writes.
pub const SWEEP_FILES: [&str; 6] = [
    "sweep.md",
    "sweep.json",
    "sweep.csv",
    COSTS[0].0,
    COSTS[1].0,
    COSTS[2].0,
];

/// Writes `sweep.md`, `sweep.json`, `sweep.csv` and the three Pareto plots
/// into `dir` (created if missing); returns the paths written.
pub fn write_sweep(r: &SweepReport, dir: &Path) -> Result<Vec<PathBuf>, SimError> {
    std::fs::create_dir_all(dir)?;
    let json = serde_json::to_string_pretty(r).map_err(|e| SimError::Io(e.to_string()))?;
    let bodies = [
        sweep_markdown(r),
        json,
        sweep_csv(r),
        pareto_plot(r, 0)?,
        pareto_plot(r, 1)?,
        pareto_plot(r, 2)?,
    ];
    let mut paths = Vec::new();
    for (name, body) in SWEEP_FILES.iter().zip(bodies) {
        let p = dir.join(name);
        std::fs::write(&p, body)?;
        paths.push(p);
    }
    Ok(paths)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pareto_front_of_a_hand_made_set() {
        // (cost, error). By hand: (1,9) cheapest; (2,4) and (5,1) trade
        // off; (3,4) is dominated by (2,4) (same error, costlier); (6,1)
        // by (5,1); (4,6) by (2,4); (2,4) twice: equal points are both on
        // the front; NaN never.
        let pts = [
            (1.0, 9.0),
            (2.0, 4.0),
            (3.0, 4.0),
            (5.0, 1.0),
            (6.0, 1.0),
            (4.0, 6.0),
            (2.0, 4.0),
            (f64::NAN, 0.0),
            (0.5, f64::NAN),
        ];
        assert_eq!(
            pareto_front(&pts),
            [true, true, false, true, false, false, true, false, false]
        );
        assert!(pareto_front(&[]).is_empty());
        assert_eq!(pareto_front(&[(3.0, 3.0)]), [true]);
    }

    #[test]
    fn variants_follow_the_config_and_drop_duplicates() {
        let c = SweepConfig {
            // 9216 rays: ×0.25 and ×0.5 both round to θa = 2, θd = 1.
            factors: vec![0.25, 0.5, 1.0, 4.0],
            ..SweepConfig::default()
        };
        let (v, skipped) = c.variants().unwrap();
        assert_eq!(skipped, ["lipac ×0.5"]);
        let t = |name: &str| {
            v.iter()
                .find(|x| x.name == name)
                .and_then(|x| x.lipac.as_ref())
                .map(|l| l.thresholds)
                .unwrap()
        };
        // 4 · 9216 / 2073600 · 1000 = 17.8 → 18; · 100 → 1.78 → 2.
        let t4 = t("lipac ×4");
        assert_eq!(
            (t4.theta_a, t4.theta_d, t4.sigma_a, t4.sigma_o),
            (18, 2, 18, 2)
        );
        let t1 = t("lipac ×1");
        assert_eq!((t1.theta_a, t1.theta_d), (4, 1));
        assert_eq!(
            (t("lipac n_a 1 n_d 15").n_a, t("lipac n_a 4 n_d 30").n_d),
            (1, 30)
        );
        let cells: Vec<f64> = v
            .iter()
            .filter(|x| x.family == Family::CellSize)
            .map(|x| x.lipac.as_ref().unwrap().cell_size)
            .collect();
        assert_eq!(cells, [16.0, 64.0]);
        let bad = SweepConfig {
            factors: vec![0.0],
            ..SweepConfig::default()
        };
        assert!(bad.variants().is_err());
        let bad = SweepConfig {
            baselines: vec![StrategyKind::Lipac],
            ..SweepConfig::default()
        };
        assert!(bad.variants().is_err());
    }
}
