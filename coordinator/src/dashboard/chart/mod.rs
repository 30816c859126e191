//! The dashboard's charts, drawn from a result document (the paper's
//! Figs. 2-7) and from heartbeat learning curves. Each returns a complete
//! SVG document; an empty input gives a small chart that says so, never an
//! error and never a non-finite coordinate.
//!
//! The pages talk to this module only: the low-level SVG writer (escaping,
//! scales, panels, colours) is the private `svg` submodule; [`short`], its number
//! format, is re-exported for the tables beside the charts.

mod svg;

use std::collections::BTreeMap;

use shared::analysis::{
    prior_weights, Method, Prior, ResultDocument, SubjectSummary, WeightSummary,
};
use shared::api::{point_label_with, ProgressPoint};

pub use svg::short;
use svg::{
    category, legend, ordered, ramp, ramp_is_light, Extent, Labels, LegendItem, Panel, Svg, Swatch,
};

/// Most subjects drawn in a heat map (the table lists all).
pub const MAX_HEATMAP_ROWS: usize = 200;

/// A chart of a search, as named in its download URL
/// (`/searches/{id}/charts/{name}.svg`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChartId {
    /// Learning curves of running (or recently finished) jobs.
    LearningCurves,
    /// Fig. 2: area and torque usage per w1 with SEM error bars.
    Fig2,
    /// Fig. 3: top trajectory and mean-of-means trajectory per w1.
    Fig3,
    /// Fig. 4: heat map of the softmax-ranked area difference.
    Fig4,
    /// Fig. 6: heat map of the softmax-ranked correlation.
    Fig6,
    /// Heat map of the posterior over the grid.
    Posterior,
    /// Identifiability: confusion matrices of held-out trials per method.
    Confusion,
    /// Identifiability: nominal vs observed coverage per method.
    Coverage,
    /// Figs. 5 and 7 for subject `i`: its path against the best-fitting
    /// mean path by each metric, with the +-1 SD band.
    Subject(usize),
}

impl ChartId {
    /// Parses a chart's file name (with or without `.svg`).
    pub fn parse(name: &str) -> Option<Self> {
        let name = name.strip_suffix(".svg").unwrap_or(name);
        Some(match name {
            "learning-curves" => Self::LearningCurves,
            "fig2-area-torque" => Self::Fig2,
            "fig3-trajectories" => Self::Fig3,
            "fig4-area-ranking" => Self::Fig4,
            "fig6-correlation-ranking" => Self::Fig6,
            "posterior" => Self::Posterior,
            "identifiability-confusion" => Self::Confusion,
            "identifiability-coverage" => Self::Coverage,
            other => {
                let i = other.strip_prefix("subject-")?;
                // Only canonical decimal numbers, so every chart has one URL.
                if i.is_empty() || (i.len() > 1 && i.starts_with('0')) {
                    return None;
                }
                Self::Subject(i.parse().ok()?)
            }
        })
    }

    /// The file name, e.g. `fig2-area-torque.svg`.
    pub fn file_name(&self) -> String {
        match self {
            Self::LearningCurves => "learning-curves.svg".into(),
            Self::Fig2 => "fig2-area-torque.svg".into(),
            Self::Fig3 => "fig3-trajectories.svg".into(),
            Self::Fig4 => "fig4-area-ranking.svg".into(),
            Self::Fig6 => "fig6-correlation-ranking.svg".into(),
            Self::Posterior => "posterior.svg".into(),
            Self::Confusion => "identifiability-confusion.svg".into(),
            Self::Coverage => "identifiability-coverage.svg".into(),
            Self::Subject(i) => format!("subject-{i}.svg"),
        }
    }
}

/// One job's learning curve.
#[derive(Debug, Clone)]
pub struct Curve {
    /// Legend text.
    pub label: String,
    /// Heartbeat progress points, oldest first.
    pub points: Vec<ProgressPoint>,
}

/// A chart saying there is nothing to draw yet.
pub fn empty(title: &str, message: &str, standalone: bool) -> String {
    let mut svg = Svg::new(640.0, 110.0, title);
    svg.text(16.0, 28.0, title, 14.0, "start", "#111111", None);
    svg.text(16.0, 64.0, message, 12.0, "start", "#777777", None);
    svg.finish(standalone)
}

/// "w1=0.5" or "w1=0.5, w2=2" for a grid point.
pub fn point_label(w: &WeightSummary) -> String {
    if w.params.is_empty() {
        return format!("value {}", short(w.value));
    }
    point_label_with(&w.params, short)
}

