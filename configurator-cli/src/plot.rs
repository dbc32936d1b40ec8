//! `configurator-cli plot`: a recording (CSV) or a calibration ellipsoid rendered to PNG or SVG.
//!
//! Pictures are how a flight is checked at a glance: the IMU, the attitude, the motors and the
//! learner's G1 estimate stacked on one time axis, or the IMU-offset uncertainty as the three
//! 95 % ellipses it projects onto the body planes. Everything is pure Rust ([`plotters`]): text
//! is laid out and rasterised by `ab_glyph` with DejaVu Sans embedded in the binary
//! (`assets/DejaVuSans.ttf`, licence beside it), so no fontconfig or FreeType is needed.

use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::register_font;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// DejaVu Sans (Bitstream Vera licence, see `assets/DejaVuSans-LICENSE.txt`).
static FONT_TTF: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
/// The family every text in the pictures uses (plotters' default family too).
const FONT: &str = "sans-serif";
/// Image width of a recording plot, px.
pub const RECORDING_WIDTH_PX: u32 = 1400;
/// Height of one recording panel, px.
pub const PANEL_HEIGHT_PX: u32 = 300;
/// Height of the figure title strip, px.
pub const TITLE_HEIGHT_PX: u32 = 40;
/// Size (width, height) of an ellipsoid plot, px: three projections side by side.
pub const ELLIPSOID_SIZE_PX: (u32, u32) = (1500, 560);
/// χ² quantile for 95 % with 3 degrees of freedom (dimensionless).
pub const CHI2_95_3DOF: f64 = 7.815;
/// Points on a drawn ellipse (the first is repeated at the end to close it).
const ELLIPSE_POINTS: usize = 360;
/// Font sizes, px: figure title, panel caption, tick and legend labels.
const TITLE_FONT_PX: u32 = 24;
const CAPTION_FONT_PX: u32 = 18;
const LABEL_FONT_PX: u32 = 13;
/// Chart margin and label-area sizes, px.
const MARGIN_PX: u32 = 10;
const X_LABEL_AREA_PX: u32 = 40;
const Y_LABEL_AREA_PX: u32 = 80;
/// Metres to millimetres.
const MM_PER_M: f64 = 1000.0;

/// What can go wrong while reading an input or drawing a picture.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{}: output must end in .png or .svg", .0.display())]
    UnsupportedFormat(PathBuf),
    #[error("{file}: empty file (no header row)")]
    Empty { file: String },
    #[error("{file}: the header has no `t` column")]
    NoTimeColumn { file: String },
    #[error("{file}:{line}: {found} fields, the header has {expected}")]
    FieldCount { file: String, line: usize, found: usize, expected: usize },
    #[error("{file}:{line}: column {column} (`{name}`): `{text}` is not a number")]
    BadNumber { file: String, line: usize, column: usize, name: String, text: String },
    #[error("{file}:{line}: the time `t` is empty")]
    MissingTime { file: String, line: usize },
    #[error("{file}: no samples")]
    NoSamples { file: String },
    #[error(
        "{file}: no known columns to plot (gyro_*, acc_*, *_deg, rate_*, cmd_*, speed_*, g1_*)"
    )]
    NoPanels { file: String },
    #[error("{title}: the covariance is not symmetric positive-definite")]
    NotPositiveDefinite { title: String },
    #[error("the χ² scale must be finite and positive, not {0}")]
    BadChi2Scale(f64),
    #[error("{file}: not the JSON of `fit imu-offset --json` ({reason})")]
    NotAFit { file: String, reason: String },
    #[error("the embedded font could not be loaded")]
    Font,
    #[error("drawing failed: {0}")]
    Draw(String),
}

/// The legend of a panel, in its upper right corner.
fn draw_legend<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
) -> Result<(), PlotError> {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font((FONT, LABEL_FONT_PX))
        .draw()
        .map_err(draw_err)
}

fn draw_err(e: impl std::fmt::Display) -> PlotError {
    PlotError::Draw(e.to_string())
}

/// Image formats, chosen by the output's extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Png,
    Svg,
}

/// The format of `out` from its extension (`.png` or `.svg`, any case).
pub fn format_of(out: &Path) -> Result<Format, PlotError> {
    match out.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("png") => Ok(Format::Png),
        Some("svg") => Ok(Format::Svg),
        _ => Err(PlotError::UnsupportedFormat(out.to_path_buf())),
    }
}

/// Registers the embedded font once; every later call is free.
fn ensure_font() -> Result<(), PlotError> {
    static OK: OnceLock<bool> = OnceLock::new();
    let ok = *OK.get_or_init(|| register_font(FONT, FontStyle::Normal, FONT_TTF).is_ok());
    ok.then_some(()).ok_or(PlotError::Font)
}

/// Motors a recording can hold (the learner's limit); one colour each.
const MOTOR_COUNT_MAX: usize = flight::learner::MAX_MOTORS;

/// Line colours: motor i has colour i in every panel (command, speed, G1); other panels colour
/// their columns in order. The Okabe–Ito palette (told apart with the common colour-vision
/// deficiencies), its yellow darkened to olive to read on white, and a brown for an eighth;
/// black is left for the legend's line-style and marker entries.
const COLOURS: [RGBColor; MOTOR_COUNT_MAX] = [
    RGBColor(0, 114, 178),   // blue
    RGBColor(213, 94, 0),    // vermillion
    RGBColor(0, 158, 115),   // bluish green
    RGBColor(204, 121, 167), // reddish purple
    RGBColor(86, 180, 233),  // sky blue
    RGBColor(230, 159, 0),   // orange
    RGBColor(150, 140, 0),   // olive
    RGBColor(120, 70, 30),   // brown
];
/// Stroke width of a series, px: 1, since plotters' bitmap backend draws wider paths as polygons
/// whose mitred joins spike far out where a signal reverses within a pixel (a motor command).
const LINE_PX: u32 = 1;
/// Stroke width of a legend's line sample, px (a straight line, no joins).
const LEGEND_LINE_PX: u32 = 2;
/// Dash and gap lengths of a dashed line, px.
const DASH_PX: (u32, u32) = (9, 5);
/// Dot and gap lengths of a dotted line, px.
const DOT_PX: (u32, u32) = (2, 4);
/// Width of the legend column right of each panel, px.
pub const LEGEND_WIDTH_PX: u32 = 200;
/// Height of one legend row, px.
const LEGEND_ROW_PX: u32 = 19;
/// Space above the first legend row, px.
const LEGEND_PAD_PX: u32 = 6;
/// Length of the line sample in front of a legend label, px.
const LEGEND_SAMPLE_PX: i32 = 28;
/// Half-width and height of the triangle marking where a line leaves the axis, px.
const MARKER_PX: (i32, i32) = (5, 8);

/// Fraction of each column's samples, the latest, whose values [`converged_axis`] fits: the
/// learner's estimates settle within a fraction of a second of the excitation and the rest of a
/// recording holds what they converged to.
pub const CONVERGED_TAIL_FRACTION: f64 = 0.5;
/// Room above and below the converged values, as a fraction of their spread (dimensionless).
pub const CONVERGED_MARGIN: f64 = 0.25;
/// All samples spanning no more than this many times the converged axis are all shown: the
/// clipping would gain less than a factor 2 of resolution (dimensionless).
pub const CLIP_ONLY_BEYOND: f64 = 2.0;
/// Padding of an axis around every sample, as a fraction of their span (dimensionless).
const ALL_SAMPLES_PAD: f64 = 0.05;

/// How a panel's y-axis is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum YScale {
    /// Every sample, padded: the signal itself is the subject (IMU, attitude, motors).
    AllSamples,
    /// What the estimates converged to ([`converged_axis`]): their first samples are transients
    /// tens of times beyond the converged values, which would squash those into a line.
    Converged,
}

