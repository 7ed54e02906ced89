//! Line charts written as PNG and SVG with plotters.
//!
//! This module owns figure layout and rendering. Text is drawn with the
//! DejaVu Sans font embedded in the binary (`problems/assets/DejaVuSans.ttf`,
//! Bitstream Vera licence in `assets/DejaVuSans-LICENSE.txt`) and registered
//! with plotters' `ab_glyph` font loader, so rendering needs no system font
//! library at run time.

use super::svg_dots::compact_dots;
use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The font family name every chart uses.
const FONT: &str = "sans-serif";
static FONT_BYTES: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");

/// Series with more points than this are drawn with thin lines.
const DENSE: usize = 300;

/// Colours for successive series (colour-blind-safe Okabe–Ito order).
const COLORS: [RGBColor; 7] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(86, 180, 233),
    RGBColor(230, 159, 0),
    RGBColor(0, 0, 0),
];

/// Errors while drawing or writing a figure.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The embedded font could not be parsed (a corrupted build).
    #[error("the embedded font could not be loaded")]
    Font,
    /// The figure has nothing to draw in some panel.
    #[error("panel `{panel}` of figure `{figure}` has no finite points to draw{hint}")]
    Empty {
        /// Figure title.
        figure: String,
        /// Panel title.
        panel: String,
        /// Extra explanation (log scales drop non-positive values).
        hint: &'static str,
    },
    /// plotters failed while drawing or writing the file.
    #[error("could not draw {path}: {message}")]
    Draw {
        /// Output file.
        path: PathBuf,
        /// The backend's message.
        message: String,
    },
}

/// Axis scale.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scale {
    /// Linear axis.
    Linear,
    /// Base-10 logarithmic axis (non-positive values are left out).
    Log,
}

/// One curve.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    /// Legend text.
    pub label: String,
    /// `(x, y)` points in drawing order.
    pub points: Vec<(f64, f64)>,
    /// Draw dashed (for reference lines such as a fitted slope).
    pub dashed: bool,
}

impl Series {
    /// A solid curve.
    pub fn new(label: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series { label: label.into(), points, dashed: false }
    }
}

/// One set of axes.
#[derive(Clone, Debug, PartialEq)]
pub struct Panel {
    /// Caption above the axes.
    pub title: String,
    /// Horizontal axis label.
    pub x_label: String,
    /// Vertical axis label.
    pub y_label: String,
    /// Horizontal scale.
    pub x_scale: Scale,
    /// Vertical scale.
    pub y_scale: Scale,
    /// The curves.
    pub series: Vec<Series>,
}

/// Panels on a grid, filled row by row.
#[derive(Clone, Debug, PartialEq)]
pub struct Figure {
    /// Title across the top.
    pub title: String,
    /// The panels.
    pub panels: Vec<Panel>,
    /// Panels per row.
    pub columns: usize,
    /// Pixel size of one panel.
    pub panel_size: (u32, u32),
}

fn ensure_font() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| register_font(FONT, FontStyle::Normal, FONT_BYTES).is_ok());
    if ok {
        Ok(())
    } else {
        Err(PlotError::Font)
    }
}

/// A figure drawn in memory: the bytes of its PNG and SVG files.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Drawn {
    /// The PNG file.
    pub png: Vec<u8>,
    /// The SVG file.
    pub svg: Vec<u8>,
}

