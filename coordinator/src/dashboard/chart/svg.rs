//! Hand-drawn SVG: an escaping writer, linear and log scales with 1-2-5
//! ticks, plot panels (axes, lines, markers, error bars, bands, heat-map
//! cells) and colour ramps. Every coordinate goes through [`num`], and the
//! drawing helpers skip non-finite data, so no `NaN` ever reaches the
//! output.

use std::fmt::Write as _;

/// Escapes text for XML/HTML content and attribute values.
pub fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            // XML 1.0 forbids most control characters even when escaped.
            c if c.is_control() && c != '\n' && c != '\t' => out.push('\u{fffd}'),
            c => out.push(c),
        }
    }
    out
}

/// A coordinate as SVG text: two decimals, trailing zeros trimmed; `0` for
/// a non-finite value (callers skip those before drawing, this is the last
/// line of defence).
pub fn num(v: f64) -> String {
    if !v.is_finite() {
        return "0".to_string();
    }
    let s = format!("{v:.2}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" || s.is_empty() {
        "0".to_string()
    } else {
        s.to_string()
    }
}

/// A number for a tick label or a table: short, no exponent for ordinary
/// magnitudes, `–` for a non-finite value.
pub fn short(v: f64) -> String {
    if !v.is_finite() {
        return "–".to_string();
    }
    let a = v.abs();
    if a == 0.0 {
        return "0".to_string();
    }
    if !(1e-3..1e5).contains(&a) {
        return format!("{v:.1e}");
    }
    let digits = if a >= 100.0 {
        0
    } else if a >= 10.0 {
        1
    } else if a >= 1.0 {
        2
    } else {
        3
    };
    let s = format!("{v:.digits$}");
    let s = if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    };
    if s == "-0" {
        "0".to_string()
    } else {
        s
    }
}

/// An SVG document being written.
pub struct Svg {
    width: f64,
    height: f64,
    title: String,
    body: String,
}

impl Svg {
    /// An empty picture of this size (pixels) whose accessible title is
    /// `title`.
    pub fn new(width: f64, height: f64, title: &str) -> Self {
        Self {
            width,
            height,
            title: title.to_string(),
            body: String::new(),
        }
    }

    /// A straight line.
    pub fn line(&mut self, x1: f64, y1: f64, x2: f64, y2: f64, stroke: &str, width: f64) {
        let _ = writeln!(
            self.body,
            r#"<line x1="{}" y1="{}" x2="{}" y2="{}" stroke="{}" stroke-width="{}"/>"#,
            num(x1),
            num(y1),
            num(x2),
            num(y2),
            esc(stroke),
            num(width)
        );
    }

