//! Errors of the back end.

/// Why the back end could not do what was asked.
#[derive(Debug, thiserror::Error)]
pub enum BackendError {
    /// The optimizer could not be set up or run.
    #[error("bundle adjustment: {0}")]
    Solver(String),
    /// A parameter is out of range.
    #[error("invalid back-end parameter {name} = {value}: {allowed}")]
    Config {
        /// The parameter's name.
        name: &'static str,
        /// The value given.
        value: String,
        /// What is allowed.
        allowed: &'static str,
    },
    /// The back-end thread stopped: it panicked or its channel closed.
    #[error("the back-end thread stopped unexpectedly: {0}")]
    ThreadDied(String),
    /// A keyframe message is inconsistent (unknown reference keyframe, non-finite pose).
    #[error("keyframe {id}: {reason}")]
    BadKeyframe {
        /// The keyframe's identifier.
        id: u64,
        /// What is wrong with it.
        reason: String,
    },
    /// The place-recognition vocabulary could not be read.
    #[error("place recognition: {0}")]
    Place(#[from] stride_frontend::place::PlaceError),
}
