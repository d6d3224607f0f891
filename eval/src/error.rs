//! Why an evaluation could not be computed.

use crate::options::{Align, DeltaUnit};

/// An evaluation that cannot be computed, with what to do about it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EvalError {
    /// No (or too few) poses could be associated in time.
    #[error(
        "only {found} pose pair(s) associated within {t_max_diff_s} s, need at least {needed} \
         (ground truth spans {gt_span}, estimate spans {est_span}{offset_note}); check that both \
         files use the same clock, or widen the association window (t_max_diff_s) or set a time \
         offset (offset_s)"
    )]
    TooFewPairs {
        /// Pairs found.
        found: usize,
        /// Pairs needed.
        needed: usize,
        /// Association window (s).
        t_max_diff_s: f64,
        /// Ground-truth time span, formatted.
        gt_span: String,
        /// Estimate time span, formatted.
        est_span: String,
        /// Mentions the offset when one was applied.
        offset_note: String,
    },
    /// The associated positions do not determine the alignment.
    #[error(
        "{align} alignment is degenerate: the {pairs} associated estimate positions span only \
         {rank} dimension(s) of the cross-covariance (collinear or coincident), so the rotation \
         about that line is undetermined. evo stops here too ('Degenerate covariance rank, Umeyama \
         alignment is not possible'). Align by the origin or not at all, or use the TUM preset, \
         which aligns anyway and warns"
    )]
    DegenerateAlignment {
        /// The requested alignment.
        align: Align,
        /// Number of associated pairs.
        pairs: usize,
        /// Number of non-zero singular values.
        rank: usize,
    },
    /// Alignment failed for another reason (e.g. all positions coincide for Sim(3)).
    #[error("{align} alignment failed: {reason}")]
    AlignmentFailed {
        /// The requested alignment.
        align: Align,
        /// Why.
        reason: String,
    },
    /// No pose pair is `delta` apart.
    #[error(
        "delta = {delta} {unit} produced no pose pair among {poses} associated poses; \
         try a smaller delta{tolerance_hint}"
    )]
    NoRelativePairs {
        /// Requested delta.
        delta: f64,
        /// Its unit.
        unit: DeltaUnit,
        /// Associated poses available.
        poses: usize,
        /// Hint about the tolerance in all-pairs mode.
        tolerance_hint: String,
    },
    /// An option value outside its domain, or a combination a preset cannot reproduce.
    #[error("option {option}: {message}")]
    InvalidOption {
        /// The field of [`crate::AteOptions`] / [`crate::RpeOptions`] at fault.
        option: &'static str,
        /// What is wrong, with the value.
        message: String,
    },
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_options_not_command_line_flags() {
        // The library serves callers without a command line: the CLI adds its flags.
        let errors = [
            EvalError::TooFewPairs {
                found: 1,
                needed: 3,
                t_max_diff_s: 0.01,
                gt_span: "0-1 s".into(),
                est_span: "5-6 s".into(),
                offset_note: String::new(),
            },
            EvalError::DegenerateAlignment {
                align: Align::Se3,
                pairs: 4,
                rank: 1,
            },
            EvalError::NoRelativePairs {
                delta: 50.0,
                unit: DeltaUnit::Frames,
                poses: 4,
                tolerance_hint: String::new(),
            },
        ];
        for e in errors {
            let m = e.to_string();
            assert!(!m.contains("--"), "{m}");
        }
    }
}
