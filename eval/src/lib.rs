//! # stride-eval
//!
//! Trajectory metrics that agree with the tools the field trusts, to the printed digit:
//!
//! * [`ate()`]: absolute trajectory error (evo's APE, TUM's `evaluate_ate.py`).
//! * [`rpe()`]: relative pose error (evo's RPE, TUM's `evaluate_rpe.py --fixed_delta`).
//! * [`options::Preset`] picks whose semantics to follow; `docs/evaluation.md` lists every
//!   place where evo and the TUM tools differ and what each preset does there.
//! * [`blur`]: image sharpness metrics for the gait-dependent motion-blur study (paper 004).
//! * [`plot`], [`report`] and [`summary`]: SVG charts, Markdown/HTML reports and the JSON
//!   objects of `stride eval`.
//!
//! Independent of file formats: it takes [`stride_core::trajectory::Trajectory`] values.

pub mod align;
pub mod ate;
pub mod blur;
pub mod error;
pub mod limits;
pub mod options;
pub mod plot;
pub mod report;
pub mod rpe;
pub mod stats;
pub mod summary;
pub mod sync;

pub use ate::{ate, AteOptions, AteResult};
pub use error::EvalError;
pub use limits::Limits;
pub use options::{Align, DeltaUnit, Preset};
pub use rpe::{rpe, RpeOptions, RpeResult};
pub use stats::Statistics;
