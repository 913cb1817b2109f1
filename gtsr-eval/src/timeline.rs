//! Error against run time: a log of evaluation points during training, written as CSV and
//! plotted as PNG (PSNR against training time, and the chamfer, the completeness split by the
//! masks' blindness and the depth error against training time when any point has them; the
//! chamfer panel also draws the mesh fused from the rendered depth alone, dashed, and the masks
//! alone, dotted).

use std::ops::Range;
use std::path::Path;

use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result, write_atomic};
use gtsr_mesh::MeshError;

/// One evaluation during a run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TimelinePoint {
    /// Training iteration at which the evaluation was made.
    pub iteration: u64,
    /// Training wall time so far in seconds (excluding evaluation time).
    pub train_seconds: f64,
    /// Mean PSNR (dB) over the evaluation views.
    pub psnr: f64,
    /// Mean SSIM over the evaluation views.
    pub ssim: f64,
    /// Chamfer distance of the extracted mesh, when one was extracted.
    pub chamfer: Option<f64>,
    /// Chamfer distance of the mesh fused from the rendered depth alone (TSDF without the
    /// masks, as PGSR and 2DGS extract): the model's own geometry, where the extracted mesh is
    /// bounded by the masks and may not follow it.
    #[serde(default)]
    pub depth_only_chamfer: Option<f64>,
    /// Chamfer distance of the masks alone at the dataset's resolution (the same at every
    /// point of a run): the baseline a mesh must beat.
    #[serde(default)]
    pub masks_alone_chamfer: Option<f64>,
    /// Median absolute error of the rendered surface depth on the evaluation views, against
    /// a ground-truth mesh, when there is one. It follows the geometry where the mesh is
    /// bounded by the masks and does not move.
    #[serde(default)]
    pub depth_error: Option<f64>,
    /// Mean distance from the ground truth the masks' hull is blind to (the part of
    /// [`crate::HullBlind`], farther than its threshold from the hull) to the extracted
    /// mesh: the part only the shading can place.
    #[serde(default)]
    pub blind_completeness: Option<f64>,
    /// Mean distance from the rest of the (seen) ground truth to the extracted mesh.
    #[serde(default)]
    pub rest_completeness: Option<f64>,
    /// [`TimelinePoint::blind_completeness`] of the masks alone (the same at every point).
    #[serde(default)]
    pub masks_alone_blind_completeness: Option<f64>,
    /// [`TimelinePoint::rest_completeness`] of the masks alone (the same at every point).
    #[serde(default)]
    pub masks_alone_rest_completeness: Option<f64>,
    /// Chamfer distance between this point's extracted mesh and the previous point's (scene
    /// units): how much the mesh still changes as the model trains. Missing at the first mesh.
    #[serde(default)]
    pub mesh_change: Option<f64>,
    /// Number of Gaussians.
    pub gaussians: u64,
    /// Free-form label (for example the method or the evaluation split); [`FINAL_LABEL`]
    /// marks a run's final evaluation.
    pub label: String,
}

/// The label of a run's final evaluation: the mesh as the run outputs it (the full extraction;
/// the evaluations during training take a quicker one), at the last training time. Plots
/// draw it as a cross off the curve; a timeline has at most one.
pub const FINAL_LABEL: &str = "final";

/// An error-against-run-time log.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Timeline {
    /// The points, in the order they were recorded.
    pub points: Vec<TimelinePoint>,
}

/// The CSV header [`Timeline::write_csv`] writes. [`Timeline::read_csv`] reads the columns by
/// name and also takes logs without the optional ones ([`OPTIONAL_COLUMNS`]).
pub const CSV_HEADER: &str = "iteration,train_seconds,psnr,ssim,chamfer,depth_only_chamfer,\
                              masks_alone_chamfer,depth_error,blind_completeness,\
                              rest_completeness,masks_alone_blind_completeness,\
                              masks_alone_rest_completeness,mesh_change,gaussians,label";

