//! The comparison's outputs: a terminal table, and a report folder with
//! `report.md`, `report.json`, `frames.csv` and SVG plots.
//!
//! The plots are hand-written SVG (polylines and circles, about a hundred
//! lines here) rather than `plotters`: four simple charts do not justify its
//! dependency tree and build time on a 2-core machine.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::compare::CompareReport;
use crate::error::SimError;
use crate::metrics::FrameMetrics;

const MIB: f64 = 1024.0 * 1024.0;

/// Names of the plot files [`write_report`] writes.
pub const PLOTS: [&str; 4] = ["memory.svg", "builds.svg", "error.svg", "time_vs_error.svg"];

/// The summary table for the terminal (fixed-width text).
pub fn table(r: &CompareReport) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{:<14} {:>9} {:>8} {:>9} {:>9} {:>8} {:>8} {:>10} {:>7} {:>8} {:>6} {:>9} {:>9} {:>8}",
        "strategy",
        "inst mean",
        "inst pk",
        "MiB mean",
        "MiB peak",
        "builds",
        "refits",
        "prims",
        "cycles",
        "lat mean",
        "p95",
        "err mean",
        "err max",
        "trace ms"
    );
    for st in &r.strategies {
        let m = &st.summary;
        let _ = writeln!(
            s,
            "{:<14} {:>9.0} {:>8} {:>9.2} {:>9.2} {:>8} {:>8} {:>10} {:>7} {:>8.2} {:>6} {:>9.4} {:>9.4} {:>8.1}",
            st.name,
            m.mean_instances,
            m.peak_instances,
            m.mean_mib,
            m.peak_mib,
            m.builds,
            m.refits,
            m.primitives_built,
            m.cycles,
            m.mean_latency,
            m.p95_latency,
            m.mean_error,
            m.max_error,
            m.mean_trace_ms
        );
    }
    s
}

/// The headline sentence: LiPaC's memory against the full scene and its error.
pub fn headline(r: &CompareReport) -> Option<String> {
    let full = r.strategy("full")?;
    let mut out = String::new();
    for name in ["lipac", "lipac-latency"] {
        let Some(l) = r.strategy(name) else {
            continue;
        };
        let (a, b) = (l.summary.mean_mib, full.summary.mean_mib);
        let change = if b > 0.0 { (a / b - 1.0) * 100.0 } else { 0.0 };
        let label = if name == "lipac" {
            "LiPaC"
        } else {
            "LiPaC + latency mitigation"
        };
        let _ = writeln!(
            out,
            "{label}: {a:.2} MiB mean vs {b:.2} MiB full ({}{:.1} %), error {:.4} (mean relative RMSE of the indirect light; max {:.4})",
            if change < 0.0 { "−" } else { "+" },
            change.abs(),
            l.summary.mean_error,
            l.summary.max_error
        );
    }
    (!out.is_empty()).then_some(out)
}

/// The Markdown report.
pub fn markdown(r: &CompareReport) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# lipac: culling strategies compared\n");
    let th = r.thresholds;
    let _ = writeln!(
        s,
        "Scene `{}` ({} instances), {} frames of the fly-through at {}x{} ({} camera rays per frame; \
         LiPaC thresholds scaled to them: θa = {}, θd = {}, σa = {}, σo = {}, n_a = {}, n_d = {}). \
         Wall time {:.1} s.\n",
        r.scene, r.instances, r.frames, r.width, r.height, r.rays_per_frame, th[0], th[1], th[2],
        th[3], th[4], th[5], r.wall_s
    );
    if let Some(h) = headline(r) {
        for line in h.lines() {
            let _ = writeln!(s, "**{line}**\n");
        }
    }
    let _ = writeln!(
        s,
        "| strategy | TLAS instances mean | peak | memory MiB mean | peak | BLAS builds | refits | \
         triangles built | triangles refit | state changes | cycles | latency mean | p95 | never active | \
         needed missing / frame | error mean | max | trace ms |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for st in &r.strategies {
        let m = &st.summary;
        let _ = writeln!(
            s,
            "| {} | {:.0} | {} | {:.2} | {:.2} | {} | {} | {} | {} | {} | {} | {:.2} | {} | {} | {:.1} | {:.4} | {:.4} | {:.1} |",
            st.name,
            m.mean_instances,
            m.peak_instances,
            m.mean_mib,
            m.peak_mib,
            m.builds,
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
            m.mean_trace_ms
        );
    }
    let _ = writeln!(
        s,
        "\nMemory is modelled on lavapipe's acceleration-structure sizes (104 B per BLAS triangle, \
         176 B per TLAS instance; LiPaC adds 12 B per hitbox and 4 B per instance): see \
         docs/MEMORY_MODEL.md. TLAS instances count counting boxes. Error: relative RMSE of the \
         indirect light against the ground truth (every instance traced, same random numbers). \
         Latency: frames from the first frame the ground-truth paths hit an instance to the first \
         frame it is traced as geometry (\"never active\": never by the end). A cycle is an instance \
         re-entering the TLAS within 30 frames of leaving it. The full-scene strategy reuses the \
         ground truth's render (identical TLAS).\n"
    );
    let _ = writeln!(
        s,
        "Ground truth: {:.1} ms per frame to render, {:.1} ms for the full TLAS, {:.1} ms for the \
         shared geometry (unit refits).\n",
        r.ground_truth_ms, r.full_tlas_ms, r.geometry_ms
    );
    let _ = writeln!(s, "## Plots\n");
    for (file, title) in PLOTS.iter().zip([
        "Memory per frame",
        "BLAS builds per frame",
        "Error per frame",
        "Trace time against error",
    ]) {
        let _ = writeln!(s, "- [{title}]({file})\n\n  ![{title}]({file})\n");
    }
    let _ = writeln!(
        s,
        "Per-frame data: [frames.csv](frames.csv); everything: [report.json](report.json)."
    );
    s
}

