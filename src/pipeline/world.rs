//! The world frame of every output: z up (gravity-aligned), metres. The SLAM runs in the
//! frame of its first camera (x right, y down, z forward); `world_from_slam` places that
//! frame in the world. Its attitude comes from, in this order of preference
//! ([`WorldPlan`]):
//!
//! 1. a reference trajectory, when asked (the ground truth, to score against a true
//!    terrain): the first frame it covers gets its pose;
//! 2. a given mounting (`--camera-pitch-deg`, `--camera-height-m`): the camera pitched down
//!    by that angle, that high above the ground, without roll;
//! 3. an accelerometer (`accelerometer.txt`): world z is the mean specific force, each
//!    sample rotated into the SLAM's frame by its frame's pose, so that the walk's own
//!    accelerations average out; the floor, when seen, gives the height;
//! 4. the floor: a RANSAC plane in the depth of the first frames and of every keyframe (a
//!    walking robot's camera sees the ground), placed by their final poses and averaged;
//!    world z is the floor's normal, the floor is at z = 0, and world x is the first
//!    camera's forward direction along the floor;
//! 5. otherwise the first camera's frame itself, which is not gravity-aligned: the run
//!    says so (a warning and `world_frame.source = "first camera"` in report.json).

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use stride_core::camera::PinholeCamera;
use stride_core::image::DepthImage;
use stride_core::plane::{ransac_plane, Plane};
use stride_core::rng::SplitMix64;
use stride_datasets::accelerometer::AccelSample;

/// The floor is looked for in every one of the first frames (then in keyframes only).
pub const FLOOR_SEARCH_FRAMES: usize = 10;
/// Depth pixels sampled for the floor: every this many pixels along rows and columns.
const FLOOR_PIXEL_STEP: u32 = 12;
/// Depths used for the floor (m): the near, accurate range of a PrimeSense camera.
const FLOOR_DEPTH_M: (f64, f64) = (0.3, 4.0);
/// A point belongs to the floor within this distance (m).
const FLOOR_THRESHOLD_M: f64 = 0.02;
/// The floor holds at least this fraction of the sampled points.
const FLOOR_MIN_FRACTION: f64 = 0.15;
/// The floor's normal is within 75 degrees of the camera's up direction (-y): a camera
/// pitched down by up to 75 degrees still finds it, a wall in front of it never counts.
const FLOOR_MIN_UP_COS: f64 = 0.26;
/// The camera is between these heights above the floor (m).
const FLOOR_HEIGHT_M: (f64, f64) = (0.05, 3.0);

/// Where the world frame's attitude came from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum WorldSource {
    /// The floor plane in the depth of the first frames, averaged.
    Floor {
        /// Frames whose depth gave a floor.
        frames: usize,
        /// Sampled depth points on the floor, over those frames.
        inliers: usize,
    },
    /// The mean specific force of an accelerometer (its height from the floor, when seen).
    Accelerometer {
        /// Samples averaged.
        samples: usize,
        /// Frames whose depth gave a floor (for the height).
        floor_frames: usize,
    },
    /// The mounting given by the user.
    Mounting,
    /// A reference trajectory (ground truth, or a robot's own state estimate): the pose
    /// it gives the first frame it covers.
    Reference,
    /// Nothing: the first camera's frame (not gravity-aligned).
    FirstCamera,
    /// The world of a saved map the run localized in.
    SavedMap {
        /// Whether that world is gravity-aligned.
        gravity_aligned: bool,
    },
}

/// How the world frame is to be found.
#[derive(Debug, Clone, PartialEq)]
pub enum WorldPlan {
    /// From the floor in the first [`FLOOR_SEARCH_FRAMES`] frames and in keyframes, else
    /// the first camera.
    Floor,
    /// From the camera's mounting: pitched down by `pitch_deg` (degrees), `height_m` (m)
    /// above the ground.
    Mounting {
        /// Downward pitch of the optical axis (degrees).
        pitch_deg: f64,
        /// Height of the camera above the ground (m).
        height_m: f64,
    },
    /// From an accelerometer's samples (camera frame), the floor giving the height.
    Accelerometer(Vec<AccelSample>),
    /// The world of a reference trajectory (`world_from_camera`, z up): the first frame
    /// within its time span gets the reference's pose there.
    Reference(stride_core::trajectory::Trajectory),
    /// A world known beforehand (a saved map's).
    Given(WorldFrame),
}