/// One panel of a recording plot: a caption, a y-axis label with unit, the columns drawn.
#[derive(Debug, Clone, PartialEq)]
pub struct Panel {
    pub title: &'static str,
    pub y_label: &'static str,
    pub columns: Vec<String>,
    pub y_scale: YScale,
    /// The columns are angles in degrees wrapped into ±180°, drawn unwrapped ([`unwrap_deg`]).
    pub unwrap_deg: bool,
}

/// One parsed column: `None` where the field was empty (or not finite).
#[derive(Debug, Clone, PartialEq)]
pub struct Column {
    pub name: String,
    pub values: Vec<Option<f64>>,
}

/// A parsed recording: the time, the columns of known panels (others are dropped), the panels.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    pub file_name: String,
    /// Sample times, s.
    pub t: Vec<f64>,
    pub columns: Vec<Column>,
    pub panels: Vec<Panel>,
}

/// What [`plot_recording`] drew.
#[derive(Debug, Clone, PartialEq)]
pub struct PlotSummary {
    /// Panel captions, top to bottom.
    pub panels: Vec<String>,
    /// Each panel's y-axis and legend, top to bottom.
    pub axes: Vec<PanelAxis>,
    /// Rows (samples) read.
    pub samples: usize,
    /// Image size (width, height), px.
    pub size_px: (u32, u32),
}

/// The y-axis and legend one panel got.
#[derive(Debug, Clone, PartialEq)]
pub struct PanelAxis {
    pub title: String,
    /// The y-axis, in the panel's unit.
    pub y_range: std::ops::Range<f64>,
    /// Samples beyond the y-axis, drawn on its edge and marked.
    pub clipped_samples: usize,
    /// Rows of the legend.
    pub legend_entries: usize,
}

/// The panels whose columns appear in `header`, in the fixed order, each with the present columns.
pub fn choose_panels(header: &[String]) -> Vec<Panel> {
    use YScale::{AllSamples, Converged};
    let has = |n: &str| header.iter().any(|h| h == n);
    let fixed = |names: &[&str]| names.iter().filter(|n| has(n)).map(|n| n.to_string()).collect();
    let numbered = |prefix: &str| {
        (0..MOTOR_COUNT_MAX).map(|i| format!("{prefix}{i}")).filter(|n| has(n)).collect()
    };
    let starting = |prefixes: &[&str]| {
        header.iter().filter(|h| prefixes.iter().any(|p| h.starts_with(p))).cloned().collect()
    };
    let groups: [(&'static str, &'static str, Vec<String>, YScale); 8] = [
        (
            "angular rate",
            "angular rate [rad/s]",
            fixed(&["gyro_x", "gyro_y", "gyro_z"]),
            AllSamples,
        ),
        (
            "specific force",
            "specific force [m/s²]",
            fixed(&["acc_x", "acc_y", "acc_z"]),
            AllSamples,
        ),
        (
            "attitude",
            "attitude, unwrapped [°]",
            fixed(&["roll_deg", "pitch_deg", "yaw_deg"]),
            AllSamples,
        ),
        ("body rates", "body rate [rad/s]", fixed(&["rate_p", "rate_q", "rate_r"]), AllSamples),
        ("motor command", "command [1 = full]", numbered("cmd_"), AllSamples),
        ("motor speed", "motor speed [rad/s]", numbered("speed_"), AllSamples),
        (
            "G1 convergence: specific force",
            "G1 [(m/s²) / unit thrust]",
            starting(&["g1_fx_", "g1_fy_", "g1_fz_"]),
            Converged,
        ),
        (
            "G1 convergence: angular acceleration",
            "G1 [(rad/s²) / unit thrust]",
            starting(&["g1_p_", "g1_q_", "g1_r_"]),
            Converged,
        ),
    ];
    groups
        .into_iter()
        .filter(|(_, _, columns, _)| !columns.is_empty())
        .map(|(title, y_label, columns, y_scale)| Panel {
            title,
            y_label,
            unwrap_deg: columns.iter().all(|c| c.ends_with("_deg")),
            columns,
            y_scale,
        })
        .collect()
}

/// An empty field is missing (`None`), as is a non-finite number; anything else must parse.
fn parse_field(text: &str) -> Result<Option<f64>, ()> {
    let text = text.trim();
    if text.is_empty() {
        return Ok(None);
    }
    text.parse::<f64>().map(|v| v.is_finite().then_some(v)).map_err(|_| ())
}

/// Parses a recording CSV (`file_name` is used in errors and as the title). Lines and columns
/// in errors are 1-based; the header is line 1. Blank lines are skipped.
pub fn parse_recording(text: &str, file_name: &str) -> Result<Recording, PlotError> {
    let file = || file_name.to_string();
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim_end_matches('\r')));
    let (_, header) = lines.next().ok_or_else(|| PlotError::Empty { file: file() })?;
    let header: Vec<String> = header.split(',').map(|s| s.trim().to_string()).collect();
    let t_index = header
        .iter()
        .position(|h| h == "t")
        .ok_or_else(|| PlotError::NoTimeColumn { file: file() })?;
    let panels = choose_panels(&header);
    let wanted: Vec<usize> = panels
        .iter()
        .flat_map(|p| &p.columns)
        .map(|name| header.iter().position(|h| h == name).expect("chosen from the header"))
        .collect();
    let mut columns: Vec<Column> =
        wanted.iter().map(|&i| Column { name: header[i].clone(), values: Vec::new() }).collect();
    let mut t = Vec::new();
    for (line, row) in lines.filter(|(_, l)| !l.trim().is_empty()) {
        let fields: Vec<&str> = row.split(',').collect();
        if fields.len() != header.len() {
            let (found, expected) = (fields.len(), header.len());
            return Err(PlotError::FieldCount { file: file(), line, found, expected });
        }
        let parse = |i: usize| {
            parse_field(fields[i]).map_err(|()| PlotError::BadNumber {
                file: file(),
                line,
                column: i + 1,
                name: header[i].clone(),
                text: fields[i].trim().to_string(),
            })
        };
        t.push(parse(t_index)?.ok_or_else(|| PlotError::MissingTime { file: file(), line })?);
        for (column, &i) in columns.iter_mut().zip(&wanted) {
            column.values.push(parse(i)?);
        }
    }
    Ok(Recording { file_name: file(), t, columns, panels })
}

/// `lo..hi` enclosing the values with 5 % padding; a degenerate or empty set gets a unit span.
fn padded_range(values: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    let (lo, hi) =
        values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if lo > hi {
        return -1.0..1.0;
    }
    let pad = if hi > lo { ALL_SAMPLES_PAD * (hi - lo) } else { 0.5f64.max(0.05 * lo.abs()) };
    lo - pad..hi + pad
}

/// A panel's y-axis: its range and how many present samples lie beyond it.
#[derive(Debug, Clone, PartialEq)]
pub struct YAxis {
    pub range: std::ops::Range<f64>,
    /// Present samples beyond `range` (drawn on its edge and marked).
    pub clipped_samples: usize,
}

/// The axis holding every present sample of `columns`, padded by 5 %.
pub fn all_samples_axis(columns: &[&[Option<f64>]]) -> YAxis {
    let range = padded_range(columns.iter().flat_map(|c| c.iter().flatten().copied()));
    YAxis { range, clipped_samples: 0 }
}