/// Draws `fig` in memory as PNG and SVG; `png` and `svg` are the files it
/// is meant for, named in errors. Commands write figures through
/// [`crate::report::files::OutputDir::render`], which writes these bytes
/// under temporary names of its own and renames them into place: no file
/// is opened by the drawing backends, so every file a command writes is
/// one the output folder knows about (and removes on an interruption).
pub fn render(fig: &Figure, png: &Path, svg: &Path) -> Result<Drawn, PlotError> {
    ensure_font()?;
    let columns = fig.columns.max(1);
    let rows = fig.panels.len().div_ceil(columns).max(1);
    let size = (fig.panel_size.0 * columns as u32, fig.panel_size.1 * rows as u32 + 40);
    let mut pixels = pixel_buffer(size);
    {
        let root = BitMapBackend::with_buffer(&mut pixels, size).into_drawing_area();
        draw(fig, &root, rows, columns).map_err(|m| draw_error(png, m))?;
        root.present().map_err(|e| draw_error(png, e.to_string()))?;
    }
    let png_bytes = encode_png(&pixels, size).map_err(|m| draw_error(png, m))?;
    let mut text = String::new();
    {
        let root = SVGBackend::with_string(&mut text, size).into_drawing_area();
        draw(fig, &root, rows, columns).map_err(|m| draw_error(svg, m))?;
        root.present().map_err(|e| draw_error(svg, e.to_string()))?;
    }
    Ok(Drawn { png: png_bytes, svg: text.into_bytes() })
}

/// Draws `fig` into the files `png` and `svg`, each replaced whole
/// ([`crate::report::files::replace_file`]).
pub fn render_files(fig: &Figure, png: &Path, svg: &Path) -> Result<(), PlotError> {
    write_drawn(&render(fig, png, svg)?, png, svg)
}

/// An RGB pixel buffer of `size`, white.
fn pixel_buffer((w, h): (u32, u32)) -> Vec<u8> {
    vec![255; w as usize * h as usize * 3]
}

/// The PNG encoding of the RGB `pixels` of `size`, as plotters' file
/// backend writes it.
fn encode_png(pixels: &[u8], (w, h): (u32, u32)) -> Result<Vec<u8>, String> {
    use image::ImageEncoder;
    let mut bytes = Vec::new();
    image::codecs::png::PngEncoder::new(&mut bytes)
        .write_image(pixels, w, h, image::ColorType::Rgb8)
        .map_err(|e| e.to_string())?;
    Ok(bytes)
}

/// Writes a drawn figure into the files `png` and `svg`.
fn write_drawn(drawn: &Drawn, png: &Path, svg: &Path) -> Result<(), PlotError> {
    for (path, bytes) in [(png, &drawn.png), (svg, &drawn.svg)] {
        crate::report::files::replace_file(path, |w| w.write_all(bytes))
            .map_err(|e| draw_error(path, e.to_string()))?;
    }
    Ok(())
}

/// Most points drawn per curve for each pixel column of a panel: the
/// smallest and the largest value in the column.
const POINTS_PER_COLUMN: usize = 2;

/// Thins a curve to at most `2·columns + 2` points that keep its envelope:
/// the points are split into `columns` buckets (equal widths of the drawn x
/// coordinate, `log10 x` on a log axis, when x never decreases; equal runs
/// of consecutive points otherwise), and each bucket keeps its lowest and
/// highest point in their original order. At one bucket per pixel column a
/// line through these points covers the same pixels as the full curve (up
/// to the one-pixel joins between columns). The first and last points are
/// always kept; curves with at most `2·columns` points are returned whole.
pub fn decimate(points: &[(f64, f64)], columns: usize, x_scale: Scale) -> Vec<(f64, f64)> {
    let columns = columns.max(1);
    if points.len() <= POINTS_PER_COLUMN * columns {
        return points.to_vec();
    }
    let tx = |x: f64| if x_scale == Scale::Log { x.log10() } else { x };
    let monotone = points.windows(2).all(|w| w[1].0 >= w[0].0);
    let (first, last) = (points[0], points[points.len() - 1]);
    let (x0, x1) = (tx(first.0), tx(last.0));
    let bucket_of = |k: usize, x: f64| -> usize {
        if monotone && x1 > x0 && x0.is_finite() && x1.is_finite() {
            (((tx(x) - x0) / (x1 - x0) * columns as f64) as usize).min(columns - 1)
        } else {
            k * columns / points.len()
        }
    };
    let mut out = Vec::with_capacity(POINTS_PER_COLUMN * columns + 2);
    out.push(first);
    let mut k = 0;
    while k < points.len() {
        let b = bucket_of(k, points[k].0);
        let (mut lo, mut hi) = (k, k);
        let mut end = k + 1;
        while end < points.len() && bucket_of(end, points[end].0) == b {
            if points[end].1 < points[lo].1 {
                lo = end;
            }
            if points[end].1 > points[hi].1 {
                hi = end;
            }
            end += 1;
        }
        for i in if lo <= hi { [lo, hi] } else { [hi, lo] } {
            if out.last() != Some(&points[i]) {
                out.push(points[i]);
            }
        }
        k = end;
    }
    if out.last() != Some(&last) {
        out.push(last);
    }
    out
}

