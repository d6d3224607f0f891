//! One configuration for every stage, as a TOML file: `stride config --print-defaults`
//! prints the defaults with what each key means ([`DEFAULTS_TOML`]); `stride run --config
//! FILE` reads one. Every key may be left out (its default applies); an unknown key, a wrong
//! type or a value out of range is an error that names the key.

use crate::pipeline::terrain::TerrainConfig;
use crate::pipeline::world::WorldPlan;
use crate::pipeline::{PipelineConfig, PipelineError, Schedule};
use serde::{Deserialize, Serialize};
use stride_backend::{BackendConfig, BackendError, BackendMode};
use stride_frontend::{FrontendError, VoConfig};

/// The defaults, documented key by key: what `stride config --print-defaults` prints. A
/// test checks that it parses to [`Config::default`] and holds every key.
pub const DEFAULTS_TOML: &str = include_str!("defaults.toml");

/// Every stage's parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// The visual odometry.
    pub odometry: VoConfig,
    /// The back end; `None` (`backend = false`) for the odometry alone.
    #[serde(with = "stride_core::serde_opt")]
    pub backend: Option<BackendConfig>,
    /// When the odometry applies the back end's corrections.
    pub schedule: ScheduleConfig,
    /// The elevation map; `None` (`map = false`) for poses only.
    #[serde(with = "stride_core::serde_opt")]
    pub map: Option<TerrainConfig>,
}

impl Default for Config {
    /// The SLAM with bundle adjustment. Its odometry weighs its measurements as the back end
    /// does ([`VoConfig::with_backend_noise_model`]: 2 mm of isotropic noise, depth trusted
    /// 3 times less than the sensor model), and the measurements it hands over already carry
    /// that factor, so the back end takes their depth as it comes (`depth_noise_scale` 1:
    /// the factor applies once). Measured 2026-11-27 against the odometry's earlier 2 cm
    /// (docs/slam-measured.md, "One noise model"): over five starts of teddy_200 the final ATE fell
    /// from 6.87 to 6.24 mm and the live one from 6.82 to 5.67 mm, every 10th frame's live
    /// ATE from 11.2 to 4.0 mm, and five synthetic walks by 14-43 %.
    fn default() -> Self {
        Self {
            odometry: VoConfig::default().with_backend_noise_model(),
            backend: Some(BackendConfig {
                depth_noise_scale: 1.0,
                ..BackendConfig::default()
            }),
            schedule: ScheduleConfig::default(),
            map: Some(TerrainConfig::default()),
        }
    }
}

/// When the odometry applies the back end's corrections ([`Schedule`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ScheduleConfig {
    /// As soon as they are ready (results then depend on thread timing).
    pub free_running: bool,
    /// Otherwise exactly this many frames after their keyframe (repeatable).
    pub lag_frames: usize,
}

impl Default for ScheduleConfig {
    fn default() -> Self {
        Self {
            free_running: false,
            lag_frames: Schedule::DEFAULT_LAG_FRAMES,
        }
    }
}

impl ScheduleConfig {
    /// The schedule this describes.
    pub fn schedule(&self) -> Schedule {
        if self.free_running {
            Schedule::Free
        } else {
            Schedule::Fixed {
                lag_frames: self.lag_frames,
            }
        }
    }
}

/// A TOML parse error on one line: its position (the first line of the parser's message)
/// and what is wrong (the last), without the source excerpt between them.
pub(crate) fn parse_message(full: &str) -> String {
    let lines: Vec<&str> = full.lines().filter(|l| !l.trim().is_empty()).collect();
    match (lines.first(), lines.last()) {
        (Some(first), Some(last)) if lines.len() > 1 => format!("{first}: {last}"),
        _ => full.trim().to_owned(),
    }
}

/// An out-of-range error for `key`.
fn out_of_range(key: String, value: String, allowed: &'static str) -> PipelineError {
    PipelineError::Config {
        key,
        value,
        allowed,
    }
}

impl Config {
    /// Parses a TOML configuration (the text of `path`, named in errors) over
    /// [`Config::default`] and checks every value: a key the text leaves out keeps its value
    /// there, also inside a section the text opens (the SLAM's odometry and back end differ
    /// from [`VoConfig::default`] and [`BackendConfig::default`]).
    pub fn from_toml(text: &str, path: &str) -> Result<Self, PipelineError> {
        Self::from_toml_over(text, path, &Config::default())
    }

    /// Reads and checks the configuration file at `path`.
    pub fn load(path: &std::path::Path) -> Result<Self, PipelineError> {
        let (text, name) = read(path)?;
        Self::from_toml(&text, &name)
    }

    /// Reads and checks the configuration file at `path` over the defaults of the back end
    /// it runs with ([`Config::defaults_for`]): `mode` when the caller decides it (`Some`,
    /// a command's flags), else the file's own. The keys the file leaves out take those
    /// defaults. Returns the configuration and the back end's mode.
    pub fn load_for(
        path: &std::path::Path,
        mode: Option<Option<BackendMode>>,
    ) -> Result<(Self, Option<BackendMode>), PipelineError> {
        let (text, name) = read(path)?;
        let mode = match mode {
            Some(m) => m,
            None => Self::from_toml(&text, &name)?.backend.map(|b| b.mode),
        };
        let config = Self::from_toml_over(&text, &name, &Self::defaults_for(mode))?;
        Ok((config, mode))
    }