/// The axis of what the columns converged to: the spread of the latest
/// [`CONVERGED_TAIL_FRACTION`] of each column's present samples, widened by
/// [`CONVERGED_MARGIN`] of it above and below. Samples beyond it (the first transients of an
/// estimate) are counted in `clipped_samples`, to be drawn on the edge and marked, never dropped.
/// Where every sample spans at most [`CLIP_ONLY_BEYOND`] times that axis, or the columns hold no
/// sample, it is [`all_samples_axis`] (nothing clipped).
///
/// Assumes the estimates settle in the first half of their samples (a recording that starts
/// before the learner runs and lasts a second beyond it); if they do not, the axis spans the
/// wandering of the second half, which is then what there is to see.
pub fn converged_axis(columns: &[&[Option<f64>]]) -> YAxis {
    let all = all_samples_axis(columns);
    let tail = columns.iter().flat_map(|column| {
        let present: Vec<f64> = column.iter().flatten().copied().collect();
        let keep = (CONVERGED_TAIL_FRACTION * present.len() as f64).ceil() as usize;
        present.into_iter().rev().take(keep)
    });
    let (lo, hi) =
        tail.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if lo > hi {
        return all;
    }
    let margin = if hi > lo { CONVERGED_MARGIN * (hi - lo) } else { 0.5f64.max(0.05 * lo.abs()) };
    let range = lo - margin..hi + margin;
    let span = |r: &std::ops::Range<f64>| r.end - r.start;
    if span(&all.range) <= CLIP_ONLY_BEYOND * span(&range) {
        return all;
    }
    let clipped_samples = columns
        .iter()
        .flat_map(|c| c.iter().flatten())
        .filter(|&&v| v < range.start || v > range.end)
        .count();
    YAxis { range, clipped_samples }
}

/// The edge of the axis a clipped sample lies beyond.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Edge {
    Below,
    Above,
}

/// Where a line leaves the axis `range`: for each run of consecutive present samples beyond the
/// same edge, the time of its first sample, s, and the edge. A missing sample ends a run.
pub fn clipped_runs(
    t: &[f64],
    values: &[Option<f64>],
    range: &std::ops::Range<f64>,
) -> Vec<(f64, Edge)> {
    let mut runs = Vec::new();
    let mut current = None;
    for (&t, v) in t.iter().zip(values) {
        let edge = v.and_then(|v| {
            (v < range.start).then_some(Edge::Below).or((v > range.end).then_some(Edge::Above))
        });
        if let Some(e) = edge.filter(|_| edge != current) {
            runs.push((t, e));
        }
        current = edge;
    }
    runs
}

/// Continuous angles, degrees, from angles wrapped into ±180°: each step between consecutive
/// present samples is taken the shorter way round, so the curve runs on past ±180° instead of
/// jumping by 360°; a missing sample is skipped, not a restart. Assumes the angle turns by less
/// than 180° between two samples (at a recording's 2 kHz, 360,000 °/s; the IMU's gyro saturates
/// at 2,000 °/s). Euler angles also jump where the pitch passes ±90° (roll and yaw both by 180°):
/// that is the representation's, and stays.
pub fn unwrap_deg(values: &[Option<f64>]) -> Vec<Option<f64>> {
    const TURN_DEG: f64 = 360.0;
    let mut last: Option<(f64, f64)> = None; // (wrapped, unwrapped)
    values
        .iter()
        .map(|v| {
            let v = (*v)?;
            let unwrapped = match last {
                Some((wrapped, unwrapped)) => {
                    let step = v - wrapped;
                    unwrapped + step - TURN_DEG * (step / TURN_DEG).round()
                }
                None => v,
            };
            last = Some((v, unwrapped));
            Some(unwrapped)
        })
        .collect()
}

/// The line style of a series.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dash {
    Solid,
    Dashed,
    Dotted,
}

/// The dashes of a per-motor panel's rows, in the order the rows first appear.
const ROW_DASHES: [Dash; 3] = [Dash::Solid, Dash::Dashed, Dash::Dotted];

/// How one column is drawn: its colour (an index into the palette) and its line style.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SeriesStyle {
    pub colour: usize,
    pub dash: Dash,
}

/// The motor of a per-motor column, counted from 0 as the columns are (`cmd_2`, `speed_2`,
/// `g1_fx_2` → 2).
pub fn motor_of(column: &str) -> Option<usize> {
    let per_motor = ["cmd_", "speed_", "g1_"].iter().any(|p| column.starts_with(p));
    let (_, index) = column.rsplit_once('_')?;
    per_motor.then(|| index.parse().ok()).flatten()
}

/// The row of a G1 column (`g1_fx_2` → `fx`).
fn g1_row_of(column: &str) -> Option<&str> {
    column.strip_prefix("g1_")?.rsplit_once('_').map(|(row, _)| row)
}

/// The G1 rows of a panel, in the order they first appear.
fn rows_of(panel: &Panel) -> Vec<&str> {
    let mut rows: Vec<&str> = Vec::new();
    for row in panel.columns.iter().filter_map(|c| g1_row_of(c)) {
        if !rows.contains(&row) {
            rows.push(row);
        }
    }
    rows
}

/// Each column's style: a per-motor column takes its motor's colour and its G1 row's dash
/// (solid, dashed, dotted); any other its place in the panel's colour and a solid line.
pub fn series_styles(panel: &Panel) -> Vec<SeriesStyle> {
    let rows = rows_of(panel);
    let dash_of = |column: &str| {
        g1_row_of(column)
            .and_then(|row| rows.iter().position(|r| *r == row))
            .map_or(Dash::Solid, |k| ROW_DASHES[k % ROW_DASHES.len()])
    };
    panel
        .columns
        .iter()
        .enumerate()
        .map(|(i, column)| match motor_of(column) {
            Some(motor) => SeriesStyle { colour: motor % COLOURS.len(), dash: dash_of(column) },
            None => SeriesStyle { colour: i % COLOURS.len(), dash: Dash::Solid },
        })
        .collect()
}

/// One row of a legend.
#[derive(Debug, Clone, PartialEq)]
pub struct LegendEntry {
    pub label: String,
    /// Index into the palette; `None`: black (a line style or a marker explained).
    pub colour: Option<usize>,
    pub dash: Dash,
    /// The clipping marker rather than a line.
    pub marker: bool,
}

/// The legend of a panel. A per-motor panel gets one entry per motor (its colour, numbered from
/// 1 as the configurator's reports do, with the columns' 0-based suffix) and, where it has
/// several G1 rows, one per row (its line style, in black): 8 motors × 3 rows are 11 entries, not
/// 24. Any other panel gets one entry per column. `clipped` adds the marker's entry.
pub fn legend_entries(panel: &Panel, clipped: bool) -> Vec<LegendEntry> {
    let line = |label: String, colour: Option<usize>, dash: Dash| LegendEntry {
        label,
        colour,
        dash,
        marker: false,
    };
    let per_motor = panel.columns.iter().all(|c| motor_of(c).is_some());
    let mut entries: Vec<LegendEntry> = if per_motor {
        let mut motors: Vec<usize> = panel.columns.iter().filter_map(|c| motor_of(c)).collect();
        motors.sort_unstable();
        motors.dedup();
        let mut entries: Vec<LegendEntry> = motors
            .into_iter()
            .map(|m| line(format!("motor {} (…_{m})", m + 1), Some(m % COLOURS.len()), Dash::Solid))
            .collect();
        let rows = rows_of(panel);
        if rows.len() > 1 {
            entries.extend(rows.iter().enumerate().map(|(k, row)| {
                line(format!("g1_{row}_…"), None, ROW_DASHES[k % ROW_DASHES.len()])
            }));
        }
        entries
    } else {
        let styles = series_styles(panel);
        panel
            .columns
            .iter()
            .zip(styles)
            .map(|(c, s)| line(c.clone(), Some(s.colour), s.dash))
            .collect()
    };
    if clipped {
        entries.push(LegendEntry {
            label: "beyond the axis".into(),
            colour: None,
            dash: Dash::Solid,
            marker: true,
        });
    }
    entries
}