/// The grid point's parameters other than the label one ("" if none):
/// points that share them form one series.
fn group_key(w: &WeightSummary, label: &str) -> String {
    let others = w
        .params
        .iter()
        .filter(|(k, _)| k.as_str() != label)
        .map(|(k, v)| (k.clone(), *v))
        .collect();
    point_label_with(&others, short)
}

/// Learning curves: success rate and mean return against environment
/// steps, one line per job.
pub fn learning_curves(curves: &[Curve], standalone: bool) -> String {
    let title = "Learning curves (from worker heartbeats)";
    if curves.iter().all(|c| c.points.is_empty()) {
        return empty(title, "No heartbeat progress recorded yet.", standalone);
    }
    let rows = curves.len().div_ceil(2) as f64;
    let mut svg = Svg::new(960.0, 330.0 + rows * 16.0, title);
    let mut xe = Extent::default();
    let mut re = Extent::default();
    for c in curves {
        for p in &c.points {
            xe.add(p.env_steps as f64);
            re.add_all(p.mean_return);
        }
    }
    let (x0, x1) = xe.padded(0.0);
    let x0 = x0.max(0.0).min(x1);
    let left = Panel::new((70.0, 36.0, 360.0, 230.0), (x0, x1), (0.0, 1.0), false);
    let right = Panel::new(
        (560.0, 36.0, 360.0, 230.0),
        (x0, x1),
        re.padded(0.08),
        false,
    );
    left.axes(
        &mut svg,
        &Labels {
            title: "Success rate",
            x: "environment steps",
            y: "success rate",
        },
    );
    right.axes(
        &mut svg,
        &Labels {
            title: "Mean episode return",
            x: "environment steps",
            y: "return",
        },
    );
    let mut items = Vec::new();
    for (i, c) in curves.iter().enumerate() {
        let color = category(i);
        let sr: Vec<(f64, f64)> = c
            .points
            .iter()
            .filter_map(|p| Some((p.env_steps as f64, p.success_rate?)))
            .collect();
        let ret: Vec<(f64, f64)> = c
            .points
            .iter()
            .filter_map(|p| Some((p.env_steps as f64, p.mean_return?)))
            .collect();
        left.series(&mut svg, &sr, color, 1.8, false);
        right.series(&mut svg, &ret, color, 1.8, false);
        items.push(LegendItem::line(c.label.clone(), color));
    }
    if re.is_empty() {
        right.notice(&mut svg, "no finished episodes yet");
    }
    legend(
        &mut svg,
        70.0,
        318.0,
        &items,
        curves.len().div_ceil(2),
        450.0,
    );
    svg.finish(standalone)
}

