//! Pareto fronts of (cost, error) ([`pareto_front`]), marked on every
//! point of a sweep per scene ([`mark_fronts`]), for the costs of
//! [`COSTS`].

use super::{SweepPoint, SweepReport};
use crate::strategy::StrategyKind;

/// A cost plotted against error: file name, title, axis label, value.
pub type Cost = (
    &'static str,
    &'static str,
    &'static str,
    fn(&SweepPoint) -> f64,
);

/// The costs with a Pareto front, in [`SweepPoint::fronts`] order, and the
/// plot files [`super::write_sweep`] writes for them.
pub const COSTS: [Cost; 4] = [
    (
        "sweep_time.svg",
        "Frame time (AS work + trace, measured on CPU) against error",
        "mean frame time (BLAS builds, refits, TLAS, trace), CPU ms",
        |p| p.summary.mean_frame_ms,
    ),
    (
        "sweep_gpu_time.svg",
        "Modelled GPU frame time against error (the device profile's rates)",
        "modelled GPU frame time (AS work + trace), ms",
        |p| p.summary.mean_gpu_frame_ms,
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
/// Recomputes the Pareto flags of every point, per scene (see the module
/// docs; the references, the oracle and hindsight, are never on a front).
pub fn mark_fronts(report: &mut SweepReport) {
    let names: Vec<String> = report.scenes.iter().map(|s| s.name.clone()).collect();
    for name in names {
        let mut idx = Vec::new();
        let mut pts = Vec::new();
        for (i, p) in report.points.iter().enumerate() {
            let reference =
                StrategyKind::from_name(&p.strategy).is_some_and(StrategyKind::is_reference);
            if p.scene == name && !reference {
                idx.push(i);
                pts.push(p.clone());
            }
        }
        mark_scene_fronts(&mut pts);
        for p in report.points.iter_mut().filter(|p| p.scene == name) {
            p.set_fronts([false; 4]);
        }
        for (i, p) in idx.into_iter().zip(pts) {
            report.points[i] = p;
        }
    }
}

fn mark_scene_fronts(points: &mut [SweepPoint]) {
    let fronts = COSTS.map(|(_, _, _, cost)| {
        pareto_front(
            &points
                .iter()
                .map(|p| (cost(p), p.summary.mean_error))
                .collect::<Vec<_>>(),
        )
    });
    for (i, p) in points.iter_mut().enumerate() {
        p.set_fronts(fronts.each_ref().map(|f| f[i]));
    }
}