/// Legend rows that fit in a legend column `height_px` high.
pub fn legend_capacity(height_px: u32) -> usize {
    (height_px.saturating_sub(LEGEND_PAD_PX) / LEGEND_ROW_PX) as usize
}

/// Runs of consecutive present points: a missing value breaks the line.
fn segments(t: &[f64], values: &[Option<f64>]) -> Vec<Vec<(f64, f64)>> {
    let mut out = vec![Vec::new()];
    for (&t, v) in t.iter().zip(values) {
        match v {
            Some(v) => out.last_mut().expect("never empty").push((t, *v)),
            None if out.last().is_some_and(|s| !s.is_empty()) => out.push(Vec::new()),
            None => {}
        }
    }
    out.retain(|s| !s.is_empty());
    out
}

/// A panel's columns as drawn: unwrapped if the panel asks, in the panel's order.
fn panel_values(rec: &Recording, panel: &Panel) -> Vec<Vec<Option<f64>>> {
    panel
        .columns
        .iter()
        .filter_map(|n| rec.columns.iter().find(|c| &c.name == n))
        .map(|c| if panel.unwrap_deg { unwrap_deg(&c.values) } else { c.values.clone() })
        .collect()
}

/// A drawing area in pixels.
type Area<DB> = DrawingArea<DB, Shift>;

/// A panel's caption area split into the chart (left) and the legend column (right).
fn panel_areas<DB: DrawingBackend>(
    area: &Area<DB>,
    caption: &str,
) -> Result<(Area<DB>, Area<DB>), PlotError> {
    let area = area.titled(caption, (FONT, CAPTION_FONT_PX)).map_err(draw_err)?;
    let width = area.dim_in_pixel().0;
    Ok(area.split_horizontally(width.saturating_sub(LEGEND_WIDTH_PX)))
}

/// Draws `points` in `style` with the series' dash.
fn draw_line<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    points: Vec<(i32, i32)>,
    style: ShapeStyle,
    dash: Dash,
) -> Result<(), PlotError> {
    match dash {
        Dash::Solid => area.draw(&PathElement::new(points, style)),
        Dash::Dashed => area.draw(&DashedPathElement::new(points, DASH_PX.0, DASH_PX.1, style)),
        Dash::Dotted => area.draw(&DashedPathElement::new(points, DOT_PX.0, DOT_PX.1, style)),
    }
    .map_err(draw_err)
}

/// The triangle on the axis edge where a line leaves it (pointing out), relative to the point
/// on the edge, px.
fn marker_shape(edge: Edge) -> Vec<(i32, i32)> {
    let (w, h) = MARKER_PX;
    let inward = match edge {
        Edge::Above => h,
        Edge::Below => -h,
    };
    vec![(0, 0), (-w, inward), (w, inward)]
}

/// The legend rows in the legend column; rows beyond its height are counted on the last row.
fn draw_legend_column<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    entries: &[LegendEntry],
) -> Result<(), PlotError> {
    let capacity = legend_capacity(area.dim_in_pixel().1);
    let shown = if entries.len() > capacity { capacity.saturating_sub(1) } else { entries.len() };
    let text =
        TextStyle::from((FONT, LABEL_FONT_PX).into_font()).pos(Pos::new(HPos::Left, VPos::Center));
    let x0 = MARGIN_PX as i32;
    let y_of = |k: usize| (LEGEND_PAD_PX + LEGEND_ROW_PX * k as u32 + LEGEND_ROW_PX / 2) as i32;
    for (k, entry) in entries.iter().take(shown).enumerate() {
        let y = y_of(k);
        let colour = entry.colour.map_or(BLACK, |c| COLOURS[c]);
        if entry.marker {
            for (dx, edge) in [(8, Edge::Above), (20, Edge::Below)] {
                let dy = match edge {
                    Edge::Above => -MARKER_PX.1 / 2,
                    Edge::Below => MARKER_PX.1 / 2,
                };
                let tip = (x0 + dx, y + dy);
                let shape = marker_shape(edge).into_iter().map(|(x, y)| (tip.0 + x, tip.1 + y));
                area.draw(&Polygon::new(shape.collect::<Vec<_>>(), colour.filled()))
                    .map_err(draw_err)?;
            }
        } else {
            let line = vec![(x0, y), (x0 + LEGEND_SAMPLE_PX, y)];
            draw_line(area, line, colour.stroke_width(LEGEND_LINE_PX), entry.dash)?;
        }
        area.draw(&Text::new(entry.label.clone(), (x0 + LEGEND_SAMPLE_PX + 8, y), text.clone()))
            .map_err(draw_err)?;
    }
    if shown < entries.len() {
        let more = format!("… {} more", entries.len() - shown);
        area.draw(&Text::new(more, (x0, y_of(shown)), text)).map_err(draw_err)?;
    }
    Ok(())
}

fn draw_recording<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    rec: &Recording,
) -> Result<Vec<PanelAxis>, PlotError> {
    root.fill(&WHITE).map_err(draw_err)?;
    let body = root.titled(&rec.file_name, (FONT, TITLE_FONT_PX)).map_err(draw_err)?;
    let time = padded_range(rec.t.iter().copied());
    let mut axes = Vec::new();
    for (panel, area) in rec.panels.iter().zip(body.split_evenly((rec.panels.len(), 1))) {
        let values = panel_values(rec, panel);
        let columns: Vec<&[Option<f64>]> = values.iter().map(Vec::as_slice).collect();
        let axis = match panel.y_scale {
            YScale::AllSamples => all_samples_axis(&columns),
            YScale::Converged => converged_axis(&columns),
        };
        let clipped = axis.clipped_samples > 0;
        let legend = legend_entries(panel, clipped);
        let caption = if clipped {
            format!(
                "{} (y-axis: what the estimates converged to; {} earlier samples beyond it ▲▼)",
                panel.title, axis.clipped_samples
            )
        } else {
            panel.title.to_string()
        };
        let (chart_area, legend_area) = panel_areas(&area, &caption)?;
        let range = axis.range.clone();
        let mut chart = ChartBuilder::on(&chart_area)
            .margin(MARGIN_PX)
            .x_label_area_size(X_LABEL_AREA_PX)
            .y_label_area_size(Y_LABEL_AREA_PX)
            .build_cartesian_2d(time.clone(), range.clone())
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc("time [s]")
            .y_desc(panel.y_label)
            .label_style((FONT, LABEL_FONT_PX))
            .draw()
            .map_err(draw_err)?;
        let plotting = chart.plotting_area().strip_coord_spec();
        let (x_px, y_px) = chart.plotting_area().get_pixel_range();
        let to_px = |(t, v): (f64, f64)| {
            let p = chart.backend_coord(&(t, v.clamp(range.start, range.end)));
            (p.0 - x_px.start, p.1 - y_px.start)
        };
        for (column, style) in columns.iter().zip(series_styles(panel)) {
            let colour = COLOURS[style.colour];
            for segment in segments(&rec.t, column) {
                let points = segment.into_iter().map(to_px).collect();
                draw_line(&plotting, points, colour.stroke_width(LINE_PX), style.dash)?;
            }
            for (t, edge) in clipped_runs(&rec.t, column, &range) {
                let tip = to_px((t, if edge == Edge::Above { range.end } else { range.start }));
                let shape = marker_shape(edge).into_iter().map(|(x, y)| (tip.0 + x, tip.1 + y));
                plotting
                    .draw(&Polygon::new(shape.collect::<Vec<_>>(), colour.filled()))
                    .map_err(draw_err)?;
            }
        }
        draw_legend_column(&legend_area, &legend)?;
        axes.push(PanelAxis {
            title: panel.title.to_string(),
            y_range: axis.range,
            clipped_samples: axis.clipped_samples,
            legend_entries: legend.len(),
        });
    }
    root.present().map_err(draw_err)?;
    Ok(axes)
}