/// Fig. 2: mean trajectory area and mean torque usage per grid value, with
/// SEM error bars, on a log axis when every value is positive.
pub fn fig2(doc: &ResultDocument, label: &str, standalone: bool) -> String {
    let title = format!("Fig. 2 - trajectory area and torque usage per {label} (mean +- SEM)");
    let usable = doc
        .weights
        .iter()
        .any(|w| w.area_mean.is_some() || w.torque_usage_mean.is_some());
    if !usable {
        return empty(
            &title,
            "No converged trials with trajectories yet.",
            standalone,
        );
    }
    let mut groups: BTreeMap<String, Vec<&WeightSummary>> = BTreeMap::new();
    for w in &doc.weights {
        groups.entry(group_key(w, label)).or_default().push(w);
    }
    for g in groups.values_mut() {
        g.sort_by(|a, b| a.value.total_cmp(&b.value));
    }
    let legend_rows = if groups.len() > 1 {
        groups.len().div_ceil(3)
    } else {
        0
    };
    let mut svg = Svg::new(960.0, 330.0 + legend_rows as f64 * 16.0, &title);
    svg.text(16.0, 18.0, &title, 13.0, "start", "#111111", None);
    let mut xe = Extent::default();
    xe.add_all(doc.weights.iter().map(|w| w.value));
    let xlog = doc.weights.iter().all(|w| w.value > 0.0);
    let xdom = if xlog {
        xe.log_padded(0.06).unwrap_or_else(|| xe.padded(0.06))
    } else {
        xe.padded(0.06)
    };
    let mut panels = Vec::new();
    type Get = fn(&WeightSummary) -> (Option<f64>, Option<f64>);
    let area: Get = |w| (w.area_mean, w.area_sem);
    let torque: Get = |w| (w.torque_usage_mean, w.torque_usage_sem);
    for (k, (get, name, ylabel)) in [
        (area, "Mean trajectory area", "area (normalized)"),
        (torque, "Mean torque usage", "torque usage (N m s)"),
    ]
    .into_iter()
    .enumerate()
    {
        let mut ye = Extent::default();
        for w in &doc.weights {
            if let (Some(m), e) = get(w) {
                let e = e.filter(|e| e.is_finite()).unwrap_or(0.0);
                ye.add(m - e);
                ye.add(m + e);
            }
        }
        let p = Panel::new(
            (70.0 + 490.0 * k as f64, 56.0, 360.0, 220.0),
            xdom,
            ye.padded(0.1),
            xlog,
        );
        p.axes(
            &mut svg,
            &Labels {
                title: name,
                x: label,
                y: ylabel,
            },
        );
        if ye.is_empty() {
            p.notice(&mut svg, "no data yet");
        }
        panels.push((p, get));
    }
    let mut items = Vec::new();
    for (gi, (key, ws)) in groups.iter().enumerate() {
        let color = if groups.len() > 1 {
            category(gi)
        } else {
            "#1f4e9c"
        };
        for (p, get) in &panels {
            let pts: Vec<(f64, f64)> = ws
                .iter()
                .filter_map(|w| Some((w.value, get(w).0?)))
                .collect();
            let errs: Vec<(f64, f64, f64)> = ws
                .iter()
                .filter_map(|w| {
                    let (m, e) = get(w);
                    Some((w.value, m?, e?))
                })
                .collect();
            let tips: Vec<(f64, f64, String)> = ws
                .iter()
                .filter_map(|w| {
                    let (m, e) = get(w);
                    let m = m?;
                    Some((
                        w.value,
                        m,
                        format!(
                            "{}: {} +- {} ({} trials used)",
                            point_label(w),
                            short(m),
                            short(e.unwrap_or(0.0)),
                            w.trials_used
                        ),
                    ))
                })
                .collect();
            p.error_bars(&mut svg, &errs, color);
            p.series(&mut svg, &pts, color, 1.8, false);
            p.markers(&mut svg, &tips, color, 3.5);
        }
        if groups.len() > 1 {
            items.push(LegendItem {
                label: if key.is_empty() {
                    "(no other parameters)".into()
                } else {
                    key.clone()
                },
                color: color.to_string(),
                kind: Swatch::Dot,
            });
        }
    }
    if !items.is_empty() {
        legend(&mut svg, 70.0, 330.0, &items, legend_rows, 300.0);
    }
    svg.finish(standalone)
}

/// Legend entries for per-grid-point colours (at most 24, then an
/// ellipsis entry).
fn weight_legend(ws: &[(usize, &WeightSummary)], colors: &[String]) -> Vec<LegendItem> {
    let mut items: Vec<LegendItem> = ws
        .iter()
        .zip(colors)
        .take(24)
        .map(|((_, w), c)| LegendItem::line(point_label(w), c.clone()))
        .collect();
    if ws.len() > 24 {
        items.push(LegendItem {
            label: format!("... {} more", ws.len() - 24),
            color: "#ffffff".into(),
            kind: Swatch::Dot,
        });
    }
    items
}

/// Fig. 3: the highest-return trajectory per grid value and the mean of
/// the trial means per grid value, in the normalized x-z plane.
pub fn fig3(doc: &ResultDocument, label: &str, standalone: bool) -> String {
    let title = format!("Fig. 3 - top and mean-of-means COM trajectories per {label}");
    let mut ws: Vec<(usize, &WeightSummary)> = doc
        .weights
        .iter()
        .enumerate()
        .filter(|(_, w)| w.mean_x.is_some() || w.top_x.is_some())
        .collect();
    if ws.is_empty() {
        return empty(
            &title,
            "No converged trials with trajectories yet.",
            standalone,
        );
    }
    ws.sort_by(|a, b| a.1.value.total_cmp(&b.1.value).then(a.0.cmp(&b.0)));
    let colors: Vec<String> = (0..ws.len()).map(|i| ordered(i, ws.len())).collect();
    let mut xe = Extent::default();
    let mut ze = Extent::default();
    for (_, w) in &ws {
        for (x, z) in [(&w.top_x, &w.top_z), (&w.mean_x, &w.mean_z)] {
            xe.add_all(x.iter().flatten().copied());
            ze.add_all(z.iter().flatten().copied());
        }
    }
    let items = weight_legend(&ws, &colors);
    let mut svg = Svg::new(960.0, 500.0, &title);
    svg.text(16.0, 18.0, &title, 13.0, "start", "#111111", None);
    for (k, name) in ["Top trajectory (highest return)", "Mean of trial means"]
        .into_iter()
        .enumerate()
    {
        let p = xz_panel(
            &mut svg,
            (70.0 + 340.0 * k as f64, 56.0, 260.0, 380.0),
            (&xe, &ze),
            name,
        );
        for ((_, w), c) in ws.iter().zip(&colors) {
            let (x, z) = if k == 0 {
                (&w.top_x, &w.top_z)
            } else {
                (&w.mean_x, &w.mean_z)
            };
            if let (Some(x), Some(z)) = (x, z) {
                let pts: Vec<(f64, f64)> = x.iter().copied().zip(z.iter().copied()).collect();
                p.series(&mut svg, &pts, c, 1.8, false);
            }
        }
    }
    legend(&mut svg, 720.0, 60.0, &items, 25, 120.0);
    svg.finish(standalone)
}