/// The world frame: `world_from_slam` and where it came from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldFrame {
    /// Maps points in the SLAM's frame (its first camera's) into the world (z up, m).
    pub world_from_slam: Isometry3<f64>,
    /// Where its attitude came from.
    pub source: WorldSource,
}

impl WorldFrame {
    /// The world of `reference` (`world_from_camera`, z up), given the SLAM's poses of the
    /// frames at `(t_s, slam_from_camera)`: the first frame the reference covers gets the
    /// reference's pose. `None` when it covers none.
    pub fn from_reference(
        reference: &stride_core::trajectory::Trajectory,
        frames: impl IntoIterator<Item = (f64, Isometry3<f64>)>,
    ) -> Option<Self> {
        frames.into_iter().find_map(|(t_s, slam_from_camera)| {
            let world_from_camera = reference.interpolate(t_s)?;
            Some(Self {
                world_from_slam: world_from_camera * slam_from_camera.inverse(),
                source: WorldSource::Reference,
            })
        })
    }

    /// The first camera's frame, not gravity-aligned.
    pub fn first_camera() -> Self {
        Self {
            world_from_slam: Isometry3::identity(),
            source: WorldSource::FirstCamera,
        }
    }

    /// A camera mounted looking forward along world x, pitched down by `pitch_deg`
    /// (degrees), `height_m` (m) above the ground, without roll; the SLAM's frame is this
    /// camera's.
    pub fn from_mounting(pitch_deg: f64, height_m: f64) -> Self {
        let p = pitch_deg.to_radians();
        let forward = Vector3::new(p.cos(), 0.0, -p.sin());
        let right = Vector3::new(0.0, -1.0, 0.0);
        let down = forward.cross(&right);
        let rotation =
            Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[right, down, forward]));
        Self {
            world_from_slam: Isometry3::from_parts(
                Translation3::new(0.0, 0.0, height_m),
                UnitQuaternion::from_rotation_matrix(&rotation),
            ),
            source: WorldSource::Mounting,
        }
    }

    /// The world of the floors seen by several cameras: each `(slam_from_camera, floor,
    /// inliers)` pairs a camera's pose in the SLAM's frame with the floor it saw (camera
    /// coordinates, normal towards the camera, see [`floor_in_camera`]). World z is the mean
    /// of their normals, the floor (their mean height) is at z = 0, world x is the first
    /// camera's forward direction along the floor, and the first camera is above the origin.
    /// `None` without floors.
    pub fn from_floors(floors: &[(Isometry3<f64>, Plane, usize)]) -> Option<Self> {
        let (mut up, mut height_m, mut inliers) = (Vector3::zeros(), 0.0, 0);
        for (slam_from_camera, floor, n) in floors {
            let normal = slam_from_camera.rotation * floor.normal.into_inner();
            up += normal;
            // Height of the SLAM's origin above this floor: the camera's height minus the
            // camera's offset from the origin along the normal.
            height_m += floor.distance_m(&Point3::origin())
                - normal.dot(&slam_from_camera.translation.vector);
            inliers += n;
        }
        let z_w = up.try_normalize(1e-9)?;
        let height_m = height_m / floors.len() as f64;
        Some(Self {
            world_from_slam: world_from_up(z_w, height_m)?,
            source: WorldSource::Floor {
                frames: floors.len(),
                inliers,
            },
        })
    }

    /// The world of an accelerometer: world z is the mean specific force of `samples`
    /// (camera frame, see `stride_datasets::accelerometer`), each rotated into the SLAM's
    /// frame by the pose of the frame nearest in time (`frames`: `(t_s, slam_from_camera)`
    /// in time order); over a walk the robot's own accelerations average out and gravity's
    /// reaction, up, remains. The first camera's height comes from `floors` when there are
    /// some (as [`WorldFrame::from_floors`]), else it is 0. `None` without samples within
    /// the frames' time span (and 50 ms around it).
    pub fn from_accelerometer(
        samples: &[AccelSample],
        frames: &[(f64, Isometry3<f64>)],
        floors: &[(Isometry3<f64>, Plane, usize)],
    ) -> Option<Self> {
        const MARGIN_S: f64 = 0.05;
        let (first, last) = (frames.first()?.0, frames.last()?.0);
        let mut sum = Vector3::zeros();
        let mut used = 0;
        for (t, f) in samples {
            if *t < first - MARGIN_S || *t > last + MARGIN_S {
                continue;
            }
            let i = frames.partition_point(|(ft, _)| ft < t);
            let nearest = [i.checked_sub(1), Some(i)]
                .into_iter()
                .flatten()
                .filter_map(|k| frames.get(k))
                .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()))?;
            sum += nearest.1.rotation * f;
            used += 1;
        }
        let z_w = sum.try_normalize(1e-9)?;
        let height_m = if floors.is_empty() {
            0.0
        } else {
            floors
                .iter()
                .map(|(slam_from_camera, floor, _)| {
                    let normal = slam_from_camera.rotation * floor.normal.into_inner();
                    floor.distance_m(&Point3::origin())
                        - normal.dot(&slam_from_camera.translation.vector)
                })
                .sum::<f64>()
                / floors.len() as f64
        };
        Some(Self {
            world_from_slam: world_from_up(z_w, height_m)?,
            source: WorldSource::Accelerometer {
                samples: used,
                floor_frames: floors.len(),
            },
        })
    }

    /// Whether z is up (every source but the first camera's frame, and a saved map's
    /// world that was not).
    pub fn is_gravity_aligned(&self) -> bool {
        !matches!(
            self.source,
            WorldSource::FirstCamera
                | WorldSource::SavedMap {
                    gravity_aligned: false
                }
        )
    }

    /// A one-line description for logs and reports.
    pub fn describe(&self) -> String {
        let (roll_deg, pitch_deg, height_m) = self.first_camera_attitude();
        let how = match self.source {
            WorldSource::Floor { frames, inliers } => {
                format!("the floor seen in {frames} frames ({inliers} depth points)")
            }
            WorldSource::Accelerometer {
                samples,
                floor_frames,
            } => format!(
                "the accelerometer ({samples} samples; height from the floor in {floor_frames} frames)"
            ),
            WorldSource::Mounting => "the given camera mounting".into(),
            WorldSource::Reference => {
                "the reference trajectory (its pose of the first frame it covers)".into()
            }
            WorldSource::FirstCamera => {
                return "the first camera's frame (no floor found, no mounting given): \
                        not gravity-aligned"
                    .into()
            }
            WorldSource::SavedMap {
                gravity_aligned: false,
            } => return "the saved map's frame: not gravity-aligned".into(),
            WorldSource::SavedMap { .. } => "the saved map's world".into(),
        };
        format!(
            "z up from {how}: first camera {height_m:.3} m above the floor, pitched down \
             {pitch_deg:.1} deg, roll {roll_deg:.1} deg"
        )
    }

    /// The first camera's roll and downward pitch (degrees) and height (m) in the world.
    pub fn first_camera_attitude(&self) -> (f64, f64, f64) {
        let r = self.world_from_slam.rotation;
        let forward = r * Vector3::z();
        let right = r * Vector3::x();
        let pitch_deg = (-forward.z).clamp(-1.0, 1.0).asin().to_degrees();
        let roll_deg = (-right.z).clamp(-1.0, 1.0).asin().to_degrees();
        (roll_deg, pitch_deg, self.world_from_slam.translation.z)
    }
}

