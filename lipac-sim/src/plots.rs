//! The report's plots, drawn as SVG text with `plotters`: per-frame line
//! charts and the time-against-error scatters of `lipac compare`
//! ([`line_plot`], [`scatter_plot`]), the Pareto plots of `lipac sweep`
//! ([`pareto_plot`]) and, through [`Plot`], the TLAS maps of
//! [`crate::tlas_map`].
//!
//! A plot is first described as data ([`Plot`]: axes, series, legend), then
//! drawn ([`Plot::svg`]). Axes get round tick labels; an axis whose positive
//! data span two decades or more is logarithmic (values at or below zero
//! are drawn on its floor, and its label says so). The legend sits in a
//! panel right of the chart, one entry per line, so it never covers data or
//! other entries. Text is SVG `<text>` in the viewer's sans-serif font (no
//! font files are read).
//!
//! ```
//! use lipac_sim::plots::{Axis, Plot, Series};
//! let mut p = Plot::new("Example", Axis::linear("x", &[0.0, 10.0]), Axis::linear("y", &[0.0, 1.0]));
//! p.series.push(Series::line("a", 0, vec![(0.0, 0.0), (10.0, 1.0)]));
//! let svg = p.svg().unwrap();
//! assert!(svg.contains(">a<") || svg.contains("\na\n"));
//! ```

use std::ops::Range;

use plotters::coord::ranged1d::{AsRangedCoord, Ranged, ValueFormatter};
use plotters::prelude::*;
use plotters::style::Color as _;

use crate::compare::CompareReport;
use crate::error::SimError;
use crate::metrics::{FrameMetrics, Summary};
use crate::strategy::StrategyKind;
use crate::sweep::{SweepPoint, SweepReport, COSTS};

/// The palette series colours index into (cycled).
pub const PALETTE: [(u8, u8, u8); 8] = [
    (0x1f, 0x77, 0xb4),
    (0xd6, 0x27, 0x28),
    (0x2c, 0xa0, 0x2c),
    (0xff, 0x7f, 0x0e),
    (0x94, 0x67, 0xbd),
    (0x8c, 0x56, 0x4b),
    (0xe3, 0x77, 0xc2),
    (0x17, 0xbe, 0xcf),
];

/// Image size of every plot, pixels.
pub const SIZE: (u32, u32) = (760, 430);
/// Width of the legend panel right of the chart, pixels.
const LEGEND_W: u32 = 190;

/// A colour: an index into [`PALETTE`] or an RGB triple.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Color {
    /// `PALETTE[i % PALETTE.len()]`.
    Palette(usize),
    /// Red, green, blue.
    Rgb(u8, u8, u8),
}

impl Color {
    fn rgb(self) -> RGBColor {
        match self {
            Color::Palette(i) => {
                let (r, g, b) = PALETTE[i % PALETTE.len()];
                RGBColor(r, g, b)
            }
            Color::Rgb(r, g, b) => RGBColor(r, g, b),
        }
    }
}

/// One plot axis: label, range, linear or logarithmic.
#[derive(Clone, Debug, PartialEq)]
pub struct Axis {
    /// Axis label.
    pub label: String,
    /// Range in data units (for a log axis: both ends positive).
    pub range: Range<f64>,
    /// Logarithmic (base 10).
    pub log: bool,
    /// Whole numbers only (frames): no ticks between them.
    pub integer: bool,
}

impl Axis {
    /// A linear axis from 0 (or the smallest value, if negative) to a round
    /// value at or above the largest of `values`.
    pub fn linear(label: &str, values: &[f64]) -> Self {
        let finite = values.iter().copied().filter(|v| v.is_finite());
        let lo = finite.clone().fold(0.0, f64::min);
        let hi = nice_max(finite.fold(0.0, f64::max));
        Self {
            label: label.to_string(),
            range: if lo < 0.0 {
                -nice_max(-lo)..hi
            } else {
                0.0..hi
            },
            log: false,
            integer: false,
        }
    }

    /// A linear axis over exactly `range`.
    pub fn fixed(label: &str, range: Range<f64>) -> Self {
        Self {
            label: label.to_string(),
            range,
            log: false,
            integer: false,
        }
    }

    /// A linear axis over exactly `range` with whole-number ticks.
    pub fn whole(label: &str, range: Range<f64>) -> Self {
        Self {
            integer: true,
            ..Self::fixed(label, range)
        }
    }

    /// How many tick labels to ask plotters for.
    fn ticks(&self) -> usize {
        if self.integer {
            ((self.range.end - self.range.start).floor() as usize + 1).clamp(2, 7)
        } else {
            7
        }
    }

