//! Charts and figures for reports, drawn with plotters into an 8-bit RGB buffer (text with
//! ab_glyph and the DejaVu Sans font shipped in `data/fonts/`, so no system font is needed)
//! and handed back as a [`Picture`] (the task writes it as PNG).

use std::path::Path;
use std::sync::Once;

use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::colors::colormaps::ViridisRGB;

use crate::model::error::{Error, Result};

const FONT: &str = "sans-serif";

fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The bytes are a valid TrueType font shipped with the crate.
        let _ = plotters::style::register_font(
            FONT,
            FontStyle::Normal,
            include_bytes!("../../data/fonts/DejaVuSans.ttf"),
        );
    });
}

/// A drawing error of the chart to be written as `file`.
fn chart_error(file: &str, e: impl std::fmt::Display) -> Error {
    Error::write(
        Path::new(file),
        "cannot draw the chart",
        std::io::Error::other(e.to_string()),
    )
}

/// Colour of series `i`.
fn colour(i: usize) -> RGBColor {
    const COLOURS: [RGBColor; 8] = [
        RGBColor(31, 119, 180),
        RGBColor(214, 39, 40),
        RGBColor(44, 160, 44),
        RGBColor(255, 127, 14),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(23, 190, 207),
    ];
    COLOURS[i % COLOURS.len()]
}

/// Which colour a series or a bar is drawn in, as the caller says: a method keeps its
/// colour in every chart.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Colour {
    /// The ground truth: near-black.
    Truth,
    /// Entry `k` of the palette (a method's own, [`crate::report::methods::Method::palette_index`]).
    Palette(usize),
    /// By position `i` in the chart: the palette's entry `3 + i`, after the methods' three.
    ByPosition,
}

/// The colour of the `i`-th series or bar.
fn colour_of(colour_of_series: Colour, i: usize) -> RGBColor {
    match colour_of_series {
        Colour::Truth => RGBColor(40, 40, 40),
        Colour::Palette(k) => colour(k),
        Colour::ByPosition => colour(3 + i),
    }
}

/// A drawn chart: 8-bit RGB, row-major, for the task to write as PNG.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Picture {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `3 × width × height` bytes.
    pub rgb: Vec<u8>,
}

/// Draws into a fresh `width × height` white buffer (`file` names it in errors).
fn draw_png(
    file: &str,
    (width, height): (u32, u32),
    draw: impl FnOnce(
        &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
    ) -> std::result::Result<(), Box<dyn std::error::Error>>,
) -> Result<Picture> {
    register_font();
    let mut buffer = vec![255_u8; 3 * width as usize * height as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width, height)).into_drawing_area();
        draw(&root).map_err(|e| chart_error(file, e))?;
        root.present().map_err(|e| chart_error(file, e))?;
    }
    Ok(Picture {
        width,
        height,
        rgb: buffer,
    })
}

/// One named polyline.
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend entry.
    pub label: String,
    /// Its colour.
    pub colour: Colour,
    /// `(x, y)` points; non-finite points are skipped.
    pub points: Vec<(f64, f64)>,
    /// Draw a marker at every point.
    pub markers: bool,
}

/// The chart type of line and scatter charts.
type XyChart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Titled axes with labels and a light grid over `xs × ys`.
fn axes<'a, 'b>(
    root: &'a DrawingArea<BitMapBackend<'b>, plotters::coord::Shift>,
    title: &str,
    x: (&str, std::ops::Range<f64>),
    y: (&str, std::ops::Range<f64>),
) -> std::result::Result<XyChart<'a, 'b>, Box<dyn std::error::Error>> {
    axes_labelled(root, title, x, y, None)
}

