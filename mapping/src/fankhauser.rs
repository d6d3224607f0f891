//! The baseline: the measurement and model update of Fankhauser et al. (2014), "Robot-centric
//! elevation mapping with uncertainty estimates", as ANYbotics' elevation_mapping implements
//! it (`ElevationMap::add`), with its published Kinect model (Nguyen et al. 2012).
//!
//! Each cell holds one height and its variance. A point whose height lies within
//! `mahalanobis_threshold` standard deviations of the cell is fused (1-D Kalman filter);
//! otherwise, if the cell was updated within `scanning_duration_s`, a higher point replaces
//! the cell and a lower point is ignored, and an older cell only gets `multi_height_noise`
//! added to its variance. Variances are clamped to `[min_variance, max_variance]`. As in
//! paper 000's comparison, the robot-pose uncertainty propagation and the fusion step are
//! left out (no pose covariance is available here). Points are applied in pixel order, as
//! the original applies them in cloud order.

use crate::error::{self, MappingError};
use crate::input::{
    prepare_binned, Binned, Binning, DepthPixel, EdgeFilter, F32Consts, HeightModel, RayCache,
    SensorFrame, VarianceConsts,
};
use crate::window::Window;
use crate::{ElevationMapper, MapLayers, UpdateStats};
use nalgebra::{Matrix3, Point3, Vector3};
use rayon::prelude::*;
use std::collections::HashMap;
use std::time::Instant;
use stride_core::camera::PinholeCamera;

/// The structured-light noise model of elevation_mapping (Nguyen et al. 2012):
/// `sigma_normal = a + b (r - c)^2` along the viewing direction and `sigma_lateral =
/// lateral * r` across it, with `r` the measurement distance; the height variance is
/// `P C Sigma_S C^T P^T` with `Sigma_S = diag(lat^2, lat^2, normal^2)` in the sensor frame.
/// Defaults: `kinect_nguyen_et_al.yaml` (a = 0.0012, b = 0.0019, c = 0.4, lateral =
/// 0.001376915, depth cut-off 0.35-3.0 m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KinectNguyenHeight {
    /// `normal_factor_a` (m).
    pub normal_a: f64,
    /// `normal_factor_b` (1/m).
    pub normal_b: f64,
    /// `normal_factor_c` (m).
    pub normal_c: f64,
    /// `lateral_factor`.
    pub lateral: f64,
    /// `cutoff_min_depth` (m).
    pub min_depth_m: f64,
    /// `cutoff_max_depth` (m).
    pub max_depth_m: f64,
}

impl Default for KinectNguyenHeight {
    fn default() -> Self {
        Self {
            normal_a: 0.0012,
            normal_b: 0.0019,
            normal_c: 0.4,
            lateral: 0.001376915,
            min_depth_m: 0.35,
            max_depth_m: 3.0,
        }
    }
}

impl KinectNguyenHeight {
    fn variance(&self, distance: f64, r3: &Vector3<f64>) -> f64 {
        let normal = self.normal_a + self.normal_b * (distance - self.normal_c).powi(2);
        let lateral = self.lateral * distance;
        lateral * lateral * (r3.x * r3.x + r3.y * r3.y) + normal * normal * r3.z * r3.z
    }
}

impl HeightModel for KinectNguyenHeight {
    fn pixel_variance(&self, _camera: &PinholeCamera, px: &DepthPixel, r3: &Vector3<f64>) -> f64 {
        self.variance(px.d_m * (px.xn * px.xn + px.yn * px.yn + 1.0).sqrt(), r3)
    }

    fn point_variance(&self, p: &Point3<f64>, _cov: &Matrix3<f64>, r3: &Vector3<f64>) -> f64 {
        self.variance(p.coords.norm(), r3)
    }

    fn range_m(&self) -> (f64, f64) {
        (self.min_depth_m, self.max_depth_m)
    }

    fn depth_sigma_m(&self, d: f64) -> f64 {
        self.normal_a + self.normal_b * (d - self.normal_c).powi(2)
    }

    /// `[normal_a, normal_b, normal_c, lateral, 0, 0, 0, 0]`.
    fn f32_consts(&self) -> F32Consts {
        let (a, b, c, l) = (self.normal_a, self.normal_b, self.normal_c, self.lateral);
        F32Consts([a, b, c, l, 0.0, 0.0, 0.0, 0.0].map(|v| v as f32))
    }

    #[inline(always)]
    fn depth_sigma_f32(c: &F32Consts, d: f32) -> f32 {
        let [a, b, c, ..] = c.0;
        a + b * (d - c) * (d - c)
    }

    #[inline(always)]
    fn pixel_variance_f32(k: &VarianceConsts, xn: f32, yn: f32, d: f32) -> f32 {
        let [a, b, c, l, ..] = k.model.0;
        let distance = d * (xn * xn + yn * yn + 1.0).sqrt();
        let e = distance - c;
        let normal = a + b * e * e;
        let lateral = l * distance;
        let [r3x, r3y, r3z] = k.r3;
        lateral * lateral * (r3x * r3x + r3y * r3y) + normal * normal * r3z * r3z
    }
}