    /// A rectangle; `stroke` draws an outline; `tip` becomes a hover title.
    #[allow(clippy::too_many_arguments)]
    pub fn rect(
        &mut self,
        x: f64,
        y: f64,
        w: f64,
        h: f64,
        fill: &str,
        stroke: Option<(&str, f64)>,
        tip: Option<&str>,
    ) {
        let outline = stroke
            .map(|(c, sw)| format!(r#" stroke="{}" stroke-width="{}""#, esc(c), num(sw)))
            .unwrap_or_default();
        let _ = write!(
            self.body,
            r#"<rect x="{}" y="{}" width="{}" height="{}" fill="{}"{outline}"#,
            num(x),
            num(y),
            num(w.max(0.0)),
            num(h.max(0.0)),
            esc(fill)
        );
        match tip {
            Some(t) => {
                let _ = writeln!(self.body, "><title>{}</title></rect>", esc(t));
            }
            None => self.body.push_str("/>\n"),
        }
    }

    /// A filled circle with an optional hover title.
    pub fn circle(&mut self, cx: f64, cy: f64, r: f64, fill: &str, tip: Option<&str>) {
        let _ = write!(
            self.body,
            r#"<circle cx="{}" cy="{}" r="{}" fill="{}""#,
            num(cx),
            num(cy),
            num(r),
            esc(fill)
        );
        match tip {
            Some(t) => {
                let _ = writeln!(self.body, "><title>{}</title></circle>", esc(t));
            }
            None => self.body.push_str("/>\n"),
        }
    }

    /// An open polyline through pixel points (at least two).
    pub fn polyline(&mut self, pts: &[(f64, f64)], stroke: &str, width: f64, dashed: bool) {
        if pts.len() < 2 {
            return;
        }
        let dash = if dashed {
            r#" stroke-dasharray="5 3""#
        } else {
            ""
        };
        let _ = writeln!(
            self.body,
            r#"<polyline fill="none" stroke="{}" stroke-width="{}" stroke-linejoin="round"{dash} points="{}"/>"#,
            esc(stroke),
            num(width),
            points(pts)
        );
    }

    /// A filled polygon through pixel points (at least three).
    pub fn polygon(&mut self, pts: &[(f64, f64)], fill: &str, opacity: f64) {
        if pts.len() < 3 {
            return;
        }
        let _ = writeln!(
            self.body,
            r#"<polygon fill="{}" fill-opacity="{}" stroke="none" points="{}"/>"#,
            esc(fill),
            num(opacity),
            points(pts)
        );
    }

    /// Text; `anchor` is `start`, `middle` or `end`; `rotate` turns it
    /// about its anchor point (degrees).
    #[allow(clippy::too_many_arguments)]
    pub fn text(
        &mut self,
        x: f64,
        y: f64,
        s: &str,
        size: f64,
        anchor: &str,
        fill: &str,
        rotate: Option<f64>,
    ) {
        let rot = rotate
            .map(|a| format!(r#" transform="rotate({} {} {})""#, num(a), num(x), num(y)))
            .unwrap_or_default();
        let _ = writeln!(
            self.body,
            r#"<text x="{}" y="{}" font-size="{}" text-anchor="{}" fill="{}"{rot}>{}</text>"#,
            num(x),
            num(y),
            num(size),
            esc(anchor),
            esc(fill),
            esc(s)
        );
    }

    /// The document. `standalone` adds the XML declaration for a
    /// downloaded file; inline copies go into HTML without it.
    pub fn finish(self, standalone: bool) -> String {
        let mut out = String::with_capacity(self.body.len() + 400);
        if standalone {
            out.push_str("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
        }
        let _ = write!(
            out,
            "<svg xmlns=\"http://www.w3.org/2000/svg\" class=\"chart\" width=\"{w}\" height=\"{h}\" \
             viewBox=\"0 0 {w} {h}\" role=\"img\" font-family=\"Helvetica, Arial, sans-serif\">\n\
             <title>{t}</title>\n<rect x=\"0\" y=\"0\" width=\"{w}\" height=\"{h}\" fill=\"#ffffff\"/>\n",
            w = num(self.width),
            h = num(self.height),
            t = esc(&self.title)
        );
        out.push_str(&self.body);
        out.push_str("</svg>\n");
        out
    }
}

fn points(pts: &[(f64, f64)]) -> String {
    let mut s = String::with_capacity(pts.len() * 12);
    for (i, (x, y)) in pts.iter().enumerate() {
        if i > 0 {
            s.push(' ');
        }
        let _ = write!(s, "{},{}", num(*x), num(*y));
    }
    s
}

/// The range of the finite values seen.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Extent {
    lo: Option<f64>,
    hi: Option<f64>,
}

impl Extent {
    /// Adds a value (non-finite ones are ignored).
    pub fn add(&mut self, v: f64) {
        if !v.is_finite() {
            return;
        }
        self.lo = Some(self.lo.map_or(v, |l| l.min(v)));
        self.hi = Some(self.hi.map_or(v, |h| h.max(v)));
    }

    /// Adds every value.
    pub fn add_all(&mut self, vs: impl IntoIterator<Item = f64>) {
        for v in vs {
            self.add(v);
        }
    }

    /// Whether any finite value was seen.
    pub fn is_empty(&self) -> bool {
        self.lo.is_none()
    }

    /// (lo, hi) widened by `pad` of the span on each side; a single value
    /// gets a unit-scale span around it; nothing seen gives (0, 1).
    pub fn padded(&self, pad: f64) -> (f64, f64) {
        let (Some(lo), Some(hi)) = (self.lo, self.hi) else {
            return (0.0, 1.0);
        };
        let span = hi - lo;
        if span.is_nan() || span <= f64::EPSILON * lo.abs().max(hi.abs()).max(1e-300) {
            let d = if lo.abs() > 0.0 { lo.abs() * 0.1 } else { 0.5 };
            return (lo - d, hi + d);
        }
        let (a, b) = (lo - span * pad, hi + span * pad);
        if a.is_finite() && b.is_finite() {
            (a, b)
        } else {
            (lo, hi)
        }
    }

    /// (lo, hi) on a log axis: positive values only, widened by `pad`
    /// decades' fraction; `None` if there is no positive value.
    pub fn log_padded(&self, pad: f64) -> Option<(f64, f64)> {
        let (lo, hi) = (self.lo?, self.hi?);
        if lo <= 0.0 {
            return None;
        }
        let (l, h) = (lo.log10(), hi.log10());
        let span = (h - l).max(0.0);
        let p = if span > 1e-9 { span * pad } else { 0.3 };
        Some((10f64.powf(l - p), 10f64.powf(h + p)))
    }
}

/// Maps data values to pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scale {
    lo: f64,
    hi: f64,
    px0: f64,
    px1: f64,
    log: bool,
}

impl Scale {
    /// A linear scale from [lo, hi] to [px0, px1].
    pub fn linear(lo: f64, hi: f64, px0: f64, px1: f64) -> Self {
        Self {
            lo,
            hi,
            px0,
            px1,
            log: false,
        }
    }

    /// A base-10 log scale; `lo` and `hi` must be positive.
    pub fn log(lo: f64, hi: f64, px0: f64, px1: f64) -> Self {
        Self {
            lo,
            hi,
            px0,
            px1,
            log: true,
        }
    }

    /// Pixel position of `v`, or `None` if `v` cannot be shown (not finite,
    /// not positive on a log scale).
    pub fn map(&self, v: f64) -> Option<f64> {
        if !v.is_finite() {
            return None;
        }
        let (a, b, t) = if self.log {
            if v <= 0.0 || self.lo <= 0.0 || self.hi <= 0.0 {
                return None;
            }
            (self.lo.log10(), self.hi.log10(), v.log10())
        } else {
            (self.lo, self.hi, v)
        };
        let span = b - a;
        if span == 0.0 || !span.is_finite() {
            return Some((self.px0 + self.px1) / 2.0);
        }
        let p = self.px0 + (t - a) / span * (self.px1 - self.px0);
        p.is_finite().then_some(p)
    }

    /// Tick values inside the domain: 1-2-5 steps (linear) or 1-2-5 per
    /// decade (log).
    pub fn ticks(&self, target: usize) -> Vec<f64> {
        if self.log {
            let mut out = Vec::new();
            let (l, h) = (
                self.lo.log10().floor() as i32,
                self.hi.log10().ceil() as i32,
            );
            let decades = (h - l).max(1);
            let mults: &[f64] = if decades > 4 {
                &[1.0]
            } else if decades > 2 {
                &[1.0, 3.0]
            } else {
                &[1.0, 2.0, 5.0]
            };
            for k in l..=h {
                for m in mults {
                    let v = m * 10f64.powi(k);
                    if v >= self.lo * (1.0 - 1e-9) && v <= self.hi * (1.0 + 1e-9) {
                        out.push(v);
                    }
                }
            }
            if out.len() >= 2 {
                return out;
            }
            return linear_ticks(self.lo, self.hi, target);
        }
        linear_ticks(self.lo, self.hi, target)
    }
}

/// 1-2-5 ticks covering [lo, hi], about `target` of them.
pub fn linear_ticks(lo: f64, hi: f64, target: usize) -> Vec<f64> {
    let span = hi - lo;
    if !(span.is_finite() && span > 0.0) {
        return if lo.is_finite() { vec![lo] } else { Vec::new() };
    }
    let raw = span / target.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last.min(first + 50))
        .map(|i| {
            let v = i as f64 * step;
            // Snap float noise (0.30000000000000004) away.
            if v.abs() < step * 1e-9 {
                0.0
            } else {
                v
            }
        })
        .collect()
}

/// A plotting area inside an [`Svg`] with its two scales.
#[derive(Debug, Clone, Copy)]
pub struct Panel {
    /// Left edge of the plot area (pixels).
    pub x: f64,
    /// Top edge.
    pub y: f64,
    /// Width.
    pub w: f64,
    /// Height.
    pub h: f64,
    /// Horizontal scale.
    pub xs: Scale,
    /// Vertical scale.
    pub ys: Scale,
}

/// Axis labels and title of a panel.
pub struct Labels<'a> {
    /// Title above the panel.
    pub title: &'a str,
    /// Horizontal axis label.
    pub x: &'a str,
    /// Vertical axis label.
    pub y: &'a str,
}

const AXIS: &str = "#333333";
const GRID: &str = "#e6e6e6";

impl Panel {
    /// A panel over the plot rectangle (x, y, w, h) with these data
    /// domains; `xlog` asks for a log x axis (used only when the domain is
    /// positive).
    pub fn new(rect: (f64, f64, f64, f64), xdom: (f64, f64), ydom: (f64, f64), xlog: bool) -> Self {
        let (x, y, w, h) = rect;
        let xs = if xlog && xdom.0 > 0.0 && xdom.1 > 0.0 {
            Scale::log(xdom.0, xdom.1, x, x + w)
        } else {
            Scale::linear(xdom.0, xdom.1, x, x + w)
        };
        Self {
            x,
            y,
            w,
            h,
            xs,
            ys: Scale::linear(ydom.0, ydom.1, y + h, y),
        }
    }

