//! Trajectory evaluation for CI: a suite of (ground truth, estimate, options, limits)
//! entries run at once ([`run_suite`]), written as one versioned JSON file, a short
//! Markdown summary for a pull request, a JUnit XML file for CI systems and an HTML report
//! ([`SuiteResult`]); and the comparison of two results ([`compare()`]).
//!
//! A suite file (TOML; paths relative to it):
//!
//! ```toml
//! [[entry]]
//! name = "fr1/xyz, SE(3)"       # unique
//! gt = "groundtruth.txt"
//! est = "estimate.txt"
//! metric = "ate"                # or "rpe"
//! align = "se3"                 # se3, sim3, origin, none [default: the preset's]
//! preset = "evo"                # or "tum"
//! t_max_diff = 0.01             # s [default: the preset's]
//! offset = 0.0                  # s
//! delta = 1.0                   # rpe: pair distance [default: the preset's]
//! delta_unit = "frames"         # rpe: frames, seconds, metres
//! all_pairs = false             # rpe
//! max_rmse = 0.02               # limits: m, m, degrees (any subset)
//! max_mean = 0.02
//! max_rot_deg = 2.0
//! ```

pub mod compare;
mod outputs;

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use stride_datasets::trajectory_file::read_tum_trajectory;
use stride_eval::limits::Exceeded;
use stride_eval::{ate, rpe, AteOptions, Limits, Preset, RpeOptions};

pub use compare::{compare, Comparison};

/// The name of a suite result's JSON schema (results.json).
pub const SUITE_SCHEMA: &str = "stride-eval-suite";
/// Its version.
pub const SUITE_SCHEMA_VERSION: u64 = 1;

/// Why a suite could not run.
#[derive(Debug, thiserror::Error)]
pub enum SuiteError {
    /// The suite file could not be read or parsed.
    #[error("suite {path}: {message}")]
    File {
        /// The file.
        path: String,
        /// What is wrong (with the line, for a parse error).
        message: String,
    },
    /// An entry is invalid or its evaluation failed.
    #[error("suite entry '{entry}': {message}")]
    Entry {
        /// The entry's name.
        entry: String,
        /// What is wrong.
        message: String,
    },
    /// A results file could not be read or is not a stride result.
    #[error("{path}: {message}")]
    Results {
        /// The file or folder.
        path: String,
        /// What is wrong.
        message: String,
    },
}

/// A suite file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct SuiteFile {
    entry: Vec<EntrySpec>,
}

/// One entry of a suite file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct EntrySpec {
    name: String,
    gt: PathBuf,
    est: PathBuf,
    metric: String,
    align: Option<String>,
    preset: Option<String>,
    t_max_diff: Option<f64>,
    offset: Option<f64>,
    delta: Option<f64>,
    delta_unit: Option<String>,
    all_pairs: Option<bool>,
    max_rmse: Option<f64>,
    max_mean: Option<f64>,
    max_rot_deg: Option<f64>,
}

/// One evaluated entry.
#[derive(Debug, Clone, Serialize)]
pub struct EntryResult {
    /// Its name.
    pub name: String,
    /// `ate` or `rpe`.
    pub metric: String,
    /// The files, as the suite file gives them.
    pub gt: String,
    /// See `gt`.
    pub est: String,
    /// The single result (`stride eval ate|rpe --json`'s object).
    pub result: serde_json::Value,
    /// Its limits.
    pub limits: Limits,
    /// The limits exceeded (empty: passed).
    pub exceeded: Vec<Exceeded>,
    /// The full result (for the report's charts), not serialized.
    #[serde(skip)]
    detail: Option<Detail>,
}

/// An entry's full result.
#[derive(Debug, Clone)]
enum Detail {
    Ate(Box<stride_eval::AteResult>),
    Rpe(Box<stride_eval::RpeResult>),
}

impl EntryResult {
    /// Whether every limit holds.
    pub fn passed(&self) -> bool {
        self.exceeded.is_empty()
    }

    /// The limits exceeded, one line each, named by their suite-file key.
    pub fn failures(&self) -> Vec<String> {
        let what = self.metric.to_uppercase();
        self.exceeded
            .iter()
            .map(|e| e.describe(&what, str::to_owned))
            .collect()
    }
}

