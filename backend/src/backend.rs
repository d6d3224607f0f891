//! The back end: adds the frontend's keyframes to the map, associates their features with
//! map points (by track, then by ORB matching near predicted positions), optimizes a local
//! window, culls what is redundant, and reports each keyframe's optimized pose.
//!
//! The odometry is never changed by the back end: feeding optimized points back into its
//! tracking made the final trajectory worse on real data (teddy_200, five seeds: 7.5 mm
//! against 4.8 mm ATE), because frames tracked against a mix of optimized and odometry
//! points are no longer consistent with the keyframe their pose is kept relative to. The
//! corrections reach the outputs instead (live poses, final trajectory).

use crate::ba::{solve, SolveReport, SolverOptions};
use crate::config::{BackendConfig, BackendMode};
use crate::error::BackendError;
use crate::map::PointId;
use crate::map::{Feature, Keyframe, KeyframeId, Map, OdometryEdge};
use crate::se3::{is_finite, left_from_right};
use crate::window::{build, final_free, local_window, EdgeKind, KeyframeEdge, MapProblem};
use nalgebra::{Isometry3, Matrix6, Vector6};
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::time::Instant;
use stride_core::camera::PinholeCamera;
use stride_frontend::KeyframeInfo;

/// A keyframe as the frontend hands it over.
#[derive(Debug, Clone, PartialEq)]
pub struct KeyframeInput {
    /// Index of the frame in the sequence.
    pub frame_index: usize,
    /// Frame time (s).
    pub t_s: f64,
    /// The frontend's `world_from_camera` for it (m).
    pub world_from_camera: Isometry3<f64>,
    /// Features and odometry link.
    pub info: KeyframeInfo,
    /// The keyframe's depth image (m along the optical axis, 0 where none), for the
    /// revisit links ([`crate::RevisitConfig`]); `None` leaves the keyframe without one.
    pub depth_m: Option<stride_core::image::DepthImage>,
}

/// What happened to one keyframe.
#[derive(Debug, Clone, PartialEq)]
pub struct KeyframeReport {
    /// The keyframe.
    pub keyframe_id: KeyframeId,
    /// Features associated with map points through their track.
    pub by_track: usize,
    /// Features associated with map points by ORB matching.
    pub by_orb: usize,
    /// Duplicated points fused (a track's point found to be an older map point).
    pub fused: usize,
    /// New map points.
    pub new_points: usize,
    /// Whether the odometry link joined the optimization (too few re-observations).
    pub odometry_edge: bool,
    /// How many of the odometry's depth links ([`stride_frontend::DepthLink`]) joined the
    /// map's constraints.
    pub depth_edges: usize,
    /// Whether a revisit link ([`crate::RevisitConfig`]) tied the keyframe to an old one.
    pub revisit_edge: bool,
    /// Observations removed as outliers after optimizing.
    pub outliers: usize,
    /// Points and keyframes culled.
    pub culled_points: usize,
    /// See `culled_points`.
    pub culled_keyframes: usize,
    /// The local optimization.
    pub solve: Option<SolveReport>,
    /// The loop closed at this keyframe, if any.
    pub loop_closure: Option<crate::LoopReport>,
    /// Wall time of the local optimization: both solves (the second after removing
    /// outliers) and the outlier test (s); 0 when none ran.
    pub optimize_s: f64,
    /// Wall time of the whole step: association, optimization, loop closure, culling (s).
    pub time_s: f64,
}

/// The back end's answer to a keyframe: its optimized pose and a report. A consumer of live
/// poses moves the odometry's later poses by the correction this implies (see
/// [`KeyframeUpdate::correction`]).
#[derive(Debug, Clone, PartialEq)]
pub struct KeyframeUpdate {
    /// The keyframe.
    pub keyframe_id: KeyframeId,
    /// Its `world_from_camera` after the local optimization (m).
    pub world_from_keyframe: Isometry3<f64>,
    /// `world_from_camera` of every keyframe of the local window after the optimization
    /// (this one included, culled ones excluded), by identifier: what a consumer that placed
    /// data at older poses (an elevation map) needs to see whether they moved.
    pub window_poses: Vec<(KeyframeId, Isometry3<f64>)>,
    /// What was done.
    pub report: KeyframeReport,
}

impl KeyframeUpdate {
    /// `optimized_from_odometry`: the rigid motion that takes the odometry's world onto the
    /// back end's, given the odometry's own pose of the same keyframe.
    pub fn correction(&self, odometry_world_from_keyframe: &Isometry3<f64>) -> Isometry3<f64> {
        self.world_from_keyframe * odometry_world_from_keyframe.inverse()
    }
}