/// CSV header of [`csv`].
pub const CSV_HEADER: &str = "strategy,frame,tlas_instances,counting_boxes,blas_bytes,tlas_bytes,overhead_bytes,total_bytes,builds,refits,primitives_built,primitives_refit,state_changes,cycles,latency_samples,latency_sum,needed_missing,error,trace_ms,tlas_build_ms,strategy_ms";

/// Per-frame CSV: one row per strategy and frame.
pub fn csv(r: &CompareReport) -> String {
    let mut s = String::from(CSV_HEADER);
    s.push('\n');
    for st in &r.strategies {
        for m in &st.frames {
            let _ = writeln!(
                s,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.3},{:.3},{:.3}",
                st.name,
                m.frame,
                m.tlas_instances,
                m.counting_boxes,
                m.blas_bytes,
                m.tlas_bytes,
                m.overhead_bytes,
                m.total_bytes(),
                m.builds,
                m.refits,
                m.primitives_built,
                m.primitives_refit,
                m.state_changes,
                m.cycles,
                m.latency_samples,
                m.latency_sum,
                m.needed_missing,
                m.error,
                m.trace_ms,
                m.tlas_build_ms,
                m.strategy_ms
            );
        }
    }
    s
}

pub(crate) const COLORS: [&str; 8] = [
    "#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf",
];
pub(crate) const W: f64 = 720.0;
pub(crate) const H: f64 = 420.0;
pub(crate) const L: f64 = 70.0;
pub(crate) const R: f64 = 150.0;
pub(crate) const T: f64 = 40.0;
pub(crate) const B: f64 = 50.0;

pub(crate) fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

pub(crate) fn nice_max(v: f64) -> f64 {
    if v <= 0.0 || !v.is_finite() {
        return 1.0;
    }
    let p = 10f64.powf(v.log10().floor());
    for m in [1.0, 2.0, 2.5, 5.0, 10.0] {
        if m * p >= v {
            return m * p;
        }
    }
    10.0 * p
}

pub(crate) fn frame_axes(
    s: &mut String,
    title: &str,
    xlabel: &str,
    ylabel: &str,
    xmax: f64,
    ymax: f64,
) {
    let _ = write!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}" font-family="sans-serif" font-size="12">
<rect width="{W}" height="{H}" fill="white"/>
<text x="{}" y="22" text-anchor="middle" font-size="15">{}</text>
<line x1="{L}" y1="{}" x2="{}" y2="{}" stroke="black"/>
<line x1="{L}" y1="{T}" x2="{L}" y2="{}" stroke="black"/>
<text x="{}" y="{}" text-anchor="middle">{}</text>
<text x="16" y="{}" text-anchor="middle" transform="rotate(-90 16 {})">{}</text>
"#,
        (L + W - R) / 2.0,
        esc(title),
        H - B,
        W - R,
        H - B,
        H - B,
        (L + W - R) / 2.0,
        H - 12.0,
        esc(xlabel),
        (T + H - B) / 2.0,
        (T + H - B) / 2.0,
        esc(ylabel)
    );
    for i in 0..=5 {
        let f = f64::from(i) / 5.0;
        let x = L + f * (W - R - L);
        let y = H - B - f * (H - B - T);
        let _ = write!(
            s,
            r##"<line x1="{x:.1}" y1="{}" x2="{x:.1}" y2="{}" stroke="black"/><text x="{x:.1}" y="{}" text-anchor="middle">{}</text>
<line x1="{}" y1="{y:.1}" x2="{L}" y2="{y:.1}" stroke="black"/><line x1="{L}" y1="{y:.1}" x2="{}" y2="{y:.1}" stroke="#ddd"/><text x="{}" y="{:.1}" text-anchor="end">{}</text>
"##,
            H - B,
            H - B + 5.0,
            H - B + 18.0,
            fmt_tick(f * xmax),
            L - 5.0,
            W - R,
            L - 8.0,
            y + 4.0,
            fmt_tick(f * ymax)
        );
    }
}

