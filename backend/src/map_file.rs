//! Maps saved to a file and read back: a run's keyframes, points, descriptors and
//! covisibility, so that a later run can localize in the same frame and extend the map.
//!
//! # Format `stride-map`, version 2
//!
//! One JSON object (UTF-8), written atomically (a temporary file renamed over the target):
//!
//! * `format`: `"stride-map"`; `version`: `2` (version 1 is the same without
//!   `place_features`, and is read). A reader refuses other formats and newer versions.
//! * `camera`: `width`, `height` (px), `fx`, `fy`, `cx`, `cy` (px) and `distortion`
//!   (Brown-Conrady `[k1, k2, p1, p2, k3]`, zeros for none) of the camera the map was made
//!   with. A run with another camera is refused: descriptors and depth noise depend on it.
//! * `world_from_map`: the rigid transform from the map's frame (the frame its keyframe
//!   poses and points are in: the first camera of the run that made it) into that run's
//!   world (z up when `gravity_aligned`), as `translation_m` `[x, y, z]` and
//!   `rotation_xyzw` (unit quaternion); `world` says where that world came from.
//! * `keyframes`, by increasing `id`: `id`, `frame_index`, `t_s` (s), `world_from_camera`
//!   (map frame, same layout as `world_from_map`), `features` and `covisibility`
//!   (`[[other keyframe id, shared points], ...]`, non-zero counts, by id), and
//!   `odometry` (`previous` keyframe id, `previous_from_this`, `information`: 36 numbers,
//!   row-major 6x6, translation then rotation, and `active`) or `null`, and, when the run
//!   kept them, `place_features` (the keyframe's multi-scale ORB features with depth, by
//!   which a later run relocalizes and closes loops; layout in [`crate::map_file_places`]).
//! * each feature: `track_id`, `px` `[column, row]` (px), `p_camera_m` `[x, y, z]` and
//!   `cov_camera_m2` (9 numbers, row-major) of its depth measurement in the keyframe's camera
//!   frame (or both `null`), `descriptor` (ORB, 64 hex digits, or `null`), and `point` (the
//!   id of the map point it observes, or `null`).
//! * `points`, by increasing `id`: `id`, `p_world_m` (map frame), `information_world`
//!   (9 numbers, 1/m^2), `descriptor`, `visible`, `found` (matching statistics) and
//!   `created_by` (a keyframe id). A point's observations are the features naming it.
//!
//! Reading checks every cross-reference (a feature naming an unknown point, a point that no
//! feature observes, an unknown keyframe, a duplicated id), that every number is finite,
//! and that the covisibility written agrees with the observations; any failure is an error
//! naming the file and what is wrong.

use crate::map::{Feature, Keyframe, KeyframeId, Map, OdometryEdge};
use crate::map_file_places::PlaceFeaturesDto;
use nalgebra::{Isometry3, Matrix3, Matrix6, Point2, Point3};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use stride_core::camera::PinholeCamera;
use stride_core::pose::{pose_from_translation_quaternion, pose_to_translation_quaternion};
use stride_frontend::features::OrbDescriptor;
use stride_frontend::points::Measurement;
use stride_frontend::recovery::{Anchor, AnchorPoint};
use stride_frontend::PlaceFeature;

/// The format's name, the first field of every file.
pub const FORMAT: &str = "stride-map";
/// The format version this build writes and the newest it reads.
pub const VERSION: u32 = 2;

/// Why a map file could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum MapFileError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// The file is not valid JSON of this format.
    #[error("{path}: not a stride map: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// What the parser said (with line and column).
        message: String,
    },
    /// Another format or a newer version.
    #[error("{path}: format {format:?} version {version}; this build reads {FORMAT:?} up to version {VERSION}")]
    Version {
        /// The file.
        path: PathBuf,
        /// Its format field.
        format: String,
        /// Its version field.
        version: u32,
    },
    /// Well-formed, but inconsistent.
    #[error("{path}: corrupt map: {reason}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Made with another camera.
    #[error("{path}: the map was made with camera {saved}, this run's camera is {current}")]
    Camera {
        /// The file.
        path: PathBuf,
        /// The map's camera.
        saved: String,
        /// The run's camera.
        current: String,
    },
}

