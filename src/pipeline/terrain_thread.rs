//! The elevation map in a thread of its own, so that integrations and rebuilds do not hold
//! up the frame path while the map keeps up. Requests are handled in the order they are
//! sent, so the map is the same on every run whatever the threads' timing; a query waits
//! for the requests before it. The queue holds at most [`QUEUE_REQUESTS`] requests (a view
//! carries a full depth image, 1.2 MB at 640x480): when the map falls behind, the frame
//! path waits for room instead of memory growing with the run (a 10,000-frame run once
//! reached 4 GB that way), and the wait is counted in [`TerrainStats::queue_wait_s`]. A
//! thread that stops unexpectedly is reported by the next call, never hidden.

use super::terrain::{Terrain, TerrainStats};
use super::PipelineError;
use nalgebra::Isometry3;
use std::sync::mpsc::{channel, sync_channel, Receiver, Sender, SyncSender};
use std::thread::JoinHandle;
use std::time::Instant;
use stride_core::image::DepthImage;
use stride_core::panic_message;
use stride_mapping::MapLayers;

/// What the pipeline asks of the map.
enum Request {
    /// A view's depth (full size; decimated in the thread) and its tie to its keyframe.
    View {
        frame: usize,
        t_s: f64,
        depth_m: Box<DepthImage>,
        keyframe: u64,
        keyframe_from_camera: Isometry3<f64>,
    },
    /// Keyframes' `world_from_camera` in the SLAM's frame.
    Poses(Vec<(u64, Isometry3<f64>)>),
    /// The world frame (`world_from_slam`), once known.
    World(Isometry3<f64>),
    /// The map as it is now.
    Layers(Sender<Result<MapLayers, PipelineError>>),
}

/// Most requests waiting for the map thread.
pub const QUEUE_REQUESTS: usize = 8;

/// The map thread.
pub struct TerrainThread {
    requests: Option<SyncSender<Request>>,
    /// Time the caller waited for room in the queue (s).
    queue_wait_s: f64,
    /// Errors of updates (the first one stops the thread).
    errors: Receiver<PipelineError>,
    handle: Option<JoinHandle<Terrain>>,
    world_sent: bool,
    /// A view is taken every this many frames, and at keyframes.
    every_frames: usize,
}

impl TerrainThread {
    /// Starts the thread with `terrain`.
    pub fn spawn(mut terrain: Terrain) -> Result<Self, PipelineError> {
        let every_frames = terrain.config().every_frames;
        let (req_tx, req_rx) = sync_channel::<Request>(QUEUE_REQUESTS);
        let (err_tx, err_rx) = channel();
        let handle = std::thread::Builder::new()
            .name("stride-map".into())
            .spawn(move || {
                // Kept for the thread's life: the map's parallel stages run on it
                // (`stride_core::parallel`: handed to the global pool from here, 5-10 % of
                // the updates ran at one worker's speed).
                let _pool = match stride_core::parallel::join_own_pool("stride-map") {
                    Ok(pool) => pool,
                    Err(e) => {
                        let _ = err_tx.send(PipelineError::MapThread(e.to_string()));
                        return terrain;
                    }
                };
                while let Ok(request) = req_rx.recv() {
                    let result = match request {
                        Request::View {
                            frame,
                            t_s,
                            depth_m,
                            keyframe,
                            keyframe_from_camera,
                        } => {
                            terrain.add_view(frame, t_s, &depth_m, keyframe, keyframe_from_camera);
                            terrain.update()
                        }
                        Request::Poses(p) => {
                            terrain.set_poses(&p);
                            terrain.update()
                        }
                        Request::World(w) => {
                            terrain.set_world(w);
                            terrain.update()
                        }
                        Request::Layers(reply) => {
                            let _ = reply.send(terrain.layers());
                            Ok(())
                        }
                    };
                    if let Err(e) = result {
                        let _ = err_tx.send(e);
                        break;
                    }
                }
                terrain
            })
            .map_err(|e| PipelineError::MapThread(e.to_string()))?;
        Ok(Self {
            requests: Some(req_tx),
            queue_wait_s: 0.0,
            errors: err_rx,
            handle: Some(handle),
            world_sent: false,
            every_frames,
        })
    }