/// The back end. Feed keyframes in order with [`Backend::add_keyframe`]; call
/// [`Backend::finish`] at the end for a full optimization.
pub struct Backend {
    pub(crate) config: BackendConfig,
    pub(crate) camera: PinholeCamera,
    pub(crate) map: Map,
    pub(crate) first: Option<KeyframeId>,
    pub(crate) newest: Option<KeyframeId>,
    /// Relative motions measured between keyframes: the odometry's depth links, the
    /// revisit links ([`crate::revisit`]), and in pose-graph mode the motions from shared
    /// points.
    pub(crate) pose_edges: Vec<KeyframeEdge>,
    /// The map point of each track the latest keyframe saw (every track the odometry still
    /// follows was in it), kept apart from the map so that the latest keyframe can be
    /// culled.
    pub(crate) tracks: HashMap<u64, PointId>,
    /// Keyframes' bags of words for loop candidates by appearance (empty when loop closure
    /// or its appearance candidates are off).
    pub(crate) places: crate::loop_closure::Places,
    /// Keyframes' depth images for the revisit links.
    pub(crate) revisits: crate::revisit::Revisits,
    /// The first keyframe placed by a prediction (the odometry lost the frame) since the map
    /// was last whole: the keyframes from it on sit where a guess put them until loop
    /// closure ties one of them to an older keyframe (then `None`).
    pub(crate) unjoined_from: Option<KeyframeId>,
    /// The first keyframe of a run in a saved map whose first frame the map could not
    /// place (the odometry put it at a saved keyframe's pose by a guess), until a loop joins
    /// its piece to the map: the keyframes from it on match only their own piece's points,
    /// since the map around the guessed pose is not what the camera sees (matching it would
    /// count its points as unseen, and culling would take them).
    pub(crate) guessed_start: Option<KeyframeId>,
    /// Every keyframe placed by a prediction: each starts a piece of the map.
    pub(crate) piece_starts: std::collections::BTreeSet<KeyframeId>,
    /// The newest keyframe tied to an old place by a revisit link or a loop.
    pub(crate) last_tied: Option<KeyframeId>,
}

/// Standard deviations (m, rad) of the link that holds a run started in a saved map by a
/// guess (its first frame not found there; see `Backend::guessed_start`): the guess may be
/// metres and tens of degrees off, so the link only fixes the piece's gauge and gives way to
/// whatever joins the piece to the map. A lost frame's link, a motion model's prediction
/// over a short gap, has `predicted_link_sigma`.
const GUESSED_START_SIGMA: (f64, f64) = (100.0, 10.0);

/// Whether an information matrix can weigh an edge: finite and positive definite.
fn usable_information(info: &Matrix6<f64>) -> bool {
    info.iter().all(|v| v.is_finite()) && info.cholesky().is_some()
}

/// The information of a frontend pose estimate, moved into the optimizer's tangent space;
/// `fallback` when the estimate has none (a predicted pose).
fn odometry_information(
    world_from_camera: &Isometry3<f64>,
    info_left: &Matrix6<f64>,
    fallback: (f64, f64),
) -> Matrix6<f64> {
    let info = tangent_information(world_from_camera, info_left);
    if usable_information(&info) {
        info
    } else {
        diagonal_information(fallback)
    }
}

impl Backend {
    /// Adds keyframe `id`'s depth link `l` as a pose-pose edge from the earlier keyframe (or
    /// the live keyframe that one is kept relative to); whether it was added.
    fn add_depth_edge(&mut self, id: KeyframeId, l: &stride_frontend::DepthLink) -> bool {
        let Some((previous, live_from_previous)) = self.map.live_ancestor(l.keyframe_id) else {
            return false;
        };
        // A right perturbation of the keyframe's pose does not depend on the frame the
        // link starts from: the link's tangent information holds after composing.
        self.add_measured_edge(
            (previous, id, EdgeKind::Odometry),
            live_from_previous * l.keyframe_from_this,
            &l.keyframe_from_this,
            &l.information,
        )
    }

    /// Adds the pose-pose edge `from -> to` with relative pose `from_from_to`, measured
    /// (by a depth alignment) as `measured` with information `info_left` (left
    /// perturbation, as the alignment gives it), of `kind`; whether that information was
    /// usable.
    pub(crate) fn add_measured_edge(
        &mut self,
        (from, to, kind): (KeyframeId, KeyframeId, EdgeKind),
        from_from_to: Isometry3<f64>,
        measured: &Isometry3<f64>,
        info_left: &Matrix6<f64>,
    ) -> bool {
        let information = tangent_information(measured, info_left);
        let usable = usable_information(&information);
        if usable {
            self.pose_edges.push(KeyframeEdge {
                from,
                to,
                from_from_to,
                information,
                kind,
            });
        }
        usable
    }
}

