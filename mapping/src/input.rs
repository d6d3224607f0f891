//! What the mappers take: a sensor frame (a depth image or a point cloud with covariances)
//! with its pose, turned into map-frame heights and height variances by a sensor model.

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use rayon::prelude::*;
use stride_core::camera::PinholeCamera;
use stride_core::image::DepthImage;
use stride_core::uncertainty::PrimeSenseModel;

use crate::MappingError;

/// The measurements of one sensor frame.
#[derive(Debug, Clone, Copy)]
pub enum Cloud<'a> {
    /// A depth image (metres along the optical axis, 0 = no return) with its camera.
    Depth {
        /// The depth image.
        depth_m: &'a DepthImage,
        /// The camera it is registered to.
        camera: &'a PinholeCamera,
    },
    /// Points in the sensor frame (m) with their covariances (m², sensor frame), from any
    /// SLAM or sensor.
    Points {
        /// Points in the sensor frame.
        points: &'a [Point3<f64>],
        /// One covariance per point.
        covariances: &'a [Matrix3<f64>],
    },
}

/// One frame for a mapper. Built by [`SensorFrame::depth`] or [`SensorFrame::points`],
/// which check that the measurements are consistent (a depth image of its camera's size, one
/// covariance per point), so a mapper never sees a frame whose pixels it would misplace.
#[derive(Debug, Clone, Copy)]
pub struct SensorFrame<'a> {
    /// The measurements (private: consistent by construction).
    cloud: Cloud<'a>,
    /// `map_from_sensor`: the sensor pose in the map frame (z up, m). A non-finite pose is
    /// allowed here; the mappers drop such a frame whole and count it (`bad_pose`).
    pub map_from_sensor: Isometry3<f64>,
    /// Time (s).
    pub time_s: f64,
}

impl<'a> SensorFrame<'a> {
    /// A depth image (metres along the optical axis, 0 = no return) seen by `camera` from
    /// `map_from_sensor` at `time_s` (s). Errors when the image's size is not the camera's.
    pub fn depth(
        depth_m: &'a DepthImage,
        camera: &'a PinholeCamera,
        map_from_sensor: Isometry3<f64>,
        time_s: f64,
    ) -> Result<Self, MappingError> {
        if (depth_m.width(), depth_m.height()) != (camera.width(), camera.height()) {
            return Err(MappingError::DepthSize {
                width: depth_m.width(),
                height: depth_m.height(),
                camera_width: camera.width(),
                camera_height: camera.height(),
            });
        }
        Ok(Self {
            cloud: Cloud::Depth { depth_m, camera },
            map_from_sensor,
            time_s,
        })
    }

    /// Points in the sensor frame (m) with one covariance each (m², sensor frame), taken
    /// from `map_from_sensor` at `time_s` (s). Errors when the counts differ.
    pub fn points(
        points: &'a [Point3<f64>],
        covariances: &'a [Matrix3<f64>],
        map_from_sensor: Isometry3<f64>,
        time_s: f64,
    ) -> Result<Self, MappingError> {
        if points.len() != covariances.len() {
            return Err(MappingError::CovarianceCount {
                points: points.len(),
                covariances: covariances.len(),
            });
        }
        Ok(Self {
            cloud: Cloud::Points {
                points,
                covariances,
            },
            map_from_sensor,
            time_s,
        })
    }

    /// The same frame with `depth_m` in place of its depth image, which must have the
    /// same size (a frame of points stays as it is).
    pub(crate) fn with_depth<'b>(&self, depth_m: &'b DepthImage) -> SensorFrame<'b>
    where
        'a: 'b,
    {
        let cloud = match self.cloud {
            Cloud::Depth { camera, .. } => Cloud::Depth { depth_m, camera },
            other => other,
        };
        SensorFrame {
            cloud,
            map_from_sensor: self.map_from_sensor,
            time_s: self.time_s,
        }
    }

    /// The measurements.
    pub fn cloud(&self) -> Cloud<'a> {
        self.cloud
    }

    /// Number of measurements (pixels of a depth image, or points).
    pub fn len(&self) -> usize {
        match self.cloud {
            Cloud::Depth { depth_m, .. } => depth_m.as_slice().len(),
            Cloud::Points { points, .. } => points.len(),
        }
    }

    /// True when the frame carries no measurement.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// True when the pose has only finite numbers (a frame with any other pose is dropped
    /// whole, its measurements counted as `bad_pose`).
    pub fn pose_is_finite(&self) -> bool {
        pose_is_finite(&self.map_from_sensor)
    }
}