/// A method's probabilities over the grid for one subject (empty if the
/// document has no such method).
fn ranking(m: Method, s: &SubjectSummary) -> &[f64] {
    s.method(m).map_or(&[], |r| r.probabilities.as_slice())
}

/// Index of the point a method inferred, as `build_report` inferred it.
pub fn best(m: Method, s: &SubjectSummary) -> Option<usize> {
    s.method(m).and_then(|r| r.inferred_index)
}

/// A method's score at point `i`.
pub fn raw(m: Method, s: &SubjectSummary, i: usize) -> Option<f64> {
    s.method(m).and_then(|r| r.scores.get(i).copied().flatten())
}

/// Columns (left x, width) of a heat map over the document's grid points,
/// `total` wide from `x0`: on a log w1 axis, each point's column as wide
/// as its cell in log value (half-way to each neighbour, as the log-cell
/// prior weighs it) when every value is positive, equal columns otherwise;
/// no column is narrower than `min`. Points added between others (an
/// extended grid) so get narrow columns where they are dense.
pub fn log_columns(doc: &ResultDocument, x0: f64, total: f64, min: f64) -> Vec<(f64, f64)> {
    let values: Vec<f64> = doc.weights.iter().map(|w| w.value).collect();
    let n = values.len();
    if n == 0 {
        return Vec::new();
    }
    let share = prior_weights(&values, &vec![true; n], Prior::LogCell);
    let spare = (total - min * n as f64).max(0.0);
    let mut x = x0;
    share
        .iter()
        .map(|s| {
            let w = min + spare * s;
            let col = (x, w);
            x += w;
            col
        })
        .collect()
}