/// The columns older logs lack (each read as missing).
pub const OPTIONAL_COLUMNS: [&str; 8] = [
    "depth_only_chamfer",
    "masks_alone_chamfer",
    "depth_error",
    "blind_completeness",
    "rest_completeness",
    "masks_alone_blind_completeness",
    "masks_alone_rest_completeness",
    "mesh_change",
];

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// Splits one CSV line (RFC 4180 quoting, no embedded newlines).
fn split_csv(line: &str) -> Option<Vec<String>> {
    let mut fields = Vec::new();
    let mut cur = String::new();
    let mut chars = line.chars().peekable();
    let mut quoted = false;
    while let Some(ch) = chars.next() {
        match (quoted, ch) {
            (true, '"') if chars.peek() == Some(&'"') => {
                chars.next();
                cur.push('"');
            }
            (true, '"') => quoted = false,
            (false, '"') if cur.is_empty() => quoted = true,
            (false, ',') => fields.push(std::mem::take(&mut cur)),
            (_, c) => cur.push(c),
        }
    }
    if quoted {
        return None;
    }
    fields.push(cur);
    Some(fields)
}

impl Timeline {
    /// An empty timeline.
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends a point.
    pub fn push(&mut self, point: TimelinePoint) {
        self.points.push(point);
    }

    /// Sets the final evaluation ([`FINAL_LABEL`]), replacing an earlier one (`point`'s label
    /// is set to it).
    pub fn set_final(&mut self, mut point: TimelinePoint) {
        self.drop_final();
        point.label = FINAL_LABEL.to_string();
        self.points.push(point);
    }

    /// Removes the final evaluation, for a run that trains on.
    pub fn drop_final(&mut self) {
        self.points.retain(|p| p.label != FINAL_LABEL);
    }

    /// The CSV text: [`CSV_HEADER`], then one line per point; floats in Rust's shortest
    /// round-trip form, a missing chamfer or depth error as an empty field, the label quoted
    /// when needed.
    pub fn to_csv(&self) -> String {
        let mut s = String::from(CSV_HEADER);
        s.push('\n');
        let opt = |v: Option<f64>| v.map(|c| c.to_string()).unwrap_or_default();
        for p in &self.points {
            s.push_str(&format!(
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
                p.iteration,
                p.train_seconds,
                p.psnr,
                p.ssim,
                opt(p.chamfer),
                opt(p.depth_only_chamfer),
                opt(p.masks_alone_chamfer),
                opt(p.depth_error),
                opt(p.blind_completeness),
                opt(p.rest_completeness),
                opt(p.masks_alone_blind_completeness),
                opt(p.masks_alone_rest_completeness),
                opt(p.mesh_change),
                p.gaussians,
                csv_field(&p.label)
            ));
        }
        s
    }

    /// Writes [`Timeline::to_csv`] to `path` atomically (temporary file, then rename).
    pub fn write_csv(&self, path: &Path) -> Result<()> {
        write_atomic(path, self.to_csv().as_bytes())
    }

