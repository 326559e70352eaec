//! Closed-loop thresholds in the comparison (`lipac compare --memory-budget
//! MiB`, `--escape-target F`, `--camera jump`): LiPaC with the Manager's
//! controller ([`lipac_core::controller`]) beside the other strategies, and
//! the report's section on it.
//!
//! * `lipac-budget`: LiPaC holding a memory budget (the report's memory:
//!   BLASes + TLAS + LiPaC's buffers; the Manager's accounting of it is
//!   [`lipac_core::Manager::controlled_bytes`], the unit cube's BLAS aside,
//!   which the budget given to the Manager leaves out).
//! * `lipac-escape`: LiPaC holding an escape fraction.
//! * The section: per controlled run, memory against the budget after
//!   warm-up ([`SETTLE_FRAMES`]) and after the camera jump; the escape
//!   fraction of every LiPaC run against its real error (the previous
//!   frame's, whose hits the fraction counts), with Pearson's and
//!   Spearman's correlation over all (frame, configuration) points; plots
//!   [`PLOTS`].

use std::fmt::Write as _;

use lipac_core::controller::{ControlTarget, ControllerConfig};

use crate::camera::CameraPath;
use crate::compare::{make_strategy, CompareConfig, CompareReport, Contender, SceneChoice};
use crate::error::SimError;
use crate::memory::MemoryModel;
use crate::plots::{Axis, Color, Plot, Series, Shape};
use crate::scene::Scene;
use crate::snapshot::Snapshot;
use crate::strategy::lipac::{Lipac, LipacConfig};

const MIB: f64 = 1024.0 * 1024.0;

/// Frames after which a controlled run counts as warmed up (the
/// controller's 30 warm-up frames plus the time the caches take to fill).
pub const SETTLE_FRAMES: u32 = 60;

/// Frames after a camera jump that the report lists separately.
pub const JUMP_WINDOW: u32 = 60;

/// Names of the plot files the section adds to the report folder.
pub const PLOTS: [&str; 3] = [
    "controller_memory.svg",
    "threshold_scale.svg",
    "escape_vs_error.svg",
];

/// The camera path of a closed-loop comparison (`lipac compare --camera`;
/// `lipac record` has its own [`crate::record::CameraChoice`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ClosedLoopPath {
    /// The paper's fly-through (270 frames).
    #[default]
    Flythrough,
    /// [`CameraPath::city_jump`]'s two views, 135 frames each (a jump at
    /// frame 135; 270 frames).
    Jump,
}

impl ClosedLoopPath {
    /// Frame of the jump, if any.
    pub const JUMP_AT: u32 = 135;

    /// The path for `scene`.
    pub fn path(self, scene: &Scene, aspect: f32) -> CameraPath {
        match self {
            Self::Flythrough => CameraPath::flythrough(scene, aspect),
            Self::Jump => {
                let j = CameraPath::city_jump(scene, aspect);
                CameraPath::jump(
                    j.camera_at(0),
                    j.camera_at(j.frames() - 1),
                    Self::JUMP_AT,
                    2 * Self::JUMP_AT,
                )
            }
        }
    }
}

/// The closed-loop runs to add to a comparison.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ClosedLoopOptions {
    /// `lipac-budget` with this budget, MiB.
    pub memory_budget_mib: Option<f64>,
    /// `lipac-escape` with this escape fraction.
    pub escape_target: Option<f64>,
    /// The camera path.
    pub camera: ClosedLoopPath,
}

/// The controller gains of the comparison: the defaults'
/// ([`ControllerConfig::default`]) with a scale of up to 1024, integral
/// gain 0.8 (27x), over-budget weight 3 and a step of up to 0.4 in ln s
/// per frame. The step: a budget of 13 MiB on the city's jump path
/// settles at a scale of ~640 (ln s ≈ 6.5), which a step of 0.2 reached
/// only after ~40 frames over the budget; at 0.4 (with the gain to use
/// it) no frame is more than 5 % over (docs/EVALUATION.md, "A default
/// within 1.15x the oracle"). The scale's range: LiPaC's default rule
/// ([`LipacConfig::DEFAULT_DECAYED`]) activates on a single hit and
/// deactivates below 0.2 hits per frame at 1080p, so a scale of 32 (the
/// library default's ceiling) leaves every cell a path met in the last
/// ~20 frames active; 1024 reaches deactivation at 205 (0.9 hits per frame
/// at 128 x 72; docs/EVALUATION.md, "A default within 1.15x the oracle").
/// At 9,216 camera rays
/// per frame most of LiPaC's memory does not depend on the thresholds
/// (pinned terrain, shared BLASes other active instances use, counting
/// boxes): street level of the jump path moves 14.2 → 12.8 MiB for scale
/// 1 → 32, about 0.03 % per 1 % of scale, so the defaults, stable on a plant
/// ten times as sensitive, follow it far too slowly; under the decayed rule
/// the plant reacts within the read-back latency, and a scale overshoot of
/// this gain moves memory by about 1 % (docs/EVALUATION.md, "Closed-loop
/// thresholds").
pub fn sim_controller() -> ControllerConfig {
    let d = ControllerConfig::default();
    ControllerConfig {
        max_scale: 1024.0,
        ki: 0.8,
        over_gain: 3.0,
        max_step: 0.4,
        tlas_record_bytes: crate::memory::TLAS_BYTES_PER_INSTANCE,
        ..d
    }
}