/// How a mapper turns a measurement into a height variance in the map frame (m²).
pub trait HeightModel: Sync {
    /// Height variance (m²) of a depth pixel of `camera`; `r3` is the map's z axis
    /// expressed in the sensor frame (the third row of the map-from-sensor rotation).
    fn pixel_variance(&self, camera: &PinholeCamera, px: &DepthPixel, r3: &Vector3<f64>) -> f64;
    /// Height variance of a sensor-frame point with the covariance its source gave.
    fn point_variance(&self, p: &Point3<f64>, cov: &Matrix3<f64>, r3: &Vector3<f64>) -> f64;
    /// Depth range accepted (m, along the optical axis).
    fn range_m(&self) -> (f64, f64);
    /// Standard deviation of a depth measurement `d` (m) along the optical axis (m).
    fn depth_sigma_m(&self, d: f64) -> f64;
    /// The model's constants in f32 for the vectorised loops ([`HeightModel::depth_sigma_f32`],
    /// [`HeightModel::pixel_variance_f32`]), copied out once per frame.
    fn f32_consts(&self) -> F32Consts;
    /// [`HeightModel::depth_sigma_m`] in f32 from the constants [`HeightModel::f32_consts`]
    /// gave, for the vectorised input stage: branch-free f32 arithmetic that reads only `c`.
    fn depth_sigma_f32(c: &F32Consts, d: f32) -> f32;
    /// [`HeightModel::pixel_variance`] in f32, for the mappers' vectorised input stage: a
    /// pixel with undistorted normalised coordinates `(xn, yn)` and depth `d` (m). Must be
    /// free of branches and calls that stop the vectorisation, and read only `k`.
    fn pixel_variance_f32(k: &VarianceConsts, xn: f32, yn: f32, d: f32) -> f32;
}

/// A height model's constants in f32, laid out as its [`HeightModel::f32_consts`] says.
/// The vectorised loops take them by value: read through a reference to the model, they
/// were loaded and converted from f64 again at every pixel (the compiler cannot tell that
/// the loop's stores leave the model alone), which kept those loops scalar.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct F32Consts(pub [f32; 8]);

/// A frame's constants of [`HeightModel::pixel_variance_f32`].
#[derive(Debug, Clone, Copy)]
pub struct VarianceConsts {
    /// The map's z axis in the sensor frame (third row of the map-from-sensor rotation).
    pub r3: [f32; 3],
    /// `1 / fx` and `1 / fy` of the camera (1/px).
    pub inv_fx: f32,
    /// See `inv_fx`.
    pub inv_fy: f32,
    /// The model's own constants ([`HeightModel::f32_consts`]).
    pub model: F32Consts,
}

/// A front-end filter of depth images against flying pixels (returns between a foreground
/// edge and the background behind it, which hang in the air in the foreground's shadow
/// where no later view can contradict them). A pixel is dropped when a pixel `n` = 1 or 2
/// pixels away (its 5 x 5 neighbourhood) is nearer by more than `tau_n(d) = n d / (f
/// tan(min_grazing)) + k sqrt(2) sigma_d(d)`: more than a surface seen at the shallowest
/// accepted angle can change over `n` pixels, plus `k` standard deviations of the difference
/// of two measurements. The second ring catches the mixed pixel whose foreground partner
/// across the edge returned nothing (sensors often drop returns beside mixed ones), which a
/// test of the 8 neighbours alone lets through. It also drops the background pixels within
/// two pixels of a foreground edge, which costs two pixels of background along each edge.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EdgeFilter {
    /// Shallowest angle between a viewing ray and a surface treated as a surface (rad).
    pub min_grazing_rad: f64,
    /// Noise allowance `k` (standard deviations).
    pub sigmas: f64,
}

impl EdgeFilter {
    /// Checks the parameters: the angle within (0, 90) degrees, `sigmas` finite and not
    /// negative. Errors name the keys as a configuration file spells them
    /// (`edge_filter.min_grazing_rad`, `edge_filter.sigmas`).
    pub fn validate(&self) -> Result<(), MappingError> {
        if !(self.min_grazing_rad > 0.0 && self.min_grazing_rad < std::f64::consts::FRAC_PI_2) {
            return Err(MappingError::Parameter {
                name: "edge_filter.min_grazing_rad",
                value: self.min_grazing_rad,
                reason: "must lie strictly between 0 and pi/2",
            });
        }
        crate::error::non_negative("edge_filter.sigmas", self.sigmas)
    }
}

