//! `sweep.md`: per scene a table of every variant, fronts marked, and
//! where LiPaC's fronts lie below the baselines' ([`sweep_markdown`]).

use std::fmt::Write as _;

use super::dominance::dominance_markdown;
use super::{SweepReport, COSTS};

/// The Markdown report: per scene a table of every variant, fronts marked;
/// then [`dominance_markdown`].
pub fn sweep_markdown(r: &SweepReport) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# lipac sweep: run time, memory and builds against error\n"
    );
    let _ = writeln!(
        s,
        "{} frames per scene (a scene's fly-through, or a trace's own frames and cameras) at {}x{} ({} camera rays per frame). \
         Wall time {:.1} s. Every configuration of a scene renders against the same ground \
         truth (rendered once per frame). Front columns: T = on the (frame time, error) Pareto \
         front (measured on the CPU), G = (modelled GPU frame time, error), M = (memory, error), \
         B = (builds, error); the oracle and hindsight (they read the ground truth's \
         hits) are references, never on a front.\n",
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
             cycles | latency mean | error mean | max | trace ms | frame ms (CPU) | GPU ms (model) | front |"
        );
        let _ = writeln!(
            s,
            "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"
        );
        for p in r.points.iter().filter(|p| p.scene == sc.name) {
            let m = &p.summary;
            let th = p
                .thresholds
                .map(|t| t.map(|v| v.to_string()).join(" "))
                .unwrap_or_else(|| "–".into());
            let front: String = [
                (p.front_time, 'T'),
                (p.front_gpu_time, 'G'),
                (p.front_memory, 'M'),
                (p.front_builds, 'B'),
            ]
            .iter()
            .filter(|(on, _)| *on)
            .map(|(_, c)| *c)
            .collect();
            let _ = writeln!(
                s,
                "| {} | {} | {} | {:.2} ({:.2}) | {:.1} | {} | {} | {:.1} | {:.4} | {:.4} | {:.1} | {:.1} | {:.3} | {} |",
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
                m.mean_frame_ms,
                m.mean_gpu_frame_ms,
                front
            );
        }
        s.push('\n');
    }
    let dominance = dominance_markdown(r);
    if !dominance.is_empty() {
        let _ = write!(s, "## LiPaC's fronts against the baselines'\n\n{dominance}");
    }
    let _ = writeln!(s, "## Plots\n");
    for (file, title, _, _) in COSTS {
        let _ = writeln!(s, "- [{title}]({file})\n\n  ![{title}]({file})\n");
    }
    let device = r.device_profile.describe();
    let _ = writeln!(
        s,
        "Data: [sweep.csv](sweep.csv); everything, with per-frame errors: [sweep.json](sweep.json).\n\n\
         Device profile: {device}. Memory is modelled on its acceleration-structure sizes \
         (docs/MEMORY_MODEL.md). {}",
        r.device_profile.gpu_model().timing_note(&device)
    );
    s
}