/// LiPaC's default configuration for `rays_per_frame` holding `target`
/// ([`with_target`]).
pub fn lipac_with_target(
    rays_per_frame: u64,
    target: ControlTarget,
) -> Result<LipacConfig, SimError> {
    Ok(with_target(
        LipacConfig::for_rays_per_frame(rays_per_frame)?,
        target,
    ))
}

/// `base` holding `target` with [`sim_controller`]. A memory budget is a
/// ceiling here: the scale never falls below 1 (`min_scale` = 1), since
/// spending spare budget by lowering the thresholds drove the scale to its
/// floor wherever the scene needed less than the budget (high above the
/// city), and it then rose too late when the camera came down
/// (docs/EVALUATION.md).
pub fn with_target(base: LipacConfig, target: ControlTarget) -> LipacConfig {
    let mut controller = sim_controller();
    controller.tlas_record_bytes = base.memory.tlas_bytes_per_instance();
    if matches!(target, ControlTarget::MemoryBudget { .. }) {
        controller.min_scale = 1.0;
    }
    LipacConfig {
        target: Some(target),
        controller,
        ..base
    }
}

/// The largest memory budget, bytes (2^63: 8 EiB).
pub const MAX_BUDGET_BYTES: u64 = 1 << 63;

/// The Manager's budget for a report memory budget of `mib` MiB: the unit
/// cube's BLAS (the report counts it, the Manager does not hold it) left
/// out. NaN, infinite, zero, negative, budgets below the unit cube and
/// budgets above [`MAX_BUDGET_BYTES`] are errors.
pub fn manager_budget(mib: f64) -> Result<ControlTarget, SimError> {
    manager_budget_with(mib, &MemoryModel::default())
}

/// [`manager_budget`] on a device of `memory`'s sizes (its unit cube).
pub fn manager_budget_with(mib: f64, memory: &MemoryModel) -> Result<ControlTarget, SimError> {
    let bytes = mib * MIB;
    let cube = memory.blas_bytes(12);
    if !bytes.is_finite() || bytes < (cube + 1) as f64 {
        return Err(SimError::BadValue(format!(
            "--memory-budget {mib} MiB must be a positive number above the unit cube's {cube} B"
        )));
    }
    // Refused, not silently capped: a budget beyond what any bytes count
    // holds is no budget a user means.
    if bytes > MAX_BUDGET_BYTES as f64 {
        return Err(SimError::BadValue(format!(
            "--memory-budget {mib} MiB is above the largest budget, {} MiB (8 EiB)",
            MAX_BUDGET_BYTES / (1 << 20)
        )));
    }
    Ok(ControlTarget::MemoryBudget {
        bytes: bytes as u64 - cube,
    })
}

/// The contenders: `config.strategies` and the controlled LiPaC runs.
pub fn contenders(
    scene: &Scene,
    config: &CompareConfig,
    opts: &ClosedLoopOptions,
) -> Result<Vec<Contender>, SimError> {
    // LiPaC as the comparison configures it (cells, merge levels, rise
    // shift, start), the controlled runs too.
    let base = crate::compare::lipac_config_of(config)?;
    let mut out = Vec::new();
    for &k in &config.strategies {
        out.push(Contender {
            name: k.name().to_string(),
            strategy: make_strategy(k, scene, &base)?,
        });
    }
    if let Some(mib) = opts.memory_budget_mib {
        let c = with_target(base.clone(), manager_budget_with(mib, &base.memory)?);
        out.push(Contender {
            name: "lipac-budget".into(),
            strategy: Box::new(Lipac::new(scene, c)?),
        });
    }
    if let Some(fraction) = opts.escape_target {
        let c = with_target(base.clone(), ControlTarget::EscapeFraction { fraction });
        out.push(Contender {
            name: "lipac-escape".into(),
            strategy: Box::new(Lipac::new(scene, c)?),
        });
    }
    Ok(out)
}