    /// Domains of equal data units per pixel on both axes (for paths in the
    /// x-z plane), grown around the data's extents to fill the rectangle.
    pub fn equal_aspect(rect: (f64, f64, f64, f64), xe: &Extent, ye: &Extent, pad: f64) -> Self {
        let (x0, x1) = xe.padded(pad);
        let (y0, y1) = ye.padded(pad);
        let (w, h) = (rect.2, rect.3);
        let ux = (x1 - x0) / w;
        let uy = (y1 - y0) / h;
        let u = ux.max(uy);
        let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
        Self::new(
            rect,
            (cx - u * w / 2.0, cx + u * w / 2.0),
            (cy - u * h / 2.0, cy + u * h / 2.0),
            false,
        )
    }

    /// Pixel position of a data point, if it can be shown.
    pub fn pt(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        Some((self.xs.map(x)?, self.ys.map(y)?))
    }

    /// Frame, grid, ticks, tick labels, axis labels and title.
    pub fn axes(&self, svg: &mut Svg, labels: &Labels) {
        svg.rect(
            self.x,
            self.y,
            self.w,
            self.h,
            "#fcfcfc",
            Some((GRID, 1.0)),
            None,
        );
        let yb = self.y + self.h;
        for t in self.xs.ticks(6) {
            if let Some(px) = self.xs.map(t) {
                svg.line(px, self.y, px, yb, GRID, 1.0);
                svg.line(px, yb, px, yb + 4.0, AXIS, 1.0);
                svg.text(px, yb + 16.0, &short(t), 11.0, "middle", AXIS, None);
            }
        }
        for t in self.ys.ticks(5) {
            if let Some(py) = self.ys.map(t) {
                svg.line(self.x, py, self.x + self.w, py, GRID, 1.0);
                svg.line(self.x - 4.0, py, self.x, py, AXIS, 1.0);
                svg.text(self.x - 7.0, py + 4.0, &short(t), 11.0, "end", AXIS, None);
            }
        }
        svg.line(self.x, yb, self.x + self.w, yb, AXIS, 1.0);
        svg.line(self.x, self.y, self.x, yb, AXIS, 1.0);
        svg.text(
            self.x + self.w / 2.0,
            yb + 34.0,
            labels.x,
            12.0,
            "middle",
            AXIS,
            None,
        );
        let ly = self.y + self.h / 2.0;
        svg.text(
            self.x - 44.0,
            ly,
            labels.y,
            12.0,
            "middle",
            AXIS,
            Some(-90.0),
        );
        svg.text(
            self.x,
            self.y - 10.0,
            labels.title,
            13.0,
            "start",
            "#111111",
            None,
        );
    }