fn draw_error(path: &Path, message: String) -> PlotError {
    PlotError::Draw { path: path.to_path_buf(), message }
}

/// Error type inside drawing: either our own empty-panel error or a backend
/// message; kept as `String` because backends' error types differ.
fn draw<DB: DrawingBackend>(
    fig: &Figure,
    root: &DrawingArea<DB, Shift>,
    rows: usize,
    columns: usize,
) -> Result<(), String> {
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let root = root.titled(&fig.title, (FONT, 24)).map_err(|e| e.to_string())?;
    let areas = root.split_evenly((rows, columns));
    for (panel, area) in fig.panels.iter().zip(areas.iter()) {
        draw_panel(&fig.title, panel, area)?;
    }
    Ok(())
}

/// Largest magnitude drawn. plotters computes an axis's ticks from powers
/// of ten of its span and loops forever once ten times the tick step
/// overflows (an axis spanning about 1e307 or more); values beyond this
/// limit are left out like non-finite ones.
pub const DRAWABLE: f64 = 1e300;

/// Finite points of a series that the axis scales can show, within
/// [`DRAWABLE`].
fn visible(points: &[(f64, f64)], xs: Scale, ys: Scale) -> Vec<(f64, f64)> {
    points
        .iter()
        .copied()
        .filter(|(x, y)| {
            x.abs() <= DRAWABLE
                && y.abs() <= DRAWABLE
                && (xs == Scale::Linear || *x > 0.0)
                && (ys == Scale::Linear || *y > 0.0)
        })
        .collect()
}

/// `label`, with a note when some finite points of `points` are beyond
/// [`DRAWABLE`] and therefore not drawn.
fn legend_label(label: &str, points: &[(f64, f64)]) -> String {
    let beyond = |v: f64| v.is_finite() && v.abs() > DRAWABLE;
    if points.iter().any(|&(x, y)| beyond(x) || beyond(y)) {
        format!("{label} (values beyond ±1e300 not drawn)")
    } else {
        label.to_string()
    }
}

/// Data range padded by 5 % (or widened around a constant).
fn range(lo: f64, hi: f64, scale: Scale) -> (f64, f64) {
    match scale {
        Scale::Linear => {
            if hi > lo {
                let pad = 0.05 * (hi - lo);
                (lo - pad, hi + pad)
            } else {
                let pad = if lo == 0.0 { 1.0 } else { 0.1 * lo.abs() };
                (lo - pad, hi + pad)
            }
        }
        Scale::Log => {
            // Whole decades, at least two, so the axis always gets labels.
            let mut a = lo.log10().floor();
            let mut b = hi.log10().ceil();
            if b - a < 2.0 {
                a -= 1.0;
                b = a + 3.0;
            }
            (10f64.powf(a), 10f64.powf(b))
        }
    }
}