/// [`axes`] with the y tick labels written by `y_format` (for values drawn at their log10).
fn axes_labelled<'a, 'b>(
    root: &'a DrawingArea<BitMapBackend<'b>, plotters::coord::Shift>,
    title: &str,
    (x_label, xs): (&str, std::ops::Range<f64>),
    (y_label, ys): (&str, std::ops::Range<f64>),
    y_format: Option<&dyn Fn(&f64) -> String>,
) -> std::result::Result<XyChart<'a, 'b>, Box<dyn std::error::Error>> {
    let mut chart = ChartBuilder::on(root)
        .caption(title, (FONT, 22))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(xs, ys)?;
    let mut mesh = chart.configure_mesh();
    mesh.x_desc(x_label)
        .y_desc(y_label)
        .light_line_style(RGBColor(238, 238, 238))
        .label_style((FONT, 14));
    if let Some(format) = y_format {
        mesh.y_label_formatter(format);
    }
    mesh.draw()?;
    Ok(chart)
}

fn padded_range(values: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if !lo.is_finite() {
        return 0.0..1.0;
    }
    let pad = if hi > lo {
        0.05 * (hi - lo)
    } else {
        0.5 * lo.abs().max(1.0)
    };
    (lo - pad)..(hi + pad)
}

/// A line chart of `series` with a legend.
pub fn line_chart(
    file: &str,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
) -> Result<Picture> {
    let finite = |s: &Series| {
        s.points
            .iter()
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .copied()
            .collect::<Vec<_>>()
    };
    let xs = padded_range(
        series
            .iter()
            .flat_map(|s| finite(s).into_iter().map(|p| p.0)),
    );
    let ys = padded_range(
        series
            .iter()
            .flat_map(|s| finite(s).into_iter().map(|p| p.1)),
    );
    // The legend in its own column right of the plot, never over the data.
    draw_png(file, (1000, 500), |root| {
        let (plot, legend) = root.split_horizontally(790);
        let mut chart = axes(&plot, title, (x_label, xs), (y_label, ys))?;
        for (i, s) in series.iter().enumerate() {
            let c = colour_of(s.colour, i);
            let points = finite(s);
            chart.draw_series(LineSeries::new(points.clone(), c.stroke_width(2)))?;
            if s.markers {
                chart.draw_series(points.iter().map(|&p| Circle::new(p, 3, c.filled())))?;
            }
            let y = 60 + 26 * i as i32;
            legend.draw(&PathElement::new(vec![(4, y), (30, y)], c.stroke_width(3)))?;
            legend.draw(&Text::new(s.label.clone(), (36, y - 8), (FONT, 14)))?;
        }
        Ok(())
    })
}

/// A bar per `(label, value, colour)`, in order, each with its name and value above it.
pub fn bar_chart(
    file: &str,
    title: &str,
    y_label: &str,
    bars: &[(String, f64, Colour)],
) -> Result<Picture> {
    let top = bars
        .iter()
        .map(|b| b.1)
        .filter(|v| v.is_finite())
        .fold(0.0_f64, f64::max)
        * 1.25;
    let top = if top > 0.0 { top } else { 1.0 };
    let n = bars.len();
    draw_png(file, (800, 450), |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(title, (FONT, 22))
            .margin(12)
            .x_label_area_size(10)
            .y_label_area_size(80)
            .build_cartesian_2d(0.0..n as f64, 0.0..top)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .disable_x_axis()
            .light_line_style(RGBColor(238, 238, 238))
            .y_desc(y_label)
            .label_style((FONT, 14))
            .draw()?;
        chart.draw_series(bars.iter().enumerate().map(|(i, b)| {
            Rectangle::new(
                [(i as f64 + 0.15, 0.0), (i as f64 + 0.85, b.1.max(0.0))],
                colour_of(b.2, i).filled(),
            )
        }))?;
        // Text hangs below its anchor: the name two lines above the bar, the value one.
        chart.draw_series(bars.iter().enumerate().map(|(i, b)| {
            Text::new(
                b.0.clone(),
                (i as f64 + 0.17, b.1.max(0.0) + 0.16 * top),
                (FONT, 15),
            )
        }))?;
        chart.draw_series(bars.iter().enumerate().map(|(i, b)| {
            Text::new(
                format!("{:.3e}", b.1),
                (i as f64 + 0.17, b.1.max(0.0) + 0.08 * top),
                (FONT, 14),
            )
        }))?;
        Ok(())
    })
}