    /// Logarithmic from the decade below the smallest positive value to the
    /// decade above the largest when the positive `values` span two decades
    /// or more, else [`Axis::linear`].
    pub fn auto(label: &str, values: &[f64]) -> Self {
        let pos = values.iter().copied().filter(|v| v.is_finite() && *v > 0.0);
        let (min, max) = (
            pos.clone().fold(f64::INFINITY, f64::min),
            pos.fold(0.0, f64::max),
        );
        if max > 0.0 && max / min >= 100.0 {
            let lo = 10f64.powf(min.log10().floor());
            let hi = 10f64.powf(max.log10().ceil());
            let zeros = values.iter().any(|v| v.is_finite() && *v <= 0.0);
            let label = if zeros {
                format!("{label} (log; 0 at the floor)")
            } else {
                format!("{label} (log)")
            };
            Self {
                label,
                range: lo..hi,
                log: true,
                integer: false,
            }
        } else {
            Self::linear(label, values)
        }
    }

    /// `v` moved onto the floor where a log axis cannot show it.
    fn clamp(&self, v: f64) -> f64 {
        if self.log && v < self.range.start {
            self.range.start
        } else {
            v
        }
    }
}

/// What a series draws.
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    /// A polyline through the points, in order.
    Line(Vec<(f64, f64)>),
    /// A dashed polyline.
    Dashed(Vec<(f64, f64)>),
    /// Circles of radius `r` pixels, filled or as rings.
    Points {
        /// Centres.
        at: Vec<(f64, f64)>,
        /// Radius, pixels.
        r: u32,
        /// Filled (else a ring).
        filled: bool,
    },
    /// Axis-aligned rectangles `(x0, y0, x1, y1)` filled with `opacity`
    /// (0 = outline only).
    Rects {
        /// Corners.
        rects: Vec<(f64, f64, f64, f64)>,
        /// Fill opacity; 0 draws the outline.
        opacity: f64,
    },
    /// Text labels (12 px) at points, offset right and up.
    Labels(Vec<(f64, f64, String)>),
}

/// One series: a shape, its colour and its legend entry.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    /// Legend entry (`None`: not in the legend).
    pub name: Option<String>,
    /// Colour.
    pub color: Color,
    /// What it draws.
    pub shape: Shape,
}

impl Series {
    /// A solid line of palette colour `color` named `name`.
    pub fn line(name: &str, color: usize, points: Vec<(f64, f64)>) -> Self {
        Self {
            name: Some(name.to_string()),
            color: Color::Palette(color),
            shape: Shape::Line(points),
        }
    }
}

/// A plot described as data; [`Plot::svg`] draws it.
#[derive(Clone, Debug, PartialEq)]
pub struct Plot {
    /// Caption.
    pub title: String,
    /// Horizontal axis.
    pub x: Axis,
    /// Vertical axis.
    pub y: Axis,
    /// Series, drawn in order (later on top); legend entries in order.
    pub series: Vec<Series>,
    /// Image size, pixels (default [`SIZE`]).
    pub size: (u32, u32),
}

impl Plot {
    /// An empty plot of [`SIZE`].
    pub fn new(title: &str, x: Axis, y: Axis) -> Self {
        Self {
            title: title.to_string(),
            x,
            y,
            series: Vec::new(),
            size: SIZE,
        }
    }

    /// The plot as an SVG document.
    pub fn svg(&self) -> Result<String, SimError> {
        for a in [&self.x, &self.y] {
            let r = &a.range;
            if !(r.start.is_finite() && r.end.is_finite() && r.start < r.end)
                || (a.log && r.start <= 0.0)
            {
                return Err(SimError::BadConfig(
                    "plot axis range is empty or not finite",
                ));
            }
        }
        let (x, y) = (self.x.range.clone(), self.y.range.clone());
        match (self.x.log, self.y.log) {
            (false, false) => self.draw(x, y),
            (true, false) => self.draw(widen(x).log_scale(), y),
            (false, true) => self.draw(x, widen(y).log_scale()),
            (true, true) => self.draw(widen(x).log_scale(), widen(y).log_scale()),
        }
    }