    /// Reads a file written by [`Timeline::write_csv`], or by a version without some of the
    /// [`OPTIONAL_COLUMNS`] (read as missing). Errors name the file and line.
    pub fn read_csv(path: &Path) -> Result<Timeline> {
        let text = std::fs::read_to_string(path).map_err(|e| MeshError::io(path, e))?;
        let err = |line: usize, message: String| -> EvalError {
            MeshError::Parse {
                path: path.to_path_buf(),
                message: format!("line {line}: {message}"),
            }
            .into()
        };
        let mut lines = text.lines().enumerate();
        let header: Vec<&str> = match lines.next() {
            Some((_, h)) => h.trim_end().split(',').collect(),
            None => Vec::new(),
        };
        // Every column of CSV_HEADER, in its order, except optional ones that are absent.
        let expected: Vec<&str> = CSV_HEADER
            .split(',')
            .filter(|c| !OPTIONAL_COLUMNS.contains(c) || header.contains(c))
            .collect();
        if header != expected {
            return Err(err(1, format!("expected header `{CSV_HEADER}`")));
        }
        let column = |name: &str| header.iter().position(|c| *c == name);
        let fields = header.len();
        let mut points = Vec::new();
        for (k, line) in lines {
            if line.trim().is_empty() {
                continue;
            }
            let f = split_csv(line).ok_or_else(|| err(k + 1, "unterminated quote".into()))?;
            if f.len() != fields {
                return Err(err(
                    k + 1,
                    format!("expected {fields} fields, found {}", f.len()),
                ));
            }
            let field = |name: &str| column(name).map(|i| f[i].trim());
            let num = |name: &str| -> Result<f64> {
                let v = field(name).unwrap_or_default();
                v.parse::<f64>()
                    .map_err(|e| err(k + 1, format!("{name} `{v}`: {e}")))
            };
            let int = |name: &str| -> Result<u64> {
                let v = field(name).unwrap_or_default();
                v.parse::<u64>()
                    .map_err(|e| err(k + 1, format!("{name} `{v}`: {e}")))
            };
            let optional = |name: &str| -> Result<Option<f64>> {
                match field(name) {
                    None | Some("") => Ok(None),
                    Some(_) => num(name).map(Some),
                }
            };
            points.push(TimelinePoint {
                iteration: int("iteration")?,
                train_seconds: num("train_seconds")?,
                psnr: num("psnr")?,
                ssim: num("ssim")?,
                chamfer: optional("chamfer")?,
                depth_only_chamfer: optional("depth_only_chamfer")?,
                masks_alone_chamfer: optional("masks_alone_chamfer")?,
                depth_error: optional("depth_error")?,
                blind_completeness: optional("blind_completeness")?,
                rest_completeness: optional("rest_completeness")?,
                masks_alone_blind_completeness: optional("masks_alone_blind_completeness")?,
                masks_alone_rest_completeness: optional("masks_alone_rest_completeness")?,
                mesh_change: optional("mesh_change")?,
                gaussians: int("gaussians")?,
                label: column("label").map(|i| f[i].clone()).unwrap_or_default(),
            });
        }
        Ok(Timeline { points })
    }
}

static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

/// How a [`LogCurve`] is drawn.
#[derive(Clone, Copy, PartialEq)]
enum Stroke {
    Solid,
    /// Long dashes.
    Dashed,
    /// Short dashes.
    Dotted,
}

impl Stroke {
    /// The lengths of a dash and of the gap after it in pixels; `None` for a solid line.
    fn dashes(self) -> Option<(i32, i32)> {
        match self {
            Stroke::Solid => None,
            Stroke::Dashed => Some((8, 6)),
            Stroke::Dotted => Some((2, 4)),
        }
    }

    /// The length of the legend's sample in pixels: as long as the stroke's first dash.
    fn sample(self) -> i32 {
        match self {
            Stroke::Solid => 20,
            Stroke::Dashed => 8,
            Stroke::Dotted => 3,
        }
    }
}

/// One curve per series of a [`LogPanel`]: one optional value of each point.
struct LogCurve {
    get: fn(&TimelinePoint) -> Option<f64>,
    /// Appended to the series' name in the legend.
    suffix: &'static str,
    stroke: Stroke,
}

impl LogCurve {
    fn new(get: fn(&TimelinePoint) -> Option<f64>, suffix: &'static str, stroke: Stroke) -> Self {
        LogCurve {
            get,
            suffix,
            stroke,
        }
    }
}

/// A panel of [`plot_png`] with a log axis.
struct LogPanel {
    caption: &'static str,
    y_desc: &'static str,
    curves: Vec<LogCurve>,
}

