//! The report's plots as SVG text: line charts per frame and scatter plots
//! of one strategy summary against another for `lipac compare`
//! ([`line_plot`], [`scatter_plot`]), and the Pareto plots of `lipac sweep`
//! ([`pareto_plot`]).

use std::fmt::Write as _;

use crate::compare::CompareReport;
use crate::metrics::FrameMetrics;
use crate::sweep::{SweepPoint, SweepReport, COSTS};
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

fn on_front(p: &SweepPoint, plot: usize) -> bool {
    [p.front_time, p.front_memory, p.front_builds][plot]
}

/// The scatter plot of cost `plot` (index into [`COSTS`]) against error:
/// one circle per point (colour per scene, black ring on the front), the
/// front of each scene as a dashed line (`class="front"`).
pub fn pareto_plot(r: &SweepReport, plot: usize) -> String {
    let (_, title, xlabel, cost) = COSTS[plot.min(COSTS.len() - 1)];
    let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
    let xmax = nice_max(r.points.iter().map(|p| finite(cost(p))).fold(0.0, f64::max));
    let ymax = nice_max(
        r.points
            .iter()
            .map(|p| finite(p.summary.mean_error))
            .fold(0.0, f64::max),
    );
    let px = |v: f64| L + (finite(v) / xmax).clamp(0.0, 1.0) * (W - R - L);
    let py = |v: f64| H - B - (finite(v) / ymax).clamp(0.0, 1.0) * (H - B - T);
    let mut s = String::new();
    frame_axes(
        &mut s,
        title,
        xlabel,
        "mean relative RMSE (indirect)",
        xmax,
        ymax,
    );
    for (si, scene) in r.scenes.iter().enumerate() {
        let color = COLORS[si % COLORS.len()];
        let mut front: Vec<(f64, f64)> = r
            .points
            .iter()
            .filter(|p| p.scene == scene.name && on_front(p, plot))
            .map(|p| (cost(p), p.summary.mean_error))
            .collect();
        front.sort_by(|a, b| a.0.total_cmp(&b.0));
        let pts: Vec<String> = front
            .iter()
            .map(|&(x, y)| format!("{:.1},{:.1}", px(x), py(y)))
            .collect();
        let _ = writeln!(
            s,
            r#"<polyline class="front" fill="none" stroke="{color}" stroke-width="1.5" stroke-dasharray="5,3" points="{}"><title>{} Pareto front</title></polyline>"#,
            pts.join(" "),
            esc(&scene.name)
        );
        for p in r.points.iter().filter(|p| p.scene == scene.name) {
            let (x, y) = (px(cost(p)), py(p.summary.mean_error));
            let ring = if on_front(p, plot) {
                r#" stroke="black" stroke-width="1.5""#
            } else {
                ""
            };
            let _ = writeln!(
                s,
                r#"<circle cx="{x:.1}" cy="{y:.1}" r="4" fill="{color}" fill-opacity="0.8"{ring}><title>{}: {} ({:.3}, error {:.4})</title></circle><text x="{:.1}" y="{:.1}" font-size="8">{}</text>"#,
                esc(&scene.name),
                esc(&p.name),
                cost(p),
                p.summary.mean_error,
                x + 5.0,
                y - 4.0,
                esc(&p.name)
            );
        }
        let y = T + 10.0 + si as f64 * 18.0;
        let _ = writeln!(
            s,
            r#"<circle cx="{}" cy="{y}" r="4" fill="{color}"/><text x="{}" y="{}">{}</text>"#,
            W - R + 20.0,
            W - R + 35.0,
            y + 4.0,
            esc(&scene.name)
        );
    }
    let y = T + 10.0 + r.scenes.len() as f64 * 18.0;
    let _ = writeln!(
        s,
        r#"<line x1="{}" y1="{y}" x2="{}" y2="{y}" stroke="black" stroke-dasharray="5,3"/><text x="{}" y="{}">Pareto front</text>"#,
        W - R + 10.0,
        W - R + 30.0,
        W - R + 35.0,
        y + 4.0
    );
    s.push_str("</svg>\n");
    s
}