/// Runs the comparison of `choice` along `opts.camera` with the controlled
/// runs of `opts` added, capturing `snapshots`.
pub fn run(
    choice: SceneChoice,
    seed: Option<u64>,
    config: &CompareConfig,
    opts: &ClosedLoopOptions,
    snapshots: &[u32],
    progress: &mut dyn FnMut(u32, u32),
) -> Result<(CompareReport, Vec<Snapshot>), SimError> {
    let mut scene = Scene::generate(&choice.config(seed))?;
    let aspect = config.width as f32 / config.height.max(1) as f32;
    let path = opts.camera.path(&scene, aspect);
    let contenders = contenders(&scene, config, opts)?;
    crate::compare::run_path(
        choice.name(),
        &mut scene,
        &path,
        config,
        contenders,
        snapshots,
        progress,
    )
}

/// Memory against the budget of one controlled run.
#[derive(Clone, Debug, PartialEq)]
pub struct BudgetFigures {
    /// Strategy name.
    pub name: String,
    /// The budget as the report counts memory, bytes.
    pub budget_bytes: u64,
    /// Frames from [`SETTLE_FRAMES`] on.
    pub frames: usize,
    /// Mean memory over those, bytes (`None` without such frames, as the
    /// two figures after it).
    pub mean_bytes: Option<f64>,
    /// Largest `|memory / budget − 1|` over those.
    pub max_deviation: Option<f64>,
    /// Largest `memory / budget − 1` (an overrun; negative: always under).
    pub max_overrun: Option<f64>,
    /// Frames more than 5 % off the budget.
    pub frames_outside: usize,
    /// Frames more than 5 % over the budget: the budget not held.
    pub frames_over: usize,
    /// Frames more than 5 % under the budget while the scale is still above
    /// 1 (spare budget the controller has not given back yet). Under the
    /// budget at scale 1 is a scene that needs less: a budget is a ceiling
    /// here ([`lipac_with_target`]).
    pub frames_spare: usize,
    /// The same over the [`JUMP_WINDOW`] frames after each camera jump
    /// (`None` without a jump in the settled frames).
    pub jump_max_deviation: Option<f64>,
    /// Frames the controller reported the budget unreachable.
    pub unreachable_frames: usize,
    /// Threshold scale at the end.
    pub final_scale: f64,
}

impl BudgetFigures {
    /// One line for the terminal: budget, the settled frames' figures (or
    /// that the run has none from [`SETTLE_FRAMES`] on), the jump, the
    /// final scale. Never `inf` or `NaN`.
    pub fn summary_line(&self) -> String {
        let mib = |b: f64| b / MIB;
        let settled = match (self.mean_bytes, self.max_deviation, self.max_overrun) {
            (Some(mean), Some(dev), Some(over)) => format!(
                "mean {:.2} MiB, max deviation {:.1} %, max overrun {:+.1} %, \
                 {} of {} frames > 5 % off ({} over, {} under at scale > 1)",
                mib(mean),
                100.0 * dev,
                100.0 * over,
                self.frames_outside,
                self.frames,
                self.frames_over,
                self.frames_spare,
            ),
            _ => "no frames to measure (the run ends before; give more --frames)".into(),
        };
        format!(
            "{}: budget {:.2} MiB, frames {SETTLE_FRAMES}+: {settled}, after the jump {}, \
             final scale {:.3}{}",
            self.name,
            mib(self.budget_bytes as f64),
            self.jump_max_deviation
                .map_or("-".into(), |d| format!("{:.1} %", 100.0 * d)),
            self.final_scale,
            if self.unreachable_frames > 0 {
                format!(", budget unreachable in {} frames", self.unreachable_frames)
            } else {
                String::new()
            }
        )
    }
}