    /// A line through data points, broken where a point cannot be shown.
    pub fn series(
        &self,
        svg: &mut Svg,
        data: &[(f64, f64)],
        color: &str,
        width: f64,
        dashed: bool,
    ) {
        let mut run: Vec<(f64, f64)> = Vec::new();
        for &(x, y) in data {
            match self.pt(x, y) {
                Some(p) => run.push(p),
                None => {
                    self.flush(svg, &mut run, color, width, dashed);
                }
            }
        }
        self.flush(svg, &mut run, color, width, dashed);
    }

    fn flush(
        &self,
        svg: &mut Svg,
        run: &mut Vec<(f64, f64)>,
        color: &str,
        width: f64,
        dashed: bool,
    ) {
        if run.len() == 1 {
            svg.circle(run[0].0, run[0].1, width.max(1.5), color, None);
        } else {
            svg.polyline(run, color, width, dashed);
        }
        run.clear();
    }

    /// Dots at data points, each with a hover title.
    pub fn markers(&self, svg: &mut Svg, data: &[(f64, f64, String)], color: &str, r: f64) {
        for (x, y, tip) in data {
            if let Some((px, py)) = self.pt(*x, *y) {
                svg.circle(px, py, r, color, Some(tip));
            }
        }
    }

    /// Vertical error bars y +- err with caps.
    pub fn error_bars(&self, svg: &mut Svg, data: &[(f64, f64, f64)], color: &str) {
        for &(x, y, e) in data {
            if !e.is_finite() || e <= 0.0 {
                continue;
            }
            let (Some(px), Some(lo), Some(hi)) =
                (self.xs.map(x), self.ys.map(y - e), self.ys.map(y + e))
            else {
                continue;
            };
            svg.line(px, lo, px, hi, color, 1.3);
            svg.line(px - 4.0, lo, px + 4.0, lo, color, 1.3);
            svg.line(px - 4.0, hi, px + 4.0, hi, color, 1.3);
        }
    }