impl LogPanel {
    /// The values of every curve of the panel over `points`.
    fn values<'p>(&self, points: impl Iterator<Item = &'p TimelinePoint>) -> Vec<f64> {
        points
            .flat_map(|p| self.curves.iter().filter_map(|c| (c.get)(p)))
            .filter(|c| c.is_finite() && *c > 0.0)
            .collect()
    }
}

fn ensure_font() -> std::result::Result<(), String> {
    static REGISTERED: std::sync::OnceLock<std::result::Result<(), String>> =
        std::sync::OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
                .map_err(|_| "the bundled DejaVuSans font failed to load".to_string())
        })
        .clone()
}

/// Padded `[lo, hi]` of finite values (a unit range around a single value).
fn range_of(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
            (l.min(v), h.max(v))
        });
    if lo > hi {
        return None;
    }
    let pad = if hi > lo {
        0.05 * (hi - lo)
    } else {
        0.5 * lo.abs().max(1.0)
    };
    Some((lo - pad, hi + pad))
}

/// The chart of one panel of [`plot_png`]: training time against a value.
type Chart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// The chart of one panel on `area`, captioned, with its axes drawn: training time over `t`
/// on x, the value over `y` on y, described as `y_desc` and labelled by `y_format` (plotters'
/// labels when `None`), with `y_label_px` pixels for the y labels. Errors as plotters' text.
fn panel_chart<'a, 'b>(
    area: &'a DrawingArea<BitMapBackend<'b>, Shift>,
    caption: &str,
    y_label_px: u32,
    (t, y): (Range<f64>, Range<f64>),
    y_desc: &str,
    y_format: Option<&dyn Fn(&f64) -> String>,
) -> std::result::Result<Chart<'a, 'b>, String> {
    let mut chart = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 24))
        .margin(16)
        .x_label_area_size(48)
        .y_label_area_size(y_label_px)
        .build_cartesian_2d(t, y)
        .map_err(|e| e.to_string())?;
    let x_format = |v: &f64| format!("{v:.0}");
    let mut mesh = chart.configure_mesh();
    mesh.x_desc("training time (s)")
        .x_labels(6)
        .x_label_formatter(&x_format)
        .y_desc(y_desc);
    if let Some(y_format) = y_format {
        mesh.y_label_formatter(y_format);
    }
    mesh.label_style(("sans-serif", 16))
        .draw()
        .map_err(|e| e.to_string())?;
    Ok(chart)
}

/// Draws the legend of `chart` at `position`. Errors as plotters' text.
fn draw_legend<'a, 'b: 'a>(
    chart: &mut Chart<'a, 'b>,
    position: SeriesLabelPosition,
) -> std::result::Result<(), String> {
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 16))
        .position(position)
        .draw()
        .map_err(|e| e.to_string())
}

/// Plot size in pixels, up to three panels.
const PLOT_SIZE: (u32, u32) = (1400, 560);
/// The least width of one panel in pixels: a plot of more panels widens.
const PANEL_MIN_WIDTH: u32 = 465;

/// Height of one legend row in pixels at the legend's 16 px font, with its spacing.
const LEGEND_ROW_PX: f64 = 22.0;
/// The legend's frame and its gap to the plot's edge, in pixels.
const LEGEND_FRAME_PX: f64 = 24.0;
/// What a log panel's caption, margins and x-axis labels take of its height, in pixels.
const PANEL_FURNITURE_PX: f64 = 112.0;

/// The share of the data's range to add above it so that a legend of `entries` rows at the
/// top of a panel `panel_px` high lies above every curve (at most 2: a panel too short for
/// its legend keeps two thirds of its height for the data).
fn legend_headroom(entries: usize, panel_px: u32) -> f64 {
    if entries == 0 {
        return 0.0;
    }
    let plot = (f64::from(panel_px) - PANEL_FURNITURE_PX).max(1.0);
    let legend = LEGEND_FRAME_PX + LEGEND_ROW_PX * entries as f64;
    (legend / (plot - legend).max(plot / 3.0)).min(2.0)
}