/// [`BudgetFigures`] of every run with a memory budget; `cuts`: the frames
/// the camera jumps at.
pub fn budget_figures(r: &CompareReport, cuts: &[u32]) -> Vec<BudgetFigures> {
    let cube = r.device_profile.memory_model().blas_bytes(12);
    let mut out = Vec::new();
    for st in &r.strategies {
        let Some(target) = st.frames.iter().find_map(|m| m.control_target) else {
            continue;
        };
        // An escape target is a fraction below 1; budgets are bytes.
        if target < 1.0 {
            continue;
        }
        let budget = (target as u64).saturating_add(cube);
        let settled: Vec<_> = st
            .frames
            .iter()
            .filter(|m| m.frame >= SETTLE_FRAMES)
            .collect();
        let dev = |b: u64| b as f64 / budget as f64 - 1.0;
        let max_dev =
            |it: &mut dyn Iterator<Item = u64>| it.map(|b| dev(b).abs()).fold(0.0, f64::max);
        let jump = cuts
            .iter()
            .filter(|&&c| c >= SETTLE_FRAMES)
            .map(|&c| {
                max_dev(
                    &mut settled
                        .iter()
                        .filter(|m| m.frame >= c && m.frame < c + JUMP_WINDOW)
                        .map(|m| m.total_bytes()),
                )
            })
            .reduce(f64::max);
        out.push(BudgetFigures {
            name: st.name.clone(),
            budget_bytes: budget,
            frames: settled.len(),
            mean_bytes: (!settled.is_empty()).then(|| {
                settled.iter().map(|m| m.total_bytes() as f64).sum::<f64>() / settled.len() as f64
            }),
            max_deviation: (!settled.is_empty())
                .then(|| max_dev(&mut settled.iter().map(|m| m.total_bytes()))),
            max_overrun: settled
                .iter()
                .map(|m| dev(m.total_bytes()))
                .reduce(f64::max),
            frames_outside: settled
                .iter()
                .filter(|m| dev(m.total_bytes()).abs() > 0.05)
                .count(),
            frames_over: settled
                .iter()
                .filter(|m| dev(m.total_bytes()) > 0.05)
                .count(),
            frames_spare: settled
                .iter()
                .filter(|m| {
                    dev(m.total_bytes()) < -0.05 && m.threshold_scale.unwrap_or(1.0) > 1.0 + 1e-9
                })
                .count(),
            jump_max_deviation: jump,
            unreachable_frames: st.frames.iter().filter(|m| m.control_unreachable).count(),
            final_scale: st
                .frames
                .last()
                .and_then(|m| m.threshold_scale)
                .unwrap_or(1.0),
        });
    }
    out
}

/// Pearson's and Spearman's correlation of paired samples.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Correlation {
    /// Pairs.
    pub points: usize,
    /// Pearson's r (NaN when a side is constant).
    pub pearson: f64,
    /// Spearman's rank correlation (average ranks for ties).
    pub spearman: f64,
}

/// Pearson's r of `x` and `y` (equal lengths; NaN for fewer than 2 points
/// or a constant side).
///
/// ```
/// use lipac_sim::closed_loop::pearson;
/// assert!((pearson(&[1.0, 2.0, 3.0], &[2.0, 4.0, 6.5]) - 0.9986).abs() < 1e-3);
/// assert!(pearson(&[1.0, 1.0], &[1.0, 2.0]).is_nan());
/// ```
pub fn pearson(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len().min(y.len());
    if n < 2 {
        return f64::NAN;
    }
    let mx = x[..n].iter().sum::<f64>() / n as f64;
    let my = y[..n].iter().sum::<f64>() / n as f64;
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in x[..n].iter().zip(&y[..n]) {
        sxy += (a - mx) * (b - my);
        sxx += (a - mx) * (a - mx);
        syy += (b - my) * (b - my);
    }
    if sxx == 0.0 || syy == 0.0 {
        return f64::NAN;
    }
    sxy / (sxx * syy).sqrt()
}

/// Ranks of `v` (1-based, ties get their average rank).
fn ranks(v: &[f64]) -> Vec<f64> {
    let mut idx: Vec<usize> = (0..v.len()).collect();
    idx.sort_by(|&a, &b| v[a].total_cmp(&v[b]));
    let mut r = vec![0.0; v.len()];
    let mut i = 0;
    while i < idx.len() {
        let mut j = i;
        while j + 1 < idx.len() && v[idx[j + 1]] == v[idx[i]] {
            j += 1;
        }
        let avg = (i + j) as f64 / 2.0 + 1.0;
        for &k in &idx[i..=j] {
            r[k] = avg;
        }
        i = j + 1;
    }
    r
}

