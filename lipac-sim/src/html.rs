//! `report.html`: the comparison as one self-contained page to open in a
//! browser: headline, summary table, the plots (inline SVG), and for each
//! snapshot frame the images of the ground truth and every strategy, their
//! error heat maps and their TLAS maps (embedded as `data:` URIs; nothing
//! is loaded from elsewhere).

use std::fmt::Write as _;

use crate::compare::CompareReport;
use crate::error::SimError;
use crate::report::{headline, PLOTS};
use crate::snapshot::{heat_scale_png, Pictures, Snapshot};
use crate::tlas_map::MapState;

/// Escapes `&`, `<`, `>` and `"` for HTML text and attributes.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Standard base64 (RFC 4648, with padding).
///
/// ```
/// assert_eq!(lipac_sim::html::base64(b"lipac"), "bGlwYWM=");
/// assert_eq!(lipac_sim::html::base64(b""), "");
/// ```
pub fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let b = [c[0], *c.get(1).unwrap_or(&0), *c.get(2).unwrap_or(&0)];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for (i, shift) in [18, 12, 6, 0].into_iter().enumerate() {
            if i <= c.len() {
                out.push(A[((n >> shift) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

fn img(mime: &str, bytes: &[u8], alt: &str, class: &str) -> String {
    format!(
        r#"<img class="{class}" alt="{}" src="data:{mime};base64,{}">"#,
        escape(alt),
        base64(bytes)
    )
}

const STYLE: &str = "body{font-family:sans-serif;margin:24px auto;max-width:1400px;color:#222;padding:0 16px}\
h1{font-size:26px}h2{margin-top:36px;border-bottom:1px solid #ccc}\
table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;padding:3px 7px;text-align:right}\
th{background:#f2f2f2}td:first-child,th:first-child{text-align:left}\
.headline{font-size:18px;font-weight:bold;background:#eef5ff;padding:10px 14px;border-left:4px solid #1f77b4}\
.plots{display:grid;grid-template-columns:repeat(auto-fill,minmax(560px,1fr));gap:12px}.plots svg{width:100%;height:auto}\
.snap{display:grid;grid-template-columns:repeat(auto-fill,minmax(270px,1fr));gap:14px}\
.snap figure{margin:0}.snap figcaption{font-size:13px;margin-top:2px}\
img.px{width:100%;image-rendering:pixelated;border:1px solid #999}\
img.map{width:100%;border:1px solid #ddd}.scale{display:flex;align-items:center;gap:8px;font-size:13px}\
img.bar{width:256px;height:12px;border:1px solid #999}\
ul.legend{list-style:none;padding:0;display:flex;flex-wrap:wrap;gap:6px 18px;font-size:13px}\
ul.legend span{display:inline-block;width:14px;height:14px;margin-right:6px;vertical-align:middle;border:1px solid #777}";

/// The page over `r` and `snapshots` (see the module docs). `plots` are the
/// SVG documents of [`PLOTS`], in order; `pictures` those of each snapshot
/// ([`Snapshot::pictures`]).
pub fn report_html(
    r: &CompareReport,
    plots: &[String],
    snapshots: &[Snapshot],
    pictures: &[Pictures],
) -> Result<String, SimError> {
    if snapshots.len() != pictures.len() {
        return Err(SimError::SizeMismatch {
            a: snapshots.len(),
            b: pictures.len(),
        });
    }
    let mut s = String::new();
    let title = format!("lipac: culling strategies compared on {}", r.scene);
    let _ = write!(
        s,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title><style>{STYLE}</style></head><body>\n<h1>{}</h1>\n",
        escape(&title),
        escape(&title)
    );
    let _ = writeln!(
        s,
        "<p>Scene <b>{}</b> ({} instances), {} frames of the fly-through at {}×{} ({} camera rays per frame). Wall time {:.1} s. Error: relative RMSE of the indirect light against the ground truth (every instance traced, same random numbers).</p>",
        escape(&r.scene),
        r.instances,
        r.frames,
        r.width,
        r.height,
        r.rays_per_frame,
        r.wall_s
    );
    if let Some(h) = headline(r) {
        for line in h.lines() {
            let _ = writeln!(s, "<p class=\"headline\">{}</p>", escape(line));
        }
    }
    let _ = writeln!(
        s,
        "<table><tr><th>strategy</th><th>TLAS instances mean</th><th>peak</th><th>memory MiB mean</th><th>peak</th><th>BLAS builds</th><th>refits</th><th>cycles</th><th>latency mean</th><th>p95</th><th>error mean</th><th>max</th><th>trace ms</th><th>frame ms (CPU)</th><th>GPU frame ms (model)</th></tr>"
    );
    for st in &r.strategies {
        let m = &st.summary;
        let _ = writeln!(
            s,
            "<tr><td>{}</td><td>{:.0}</td><td>{}</td><td>{:.2}</td><td>{:.2}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.2}</td><td>{}</td><td>{:.4}</td><td>{:.4}</td><td>{:.1}</td><td>{:.1}</td><td>{:.3}</td></tr>",
            escape(&st.name),
            m.mean_instances,
            m.peak_instances,
            m.mean_mib,
            m.peak_mib,
            m.builds,
            m.refits,
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
    let _ = writeln!(
        s,
        "</table>\n<p>{}</p>\n<p>{}</p>",
        escape(&crate::report::memory_note(&r.device_profile)),
        escape(&crate::report::timing_note(r))
    );
    s.push_str("<h2 id=\"plots\">Plots</h2>\n<div class=\"plots\">\n");
    for (svg, file) in plots.iter().zip(PLOTS) {
        let body = svg.trim_start_matches(|c| c != '<');
        let _ = writeln!(s, "<div title=\"{file}\">{body}</div>");
    }
    s.push_str("</div>\n");
    if snapshots.is_empty() {
        s.push_str("<p>No snapshots: run with <code>--snapshots 0,90,180</code> for images, error heat maps and TLAS maps of chosen frames.</p>\n");
    } else {
        let bar = img(
            "image/png",
            &heat_scale_png(256)?,
            "heat map colour scale",
            "bar",
        );
        s.push_str("<h2 id=\"snapshots\">Snapshots</h2>\n<p>Indirect light of the ground truth and of each strategy, all at the ground truth's exposure, and each strategy's per-pixel error |strategy − ground truth| (heat map; black is exactly zero).</p>\n");
        for (snap, pics) in snapshots.iter().zip(pictures) {
            let scale = snap.scale();
            let _ = writeln!(
                s,
                "<h3>Frame {}</h3>\n<div class=\"scale\">heat map scale: 0 {bar} ≥ {scale:.3} (the frame's 99th-percentile indirect luminance)</div>\n<div class=\"snap\">",
                snap.frame
            );
            let _ = writeln!(
                s,
                "<figure>{}<figcaption><b>ground truth</b></figcaption></figure>",
                img("image/png", &pics.ground_truth, "ground truth", "px")
            );
            for (st, [image, heat, _]) in snap.strategies.iter().zip(&pics.strategies) {
                let _ = writeln!(
                    s,
                    "<figure>{}<figcaption><b>{}</b>: error {:.4}</figcaption>{}<figcaption>{} error heat map</figcaption></figure>",
                    img("image/png", image, &st.name, "px"),
                    escape(&st.name),
                    st.error,
                    img("image/png", heat, &format!("{} error", st.name), "px"),
                    escape(&st.name)
                );
            }
            s.push_str("</div>\n");
        }
        let side = snapshots[0]
            .strategies
            .first()
            .map_or(0.0, |st| st.map.side());
        let _ = writeln!(
            s,
            "<h2 id=\"maps\">TLAS maps</h2>\n<p>Seen from above (x to the right, z down), {side:.0} m across. Instances whose geometry is in the TLAS are active, those a counting box stands for omitted, those nothing stands for inactive (inside an inactive hitbox, or culled); inactive hitboxes are the counting boxes of whole cells.</p>"
        );
        if let Some(st) = snapshots[0].strategies.first() {
            s.push_str("<ul class=\"legend\">");
            for (name, c, _) in st.map.legend() {
                let _ = write!(
                    s,
                    "<li><span style=\"background:#{:02x}{:02x}{:02x}\"></span>{}</li>",
                    c[0],
                    c[1],
                    c[2],
                    escape(name)
                );
            }
            s.push_str("</ul>\n");
        }
        for (snap, pics) in snapshots.iter().zip(pictures) {
            let _ = writeln!(s, "<h3>Frame {}</h3>\n<div class=\"snap\">", snap.frame);
            for (st, [_, _, map]) in snap.strategies.iter().zip(&pics.strategies) {
                let _ = writeln!(
                    s,
                    "<figure>{}<figcaption><b>{}</b>: {} active, {} omitted, {} inactive, {} inactive hitboxes</figcaption></figure>",
                    img("image/png", map, &format!("{} TLAS map", st.name), "map"),
                    escape(&st.name),
                    st.map.count(MapState::Active),
                    st.map.count(MapState::Omitted),
                    st.map.count(MapState::Inactive),
                    st.map.hitboxes.len()
                );
            }
            s.push_str("</div>\n");
        }
    }
    s.push_str("<p>Data: <a href=\"frames.csv\">frames.csv</a>, <a href=\"report.json\">report.json</a>, <a href=\"report.md\">report.md</a>.</p>\n</body></html>\n");
    Ok(s)
}
