//! The comparison's outputs: a terminal table, and a report folder with
//! `report.md`, `report.json`, `frames.csv`, SVG plots ([`crate::plots`]),
//! `report.html` ([`crate::html`]) and, when asked, snapshot pictures
//! ([`crate::snapshot`]).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use lipac_core::thresholds::{DecisionRule, Thresholds};

use crate::compare::CompareReport;
use crate::error::SimError;
use crate::html::report_html;
use crate::plots::{line_plot, scatter_plot};
use crate::snapshot::{write_snapshots, Snapshot};

const MIB: f64 = 1024.0 * 1024.0;

/// Names of the plot files [`write_report`] writes.
pub const PLOTS: [&str; 6] = [
    "memory.svg",
    "builds.svg",
    "error.svg",
    "frame_time.svg",
    "time_vs_error.svg",
    "gpu_time_vs_error.svg",
];

/// Titles of the [`PLOTS`], in order.
pub const PLOT_TITLES: [&str; 6] = [
    "Acceleration-structure memory per frame",
    "BLAS builds per frame",
    "Error per frame",
    "Frame time per frame (AS work + trace, measured on CPU)",
    "Frame time (AS work + trace, measured on CPU) against error",
    "Modelled GPU frame time against error (the device profile's rates)",
];

/// The summary table for the terminal (fixed-width text).
pub fn table(r: &CompareReport) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{:<14} {:>9} {:>8} {:>9} {:>9} {:>8} {:>8} {:>10} {:>7} {:>8} {:>6} {:>9} {:>9} {:>8} {:>8} {:>8}",
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
        "trace ms",
        "frame ms",
        "GPU ms"
    );
    for st in &r.strategies {
        let m = &st.summary;
        let _ = writeln!(
            s,
            "{:<14} {:>9.0} {:>8} {:>9.2} {:>9.2} {:>8} {:>8} {:>10} {:>7} {:>8.2} {:>6} {:>9.4} {:>9.4} {:>8.1} {:>8.1} {:>8.3}",
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
            m.mean_trace_ms,
            m.mean_frame_ms,
            m.mean_gpu_frame_ms
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

/// The Markdown report; `snapshots`: whether the report folder has
/// `snapshots/` (mentioned with `report.html`).
pub fn markdown(r: &CompareReport, snapshots: bool) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# lipac: culling strategies compared\n");
    let th = r.thresholds;
    let paper = format!(
        "the paper's rule, thresholds scaled to them: θa = {}, θd = {}, σa = {}, σo = {}, n_a = {}, n_d = {}",
        th[0], th[1], th[2], th[3], th[4], th[5]
    );
    let _ = writeln!(
        s,
        "Scene `{}` ({} instances), {} frames of the fly-through at {}x{} ({} camera rays per frame; \
         LiPaC decides with {}{}). Wall time {:.1} s.\n",
        r.scene,
        r.instances,
        r.frames,
        r.width,
        r.height,
        r.rays_per_frame,
        if r.rule.is_empty() { &paper } else { &r.rule },
        if r.start.is_empty() {
            String::new()
        } else {
            format!("; it starts with {}", r.start)
        },
        r.wall_s
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
        "\n{} TLAS instances count counting boxes. Error: relative RMSE of the \
         indirect light against the ground truth (every instance traced, same random numbers). \
         Latency: frames from the first frame the ground-truth paths hit an instance to the first \
         frame it is traced as geometry (\"never active\": never by the end). A cycle is an instance \
         re-entering the TLAS within 30 frames of leaving it. The full-scene strategy reuses the \
         ground truth's render (identical TLAS).\n",
        memory_note(&r.device_profile)
    );
    s.push_str(&breakdown_markdown(r));
    let _ = writeln!(
        s,
        "Ground truth: {:.1} ms per frame to render, {:.1} ms for the full TLAS, {:.1} ms for the \
         shared geometry (unit refits).\n",
        r.ground_truth_ms, r.full_tlas_ms, r.geometry_ms
    );
    let _ = writeln!(s, "## Run time against error\n");
    let t = &r.blas_throughput;
    let _ = writeln!(
        s,
        "obvhs throughput measured this run on the scene's meshes: build {:.1} ns per triangle, \
         refit {:.1} ns per triangle ({} and {} triangles measured).\n",
        t.build_ns_per_triangle, t.refit_ns_per_triangle, t.triangles_built, t.triangles_refit
    );
    let _ = writeln!(
        s,
        "| strategy | BLAS build ms | BLAS refit ms | TLAS build ms | trace ms | **frame ms** mean | median | \
         GPU model: BLAS build ms | refit | TLAS | trace | **GPU frame ms** | error mean |"
    );
    let _ = writeln!(
        s,
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    for st in &r.strategies {
        let m = &st.summary;
        let _ = writeln!(
            s,
            "| {} | {:.2} | {:.2} | {:.2} | {:.2} | **{:.2}** | {:.2} | {:.4} | {:.4} | {:.4} | {:.4} | **{:.4}** | {:.4} |",
            st.name,
            m.mean_blas_build_ms,
            m.mean_blas_refit_ms,
            m.mean_tlas_build_ms,
            m.mean_trace_ms,
            m.mean_frame_ms,
            m.median_frame_ms,
            m.mean_gpu_blas_build_ms,
            m.mean_gpu_blas_refit_ms,
            m.mean_gpu_tlas_build_ms,
            m.mean_gpu_trace_ms,
            m.mean_gpu_frame_ms,
            m.mean_error
        );
    }
    let _ = writeln!(s, "\n{}\n", timing_note(r));
    let _ = writeln!(s, "## Plots\n");
    for (file, title) in PLOTS.iter().zip(PLOT_TITLES) {
        let _ = writeln!(s, "- [{title}]({file})\n\n  ![{title}]({file})\n");
    }
    let _ = writeln!(
        s,
        "Per-frame data: [frames.csv](frames.csv); everything: [report.json](report.json). \
         Open [report.html](report.html) in a browser for the plots{}.",
        if snapshots {
            ", the snapshot images, error heat maps and TLAS maps (files in snapshots/)"
        } else {
            " (run with `--snapshots 0,90,180` for images, error heat maps and TLAS maps)"
        }
    );
    if let Some(section) = crate::closed_loop::markdown(r, &r.camera_cuts) {
        s.push_str(&section);
    }
    s
}

/// LiPaC's decision rule in words, as the report prints it: the paper's
/// thresholds, or the decayed rule's half-life (and rise shift, if it has
/// one) and rates in hits per frame.
///
/// ```
/// use lipac_sim::report::rule_description;
/// use lipac_core::thresholds::Thresholds;
/// use lipac_sim::strategy::lipac::LipacConfig;
/// assert!(rule_description(&Thresholds::paper()).starts_with("the paper's rule"));
/// let default = LipacConfig::for_rays_per_frame(128 * 72).unwrap().thresholds;
/// let d = rule_description(&default);
/// assert!(d.starts_with("the decayed rule: half-life 5.5 frames (shift 3, rising with shift 1)"), "{d}");
/// // Rates far below one hit per frame keep three significant digits.
/// assert!(d.contains("deactivates below 0.000885 hits"), "{d}");
/// ```
pub fn rule_description(t: &Thresholds) -> String {
    match t.rule {
        DecisionRule::Paper => format!(
            "the paper's rule, thresholds scaled to them: θa = {}, θd = {}, σa = {}, σo = {}, \
             n_a = {}, n_d = {}",
            t.theta_a, t.theta_d, t.sigma_a, t.sigma_o, t.n_a, t.n_d
        ),
        DecisionRule::Decayed(d) => {
            // Three decimals, or three significant digits below 0.1 hits.
            let hits = |rate: u32| {
                let x = f64::from(rate) / 65536.0;
                let decimals = if x == 0.0 || x >= 0.1 {
                    3
                } else {
                    (2.0 - x.log10().floor()) as usize
                };
                format!("{x:.decimals$}")
            };
            let rise = if d.rise_shift == d.shift {
                String::new()
            } else {
                format!(", rising with shift {}", d.rise_shift)
            };
            format!(
                "the decayed rule: half-life {:.1} frames (shift {}{rise}), a hitbox activates above \
                 {} and deactivates below {} hits per frame, a unique-BLAS instance above {} \
                 / below {}, plus {} / {} per inactive shared / unique instance",
                std::f64::consts::LN_2 * f64::from(1u32 << d.shift.min(30)),
                d.shift,
                hits(d.activate),
                hits(d.deactivate),
                hits(d.instance_activate),
                hits(d.instance_omit),
                hits(d.per_shared),
                hits(d.per_unique)
            )
        }
    }
}

/// How LiPaC starts ([`LipacConfig::warm_start`](crate::strategy::lipac::LipacConfig::warm_start), its hold and cuts), in
/// words for the report's header.
///
/// ```
/// use lipac_sim::report::start_description;
/// use lipac_sim::strategy::lipac::LipacConfig;
/// let mut c = LipacConfig::for_rays_per_frame(128 * 72).unwrap();
/// assert_eq!(
///     start_description(&c),
///     "a warm start of everything in view and of everything within 800 m of the camera"
/// );
/// c.warm_start_hold = 8;
/// c.warm_start_at_cuts = true;
/// assert!(start_description(&c).ends_with(", held 8 frames without hits, again at every camera cut"));
/// c.warm_start = None;
/// assert!(start_description(&c).starts_with("the paper's cold start"));
/// ```
pub fn start_description(c: &crate::strategy::lipac::LipacConfig) -> String {
    let Some(h) = c.warm_start else {
        return "the paper's cold start (nothing but the pinned instances until the first \
                read-back)"
            .into();
    };
    let mut s = if h.max_distance == f32::INFINITY || h.min_projected_size == 0.0 {
        "a warm start of everything in view".to_string()
    } else {
        format!(
            "a warm start of what in view is within {} m or of projected size at least {}",
            h.max_distance, h.min_projected_size
        )
    };
    if h.surround_radius > 0.0 {
        s.push_str(&format!(
            " and of everything within {} m of the camera",
            h.surround_radius
        ));
    }
    if c.warm_start_hold > 0 {
        s.push_str(&format!(", held {} frames without hits", c.warm_start_hold));
    }
    if c.warm_start_at_cuts {
        s.push_str(", again at every camera cut");
    }
    s
}

/// The sections "Where the memory goes" and "What is missing" of
/// `report.md`: each strategy's mean memory by term and its missing
/// instances by kind and by how long they stayed missing.
pub fn breakdown_markdown(r: &CompareReport) -> String {
    let mut s = String::from("## Where the memory goes\n\n");
    s.push_str(
        "| strategy | terrain BLAS MiB | own BLAS | shared BLAS in use | shared BLAS cached only | \
         TLAS geometry records | TLAS counting boxes | LiPaC buffers | total |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for st in &r.strategies {
        let m = &st.summary;
        let p = m.mean_split_mib;
        let _ = writeln!(
            s,
            "| {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
            st.name, p[0], p[1], p[2], p[3], p[4], p[5], p[6], m.mean_mib
        );
    }
    s.push_str(
        "\nMeans over the frames. \"Cached only\": shared BLASes no active instance uses, kept \
         by the BLAS cache's retention; the total also counts LiPaC's counting-box unit cube.\n\n\
         ## What is missing\n\n\
         | strategy | missing / frame: terrain | shared BLAS | own BLAS | ground-truth hits on \
         missing | instances missing 1–2 frames (hits) | 3–10 | 11–30 | > 30 |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for st in &r.strategies {
        let m = &st.summary;
        let k = m.mean_missing_by_kind;
        let t = &m.missing_tail;
        let total = t.hits.iter().sum::<u64>().max(1) as f64;
        let class = |c: usize| {
            format!(
                "{} ({:.0} %)",
                t.instances[c],
                100.0 * t.hits[c] as f64 / total
            )
        };
        let _ = writeln!(
            s,
            "| {} | {:.1} | {:.1} | {:.1} | {:.1} % | {} | {} | {} | {} |",
            st.name,
            k[0],
            k[1],
            k[2],
            100.0 * m.missing_hit_share,
            class(0),
            class(1),
            class(2),
            class(3)
        );
    }
    s.push_str(
        "\nMissing: instances the ground-truth bounce rays hit this frame that the strategy \
         does not trace as geometry. The classes count each instance once by the number of \
         frames it was missing while hit, with the share of all hits on missing instances \
         that fell in those frames.\n\n",
    );
    s
}

/// CSV header of [`csv`].
pub const CSV_HEADER: &str = "strategy,frame,tlas_instances,counting_boxes,blas_bytes,tlas_bytes,overhead_bytes,total_bytes,builds,refits,primitives_built,primitives_refit,state_changes,cycles,latency_samples,latency_sum,needed_missing,error,trace_ms,tlas_build_ms,strategy_ms,traced_rays,blas_build_ms,blas_refit_ms,frame_ms,gpu_blas_build_ms,gpu_blas_refit_ms,gpu_tlas_build_ms,gpu_trace_ms,gpu_frame_ms";

/// Per-frame CSV: one row per strategy and frame.
pub fn csv(r: &CompareReport) -> String {
    let mut s = String::from(CSV_HEADER);
    s.push('\n');
    for st in &r.strategies {
        for m in &st.frames {
            let _ = writeln!(
                s,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.3},{:.3},{:.3},{},{:.3},{:.3},{:.3},{:.6},{:.6},{:.6},{:.6},{:.6}",
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
                m.strategy_ms,
                m.traced_rays,
                m.blas_build_ms,
                m.blas_refit_ms,
                m.frame_ms,
                m.gpu_blas_build_ms,
                m.gpu_blas_refit_ms,
                m.gpu_tlas_build_ms,
                m.gpu_trace_ms,
                m.gpu_frame_ms
            );
        }
    }
    s
}

/// The [`PLOTS`] as SVG documents, in order.
pub fn plots(r: &CompareReport) -> Result<Vec<String>, SimError> {
    Ok(vec![
        line_plot(r, PLOT_TITLES[0], "MiB", |m| m.total_bytes() as f64 / MIB)?,
        line_plot(r, PLOT_TITLES[1], "builds", |m| m.builds as f64)?,
        line_plot(r, PLOT_TITLES[2], "relative RMSE (indirect)", |m| m.error)?,
        line_plot(r, PLOT_TITLES[3], "frame time, CPU ms", |m| m.frame_ms)?,
        scatter_plot(
            r,
            PLOT_TITLES[4],
            "mean frame time (BLAS builds, refits, TLAS, trace), CPU ms",
            |s| s.mean_frame_ms,
        )?,
        scatter_plot(
            r,
            PLOT_TITLES[5],
            "modelled GPU frame time (AS work + trace), ms",
            |s| s.mean_gpu_frame_ms,
        )?,
    ])
}

/// Writes `report.md`, `report.json`, `frames.csv`, the [`PLOTS`] and
/// `report.html` into `dir` (created if missing); returns the paths
/// written. [`write_report_with_snapshots`] without snapshots.
pub fn write_report(r: &CompareReport, dir: &Path) -> Result<Vec<PathBuf>, SimError> {
    write_report_with_snapshots(r, &[], dir)
}

/// [`write_report`] plus the pictures of `snapshots`: in `report.html`,
/// and as files under `dir/snapshots/` ([`crate::snapshot::write_snapshots`]).
pub fn write_report_with_snapshots(
    r: &CompareReport,
    snapshots: &[Snapshot],
    dir: &Path,
) -> Result<Vec<PathBuf>, SimError> {
    std::fs::create_dir_all(dir)?;
    let json = serde_json::to_string_pretty(r).map_err(|e| SimError::Io(e.to_string()))?;
    let svgs = plots(r)?;
    let pictures = snapshots
        .iter()
        .map(Snapshot::pictures)
        .collect::<Result<Vec<_>, _>>()?;
    let html = report_html(r, &svgs, snapshots, &pictures)?;
    let mut files: Vec<(&str, String)> = vec![
        ("report.md", markdown(r, !snapshots.is_empty())),
        ("report.json", json),
        ("frames.csv", csv(r)),
    ];
    files.extend(PLOTS.iter().copied().zip(svgs));
    files.extend(crate::closed_loop::plots(r)?);
    files.push(("report.html", html));
    let mut paths = Vec::new();
    for (name, body) in files {
        let p = dir.join(name);
        std::fs::write(&p, body)?;
        paths.push(p);
    }
    paths.extend(write_snapshots(snapshots, &pictures, dir)?);
    Ok(paths)
}

/// The report's sentence on the memory model: the profile named, its
/// bytes per BLAS triangle and per TLAS instance, LiPaC's own buffers.
pub fn memory_note(profile: &crate::device_profile::DeviceProfile) -> String {
    let lipac = "LiPaC adds 20 B per hitbox and 4 B per instance slot, 8 B under the decayed rule";
    if profile.is_builtin() {
        return format!(
            "Memory is modelled on lavapipe's acceleration-structure sizes (104 B per BLAS \
             triangle, 176 B per TLAS instance; {lipac}; the built-in device profile): see \
             docs/MEMORY_MODEL.md."
        );
    }
    let m = profile.memory_model();
    let per_triangle: Vec<String> = profile
        .blas
        .sizes
        .iter()
        .map(|b| {
            let compacted = b
                .compacted_bytes
                .filter(|&c| c != b.built_bytes)
                .map_or(String::new(), |c| {
                    format!(" ({:.0} compacted)", c as f64 / b.triangles as f64)
                });
            format!(
                "{:.0} at {} triangles{compacted}",
                b.built_bytes as f64 / b.triangles as f64,
                b.triangles
            )
        })
        .collect();
    format!(
        "Memory is modelled on the acceleration-structure sizes of the device profile {} (BLAS \
         bytes per triangle as built: {}; {} B per TLAS instance; {lipac}): see \
         docs/MEMORY_MODEL.md. The profile's source: {}",
        profile.describe(),
        per_triangle.join("; "),
        m.tlas_bytes_per_instance(),
        profile.source
    )
}

/// The report's paragraph on how its times are made, naming the profile
/// of the modelled GPU time ([`crate::metrics::GpuModel::timing_note`]).
pub fn timing_note(r: &CompareReport) -> String {
    r.gpu_model.timing_note(&r.device_profile.describe())
}