/// Spearman's rank correlation of `x` and `y`.
///
/// ```
/// use lipac_sim::closed_loop::spearman;
/// // Monotone but not linear: rank correlation 1.
/// assert!((spearman(&[1.0, 2.0, 3.0, 4.0], &[1.0, 8.0, 27.0, 64.0]) - 1.0).abs() < 1e-12);
/// assert!((spearman(&[1.0, 2.0, 3.0], &[3.0, 2.0, 1.0]) + 1.0).abs() < 1e-12);
/// ```
pub fn spearman(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len().min(y.len());
    pearson(&ranks(&x[..n]), &ranks(&y[..n]))
}

/// Per LiPaC run: (escape fraction counted in frame `f + 1`, error of frame
/// `f`), the fraction's hits being those frame `f` traced. Frames before
/// [`SETTLE_FRAMES`] are left out (cold start).
pub fn escape_error_pairs(r: &CompareReport) -> Vec<(String, Vec<(f64, f64)>)> {
    r.strategies
        .iter()
        .filter_map(|st| {
            let pts: Vec<(f64, f64)> = st
                .frames
                .windows(2)
                .filter(|w| w[0].frame >= SETTLE_FRAMES && w[0].error.is_finite())
                .filter_map(|w| w[1].escape_fraction.map(|e| (e, w[0].error)))
                .collect();
            (!pts.is_empty()).then(|| (st.name.clone(), pts))
        })
        .collect()
}

/// The correlation of escape fraction and error over every LiPaC run's
/// pairs ([`escape_error_pairs`]), `None` without any.
pub fn escape_error_correlation(r: &CompareReport) -> Option<Correlation> {
    let (x, y): (Vec<f64>, Vec<f64>) = escape_error_pairs(r)
        .into_iter()
        .flat_map(|(_, p)| p)
        .unzip();
    (!x.is_empty()).then(|| Correlation {
        points: x.len(),
        pearson: pearson(&x, &y),
        spearman: spearman(&x, &y),
    })
}