impl Default for EdgeFilter {
    /// 8 degrees (a floor 4 m away seen from 0.5 m is at 7 degrees and loses no more
    /// pixels than the sensor already does at such angles), 3 standard deviations.
    fn default() -> Self {
        Self {
            min_grazing_rad: 8f64.to_radians(),
            sigmas: 3.0,
        }
    }
}

impl EdgeFilter {
    /// The jump (m) above which a nearer neighbour (one pixel away) marks a pixel of depth
    /// `d` (m) as an edge, for focal length `f_px` and depth standard deviation `sigma_d`
    /// (m): `tau_1(d)`.
    pub fn threshold_m(&self, d: f64, f_px: f64, sigma_d: f64) -> f64 {
        self.threshold_apart_m(1.0, d, f_px, sigma_d)
    }

    /// As [`EdgeFilter::threshold_m`] for a nearer pixel `n_px` pixels away: `tau_n(d)`.
    pub fn threshold_apart_m(&self, n_px: f64, d: f64, f_px: f64, sigma_d: f64) -> f64 {
        n_px * d / (f_px.max(1.0) * self.min_grazing_rad.tan().max(1e-3))
            + self.sigmas * std::f64::consts::SQRT_2 * sigma_d
    }
}

/// A depth measurement at a pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthPixel {
    /// Column (px).
    pub u: f64,
    /// Row (px).
    pub v: f64,
    /// Undistorted normalised x coordinate (x / z in the camera frame).
    pub xn: f64,
    /// Undistorted normalised y coordinate (y / z in the camera frame).
    pub yn: f64,
    /// Depth along the optical axis (m).
    pub d_m: f64,
}

/// Paper 000's PrimeSense model (eqs. 10-12): the height variance is `r3^T Sigma_p r3` with
/// `Sigma_p = J diag(sigma_u^2, sigma_v^2, sigma_d^2) J^T`, computed without forming the 3x3
/// matrix: `sigma_u^2 (r3x d/fx)^2 + sigma_v^2 (r3y d/fy)^2 + sigma_d^2 (r3 . (xn, yn, 1))^2`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PrimeSenseHeight {
    /// The point model.
    pub model: PrimeSenseModel,
    /// Nearest depth used (m).
    pub min_depth_m: f64,
    /// Farthest depth used (m).
    pub max_depth_m: f64,
}

impl Default for PrimeSenseHeight {
    fn default() -> Self {
        Self {
            model: PrimeSenseModel::default(),
            min_depth_m: 0.3,
            max_depth_m: 4.5,
        }
    }
}

impl HeightModel for PrimeSenseHeight {
    fn pixel_variance(&self, camera: &PinholeCamera, px: &DepthPixel, r3: &Vector3<f64>) -> f64 {
        let (xn, yn, d) = (px.xn, px.yn, px.d_m);
        let s = self.model.sigma_d(d);
        let a = r3.x * d / camera.fx();
        let b = r3.y * d / camera.fy();
        let c = r3.x * xn + r3.y * yn + r3.z;
        self.model.var_u_px2 * a * a + self.model.var_v_px2 * b * b + s * s * c * c
    }

    fn point_variance(&self, _p: &Point3<f64>, cov: &Matrix3<f64>, r3: &Vector3<f64>) -> f64 {
        (r3.transpose() * cov * r3)[(0, 0)]
    }

    fn range_m(&self) -> (f64, f64) {
        (self.min_depth_m, self.max_depth_m)
    }

    fn depth_sigma_m(&self, d: f64) -> f64 {
        self.model.sigma_d(d)
    }

    /// `[k1, k2, k3, k4, min_sigma_d_m, var_u_px2, var_v_px2, 0]`: the depth noise's cubic,
    /// its floor and the pixel noise.
    fn f32_consts(&self) -> F32Consts {
        let m = &self.model;
        let [k1, k2, k3, k4] = m.depth_sigma_coeffs;
        F32Consts(
            [
                k1,
                k2,
                k3,
                k4,
                m.min_sigma_d_m,
                m.var_u_px2,
                m.var_v_px2,
                0.0,
            ]
            .map(|c| c as f32),
        )
    }

    #[inline(always)]
    fn depth_sigma_f32(c: &F32Consts, d: f32) -> f32 {
        let [k1, k2, k3, k4, floor, ..] = c.0;
        (((k1 * d + k2) * d + k3) * d + k4).max(floor)
    }