/// An axis tick label: `0` for values within `1e-9` of the axis span (so a
/// linear axis through zero never shows round-off), fixed point from `1e-2`
/// to `1e5`, scientific notation otherwise.
pub fn tick_label(v: f64, span: f64) -> String {
    if v == 0.0 || v.abs() < 1e-9 * span {
        "0".into()
    } else if v.abs() >= 1e-2 && v.abs() < 1e5 {
        let s = format!("{v:.4}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        s.to_string()
    } else {
        format!("{v:.1e}")
    }
}

/// The corner of the plot area that the data touch least, for the legend.
fn emptiest_corner(data: &[Vec<(f64, f64)>], x: (f64, f64, Scale), y: (f64, f64, Scale)) -> SeriesLabelPosition {
    let unit = |v: f64, (lo, hi, scale): (f64, f64, Scale)| match scale {
        Scale::Linear => (v - lo) / (hi - lo),
        Scale::Log => (v.ln() - lo.ln()) / (hi.ln() - lo.ln()),
    };
    // Legend boxes take roughly the outer 45 % × 30 % of the area.
    let mut counts = [0usize; 4];
    for &(px, py) in data.iter().flatten() {
        let (u, w) = (unit(px, x), unit(py, y));
        let left = u < 0.45;
        let right = u > 0.55;
        let top = w > 0.7;
        let bottom = w < 0.3;
        counts[0] += usize::from(left && top);
        counts[1] += usize::from(right && top);
        counts[2] += usize::from(left && bottom);
        counts[3] += usize::from(right && bottom);
    }
    let corners = [
        SeriesLabelPosition::UpperLeft,
        SeriesLabelPosition::UpperRight,
        SeriesLabelPosition::LowerLeft,
        SeriesLabelPosition::LowerRight,
    ];
    let best = (0..4).min_by_key(|&i| counts[i]).unwrap_or(0);
    corners[best].clone()
}

fn draw_panel<DB: DrawingBackend>(figure: &str, panel: &Panel, area: &DrawingArea<DB, Shift>) -> Result<(), String> {
    // One bucket per pixel column of the panel keeps every curve at a few
    // thousand points however long the run (file size and drawing time).
    let columns = area.dim_in_pixel().0 as usize;
    let data: Vec<Vec<(f64, f64)>> = panel
        .series
        .iter()
        .map(|s| decimate(&visible(&s.points, panel.x_scale, panel.y_scale), columns, panel.x_scale))
        .collect();
    let all = data.iter().flatten();
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for &(x, y) in all {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if !x0.is_finite() {
        let hint = if panel.y_scale == Scale::Log {
            " (log scale drops values ≤ 0; values beyond ±1e300 are not drawn)"
        } else {
            " (values beyond ±1e300 are not drawn)"
        };
        return Err(PlotError::Empty { figure: figure.into(), panel: panel.title.clone(), hint }.to_string());
    }
    let (x0, x1) = if panel.x_scale == Scale::Log { range(x0, x1, Scale::Log) } else { (x0, x1.max(x0 + 1e-300)) };
    let (y0, y1) = range(y0, y1, panel.y_scale);
    // On a log axis every tick is a power of ten, never a rounded zero.
    let span = |lo: f64, hi: f64, scale: Scale| if scale == Scale::Log { 0.0 } else { hi - lo };
    let (x_span, y_span) = (span(x0, x1, panel.x_scale), span(y0, y1, panel.y_scale));
    let mut builder = ChartBuilder::on(area);
    builder.caption(&panel.title, (FONT, 18)).margin(12).x_label_area_size(44).y_label_area_size(84);
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    // plotters types the coordinate system by scale, so each combination is
    // its own code path; the macro keeps them identical.
    macro_rules! finish {
        ($chart:expr) => {{
            let mut chart = $chart;
            draw_axes(&mut chart, (&panel.x_label, &panel.y_label), (x_span, y_span))?;
            for (k, (series, pts)) in panel.series.iter().zip(data.iter()).enumerate() {
                let color = COLORS[k % COLORS.len()];
                // Wide polylines get miter joins, which shoot far out of the
                // chart at the sharp turns of dense oscillating data; dense
                // curves are therefore drawn one pixel wide.
                let width = if series.dashed || pts.len() > DENSE { 1 } else { 2 };
                let style = ShapeStyle::from(&color).stroke_width(width);
                if series.dashed {
                    chart
                        .draw_series(DashedLineSeries::new(pts.iter().copied(), 6, 4, style))
                        .map_err(e)?
                        .label(legend_label(&series.label, &series.points))
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color));
                } else {
                    chart
                        .draw_series(LineSeries::new(pts.iter().copied(), style))
                        .map_err(e)?
                        .label(legend_label(&series.label, &series.points))
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2)));
                }
            }
            draw_legend(&mut chart, emptiest_corner(&data, (x0, x1, panel.x_scale), (y0, y1, panel.y_scale)))?;
        }};
    }
    match (panel.x_scale, panel.y_scale) {
        (Scale::Linear, Scale::Linear) => finish!(builder.build_cartesian_2d(x0..x1, y0..y1).map_err(e)?),
        (Scale::Linear, Scale::Log) => finish!(builder.build_cartesian_2d(x0..x1, (y0..y1).log_scale()).map_err(e)?),
        (Scale::Log, Scale::Linear) => finish!(builder.build_cartesian_2d((x0..x1).log_scale(), y0..y1).map_err(e)?),
        (Scale::Log, Scale::Log) => {
            finish!(builder.build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale()).map_err(e)?)
        }
    }
    Ok(())
}