/// Reads the recording at `csv_path` and draws its panels to `out` (`.png` or `.svg`).
pub fn plot_recording(csv_path: &Path, out: &Path) -> Result<PlotSummary, PlotError> {
    let format = format_of(out)?;
    let text = std::fs::read_to_string(csv_path)
        .map_err(|source| PlotError::Io { path: csv_path.to_path_buf(), source })?;
    let name = csv_path
        .file_name()
        .map_or_else(|| csv_path.display().to_string(), |n| n.to_string_lossy().into());
    let rec = parse_recording(&text, &name)?;
    if rec.t.is_empty() {
        return Err(PlotError::NoSamples { file: name });
    }
    if rec.panels.is_empty() {
        return Err(PlotError::NoPanels { file: name });
    }
    ensure_font()?;
    let size = (RECORDING_WIDTH_PX, TITLE_HEIGHT_PX + PANEL_HEIGHT_PX * rec.panels.len() as u32);
    let axes = match format {
        Format::Png => draw_recording(&BitMapBackend::new(out, size).into_drawing_area(), &rec)?,
        Format::Svg => draw_recording(&SVGBackend::new(out, size).into_drawing_area(), &rec)?,
    };
    let panels = rec.panels.iter().map(|p| p.title.to_string()).collect();
    Ok(PlotSummary { panels, axes, samples: rec.t.len(), size_px: size })
}

/// The 95 % ellipsoid of an IMU-offset fit, from the JSON `fit imu-offset --json` prints
/// (`r_imu_m`, `covariance_m2`); `file_name` titles it.
pub fn ellipsoid_from_fit_json(text: &str, file_name: &str) -> Result<EllipsoidPlot, PlotError> {
    let not_a_fit =
        |reason: &str| PlotError::NotAFit { file: file_name.into(), reason: reason.into() };
    let value: serde_json::Value =
        serde_json::from_str(text).map_err(|e| not_a_fit(&e.to_string()))?;
    let numbers = |v: &serde_json::Value| -> Option<Vec<f64>> {
        v.as_array()?.iter().map(serde_json::Value::as_f64).collect()
    };
    let centre = numbers(&value["r_imu_m"])
        .filter(|c| c.len() == 3)
        .ok_or_else(|| not_a_fit("no `r_imu_m` of three numbers"))?;
    let rows: Vec<Vec<f64>> = value["covariance_m2"]
        .as_array()
        .and_then(|rows| rows.iter().map(numbers).collect())
        .filter(|rows: &Vec<Vec<f64>>| rows.len() == 3 && rows.iter().all(|r| r.len() == 3))
        .ok_or_else(|| not_a_fit("no 3 × 3 `covariance_m2`"))?;
    let mut covariance_m2 = [[0.0; 3]; 3];
    for (dst, src) in covariance_m2.iter_mut().zip(&rows) {
        dst.copy_from_slice(src);
    }
    Ok(EllipsoidPlot {
        title: format!("IMU offset, 95 % ellipsoid: {file_name}"),
        centre_m: [centre[0], centre[1], centre[2]],
        covariance_m2,
        chi2_scale: CHI2_95_3DOF,
    })
}

/// Reads a fit (`fit imu-offset --json` output) and draws its ellipsoid to `out`.
pub fn plot_fit(json_path: &Path, out: &Path) -> Result<(), PlotError> {
    format_of(out)?;
    let text = std::fs::read_to_string(json_path)
        .map_err(|source| PlotError::Io { path: json_path.to_path_buf(), source })?;
    let name = json_path
        .file_name()
        .map_or_else(|| json_path.display().to_string(), |n| n.to_string_lossy().into());
    plot_ellipsoid(&ellipsoid_from_fit_json(&text, &name)?, out)
}

/// A calibration ellipsoid {x : (x − c)ᵀ Σ⁻¹ (x − c) ≤ k} to draw.
#[derive(Debug, Clone, PartialEq)]
pub struct EllipsoidPlot {
    pub title: String,
    /// Centre c, m.
    pub centre_m: [f64; 3],
    /// Covariance Σ, m² (symmetric positive-definite).
    pub covariance_m2: [[f64; 3]; 3],
    /// k, e.g. [`CHI2_95_3DOF`] for the 95 % region.
    pub chi2_scale: f64,
}

/// `n` points (then the first again) on the ellipse {p : (p − c)ᵀ S⁻¹ (p − c) = k}: p = c + L u
/// with S = L Lᵀ (Cholesky) and |u|² = k. `None` if S is not symmetric positive-definite, k is
/// not positive or `n` is 0.
pub fn ellipse_points(
    centre: [f64; 2],
    s: [[f64; 2]; 2],
    k: f64,
    n: usize,
) -> Option<Vec<(f64, f64)>> {
    let symmetric = (s[0][1] - s[1][0]).abs() <= 1e-12 * (s[0][0].abs() + s[1][1].abs());
    let l00 = s[0][0].sqrt();
    let l10 = s[1][0] / l00;
    let l11 = (s[1][1] - l10 * l10).sqrt();
    if !(symmetric && l00 > 0.0 && l11 > 0.0 && l10.is_finite() && k > 0.0 && n > 0) {
        return None;
    }
    let r = k.sqrt();
    let point = |i: usize| {
        let a = std::f64::consts::TAU * (i % n) as f64 / n as f64;
        let (u0, u1) = (r * a.cos(), r * a.sin());
        (centre[0] + l00 * u0, centre[1] + l10 * u0 + l11 * u1)
    };
    Some((0..=n).map(point).collect())
}

/// True if the 3 × 3 matrix is symmetric and its leading minors are all positive.
fn is_spd3(m: &[[f64; 3]; 3]) -> bool {
    let scale = (0..3).map(|i| m[i][i].abs()).sum::<f64>();
    let symmetric = (0..3).all(|i| (0..3).all(|j| (m[i][j] - m[j][i]).abs() <= 1e-12 * scale));
    let d2 = m[0][0] * m[1][1] - m[0][1] * m[1][0];
    let d3 = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    symmetric && m[0][0] > 0.0 && d2 > 0.0 && d3 > 0.0
}

/// The (horizontal, vertical) axis indices and names of the three projections.
const PLANES: [(usize, usize, &str, &str); 3] =
    [(0, 1, "x", "y"), (0, 2, "x", "z"), (1, 2, "y", "z")];

/// One projection: the closed ellipse and its centre, mm.
type Projection = (Vec<(f64, f64)>, (f64, f64));

/// The three projected ellipses (in [`PLANES`] order), after checking Σ and k.
fn projections(e: &EllipsoidPlot) -> Result<Vec<Projection>, PlotError> {
    if !(e.chi2_scale.is_finite() && e.chi2_scale > 0.0) {
        return Err(PlotError::BadChi2Scale(e.chi2_scale));
    }
    let not_spd = || PlotError::NotPositiveDefinite { title: e.title.clone() };
    if !is_spd3(&e.covariance_m2) {
        return Err(not_spd());
    }
    let (c, s) = (e.centre_m, e.covariance_m2);
    PLANES
        .iter()
        .map(|&(i, j, _, _)| {
            let sub = [[s[i][i], s[i][j]], [s[j][i], s[j][j]]];
            let points = ellipse_points([c[i], c[j]], sub, e.chi2_scale, ELLIPSE_POINTS)
                .ok_or_else(not_spd)?;
            let mm = points.into_iter().map(|(x, y)| (x * MM_PER_M, y * MM_PER_M)).collect();
            Ok((mm, (c[i] * MM_PER_M, c[j] * MM_PER_M)))
        })
        .collect()
}