    fn draw<XS, YS>(&self, xs: XS, ys: YS) -> Result<String, SimError>
    where
        XS: AsRangedCoord<Value = f64>,
        YS: AsRangedCoord<Value = f64>,
        XS::CoordDescType: Ranged<ValueType = f64> + ValueFormatter<f64>,
        YS::CoordDescType: Ranged<ValueType = f64> + ValueFormatter<f64>,
    {
        let err = |e: &dyn std::fmt::Display| SimError::Io(format!("drawing a plot: {e}"));
        let mut out = String::new();
        {
            let root = SVGBackend::with_string(&mut out, self.size).into_drawing_area();
            root.fill(&WHITE).map_err(|e| err(&e))?;
            let (left, legend) = root.split_horizontally(self.size.0.saturating_sub(LEGEND_W));
            let mut chart = ChartBuilder::on(&left)
                .caption(&self.title, ("sans-serif", 17))
                .margin(12)
                .x_label_area_size(42)
                .y_label_area_size(62)
                .build_cartesian_2d(xs, ys)
                .map_err(|e| err(&e))?;
            let fmt = |v: &f64| round_label(*v);
            chart
                .configure_mesh()
                .x_desc(&self.x.label)
                .y_desc(&self.y.label)
                .x_labels(self.x.ticks())
                .y_labels(self.y.ticks())
                .x_label_formatter(&fmt)
                .y_label_formatter(&fmt)
                .light_line_style(WHITE.mix(0.0))
                .bold_line_style(BLACK.mix(0.08))
                .label_style(("sans-serif", 12))
                .axis_desc_style(("sans-serif", 13))
                .draw()
                .map_err(|e| err(&e))?;
            let (cx, cy) = (&self.x, &self.y);
            let pt = |&(a, b): &(f64, f64)| (cx.clamp(a), cy.clamp(b));
            // Non-finite values (a hits-only replay has no error) are not drawn.
            let finite = |p: &&(f64, f64)| p.0.is_finite() && p.1.is_finite();
            let mut placed: Vec<[i32; 4]> = Vec::new();
            for s in &self.series {
                let c = s.color.rgb();
                match &s.shape {
                    Shape::Line(p) => {
                        chart
                            .draw_series(LineSeries::new(
                                p.iter().filter(finite).map(pt),
                                c.stroke_width(2),
                            ))
                            .map_err(|e| err(&e))?;
                    }
                    Shape::Dashed(p) => {
                        chart
                            .draw_series(DashedLineSeries::new(
                                p.iter().filter(finite).map(pt),
                                6,
                                4,
                                c.stroke_width(2),
                            ))
                            .map_err(|e| err(&e))?;
                    }
                    Shape::Points { at, r, filled } => {
                        let style = if *filled {
                            c.filled()
                        } else {
                            c.stroke_width(2)
                        };
                        chart
                            .draw_series(
                                at.iter()
                                    .filter(finite)
                                    .map(|p| Circle::new(pt(p), *r, style)),
                            )
                            .map_err(|e| err(&e))?;
                    }
                    Shape::Rects { rects, opacity } => {
                        let style = if *opacity > 0.0 {
                            c.mix(*opacity).filled()
                        } else {
                            c.stroke_width(1)
                        };
                        chart
                            .draw_series(rects.iter().map(|&(x0, y0, x1, y1)| {
                                Rectangle::new([pt(&(x0, y0)), pt(&(x1, y1))], style)
                            }))
                            .map_err(|e| err(&e))?;
                    }
                    Shape::Labels(l) => {
                        // Each label takes the first of a few places beside
                        // its point that no earlier label covers.
                        for (a, b, t) in l.iter().filter(|l| l.0.is_finite() && l.1.is_finite()) {
                            let (px, py) = chart.backend_coord(&pt(&(*a, *b)));
                            let w = 6 * t.chars().count() as i32;
                            let spot = LABEL_SPOTS
                                .iter()
                                .map(|&(dx, dy)| {
                                    let x = if dx < 0 { px - w + dx } else { px + dx };
                                    [x, py + dy, x + w, py + dy + 12]
                                })
                                .find(|r| !placed.iter().any(|q| overlaps(r, q)))
                                .unwrap_or([px + 5, py - 14, px + 5 + w, py - 2]);
                            placed.push(spot);
                            left.draw(&Text::new(
                                t.clone(),
                                (spot[0], spot[1]),
                                ("sans-serif", 11).into_font().color(&c),
                            ))
                            .map_err(|e| err(&e))?;
                        }
                    }
                }
            }
            // The legend panel: one entry per 20 px line.
            let mut row = 0i32;
            for s in &self.series {
                let Some(name) = &s.name else { continue };
                let y = 46 + row * 20;
                let c = s.color.rgb();
                match &s.shape {
                    Shape::Line(_) | Shape::Labels(_) => legend
                        .draw(&PathElement::new(vec![(4, y), (28, y)], c.stroke_width(2)))
                        .map_err(|e| err(&e))?,
                    Shape::Dashed(_) => {
                        for x in [4, 16] {
                            legend
                                .draw(&PathElement::new(
                                    vec![(x, y), (x + 8, y)],
                                    c.stroke_width(2),
                                ))
                                .map_err(|e| err(&e))?;
                        }
                    }
                    Shape::Points { r, filled, .. } => {
                        let style = if *filled {
                            c.filled()
                        } else {
                            c.stroke_width(2)
                        };
                        legend
                            .draw(&Circle::new((16, y), (*r).min(7), style))
                            .map_err(|e| err(&e))?;
                    }
                    Shape::Rects { opacity, .. } => {
                        let style = if *opacity > 0.0 {
                            c.mix(opacity.max(0.5)).filled()
                        } else {
                            c.stroke_width(1)
                        };
                        legend
                            .draw(&Rectangle::new([(8, y - 6), (24, y + 6)], style))
                            .map_err(|e| err(&e))?;
                    }
                }
                legend
                    .draw(&Text::new(
                        name.clone(),
                        (34, y - 7),
                        ("sans-serif", 12).into_font(),
                    ))
                    .map_err(|e| err(&e))?;
                row += 1;
            }
            root.present().map_err(|e| err(&e))?;
        }
        Ok(out)
    }
}