/// The information `info_left` of a pose estimate `world_from_camera` (left perturbation,
/// as RANSAC and the odometry give it) in the optimizer's tangent space (camera-frame right
/// perturbation), symmetrized.
pub(crate) fn tangent_information(
    world_from_camera: &Isometry3<f64>,
    info_left: &Matrix6<f64>,
) -> Matrix6<f64> {
    let a = left_from_right(world_from_camera);
    let info = a.transpose() * info_left * a;
    (info + info.transpose()) * 0.5
}

/// The information of a pose error with independent standard deviations `(t, r)` (m, rad)
/// on each translation and rotation component.
pub(crate) fn diagonal_information((t, r): (f64, f64)) -> Matrix6<f64> {
    let (it, ir) = (1.0 / (t * t), 1.0 / (r * r));
    Matrix6::from_diagonal(&Vector6::new(it, it, it, ir, ir, ir))
}

impl Backend {
    /// A back end for a camera. Validates the configuration.
    pub fn new(camera: PinholeCamera, config: BackendConfig) -> Result<Self, BackendError> {
        config.validate()?;
        let places = crate::loop_closure::Places::new(&config.loop_closure)?;
        Ok(Self {
            config,
            map: Map::new(),
            first: None,
            newest: None,
            pose_edges: Vec::new(),
            tracks: HashMap::new(),
            places,
            revisits: crate::revisit::Revisits::new(&camera),
            unjoined_from: None,
            guessed_start: None,
            piece_starts: std::collections::BTreeSet::new(),
            last_tied: None,
            camera,
        })
    }

    /// A back end that extends a saved map: its keyframes are kept, the oldest holds the
    /// gauge, and new keyframes (numbered after the map's) are matched against its points
    /// like any others. `place_features` are the saved keyframes' (for loop closure; a
    /// keyframe without falls back to its mapped features). Validates the configuration.
    pub fn with_map(
        camera: PinholeCamera,
        config: BackendConfig,
        map: Map,
        place_features: &BTreeMap<KeyframeId, Vec<stride_frontend::PlaceFeature>>,
    ) -> Result<Self, BackendError> {
        let mut backend = Self::new(camera, config)?;
        backend.first = map.keyframes().keys().next().copied();
        backend.map = map;
        let ids: Vec<KeyframeId> = backend.map.keyframes().keys().copied().collect();
        for id in ids {
            if let Some(f) = place_features.get(&id) {
                backend.places.keep(id, f);
            }
            backend.index_place(id);
        }
        Ok(backend)
    }

    /// The map.
    pub fn map(&self) -> &Map {
        &self.map
    }

    /// The map, taking the back end apart.
    pub fn into_map(self) -> Map {
        self.map
    }

    /// The configuration.
    pub fn config(&self) -> &BackendConfig {
        &self.config
    }