/// Axis ranges centred on `centre` enclosing `points` with 10 % room, in the plotting area's
/// aspect ratio (`w_px` × `h_px`) so that one mm is as long on both axes.
fn equal_scale_ranges(
    points: &[(f64, f64)],
    centre: (f64, f64),
    w_px: u32,
    h_px: u32,
) -> [std::ops::Range<f64>; 2] {
    let (dx, dy) = points.iter().fold((0.0f64, 0.0f64), |(dx, dy), p| {
        (dx.max((p.0 - centre.0).abs()), dy.max((p.1 - centre.1).abs()))
    });
    let mm_per_px = 1.1 * (2.0 * dx / f64::from(w_px)).max(2.0 * dy / f64::from(h_px));
    let (hx, hy) = (0.5 * mm_per_px * f64::from(w_px), 0.5 * mm_per_px * f64::from(h_px));
    [centre.0 - hx..centre.0 + hx, centre.1 - hy..centre.1 + hy]
}

fn draw_ellipsoid<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    e: &EllipsoidPlot,
) -> Result<(), PlotError> {
    let projections = projections(e)?;
    root.fill(&WHITE).map_err(draw_err)?;
    let body = root.titled(&e.title, (FONT, TITLE_FONT_PX)).map_err(draw_err)?;
    for ((points, centre), (area, &(_, _, h, v))) in
        projections.iter().zip(body.split_evenly((1, 3)).iter().zip(&PLANES))
    {
        let area = area
            .titled(&format!("{h}–{v} projection (95 %)"), (FONT, CAPTION_FONT_PX))
            .map_err(draw_err)?;
        let (w, hh) = area.dim_in_pixel();
        let plot_w = w.saturating_sub(2 * MARGIN_PX + Y_LABEL_AREA_PX).max(1);
        let plot_h = hh.saturating_sub(2 * MARGIN_PX + X_LABEL_AREA_PX).max(1);
        let [xr, yr] = equal_scale_ranges(points, *centre, plot_w, plot_h);
        let mut chart = ChartBuilder::on(&area)
            .margin(MARGIN_PX)
            .x_label_area_size(X_LABEL_AREA_PX)
            .y_label_area_size(Y_LABEL_AREA_PX)
            .build_cartesian_2d(xr, yr)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc(format!("{h} [mm]"))
            .y_desc(format!("{v} [mm]"))
            .label_style((FONT, LABEL_FONT_PX))
            .draw()
            .map_err(draw_err)?;
        let blue = BLUE.stroke_width(2);
        chart
            .draw_series(LineSeries::new(points.iter().copied(), blue))
            .map_err(draw_err)?
            .label("95 % region")
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], blue));
        chart
            .draw_series(std::iter::once(Cross::new(*centre, 6, RED.stroke_width(2))))
            .map_err(draw_err)?
            .label(format!("centre ({:.1}, {:.1}) mm", centre.0, centre.1))
            .legend(|(x, y)| Cross::new((x + 9, y), 5, RED.stroke_width(2)));
        draw_legend(&mut chart)?;
    }
    root.present().map_err(draw_err)
}

