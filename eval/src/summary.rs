//! Presenting results: the JSON objects of `stride eval --json`, terminal tables, charts and
//! report sections.

use crate::ate::AteResult;
use crate::plot::{render, Chart, ColoredPath, Series, Style, PALETTE};
use crate::report::Report;
use crate::rpe::RpeResult;
use crate::stats::Statistics;
use serde_json::{json, Map, Value};
use std::fmt::Write as _;

/// The name of a single result's JSON schema (`stride eval ate|rpe --json`, report.json).
pub const RESULT_SCHEMA: &str = "stride-eval-result";
/// Its version: 1 added `schema`, `schema_version` and `metric` to version 0's keys, which
/// are unchanged (docs/evaluation.md).
pub const RESULT_SCHEMA_VERSION: u64 = 1;

/// The schema's name and version, and the metric (`ate`, `rpe`).
fn schema_header(metric: &str) -> Map<String, Value> {
    let mut m = Map::new();
    m.insert("schema".into(), json!(RESULT_SCHEMA));
    m.insert("schema_version".into(), json!(RESULT_SCHEMA_VERSION));
    m.insert("metric".into(), json!(metric));
    m
}

fn put_stats(map: &mut Map<String, Value>, prefix: &str, s: &Statistics) {
    for (k, v) in s.rows() {
        map.insert(format!("{prefix}{k}"), json!(v));
    }
    if prefix.is_empty() {
        map.insert("count".into(), json!(s.count));
    }
}

fn stats_table(columns: &[(&str, &Statistics)]) -> String {
    let mut t = format!("{:>8}", "");
    for (name, _) in columns {
        let _ = write!(t, "{name:>18}");
    }
    t.push('\n');
    for (k, row) in ["rmse", "mean", "median", "std", "min", "max", "sse"]
        .iter()
        .enumerate()
    {
        let _ = write!(t, "{row:>8}");
        for (_, s) in columns {
            let v = s.rows().get(k).map_or(f64::NAN, |r| r.1);
            let _ = write!(t, "{v:>18.6}");
        }
        t.push('\n');
    }
    t
}

impl AteResult {
    /// The `stride eval ate --json` object: `rmse, mean, median, std, min, max, sse, count`
    /// of the position error (m), `align`, `preset`, the association window `t_max_diff`
    /// (s) and `offset` (s), the alignment's `scale`, and the orientation error statistics
    /// as `rot_deg_rmse`, `rot_deg_mean`, ...
    pub fn to_json(&self) -> Value {
        let mut m = schema_header("ate");
        put_stats(&mut m, "", &self.trans_m);
        m.insert("align".into(), json!(self.options.align.to_string()));
        m.insert("preset".into(), json!(self.options.preset.to_string()));
        m.insert("t_max_diff".into(), json!(self.options.t_max_diff_s));
        m.insert("offset".into(), json!(self.options.offset_s));
        m.insert("scale".into(), json!(self.alignment.scale));
        put_stats(&mut m, "rot_deg_", &self.rot_deg);
        Value::Object(m)
    }

    /// A readable multi-line table of the statistics.
    pub fn table(&self) -> String {
        let o = &self.options;
        let mut t = format!(
            "ATE  preset {}  align {}  pairs {}  t_max_diff {} s{}\n",
            o.preset,
            o.align,
            self.trans_m.count,
            o.t_max_diff_s,
            if o.align == crate::options::Align::Sim3 {
                format!("  scale {:.6}", self.alignment.scale)
            } else {
                String::new()
            }
        );
        t.push_str(&stats_table(&[
            ("translation (m)", &self.trans_m),
            ("rotation (deg)", &self.rot_deg),
        ]));
        t
    }

    /// Two panels: the trajectories seen from above (world x-y, ground truth grey, estimate
    /// coloured by position error) and the position error over time.
    pub fn chart_svg(&self) -> String {
        let t0 = self.stamps_s.first().copied().unwrap_or(0.0);
        let top = Chart {
            title: "Trajectories from above (x-y)".into(),
            x_label: "x (m)".into(),
            y_label: "y (m)".into(),
            series: vec![Series::line(
                "ground truth",
                "#888",
                self.gt_positions.iter().map(|p| (p.x, p.y)).collect(),
            )
            .with_style(Style::Dashed)],
            colored: Some(ColoredPath {
                label: "estimate, error (m)".into(),
                points: self.est_positions.iter().map(|p| (p.x, p.y)).collect(),
                values: self.errors_m.clone(),
            }),
            raster: None,
            equal_aspect: true,
            y_from_zero: false,
        };
        let over_time = Chart {
            title: format!("ATE over time (rmse {:.4} m)", self.trans_m.rmse),
            x_label: "time since first pair (s)".into(),
            y_label: "position error (m)".into(),
            series: vec![
                Series::line(
                    "error",
                    PALETTE[0],
                    self.stamps_s
                        .iter()
                        .zip(&self.errors_m)
                        .map(|(t, e)| (t - t0, *e))
                        .collect(),
                ),
                Series::line(
                    "rmse",
                    PALETTE[1],
                    vec![
                        (0.0, self.trans_m.rmse),
                        (
                            self.stamps_s.last().map_or(0.0, |t| t - t0),
                            self.trans_m.rmse,
                        ),
                    ],
                )
                .with_style(Style::Dashed),
            ],
            colored: None,
            raster: None,
            equal_aspect: false,
            y_from_zero: true,
        };
        render(&[top, over_time], 2, 560.0, 420.0)
    }

