//! The choices an evaluation makes: which tool's semantics, which alignment, which delta.
//!
//! See `docs/evaluation.md` for every place where evo and the TUM tools differ and what each
//! preset does there.

use serde::Serialize;
use std::fmt;
use std::str::FromStr;

/// Whose semantics to reproduce.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Preset {
    /// evo 1.38 (`evo_ape`, `evo_rpe`): nearest-neighbour association within 0.01 s (a pose
    /// may be matched twice), alignment only when asked, RPE over consecutive frame pairs,
    /// rotation errors from the logarithm map.
    Evo,
    /// TUM RGB-D benchmark (`evaluate_ate.py`, `evaluate_rpe.py --fixed_delta`): greedy
    /// one-to-one association within 0.02 s, SE(3) alignment always, RPE with a 1 s delta
    /// and its own nearest-stamp matching, rotation errors by `acos((tr R - 1) / 2)`.
    Tum,
}

impl Preset {
    /// Default association window (s): 0.01 for evo, 0.02 for the TUM tools.
    pub fn default_t_max_diff_s(self) -> f64 {
        match self {
            Preset::Evo => 0.01,
            Preset::Tum => 0.02,
        }
    }

    /// Default ATE alignment: none for evo (it aligns only with `-a`), SE(3) for TUM.
    pub fn default_ate_align(self) -> Align {
        match self {
            Preset::Evo => Align::None,
            Preset::Tum => Align::Se3,
        }
    }

    /// Default RPE delta: 1 frame for evo, 1 second for TUM.
    pub fn default_rpe_delta(self) -> (f64, DeltaUnit) {
        match self {
            Preset::Evo => (1.0, DeltaUnit::Frames),
            Preset::Tum => (1.0, DeltaUnit::Seconds),
        }
    }
}

/// How the estimate is brought into the ground truth's frame before comparing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Align {
    /// Compare as given.
    None,
    /// Umeyama rotation + translation fitted to the associated positions.
    Se3,
    /// Umeyama rotation + translation + scale (for monocular estimates).
    Sim3,
    /// Move the estimate so that its first associated pose equals the ground truth's.
    Origin,
}

/// The unit of an RPE delta.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DeltaUnit {
    /// Poses apart (integer delta).
    Frames,
    /// Seconds apart.
    Seconds,
    /// Metres travelled along the estimate's path.
    Metres,
}

/// A string that names no option value.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown {what} '{value}' (expected one of: {expected})")]
pub struct ParseOptionError {
    what: &'static str,
    value: String,
    expected: &'static str,
}

macro_rules! string_enum {
    ($ty:ty, $what:literal, $expected:literal, { $($name:literal $(| $alias:literal)* => $variant:expr),+ $(,)? }) => {
        impl FromStr for $ty {
            type Err = ParseOptionError;
            fn from_str(s: &str) -> Result<Self, Self::Err> {
                match s.to_ascii_lowercase().as_str() {
                    $($name $(| $alias)* => Ok($variant),)+
                    _ => Err(ParseOptionError { what: $what, value: s.to_owned(), expected: $expected }),
                }
            }
        }
    };
}

string_enum!(Preset, "preset", "evo, tum", { "evo" => Preset::Evo, "tum" => Preset::Tum });
string_enum!(Align, "alignment", "se3, sim3, origin, none", {
    "none" => Align::None, "se3" => Align::Se3, "sim3" => Align::Sim3, "origin" => Align::Origin,
});
string_enum!(DeltaUnit, "delta unit", "frames, seconds, metres", {
    "frames" | "f" => DeltaUnit::Frames,
    "seconds" | "s" => DeltaUnit::Seconds,
    "metres" | "meters" | "m" => DeltaUnit::Metres,
});

impl fmt::Display for Preset {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Preset::Evo => "evo",
            Preset::Tum => "tum",
        })
    }
}

impl fmt::Display for Align {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Align::None => "none",
            Align::Se3 => "se3",
            Align::Sim3 => "sim3",
            Align::Origin => "origin",
        })
    }
}

impl fmt::Display for DeltaUnit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            DeltaUnit::Frames => "frames",
            DeltaUnit::Seconds => "seconds",
            DeltaUnit::Metres => "metres",
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_names_and_aliases() {
        assert_eq!("TUM".parse::<Preset>().unwrap(), Preset::Tum);
        assert_eq!("sim3".parse::<Align>().unwrap(), Align::Sim3);
        assert_eq!("m".parse::<DeltaUnit>().unwrap(), DeltaUnit::Metres);
        assert_eq!("meters".parse::<DeltaUnit>().unwrap(), DeltaUnit::Metres);
        let e = "affine".parse::<Align>().unwrap_err().to_string();
        assert_eq!(
            e,
            "unknown alignment 'affine' (expected one of: se3, sim3, origin, none)"
        );
    }
}