    /// A filled band between two boundary lines given point by point (both
    /// the same length); split where a point cannot be shown.
    pub fn band(
        &self,
        svg: &mut Svg,
        a: &[(f64, f64)],
        b: &[(f64, f64)],
        color: &str,
        opacity: f64,
    ) {
        let n = a.len().min(b.len());
        let mut start = 0;
        while start < n {
            let mut end = start;
            let mut top = Vec::new();
            let mut bottom = Vec::new();
            while end < n {
                match (self.pt(a[end].0, a[end].1), self.pt(b[end].0, b[end].1)) {
                    (Some(p), Some(q)) => {
                        top.push(p);
                        bottom.push(q);
                        end += 1;
                    }
                    _ => break,
                }
            }
            if top.len() >= 2 {
                bottom.reverse();
                top.extend(bottom);
                svg.polygon(&top, color, opacity);
            }
            start = end + 1;
        }
    }

    /// A small "no data" notice in the middle of the panel.
    pub fn notice(&self, svg: &mut Svg, msg: &str) {
        svg.text(
            self.x + self.w / 2.0,
            self.y + self.h / 2.0,
            msg,
            12.0,
            "middle",
            "#888888",
            None,
        );
    }
}

/// A legend: coloured swatches with labels, in columns of `per_col` rows
/// starting at (x, y). Dashed entries get a dashed swatch; band entries a
/// filled box.
pub fn legend(svg: &mut Svg, x: f64, y: f64, items: &[LegendItem], per_col: usize, col_w: f64) {
    let per_col = per_col.max(1);
    for (i, it) in items.iter().enumerate() {
        let cx = x + (i / per_col) as f64 * col_w;
        let cy = y + (i % per_col) as f64 * 16.0;
        match it.kind {
            Swatch::Line { dashed } => {
                svg.polyline(&[(cx, cy), (cx + 18.0, cy)], &it.color, 2.5, dashed)
            }
            Swatch::Band => svg.rect(cx, cy - 5.0, 18.0, 10.0, &it.color, None, None),
            Swatch::Dot => svg.circle(cx + 9.0, cy, 4.0, &it.color, None),
        }
        svg.text(cx + 24.0, cy + 4.0, &it.label, 11.0, "start", AXIS, None);
    }
}

/// How a legend entry's swatch looks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Swatch {
    /// A line, solid or dashed.
    Line {
        /// Dashed.
        dashed: bool,
    },
    /// A filled box (a band).
    Band,
    /// A dot (markers).
    Dot,
}