/// Figs. 4 and 6 and the posterior: subject x grid value heat map of a
/// method's probabilities, with each subject's inferred value outlined.
/// The w1 axis is logarithmic ([`log_columns`]).
pub fn heatmap(doc: &ResultDocument, label: &str, metric: Method, standalone: bool) -> String {
    let raw_name = metric.score_symbol();
    let title = match metric {
        Method::Area => {
            format!("Fig. 4 - softmax ranking of the area difference, subject x {label}")
        }
        Method::Correlation => {
            format!("Fig. 6 - softmax ranking of the correlation, subject x {label}")
        }
        Method::Posterior => format!("Posterior probability over the grid, subject x {label}"),
        Method::PosteriorOneSolver => {
            format!("One-solver posterior over the grid, subject x {label}")
        }
    };
    if doc.subjects.is_empty() {
        return empty(&title, "This search has no subjects.", standalone);
    }
    if doc.weights.is_empty() || doc.weights.iter().all(|w| w.mean_x.is_none()) {
        return empty(&title, "No grid point has a mean path yet.", standalone);
    }
    let n = doc.weights.len();
    let rows: Vec<&SubjectSummary> = doc.subjects.iter().take(MAX_HEATMAP_ROWS).collect();
    let name_w = rows
        .iter()
        .map(|s| s.subject.chars().count().min(24))
        .max()
        .unwrap_or(4) as f64
        * 7.0
        + 16.0;
    let cell_w = (640.0 / n as f64).clamp(12.0, 72.0);
    let cell_h = match rows.len() {
        0..=20 => 26.0,
        21..=40 => 22.0,
        _ => 14.0,
    };
    let x0 = name_w.max(60.0);
    let y0 = 44.0;
    let grid_w = cell_w * n as f64;
    let cols = log_columns(doc, x0, grid_w, (cell_w * 0.5).max(12.0));
    let narrowest = cols.iter().map(|c| c.1).fold(f64::INFINITY, f64::min);
    let show_values = narrowest >= 36.0 && cell_h >= 20.0;
    let grid_h = cell_h * rows.len() as f64;
    let rotate_labels = narrowest < 40.0;
    let label_h = if rotate_labels { 60.0 } else { 30.0 };
    let width = (x0 + grid_w + 110.0).max(560.0);
    let extra = if doc.subjects.len() > rows.len() {
        18.0
    } else {
        0.0
    };
    let height = y0 + grid_h + label_h + 30.0 + extra;
    let mut svg = Svg::new(width, height.max(160.0), &title);
    svg.text(12.0, 18.0, &title, 13.0, "start", "#111111", None);
    svg.text(
        12.0,
        34.0,
        match metric {
            Method::Posterior | Method::PosteriorOneSolver => {
                "outlined: inferred value (most probable)"
            }
            _ => "outlined: inferred value (smallest D / largest rho)",
        },
        11.0,
        "start",
        "#555555",
        None,
    );
    for (r, s) in rows.iter().enumerate() {
        let y = y0 + r as f64 * cell_h;
        let name: String = s.subject.chars().take(24).collect();
        svg.text(
            x0 - 6.0,
            y + cell_h / 2.0 + 4.0,
            &name,
            11.0,
            "end",
            "#222222",
            None,
        );
        let ranking = ranking(metric, s);
        for (i, &(x, cell_w)) in cols.iter().enumerate() {
            let v = ranking.get(i).copied().filter(|v| v.is_finite());
            let raw = raw(metric, s, i);
            let (fill, tip) = match (v, raw) {
                (Some(v), Some(d)) => (
                    ramp(v),
                    format!(
                        "{} at {}: ranking {}, {raw_name} = {}",
                        s.subject,
                        point_label(&doc.weights[i]),
                        short(v),
                        short(d)
                    ),
                ),
                _ => (
                    "#dddddd".to_string(),
                    format!(
                        "{} at {}: no value",
                        s.subject,
                        point_label(&doc.weights[i])
                    ),
                ),
            };
            svg.rect(
                x,
                y,
                cell_w,
                cell_h,
                &fill,
                Some(("#ffffff", 0.5)),
                Some(&tip),
            );
            if show_values {
                if let (Some(v), Some(_)) = (v, raw) {
                    let ink = if ramp_is_light(v) {
                        "#111111"
                    } else {
                        "#ffffff"
                    };
                    svg.text(
                        x + cell_w / 2.0,
                        y + cell_h / 2.0 + 4.0,
                        &format!("{v:.2}"),
                        10.0,
                        "middle",
                        ink,
                        None,
                    );
                }
            }
        }
        if let Some(&(x, cell_w)) = best(metric, s).and_then(|b| cols.get(b)) {
            svg.rect(
                x + 1.0,
                y + 1.0,
                cell_w - 2.0,
                cell_h - 2.0,
                "none",
                Some(("#e4002b", 2.5)),
                None,
            );
        }
        if s.error.is_some() {
            svg.text(
                x0 + 6.0,
                y + cell_h / 2.0 + 4.0,
                "not analysed",
                10.0,
                "start",
                "#555555",
                None,
            );
        }
    }
    let ly = y0 + grid_h + 14.0;
    for (w, &(cx, cw)) in doc.weights.iter().zip(&cols) {
        let x = cx + cw / 2.0;
        let text = if w.params.len() <= 1 {
            short(w.value)
        } else {
            point_label(w)
        };
        if rotate_labels {
            svg.text(x + 3.0, ly, &text, 10.0, "end", "#222222", Some(-60.0));
        } else {
            svg.text(x, ly, &text, 10.0, "middle", "#222222", None);
        }
    }
    svg.text(
        x0 + grid_w / 2.0,
        ly + label_h,
        label,
        12.0,
        "middle",
        "#222222",
        None,
    );
    if extra > 0.0 {
        svg.text(
            12.0,
            height - 6.0,
            &format!(
                "first {} of {} subjects shown; the table lists all",
                rows.len(),
                doc.subjects.len()
            ),
            11.0,
            "start",
            "#555555",
            None,
        );
    }
    // Colour bar.
    let bx = x0 + grid_w + 24.0;
    let bh = grid_h.clamp(60.0, 200.0);
    let steps = 20;
    for k in 0..steps {
        let t = 1.0 - (k as f64 + 0.5) / steps as f64;
        svg.rect(
            bx,
            y0 + k as f64 * bh / steps as f64,
            14.0,
            bh / steps as f64 + 0.5,
            &ramp(t),
            None,
            None,
        );
    }
    svg.text(bx + 18.0, y0 + 8.0, "1", 10.0, "start", "#222222", None);
    svg.text(bx + 18.0, y0 + bh, "0", 10.0, "start", "#222222", None);
    svg.text(
        bx + 7.0,
        y0 + bh + 14.0,
        "ranking",
        10.0,
        "middle",
        "#222222",
        None,
    );
    svg.finish(standalone)
}

