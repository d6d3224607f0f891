//! Small, dependency-free SVG charts for reports: line series, scatter markers and a path
//! coloured by a value (with its colour bar), on axes with readable ticks.
//!
//! Output is deterministic (same input, same bytes) so reports can be diffed.

use std::fmt::Write as _;

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Style {
    /// A polyline through the points.
    Line,
    /// A dashed polyline.
    Dashed,
    /// A small circle at each point.
    Markers,
}

/// A named data series in chart units.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend text.
    pub label: String,
    /// `(x, y)` points; non-finite points break the line.
    pub points: Vec<(f64, f64)>,
    /// CSS colour.
    pub color: String,
    /// Line or markers.
    pub style: Style,
}

impl Series {
    /// A solid line series.
    pub fn line(label: impl Into<String>, color: &str, points: Vec<(f64, f64)>) -> Self {
        Self {
            label: label.into(),
            points,
            color: color.to_owned(),
            style: Style::Line,
        }
    }

    /// The same series with another style.
    pub fn with_style(mut self, style: Style) -> Self {
        self.style = style;
        self
    }
}

/// A path whose segments are coloured by a value (e.g. the position error along a trajectory).
#[derive(Debug, Clone, PartialEq)]
pub struct ColoredPath {
    /// Legend / colour-bar title.
    pub label: String,
    /// `(x, y)` points in chart units.
    pub points: Vec<(f64, f64)>,
    /// One value per point (the segment from `i` to `i+1` takes the mean of both).
    pub values: Vec<f64>,
}

/// An image laid on the chart's axes (a map seen from above), coloured by viridis over a
/// value range that the chart's colour bar shows.
#[derive(Debug, Clone, PartialEq)]
pub struct Raster {
    /// Colour-bar title (with unit).
    pub label: String,
    /// PNG bytes, top row at `extent`'s largest y.
    pub png: Vec<u8>,
    /// `(x_min, x_max, y_min, y_max)` the image covers, in chart units.
    pub extent: (f64, f64, f64, f64),
    /// The values of the colour map's ends (dark, yellow).
    pub range: (f64, f64),
}

/// One chart panel.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Chart {
    /// Title above the panel.
    pub title: String,
    /// X axis label (with unit).
    pub x_label: String,
    /// Y axis label (with unit).
    pub y_label: String,
    /// Series drawn in order (later ones on top).
    pub series: Vec<Series>,
    /// An optional value-coloured path, drawn above the series, with a colour bar.
    pub colored: Option<ColoredPath>,
    /// An optional image under everything, with its colour bar (which replaces the
    /// coloured path's).
    pub raster: Option<Raster>,
    /// Same scale on both axes (for maps and trajectories seen from above).
    pub equal_aspect: bool,
    /// Include y = 0 in the range (for error plots).
    pub y_from_zero: bool,
}

/// Palette for series, colour-blind safe (Okabe-Ito).
pub const PALETTE: [&str; 7] = [
    "#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000",
];

/// Escapes text for SVG/HTML.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// "Nice" tick positions covering `[lo, hi]`, about `target` of them.
pub fn nice_ticks(lo: f64, hi: f64, target: usize) -> (Vec<f64>, f64) {
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo {
        return (vec![lo], 1.0);
    }
    let raw = (hi - lo) / target.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 2.5, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let first = (lo / step).ceil() * step;
    let mut ticks = Vec::new();
    let mut k = 0.0;
    while first + k * step <= hi + step * 1e-9 && ticks.len() < 50 {
        ticks.push(first + k * step);
        k += 1.0;
    }
    (ticks, step)
}

fn tick_label(v: f64, step: f64) -> String {
    // As many decimals as the step needs (0.25 -> 2, 5 -> 0).
    let decimals = (0..=9)
        .find(|&d| {
            let scaled = step * 10f64.powi(d);
            (scaled - scaled.round()).abs() < 1e-6 * scaled.abs().max(1.0)
        })
        .unwrap_or(9) as usize;
    let s = format!("{v:.decimals$}");
    match s.strip_prefix('-') {
        Some(rest) if rest.chars().all(|c| c == '0' || c == '.') => rest.to_owned(),
        _ => s,
    }
}

pub use stride_output::colormap::viridis;

struct Frame {
    x: f64,
    y: f64,
    w: f64,
    h: f64,
    xmin: f64,
    xmax: f64,
    ymin: f64,
    ymax: f64,
}