/// A scatter plot: one set of axes, each series drawn as dots (no lines),
/// for point sets such as Poincaré sections.
#[derive(Clone, Debug, PartialEq)]
pub struct Scatter {
    /// Title across the top.
    pub title: String,
    /// Horizontal axis label.
    pub x_label: String,
    /// Vertical axis label.
    pub y_label: String,
    /// The point sets (one colour each; the legend shows at most
    /// [`SCATTER_LEGEND_ENTRIES`] of them).
    pub series: Vec<Series>,
    /// Pixel size of the plot.
    pub size: (u32, u32),
}

/// Series named in a scatter plot's legend; later ones are drawn unnamed.
pub const SCATTER_LEGEND_ENTRIES: usize = 12;

/// Draws `fig` in memory as PNG and SVG, every finite point as a dot;
/// `png` and `svg` are the files it is meant for, named in errors.
/// A dot that a later dot on the same pixel covers is left out
/// ([`last_dot_per_pixel`]): the figure is the one every dot draws, and a
/// section of millions of crossings on a few curves writes an SVG of as
/// many dots as the curves cover pixels. The SVG writes each run of dots
/// of one colour as one path ([`compact_dots`]), about 10 bytes a dot.
/// Commands write scatter plots through
/// [`crate::report::files::OutputDir::render_scatter`].
pub fn render_scatter(fig: &Scatter, png: &Path, svg: &Path) -> Result<Drawn, PlotError> {
    ensure_font()?;
    let mut pixels = pixel_buffer(fig.size);
    {
        let root = BitMapBackend::with_buffer(&mut pixels, fig.size).into_drawing_area();
        draw_scatter(fig, &root).map_err(|m| draw_error(png, m))?;
        root.present().map_err(|e| draw_error(png, e.to_string()))?;
    }
    let png_bytes = encode_png(&pixels, fig.size).map_err(|m| draw_error(png, m))?;
    let mut text = String::new();
    {
        let root = SVGBackend::with_string(&mut text, fig.size).into_drawing_area();
        draw_scatter(fig, &root).map_err(|m| draw_error(svg, m))?;
        root.present().map_err(|e| draw_error(svg, e.to_string()))?;
    }
    Ok(Drawn { png: png_bytes, svg: compact_dots(&text).into_bytes() })
}

/// Draws the scatter plot `fig` into the files `png` and `svg`, each
/// replaced whole ([`crate::report::files::replace_file`]).
pub fn render_scatter_files(fig: &Scatter, png: &Path, svg: &Path) -> Result<(), PlotError> {
    write_drawn(&render_scatter(fig, png, svg)?, png, svg)
}