/// The floor in a depth image (camera coordinates, normal towards the camera) and the
/// number of sampled depth points on it: a seeded RANSAC plane below the camera holding
/// enough of the points. `None` when there is none.
pub fn floor_in_camera(depth: &DepthImage, camera: &PinholeCamera) -> Option<(Plane, usize)> {
    let mut points = Vec::new();
    for v in (0..depth.height()).step_by(FLOOR_PIXEL_STEP as usize) {
        for u in (0..depth.width()).step_by(FLOOR_PIXEL_STEP as usize) {
            let d = f64::from(depth.get(u, v)?);
            if d >= FLOOR_DEPTH_M.0 && d <= FLOOR_DEPTH_M.1 {
                let px = nalgebra::Point2::new(f64::from(u), f64::from(v));
                points.push(camera.unproject(&px, d));
            }
        }
    }
    let camera_up = -Vector3::y();
    let below = |plane: &Plane| {
        let p = plane.facing(&Point3::origin());
        let height = p.distance_m(&Point3::origin());
        p.normal.dot(&camera_up) >= FLOOR_MIN_UP_COS
            && (FLOOR_HEIGHT_M.0..=FLOOR_HEIGHT_M.1).contains(&height)
    };
    let mut rng = SplitMix64::new(0xF1007);
    let (plane, inliers) = ransac_plane(&points, FLOOR_THRESHOLD_M, 150, &mut rng, below)?;
    ((inliers as f64) >= FLOOR_MIN_FRACTION * points.len() as f64)
        .then(|| (plane.facing(&Point3::origin()), inliers))
}