/// Draws PSNR against training time (left panel) and, when any point has them, the chamfer
/// distance, the completeness on the hull-blind part and elsewhere, and the depth error
/// against training time on log axes (further panels; 1400 x 560 px up to three panels, wider
/// with four), one line per series with a legend, a series' final evaluation ([`FINAL_LABEL`]) as a cross
/// off its line, and writes the PNG to `path` atomically. Errors when no series has a point.
pub fn plot_png(path: &Path, series: &[(&str, &Timeline)]) -> Result<()> {
    let plot_err = |message: String| EvalError::Plot {
        path: path.to_path_buf(),
        message,
    };
    ensure_font().map_err(plot_err)?;
    let all = || series.iter().flat_map(|(_, t)| t.points.iter());
    if all().next().is_none() {
        return Err(plot_err("no timeline has any point".into()));
    }
    let (t0, t1) = range_of(all().map(|p| p.train_seconds))
        .ok_or_else(|| plot_err("no finite training time".into()))?;
    let t0 = t0.max(0.0).min(t1 - 1e-9);
    let psnr_range = range_of(all().map(|p| p.psnr)).unwrap_or((0.0, 1.0));
    let log_panels: Vec<LogPanel> = [
        LogPanel {
            caption: "Chamfer vs training time",
            y_desc: "chamfer distance (log scale)",
            curves: vec![
                LogCurve::new(|p| p.chamfer, "", Stroke::Solid),
                LogCurve::new(|p| p.depth_only_chamfer, ", depth alone", Stroke::Dashed),
                LogCurve::new(|p| p.masks_alone_chamfer, ", masks alone", Stroke::Dotted),
            ],
        },
        LogPanel {
            caption: "Completeness by the masks' blindness",
            y_desc: "ground truth to mesh, mean (log scale)",
            curves: vec![
                LogCurve::new(|p| p.blind_completeness, ", hull-blind", Stroke::Solid),
                LogCurve::new(|p| p.rest_completeness, ", elsewhere", Stroke::Dashed),
                LogCurve::new(
                    |p| p.masks_alone_blind_completeness,
                    ", masks alone (hull-blind)",
                    Stroke::Dotted,
                ),
                LogCurve::new(
                    |p| p.masks_alone_rest_completeness,
                    ", masks alone (elsewhere)",
                    Stroke::Dotted,
                ),
            ],
        },
        LogPanel {
            caption: "Depth error vs training time",
            y_desc: "median |depth error| (log scale)",
            curves: vec![LogCurve::new(|p| p.depth_error, "", Stroke::Solid)],
        },
    ]
    .into_iter()
    .filter(|panel| !panel.values(all()).is_empty())
    .collect();
    let (w, h) = PLOT_SIZE;
    let w = w.max(PANEL_MIN_WIDTH * (1 + log_panels.len() as u32));
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_err(e.to_string()))?;
        let panels = root.split_evenly((1, 1 + log_panels.len()));
        let colour = |k: usize| Palette99::pick(k).to_rgba();
        {
            let mut chart = panel_chart(
                &panels[0],
                "PSNR vs training time",
                64,
                (t0..t1, psnr_range.0..psnr_range.1),
                "PSNR (dB)",
                None,
            )
            .map_err(plot_err)?;
            for (k, (name, t)) in series.iter().enumerate() {
                let c = colour(k);
                let finite = |p: &&TimelinePoint| p.psnr.is_finite() && p.train_seconds.is_finite();
                chart
                    .draw_series(
                        (t.points.iter().filter(finite))
                            .filter(|p| p.label == FINAL_LABEL)
                            .map(|p| Cross::new((p.train_seconds, p.psnr), 7, c.stroke_width(2))),
                    )
                    .map_err(|e| plot_err(e.to_string()))?;
                chart
                    .draw_series(LineSeries::new(
                        (t.points.iter().filter(finite))
                            .filter(|p| p.label != FINAL_LABEL)
                            .map(|p| (p.train_seconds, p.psnr)),
                        c.stroke_width(2),
                    ))
                    .map_err(|e| plot_err(e.to_string()))?
                    .label(name.to_string())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2))
                    });
            }
            draw_legend(&mut chart, SeriesLabelPosition::LowerRight).map_err(plot_err)?;
        }
        for (panel, area) in log_panels.iter().zip(&panels[1..]) {
            let values = panel.values(all());
            let lo = values.iter().cloned().fold(f64::INFINITY, f64::min);
            let hi = values.iter().cloned().fold(0.0, f64::max);
            // log10 of the value on a linear axis, labelled with the value itself: plotters
            // labels a log axis only at powers of ten, so a range inside one decade (every
            // method at 1.8e-3 to 4.6e-3) had no label at all.
            let (lo, mut hi) = ((lo / 1.25).log10(), (hi * 1.25).log10());
            // Room above the data for the legend in the upper right, so that it covers no curve.
            let entries = (series.iter())
                .flat_map(|(_, t)| {
                    (panel.curves.iter()).filter(|c| t.points.iter().any(|p| (c.get)(p).is_some()))
                })
                .count();
            hi += (hi - lo) * legend_headroom(entries, area.dim_in_pixel().1);
            let mut chart = panel_chart(
                area,
                panel.caption,
                80,
                (t0..t1, lo..hi),
                panel.y_desc,
                Some(&|v| format!("{:.1e}", 10f64.powf(*v))),
            )
            .map_err(plot_err)?;
            for (k, (name, t)) in series.iter().enumerate() {
                let c = colour(k);
                for curve in &panel.curves {
                    let on_curve = |last: bool| -> Vec<(f64, f64)> {
                        (t.points.iter())
                            .filter(|p| (p.label == FINAL_LABEL) == last)
                            .filter_map(|p| Some((p.train_seconds, (curve.get)(p)?)))
                            .filter(|(s, c)| s.is_finite() && c.is_finite() && *c > 0.0)
                            .map(|(s, c)| (s, c.log10()))
                            .collect()
                    };
                    // A baseline (dotted) is one line through every point, final included,
                    // without markers.
                    let baseline = curve.stroke == Stroke::Dotted;
                    let (pts, last) = if baseline {
                        let mut all = on_curve(false);
                        all.extend(on_curve(true));
                        (all, Vec::new())
                    } else {
                        (on_curve(false), on_curve(true))
                    };
                    chart
                        .draw_series(last.iter().map(|&p| Cross::new(p, 7, c.stroke_width(2))))
                        .map_err(|e| plot_err(e.to_string()))?;
                    if pts.is_empty() {
                        continue;
                    }
                    let label = format!("{name}{}", curve.suffix);
                    let style = c.stroke_width(2);
                    let drawn = match curve.stroke.dashes() {
                        None => chart.draw_series(LineSeries::new(pts.iter().copied(), style)),
                        Some((dash, gap)) => chart.draw_series(DashedLineSeries::new(
                            pts.iter().copied(),
                            dash,
                            gap,
                            style,
                        )),
                    };
                    let sample = curve.stroke.sample();
                    drawn
                        .map_err(|e| plot_err(e.to_string()))?
                        .label(label)
                        .legend(move |(x, y)| {
                            PathElement::new(vec![(x, y), (x + sample, y)], style)
                        });
                    if !baseline {
                        chart
                            .draw_series(pts.iter().map(|&p| Circle::new(p, 3, c.filled())))
                            .map_err(|e| plot_err(e.to_string()))?;
                    }
                }
            }
            draw_legend(&mut chart, SeriesLabelPosition::UpperRight).map_err(plot_err)?;
        }
        root.present().map_err(|e| plot_err(e.to_string()))?;
    }
    let img = image::RgbImage::from_raw(w, h, buf)
        .ok_or_else(|| plot_err("plot buffer has the wrong size".into()))?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| plot_err(e.to_string()))?;
    write_atomic(path, &png)
}