    #[inline(always)]
    fn pixel_variance_f32(k: &VarianceConsts, xn: f32, yn: f32, d: f32) -> f32 {
        let [.., var_u, var_v, _] = k.model.0;
        let s = Self::depth_sigma_f32(&k.model, d);
        let [r3x, r3y, r3z] = k.r3;
        let a = r3x * d * k.inv_fx;
        let b = r3y * d * k.inv_fy;
        let c = r3x * xn + r3y * yn + r3z;
        var_u * a * a + var_v * b * b + s * s * c * c
    }
}

/// Per-frame counts of measurements that were dropped, by reason.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct Rejections {
    /// No return (depth 0) in a depth image.
    pub no_return: usize,
    /// NaN or infinite coordinate.
    pub non_finite: usize,
    /// Outside the sensor model's depth range.
    pub out_of_range: usize,
    /// Zero, negative or non-finite variance.
    pub bad_variance: usize,
    /// Outside the map window.
    pub outside_window: usize,
    /// The frame's pose was not finite (every point dropped).
    pub bad_pose: usize,
    /// Dropped by the depth-edge (flying pixel) filter.
    pub depth_edge: usize,
}

impl Rejections {
    /// Adds another frame's counts.
    pub fn add(&mut self, o: &Rejections) {
        self.no_return += o.no_return;
        self.non_finite += o.non_finite;
        self.out_of_range += o.out_of_range;
        self.bad_variance += o.bad_variance;
        self.outside_window += o.outside_window;
        self.bad_pose += o.bad_pose;
        self.depth_edge += o.depth_edge;
    }
}

/// A measurement placed in the map frame: position (m) and height variance (m²), as a
/// mapper takes it (not a SLAM map point).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HeightSample {
    /// x (m, map frame).
    pub x: f64,
    /// y (m, map frame).
    pub y: f64,
    /// Height z (m, map frame, up).
    pub z: f64,
    /// Variance of the height (m²).
    pub var: f64,
}

/// True when the pose has only finite numbers.
pub fn pose_is_finite(t: &Isometry3<f64>) -> bool {
    t.translation.vector.iter().all(|v| v.is_finite())
        && t.rotation.coords.iter().all(|v| v.is_finite())
}

/// Undistorted normalised coordinates of every pixel of a camera with lens distortion,
/// computed once (a camera without distortion needs no table).
#[derive(Debug, Clone, Default)]
pub struct RayCache {
    camera: Option<PinholeCamera>,
    rays: Vec<(f32, f32)>,
}

impl RayCache {
    /// The rays of `camera` (the table is rebuilt only when the camera changes).
    pub fn rays(&mut self, camera: &PinholeCamera) -> Rays<'_> {
        if camera.distortion().is_none() {
            return Rays::Pinhole(*camera);
        }
        if self.camera.as_ref() != Some(camera) {
            let (w, h) = (camera.width() as usize, camera.height() as usize);
            self.rays = (0..w * h)
                .into_par_iter()
                .map(|i| {
                    let n = camera.normalized_from_pixel(&nalgebra::Point2::new(
                        (i % w) as f64,
                        (i / w) as f64,
                    ));
                    (n.x as f32, n.y as f32)
                })
                .collect();
            self.camera = Some(*camera);
        }
        Rays::Table(&self.rays, camera.width() as usize)
    }

    /// The rays of `camera` when no table needs building (no distortion, or the table
    /// holds this camera's); `None` otherwise.
    pub fn cached(&self, camera: &PinholeCamera) -> Option<Rays<'_>> {
        if camera.distortion().is_none() {
            Some(Rays::Pinhole(*camera))
        } else {
            (self.camera.as_ref() == Some(camera))
                .then(|| Rays::Table(&self.rays, camera.width() as usize))
        }
    }
}

/// The undistorted normalised coordinates `(x/z, y/z)` of a camera's pixels.
#[derive(Debug, Clone, Copy)]
pub enum Rays<'a> {
    /// Computed from the intrinsics (no distortion).
    Pinhole(PinholeCamera),
    /// Looked up in a row-major table of `width` columns.
    Table(&'a [(f32, f32)], usize),
}