/// Labelled points `(label, x, y)`.
pub fn scatter_chart(
    file: &str,
    title: &str,
    x_label: &str,
    y_label: &str,
    points: &[(String, f64, f64)],
) -> Result<Picture> {
    let xs = padded_range(points.iter().map(|p| p.1).chain([0.0]));
    let ys = padded_range(points.iter().map(|p| p.2));
    let xs = xs.start..(xs.end + 0.25 * (xs.end - xs.start));
    draw_png(file, (800, 500), |root| {
        let mut chart = axes(root, title, (x_label, xs), (y_label, ys))?;
        for (i, (label, x, y)) in points.iter().enumerate() {
            chart.draw_series([Circle::new((*x, *y), 6, colour(i).filled())])?;
            chart.draw_series([Text::new(
                label.clone(),
                (*x, *y),
                (FONT, 15).into_font().color(&BLACK),
            )
            .into_dyn()])?;
        }
        Ok(())
    })
}

/// One point of [`model_size_chart`]: which dataset and model (indices into its name lists),
/// parameters and held-out PSNR.
pub struct SizePoint {
    /// Index into the dataset names: the marker's shape.
    pub dataset: usize,
    /// Index into the model names: the marker's colour.
    pub model: usize,
    /// Stored numbers.
    pub parameters: f64,
    /// dB.
    pub psnr: f64,
}

/// Parameters (a log axis labelled in values) against held-out PSNR: one colour per model,
/// one marker shape per dataset, and the legend beside the plot, not over it (no labels at
/// the points, so none collide; the report's table beside the chart has the numbers).
pub fn model_size_chart(
    file: &str,
    title: &str,
    datasets: &[&str],
    models: &[&str],
    points: &[SizePoint],
) -> Result<Picture> {
    let (lo, hi) = points
        .iter()
        .map(|p| p.parameters.max(1.0))
        .fold((f64::INFINITY, 0.0_f64), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    let (lo, hi) = if lo.is_finite() {
        (lo / 1.6, hi * 1.6)
    } else {
        (1.0, 10.0)
    };
    let ys = padded_range(points.iter().map(|p| p.psnr));
    draw_png(file, (900, 500), |root| {
        let (plot, legend) = root.split_horizontally(690);
        let mut chart = ChartBuilder::on(&plot)
            .caption(title, (FONT, 22))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d((lo..hi).log_scale(), ys)?;
        chart
            .configure_mesh()
            .x_desc("parameters (log scale)")
            .y_desc("PSNR, held-out views and times (dB)")
            .x_label_formatter(&|v| format!("{}", *v as u64))
            .light_line_style(RGBColor(238, 238, 238))
            .label_style((FONT, 14))
            .draw()?;
        for p in points {
            let (at, c) = ((p.parameters.max(1.0), p.psnr), colour(p.model));
            match p.dataset % 3 {
                0 => chart.draw_series([Circle::new(at, 6, c.filled())])?,
                1 => chart.draw_series([TriangleMarker::new(at, 8, c.filled())])?,
                _ => chart.draw_series([Cross::new(at, 6, c.stroke_width(3))])?,
            };
        }
        let text =
            |s: &str, x: i32, y: i32| Text::new(s.to_owned(), (x, y), (FONT, 15).into_font());
        legend.draw(&text("model (colour)", 10, 60))?;
        for (k, name) in models.iter().enumerate() {
            let y = 90 + 24 * k as i32;
            legend.draw(&Circle::new((18, y + 7), 6, colour(k).filled()))?;
            legend.draw(&text(name, 32, y))?;
        }
        let top = 110 + 24 * models.len() as i32;
        legend.draw(&text("data (shape)", 10, top))?;
        for (k, name) in datasets.iter().enumerate() {
            let y = top + 30 + 24 * k as i32;
            let grey = RGBColor(90, 90, 90);
            match k % 3 {
                0 => legend.draw(&Circle::new((18, y + 7), 6, grey.filled()))?,
                1 => legend.draw(&TriangleMarker::new((18, y + 7), 8, grey.filled()))?,
                _ => legend.draw(&Cross::new((18, y + 7), 6, grey.stroke_width(3)))?,
            }
            legend.draw(&text(name, 32, y))?;
        }
        Ok(())
    })
}

/// One panel of a volume figure: a label and `res × res` values (row-major).
pub struct Panel<'a> {
    /// Caption under the panel.
    pub label: String,
    /// Values, row-major, `res²`.
    pub values: &'a [f32],
}