/// Figs. 5 and 7 for one subject: its path against the best-fitting mean
/// path by area (left) and by correlation (right), each with the +-1 SD
/// band of the trial means.
pub fn subject_fit(
    doc: &ResultDocument,
    label: &str,
    i: usize,
    standalone: bool,
) -> Option<String> {
    let s = doc.subjects.get(i)?;
    let title = format!(
        "Figs. 5 and 7 - subject {} against its best-fitting mean path",
        s.subject
    );
    let (Some(sx), Some(sz)) = (&s.x, &s.z) else {
        let why = s
            .error
            .clone()
            .unwrap_or_else(|| "no resampled path".into());
        return Some(empty(
            &title,
            &format!("Subject not analysed: {why}"),
            standalone,
        ));
    };
    let mut svg = Svg::new(760.0, 500.0, &title);
    svg.text(16.0, 18.0, &title, 13.0, "start", "#111111", None);
    let by_area = format!("Inferred {label} by area difference (Fig. 5)");
    let by_corr = format!("Inferred {label} by correlation (Fig. 7)");
    let picks = [
        (Method::Area, by_area.as_str(), "#d95f02"),
        (Method::Correlation, by_corr.as_str(), "#1b9e77"),
    ];
    let subject_pts: Vec<(f64, f64)> = sx.iter().copied().zip(sz.iter().copied()).collect();
    for (k, (metric, name, color)) in picks.into_iter().enumerate() {
        let best = best(metric, s).and_then(|b| Some((b, doc.weights.get(b)?)));
        let mut xe = Extent::default();
        let mut ze = Extent::default();
        xe.add_all(sx.iter().copied());
        ze.add_all(sz.iter().copied());
        let mut band = None;
        if let Some((_, w)) = best {
            if let (Some(mx), Some(mz)) = (&w.mean_x, &w.mean_z) {
                let sd = w.sd_x.clone().unwrap_or_else(|| vec![0.0; mx.len()]);
                let lo: Vec<(f64, f64)> = mx
                    .iter()
                    .zip(&sd)
                    .zip(mz)
                    .map(|((x, d), z)| (x - d, *z))
                    .collect();
                let hi: Vec<(f64, f64)> = mx
                    .iter()
                    .zip(&sd)
                    .zip(mz)
                    .map(|((x, d), z)| (x + d, *z))
                    .collect();
                for &(x, z) in lo.iter().chain(&hi) {
                    xe.add(x);
                    ze.add(z);
                }
                let mean: Vec<(f64, f64)> = mx.iter().copied().zip(mz.iter().copied()).collect();
                band = Some((lo, hi, mean));
            }
        }
        let p = xz_panel(
            &mut svg,
            (70.0 + 360.0 * k as f64, 56.0, 280.0, 340.0),
            (&xe, &ze),
            name,
        );
        let mut items = vec![LegendItem {
            label: format!("subject {}", s.subject.chars().take(30).collect::<String>()),
            color: "#111111".into(),
            kind: Swatch::Line { dashed: true },
        }];
        match (best, band) {
            (Some((b, w)), Some((lo, hi, mean))) => {
                p.band(&mut svg, &lo, &hi, color, 0.22);
                p.series(&mut svg, &mean, color, 2.2, false);
                let symbol = metric.score_symbol();
                let score = raw(metric, s, b).map(|v| format!("{symbol} = {}", short(v)));
                items.push(LegendItem::line(
                    format!(
                        "mean path {}{}",
                        point_label(w),
                        score.map(|s| format!(" ({s})")).unwrap_or_default()
                    ),
                    color,
                ));
                items.push(LegendItem {
                    label: "+-1 SD across trial means".into(),
                    color: color.into(),
                    kind: Swatch::Band,
                });
            }
            _ => p.notice(&mut svg, "no grid point has a mean path yet"),
        }
        p.series(&mut svg, &subject_pts, "#111111", 1.8, true);
        legend(&mut svg, p.x, 448.0, &items, 3, 300.0);
    }
    Some(svg.finish(standalone))
}

