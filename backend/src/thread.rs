//! The back end in its own thread: keyframes in and updates out over channels (owned
//! messages, no shared map), so that the frontend never waits for an optimization unless
//! it asks to.
//!
//! A thread that stops unexpectedly (a panic, an error) is reported as an error by the next
//! call, never hidden: its error, or its panic message.
//!
//! Bundle adjustment's parallel stages, the final optimization's included, run on a rayon
//! pool the thread belongs to ([`stride_core::parallel`]): handed to the global pool from
//! here, they took twice as long in the median (teddy_200: 13 -> 6 ms per keyframe).

use crate::ba::SolveReport;
use crate::backend::{Backend, KeyframeInput, KeyframeUpdate};
use crate::error::BackendError;
use std::sync::mpsc::{channel, Receiver, Sender, TryRecvError};
use std::thread::JoinHandle;
use stride_core::panic_message;

/// What the frontend sends.
enum Request {
    Keyframe(Box<KeyframeInput>),
    /// No more keyframes: run the final optimization and stop.
    Finish,
}

/// What the thread hands back when it stops: the back end, and the final optimization's
/// outcome when it was asked for.
type Stopped = (Backend, Option<Result<Option<SolveReport>, BackendError>>);

/// The back end, running in a thread of its own.
pub struct BackendThread {
    requests: Option<Sender<Request>>,
    updates: Receiver<Result<KeyframeUpdate, BackendError>>,
    handle: Option<JoinHandle<Stopped>>,
    /// Keyframes sent and not yet answered.
    pending: usize,
}

/// What the thread returns when it is finished: the back end (its map) and the final
/// optimization's report.
pub struct Finished {
    /// The back end, after the final optimization.
    pub backend: Backend,
    /// The final optimization, when there was one.
    pub final_solve: Option<SolveReport>,
    /// Updates that were still queued when the run finished, in order.
    pub late_updates: Vec<KeyframeUpdate>,
}

impl BackendThread {
    /// Starts the thread.
    pub fn spawn(mut backend: Backend) -> Result<Self, BackendError> {
        let (req_tx, req_rx) = channel::<Request>();
        let (upd_tx, upd_rx) = channel();
        let handle = std::thread::Builder::new()
            .name("stride-backend".into())
            .spawn(move || {
                // Kept for the thread's life: its parallel stages run on it.
                let _pool = match stride_core::parallel::join_own_pool("stride-backend") {
                    Ok(pool) => pool,
                    Err(e) => {
                        let _ = upd_tx.send(Err(BackendError::ThreadDied(e.to_string())));
                        return (backend, None);
                    }
                };
                while let Ok(request) = req_rx.recv() {
                    let input = match request {
                        Request::Keyframe(input) => input,
                        Request::Finish => {
                            let solved = backend.finish();
                            return (backend, Some(solved));
                        }
                    };
                    let result = backend.add_keyframe(*input);
                    let failed = result.is_err();
                    if upd_tx.send(result).is_err() || failed {
                        break;
                    }
                }
                (backend, None)
            })
            .map_err(|e| BackendError::ThreadDied(format!("could not start: {e}")))?;
        Ok(Self {
            requests: Some(req_tx),
            updates: upd_rx,
            handle: Some(handle),
            pending: 0,
        })
    }

    /// Keyframes sent and not yet answered.
    pub fn pending(&self) -> usize {
        self.pending
    }

    /// Sends a keyframe (never blocks).
    pub fn send(&mut self, input: KeyframeInput) -> Result<(), BackendError> {
        let sent = self
            .requests
            .as_ref()
            .is_some_and(|tx| tx.send(Request::Keyframe(Box::new(input))).is_ok());
        if !sent {
            return Err(self.death());
        }
        self.pending += 1;
        Ok(())
    }

    /// The next update if one is ready (never blocks).
    pub fn try_recv(&mut self) -> Result<Option<KeyframeUpdate>, BackendError> {
        match self.updates.try_recv() {
            Ok(r) => self.answered(r).map(Some),
            Err(TryRecvError::Empty) => Ok(None),
            Err(TryRecvError::Disconnected) => Err(self.death()),
        }
    }

    /// The next update, waiting for it.
    pub fn recv(&mut self) -> Result<KeyframeUpdate, BackendError> {
        match self.updates.recv() {
            Ok(r) => self.answered(r),
            Err(_) => Err(self.death()),
        }
    }

    /// Books an answer. After an error the thread stops, so later sends fail at once
    /// instead of racing its exit.
    fn answered(
        &mut self,
        r: Result<KeyframeUpdate, BackendError>,
    ) -> Result<KeyframeUpdate, BackendError> {
        self.pending = self.pending.saturating_sub(1);
        if r.is_err() {
            self.requests = None;
        }
        r
    }

    /// Why the thread is gone: the error it reported, its panic message, or that it
    /// stopped.
    fn death(&mut self) -> BackendError {
        self.requests = None;
        while let Ok(r) = self.updates.try_recv() {
            if let Err(e) = r {
                return e;
            }
        }
        match self.handle.take().map(JoinHandle::join) {
            Some(Err(p)) => BackendError::ThreadDied(panic_message(p.as_ref())),
            _ => BackendError::ThreadDied("it stopped before the run ended".into()),
        }
    }

    /// Waits for every pending keyframe, then has the thread run the final optimization
    /// (on its pool) and stop.
    pub fn finish(mut self) -> Result<Finished, BackendError> {
        let mut late_updates = Vec::new();
        while self.pending > 0 {
            late_updates.push(self.recv()?);
        }
        let asked = self
            .requests
            .take()
            .is_some_and(|tx| tx.send(Request::Finish).is_ok());
        if !asked {
            return Err(self.death());
        }
        let (backend, final_solve) = match self.handle.take().map(JoinHandle::join) {
            Some(Ok((b, Some(solved)))) => (b, solved?),
            Some(Ok((_, None))) => return Err(self.death()),
            Some(Err(p)) => return Err(BackendError::ThreadDied(panic_message(p.as_ref()))),
            None => return Err(BackendError::ThreadDied("already stopped".into())),
        };
        Ok(Finished {
            backend,
            final_solve,
            late_updates,
        })
    }
}