    /// Adds a keyframe: association, new points, local optimization, culling.
    pub fn add_keyframe(&mut self, input: KeyframeInput) -> Result<KeyframeUpdate, BackendError> {
        let start = Instant::now();
        let id = input.info.id;
        let bad = |reason: String| BackendError::BadKeyframe { id, reason };
        if !is_finite(&input.world_from_camera) {
            return Err(bad("its pose is not finite".into()));
        }
        // A link without information is a predicted pose: a new piece of the map starts.
        let predicted_link = input.info.odometry.as_ref().is_some_and(|l| {
            !usable_information(&tangent_information(
                &input.world_from_camera,
                &l.information,
            ))
        });
        // The first keyframe of a run in a saved map that the map could not place: put at
        // a saved keyframe's pose with nothing to go on, its link only holds the piece's
        // gauge until a loop joins it.
        let guessed_start = predicted_link && self.newest.is_none();
        let sigma = if guessed_start {
            GUESSED_START_SIGMA
        } else {
            self.config.predicted_link_sigma
        };
        // 1. The odometry's link, to the previous keyframe or, when that one was culled, to
        // the keyframe it is kept relative to; the pose predicted through it.
        let odometry = input.info.odometry.as_ref().and_then(|l| {
            let (previous, live_from_previous) = self.map.live_ancestor(l.previous_id)?;
            Some(OdometryEdge {
                previous,
                previous_from_this: live_from_previous * l.previous_from_this,
                information: odometry_information(&input.world_from_camera, &l.information, sigma),
                active: false,
            })
        });
        if predicted_link {
            self.unjoined_from.get_or_insert(id);
            self.piece_starts.insert(id);
            if guessed_start {
                self.guessed_start = Some(id);
            }
        } else if let (Some(start), Some(e)) = (self.guessed_start, &odometry) {
            // Relocalized against a keyframe before the guessed start: in the map again.
            if e.previous < start {
                self.guessed_start = None;
            }
        }
        let predicted = odometry
            .as_ref()
            .and_then(|e| {
                Some(self.map.keyframe(e.previous)?.world_from_camera * e.previous_from_this)
            })
            .filter(is_finite)
            .unwrap_or(input.world_from_camera);
        let pose_cov = odometry
            .as_ref()
            .and_then(|o| o.information.try_inverse())
            .unwrap_or_else(|| Matrix6::identity() * 1e-4);
        let kf = Keyframe {
            id,
            frame_index: input.frame_index,
            t_s: input.t_s,
            world_from_camera: predicted,
            features: input
                .info
                .features
                .iter()
                .map(|f| Feature {
                    track_id: f.track_id,
                    px: f.px,
                    measurement: f.measurement,
                    descriptor: f.descriptor,
                    point: None,
                })
                .collect(),
            covisibility: BTreeMap::new(),
            odometry,
        };
        if !self.map.insert_keyframe(kf) {
            return Err(bad("a keyframe with this identifier exists".into()));
        }
        let previous = self
            .newest
            .and_then(|n| self.map.live_ancestor(n))
            .map(|(k, _)| k);
        self.first.get_or_insert(id);
        self.newest = Some(id);
        let mut report = KeyframeReport {
            keyframe_id: id,
            by_track: 0,
            by_orb: 0,
            fused: 0,
            new_points: 0,
            odometry_edge: false,
            depth_edges: 0,
            revisit_edge: false,
            outliers: 0,
            culled_points: 0,
            culled_keyframes: 0,
            solve: None,
            loop_closure: None,
            optimize_s: 0.0,
            time_s: 0.0,
        };
        // The depth links: constraints between the two poses for as long as both live.
        report.depth_edges = input
            .info
            .depth_links
            .iter()
            .filter(|l| self.add_depth_edge(id, l))
            .count();
        // 2. Association: tracks first, then ORB matching against the local map.
        let (by_track, pose_cov) = self.associate_tracks(id, pose_cov);
        report.by_track = by_track;
        (report.by_orb, report.fused) = self.match_local_map(id, previous, &pose_cov);
        // 3. New points for what matched nothing.
        let n = self.map.keyframe(id).map_or(0, |k| k.features.len());
        for f in 0..n {
            if self.map.create_point(id, f).is_some() {
                report.new_points += 1;
            }
        }
        // 4. A keyframe that re-observes too little is tied by its odometry.
        if report.by_track + report.by_orb < self.config.min_reobserved {
            if let Some(e) = self.map.odometry_mut(id) {
                e.active = true;
                report.odometry_edge = true;
            }
        }
        if self.config.mode == BackendMode::PoseGraph {
            self.measure_pose_edges(id);
        }
        report.revisit_edge = self.add_revisit_edge(id, input.depth_m.as_ref());
        // 5. Optimize the local window, drop outliers, cull.
        let window = local_window(&self.map, id, &self.config);
        let every = self.config.optimize_every_keyframes.max(1) as u64;
        let optimize_start = Instant::now();
        let (solve_report, outliers) = if id % every == 0 {
            self.optimize(&window, self.config.local_iterations)?
        } else {
            (None, 0)
        };
        report.optimize_s = optimize_start.elapsed().as_secs_f64();
        report.solve = solve_report;
        report.outliers = outliers;
        self.places.keep(id, &input.info.place_features);
        // A keyframe within `window_keyframes` of one tied to an old place (by a revisit link
        // or a loop) is tied to it through bundle adjustment: no loop to close there.
        if report.revisit_edge {
            self.last_tied = Some(id);
        }
        let reach = self.config.window_keyframes as u64;
        let tied = self
            .last_tied
            .is_some_and(|t| id.saturating_sub(t) <= reach);
        report.loop_closure = self.close_loop(id, tied)?;
        if report.loop_closure.is_some() {
            self.last_tied = Some(id);
        }
        self.tracks = self.map.keyframe(id).map_or_else(HashMap::new, |kf| {
            kf.features
                .iter()
                .filter_map(|f| Some((f.track_id, f.point?)))
                .collect()
        });
        report.culled_keyframes =
            self.cull_keyframes(&window) + self.cull_revisit(id) + self.cull_to_budget();
        report.culled_points = self.cull_points(id);
        // A keyframe that has left the window (and whose new points have had their grace
        // period) keeps only the features that observe a point.
        let settled = self.config.window_keyframes as u64 + self.config.point_grace_keyframes;
        if let Some(old) = id.checked_sub(settled) {
            self.map.drop_unmapped_features(old);
        }
        let window_poses = window
            .iter()
            .filter_map(|&k| Some((k, self.map.keyframe(k)?.world_from_camera)))
            .collect();
        report.time_s = start.elapsed().as_secs_f64();
        tracing::debug!(
            "keyframe {id}: {} map points by track, {} by ORB, {} new, {} fused, {} outliers{}",
            report.by_track,
            report.by_orb,
            report.new_points,
            report.fused,
            report.outliers,
            if report.odometry_edge {
                ", tied by its odometry"
            } else {
                ""
            }
        );
        Ok(KeyframeUpdate {
            keyframe_id: id,
            world_from_keyframe: self.map.pose_of(id).unwrap_or(predicted),
            window_poses,
            report,
        })
    }