/// `world_from_slam` for a world whose z axis is `z_w` (unit, SLAM coordinates), whose x
/// axis is the first camera's forward direction along the floor (its image's up direction
/// when it looks straight down), with the SLAM's origin `height_m` above the world's.
fn world_from_up(z_w: Vector3<f64>, height_m: f64) -> Option<Isometry3<f64>> {
    let forward = Vector3::z();
    let image_up = -Vector3::y();
    let x_w = (forward - z_w * z_w.dot(&forward))
        .try_normalize(1e-6)
        .or_else(|| (image_up - z_w * z_w.dot(&image_up)).try_normalize(1e-9))?;
    let y_w = z_w.cross(&x_w);
    // Rows of world_from_slam's rotation are the world axes in the SLAM's coordinates.
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_rows(&[
        x_w.transpose(),
        y_w.transpose(),
        z_w.transpose(),
    ]));
    Some(Isometry3::from_parts(
        Translation3::new(0.0, 0.0, height_m),
        UnitQuaternion::from_rotation_matrix(&rotation),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mounted_camera_and_its_floor_give_the_same_world() {
        // A camera 0.45 m above a flat floor, pitched down 35 degrees: render the floor's
        // depth, find it, and compare with the mounting.
        let mounted = WorldFrame::from_mounting(35.0, 0.45);
        let (roll, pitch, height) = mounted.first_camera_attitude();
        assert!(roll.abs() < 1e-9 && (pitch - 35.0).abs() < 1e-9 && (height - 0.45).abs() < 1e-12);
        let camera = PinholeCamera::new(260.0, 260.0, 159.5, 119.5, 320, 240).unwrap();
        let world_from_camera = mounted.world_from_slam;
        let o = world_from_camera.translation.vector;
        let mut depth = DepthImage::filled(320, 240, 0.0);
        for v in 0..240 {
            for u in 0..320 {
                let ray = camera.unproject(&nalgebra::Point2::new(f64::from(u), f64::from(v)), 1.0);
                let dir = world_from_camera.rotation * ray.coords;
                if dir.z < -1e-6 {
                    let z = (-o.z / dir.z) as f32; // ray depth = z along the optical axis
                    if let Some(d) = depth.get_mut(u, v) {
                        *d = z;
                    }
                }
            }
        }
        let (floor, inliers) = floor_in_camera(&depth, &camera).unwrap();
        let found = WorldFrame::from_floors(&[(Isometry3::identity(), floor, inliers)]).unwrap();
        assert!(matches!(found.source, WorldSource::Floor { frames: 1, .. }));
        let (roll, pitch, height) = found.first_camera_attitude();
        assert!(
            roll.abs() < 0.01 && (pitch - 35.0).abs() < 0.01,
            "{roll} {pitch}"
        );
        assert!((height - 0.45).abs() < 1e-4, "{height}");
        let delta = mounted.world_from_slam.inverse() * found.world_from_slam;
        assert!(delta.rotation.angle() < 1e-3 && delta.translation.vector.norm() < 1e-3);
        // A wall straight ahead is not a floor.
        let wall = DepthImage::filled(320, 240, 1.5);
        assert!(floor_in_camera(&wall, &camera).is_none());
    }
}