/// A suite's results.
#[derive(Debug, Clone)]
pub struct SuiteResult {
    /// The suite file.
    pub suite: PathBuf,
    /// Every entry, in the file's order.
    pub entries: Vec<EntryResult>,
}

impl SuiteResult {
    /// Entries that exceeded a limit.
    pub fn failed(&self) -> usize {
        self.entries.iter().filter(|e| !e.passed()).count()
    }
}

/// Runs every entry of the suite file at `path`.
pub fn run_suite(path: &Path) -> Result<SuiteResult, SuiteError> {
    let file_err = |message: String| SuiteError::File {
        path: path.display().to_string(),
        message,
    };
    let text = std::fs::read_to_string(path).map_err(|e| file_err(e.to_string()))?;
    let spec: SuiteFile = toml::from_str(&text)
        .map_err(|e| file_err(crate::config::parse_message(&e.to_string())))?;
    if spec.entry.is_empty() {
        return Err(file_err("no [[entry]]".into()));
    }
    let base = path.parent().unwrap_or(Path::new("."));
    let mut names = std::collections::HashSet::new();
    let mut entries = Vec::new();
    for e in spec.entry {
        if !names.insert(e.name.clone()) {
            return Err(file_err(format!("two entries are named '{}'", e.name)));
        }
        entries.push(run_entry(&e, base)?);
    }
    Ok(SuiteResult {
        suite: path.to_path_buf(),
        entries,
    })
}

/// Parses an option value with its `FromStr`, naming the entry and key on failure.
fn parse<T: std::str::FromStr>(entry: &str, key: &str, v: &str) -> Result<T, SuiteError>
where
    T::Err: std::fmt::Display,
{
    v.parse().map_err(|e: T::Err| SuiteError::Entry {
        entry: entry.to_owned(),
        message: format!("{key} = \"{v}\": {e}"),
    })
}

/// Evaluates one entry.
fn run_entry(e: &EntrySpec, base: &Path) -> Result<EntryResult, SuiteError> {
    let err = |message: String| SuiteError::Entry {
        entry: e.name.clone(),
        message,
    };
    let limits = Limits {
        max_rmse: e.max_rmse,
        max_mean: e.max_mean,
        max_rot_deg: e.max_rot_deg,
    };
    limits.validate().map_err(|x| err(x.to_string()))?;
    let preset: Preset = match &e.preset {
        Some(p) => parse(&e.name, "preset", p)?,
        None => Preset::Evo,
    };
    let load = |p: &Path| read_tum_trajectory(&base.join(p)).map_err(|x| err(x.to_string()));
    let (gt, est) = (load(&e.gt)?, load(&e.est)?);
    let (result, trans, rot, detail) = match e.metric.as_str() {
        "ate" => {
            let mut o = AteOptions::for_preset(preset);
            if let Some(a) = &e.align {
                o.align = parse(&e.name, "align", a)?;
            }
            o.t_max_diff_s = e.t_max_diff.unwrap_or(o.t_max_diff_s);
            o.offset_s = e.offset.unwrap_or(0.0);
            let r = ate(&gt, &est, &o).map_err(|x| err(x.to_string()))?;
            (r.to_json(), r.trans_m, r.rot_deg, Detail::Ate(Box::new(r)))
        }
        "rpe" => {
            let mut o = RpeOptions::for_preset(preset);
            if let Some(a) = &e.align {
                o.align = parse(&e.name, "align", a)?;
            }
            o.t_max_diff_s = e.t_max_diff.unwrap_or(o.t_max_diff_s);
            o.offset_s = e.offset.unwrap_or(0.0);
            o.delta = e.delta.unwrap_or(o.delta);
            if let Some(u) = &e.delta_unit {
                o.unit = parse(&e.name, "delta_unit", u)?;
            }
            o.all_pairs = e.all_pairs.unwrap_or(false);
            let r = rpe(&gt, &est, &o).map_err(|x| err(x.to_string()))?;
            (r.to_json(), r.trans_m, r.rot_deg, Detail::Rpe(Box::new(r)))
        }
        other => return Err(err(format!("metric = \"{other}\": ate or rpe"))),
    };
    Ok(EntryResult {
        name: e.name.clone(),
        metric: e.metric.clone(),
        gt: e.gt.display().to_string(),
        est: e.est.display().to_string(),
        exceeded: limits.exceeded(&trans, &rot),
        result,
        limits,
        detail: Some(detail),
    })
}

#[cfg(test)]
mod tests;
