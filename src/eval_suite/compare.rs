//! Two results side by side (two suites' results.json, or two single results'
//! report.json): every statistic with its change, absolute and relative, and the
//! regressions beyond a tolerance. Every statistic compared is an error: lower is better.

use super::{SuiteError, SUITE_SCHEMA, SUITE_SCHEMA_VERSION};
use serde::Serialize;
use serde_json::{json, Value};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use stride_eval::summary::{RESULT_SCHEMA, RESULT_SCHEMA_VERSION};

/// The statistics compared, as keys of a single result.
pub const STATISTICS: [&str; 6] = ["rmse", "mean", "median", "std", "max", "rot_deg_rmse"];

/// One statistic of one entry in both results.
#[derive(Debug, Clone, Serialize)]
pub struct Row {
    /// The entry (`result` for a single result).
    pub entry: String,
    /// `ate` or `rpe`.
    pub metric: String,
    /// The statistic (a key of the result: `rmse`, `rot_deg_rmse`, ...).
    pub statistic: String,
    /// Its value in the base (m or degrees).
    pub base: f64,
    /// Its value in the new result.
    pub new: f64,
}

impl Row {
    /// `new - base`.
    pub fn change(&self) -> f64 {
        self.new - self.base
    }

    /// The change in percent of the base (infinite when the base is 0 and the new is not).
    pub fn change_pct(&self) -> f64 {
        if self.base == 0.0 {
            if self.new == 0.0 {
                0.0
            } else {
                f64::INFINITY * self.change().signum()
            }
        } else {
            100.0 * self.change() / self.base.abs()
        }
    }

    /// Whether it got worse by more than `pct` percent (a NaN new value always is).
    pub fn regressed(&self, pct: f64) -> bool {
        self.new.is_nan() || self.change_pct() > pct
    }
}

/// Two results compared.
#[derive(Debug, Clone, Serialize)]
pub struct Comparison {
    /// Where the base came from.
    pub base: PathBuf,
    /// Where the new result came from.
    pub new: PathBuf,
    /// Every statistic of every entry present in both.
    pub rows: Vec<Row>,
    /// Entries (`name (metric)`) in the base and not in the new result.
    pub missing: Vec<String>,
    /// Entries in the new result and not in the base.
    pub added: Vec<String>,
}

/// One entry of a results file: name, metric, single result.
type Entry = (String, String, Value);

/// Reads a results file: a suite's results.json, or a single result's report.json (schema
/// version 0, which had no `schema` key, or 1); a folder means the one it holds.
pub fn load(path: &Path) -> Result<Vec<Entry>, SuiteError> {
    let file = if path.is_dir() {
        let suite = path.join("results.json");
        if suite.is_file() {
            suite
        } else {
            path.join("report.json")
        }
    } else {
        path.to_path_buf()
    };
    let err = |message: String| SuiteError::Results {
        path: file.display().to_string(),
        message,
    };
    let text = std::fs::read_to_string(&file).map_err(|e| err(e.to_string()))?;
    let v: Value = serde_json::from_str(&text).map_err(|e| err(format!("not JSON: {e}")))?;
    let version = v.get("schema_version").and_then(Value::as_u64).unwrap_or(0);
    match v.get("schema").and_then(Value::as_str) {
        Some(SUITE_SCHEMA) => {
            if version > SUITE_SCHEMA_VERSION {
                return Err(err(format!(
                    "suite schema version {version} is newer than this stride's ({SUITE_SCHEMA_VERSION})"
                )));
            }
            let entries = v
                .get("entries")
                .and_then(Value::as_array)
                .ok_or_else(|| err("no entries".into()))?;
            entries
                .iter()
                .map(|e| {
                    let name = e.get("name").and_then(Value::as_str);
                    let metric = e.get("metric").and_then(Value::as_str);
                    match (name, metric, e.get("result")) {
                        (Some(n), Some(m), Some(r)) => Ok((n.to_owned(), m.to_owned(), r.clone())),
                        _ => Err(err("an entry lacks its name, metric or result".into())),
                    }
                })
                .collect()
        }
        Some(RESULT_SCHEMA) | None => {
            if version > RESULT_SCHEMA_VERSION {
                return Err(err(format!(
                    "result schema version {version} is newer than this stride's ({RESULT_SCHEMA_VERSION})"
                )));
            }
            if v.get("rmse").is_none() {
                return Err(err("not a stride eval result (no rmse)".into()));
            }
            // Version 0 did not name the metric: only RPE results have a delta.
            let metric = match v.get("metric").and_then(Value::as_str) {
                Some(m) => m.to_owned(),
                None if v.get("delta").is_some() => "rpe".to_owned(),
                None => "ate".to_owned(),
            };
            Ok(vec![("result".to_owned(), metric, v)])
        }
        Some(other) => Err(err(format!("unknown schema '{other}'"))),
    }
}