/// The identifiability report: per method a confusion-matrix heat map of
/// held-out trials (rows the true value, columns the inferred one, each row
/// shaded by its share of that row's cases), then the coverage plot.
pub fn confusion(doc: &ResultDocument, label: &str, standalone: bool) -> String {
    let title =
        format!("Identifiability - held-out trials, true {label} (rows) x inferred (columns)");
    let Some(h) = doc.identifiability.as_ref().filter(|h| h.cases > 0) else {
        return empty(
            &title,
            "Shown once every grid point has 3 usable trials, or when the search completes.",
            standalone,
        );
    };
    let n = h.values.len();
    let cell = (220.0 / n.max(1) as f64).clamp(14.0, 40.0);
    let panel_w = cell * n as f64;
    let (x0, y0) = (70.0, 62.0);
    let gap = 60.0;
    let methods: Vec<_> = h.methods.iter().collect();
    let width = (x0 + (panel_w + gap) * methods.len() as f64 + 20.0).max(560.0);
    let height = y0 + panel_w + 60.0;
    let mut svg = Svg::new(width, height, &title);
    svg.text(12.0, 18.0, &title, 13.0, "start", "#111111", None);
    svg.text(
        12.0,
        34.0,
        &format!(
            "{} held-out trials, each scored against the grid rebuilt without it; outlined: the true value",
            h.cases
        ),
        11.0,
        "start",
        "#555555",
        None,
    );
    for (k, (m, tally)) in methods.iter().enumerate() {
        let px = x0 + k as f64 * (panel_w + gap);
        svg.text(
            px,
            y0 - 10.0,
            &format!(
                "{} ({} / {} within one)",
                m.title(),
                tally.within_one,
                h.cases
            ),
            11.0,
            "start",
            "#222222",
            None,
        );
        for (i, row) in tally.confusion.iter().enumerate() {
            let total: u32 = row.iter().sum();
            let y = y0 + i as f64 * cell;
            if k == 0 {
                svg.text(
                    px - 6.0,
                    y + cell / 2.0 + 4.0,
                    &short(h.values[i]),
                    10.0,
                    "end",
                    "#222222",
                    None,
                );
            }
            for (j, &c) in row.iter().enumerate() {
                let x = px + j as f64 * cell;
                let share = if total > 0 {
                    f64::from(c) / f64::from(total)
                } else {
                    0.0
                };
                let tip = format!(
                    "true {label} = {}, inferred {}: {c} of {total} by {}",
                    short(h.values[i]),
                    short(h.values[j]),
                    m.title()
                );
                svg.rect(
                    x,
                    y,
                    cell,
                    cell,
                    &ramp(share),
                    Some(("#ffffff", 0.5)),
                    Some(&tip),
                );
                if cell >= 22.0 && c > 0 {
                    let ink = if ramp_is_light(share) {
                        "#111111"
                    } else {
                        "#ffffff"
                    };
                    svg.text(
                        x + cell / 2.0,
                        y + cell / 2.0 + 4.0,
                        &c.to_string(),
                        10.0,
                        "middle",
                        ink,
                        None,
                    );
                }
            }
            svg.rect(
                px + i as f64 * cell + 1.0,
                y + 1.0,
                cell - 2.0,
                cell - 2.0,
                "none",
                Some(("#e4002b", 1.5)),
                None,
            );
        }
        for (j, v) in h.values.iter().enumerate() {
            let x = px + j as f64 * cell + cell / 2.0;
            svg.text(
                x,
                y0 + panel_w + 14.0,
                &short(*v),
                10.0,
                "middle",
                "#222222",
                Some(-45.0),
            );
        }
    }
    svg.finish(standalone)
}

/// Calibration plot: nominal mass of the highest-probability sets against
/// the observed coverage of held-out trials, one line per method, with the
/// diagonal of perfect calibration.
pub fn coverage(doc: &ResultDocument, standalone: bool) -> String {
    let title = "Calibration - nominal vs observed coverage of the highest-probability sets";
    let Some(h) = doc
        .identifiability
        .as_ref()
        .filter(|h| !h.coverage.is_empty())
    else {
        return empty(
            title,
            "Shown once every grid point has 3 usable trials, or when the search completes.",
            standalone,
        );
    };
    let mut svg = Svg::new(640.0, 400.0, title);
    svg.text(12.0, 18.0, title, 13.0, "start", "#111111", None);
    let p = Panel::new((70.0, 40.0, 330.0, 300.0), (0.4, 1.0), (0.0, 1.0), false);
    p.axes(
        &mut svg,
        &Labels {
            title: "",
            x: "nominal mass",
            y: "observed coverage",
        },
    );
    p.series(&mut svg, &[(0.4, 0.4), (1.0, 1.0)], "#999999", 1.0, true);
    let mut items = vec![LegendItem {
        label: "perfect calibration".into(),
        color: "#999999".into(),
        kind: Swatch::Line { dashed: true },
    }];
    for (k, (m, cal)) in h.coverage.iter().enumerate() {
        let color = category(k);
        let pts: Vec<(f64, f64)> = cal.levels.iter().map(|l| (l.level, l.coverage)).collect();
        p.series(&mut svg, &pts, color, 2.0, false);
        let marks: Vec<(f64, f64, String)> = cal
            .levels
            .iter()
            .map(|l| {
                (
                    l.level,
                    l.coverage,
                    format!(
                        "{}: {:.0} % sets cover {:.1} % (mean size {:.1})",
                        m.title(),
                        l.level * 100.0,
                        l.coverage * 100.0,
                        l.mean_set_size
                    ),
                )
            })
            .collect();
        p.markers(&mut svg, &marks, color, 3.5);
        items.push(LegendItem::line(
            format!("{} (gain {:+.2} nats)", m.title(), cal.gain_nats),
            color,
        ));
    }
    legend(&mut svg, 420.0, 60.0, &items, 8, 210.0);
    svg.finish(standalone)
}