/// Parameters of [`FankhauserMapper`].
#[derive(Debug, Clone, PartialEq)]
pub struct FankhauserConfig {
    /// Cell size (m).
    pub resolution_m: f64,
    /// Side of the moving window (m).
    pub size_m: f64,
    /// `mahalanobis_distance_threshold`.
    pub mahalanobis_threshold: f64,
    /// `multi_height_noise` (m²).
    pub multi_height_noise: f64,
    /// `scanning_duration` (s).
    pub scanning_duration_s: f64,
    /// `min_variance` (m²).
    pub min_variance: f64,
    /// `max_variance` (m²).
    pub max_variance: f64,
    /// Window centre ahead of the sensor (m), as [`crate::stack::StackConfig`].
    pub lookahead_m: f64,
    /// Window recentring threshold (m).
    pub recenter_threshold_m: f64,
    /// Sensor model.
    pub sensor: KinectNguyenHeight,
    /// Depth-edge filter ([`crate::input::EdgeFilter`]); elevation_mapping has none, so
    /// `None` by default.
    pub edge_filter: Option<EdgeFilter>,
}

impl Default for FankhauserConfig {
    /// elevation_mapping's published map parameters (`long_range.yaml`: Mahalanobis
    /// threshold 2.5, multi-height noise 2e-5 m², variance clamped to [1e-4, 1e4] m²;
    /// scanning duration 1 s) on the same 1 cm, 4 x 4 m window as the stack mapper.
    fn default() -> Self {
        Self {
            resolution_m: 0.01,
            size_m: 4.0,
            mahalanobis_threshold: 2.5,
            multi_height_noise: 2e-5,
            scanning_duration_s: 1.0,
            min_variance: 1e-4,
            max_variance: 1e4,
            lookahead_m: 1.2,
            recenter_threshold_m: 0.3,
            sensor: KinectNguyenHeight::default(),
            edge_filter: None,
        }
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Cell {
    h: f32,
    var: f32,
    time: f32,
    valid: bool,
    updates: u32,
    last_frame: u32,
}

/// Bands of storage rows updated in parallel (fixed: results never depend on the thread
/// count).
const BANDS: usize = 8;

/// The Fankhauser et al. (2014) elevation map. See the module documentation.
pub struct FankhauserMapper {
    cfg: FankhauserConfig,
    window: Window<Cell>,
    archive: HashMap<(i64, i64), Cell>,
    rays: RayCache,
    binned: Binned,
    frame_no: u32,
    t0: Option<f64>,
}

impl FankhauserConfig {
    /// Checks every parameter ([`FankhauserMapper::new`] does): the window as
    /// [`crate::stack::StackConfig::validate`], a positive Mahalanobis threshold, noise and
    /// duration not negative, `0 < min_variance <= max_variance`, a depth range with
    /// `min < max`. Returns the window's cells per side.
    pub fn validate(&self) -> Result<usize, MappingError> {
        let cells = error::window_cells(
            self.resolution_m,
            self.size_m,
            self.lookahead_m,
            self.recenter_threshold_m,
        )?;
        error::positive("mahalanobis_threshold", self.mahalanobis_threshold)?;
        error::non_negative("multi_height_noise", self.multi_height_noise)?;
        error::non_negative("scanning_duration_s", self.scanning_duration_s)?;
        error::positive("min_variance", self.min_variance)?;
        error::positive("max_variance", self.max_variance)?;
        if self.max_variance < self.min_variance {
            return Err(MappingError::Parameter {
                name: "max_variance",
                value: self.max_variance,
                reason: "must not be below min_variance",
            });
        }
        error::depth_range(self.sensor.min_depth_m, self.sensor.max_depth_m)?;
        if let Some(e) = &self.edge_filter {
            e.validate()?;
        }
        Ok(cells)
    }
}

impl FankhauserMapper {
    /// A mapper with these parameters, once [`FankhauserConfig::validate`] accepts them.
    pub fn new(cfg: FankhauserConfig) -> Result<Self, MappingError> {
        let size = cfg.validate()?;
        Ok(Self {
            window: Window::new(size, cfg.resolution_m, (0, 0)),
            cfg,
            archive: HashMap::new(),
            rays: RayCache::default(),
            binned: Binned::default(),
            frame_no: 0,
            t0: None,
        })
    }

    /// Keeps the window ahead of the sensor; evicted cells go to the archive.
    fn recenter(&mut self, frame: &SensorFrame<'_>) {
        let archive = &mut self.archive;
        self.window.follow(
            &frame.map_from_sensor,
            self.cfg.lookahead_m,
            self.cfg.recenter_threshold_m,
            |cell, c| {
                if c.valid {
                    archive.insert(cell, *c);
                }
            },
        );
    }
}

impl ElevationMapper for FankhauserMapper {
    fn name(&self) -> &'static str {
        "fankhauser"
    }

    fn memory_bytes(&self) -> usize {
        self.window.memory_bytes()
            + self.archive.capacity() * std::mem::size_of::<((i64, i64), Cell)>()
            + self.binned.memory_bytes()
    }

    fn integrate(&mut self, frame: &SensorFrame<'_>) -> UpdateStats {
        let start = Instant::now();
        self.frame_no += 1;
        let cfg = self.cfg.clone();
        if !frame.pose_is_finite() {
            return UpdateStats::bad_pose(frame, start);
        }
        self.recenter(frame);
        let t = (frame.time_s - *self.t0.get_or_insert(frame.time_s)) as f32;
        let size = self.window.size();
        let band_cells = size.div_ceil(BANDS) * size;
        let rej = prepare_binned(
            frame,
            &cfg.sensor,
            &mut self.rays,
            Binning {
                binner: &self.window.binner(size.div_ceil(BANDS)),
                centrality: false,
                smooth: false,
                faces: None,
            },
            BANDS,
            cfg.edge_filter.as_ref(),
            &mut self.binned,
        );
        let prepare_s = start.elapsed().as_secs_f64();
        let binned = &self.binned;
        let frame_no = self.frame_no;
        let used: usize = self
            .window
            .cells_mut()
            .par_chunks_mut(band_cells)
            .enumerate()
            .map(|(b, cells)| {
                let lo = b * band_cells;
                let mut used = 0;
                // Points in input order within each cell, as the original applies them.
                for p in binned.band(b) {
                    let Some(c) = cells.get_mut((p.cell() as usize).wrapping_sub(lo)) else {
                        continue;
                    };
                    let (z, vp) = (p.z_m, p.var_m2);
                    used += 1;
                    c.updates += u32::from(c.last_frame != frame_no);
                    c.last_frame = frame_no;
                    if !c.valid {
                        *c = Cell {
                            h: z,
                            var: vp,
                            time: t,
                            valid: true,
                            updates: c.updates,
                            last_frame: frame_no,
                        };
                        continue;
                    }
                    let d = (z - c.h).abs() / c.var.sqrt();
                    if f64::from(d) > cfg.mahalanobis_threshold {
                        let recent = f64::from(t - c.time) <= cfg.scanning_duration_s;
                        if recent && c.h > z {
                            // A lower point from a recent scan: ignored.
                        } else if recent {
                            c.h = z;
                            c.var = vp;
                        } else {
                            c.var += cfg.multi_height_noise as f32;
                        }
                        continue;
                    }
                    c.h = (c.var * z + vp * c.h) / (c.var + vp);
                    c.var = vp * c.var / (vp + c.var);
                    c.time = t;
                }
                for c in cells
                    .iter_mut()
                    .filter(|c| c.valid && c.last_frame == frame_no)
                {
                    c.var = c
                        .var
                        .clamp(cfg.min_variance as f32, cfg.max_variance as f32);
                }
                used
            })
            .sum();
        UpdateStats {
            points_used: used,
            points_overflow: 0,
            rejected: rej,
            cells_cleared: 0,
            steep_pushed: 0,
            update_s: start.elapsed().as_secs_f64(),
            prepare_s,
            checks_s: 0.0,
        }
    }

    fn export(&self) -> MapLayers {
        let mut cells = self.archive.clone();
        for (i, c) in self.window.cells().iter().enumerate() {
            if c.valid {
                cells.insert(self.window.cell_of_index(i), *c);
            }
        }
        MapLayers::from_cells(
            self.cfg.resolution_m,
            cells
                .iter()
                .map(|(&k, c)| (k, c.h, c.var, f32::NAN, c.updates as f32)),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stride_core::rng::SplitMix64;

    #[test]
    fn height_variance_matches_monte_carlo_sampling() {
        // Sample the sensor-frame noise (normal along the ray, lateral across) and look at
        // the spread of the map height.
        let m = KinectNguyenHeight::default();
        let rot = nalgebra::UnitQuaternion::from_euler_angles(-2.0, 0.2, 0.5).to_rotation_matrix();
        let r3 = Vector3::new(rot[(2, 0)], rot[(2, 1)], rot[(2, 2)]);
        let p = Point3::new(0.0, 0.0, 2.0); // on the optical axis: normal = z
        let normal = m.normal_a + m.normal_b * (2.0f64 - m.normal_c).powi(2);
        let lateral = m.lateral * 2.0;
        let mut rng = SplitMix64::new(5);
        let n = 200_000;
        let (mut s, mut s2) = (0.0, 0.0);
        for _ in 0..n {
            let q = p + Vector3::new(
                lateral * rng.normal(),
                lateral * rng.normal(),
                normal * rng.normal(),
            );
            let h = (rot * q).z;
            s += h;
            s2 += h * h;
        }
        let var = s2 / n as f64 - (s / n as f64).powi(2);
        let model = m.point_variance(&p, &Matrix3::zeros(), &r3);
        assert!((var / model - 1.0).abs() < 0.02, "{var} vs {model}");
    }
}
