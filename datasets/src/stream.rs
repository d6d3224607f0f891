//! Frames decoded ahead on a background thread, in order, with failures reported in place.
//!
//! Invariant: a [`FrameStream`] of `len` frames yields exactly `len` items (a frame or a
//! [`StreamError::Frame`] for each), unless its decoder thread cannot start or dies: then it
//! yields one [`StreamError::Stopped`] naming how far it got, and ends. A consumer cannot
//! mistake a dead decoder for the end of the sequence.

use crate::error::DatasetError;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::thread::JoinHandle;
use stride_core::frame::RgbdFrame;

/// A frame decoded by [`FrameStream`], with the time decoding took.
#[derive(Debug, Clone)]
pub struct DecodedFrame {
    /// The frame.
    pub frame: RgbdFrame,
    /// Wall time spent reading and decoding both images (s), on the decoder thread.
    pub decode_s: f64,
}

/// A frame [`FrameStream`] could not load.
#[derive(Debug)]
pub struct FrameFailure {
    /// Index of the frame in the sequence.
    pub index: usize,
    /// Why it failed (names the file).
    pub error: DatasetError,
}

/// What a [`FrameStream`] yields in place of a frame.
#[derive(Debug, thiserror::Error)]
pub enum StreamError {
    /// One frame could not be loaded; the stream goes on with the next one.
    #[error("frame {}: {}", .0.index, .0.error)]
    Frame(FrameFailure),
    /// The decoder thread could not start, or stopped before the last frame (a panic): the
    /// stream ends here, and the run should fail.
    #[error("{0}")]
    Stopped(DatasetError),
}

/// The channel's items: a decoded frame or one that failed.
pub type Decoded = Result<DecodedFrame, FrameFailure>;

/// Frames decoded ahead on a background thread; see [`crate::tum::TumSequence::stream`].
pub struct FrameStream {
    rx: Receiver<Decoded>,
    handle: Option<JoinHandle<()>>,
    spawn_error: Option<String>,
    dir: PathBuf,
    len: usize,
    yielded: usize,
    stopped: bool,
}

impl FrameStream {
    /// Runs `work` on a new thread named `stride-decode`, which sends the `len` items of the
    /// sequence in `dir` through a channel holding up to `prefetch` of them.
    pub(crate) fn spawn(
        dir: &Path,
        len: usize,
        prefetch: usize,
        work: impl FnOnce(SyncSender<Decoded>) + Send + 'static,
    ) -> Self {
        let (tx, rx) = sync_channel(prefetch.max(1));
        let (handle, spawn_error) = match std::thread::Builder::new()
            .name("stride-decode".into())
            .spawn(move || work(tx))
        {
            Ok(h) => (Some(h), None),
            Err(e) => (None, Some(format!("could not start ({e})"))),
        };
        Self {
            rx,
            handle,
            spawn_error,
            dir: dir.to_path_buf(),
            len,
            yielded: 0,
            stopped: false,
        }
    }

    /// Number of frames the stream will yield (successes and failures).
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when the stream yields nothing.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Why the decoder thread ended early.
    fn death(&mut self) -> DatasetError {
        let why = match self.handle.take().map(JoinHandle::join) {
            Some(Err(panic)) => {
                let msg = panic
                    .downcast_ref::<&str>()
                    .map(|s| (*s).to_owned())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "a panic".into());
                format!("died ({msg})")
            }
            Some(Ok(())) => "stopped".into(),
            None => self
                .spawn_error
                .clone()
                .unwrap_or_else(|| "was lost".into()),
        };
        DatasetError::invalid(
            &self.dir,
            format!(
                "the frame decoder thread {why} after {} of {} frames",
                self.yielded, self.len
            ),
        )
    }
}

impl Iterator for FrameStream {
    type Item = Result<DecodedFrame, StreamError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.stopped || self.yielded >= self.len {
            return None;
        }
        match self.rx.recv() {
            Ok(item) => {
                self.yielded += 1;
                Some(item.map_err(StreamError::Frame))
            }
            Err(_) => {
                self.stopped = true;
                Some(Err(StreamError::Stopped(self.death())))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_decoder_that_dies_ends_the_stream_with_an_error() {
        let stream = FrameStream::spawn(Path::new("seq"), 3, 1, |tx| {
            let failure = FrameFailure {
                index: 0,
                error: DatasetError::invalid("seq/rgb/0.png", "unreadable"),
            };
            let _ = tx.send(Err(failure));
            panic!("decoder bug");
        });
        let items: Vec<_> = stream.collect();
        assert_eq!(items.len(), 2);
        assert!(matches!(&items[0], Err(StreamError::Frame(f)) if f.index == 0));
        let Err(StreamError::Stopped(e)) = &items[1] else {
            panic!("expected a stop, got {:?}", items[1]);
        };
        let e = e.to_string();
        assert!(
            e.contains("seq: the frame decoder thread died (decoder bug) after 1 of 3 frames"),
            "{e}"
        );
    }

    #[test]
    fn a_decoder_that_returns_early_is_reported_too() {
        let stream = FrameStream::spawn(Path::new("seq"), 2, 1, |_tx| {});
        let items: Vec<_> = stream.collect();
        assert_eq!(items.len(), 1);
        assert!(
            matches!(&items[0], Err(StreamError::Stopped(e)) if e.to_string().contains("stopped after 0 of 2"))
        );
    }
}
