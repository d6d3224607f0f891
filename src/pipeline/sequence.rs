//! The pipeline over a recorded sequence: frames decoded ahead on a background thread and
//! fed one by one, unreadable frames recorded as skipped.

use super::{FrameRecord, Pipeline, PipelineConfig, PipelineError, PipelineOutput};
use stride_datasets::sequence::Sequence;
use stride_datasets::stream::StreamError;

/// Frames decoded ahead of the pipeline.
const DECODE_AHEAD: usize = 4;

/// Runs the pipeline over the first `max_frames` frames of `seq` (all when `None`);
/// `on_frame` sees each frame's record as it is made (for progress bars).
pub fn run_sequence(
    seq: &Sequence,
    config: PipelineConfig,
    max_frames: Option<usize>,
    mut on_frame: impl FnMut(&FrameRecord),
) -> Result<PipelineOutput, PipelineError> {
    let mut pipeline = Pipeline::new(seq.camera(), config)?;
    if let Some(samples) = seq.gyroscope() {
        pipeline.add_gyroscope(samples);
    }
    if let Some(samples) = seq.accelerometer() {
        pipeline.add_accelerometer(samples);
    }
    for item in seq.stream(max_frames, DECODE_AHEAD) {
        let record = match item {
            Ok(d) => pipeline.process(&d.frame, d.decode_s)?,
            Err(StreamError::Frame(failure)) => {
                let t_s = seq.frame_time_s(failure.index).unwrap_or(f64::NAN);
                pipeline.skip(failure.index, t_s, failure.error.to_string())?
            }
            Err(StreamError::Stopped(e)) => return Err(e.into()),
        };
        on_frame(&record);
    }
    pipeline.finish()
}
