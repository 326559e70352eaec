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
//! [`Thresholds::for_rays_per_frame`](lipac_core::thresholds::Thresholds::for_rays_per_frame)`(f · rays)`: θa, θd, σa, σo all scale
//! by `f`, keeping the paper's 10:1 ratio of activation to deactivation,
//! with the same rounding (at least 1, lower below upper). At small images
//! low factors round to the same thresholds; such duplicates are run once
//! (the later names are listed in [`SweepReport::skipped`]).
//!
//! For each scene and each cost of [`COSTS`] (frame time measured on the
//! CPU, modelled GPU frame time, memory, builds) the points not
//! dominated in (cost, error) form the Pareto front ([`pareto_front`]). The
//! oracle and the hindsight references
//! ([`crate::strategy::StrategyKind::is_reference`]) are plotted but kept
//! off the fronts: they read the ground truth's hits, no renderer can do
//! that, and the oracle's zero error would dominate every costlier
//! configuration.
//!
//! **On many machines.** [`shard`] splits a sweep into disjoint parts
//! (`lipac sweep --shard K/N`) and merges their results into the report of
//! one run (`lipac sweep --merge DIR...`); docs/SCALING_OUT.md shows Slurm,
//! Kubernetes and GNU parallel set-ups.
//!
//! The modules: [`variants`] (what is run), [`results`] (what comes back),
//! [`pareto`] (the fronts and the costs they are over), [`csv`] and
//! [`markdown`] (two of the files [`write_sweep`] writes; the plots are
//! [`crate::plots::pareto_plot`]), [`dominance`] (where LiPaC's fronts lie
//! below the frustum's and the heuristic's, printed in `sweep.md`),
//! [`shard`] (a sweep in parts).

pub mod csv;
pub mod dominance;
pub mod markdown;
pub mod pareto;
pub mod results;
pub mod shard;
pub mod variants;

use std::path::{Path, PathBuf};

pub use csv::{sweep_csv, SWEEP_CSV_HEADER};
pub use markdown::sweep_markdown;
pub use pareto::{mark_fronts, pareto_front, Cost, COSTS};
pub use results::{SweepPoint, SweepReport, SweepScene};
pub use variants::{
    parse_decayed_spec, parse_decayed_variant, scaled_thresholds, DecayedVariant, Family,
    SweepConfig, Variant,
};

use crate::error::SimError;
use crate::plots::pareto_plot;

/// Runs the sweep. `progress(scene index, scenes, frame, frames)` is called
/// after every frame. The same as [`shard::run_shard`] of shard 1/1,
/// [`shard::merge`]d; `lipac sweep --shard K/N` runs a part of it.
pub fn run(
    config: &SweepConfig,
    progress: &mut dyn FnMut(usize, usize, u32, u32),
) -> Result<SweepReport, SimError> {
    shard::merge(&[shard::run_shard(config, shard::Shard::WHOLE, progress)?])
}

/// Names of every file [`write_sweep`] writes.
pub const SWEEP_FILES: [&str; 7] = [
    "sweep.md",
    "sweep.json",
    "sweep.csv",
    COSTS[0].0,
    COSTS[1].0,
    COSTS[2].0,
    COSTS[3].0,
];

/// Writes `sweep.md`, `sweep.json`, `sweep.csv` and the four Pareto plots
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
        pareto_plot(r, 3)?,
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
mod tests;