impl Frame {
    fn px(&self, x: f64, y: f64) -> (f64, f64) {
        (
            self.x + (x - self.xmin) / (self.xmax - self.xmin) * self.w,
            self.y + self.h - (y - self.ymin) / (self.ymax - self.ymin) * self.h,
        )
    }
}

fn extent(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    values
        .filter(|v| v.is_finite())
        .fold(None, |acc, v| match acc {
            None => Some((v, v)),
            Some((a, b)) => Some((a.min(v), b.max(v))),
        })
}

fn padded(lo: f64, hi: f64) -> (f64, f64) {
    if hi > lo {
        let pad = (hi - lo) * 0.04;
        (lo - pad, hi + pad)
    } else {
        let pad = if lo == 0.0 { 1.0 } else { lo.abs() * 0.1 };
        (lo - pad, hi + pad)
    }
}

fn polyline(out: &mut String, f: &Frame, pts: &[(f64, f64)], color: &str, dashed: bool) {
    let mut run: Vec<(f64, f64)> = Vec::new();
    let flush = |out: &mut String, run: &mut Vec<(f64, f64)>| {
        if run.len() >= 2 {
            let d: Vec<String> = run.iter().map(|(x, y)| format!("{x:.1},{y:.1}")).collect();
            let _ = write!(
                out,
                r#"<polyline fill="none" stroke="{color}" stroke-width="1.6"{} points="{}"/>"#,
                if dashed {
                    r#" stroke-dasharray="5,3""#
                } else {
                    ""
                },
                d.join(" ")
            );
        }
        run.clear();
    };
    for &(x, y) in pts {
        if x.is_finite() && y.is_finite() {
            run.push(f.px(x, y));
        } else {
            flush(out, &mut run);
        }
    }
    flush(out, &mut run);
}