/// The report's section "Closed-loop thresholds", `None` when no run
/// counted escape fractions (no LiPaC run).
pub fn markdown(r: &CompareReport, cuts: &[u32]) -> Option<String> {
    let pairs = escape_error_pairs(r);
    if pairs.is_empty() {
        return None;
    }
    let mut s = String::new();
    let _ = writeln!(s, "\n## Closed-loop thresholds\n");
    let budgets = budget_figures(r, cuts);
    if !budgets.is_empty() {
        let _ = writeln!(
            s,
            "Memory against the budget from frame {SETTLE_FRAMES} on{}:\n",
            if cuts.is_empty() {
                String::new()
            } else {
                format!(
                    " (camera jump at frame {}; the {JUMP_WINDOW} frames after it also alone)",
                    cuts.iter()
                        .map(u32::to_string)
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            }
        );
        let _ = writeln!(
            s,
            "| run | budget MiB | mean MiB | max deviation | max overrun | frames > 5 % off | > 5 % over | > 5 % under at scale > 1 | after the jump | unreachable frames | final scale |"
        );
        let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
        for b in &budgets {
            let _ = writeln!(
                s,
                "| {} | {:.2} | {} | {} | {} | {} of {} | {} | {} | {} | {} | {:.3} |",
                b.name,
                b.budget_bytes as f64 / MIB,
                b.mean_bytes
                    .map_or("–".into(), |m| format!("{:.2}", m / MIB)),
                b.max_deviation
                    .map_or("–".into(), |d| format!("{:.1} %", 100.0 * d)),
                b.max_overrun
                    .map_or("–".into(), |d| format!("{:+.1} %", 100.0 * d)),
                b.frames_outside,
                b.frames,
                b.frames_over,
                b.frames_spare,
                b.jump_max_deviation
                    .map_or("–".into(), |d| format!("{:.1} %", 100.0 * d)),
                b.unreachable_frames,
                b.final_scale
            );
        }
        let _ = writeln!(s);
    }
    let _ = writeln!(
        s,
        "Escape fraction (share of counted hits ending in counting boxes, no ground truth) \
         against the real error of the frame whose hits it counts, frames {SETTLE_FRAMES}+:\n"
    );
    let _ = writeln!(
        s,
        "| run | frames | mean escape | mean error | Pearson | Spearman |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|");
    for (name, p) in &pairs {
        let (x, y): (Vec<f64>, Vec<f64>) = p.iter().copied().unzip();
        let _ = writeln!(
            s,
            "| {name} | {} | {:.4} | {:.4} | {:.3} | {:.3} |",
            p.len(),
            x.iter().sum::<f64>() / x.len() as f64,
            y.iter().sum::<f64>() / y.len() as f64,
            pearson(&x, &y),
            spearman(&x, &y)
        );
    }
    if let Some(c) = escape_error_correlation(r) {
        let _ = writeln!(
            s,
            "| all LiPaC runs | {} | | | {:.3} | {:.3} |",
            c.points, c.pearson, c.spearman
        );
    }
    let _ = writeln!(s);
    for (file, title) in PLOTS.iter().zip([
        "Controlled memory against the budget",
        "Threshold scale per frame",
        "Escape fraction against error",
    ]) {
        let _ = writeln!(s, "- [{title}]({file})\n\n  ![{title}]({file})\n");
    }
    Some(s)
}

/// The section's [`PLOTS`], `(file name, SVG)`; empty without LiPaC runs.
pub fn plots(r: &CompareReport) -> Result<Vec<(&'static str, String)>, SimError> {
    let pairs = escape_error_pairs(r);
    if pairs.is_empty() {
        return Ok(Vec::new());
    }
    let last = f64::from(r.frames.saturating_sub(1).max(1));
    let lipac: Vec<_> = r
        .strategies
        .iter()
        .filter(|s| s.frames.iter().any(|m| m.threshold_scale.is_some()))
        .collect();

    // Memory of the LiPaC runs and each budget.
    let budgets = budget_figures(r, &[]);
    let mut values: Vec<f64> = lipac
        .iter()
        .flat_map(|s| s.frames.iter().map(|m| m.total_bytes() as f64 / MIB))
        .collect();
    values.extend(budgets.iter().map(|b| b.budget_bytes as f64 / MIB));
    values.push(0.0);
    let mut mem = Plot::new(
        "LiPaC memory against the budget",
        Axis::whole("frame", 0.0..last),
        Axis::linear("MiB", &values),
    );
    for (i, st) in lipac.iter().enumerate() {
        let pts = st
            .frames
            .iter()
            .map(|m| (f64::from(m.frame), m.total_bytes() as f64 / MIB))
            .collect();
        mem.series.push(Series::line(&st.name, i, pts));
    }
    for b in &budgets {
        let y = b.budget_bytes as f64 / MIB;
        mem.series.push(Series {
            name: Some(format!("budget of {}", b.name)),
            color: Color::Rgb(0, 0, 0),
            shape: Shape::Dashed(vec![(0.0, y), (last, y)]),
        });
    }

    // Threshold scale.
    let scales: Vec<f64> = lipac
        .iter()
        .flat_map(|s| s.frames.iter().filter_map(|m| m.threshold_scale))
        .chain([1.0])
        .collect();
    let mut scale = Plot::new(
        "Threshold scale per frame",
        Axis::whole("frame", 0.0..last),
        Axis::auto("scale on θa, θd, σa, σo", &scales),
    );
    for (i, st) in lipac.iter().enumerate() {
        let pts = st
            .frames
            .iter()
            .filter_map(|m| m.threshold_scale.map(|s| (f64::from(m.frame), s)))
            .collect();
        scale.series.push(Series::line(&st.name, i, pts));
    }

    // Escape fraction against error.
    // (The floors keep an axis of zeros non-empty.)
    let xs: Vec<f64> = pairs
        .iter()
        .flat_map(|(_, p)| p.iter().map(|q| q.0))
        .chain([1e-3])
        .collect();
    let ys: Vec<f64> = pairs
        .iter()
        .flat_map(|(_, p)| p.iter().map(|q| q.1))
        .chain([1e-3])
        .collect();
    let title = match escape_error_correlation(r) {
        Some(c) => format!(
            "Escape fraction against error (Pearson {:.2}, Spearman {:.2})",
            c.pearson, c.spearman
        ),
        None => "Escape fraction against error".into(),
    };
    let mut scatter = Plot::new(
        &title,
        Axis::linear("escape fraction (counted hits in counting boxes)", &xs),
        Axis::linear("relative RMSE of the indirect light", &ys),
    );
    for (i, (name, p)) in pairs.iter().enumerate() {
        scatter.series.push(Series {
            name: Some(name.clone()),
            color: Color::Palette(i),
            shape: Shape::Points {
                at: p.clone(),
                r: 2,
                filled: true,
            },
        });
    }
    Ok(vec![
        (PLOTS[0], mem.svg()?),
        (PLOTS[1], scale.svg()?),
        (PLOTS[2], scatter.svg()?),
    ])
}

#[cfg(test)]
mod tests;