/// Compares the results at `base` and `new` (files or folders, see [`load`]).
pub fn compare(base: &Path, new: &Path) -> Result<Comparison, SuiteError> {
    let (b, n) = (load(base)?, load(new)?);
    let key = |e: &Entry| format!("{} ({})", e.0, e.1);
    let mut rows = Vec::new();
    let mut missing = Vec::new();
    for be in &b {
        let Some(ne) = n.iter().find(|ne| ne.0 == be.0 && ne.1 == be.1) else {
            missing.push(key(be));
            continue;
        };
        for s in STATISTICS {
            let get = |r: &Value| r.get(s).and_then(Value::as_f64).unwrap_or(f64::NAN);
            let (bv, nv) = (get(&be.2), get(&ne.2));
            if bv.is_nan() && nv.is_nan() {
                continue;
            }
            rows.push(Row {
                entry: be.0.clone(),
                metric: be.1.clone(),
                statistic: s.to_owned(),
                base: bv,
                new: nv,
            });
        }
    }
    let added = n
        .iter()
        .filter(|ne| !b.iter().any(|be| be.0 == ne.0 && be.1 == ne.1))
        .map(key)
        .collect();
    Ok(Comparison {
        base: base.to_path_buf(),
        new: new.to_path_buf(),
        rows,
        missing,
        added,
    })
}

impl Comparison {
    /// The rows worse by more than `pct` percent.
    pub fn regressions(&self, pct: f64) -> Vec<&Row> {
        self.rows.iter().filter(|r| r.regressed(pct)).collect()
    }

    /// A Markdown table of every row, regressions beyond `tolerance_pct` marked.
    pub fn markdown(&self, tolerance_pct: f64) -> String {
        let worse = self.regressions(tolerance_pct).len();
        let mut md = format!(
            "### stride eval compare: {} statistics, {worse} worse by more than {tolerance_pct} %\n\nbase {}, new {}\n\n| entry | metric | statistic | base | new | change | change % | |\n|---|---|---|---:|---:|---:|---:|---|\n",
            self.rows.len(),
            self.base.display(),
            self.new.display()
        );
        for r in &self.rows {
            let _ = writeln!(
                md,
                "| {} | {} | {} | {:.6} | {:.6} | {:+.6} | {:+.1} | {} |",
                r.entry.replace('|', "\\|"),
                r.metric.to_uppercase(),
                r.statistic,
                r.base,
                r.new,
                r.change(),
                r.change_pct(),
                if r.regressed(tolerance_pct) {
                    "**regression**"
                } else {
                    ""
                }
            );
        }
        for m in &self.missing {
            let _ = writeln!(md, "\nmissing from the new result: {m}");
        }
        for a in &self.added {
            let _ = writeln!(md, "\nnew in the new result: {a}");
        }
        md
    }

    /// The comparison as JSON, with each row's change and whether it regressed beyond
    /// `tolerance_pct`.
    pub fn to_json(&self, tolerance_pct: f64) -> Value {
        let rows: Vec<Value> = self
            .rows
            .iter()
            .map(|r| {
                json!({"entry": r.entry, "metric": r.metric, "statistic": r.statistic,
                       "base": r.base, "new": r.new, "change": r.change(),
                       "change_pct": r.change_pct(), "regression": r.regressed(tolerance_pct)})
            })
            .collect();
        json!({
            "schema": "stride-eval-compare",
            "schema_version": 1,
            "base": self.base.display().to_string(),
            "new": self.new.display().to_string(),
            "tolerance_pct": tolerance_pct,
            "rows": rows,
            "missing": self.missing,
            "added": self.added,
        })
    }
}