    /// Sends a request; an error when the thread has stopped (with its own error when it
    /// left one).
    fn send(&mut self, r: Request) -> Result<(), PipelineError> {
        if let Ok(e) = self.errors.try_recv() {
            return Err(e);
        }
        let start = Instant::now();
        let sent = self.requests.as_ref().is_some_and(|tx| tx.send(r).is_ok());
        self.queue_wait_s += start.elapsed().as_secs_f64();
        if sent {
            Ok(())
        } else {
            Err(self.died())
        }
    }

    /// Why the thread is gone: its error, or its panic.
    fn died(&mut self) -> PipelineError {
        if let Ok(e) = self.errors.try_recv() {
            return e;
        }
        self.requests = None;
        match self.handle.take().map(JoinHandle::join) {
            Some(Err(p)) => PipelineError::MapThread(panic_message(p.as_ref())),
            Some(Ok(_)) | None => match self.errors.try_recv() {
                Ok(e) => e,
                Err(_) => PipelineError::MapThread("it stopped".into()),
            },
        }
    }

    /// Whether the frame at position `frame` is to be a view: every `every_frames`-th
    /// frame, and every keyframe.
    pub fn wants(&self, frame: usize, keyframe: bool) -> bool {
        keyframe || frame % self.every_frames == 0
    }

    /// Hands a view to the map: the depth of the frame at position `frame`, seen at `t_s`
    /// (s), tied to `keyframe` by `keyframe_from_camera`.
    pub fn view(
        &mut self,
        frame: usize,
        t_s: f64,
        depth_m: &DepthImage,
        keyframe: u64,
        keyframe_from_camera: Isometry3<f64>,
    ) -> Result<(), PipelineError> {
        self.send(Request::View {
            frame,
            t_s,
            depth_m: Box::new(depth_m.clone()),
            keyframe,
            keyframe_from_camera,
        })
    }

    /// Hands keyframes' poses (SLAM frame) to the map; nothing is sent for none.
    pub fn poses(&mut self, poses: Vec<(u64, Isometry3<f64>)>) -> Result<(), PipelineError> {
        if poses.is_empty() {
            return Ok(());
        }
        self.send(Request::Poses(poses))
    }

    /// Whether the world frame has been handed over.
    pub fn has_world(&self) -> bool {
        self.world_sent
    }

    /// Hands the world frame over (once).
    pub fn world(&mut self, world_from_slam: Isometry3<f64>) -> Result<(), PipelineError> {
        self.world_sent = true;
        self.send(Request::World(world_from_slam))
    }

    /// The map as it is once every request sent so far is handled.
    pub fn layers(&mut self) -> Result<MapLayers, PipelineError> {
        let (tx, rx) = channel();
        self.send(Request::Layers(tx))?;
        match rx.recv() {
            Ok(layers) => layers,
            Err(_) => Err(self.died()),
        }
    }

    /// Waits for every request, then makes the final map at `final_poses` (world frame, one
    /// per frame position), without the views of the frames `left_out`, on the caller's
    /// thread.
    pub fn finish(
        mut self,
        final_poses: &[Isometry3<f64>],
        left_out: &[bool],
    ) -> Result<(MapLayers, TerrainStats), PipelineError> {
        self.requests = None;
        let terrain = match self.handle.take().map(JoinHandle::join) {
            Some(Ok(t)) => t,
            Some(Err(p)) => return Err(PipelineError::MapThread(panic_message(p.as_ref()))),
            None => return Err(PipelineError::MapThread("it was not running".into())),
        };
        if let Ok(e) = self.errors.try_recv() {
            return Err(e);
        }
        let (layers, mut stats) = terrain.finish(
            |frame| final_poses.get(frame).copied(),
            |frame| left_out.get(frame).copied().unwrap_or(false),
        )?;
        stats.queue_wait_s = self.queue_wait_s;
        Ok((layers, stats))
    }
}