/// A rigid transform as written: translation (m) and unit quaternion `[x, y, z, w]`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PoseDto {
    translation_m: [f64; 3],
    rotation_xyzw: [f64; 4],
}

impl PoseDto {
    fn from_iso(p: &Isometry3<f64>) -> Self {
        let (translation_m, rotation_xyzw) = pose_to_translation_quaternion(p);
        Self {
            translation_m,
            rotation_xyzw,
        }
    }

    /// The pose, when its numbers are finite and its quaternion of unit length (within
    /// 1e-6: a file's rotations are written normalized).
    fn to_iso(self) -> Option<Isometry3<f64>> {
        let (pose, norm) =
            pose_from_translation_quaternion(self.translation_m, self.rotation_xyzw).ok()?;
        ((norm - 1.0).abs() <= 1e-6).then_some(pose)
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraDto {
    width: u32,
    height: u32,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    distortion: [f64; 5],
}

impl CameraDto {
    fn of(c: &PinholeCamera) -> Self {
        Self {
            width: c.width(),
            height: c.height(),
            fx: c.fx(),
            fy: c.fy(),
            cx: c.cx(),
            cy: c.cy(),
            distortion: c.distortion().map_or([0.0; 5], |d| d.to_array()),
        }
    }

    /// Equal up to what a decimal round trip of the settings could change.
    fn same(&self, o: &Self) -> bool {
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1.0);
        let d = self.distortion.iter().zip(&o.distortion);
        (self.width, self.height) == (o.width, o.height)
            && close(self.fx, o.fx)
            && close(self.fy, o.fy)
            && close(self.cx, o.cx)
            && close(self.cy, o.cy)
            && d.into_iter().all(|(a, b)| close(*a, *b))
    }

    fn describe(&self) -> String {
        format!(
            "{}x{} fx {} fy {} cx {} cy {} distortion {:?}",
            self.width, self.height, self.fx, self.fy, self.cx, self.cy, self.distortion
        )
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FeatureDto {
    track_id: u64,
    px: [f32; 2],
    p_camera_m: Option<[f64; 3]>,
    cov_camera_m2: Option<[f64; 9]>,
    descriptor: Option<String>,
    point: Option<u64>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct OdometryDto {
    previous: u64,
    previous_from_this: PoseDto,
    information: Vec<f64>,
    active: bool,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct KeyframeDto {
    id: u64,
    frame_index: usize,
    t_s: f64,
    world_from_camera: PoseDto,
    features: Vec<FeatureDto>,
    covisibility: Vec<(u64, u32)>,
    odometry: Option<OdometryDto>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    place_features: Option<PlaceFeaturesDto>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PointDto {
    id: u64,
    p_world_m: [f64; 3],
    information_world: [f64; 9],
    descriptor: Option<String>,
    visible: u32,
    found: u32,
    created_by: u64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileDto {
    format: String,
    version: u32,
    camera: CameraDto,
    world_from_map: PoseDto,
    world: String,
    gravity_aligned: bool,
    keyframes: Vec<KeyframeDto>,
    points: Vec<PointDto>,
}

/// Only the header, read first so that a newer version gets its own error.
#[derive(Deserialize)]
struct HeaderDto {
    format: String,
    version: u32,
}

/// A map with what a later run needs to use it.
#[derive(Debug, Clone)]
pub struct SavedMap {
    /// The camera it was made with.
    pub camera: PinholeCamera,
    /// Keyframes and points, in the map's frame.
    pub map: Map,
    /// `world_from_map` (m): the map's frame in the world of the run that made it.
    pub world_from_map: Isometry3<f64>,
    /// Where that world came from (e.g. "floor"), for reports.
    pub world: String,
    /// Whether that world is gravity-aligned (z up).
    pub gravity_aligned: bool,
    /// The place features of the keyframes that have them (camera frame, m), by keyframe.
    pub place_features: BTreeMap<KeyframeId, Vec<PlaceFeature>>,
}

/// An ORB descriptor as 64 hex digits.
pub(crate) fn hex(d: &OrbDescriptor) -> String {
    d.iter().map(|b| format!("{b:02x}")).collect()
}

/// [`hex`]'s descriptor back; `None` unless `s` is 64 hex digits.
pub(crate) fn unhex(s: &str) -> Option<OrbDescriptor> {
    let mut out = [0u8; 32];
    if s.len() != 64 || !s.is_ascii() {
        return None;
    }
    for (i, o) in out.iter_mut().enumerate() {
        *o = u8::from_str_radix(s.get(2 * i..2 * i + 2)?, 16).ok()?;
    }
    Some(out)
}

fn finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

impl SavedMap {
    /// The map's keyframes as relocalization needs them: each keyframe's features that
    /// observe a map point and have a descriptor and a measurement, with the (optimized)
    /// point in the keyframe's camera frame, then its place features as measured.
    pub fn anchors(&self) -> Vec<Anchor> {
        let map = &self.map;
        map.keyframes()
            .values()
            .map(|kf| {
                let camera_from_world = kf.world_from_camera.inverse();
                let points = kf
                    .features
                    .iter()
                    .filter_map(|f| {
                        let p = map.point(f.point?)?;
                        Some(AnchorPoint {
                            px: f.px,
                            descriptor: f.descriptor?,
                            p_camera: Measurement {
                                p: camera_from_world * p.p_world,
                                cov: f.measurement?.cov,
                            },
                        })
                    })
                    .chain(
                        self.place_features
                            .get(&kf.id)
                            .into_iter()
                            .flatten()
                            .map(|f| AnchorPoint {
                                px: f.px,
                                descriptor: f.descriptor,
                                p_camera: f.measurement,
                            }),
                    )
                    .collect();
                Anchor {
                    id: kf.id,
                    world_from_camera: kf.world_from_camera,
                    points,
                }
            })
            .collect()
    }

    /// The identifier after the map's keyframes (and culled keyframes): where a run that
    /// extends the map numbers its own.
    pub fn next_keyframe_id(&self) -> KeyframeId {
        let ids = self.map.keyframes().keys().chain(self.map.culled().keys());
        ids.max().map_or(0, |m| m + 1)
    }

    /// Writes the map to `path` atomically (a temporary file beside it, then a rename).
    pub fn save(&self, path: &Path) -> Result<(), MapFileError> {
        let map = &self.map;
        let keyframes = map.keyframes().values().map(|kf| {
            let places = self.place_features.get(&kf.id);
            KeyframeDto {
                place_features: places.map(|f| PlaceFeaturesDto::of(f)),
                ..keyframe_dto(map, kf)
            }
        });
        let points = map.points().iter().map(|(&id, p)| PointDto {
            id,
            p_world_m: [p.p_world.x, p.p_world.y, p.p_world.z],
            information_world: mat3(&p.information_world),
            descriptor: p.descriptor.as_ref().map(hex),
            visible: p.visible,
            found: p.found,
            created_by: p.created_by,
        });
        let file = FileDto {
            format: FORMAT.into(),
            version: VERSION,
            camera: CameraDto::of(&self.camera),
            world_from_map: PoseDto::from_iso(&self.world_from_map),
            world: self.world.clone(),
            gravity_aligned: self.gravity_aligned,
            keyframes: keyframes.collect(),
            points: points.collect(),
        };
        let io = |source| MapFileError::Io {
            path: path.to_path_buf(),
            source,
        };
        let bytes = serde_json::to_vec(&file).map_err(|e| io(std::io::Error::other(e)))?;
        stride_output::fs::write_atomic(path, &bytes).map_err(io)
    }

    /// Reads a map written by [`SavedMap::save`], checking it (see the module
    /// documentation), and that it was made with `camera`.
    pub fn load(path: &Path, camera: &PinholeCamera) -> Result<Self, MapFileError> {
        let p = || path.to_path_buf();
        let bytes = std::fs::read(path).map_err(|source| MapFileError::Io { path: p(), source })?;
        let parse = |e: serde_json::Error| MapFileError::Parse {
            path: p(),
            message: e.to_string(),
        };
        let header: HeaderDto = serde_json::from_slice(&bytes).map_err(parse)?;
        if header.format != FORMAT || header.version > VERSION {
            return Err(MapFileError::Version {
                path: p(),
                format: header.format,
                version: header.version,
            });
        }
        let file: FileDto = serde_json::from_slice(&bytes).map_err(parse)?;
        let current = CameraDto::of(camera);
        if !file.camera.same(&current) {
            return Err(MapFileError::Camera {
                path: p(),
                saved: file.camera.describe(),
                current: current.describe(),
            });
        }
        let corrupt = |reason: String| MapFileError::Corrupt { path: p(), reason };
        let world_from_map = file
            .world_from_map
            .to_iso()
            .ok_or_else(|| corrupt("world_from_map is not a finite rigid transform".into()))?;
        let map = restore(&file).map_err(corrupt)?;
        let place_features = file
            .keyframes
            .iter()
            .filter_map(|k| Some((k.id, k.place_features.as_ref()?)))
            .map(|(id, dto)| Ok((id, dto.features(id)?)))
            .collect::<Result<_, String>>()
            .map_err(corrupt)?;
        Ok(Self {
            camera: *camera,
            map,
            world_from_map,
            world: file.world,
            gravity_aligned: file.gravity_aligned,
            place_features,
        })
    }
}

fn mat3(m: &Matrix3<f64>) -> [f64; 9] {
    let mut out = [0.0; 9];
    for (i, o) in out.iter_mut().enumerate() {
        *o = m[(i / 3, i % 3)];
    }
    out
}

fn keyframe_dto(map: &Map, kf: &Keyframe) -> KeyframeDto {
    let features = kf.features.iter().map(|f| FeatureDto {
        track_id: f.track_id,
        px: [f.px.x, f.px.y],
        p_camera_m: f.measurement.map(|m| [m.p.x, m.p.y, m.p.z]),
        cov_camera_m2: f.measurement.map(|m| mat3(&m.cov)),
        descriptor: f.descriptor.as_ref().map(hex),
        point: f.point,
    });
    // A link to a keyframe culled since is written to the keyframe it is kept relative to.
    let odometry = kf.odometry.as_ref().and_then(|e| {
        let (previous, live_from_previous) = map.live_ancestor(e.previous)?;
        Some(OdometryDto {
            previous,
            previous_from_this: PoseDto::from_iso(&(live_from_previous * e.previous_from_this)),
            information: e.information.transpose().iter().copied().collect(),
            active: e.active,
        })
    });
    KeyframeDto {
        id: kf.id,
        frame_index: kf.frame_index,
        t_s: kf.t_s,
        world_from_camera: PoseDto::from_iso(&kf.world_from_camera),
        features: features.collect(),
        covisibility: kf.covisibility.iter().map(|(&k, &n)| (k, n)).collect(),
        odometry,
        place_features: None,
    }
}

fn feature(kf: u64, i: usize, f: &FeatureDto) -> Result<Feature, String> {
    let at = || format!("keyframe {kf} feature {i}");
    let measurement = match (f.p_camera_m, f.cov_camera_m2) {
        (Some(p), Some(c)) if finite(&p) && finite(&c) => Some(Measurement {
            p: Point3::from(p),
            cov: Matrix3::from_row_slice(&c),
        }),
        (None, None) => None,
        _ => return Err(format!("{}: measurement incomplete or not finite", at())),
    };
    let descriptor = match &f.descriptor {
        Some(s) => Some(
            unhex(s).ok_or_else(|| format!("{}: descriptor {s:?} is not 64 hex digits", at()))?,
        ),
        None => None,
    };
    Ok(Feature {
        track_id: f.track_id,
        px: Point2::new(f.px[0], f.px[1]),
        measurement,
        descriptor,
        point: None,
    })
}

/// Builds the map through [`Map`]'s own methods (so that its invariants hold), then checks
/// the written covisibility against the one the observations give.
fn restore(file: &FileDto) -> Result<Map, String> {
    let mut map = Map::new();
    let ids: BTreeSet<u64> = file.keyframes.iter().map(|k| k.id).collect();
    if ids.len() != file.keyframes.len() {
        return Err("a keyframe id appears twice".into());
    }
    for k in &file.keyframes {
        let pose = k.world_from_camera.to_iso();
        let world_from_camera =
            pose.ok_or_else(|| format!("keyframe {}: pose not a finite rigid transform", k.id))?;
        let features = k.features.iter().enumerate();
        let features = features
            .map(|(i, f)| feature(k.id, i, f))
            .collect::<Result<_, _>>()?;
        let odometry = k
            .odometry
            .as_ref()
            .map(|o| odometry(k.id, o, &ids))
            .transpose()?;
        map.insert_keyframe(Keyframe {
            id: k.id,
            frame_index: k.frame_index,
            t_s: k.t_s,
            world_from_camera,
            features,
            covisibility: BTreeMap::new(),
            odometry,
        });
    }
    // Each point's observations, in keyframe order.
    let mut observers: BTreeMap<u64, Vec<(KeyframeId, usize)>> = BTreeMap::new();
    for k in &file.keyframes {
        for (i, f) in k.features.iter().enumerate() {
            if let Some(p) = f.point {
                observers.entry(p).or_default().push((k.id, i));
            }
        }
    }
    let mut known = BTreeSet::new();
    for p in &file.points {
        if !known.insert(p.id) {
            return Err(format!("point id {} appears twice", p.id));
        }
        if !finite(&p.p_world_m) || !finite(&p.information_world) {
            return Err(format!("point {}: a number is not finite", p.id));
        }
        let obs = observers.get(&p.id).map_or(&[][..], Vec::as_slice);
        let Some((&(k0, f0), rest)) = obs.split_first() else {
            return Err(format!("point {}: no feature observes it", p.id));
        };
        let bad_obs = |k, f| {
            format!("point {}: keyframe {k} feature {f} cannot observe it (no measurement, or a second observation by the same keyframe)", p.id)
        };
        let id = map.create_point(k0, f0).ok_or_else(|| bad_obs(k0, f0))?;
        for &(k, f) in rest {
            if !map.add_observation(id, k, f) {
                return Err(bad_obs(k, f));
            }
        }
        let descriptor = match &p.descriptor {
            Some(s) => Some(unhex(s).ok_or_else(|| format!("point {}: bad descriptor", p.id))?),
            None => None,
        };
        map.set_position(id, Point3::from(p.p_world_m));
        if let Some(mp) = map.point_mut(id) {
            mp.information_world = Matrix3::from_row_slice(&p.information_world);
            mp.descriptor = descriptor;
            (mp.visible, mp.found, mp.created_by) = (p.visible, p.found, p.created_by);
        }
    }
    if let Some(unknown) = observers.keys().find(|p| !known.contains(p)) {
        return Err(format!(
            "a feature observes point {unknown}, which is not in the file"
        ));
    }
    for k in &file.keyframes {
        let rebuilt = map.keyframe(k.id).map(|kf| &kf.covisibility);
        let written: BTreeMap<u64, u32> = k.covisibility.iter().copied().collect();
        if rebuilt != Some(&written) {
            return Err(format!(
                "keyframe {}: its covisibility disagrees with the points' observations",
                k.id
            ));
        }
    }
    Ok(map)
}

fn odometry(id: u64, o: &OdometryDto, ids: &BTreeSet<u64>) -> Result<OdometryEdge, String> {
    let bad = |what: &str| format!("keyframe {id}: odometry link {what}");
    if !ids.contains(&o.previous) {
        return Err(bad(&format!("names unknown keyframe {}", o.previous)));
    }
    let previous_from_this = o
        .previous_from_this
        .to_iso()
        .ok_or_else(|| bad("pose is not rigid"))?;
    if o.information.len() != 36 || !finite(&o.information) {
        return Err(bad("information is not 36 finite numbers"));
    }
    Ok(OdometryEdge {
        previous: o.previous,
        previous_from_this,
        information: Matrix6::from_row_slice(&o.information),
        active: o.active,
    })
}

#[cfg(test)]
#[path = "map_file_tests.rs"]
mod tests;