impl Rays<'_> {
    /// Fills `out` with the rays of row `v` (`width` pixels).
    pub fn row(&self, v: usize, width: usize, out: &mut Vec<(f64, f64)>) {
        out.clear();
        match self {
            Rays::Pinhole(c) => {
                let (ifx, yn) = (1.0 / c.fx(), (v as f64 - c.cy()) / c.fy());
                out.extend((0..width).map(|u| ((u as f64 - c.cx()) * ifx, yn)));
            }
            Rays::Table(t, w) => {
                let row = t.get(v * w..(v + 1) * w).unwrap_or(&[]);
                out.extend(
                    row.iter()
                        .take(width)
                        .map(|&(x, y)| (f64::from(x), f64::from(y))),
                );
                out.resize(width, (f64::NAN, f64::NAN));
            }
        }
    }
}

/// Why a measurement was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Reason {
    NoReturn,
    NonFinite,
    OutOfRange,
    BadVariance,
    DepthEdge,
}

impl Rejections {
    pub(crate) fn count(&mut self, r: Reason) {
        match r {
            Reason::NoReturn => self.no_return += 1,
            Reason::NonFinite => self.non_finite += 1,
            Reason::OutOfRange => self.out_of_range += 1,
            Reason::BadVariance => self.bad_variance += 1,
            Reason::DepthEdge => self.depth_edge += 1,
        }
    }
}

/// The sensor pose as plain numbers for the per-point transform.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Placement {
    pub(crate) rot: nalgebra::Matrix3<f64>,
    pub(crate) trans: Vector3<f64>,
    /// The map's z axis in the sensor frame (third row of the rotation).
    pub(crate) r3: Vector3<f64>,
    /// Accepted depth range (m).
    pub(crate) range: (f64, f64),
}

impl Placement {
    pub(crate) fn new(t: &Isometry3<f64>, range: (f64, f64)) -> Self {
        let rot = t.rotation.to_rotation_matrix().into_inner();
        Self {
            rot,
            trans: t.translation.vector,
            r3: Vector3::new(rot[(2, 0)], rot[(2, 1)], rot[(2, 2)]),
            range,
        }
    }

    #[inline]
    pub(crate) fn place(&self, p: Vector3<f64>, var: f64) -> Result<HeightSample, Reason> {
        if !(var.is_finite() && var > 0.0) {
            return Err(Reason::BadVariance);
        }
        let q = self.rot * p + self.trans;
        Ok(HeightSample {
            x: q.x,
            y: q.y,
            z: q.z,
            var,
        })
    }

    /// A depth pixel `(u, v)` (px) with undistorted normalised coordinates `(xn, yn)` and
    /// depth `d` (m).
    #[inline]
    pub(crate) fn pixel<M: HeightModel + ?Sized>(
        &self,
        model: &M,
        camera: &PinholeCamera,
        u: usize,
        v: usize,
        (xn, yn): (f64, f64),
        d: f32,
    ) -> Result<HeightSample, Reason> {
        let d = f64::from(d);
        if d == 0.0 {
            Err(Reason::NoReturn)
        } else if !d.is_finite() {
            Err(Reason::NonFinite)
        } else if d < self.range.0 || d > self.range.1 {
            Err(Reason::OutOfRange)
        } else {
            self.place(
                Vector3::new(xn * d, yn * d, d),
                model.pixel_variance(
                    camera,
                    &DepthPixel {
                        u: u as f64,
                        v: v as f64,
                        xn,
                        yn,
                        d_m: d,
                    },
                    &self.r3,
                ),
            )
        }
    }

    /// A sensor-frame point with its covariance.
    #[inline]
    pub(crate) fn point<M: HeightModel + ?Sized>(
        &self,
        model: &M,
        p: &Point3<f64>,
        cov: Option<&Matrix3<f64>>,
    ) -> Result<HeightSample, Reason> {
        if !p.coords.iter().all(|v| v.is_finite()) {
            Err(Reason::NonFinite)
        } else if p.z < self.range.0 || p.z > self.range.1 {
            Err(Reason::OutOfRange)
        } else {
            match cov {
                // A covariance must be finite with positive variances, whether or not the
                // sensor model uses it.
                Some(c)
                    if c.iter().all(|v| v.is_finite()) && c.diagonal().iter().all(|&v| v > 0.0) =>
                {
                    self.place(p.coords, model.point_variance(p, c, &self.r3))
                }
                _ => Err(Reason::BadVariance),
            }
        }
    }
}

pub use crate::binned::{
    filtered_map_points, prepare_binned, to_map_points, Binned, Binning, CellPoint, FACE, SLICES,
    VAR_MAX_M2, VAR_MIN_M2,
};

#[cfg(test)]
#[path = "input_tests.rs"]
mod tests;
