//! Where LiPaC's front lies below a baseline's, error level by error level
//! ([`front_dominance`]), and the per-scene summary `sweep.md` prints
//! ([`dominance_markdown`]).
//!
//! A front is read as a step function of the error level `e`: the least
//! cost of any of a group's points whose mean error is at most `e`
//! ([`front_at`]); a group with no such point has no value there. LiPaC's
//! group is every `lipac` and `lipac-latency` point of the scene; a
//! baseline's group is its strategy's points (usually one). Both step
//! functions only change at the errors of their points, so the verdict is
//! constant between consecutive errors and the intervals are exact.

use std::fmt::Write as _;

use super::{SweepPoint, SweepReport, COSTS};
use crate::strategy::StrategyKind;

/// How LiPaC's front compares with a baseline's at one error level.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// Both have a point with error ≤ e; LiPaC's least cost is lower.
    Below,
    /// Both have one; LiPaC's least cost is equal or higher.
    NotBelow,
    /// Only LiPaC has a point with error ≤ e.
    LipacOnly,
    /// Only the baseline has one.
    BaselineOnly,
    /// Neither has one.
    Neither,
}

impl Verdict {
    /// Short text for reports.
    pub fn label(self) -> &'static str {
        match self {
            Self::Below => "LiPaC below",
            Self::NotBelow => "LiPaC not below",
            Self::LipacOnly => "LiPaC only",
            Self::BaselineOnly => "baseline only",
            Self::Neither => "neither",
        }
    }
}

/// Error levels `[lo, hi)` over which the verdict is the same (`hi` is
/// infinite for the last).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Interval {
    /// Lowest error level of the interval.
    pub lo: f64,
    /// First error level past it.
    pub hi: f64,
    /// The verdict over the interval.
    pub verdict: Verdict,
}

/// The least cost of any `(cost, error)` point with error ≤ `e`, if any
/// (points with a NaN coordinate never count).
///
/// ```
/// use lipac_sim::sweep::dominance::front_at;
/// let pts = [(10.0, 0.02), (5.0, 0.1)];
/// assert_eq!(front_at(&pts, 0.01), None);
/// assert_eq!(front_at(&pts, 0.05), Some(10.0));
/// assert_eq!(front_at(&pts, 0.1), Some(5.0));
/// ```
pub fn front_at(points: &[(f64, f64)], e: f64) -> Option<f64> {
    points
        .iter()
        .filter(|(c, err)| !c.is_nan() && *err <= e)
        .map(|&(c, _)| c)
        .min_by(f64::total_cmp)
}

/// The verdict of `lipac`'s front against `baseline`'s at every error
/// level ≥ `min_error`, as maximal intervals of one verdict.
///
/// ```
/// use lipac_sim::sweep::dominance::{front_dominance, Verdict};
/// // LiPaC: 7 MiB at 0.04; frustum: 11 MiB at 0.02.
/// let d = front_dominance(&[(7.0, 0.04)], &[(11.0, 0.02)], 0.005);
/// let v: Vec<_> = d.iter().map(|i| (i.lo, i.verdict)).collect();
/// assert_eq!(v, [(0.005, Verdict::Neither), (0.02, Verdict::BaselineOnly), (0.04, Verdict::Below)]);
/// ```
pub fn front_dominance(
    lipac: &[(f64, f64)],
    baseline: &[(f64, f64)],
    min_error: f64,
) -> Vec<Interval> {
    let mut levels: Vec<f64> = lipac
        .iter()
        .chain(baseline)
        .map(|&(_, e)| e)
        .filter(|e| e.is_finite() && *e >= min_error)
        .collect();
    levels.push(min_error);
    levels.sort_by(f64::total_cmp);
    levels.dedup();
    let mut out: Vec<Interval> = Vec::new();
    for (i, &e) in levels.iter().enumerate() {
        let verdict = match (front_at(lipac, e), front_at(baseline, e)) {
            (Some(l), Some(b)) if l < b => Verdict::Below,
            (Some(_), Some(_)) => Verdict::NotBelow,
            (Some(_), None) => Verdict::LipacOnly,
            (None, Some(_)) => Verdict::BaselineOnly,
            (None, None) => Verdict::Neither,
        };
        let hi = levels.get(i + 1).copied().unwrap_or(f64::INFINITY);
        match out.last_mut() {
            Some(last) if last.verdict == verdict => last.hi = hi,
            _ => out.push(Interval { lo: e, hi, verdict }),
        }
    }
    out
}

/// The error level from which [`dominance_markdown`] compares.
pub const MIN_ERROR: f64 = 0.005;