/// Offsets (pixels, top left of the text; negative x: right-aligned left of
/// the point) tried in turn for a point's label.
const LABEL_SPOTS: [(i32, i32); 6] = [(6, -15), (6, 3), (-6, -15), (-6, 3), (6, -6), (-6, -6)];

fn overlaps(a: &[i32; 4], b: &[i32; 4]) -> bool {
    a[0] < b[2] && b[0] < a[2] && a[1] < b[3] && b[1] < a[3]
}

/// A log range a hair wider, so that plotters labels both end decades.
fn widen(r: Range<f64>) -> Range<f64> {
    r.start * 0.999..r.end * 1.001
}

/// A tick label without float noise: `50`, `2.5`, `0.001`, `1e-5`.
///
/// ```
/// use lipac_sim::plots::round_label;
/// assert_eq!(round_label(50.0), "50");
/// assert_eq!(round_label(0.30000000000000004), "0.3");
/// assert_eq!(round_label(0.001), "0.001");
/// assert_eq!(round_label(1e-5), "1e-5");
/// assert_eq!(round_label(2.5e6), "2500000");
/// ```
pub fn round_label(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return if v.is_finite() {
            "0".into()
        } else {
            v.to_string()
        };
    }
    if v.abs() < 1e-3 {
        let s = format!("{v:.3e}");
        let (m, e) = s.split_once('e').unwrap_or((&s, "0"));
        let m = m.trim_end_matches('0').trim_end_matches('.');
        return format!("{m}e{e}");
    }
    // Six significant digits, trailing zeros dropped.
    let decimals = (5 - v.abs().log10().floor() as i32).clamp(0, 9) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// The smallest 1, 2, 2.5 or 5 times a power of ten at or above `v`
/// (1 for non-positive or non-finite `v`).
pub fn nice_max(v: f64) -> f64 {
    if v <= 0.0 || !v.is_finite() {
        return 1.0;
    }
    let p = 10f64.powf(v.log10().floor());
    for m in [1.0, 2.0, 2.5, 5.0, 10.0] {
        if m * p >= v * (1.0 - 1e-12) {
            return m * p;
        }
    }
    10.0 * p
}

/// The data of [`line_plot`]: one line per strategy of `value(frame
/// metrics)` against the frame, y axis by [`Axis::auto`].
pub fn line_chart(
    r: &CompareReport,
    title: &str,
    ylabel: &str,
    value: impl Fn(&FrameMetrics) -> f64,
) -> Plot {
    let values: Vec<f64> = r
        .strategies
        .iter()
        .flat_map(|s| s.frames.iter().map(&value))
        .collect();
    let last = f64::from(r.frames.saturating_sub(1).max(1));
    let mut p = Plot::new(
        title,
        Axis::whole("frame", 0.0..last),
        Axis::auto(ylabel, &values),
    );
    for (i, st) in r.strategies.iter().enumerate() {
        let pts = st
            .frames
            .iter()
            .map(|m| (f64::from(m.frame), value(m)))
            .collect();
        p.series.push(Series::line(&st.name, i, pts));
    }
    p
}