    /// Optimizes `free` keyframes (and their points in bundle-adjustment mode), removes the
    /// outlier observations and optimizes again if there were any. Returns the first
    /// solve's report and the number of outliers.
    pub(crate) fn optimize(
        &mut self,
        free: &[KeyframeId],
        iterations: usize,
    ) -> Result<(Option<SolveReport>, usize), BackendError> {
        let with_points = self.config.mode == BackendMode::BundleAdjustment;
        let gauge = self.gauge(free);
        let max_fixed = self.config.max_fixed_keyframes;
        let mut mp: MapProblem = build(
            &self.map,
            free,
            &gauge,
            with_points,
            &self.pose_edges,
            max_fixed,
            &self.config,
        );
        if mp.problem.poses.iter().all(|p| p.fixed) && mp.problem.points.is_empty() {
            return Ok((None, 0));
        }
        let opts = SolverOptions {
            max_iterations: iterations,
            point_huber_chi2: Some(self.config.huber_chi2),
            ..SolverOptions::default()
        };
        let first = solve(&mut mp.problem, &opts)?;
        mp.write_back(&mut self.map);
        if !with_points {
            self.place_points(free);
            return Ok((Some(first), 0));
        }
        let outliers = mp.outliers(self.config.outlier_chi2);
        for &(p, k) in &outliers {
            self.map.remove_observation(p, k);
        }
        if !outliers.is_empty() {
            let mut again = build(
                &self.map,
                free,
                &gauge,
                true,
                &self.pose_edges,
                max_fixed,
                &self.config,
            );
            solve(&mut again.problem, &opts)?;
            again.write_back(&mut self.map);
        }
        Ok((Some(first), outliers.len()))
    }

    /// The keyframes held fixed for the gauge: the first keyframe, and when the window has
    /// no fixed neighbour at all, its oldest keyframe.
    fn gauge(&self, free: &[KeyframeId]) -> BTreeSet<KeyframeId> {
        let mut g = BTreeSet::new();
        if let Some(f) = self.first {
            g.insert(f);
        }
        let free_set: BTreeSet<KeyframeId> = free.iter().copied().collect();
        let anchored = free.iter().any(|k| g.contains(k))
            || free.iter().filter_map(|k| self.map.keyframe(*k)).any(|kf| {
                kf.covisibility.keys().any(|o| !free_set.contains(o))
                    || kf
                        .odometry
                        .as_ref()
                        .is_some_and(|e| e.active && !free_set.contains(&e.previous))
            });
        if !anchored {
            if let Some(&oldest) = free.iter().min() {
                g.insert(oldest);
            }
        }
        g
    }

    /// The final optimization, of `final_iterations`: the newest local window, or from the
    /// oldest keyframe that links tie (see `window::final_free`).
    pub fn finish(&mut self) -> Result<Option<SolveReport>, BackendError> {
        let free = final_free(&self.map, &self.pose_edges, &self.config);
        if free.is_empty() {
            return Ok(None);
        }
        let (report, _) = self.optimize(&free, self.config.final_iterations)?;
        if let Some(newest) = self.newest {
            self.cull_points(newest);
        }
        Ok(report)
    }
}