impl Chart {
    /// Draws the chart into the rectangle `(x, y, w, h)` (pixels) of an SVG being built.
    pub fn render_into(&self, out: &mut String, x: f64, y: f64, w: f64, h: f64) {
        let colorbar_w = if self.colored.is_some() || self.raster.is_some() {
            74.0
        } else {
            0.0
        };
        let (ml, mr, mt, mb) = (62.0, 14.0 + colorbar_w, 30.0, 44.0);
        let mut f = Frame {
            x: x + ml,
            y: y + mt,
            w: (w - ml - mr).max(10.0),
            h: (h - mt - mb).max(10.0),
            xmin: 0.0,
            xmax: 1.0,
            ymin: 0.0,
            ymax: 1.0,
        };
        let all_pts = self
            .series
            .iter()
            .flat_map(|s| s.points.iter().copied())
            .chain(self.colored.iter().flat_map(|c| c.points.iter().copied()))
            .chain(self.raster.iter().flat_map(|r| {
                let (x0, x1, y0, y1) = r.extent;
                [(x0, y0), (x1, y1)]
            }));
        let pts: Vec<(f64, f64)> = all_pts.collect();
        let (x0, x1) = extent(pts.iter().map(|p| p.0)).unwrap_or((0.0, 1.0));
        let (mut y0, y1) = extent(pts.iter().map(|p| p.1)).unwrap_or((0.0, 1.0));
        if self.y_from_zero {
            y0 = y0.min(0.0);
        }
        let (mut x0, mut x1) = padded(x0, x1);
        let (mut y0, mut y1) = padded(y0, y1);
        if self.y_from_zero && y0 < 0.0 && pts.iter().all(|p| p.1.is_nan() || p.1 >= 0.0) {
            y0 = 0.0;
        }
        if self.equal_aspect {
            let sx = (x1 - x0) / f.w;
            let sy = (y1 - y0) / f.h;
            let s = sx.max(sy);
            let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
            x0 = cx - s * f.w / 2.0;
            x1 = cx + s * f.w / 2.0;
            y0 = cy - s * f.h / 2.0;
            y1 = cy + s * f.h / 2.0;
        }
        (f.xmin, f.xmax, f.ymin, f.ymax) = (x0, x1, y0, y1);

        // Frame, grid and ticks.
        let _ = write!(
            out,
            r##"<rect x="{:.1}" y="{:.1}" width="{:.1}" height="{:.1}" fill="#fff" stroke="#888"/>"##,
            f.x, f.y, f.w, f.h
        );
        let (xt, xs) = nice_ticks(x0, x1, 6);
        for t in &xt {
            let (px, _) = f.px(*t, y0);
            let _ = write!(
                out,
                r##"<line x1="{px:.1}" y1="{:.1}" x2="{px:.1}" y2="{:.1}" stroke="#e4e4e4"/><text x="{px:.1}" y="{:.1}" font-size="11" text-anchor="middle" fill="#333">{}</text>"##,
                f.y,
                f.y + f.h,
                f.y + f.h + 15.0,
                tick_label(*t, xs)
            );
        }
        let (yt, ys) = nice_ticks(y0, y1, 5);
        for t in &yt {
            let (_, py) = f.px(x0, *t);
            let _ = write!(
                out,
                r##"<line x1="{:.1}" y1="{py:.1}" x2="{:.1}" y2="{py:.1}" stroke="#e4e4e4"/><text x="{:.1}" y="{:.1}" font-size="11" text-anchor="end" fill="#333">{}</text>"##,
                f.x,
                f.x + f.w,
                f.x - 5.0,
                py + 4.0,
                tick_label(*t, ys)
            );
        }
        let _ = write!(
            out,
            r##"<text x="{:.1}" y="{:.1}" font-size="13" font-weight="bold" fill="#222">{}</text>"##,
            f.x,
            y + 18.0,
            escape(&self.title)
        );
        let _ = write!(
            out,
            r##"<text x="{:.1}" y="{:.1}" font-size="12" text-anchor="middle" fill="#222">{}</text>"##,
            f.x + f.w / 2.0,
            y + h - 8.0,
            escape(&self.x_label)
        );
        let _ = write!(
            out,
            r##"<text transform="translate({:.1},{:.1}) rotate(-90)" font-size="12" text-anchor="middle" fill="#222">{}</text>"##,
            x + 14.0,
            f.y + f.h / 2.0,
            escape(&self.y_label)
        );

        // Data, clipped to the frame.
        let clip_id = format!("clip{}x{}", x as i64, y as i64);
        let _ = write!(
            out,
            r#"<clipPath id="{clip_id}"><rect x="{:.1}" y="{:.1}" width="{:.1}" height="{:.1}"/></clipPath><g clip-path="url(#{clip_id})">"#,
            f.x, f.y, f.w, f.h
        );
        if let Some(r) = &self.raster {
            use base64::Engine as _;
            let (x0, x1, y0, y1) = r.extent;
            let ((a0, b0), (a1, b1)) = (f.px(x0, y1), f.px(x1, y0));
            let _ = write!(
                out,
                r#"<image x="{a0:.1}" y="{b0:.1}" width="{:.1}" height="{:.1}" preserveAspectRatio="none" style="image-rendering:pixelated" href="data:image/png;base64,{}"/>"#,
                a1 - a0,
                b1 - b0,
                base64::engine::general_purpose::STANDARD.encode(&r.png)
            );
        }
        for s in &self.series {
            match s.style {
                Style::Line => polyline(out, &f, &s.points, &s.color, false),
                Style::Dashed => polyline(out, &f, &s.points, &s.color, true),
                Style::Markers => {
                    for &(px, py) in &s.points {
                        if px.is_finite() && py.is_finite() {
                            let (a, b) = f.px(px, py);
                            let _ = write!(
                                out,
                                r#"<circle cx="{a:.1}" cy="{b:.1}" r="2.2" fill="{}"/>"#,
                                s.color
                            );
                        }
                    }
                }
            }
        }
        let mut value_range = None;
        if let Some(c) = &self.colored {
            if let Some((vmin, vmax)) = extent(c.values.iter().copied()) {
                let span = if vmax > vmin { vmax - vmin } else { 1.0 };
                for (k, w2) in c.points.windows(2).enumerate() {
                    let v = (c.values.get(k).copied().unwrap_or(vmin)
                        + c.values.get(k + 1).copied().unwrap_or(vmin))
                        / 2.0;
                    let (r, g, b) = viridis((v - vmin) / span);
                    let ((a0, b0), (a1, b1)) = (f.px(w2[0].0, w2[0].1), f.px(w2[1].0, w2[1].1));
                    if [a0, b0, a1, b1].iter().all(|v| v.is_finite()) {
                        let _ = write!(
                            out,
                            r#"<line x1="{a0:.1}" y1="{b0:.1}" x2="{a1:.1}" y2="{b1:.1}" stroke="rgb({r},{g},{b})" stroke-width="2.4" stroke-linecap="round"/>"#
                        );
                    }
                }
                value_range = Some((vmin, vmax));
            }
        }
        out.push_str("</g>");

        // Legend.
        let mut ly = f.y + 14.0;
        let mut entries: Vec<(&str, String, Style)> = self
            .series
            .iter()
            .filter(|s| !s.label.is_empty())
            .map(|s| (s.label.as_str(), s.color.clone(), s.style))
            .collect();
        if let Some(c) = &self.colored {
            entries.push((c.label.as_str(), "rgb(33,144,141)".to_owned(), Style::Line));
        }
        // A light backdrop, so that the entries stay readable over a map or dense lines.
        if let Some(longest) = entries.iter().map(|(l, _, _)| l.chars().count()).max() {
            let _ = write!(
                out,
                r##"<rect class="legend" x="{:.1}" y="{:.1}" width="{:.1}" height="{:.1}" rx="3" fill="#ffffff" fill-opacity="0.8"/>"##,
                f.x + 4.0,
                f.y + 2.0,
                30.0 + 6.2 * longest as f64,
                15.0 * entries.len() as f64 + 4.0
            );
        }
        for (label, color, style) in entries {
            let lx = f.x + 8.0;
            match style {
                Style::Markers => {
                    let _ = write!(
                        out,
                        r#"<circle cx="{:.1}" cy="{:.1}" r="3" fill="{color}"/>"#,
                        lx + 9.0,
                        ly - 4.0
                    );
                }
                _ => {
                    let _ = write!(
                        out,
                        r#"<line x1="{lx:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="{color}" stroke-width="2.4"{}/>"#,
                        ly - 4.0,
                        lx + 18.0,
                        ly - 4.0,
                        if style == Style::Dashed {
                            r#" stroke-dasharray="5,3""#
                        } else {
                            ""
                        }
                    );
                }
            }
            let _ = write!(
                out,
                r##"<text x="{:.1}" y="{ly:.1}" font-size="11" fill="#222">{}</text>"##,
                lx + 24.0,
                escape(label)
            );
            ly += 15.0;
        }

        // Colour bar: the raster's, else the coloured path's.
        let bar = match (&self.raster, &self.colored, value_range) {
            (Some(r), _, _) => Some((r.label.as_str(), r.range)),
            (None, Some(c), Some(range)) => Some((c.label.as_str(), range)),
            _ => None,
        };
        if let Some((label, (vmin, vmax))) = bar {
            let bx = f.x + f.w + 14.0;
            let (bw, bh) = (12.0, f.h);
            let steps = 32;
            for i in 0..steps {
                let t0 = i as f64 / steps as f64;
                let (r, g, b) = viridis(1.0 - t0 - 0.5 / steps as f64);
                let _ = write!(
                    out,
                    r#"<rect x="{bx:.1}" y="{:.1}" width="{bw:.1}" height="{:.2}" fill="rgb({r},{g},{b})"/>"#,
                    f.y + t0 * bh,
                    bh / steps as f64 + 0.5
                );
            }
            let _ = write!(
                out,
                r##"<rect x="{bx:.1}" y="{:.1}" width="{bw:.1}" height="{bh:.1}" fill="none" stroke="#888"/>"##,
                f.y
            );
            let (vt, vs) = nice_ticks(vmin, vmax.max(vmin + 1e-12), 4);
            for t in vt {
                let py = f.y + bh - (t - vmin) / (vmax - vmin).max(1e-12) * bh;
                let _ = write!(
                    out,
                    r##"<text x="{:.1}" y="{:.1}" font-size="10" fill="#333">{}</text>"##,
                    bx + bw + 3.0,
                    py + 3.5,
                    tick_label(t, vs)
                );
            }
            let _ = write!(
                out,
                r##"<text transform="translate({:.1},{:.1}) rotate(-90)" font-size="11" text-anchor="middle" fill="#222">{}</text>"##,
                bx + bw + 40.0,
                f.y + bh / 2.0,
                escape(label)
            );
        }
    }
}