fn fmt_tick(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else if v.abs() >= 100.0 {
        format!("{v:.0}")
    } else if v.abs() >= 1.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.3}")
    }
}

pub(crate) fn legend(s: &mut String, i: usize, name: &str) {
    let y = T + 10.0 + i as f64 * 18.0;
    let _ = writeln!(
        s,
        r#"<line x1="{}" y1="{y}" x2="{}" y2="{y}" stroke="{}" stroke-width="2"/><text x="{}" y="{}">{}</text>"#,
        W - R + 10.0,
        W - R + 30.0,
        COLORS[i % COLORS.len()],
        W - R + 35.0,
        y + 4.0,
        esc(name)
    );
}

/// A line chart of `value(frame metrics)` per frame, one polyline per
/// strategy.
pub fn line_plot(
    r: &CompareReport,
    title: &str,
    ylabel: &str,
    value: impl Fn(&FrameMetrics) -> f64,
) -> String {
    let xmax = f64::from(r.frames.saturating_sub(1).max(1));
    let ymax = nice_max(
        r.strategies
            .iter()
            .flat_map(|s| s.frames.iter().map(&value))
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max),
    );
    let mut s = String::new();
    frame_axes(&mut s, title, "frame", ylabel, xmax, ymax);
    for (i, st) in r.strategies.iter().enumerate() {
        let mut pts = String::new();
        for m in &st.frames {
            let v = value(m);
            let v = if v.is_finite() { v } else { ymax };
            let x = L + f64::from(m.frame) / xmax * (W - R - L);
            let y = H - B - (v / ymax).clamp(0.0, 1.0) * (H - B - T);
            let _ = write!(pts, "{x:.1},{y:.1} ");
        }
        let _ = writeln!(
            s,
            r#"<polyline fill="none" stroke="{}" stroke-width="1.5" points="{}"><title>{}</title></polyline>"#,
            COLORS[i % COLORS.len()],
            pts.trim_end(),
            esc(&st.name)
        );
        legend(&mut s, i, &st.name);
    }
    s.push_str("</svg>\n");
    s
}

/// Mean trace time against mean error, one point per strategy.
pub fn scatter_plot(r: &CompareReport) -> String {
    let xmax = nice_max(
        r.strategies
            .iter()
            .map(|s| s.summary.mean_trace_ms)
            .fold(0.0, f64::max),
    );
    let ymax = nice_max(
        r.strategies
            .iter()
            .map(|s| s.summary.mean_error)
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max),
    );
    let mut s = String::new();
    frame_axes(
        &mut s,
        "Trace time against error",
        "mean trace time per frame, ms",
        "mean relative RMSE (indirect)",
        xmax,
        ymax,
    );
    for (i, st) in r.strategies.iter().enumerate() {
        let m = &st.summary;
        let x = L + (m.mean_trace_ms / xmax).clamp(0.0, 1.0) * (W - R - L);
        let y = H - B - (m.mean_error / ymax).clamp(0.0, 1.0) * (H - B - T);
        let _ = writeln!(
            s,
            r#"<circle cx="{x:.1}" cy="{y:.1}" r="5" fill="{}"><title>{}</title></circle><text x="{:.1}" y="{:.1}">{}</text>"#,
            COLORS[i % COLORS.len()],
            esc(&st.name),
            x + 7.0,
            y - 7.0,
            esc(&st.name)
        );
        legend(&mut s, i, &st.name);
    }
    s.push_str("</svg>\n");
    s
}

/// Writes `report.md`, `report.json`, `frames.csv` and the [`PLOTS`] into
/// `dir` (created if missing); returns the paths written.
pub fn write_report(r: &CompareReport, dir: &Path) -> Result<Vec<PathBuf>, SimError> {
    std::fs::create_dir_all(dir)?;
    let json = serde_json::to_string_pretty(r).map_err(|e| SimError::Io(e.to_string()))?;
    let files: Vec<(&str, String)> = vec![
        ("report.md", markdown(r)),
        ("report.json", json),
        ("frames.csv", csv(r)),
        (
            PLOTS[0],
            line_plot(r, "Acceleration-structure memory per frame", "MiB", |m| {
                m.total_bytes() as f64 / MIB
            }),
        ),
        (
            PLOTS[1],
            line_plot(r, "BLAS builds per frame", "builds", |m| m.builds as f64),
        ),
        (
            PLOTS[2],
            line_plot(r, "Error per frame", "relative RMSE (indirect)", |m| {
                m.error
            }),
        ),
        (PLOTS[3], scatter_plot(r)),
    ];
    let mut paths = Vec::new();
    for (name, body) in files {
        let p = dir.join(name);
        std::fs::write(&p, body)?;
        paths.push(p);
    }
    Ok(paths)
}