    /// [`Config::from_toml`], with the keys the text leaves out taken from `base`. A back
    /// end the text configures where `base` has none takes the keys it leaves out from the
    /// defaults of its mode ([`Config::defaults_for`]).
    pub fn from_toml_over(text: &str, path: &str, base: &Config) -> Result<Self, PipelineError> {
        let file_error = |message: String| PipelineError::ConfigFile {
            path: path.to_owned(),
            message,
        };
        // Parsed on its own first: serde's errors name the key and the line in the file,
        // which the merged value below no longer knows.
        let parsed: Config =
            toml::from_str(text).map_err(|e| file_error(parse_message(&e.to_string())))?;
        let file: toml::Value = toml::from_str(text).map_err(|e| file_error(e.to_string()))?;
        let mut base = base.clone();
        if base.backend.is_none() && file.get("backend").is_some_and(toml::Value::is_table) {
            base.backend = Self::defaults_for(parsed.backend.map(|b| b.mode)).backend;
        }
        let mut merged = toml::Value::try_from(&base).map_err(|e| file_error(e.to_string()))?;
        overlay(&mut merged, file);
        let config: Config = merged
            .try_into()
            .map_err(|e: toml::de::Error| file_error(parse_message(&e.to_string())))?;
        config.validate().map_err(|e| match e {
            PipelineError::Config {
                key,
                value,
                allowed,
            } => file_error(format!("{key} = {value}: {allowed}")),
            other => other,
        })?;
        Ok(config)
    }

    /// The defaults of the odometry running alone: no back end, and the odometry's
    /// [`VoConfig::odometry_only`] settings.
    pub fn odometry_alone() -> Self {
        Self {
            odometry: VoConfig::odometry_only(),
            backend: None,
            ..Self::default()
        }
    }

    /// The defaults for a back end in `mode`: bundle adjustment's are [`Config::default`];
    /// the pose graph keeps the odometry's own noise model ([`VoConfig::default`], 2 cm
    /// of isotropic noise), because the back end's made it worse under blur (teddy_200
    /// blurred by 5 px: 9.0 -> 25.7 mm), and points behind occluding edges at full weight
    /// (`occluded_sigma_px` 0); `None`, the odometry alone, has its own
    /// ([`Config::odometry_alone`]).
    pub fn defaults_for(mode: Option<BackendMode>) -> Self {
        match mode {
            None => Self::odometry_alone(),
            Some(BackendMode::BundleAdjustment) => Self::default(),
            // Trusting points behind occluding edges less made the pose graph worse
            // (teddy_200 7.5 -> 20.4 mm, docs/blur.md).
            Some(BackendMode::PoseGraph) => Self {
                odometry: VoConfig {
                    occluded_sigma_px: 0.0,
                    ..VoConfig::default()
                },
                backend: Some(BackendConfig {
                    mode: BackendMode::PoseGraph,
                    ..BackendConfig::default()
                }),
                ..Self::default()
            },
        }
    }

    /// The back end to run in `mode`: this configuration's with its mode set, or, when it
    /// has none (a file's `backend = false` under a command that asks for one), the defaults
    /// for `mode` ([`Config::defaults_for`]), whose depth weighting matches the odometry's.
    pub fn backend_in(&self, mode: BackendMode) -> BackendConfig {
        let base = self
            .backend
            .clone()
            .or_else(|| Self::defaults_for(Some(mode)).backend)
            .unwrap_or_default();
        BackendConfig { mode, ..base }
    }

    /// The configuration as TOML (every key, the values in use).
    pub fn to_toml(&self) -> Result<String, PipelineError> {
        toml::to_string(self).map_err(|e| PipelineError::ConfigFile {
            path: "(writing)".into(),
            message: e.to_string(),
        })
    }

    /// Checks every value; the error names the key (`section.name`) and what is allowed.
    pub fn validate(&self) -> Result<(), PipelineError> {
        self.odometry.validate().map_err(|e| match e {
            FrontendError::Parameter {
                name,
                value,
                allowed,
            } => out_of_range(format!("odometry.{name}"), value, allowed),
            other => PipelineError::Odometry(other),
        })?;
        if let Some(b) = &self.backend {
            b.validate().map_err(|e| match e {
                BackendError::Config {
                    name,
                    value,
                    allowed,
                } => out_of_range(format!("backend.{name}"), value, allowed),
                other => PipelineError::Backend(other),
            })?;
        }
        if !(0..=100).contains(&self.schedule.lag_frames) {
            return Err(out_of_range(
                "schedule.lag_frames".into(),
                self.schedule.lag_frames.to_string(),
                "0 to 100 frames",
            ));
        }
        if let Some(m) = &self.map {
            m.validate()?;
        }
        Ok(())
    }

    /// The pipeline's configuration, with its world frame found by `world`.
    pub fn pipeline(&self, world: WorldPlan) -> PipelineConfig {
        PipelineConfig {
            odometry: self.odometry.clone(),
            backend: self.backend.clone().map(|b| (b, self.schedule.schedule())),
            world,
            map: self.map.clone(),
            saved_map: None,
        }
    }
}

/// The text of the configuration file at `path`, and the name errors give it.
fn read(path: &std::path::Path) -> Result<(String, String), PipelineError> {
    let name = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| PipelineError::ConfigFile {
        path: name.clone(),
        message: e.to_string(),
    })?;
    Ok((text, name))
}

/// Writes `over`'s keys into `base`, table by table: a key `over` leaves out keeps `base`'s
/// value. A table that names a different `kind` (a variant of an enum, such as the
/// odometry's inlier test) replaces `base`'s whole, since the variants' keys differ.
fn overlay(base: &mut toml::Value, over: toml::Value) {
    match (base, over) {
        (toml::Value::Table(b), toml::Value::Table(o))
            if o.get("kind").is_none() || o.get("kind") == b.get("kind") =>
        {
            for (key, value) in o {
                match b.get_mut(&key) {
                    Some(slot) => overlay(slot, value),
                    None => {
                        b.insert(key, value);
                    }
                }
            }
        }
        (slot, value) => *slot = value,
    }
}

#[cfg(test)]
mod tests;