/// Panels side by side, each `res × res` scaled up, coloured with viridis over
/// `[0, vmax]`, under `title`.
pub fn panels_figure(
    file: &str,
    title: &str,
    res: usize,
    panels: &[Panel<'_>],
    vmax: f32,
) -> Result<Picture> {
    let scale = (256 / res.max(1)).max(1) as u32;
    let side = res as u32 * scale;
    let (gap, top, bottom, bar) = (16_u32, 40_u32, 34_u32, 90_u32);
    let width = gap + panels.len() as u32 * (side + gap) + bar;
    let height = top + side + bottom;
    draw_png(file, (width, height), |root| {
        root.draw(&Text::new(title.to_owned(), (gap as i32, 10), (FONT, 20)))?;
        for (p, panel) in panels.iter().enumerate() {
            let x0 = gap + p as u32 * (side + gap);
            for row in 0..res {
                for col in 0..res {
                    let v = panel.values[row * res + col];
                    let f = if vmax > 0.0 {
                        f64::from((v / vmax).clamp(0.0, 1.0))
                    } else {
                        0.0
                    };
                    let c = ViridisRGB::get_color(f);
                    let (x, y) = (
                        (x0 + col as u32 * scale) as i32,
                        (top + row as u32 * scale) as i32,
                    );
                    root.draw(&Rectangle::new(
                        [(x, y), (x + scale as i32, y + scale as i32)],
                        c.filled(),
                    ))?;
                }
            }
            root.draw(&Text::new(
                panel.label.clone(),
                (x0 as i32, (top + side + 8) as i32),
                (FONT, 16),
            ))?;
        }
        // The colour bar: 0 at the bottom, vmax at the top, with its values.
        let x0 = (gap + panels.len() as u32 * (side + gap)) as i32;
        for k in 0..side {
            let f = f64::from(side - 1 - k) / f64::from(side.max(2) - 1);
            let y = (top + k) as i32;
            root.draw(&Rectangle::new(
                [(x0, y), (x0 + 18, y + 1)],
                ViridisRGB::get_color(f).filled(),
            ))?;
        }
        for k in 0..=4 {
            let f = f64::from(k) / 4.0;
            let y = top as i32 + ((1.0 - f) * f64::from(side - 1)) as i32;
            root.draw(&PathElement::new(vec![(x0 + 18, y), (x0 + 24, y)], BLACK))?;
            root.draw(&Text::new(
                format!("{:.2}", f * f64::from(vmax)),
                (x0 + 27, y - 7),
                (FONT, 13),
            ))?;
        }
        Ok(())
    })
}

/// The xy, xz and yz slices of `volume` at time `tau` through its peak, labelled with
/// their plane's coordinate, coloured over `[0, vmax]`.
pub fn volume_slices_figure(
    file: &str,
    name: &str,
    tau: f64,
    volume: &crate::volume::Volume,
    vmax: f32,
) -> Result<Picture> {
    let g = &volume.grid;
    let peak = volume.peak_cell();
    let at = |a: usize| g.centre(a, peak[a]);
    let [xy, xz, yz] = volume.slices_through(peak);
    let (hi, lo) = volume.range();
    // Rows run along the second named axis, columns along the first; every axis spans the
    // grid, in scene units.
    let panels = [
        Panel {
            label: format!("xy at z = {:.2}", at(2)),
            values: &xy,
        },
        Panel {
            label: format!("xz at y = {:.2}", at(1)),
            values: &xz,
        },
        Panel {
            label: format!("yz at x = {:.2}", at(0)),
            values: &yz,
        },
    ];
    let title = format!(
        "{name}, t = {tau}: max {hi:.3}, min {lo:.3}; axes [{:.2}, {:.2}] scene units",
        g.min[0].min(g.min[1]).min(g.min[2]),
        g.max[0].max(g.max[1]).max(g.max[2])
    );
    panels_figure(file, &title, g.res, &panels, vmax)
}

/// One point of a speed-against-error chart.
#[derive(Clone, Debug)]
pub struct TradeOffPoint {
    /// Text shown next to front points.
    pub label: String,
    /// Cost (x).
    pub cost: f64,
    /// Error (y, drawn on a log₁₀ axis; must be > 0 to be drawn).
    pub error: f64,
    /// Series index (colour and legend entry).
    pub series: usize,
    /// On the Pareto front: drawn larger, labelled and joined by a line.
    pub front: bool,
}

/// Cost against log₁₀ error, one colour per entry of `series`, the Pareto front joined by a
/// line and labelled.
pub fn pareto_chart(
    file: &str,
    title: &str,
    (x_label, y_label): (&str, &str),
    series: &[String],
    points: &[TradeOffPoint],
) -> Result<Picture> {
    let drawable: Vec<&TradeOffPoint> = points
        .iter()
        .filter(|p| p.cost.is_finite() && p.error > 0.0 && p.error.is_finite())
        .collect();
    let xs = padded_range(drawable.iter().map(|p| p.cost).chain([0.0]));
    let xs = xs.start..(xs.end + 0.3 * (xs.end - xs.start));
    let ys = padded_range(drawable.iter().map(|p| p.error.log10()));
    let (xs_span, ys_span) = (xs.end - xs.start, ys.end - ys.start);
    let mut front: Vec<(f64, f64)> = drawable
        .iter()
        .filter(|p| p.front)
        .map(|p| (p.cost, p.error.log10()))
        .collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    draw_png(file, (900, 560), |root| {
        // The errors are drawn at their log10, and the axis is labelled with the values.
        let mut chart = axes_labelled(
            root,
            title,
            (x_label, xs),
            (y_label, ys),
            Some(&|v| format!("{:.0e}", 10f64.powf(*v))),
        )?;
        chart
            .draw_series(LineSeries::new(front.clone(), BLACK.stroke_width(1)))?
            .label("Pareto front")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(1)));
        for (s, name) in series.iter().enumerate() {
            let c = colour(s);
            chart
                .draw_series(
                    drawable
                        .iter()
                        .filter(|p| p.series == s)
                        .map(|p| Circle::new((p.cost, p.error.log10()), 4, c.filled())),
                )?
                .label(name.clone())
                .legend(move |(x, y)| Circle::new((x + 10, y), 4, c.filled()));
        }
        chart.draw_series(
            drawable
                .iter()
                .filter(|p| p.front)
                .map(|p| Circle::new((p.cost, p.error.log10()), 7, BLACK.stroke_width(1))),
        )?;
        // Label front points from the most accurate up, skipping one that would overlap the
        // last label drawn.
        let (x_span, y_span) = (xs_span, ys_span);
        let mut labelled: Vec<(f64, f64)> = Vec::new();
        let mut front_points: Vec<&&TradeOffPoint> = drawable.iter().filter(|p| p.front).collect();
        front_points.sort_by(|a, b| a.error.total_cmp(&b.error));
        for p in front_points {
            let at = (p.cost, p.error.log10());
            let clear = labelled.iter().all(|&(x, y)| {
                (x - at.0).abs() > 0.12 * x_span || (y - at.1).abs() > 0.05 * y_span
            });
            if clear {
                chart.draw_series([Text::new(
                    format!("  {}", p.label),
                    at,
                    (FONT, 13).into_font().color(&BLACK),
                )])?;
                labelled.push(at);
            }
        }
        chart
            .configure_series_labels()
            .label_font((FONT, 14))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::LowerLeft)
            .draw()?;
        Ok(())
    })
}