/// Renders charts side by side in a grid of `columns`, each panel `panel_w` x `panel_h`
/// pixels, as a standalone SVG document.
pub fn render(charts: &[Chart], columns: usize, panel_w: f64, panel_h: f64) -> String {
    let columns = columns.max(1);
    let rows = charts.len().div_ceil(columns).max(1);
    let (w, h) = (panel_w * columns as f64, panel_h * rows as f64);
    let mut out = String::new();
    let _ = write!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w:.0}" height="{h:.0}" viewBox="0 0 {w:.0} {h:.0}" font-family="Helvetica, Arial, sans-serif">"#
    );
    out.push_str(r##"<rect width="100%" height="100%" fill="#fafafa"/>"##);
    for (k, c) in charts.iter().enumerate() {
        let (col, row) = (k % columns, k / columns);
        c.render_into(
            &mut out,
            col as f64 * panel_w,
            row as f64 * panel_h,
            panel_w,
            panel_h,
        );
    }
    out.push_str("</svg>\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_numbers_inside_the_range() {
        let (t, s) = nice_ticks(0.013, 0.087, 5);
        assert_eq!(s, 0.02);
        assert!(t.first().unwrap() >= &0.013 && t.last().unwrap() <= &0.087);
        assert_eq!(tick_label(0.04, 0.02), "0.04");
        assert_eq!(tick_label(2.5, 2.5), "2.5");
        assert_eq!(tick_label(-0.0, 0.5), "0.0");
        assert_eq!(tick_label(1500.0, 500.0), "1500");
    }

    #[test]
    fn renders_a_deterministic_svg_with_all_parts() {
        let chart = Chart {
            title: "T <1>".into(),
            x_label: "x (m)".into(),
            y_label: "y (m)".into(),
            series: vec![Series::line(
                "gt",
                PALETTE[0],
                vec![(0.0, 0.0), (1.0, 1.0), (f64::NAN, 0.0), (2.0, 0.0)],
            )],
            colored: Some(ColoredPath {
                label: "error (m)".into(),
                points: vec![(0.0, 0.1), (1.0, 1.1), (2.0, 0.1)],
                values: vec![0.0, 0.5, 1.0],
            }),
            raster: None,
            equal_aspect: true,
            y_from_zero: false,
        };
        let a = render(&[chart.clone(), Chart::default()], 2, 400.0, 300.0);
        let b = render(&[chart, Chart::default()], 2, 400.0, 300.0);
        assert_eq!(a, b);
        assert!(a.starts_with("<svg") && a.trim_end().ends_with("</svg>"));
        assert!(a.contains("T &lt;1&gt;"));
        assert!(a.contains("<polyline") && a.contains("stroke=\"rgb("));
        assert_eq!(viridis(0.0), (68, 1, 84));
        assert_eq!(viridis(1.0), (253, 231, 37));
    }

    #[test]
    fn a_raster_is_embedded_on_its_extent_with_its_own_colour_bar() {
        let chart = Chart {
            series: vec![Series::line(
                "path",
                PALETTE[1],
                vec![(0.5, 0.5), (1.0, 1.0)],
            )],
            raster: Some(Raster {
                label: "height (m)".into(),
                png: b"png".to_vec(),
                extent: (0.0, 2.0, 0.0, 1.0),
                range: (0.25, 0.75),
            }),
            ..Chart::default()
        };
        let svg = render(&[chart], 1, 400.0, 300.0);
        // The PNG's bytes as a data URI ("png" in base64), and the bar's title and ends.
        assert!(svg.contains("href=\"data:image/png;base64,cG5n\""), "{svg}");
        // The legend sits on a backdrop drawn after the raster, so it stays readable.
        let (image, backdrop) = (svg.find("<image"), svg.find("<rect class=\"legend\""));
        assert!(image.is_some() && backdrop > image, "{svg}");
        assert!(svg.contains("height (m)"));
        assert!(svg.contains(">0.4<") || svg.contains(">0.5<"), "{svg}");
        // On equal axes the image would span twice as wide as high; here it just has a size.
        let attr = |name: &str| -> f64 {
            let i = svg.find("<image").unwrap();
            let rest = &svg[i..];
            let k = rest.find(&format!(" {name}=\"")).unwrap() + name.len() + 3;
            rest[k..].split('"').next().unwrap().parse().unwrap()
        };
        let (w, h) = (attr("width"), attr("height"));
        assert!(w > 0.0 && h > 0.0);
    }
}