/// Draws the x–y, x–z and y–z projections of the ellipsoid, in mm, to `out` (`.png` or `.svg`).
pub fn plot_ellipsoid(e: &EllipsoidPlot, out: &Path) -> Result<(), PlotError> {
    let format = format_of(out)?;
    projections(e)?; // check before creating the file
    ensure_font()?;
    match format {
        Format::Png => {
            draw_ellipsoid(&BitMapBackend::new(out, ELLIPSOID_SIZE_PX).into_drawing_area(), e)
        }
        Format::Svg => {
            draw_ellipsoid(&SVGBackend::new(out, ELLIPSOID_SIZE_PX).into_drawing_area(), e)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fresh directory under the system temp dir, unique to this process and test.
    fn temp_dir(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("configurator-plot-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    const CSV: &str = "t,gyro_x,gyro_y,gyro_z,cmd_0,cmd_2,speed_0,g1_fz_0,note\n\
                       0.0,0.1,0.2,0.3,0.5,0.5,,1.0,a\n\
                       0.1,0.2,0.1,0.0,0.6,0.4,100,1.1,b\n\
                       0.2,0.3,0.0,-0.1,0.7,0.3,110,1.2,c\n";

    #[test]
    fn panels_are_chosen_from_the_columns_in_order() {
        let rec = parse_recording(CSV, "r.csv").unwrap();
        let titles: Vec<_> = rec.panels.iter().map(|p| p.title).collect();
        assert_eq!(
            titles,
            ["angular rate", "motor command", "motor speed", "G1 convergence: specific force"]
        );
        assert_eq!(rec.panels[1].columns, ["cmd_0", "cmd_2"]);
        assert_eq!(rec.t, [0.0, 0.1, 0.2]);
        let speed = rec.columns.iter().find(|c| c.name == "speed_0").unwrap();
        assert_eq!(speed.values, [None, Some(100.0), Some(110.0)]);
        assert!(rec.columns.iter().all(|c| c.name != "note"), "unknown columns are dropped");
    }

    /// An estimate that starts with transients of −200 and +2,500 and settles within ±50: the
    /// axis is what it settled to (with its margin), the transients are counted and marked.
    #[test]
    fn a_convergence_axis_fits_what_converged_and_marks_the_transients() {
        let n = 1000;
        let t: Vec<f64> = (0..n).map(|i| i as f64 * 0.01).collect();
        // Two estimates: a transient in the first 5 % of the samples, then steady values with a
        // small wobble (±1) at −50 and +48.
        let settle = |start: f64, end: f64| -> Vec<Option<f64>> {
            (0..n)
                .map(|i| {
                    let wobble = (i as f64 * 0.7).sin();
                    Some(match i {
                        0..=19 => start,
                        20..=49 => start * 0.2 + end * 0.8,
                        _ => end + wobble,
                    })
                })
                .collect()
        };
        let a = settle(-200.0, -50.0);
        let b = settle(2500.0, 48.0);
        let axis = converged_axis(&[&a, &b]);
        let (lo, hi) = (axis.range.start, axis.range.end);
        assert!(lo <= -51.0 && hi >= 49.0, "every converged value is on the axis: {lo}..{hi}");
        assert!(lo > -80.0 && hi < 80.0, "the transients do not widen the axis: {lo}..{hi}");
        let beyond =
            [&a, &b].iter().flat_map(|c| c.iter().flatten()).filter(|&&v| v < lo || v > hi).count();
        assert_eq!(axis.clipped_samples, beyond);
        assert_eq!(axis.clipped_samples, 20 + 30 + 20 + 30, "the transients, none of the rest");
        // Each excursion is marked once, on its own edge, where it starts.
        assert_eq!(clipped_runs(&t, &a, &axis.range), [(0.0, Edge::Below)]);
        assert_eq!(clipped_runs(&t, &b, &axis.range), [(0.0, Edge::Above)]);
        // The whole range would have spent 98 % of the height on the transients.
        let all = all_samples_axis(&[&a, &b]);
        assert!((hi - lo) / (all.range.end - all.range.start) < 0.06);
    }

    #[test]
    fn without_a_transient_a_convergence_axis_shows_every_sample() {
        // A gentle settling (overshoot within twice the converged spread) is not worth clipping.
        let a: Vec<Option<f64>> = (0..100).map(|i| Some(10.0 + 10.0 / (1.0 + i as f64))).collect();
        let b: Vec<Option<f64>> = (0..100).map(|_| Some(-10.0)).collect();
        let axis = converged_axis(&[&a, &b]);
        assert_eq!(axis, all_samples_axis(&[&a, &b]));
        assert_eq!(axis.clipped_samples, 0);
        // Columns with no samples at all get the default axis, not a panic.
        let empty: Vec<Option<f64>> = vec![None; 10];
        assert_eq!(converged_axis(&[&empty]).range, -1.0..1.0);
        // A missing sample ends a run of clipped samples: two runs, two markers.
        let t = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0];
        let v = [Some(9.0), None, Some(9.0), Some(0.0), Some(-9.0), Some(-9.0)];
        assert_eq!(
            clipped_runs(&t, &v, &(-1.0..1.0)),
            [(0.0, Edge::Above), (2.0, Edge::Above), (4.0, Edge::Below)]
        );
    }

    #[test]
    fn angles_are_unwrapped_across_plus_minus_180_degrees() {
        let deg = |v: &[f64]| v.iter().map(|&x| Some(x)).collect::<Vec<_>>();
        // Through +180° and on, back through it, and through −180° the other way.
        let up = unwrap_deg(&deg(&[170.0, 179.0, -179.0, -170.0, 179.5]));
        assert_eq!(up, deg(&[170.0, 179.0, 181.0, 190.0, 179.5]));
        let down = unwrap_deg(&deg(&[-175.0, 178.0, 100.0]));
        assert_eq!(down, deg(&[-175.0, -182.0, -260.0]));
        // A gap does not restart the unwrap; the first sample is kept as it is.
        let gap = unwrap_deg(&[None, Some(-170.0), None, Some(175.0)]);
        assert_eq!(gap, [None, Some(-170.0), None, Some(-185.0)]);
        // Three turns of yaw at 10° per sample, wrapped into ±180°: a straight line to 1,080°.
        let wrapped: Vec<Option<f64>> = (0..=108)
            .map(|i| {
                let a = (10.0 * i as f64 + 180.0).rem_euclid(360.0) - 180.0;
                Some(a)
            })
            .collect();
        let unwrapped = unwrap_deg(&wrapped);
        for (i, v) in unwrapped.iter().enumerate() {
            let v = v.unwrap();
            assert!((v - 10.0 * i as f64).abs() < 1e-9, "sample {i}: {v}°");
            // The same angle as the one recorded, a whole number of turns away.
            let turns = (v - wrapped[i].unwrap()) / 360.0;
            assert!((turns - turns.round()).abs() < 1e-12);
        }
    }

    /// An octorotor's G1 columns (8 motors × 3 rows) colour by motor and dash by row, and the
    /// legend has a row per motor and per G1 row, which fits beside the panel at the default size.
    #[test]
    fn an_octorotor_legend_is_grouped_by_motor_and_row_and_fits() {
        let mut header = vec!["t".to_string()];
        for row in ["fx", "fy", "fz", "p", "q", "r"] {
            header.extend((0..8).map(|m| format!("g1_{row}_{m}")));
        }
        header.extend((0..8).map(|m| format!("cmd_{m}")));
        header.extend(["gyro_x", "gyro_y", "gyro_z"].map(String::from));
        let panels = choose_panels(&header);
        let force = panels.iter().find(|p| p.title == "G1 convergence: specific force").unwrap();
        assert_eq!(force.columns.len(), 24);
        let styles = series_styles(force);
        let of = |name: &str| styles[force.columns.iter().position(|c| c == name).unwrap()];
        assert_eq!(of("g1_fx_3"), SeriesStyle { colour: 3, dash: Dash::Solid });
        assert_eq!(of("g1_fy_3"), SeriesStyle { colour: 3, dash: Dash::Dashed });
        assert_eq!(of("g1_fz_7"), SeriesStyle { colour: 7, dash: Dash::Dotted });
        // A motor has the same colour in every panel.
        let command = panels.iter().find(|p| p.title == "motor command").unwrap();
        assert_eq!(series_styles(command)[3], SeriesStyle { colour: 3, dash: Dash::Solid });

        let legend = legend_entries(force, true);
        assert_eq!(legend.len(), 8 + 3 + 1, "{legend:?}");
        assert_eq!(legend[0].label, "motor 1 (…_0)");
        assert_eq!(legend[7].colour, Some(7));
        assert_eq!((legend[9].label.as_str(), legend[9].dash), ("g1_fy_…", Dash::Dashed));
        assert!(legend[11].marker);
        assert_eq!(legend_entries(command, false).len(), 8, "no row entries with one row");
        let gyro = panels.iter().find(|p| p.title == "angular rate").unwrap();
        let labels: Vec<_> = legend_entries(gyro, false).into_iter().map(|e| e.label).collect();
        assert_eq!(labels, ["gyro_x", "gyro_y", "gyro_z"]);

        // The legend column of a default-size panel, laid out as drawn, holds all 12 rows.
        let mut sink = String::new();
        let area = SVGBackend::with_string(&mut sink, (RECORDING_WIDTH_PX, PANEL_HEIGHT_PX))
            .into_drawing_area();
        ensure_font().unwrap();
        let caption =
            "G1 convergence: specific force (y-axis: … 5600 earlier samples beyond it ▲▼)";
        let (chart, legend_area) = panel_areas(&area, caption).unwrap();
        assert_eq!(legend_area.dim_in_pixel().0, LEGEND_WIDTH_PX);
        assert!(chart.dim_in_pixel().0 >= RECORDING_WIDTH_PX - LEGEND_WIDTH_PX);
        let capacity = legend_capacity(legend_area.dim_in_pixel().1);
        assert!(capacity >= legend.len(), "{capacity} rows fit, {} needed", legend.len());
    }

    #[test]
    fn the_attitude_panel_unwraps_and_the_g1_panels_scale_to_convergence() {
        let header: Vec<String> =
            ["t", "roll_deg", "gyro_x", "g1_p_0"].iter().map(|s| s.to_string()).collect();
        let panels = choose_panels(&header);
        let scales: Vec<_> = panels.iter().map(|p| (p.title, p.y_scale, p.unwrap_deg)).collect();
        assert_eq!(
            scales,
            [
                ("angular rate", YScale::AllSamples, false),
                ("attitude", YScale::AllSamples, true),
                ("G1 convergence: angular acceleration", YScale::Converged, false),
            ]
        );
        for panel in &panels {
            let unit = panel.y_label.split_once('[').map(|(_, u)| u.trim_end_matches(']'));
            assert!(unit.is_some_and(|u| !u.is_empty()), "no unit in `{}`", panel.y_label);
        }
    }

    #[test]
    fn a_gap_splits_the_line() {
        let t = [0.0, 1.0, 2.0, 3.0];
        let segs = segments(&t, &[Some(1.0), None, Some(2.0), Some(3.0)]);
        assert_eq!(segs, vec![vec![(0.0, 1.0)], vec![(2.0, 2.0), (3.0, 3.0)]]);
    }

    #[test]
    fn parse_errors_name_file_line_and_column() {
        let err = parse_recording("t,acc_x,acc_y\n0,1,2\n0.1,1,x2\n", "f.csv").unwrap_err();
        assert!(
            matches!(&err, PlotError::BadNumber { line: 3, column: 3, name, .. } if name == "acc_y")
        );
        assert_eq!(err.to_string(), "f.csv:3: column 3 (`acc_y`): `x2` is not a number");
        let err = parse_recording("t,acc_x\n0,1\n0.1\n", "f.csv").unwrap_err();
        assert!(matches!(err, PlotError::FieldCount { line: 3, found: 1, expected: 2, .. }));
        let err = parse_recording("acc_x\n1\n", "f.csv").unwrap_err();
        assert!(matches!(err, PlotError::NoTimeColumn { .. }));
        let err = parse_recording("t,acc_x\n,1\n", "f.csv").unwrap_err();
        assert!(matches!(err, PlotError::MissingTime { line: 2, .. }));
        // A bad field in an ignored column is not an error.
        assert!(parse_recording("t,acc_x,junk\n0,1,??\n", "f.csv").is_ok());
    }

    #[test]
    fn the_output_format_comes_from_the_extension() {
        assert_eq!(format_of(Path::new("a.PNG")).unwrap(), Format::Png);
        assert_eq!(format_of(Path::new("a.svg")).unwrap(), Format::Svg);
        assert!(matches!(format_of(Path::new("a.jpg")), Err(PlotError::UnsupportedFormat(_))));
        assert!(matches!(format_of(Path::new("a")), Err(PlotError::UnsupportedFormat(_))));
    }

    #[test]
    fn an_svg_recording_holds_the_panel_titles() {
        let dir = temp_dir("svg");
        let (csv, out) = (dir.join("flight.csv"), dir.join("flight.svg"));
        std::fs::write(&csv, CSV).unwrap();
        let summary = plot_recording(&csv, &out).unwrap();
        assert_eq!(summary.samples, 3);
        assert_eq!(summary.size_px, (RECORDING_WIDTH_PX, TITLE_HEIGHT_PX + 4 * PANEL_HEIGHT_PX));
        let svg = std::fs::read_to_string(&out).unwrap();
        for title in [
            "flight.csv",
            "angular rate",
            "motor command",
            "motor speed",
            "G1 convergence",
            "gyro_z",
            "motor 1 (…_0)",
        ] {
            assert!(svg.contains(title), "missing {title}");
        }
        assert!(svg.contains("angular rate [rad/s]") && svg.contains("time [s]"));
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn a_png_recording_has_the_signature_and_the_size() {
        let dir = temp_dir("png");
        let (csv, out) = (dir.join("flight.csv"), dir.join("flight.png"));
        std::fs::write(&csv, CSV).unwrap();
        let summary = plot_recording(&csv, &out).unwrap();
        let png = std::fs::read(&out).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
        assert_eq!(&png[12..16], b"IHDR");
        let width = u32::from_be_bytes(png[16..20].try_into().unwrap());
        let height = u32::from_be_bytes(png[20..24].try_into().unwrap());
        assert_eq!((width, height), summary.size_px);
        assert!(matches!(
            plot_recording(&csv, &dir.join("x.gif")),
            Err(PlotError::UnsupportedFormat(_))
        ));
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn a_fit_json_gives_its_centre_and_covariance_and_anything_else_is_refused() {
        let fit = r#"{"r_imu_m": [0.01, -0.013, 0.008],
            "covariance_m2": [[4e-6, 1e-7, 0], [1e-7, 1e-6, 0], [0, 0, 2.5e-7]]}"#;
        let e = ellipsoid_from_fit_json(fit, "fit.json").unwrap();
        assert_eq!(e.centre_m, [0.01, -0.013, 0.008]);
        assert_eq!(e.covariance_m2[0], [4e-6, 1e-7, 0.0]);
        assert_eq!(e.chi2_scale, CHI2_95_3DOF);
        for bad in ["{}", "[1, 2]", r#"{"r_imu_m": [1, 2, 3], "covariance_m2": [[1, 0], [0, 1]]}"#]
        {
            assert!(matches!(
                ellipsoid_from_fit_json(bad, "x.json"),
                Err(PlotError::NotAFit { .. })
            ));
        }
    }

    fn ellipsoid() -> EllipsoidPlot {
        EllipsoidPlot {
            title: "IMU offset".into(),
            centre_m: [0.01, -0.02, 0.005],
            covariance_m2: [
                [4e-6, 1.5e-6, -0.5e-6],
                [1.5e-6, 2e-6, 0.3e-6],
                [-0.5e-6, 0.3e-6, 1e-6],
            ],
            chi2_scale: CHI2_95_3DOF,
        }
    }

    #[test]
    fn projected_ellipse_points_lie_on_the_quadratic_form() {
        let s = [[4e-6, 1.5e-6], [1.5e-6, 2e-6]];
        let det = s[0][0] * s[1][1] - s[0][1] * s[1][0];
        let inv = [[s[1][1] / det, -s[0][1] / det], [-s[1][0] / det, s[0][0] / det]];
        let c = [0.01, -0.02];
        let points = ellipse_points(c, s, CHI2_95_3DOF, 100).unwrap();
        assert_eq!(points.len(), 101);
        assert_eq!(points[0], points[100]);
        for (x, y) in points {
            let (dx, dy) = (x - c[0], y - c[1]);
            let q = dx * (inv[0][0] * dx + inv[0][1] * dy) + dy * (inv[1][0] * dx + inv[1][1] * dy);
            assert!((q - CHI2_95_3DOF).abs() < 1e-9, "q = {q}");
        }
    }

    #[test]
    fn a_covariance_that_is_not_positive_definite_is_refused() {
        let dir = temp_dir("npd");
        let mut e = ellipsoid();
        e.covariance_m2 = [[1e-6, 2e-6, 0.0], [2e-6, 1e-6, 0.0], [0.0, 0.0, 1e-6]]; // eigenvalue −1e-6
        let out = dir.join("e.svg");
        assert!(matches!(plot_ellipsoid(&e, &out), Err(PlotError::NotPositiveDefinite { .. })));
        assert!(!out.exists());
        e.covariance_m2 = ellipsoid().covariance_m2;
        e.chi2_scale = 0.0;
        assert!(matches!(plot_ellipsoid(&e, &out), Err(PlotError::BadChi2Scale(_))));
        assert!(ellipse_points([0.0; 2], [[1.0, 0.0], [0.0, 0.0]], 1.0, 8).is_none());
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn ellipsoid_plots_render_with_equal_axis_scales() {
        let dir = temp_dir("ellipsoid");
        plot_ellipsoid(&ellipsoid(), &dir.join("e.svg")).unwrap();
        let svg = std::fs::read_to_string(dir.join("e.svg")).unwrap();
        for text in ["IMU offset", "x–y projection", "x–z projection", "y–z projection", "z [mm]"]
        {
            assert!(svg.contains(text), "missing {text}");
        }
        let out = dir.join("e.png");
        plot_ellipsoid(&ellipsoid(), &out).unwrap();
        assert_eq!(&std::fs::read(&out).unwrap()[..8], b"\x89PNG\r\n\x1a\n");
        // The computed plotting area is the one plotters makes, so a mm is as long on x as on y.
        let mut sink = String::new();
        let area = SVGBackend::with_string(&mut sink, (500, 480)).into_drawing_area();
        let (w, h) = area.dim_in_pixel();
        let (pw, ph) = (w - 2 * MARGIN_PX - Y_LABEL_AREA_PX, h - 2 * MARGIN_PX - X_LABEL_AREA_PX);
        let [xr, yr] = equal_scale_ranges(&[(3.0, 1.0), (-1.0, 0.0)], (0.0, 0.0), pw, ph);
        let chart = ChartBuilder::on(&area)
            .margin(MARGIN_PX)
            .x_label_area_size(X_LABEL_AREA_PX)
            .y_label_area_size(Y_LABEL_AREA_PX)
            .build_cartesian_2d(xr.clone(), yr.clone())
            .unwrap();
        let (px, py) = chart.plotting_area().get_pixel_range();
        let x_scale = f64::from(px.end - px.start) / (xr.end - xr.start);
        let y_scale = f64::from(py.end - py.start) / (yr.end - yr.start);
        assert!((x_scale / y_scale - 1.0).abs() < 1e-9, "{x_scale} vs {y_scale} px/mm");
        assert!(xr.end >= 3.0 && xr.start <= -3.0, "the centred range holds every point");
        std::fs::remove_dir_all(dir).unwrap();
    }
}
