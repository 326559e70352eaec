//! `sweep.csv`: one row per scene and variant ([`sweep_csv`]).

use std::fmt::Write as _;

use super::SweepReport;

/// CSV header of [`sweep_csv`].
pub const SWEEP_CSV_HEADER: &str = "scene,name,family,strategy,factor,cell_size,theta_a,theta_d,sigma_a,sigma_o,n_a,n_d,latency_distance,latency_size,mean_instances,mean_mib,peak_mib,mean_blas_mib,builds,builds_per_frame,refits,primitives_built,primitives_refit,state_changes,cycles,mean_latency,p95_latency,never_active,mean_needed_missing,mean_error,max_error,mean_trace_ms,mean_tlas_build_ms,mean_strategy_ms,mean_blas_build_ms,mean_blas_refit_ms,mean_frame_ms,median_frame_ms,mean_traced_rays,mean_gpu_blas_build_ms,mean_gpu_blas_refit_ms,mean_gpu_tlas_build_ms,mean_gpu_trace_ms,mean_gpu_frame_ms,front_time,front_gpu_time,front_memory,front_builds";

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
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.1},{:.4},{:.4},{:.4},{},{:.3},{},{},{},{},{},{:.3},{},{},{:.2},{:.6},{:.6},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.1},{:.6},{:.6},{:.6},{:.6},{:.6},{},{},{},{}",
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
            m.mean_blas_build_ms,
            m.mean_blas_refit_ms,
            m.mean_frame_ms,
            m.median_frame_ms,
            m.mean_traced_rays,
            m.mean_gpu_blas_build_ms,
            m.mean_gpu_blas_refit_ms,
            m.mean_gpu_tlas_build_ms,
            m.mean_gpu_trace_ms,
            m.mean_gpu_frame_ms,
            p.front_time,
            p.front_gpu_time,
            p.front_memory,
            p.front_builds
        );
    }
    s
}