fn is_lipac(p: &SweepPoint) -> bool {
    p.strategy == StrategyKind::Lipac.name() || p.strategy == StrategyKind::LipacLatency.name()
}

/// Per scene, for each cost of [`COSTS`] but builds and each of the
/// frustum and heuristic baselines present: the intervals of error levels
/// ≥ [`MIN_ERROR`] and their verdicts. Empty when the sweep has no LiPaC
/// point or neither baseline.
pub fn dominance_markdown(r: &SweepReport) -> String {
    let mut s = String::new();
    let baselines = [StrategyKind::Frustum, StrategyKind::Heuristic];
    for sc in &r.scenes {
        let pts: Vec<&SweepPoint> = r.points.iter().filter(|p| p.scene == sc.name).collect();
        let lipac: Vec<&SweepPoint> = pts.iter().copied().filter(|p| is_lipac(p)).collect();
        if lipac.is_empty() {
            continue;
        }
        let mut lines = Vec::new();
        for (file, _, _, cost) in COSTS.iter().filter(|c| c.0 != "sweep_builds.svg") {
            let name = match *file {
                "sweep_time.svg" => "frame time (CPU, ms)",
                "sweep_gpu_time.svg" => "modelled GPU time (ms)",
                "sweep_memory.svg" => "memory (MiB)",
                other => other,
            };
            let xy = |g: &[&SweepPoint]| -> Vec<(f64, f64)> {
                g.iter().map(|p| (cost(p), p.summary.mean_error)).collect()
            };
            for b in baselines {
                let base: Vec<&SweepPoint> = pts
                    .iter()
                    .copied()
                    .filter(|p| p.strategy == b.name())
                    .collect();
                if base.is_empty() {
                    continue;
                }
                let (l, bx) = (xy(&lipac), xy(&base));
                let text: Vec<String> = front_dominance(&l, &bx, MIN_ERROR)
                    .iter()
                    .map(|i| {
                        let range = if i.hi.is_finite() {
                            format!("[{:.4}, {:.4})", i.lo, i.hi)
                        } else {
                            format!("≥ {:.4}", i.lo)
                        };
                        // The two least costs where the interval starts.
                        let at = match (front_at(&l, i.lo), front_at(&bx, i.lo)) {
                            (Some(x), Some(y)) => format!(" ({x:.3} vs {y:.3} from {:.4})", i.lo),
                            _ => String::new(),
                        };
                        format!("{range} {}{at}", i.verdict.label())
                    })
                    .collect();
                lines.push(format!("- {name} vs {}: {}", b.name(), text.join("; ")));
            }
        }
        if lines.is_empty() {
            continue;
        }
        let _ = writeln!(
            s,
            "### {}: LiPaC's front against the baselines' (error ≥ {MIN_ERROR})\n\n\
             A front at error level e is the least cost of the group's points with mean \
             error ≤ e; LiPaC's group is every lipac and lipac-latency point.\n",
            sc.name
        );
        for l in lines {
            let _ = writeln!(s, "{l}");
        }
        s.push('\n');
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn below_where_lipac_is_cheaper_and_not_where_the_baseline_is() {
        // LiPaC: (12, 0.03), (8, 0.06); heuristic (5, 0.2).
        let d = front_dominance(&[(12.0, 0.03), (8.0, 0.06)], &[(5.0, 0.2)], 0.005);
        let v: Vec<_> = d.iter().map(|i| (i.lo, i.hi, i.verdict)).collect();
        assert_eq!(
            v,
            [
                (0.005, 0.03, Verdict::Neither),
                (0.03, 0.2, Verdict::LipacOnly),
                (0.2, f64::INFINITY, Verdict::NotBelow),
            ]
        );
    }

    #[test]
    fn equal_cost_is_not_below_and_nan_points_never_count() {
        let d = front_dominance(&[(5.0, 0.01), (1.0, f64::NAN)], &[(5.0, 0.01)], 0.005);
        assert_eq!(d.last().unwrap().verdict, Verdict::NotBelow);
        assert_eq!(d.len(), 2);
        assert_eq!(front_at(&[(f64::NAN, 0.0)], 1.0), None);
    }

    #[test]
    fn errors_below_the_minimum_start_the_first_interval() {
        // A baseline at error 0 counts from the first level on.
        let d = front_dominance(&[(3.0, 0.05)], &[(20.0, 0.0)], 0.005);
        let v: Vec<_> = d.iter().map(|i| (i.lo, i.verdict)).collect();
        assert_eq!(v, [(0.005, Verdict::BaselineOnly), (0.05, Verdict::Below)]);
    }
}