/// One legend entry.
#[derive(Debug, Clone)]
pub struct LegendItem {
    /// Text.
    pub label: String,
    /// Colour.
    pub color: String,
    /// Swatch.
    pub kind: Swatch,
}

impl LegendItem {
    /// A solid-line entry.
    pub fn line(label: impl Into<String>, color: impl Into<String>) -> Self {
        Self {
            label: label.into(),
            color: color.into(),
            kind: Swatch::Line { dashed: false },
        }
    }
}

/// Viridis-like sequential colour for `t` in [0, 1] (clamped).
pub fn ramp(t: f64) -> String {
    const STOPS: [(f64, f64, f64); 6] = [
        (68.0, 1.0, 84.0),
        (65.0, 68.0, 135.0),
        (42.0, 120.0, 142.0),
        (34.0, 168.0, 132.0),
        (122.0, 209.0, 81.0),
        (253.0, 231.0, 37.0),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let f = t * (STOPS.len() - 1) as f64;
    let i = (f.floor() as usize).min(STOPS.len() - 2);
    let u = f - i as f64;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    let mix = |p: f64, q: f64| (p + (q - p) * u).round().clamp(0.0, 255.0) as u8;
    format!(
        "#{:02x}{:02x}{:02x}",
        mix(a.0, b.0),
        mix(a.1, b.1),
        mix(a.2, b.2)
    )
}

/// Whether text on [`ramp`]`(t)` should be dark (light background).
pub fn ramp_is_light(t: f64) -> bool {
    t.is_finite() && t > 0.62
}

/// Colour `i` of `n` ordered series: a ramp that avoids viridis' pale
/// yellow end so thin lines stay visible.
pub fn ordered(i: usize, n: usize) -> String {
    if n <= 1 {
        return ramp(0.35);
    }
    ramp(0.9 * i as f64 / (n - 1) as f64)
}

/// Categorical colour `i` (repeats after ten).
pub fn category(i: usize) -> &'static str {
    const C: [&str; 10] = [
        "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
        "#bcbd22", "#17becf",
    ];
    C[i % C.len()]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escaping_covers_markup_and_quotes() {
        assert_eq!(
            esc(r#"<a href="x">&'"#),
            "&lt;a href=&quot;x&quot;&gt;&amp;&#39;"
        );
        assert_eq!(esc("a\u{1}b"), "a\u{fffd}b");
    }

    #[test]
    fn numbers_are_short_and_never_nan() {
        assert_eq!(num(1.0), "1");
        assert_eq!(num(1.256), "1.26");
        assert_eq!(num(-0.001), "0");
        assert_eq!(num(f64::NAN), "0");
        assert_eq!(num(f64::INFINITY), "0");
        assert_eq!(short(0.1), "0.1");
        assert_eq!(short(16.0), "16");
        assert_eq!(short(12345.0), "12345");
        assert_eq!(short(1e6), "1.0e6");
        assert_eq!(short(f64::NAN), "–");
    }

    #[test]
    fn linear_ticks_are_one_two_five_steps_inside_the_domain() {
        let t = linear_ticks(0.0, 1.0, 5);
        assert_eq!(t.len(), 6);
        assert!((t[3] - 0.6).abs() < 1e-12 && t[0] == 0.0 && (t[5] - 1.0).abs() < 1e-12);
        let t = linear_ticks(-0.33, 0.41, 5);
        assert!(t.iter().all(|v| (-0.33..=0.41).contains(v)));
        assert!(t.contains(&0.0));
        assert!(linear_ticks(1.0, 1.0, 5) == vec![1.0]);
    }

    #[test]
    fn log_scale_maps_decades_evenly_and_refuses_non_positive() {
        let s = Scale::log(0.1, 10.0, 0.0, 200.0);
        assert!((s.map(1.0).unwrap() - 100.0).abs() < 1e-9);
        assert!((s.map(0.1).unwrap()).abs() < 1e-9);
        assert_eq!(s.map(0.0), None);
        assert_eq!(s.map(f64::NAN), None);
        let t = s.ticks(5);
        assert!(
            t.contains(&1.0) && t.contains(&0.2) && t.contains(&5.0),
            "{t:?}"
        );
    }

    #[test]
    fn extents_ignore_non_finite_and_widen_degenerate_ranges() {
        let mut e = Extent::default();
        assert_eq!(e.padded(0.1), (0.0, 1.0));
        e.add(f64::NAN);
        assert!(e.is_empty());
        e.add(2.0);
        let (lo, hi) = e.padded(0.1);
        assert!(lo < 2.0 && hi > 2.0);
        e.add(4.0);
        assert_eq!(e.padded(0.0), (2.0, 4.0));
        let (a, b) = e.log_padded(0.0).unwrap();
        assert!((a - 2.0).abs() < 1e-9 && (b - 4.0).abs() < 1e-9, "{a} {b}");
        let mut neg = Extent::default();
        neg.add(-1.0);
        assert_eq!(neg.log_padded(0.1), None);
    }

    #[test]
    fn series_breaks_at_unshowable_points_and_writes_no_nan() {
        let p = Panel::new((50.0, 20.0, 200.0, 100.0), (0.1, 10.0), (0.0, 1.0), true);
        let mut svg = Svg::new(300.0, 160.0, "t");
        p.axes(
            &mut svg,
            &Labels {
                title: "t",
                x: "w1",
                y: "y",
            },
        );
        p.series(
            &mut svg,
            &[
                (0.1, 0.1),
                (1.0, f64::NAN),
                (2.0, 0.5),
                (5.0, 0.7),
                (-1.0, 0.2),
            ],
            "#000",
            2.0,
            false,
        );
        p.error_bars(&mut svg, &[(1.0, 0.5, f64::NAN), (2.0, 0.5, 0.1)], "#000");
        p.band(
            &mut svg,
            &[(0.2, 0.1), (0.3, f64::INFINITY), (0.4, 0.3), (0.5, 0.4)],
            &[(0.2, 0.0), (0.3, 0.0), (0.4, 0.1), (0.5, 0.2)],
            "#00f",
            0.2,
        );
        let out = svg.finish(true);
        assert!(!out.contains("NaN") && !out.contains("inf"), "{out}");
        assert_eq!(out.matches("<polyline").count(), 1);
        assert_eq!(out.matches("<polygon").count(), 1);
    }

    #[test]
    fn ramp_spans_dark_to_light() {
        assert_eq!(ramp(0.0), "#440154");
        assert_eq!(ramp(1.0), "#fde725");
        assert_eq!(ramp(f64::NAN), "#440154");
    }
}