/// Renders chart `id` of a document (every id but the learning curves);
/// `None` for a subject index past the end.
pub fn render(doc: &ResultDocument, label: &str, id: ChartId, standalone: bool) -> Option<String> {
    Some(match id {
        ChartId::LearningCurves => return None,
        ChartId::Fig2 => fig2(doc, label, standalone),
        ChartId::Fig3 => fig3(doc, label, standalone),
        ChartId::Fig4 => heatmap(doc, label, Method::Area, standalone),
        ChartId::Fig6 => heatmap(doc, label, Method::Correlation, standalone),
        ChartId::Posterior => heatmap(doc, label, Method::Posterior, standalone),
        ChartId::Confusion => confusion(doc, label, standalone),
        ChartId::Coverage => coverage(doc, standalone),
        ChartId::Subject(i) => return subject_fit(doc, label, i, standalone),
    })
}

/// An equal-aspect panel of the sagittal plane (normalized x across, z up)
/// over `rect`, its axes drawn: the path figures' panels.
fn xz_panel(
    svg: &mut Svg,
    rect: (f64, f64, f64, f64),
    (xe, ze): (&Extent, &Extent),
    title: &str,
) -> Panel {
    let p = Panel::equal_aspect(rect, xe, ze, 0.05);
    p.axes(
        svg,
        &Labels {
            title,
            x: "x (normalized)",
            y: "z (normalized)",
        },
    );
    p
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid_doc(values: &[f64]) -> ResultDocument {
        let weights: Vec<shared::analysis::WeightInput> = values
            .iter()
            .map(|&v| shared::analysis::WeightInput {
                params: BTreeMap::from([("w1".to_string(), v)]),
                trials: Vec::new(),
            })
            .collect();
        shared::analysis::build_report(&weights, &[], &Default::default())
    }

    #[test]
    fn heat_map_columns_follow_log_w1() {
        let even = log_columns(&grid_doc(&[1.0, 2.0, 4.0, 8.0]), 10.0, 400.0, 20.0);
        for (i, (x, w)) in even.iter().enumerate() {
            assert!((w - 100.0).abs() < 1e-9 && (x - (10.0 + 100.0 * i as f64)).abs() < 1e-9);
        }
        // A refined stretch gets narrow columns; the whole keeps its width.
        let fine = log_columns(
            &grid_doc(&[1.0, 2.0, 2.0 * 2f64.sqrt(), 4.0, 8.0]),
            0.0,
            500.0,
            20.0,
        );
        let total: f64 = fine.iter().map(|c| c.1).sum();
        assert!((total - 500.0).abs() < 1e-9);
        assert!(fine[2].1 < fine[0].1 && fine[2].1 >= 20.0);
        assert!(fine
            .windows(2)
            .all(|p| (p[0].0 + p[0].1 - p[1].0).abs() < 1e-9));
    }

    #[test]
    fn chart_names_round_trip_and_reject_odd_spellings() {
        for id in [
            ChartId::LearningCurves,
            ChartId::Fig2,
            ChartId::Fig3,
            ChartId::Fig4,
            ChartId::Fig6,
            ChartId::Subject(0),
            ChartId::Subject(12),
        ] {
            assert_eq!(ChartId::parse(&id.file_name()), Some(id));
        }
        assert_eq!(ChartId::parse("subject-01.svg"), None);
        assert_eq!(ChartId::parse("subject-.svg"), None);
        assert_eq!(ChartId::parse("subject--1.svg"), None);
        assert_eq!(ChartId::parse("../etc.svg"), None);
    }

    #[test]
    fn empty_document_gives_notice_charts() {
        let doc = ResultDocument {
            analysis_version: shared::analysis::ANALYSIS_VERSION,
            weights: vec![],
            subjects: vec![],
            identifiability: None,
            notes: vec![],
        };
        for id in [
            ChartId::Fig2,
            ChartId::Fig3,
            ChartId::Fig4,
            ChartId::Fig6,
            ChartId::Posterior,
            ChartId::Confusion,
            ChartId::Coverage,
        ] {
            let s = render(&doc, "w1", id, true).unwrap();
            assert!(s.contains("<svg") && s.contains("</svg>"), "{s}");
        }
        assert!(render(&doc, "w1", ChartId::Subject(0), true).is_none());
        let c = learning_curves(&[], true);
        assert!(c.contains("No heartbeat"));
    }
}