    /// Adds a section with the table and the chart to a report.
    pub fn add_to_report(&self, report: &mut Report, figure_name: &str) {
        let o = &self.options;
        report.heading("Absolute trajectory error (ATE)");
        report.paragraph(format!(
            "Preset {} (association within {} s{}), alignment {}{}; {} associated pose pairs.",
            o.preset,
            o.t_max_diff_s,
            if o.offset_s != 0.0 {
                format!(", offset {} s", o.offset_s)
            } else {
                String::new()
            },
            o.align,
            if o.align == crate::options::Align::Sim3 {
                format!(" (scale {:.6})", self.alignment.scale)
            } else {
                String::new()
            },
            self.trans_m.count
        ));
        report.table(
            &["statistic", "translation (m)", "rotation (deg)"],
            self.trans_m
                .rows()
                .iter()
                .zip(self.rot_deg.rows())
                .map(|((k, a), (_, b))| vec![(*k).to_owned(), format!("{a:.6}"), format!("{b:.6}")])
                .collect(),
        );
        for w in &self.warnings {
            report.paragraph(format!("Warning: {w}"));
        }
        report.figure(figure_name, self.chart_svg(), "Left: trajectories from above, estimate coloured by position error. Right: position error over time.");
    }
}

fn pair_mode(o: &crate::rpe::RpeOptions) -> &'static str {
    match (o.preset, o.all_pairs) {
        (crate::options::Preset::Tum, _) => "a pair from every pose",
        (_, true) => "all pairs",
        (_, false) => "consecutive pairs",
    }
}

impl RpeResult {
    /// The `stride eval rpe --json` object: the translation error statistics (m) with
    /// `count`, `align`, `preset`, `delta`, `unit`, `all_pairs`, and the rotation error
    /// statistics as `rot_deg_*` (degrees) and `rot_chordal_*` (dimensionless).
    pub fn to_json(&self) -> Value {
        let o = &self.options;
        let mut m = schema_header("rpe");
        put_stats(&mut m, "", &self.trans_m);
        m.insert("align".into(), json!(o.align.to_string()));
        m.insert("preset".into(), json!(o.preset.to_string()));
        m.insert("delta".into(), json!(o.delta));
        m.insert("unit".into(), json!(o.unit.to_string()));
        m.insert("all_pairs".into(), json!(o.all_pairs));
        m.insert("t_max_diff".into(), json!(o.t_max_diff_s));
        m.insert("offset".into(), json!(o.offset_s));
        put_stats(&mut m, "rot_deg_", &self.rot_deg);
        put_stats(&mut m, "rot_chordal_", &self.rot_chordal);
        Value::Object(m)
    }

    /// A readable multi-line table of the statistics.
    pub fn table(&self) -> String {
        let o = &self.options;
        let mut t = format!(
            "RPE  preset {}  delta {} {}  {}  align {}  pairs {}\n",
            o.preset,
            o.delta,
            o.unit,
            pair_mode(o),
            o.align,
            self.trans_m.count
        );
        t.push_str(&stats_table(&[
            ("translation (m)", &self.trans_m),
            ("rotation (deg)", &self.rot_deg),
            ("rotation (chord)", &self.rot_chordal),
        ]));
        t
    }

    /// Two panels: translation and rotation error of each pair over time.
    pub fn chart_svg(&self) -> String {
        let t0 = self.pairs.first().map_or(0.0, |p| p.t_s);
        let panel =
            |title: String, y_label: &str, f: fn(&crate::rpe::RpePair) -> f64, color: &str| Chart {
                title,
                x_label: "time of the pair's first pose (s)".into(),
                y_label: y_label.into(),
                series: vec![Series::line(
                    "",
                    color,
                    self.pairs.iter().map(|p| (p.t_s - t0, f(p))).collect(),
                )],
                colored: None,
                raster: None,
                equal_aspect: false,
                y_from_zero: true,
            };
        let per = format!("per {} {}", self.options.delta, self.options.unit);
        render(
            &[
                panel(
                    format!("RPE translation (rmse {:.4} m)", self.trans_m.rmse),
                    &format!("translation error (m) {per}"),
                    |p| p.trans_m,
                    PALETTE[0],
                ),
                panel(
                    format!("RPE rotation (rmse {:.3} deg)", self.rot_deg.rmse),
                    &format!("rotation error (deg) {per}"),
                    |p| p.rot_deg,
                    PALETTE[1],
                ),
            ],
            2,
            560.0,
            380.0,
        )
    }

    /// Adds a section with the table and the chart to a report.
    pub fn add_to_report(&self, report: &mut Report, figure_name: &str) {
        let o = &self.options;
        report.heading("Relative pose error (RPE)");
        report.paragraph(format!(
            "Preset {}, delta {} {} ({}), alignment {}; {} pose pairs.",
            o.preset,
            o.delta,
            o.unit,
            pair_mode(o),
            o.align,
            self.trans_m.count
        ));
        report.table(
            &[
                "statistic",
                "translation (m)",
                "rotation (deg)",
                "rotation (chordal)",
            ],
            self.trans_m
                .rows()
                .iter()
                .zip(self.rot_deg.rows())
                .zip(self.rot_chordal.rows())
                .map(|(((k, a), (_, b)), (_, c))| {
                    vec![
                        (*k).to_owned(),
                        format!("{a:.6}"),
                        format!("{b:.6}"),
                        format!("{c:.6}"),
                    ]
                })
                .collect(),
        );
        for w in &self.warnings {
            report.paragraph(format!("Warning: {w}"));
        }
        report.figure(
            figure_name,
            self.chart_svg(),
            "Translation (left) and rotation (right) error of each pose pair over time.",
        );
    }
}