/// A line chart of `value(frame metrics)` per frame, one line per strategy
/// ([`line_chart`] drawn).
pub fn line_plot(
    r: &CompareReport,
    title: &str,
    ylabel: &str,
    value: impl Fn(&FrameMetrics) -> f64,
) -> Result<String, SimError> {
    line_chart(r, title, ylabel, value).svg()
}

/// `cost(summary)` against mean error, one point per strategy, titled
/// `title` with x axis `xlabel` (both axes by [`Axis::auto`]: the cheap
/// strategies and the full scene may lie decades apart).
pub fn scatter_plot(
    r: &CompareReport,
    title: &str,
    xlabel: &str,
    cost: fn(&Summary) -> f64,
) -> Result<String, SimError> {
    let xs: Vec<f64> = r.strategies.iter().map(|s| cost(&s.summary)).collect();
    let ys: Vec<f64> = r.strategies.iter().map(|s| s.summary.mean_error).collect();
    let mut p = Plot::new(
        title,
        Axis::auto(xlabel, &xs),
        Axis::auto("mean relative RMSE (indirect)", &ys),
    );
    for (i, st) in r.strategies.iter().enumerate() {
        p.series.push(Series {
            name: Some(st.name.clone()),
            color: Color::Palette(i),
            shape: Shape::Points {
                at: vec![(cost(&st.summary), st.summary.mean_error)],
                r: 6,
                filled: true,
            },
        });
    }
    p.svg()
}

/// The data of [`pareto_plot`]: per scene its points (filled circles, one
/// colour per scene), its references (the oracle and hindsight: hollow
/// circles with their names, never on a front) and its front (dashed,
/// through the front's points, which also get a black ring and their
/// configuration's name).
pub fn pareto_chart(r: &SweepReport, plot: usize) -> Plot {
    let (_, title, xlabel, cost) = COSTS[plot.min(COSTS.len() - 1)];
    let xs: Vec<f64> = r.points.iter().map(cost).collect();
    let ys: Vec<f64> = r.points.iter().map(|p| p.summary.mean_error).collect();
    let mut p = Plot::new(
        title,
        Axis::auto(xlabel, &xs),
        Axis::auto("mean relative RMSE (indirect)", &ys),
    );
    let mut rings = Vec::new();
    for (si, scene) in r.scenes.iter().enumerate() {
        let of_scene = || r.points.iter().filter(|q| q.scene == scene.name);
        let mut front: Vec<(f64, f64)> = of_scene()
            .filter(|q| q.on_front(plot))
            .map(|q| (cost(q), q.summary.mean_error))
            .collect();
        front.sort_by(|a, b| a.0.total_cmp(&b.0));
        rings.extend(front.iter().copied());
        p.series.push(Series {
            name: Some(format!("{} Pareto front", scene.name)),
            color: Color::Palette(si),
            shape: Shape::Dashed(front),
        });
        let at = |q: &SweepPoint| (cost(q), q.summary.mean_error);
        p.series.push(Series {
            name: Some(scene.name.clone()),
            color: Color::Palette(si),
            shape: Shape::Points {
                at: of_scene().filter(|q| !is_reference(q)).map(at).collect(),
                r: 4,
                filled: true,
            },
        });
        let references: Vec<(f64, f64)> = of_scene().filter(|q| is_reference(q)).map(at).collect();
        if !references.is_empty() {
            p.series.push(Series {
                name: Some(format!("{} references", scene.name)),
                color: Color::Palette(si),
                shape: Shape::Points {
                    at: references,
                    r: 4,
                    filled: false,
                },
            });
        }
        p.series.push(Series {
            name: None,
            color: Color::Palette(si),
            shape: Shape::Labels(
                of_scene()
                    .filter(|q| q.on_front(plot) || is_reference(q))
                    .map(|q| (cost(q), q.summary.mean_error, q.name.clone()))
                    .collect(),
            ),
        });
    }
    p.series.push(Series {
        name: Some("on a front".into()),
        color: Color::Rgb(0, 0, 0),
        shape: Shape::Points {
            at: rings,
            r: 6,
            filled: false,
        },
    });
    p
}

/// Whether a sweep point is a reference that reads the ground truth
/// ([`StrategyKind::is_reference`]).
fn is_reference(q: &SweepPoint) -> bool {
    StrategyKind::from_name(&q.strategy).is_some_and(StrategyKind::is_reference)
}

/// The scatter plot of cost `plot` (index into [`COSTS`]) against error
/// ([`pareto_chart`] drawn).
pub fn pareto_plot(r: &SweepReport, plot: usize) -> Result<String, SimError> {
    pareto_chart(r, plot).svg()
}

#[cfg(test)]
mod tests;