fn draw_scatter<DB: DrawingBackend>(fig: &Scatter, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let data: Vec<Vec<(f64, f64)>> =
        fig.series.iter().map(|s| visible(&s.points, Scale::Linear, Scale::Linear)).collect();
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for &(x, y) in data.iter().flatten() {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if !x0.is_finite() {
        let hint = " (values beyond ±1e300 are not drawn)";
        return Err(PlotError::Empty { figure: fig.title.clone(), panel: fig.title.clone(), hint }.to_string());
    }
    let (x0, x1) = range(x0, x1, Scale::Linear);
    let (y0, y1) = range(y0, y1, Scale::Linear);
    let (x_span, y_span) = (x1 - x0, y1 - y0);
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    let mut chart = ChartBuilder::on(root)
        .caption(&fig.title, (FONT, 20))
        .margin(12)
        .x_label_area_size(44)
        .y_label_area_size(84)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(e)?;
    draw_axes(&mut chart, (&fig.x_label, &fig.y_label), (x_span, y_span))?;
    let dots = last_dot_per_pixel(&data, |p| chart.backend_coord(p));
    for (k, (series, pts)) in fig.series.iter().zip(dots.iter()).enumerate() {
        let color = COLORS[k % COLORS.len()];
        let drawn =
            chart.draw_series(pts.iter().map(|&p| Circle::new(p, 1, ShapeStyle::from(&color).filled()))).map_err(e)?;
        if k < SCATTER_LEGEND_ENTRIES {
            drawn
                .label(legend_label(&series.label, &series.points))
                .legend(move |(x, y)| Circle::new((x + 10, y), 3, color.filled()));
        }
    }
    draw_legend(&mut chart, emptiest_corner(&data, (x0, x1, Scale::Linear), (y0, y1, Scale::Linear)))
}

/// The dots of a scatter plot worth drawing, series by series in their
/// order: of the points that `pixel` puts on one pixel, only the last one
/// drawn (the last of the last series that has one there). Every dot has
/// the same size and an opaque colour, so the last dot centred on a pixel
/// covers all the earlier ones there, and the dots kept are drawn in the
/// order of their last occurrence: every pixel of the figure ends with the
/// colour it has when every point is drawn. The number of dots is at most
/// the number of pixels the points fall on.
pub fn last_dot_per_pixel<P: Copy, K: Eq + std::hash::Hash>(series: &[Vec<P>], pixel: impl Fn(&P) -> K) -> Vec<Vec<P>> {
    let mut covered = std::collections::HashSet::new();
    let mut kept: Vec<Vec<P>> = series
        .iter()
        .rev()
        .map(|points| {
            let mut last: Vec<P> = points.iter().rev().filter(|p| covered.insert(pixel(p))).copied().collect();
            last.reverse();
            last
        })
        .collect();
    kept.reverse();
    kept
}

/// Draws the axes every chart shares: the descriptions `labels`, tick
/// labels rounded to the axis spans `spans` ([`tick_label`]), no light grid.
fn draw_axes<DB, X, Y>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<X, Y>>,
    (x_label, y_label): (&str, &str),
    (x_span, y_span): (f64, f64),
) -> Result<(), String>
where
    DB: DrawingBackend,
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .x_label_formatter(&|v| tick_label(*v, x_span))
        .y_label_formatter(&|v| tick_label(*v, y_span))
        .label_style((FONT, 13))
        .axis_desc_style((FONT, 15))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(|e| e.to_string())
}

/// Draws the legend box every chart shares at `corner`.
fn draw_legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    corner: SeriesLabelPosition,
) -> Result<(), String> {
    chart
        .configure_series_labels()
        .label_font((FONT, 13))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.4))
        .position(corner)
        .draw()
        .map_err(|e| e.to_string())
}
