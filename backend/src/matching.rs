//! ORB map matching near predicted positions (PUT SLAM, paper 004 section 3.1): map points
//! are projected into a new keyframe with its predicted pose, and each is compared only
//! with the keyframe's features within a pixel radius of its projection. The radius grows
//! with the prediction's uncertainty. A match must pass three tests: Hamming distance,
//! Lowe's ratio against the second-best feature, and the 3-D Mahalanobis distance between
//! the predicted and the measured point.

use crate::map::{Feature, MapPoint, PointId};
use crate::se3::skew;
use nalgebra::{Isometry3, Matrix2x3, Matrix3, Matrix3x6, Matrix6, Point2};
use stride_core::camera::PinholeCamera;
use stride_frontend::features::hamming;

/// Settings of [`match_points`].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MatchParams {
    /// Smallest search radius around a projection (px).
    pub min_radius_px: f64,
    /// Largest search radius (px).
    pub max_radius_px: f64,
    /// The radius is this many standard deviations of the projection's uncertainty (from
    /// the pose prediction's covariance), within the bounds above.
    pub sigmas: f64,
    /// Largest Hamming distance accepted (of 256 bits).
    pub max_hamming: u32,
    /// Lowe's ratio: the best distance must be below this fraction of the second best.
    pub ratio: f64,
    /// Bound on the squared Mahalanobis distance between predicted and measured point (3
    /// degrees of freedom; 11.34 is the 99 % quantile).
    pub chi2_gate: f64,
    /// Isotropic standard deviation (m) added to the gate's covariance for what the sensor
    /// model leaves out.
    pub model_noise_m: f64,
}

impl Default for MatchParams {
    fn default() -> Self {
        Self {
            min_radius_px: 8.0,
            max_radius_px: 40.0,
            sigmas: 3.0,
            max_hamming: 50,
            ratio: 0.8,
            chi2_gate: 11.34,
            model_noise_m: 0.01,
        }
    }
}

/// A match: a feature of the keyframe and the map point it observes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Match {
    /// Index of the feature in the keyframe.
    pub feature: usize,
    /// The map point.
    pub point: PointId,
    /// Hamming distance of their descriptors.
    pub distance: u32,
}

/// Features of a keyframe binned in square cells, for radius queries.
struct FeatureGrid<'a> {
    cell_px: f64,
    cols: usize,
    rows: usize,
    cells: Vec<Vec<usize>>,
    features: &'a [Feature],
}

impl<'a> FeatureGrid<'a> {
    fn new(features: &'a [Feature], eligible: &[usize], width: u32, height: u32) -> Self {
        let cell_px = 16.0;
        let cols = (f64::from(width) / cell_px).ceil().max(1.0) as usize;
        let rows = (f64::from(height) / cell_px).ceil().max(1.0) as usize;
        let mut cells = vec![Vec::new(); cols * rows];
        for &i in eligible {
            let Some(f) = features.get(i) else { continue };
            let (c, r) = (
                (f64::from(f.px.x) / cell_px).floor(),
                (f64::from(f.px.y) / cell_px).floor(),
            );
            if c >= 0.0 && r >= 0.0 && (c as usize) < cols && (r as usize) < rows {
                if let Some(cell) = cells.get_mut(r as usize * cols + c as usize) {
                    cell.push(i);
                }
            }
        }
        Self {
            cell_px,
            cols,
            rows,
            cells,
            features,
        }
    }

    /// Features within `radius` px of `px`, in cell order.
    fn within(&self, px: &Point2<f64>, radius: f64, mut visit: impl FnMut(usize, &Feature)) {
        let lo_c = ((px.x - radius) / self.cell_px).floor().max(0.0) as usize;
        let lo_r = ((px.y - radius) / self.cell_px).floor().max(0.0) as usize;
        let hi_c = (((px.x + radius) / self.cell_px).floor().max(0.0) as usize).min(self.cols - 1);
        let hi_r = (((px.y + radius) / self.cell_px).floor().max(0.0) as usize).min(self.rows - 1);
        let r2 = radius * radius;
        for r in lo_r..=hi_r {
            for c in lo_c..=hi_c {
                for &i in self.cells.get(r * self.cols + c).map_or(&[][..], |v| v) {
                    let Some(f) = self.features.get(i) else {
                        continue;
                    };
                    let (dx, dy) = (f64::from(f.px.x) - px.x, f64::from(f.px.y) - px.y);
                    if dx * dx + dy * dy <= r2 {
                        visit(i, f);
                    }
                }
            }
        }
    }
}

/// Standard deviation (px) of a projection's position from the pose's covariance
/// (`pose_cov`, in the retraction's tangent space of `world_from_camera`).
fn projection_sigma_px(
    camera: &PinholeCamera,
    q: &nalgebra::Point3<f64>,
    pose_cov: &Matrix6<f64>,
) -> f64 {
    let z = q.z.max(1e-3);
    let j_pix = Matrix2x3::new(
        camera.fx() / z,
        0.0,
        -camera.fx() * q.x / (z * z),
        0.0,
        camera.fy() / z,
        -camera.fy() * q.y / (z * z),
    );
    let mut j_q = Matrix3x6::zeros();
    j_q.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(-Matrix3::identity()));
    j_q.fixed_view_mut::<3, 3>(0, 3).copy_from(&skew(&q.coords));
    let j = j_pix * j_q;
    let c = j * pose_cov * j.transpose();
    c.trace().max(0.0).sqrt()
}

/// Matches map points to a keyframe's features. `candidates` are the points to try (in
/// the order given, which decides nothing but the work order); `eligible` the features
/// that may match (with a descriptor and a measurement). Each feature gets at most one
/// point: the closest in Hamming distance (ties: the smaller point identifier). Also
/// returns the candidates that project into the image (for the map's found ratio).
pub fn match_points(
    camera: &PinholeCamera,
    world_from_camera: &Isometry3<f64>,
    pose_cov: &Matrix6<f64>,
    features: &[Feature],
    eligible: &[usize],
    candidates: &[(PointId, &MapPoint)],
    params: &MatchParams,
) -> (Vec<Match>, Vec<PointId>) {
    let grid = FeatureGrid::new(features, eligible, camera.width(), camera.height());
    let camera_from_world = world_from_camera.inverse();
    let r_cw = camera_from_world.rotation.to_rotation_matrix().into_inner();
    let model = Matrix3::identity() * params.model_noise_m * params.model_noise_m;
    let mut best_for: Vec<Option<Match>> = vec![None; features.len()];
    let mut visible = Vec::new();
    for &(pid, p) in candidates {
        let Some(desc) = p.descriptor else { continue };
        let q = camera_from_world * p.p_world;
        if q.z < 0.1 {
            continue;
        }
        let Some(px) = camera.project(&q) else {
            continue;
        };
        if !camera.contains(&px) {
            continue;
        }
        visible.push(pid);
        let radius = (params.sigmas * projection_sigma_px(camera, &q, pose_cov))
            .clamp(params.min_radius_px, params.max_radius_px);
        let (mut best, mut second): (Option<(u32, usize)>, Option<u32>) = (None, None);
        grid.within(&px, radius, |i, f| {
            let Some(d) = f.descriptor.as_ref().map(|fd| hamming(&desc, fd)) else {
                return;
            };
            match best {
                Some((bd, bi)) if d < bd || (d == bd && i < bi) => {
                    second = Some(bd);
                    best = Some((d, i));
                }
                Some(_) => second = Some(second.map_or(d, |s| s.min(d))),
                None => best = Some((d, i)),
            }
        });
        let Some((d, i)) = best else { continue };
        if d > params.max_hamming
            || second.is_some_and(|s| f64::from(d) >= params.ratio * f64::from(s))
        {
            continue;
        }
        let Some(m) = features.get(i).and_then(|f| f.measurement) else {
            continue;
        };
        let cov_p = p
            .covariance()
            .map_or(Matrix3::zeros(), |c| r_cw * c * r_cw.transpose());
        let r = m.p - q;
        let Some(inv) = (m.cov + cov_p + model).try_inverse() else {
            continue;
        };
        if r.dot(&(inv * r)) > params.chi2_gate {
            continue;
        }
        let cand = Match {
            feature: i,
            point: pid,
            distance: d,
        };
        if let Some(slot) = best_for.get_mut(i) {
            match slot {
                Some(m) if (m.distance, m.point) <= (d, pid) => {}
                _ => *slot = Some(cand),
            }
        }
    }
    (best_for.into_iter().flatten().collect(), visible)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Translation3, UnitQuaternion};
    use stride_frontend::points::Measurement;

    fn camera() -> PinholeCamera {
        PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480).unwrap()
    }

    fn point(p: Point3<f64>, desc: [u8; 32]) -> MapPoint {
        MapPoint {
            p_world: p,
            information_world: Matrix3::identity() * 1e5,
            descriptor: Some(desc),
            observations: Vec::new(),
            visible: 0,
            found: 0,
            created_by: 0,
        }
    }

    fn feature_at(
        cam: &PinholeCamera,
        pose: &Isometry3<f64>,
        p: &Point3<f64>,
        desc: [u8; 32],
    ) -> Feature {
        let q = pose.inverse() * p;
        let px = cam.project(&q).unwrap();
        Feature {
            track_id: 0,
            px: Point2::new(px.x as f32, px.y as f32),
            measurement: Some(Measurement {
                p: q,
                cov: Matrix3::identity() * 1e-5,
            }),
            descriptor: Some(desc),
            point: None,
        }
    }

    #[test]
    fn matches_by_projection_descriptor_and_geometry() {
        let cam = camera();
        let pose =
            Isometry3::from_parts(Translation3::new(0.1, 0.0, 0.0), UnitQuaternion::identity());
        let pa = Point3::new(0.2, 0.1, 2.0);
        let pb = Point3::new(-0.3, 0.0, 2.5);
        let pc = Point3::new(0.0, -0.2, 1.8);
        let (da, db, dc) = ([0u8; 32], [0xFFu8; 32], [0x0Fu8; 32]);
        let mut features = vec![
            feature_at(&cam, &pose, &pa, da),
            feature_at(&cam, &pose, &pb, db),
            feature_at(&cam, &pose, &pc, dc),
        ];
        // Point c's feature measures a point 20 cm deeper: same pixel, same descriptor, but
        // the 3-D gate rejects it.
        if let Some(m) = features[2].measurement.as_mut() {
            m.p.z += 0.2;
        }
        let points = [point(pa, da), point(pb, db), point(pc, dc)];
        let cands: Vec<(PointId, &MapPoint)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| (i as u64, p))
            .collect();
        let (m, visible) = match_points(
            &cam,
            &pose,
            &(Matrix6::identity() * 1e-8),
            &features,
            &[0, 1, 2],
            &cands,
            &MatchParams::default(),
        );
        assert_eq!(m.len(), 2, "{m:?}");
        assert_eq!(visible, vec![0, 1, 2]);
        assert!(m.contains(&Match {
            feature: 0,
            point: 0,
            distance: 0
        }));
        assert!(m.contains(&Match {
            feature: 1,
            point: 1,
            distance: 0
        }));
        // A feature not eligible is never matched; a far-off prediction finds nothing.
        let (none, _) = match_points(
            &cam,
            &pose,
            &(Matrix6::identity() * 1e-8),
            &features,
            &[2],
            &cands,
            &MatchParams::default(),
        );
        assert!(none.is_empty());
        let moved =
            Isometry3::from_parts(Translation3::new(0.6, 0.0, 0.0), UnitQuaternion::identity());
        let (far, _) = match_points(
            &cam,
            &moved,
            &(Matrix6::identity() * 1e-8),
            &features,
            &[0, 1],
            &cands,
            &MatchParams::default(),
        );
        assert!(far.is_empty(), "{far:?}");
    }

    #[test]
    fn ambiguous_descriptors_fail_the_ratio_test() {
        let cam = camera();
        let pose = Isometry3::identity();
        let p = Point3::new(0.0, 0.0, 2.0);
        let mut near = feature_at(&cam, &pose, &p, [1u8; 32]);
        near.px.x += 4.0;
        let features = vec![feature_at(&cam, &pose, &p, [0u8; 32]), near];
        let mp = point(p, [0u8; 32]);
        // Distances 0 and 32: passes. Make the second as close as the first: fails.
        let (ok, _) = match_points(
            &cam,
            &pose,
            &Matrix6::zeros(),
            &features,
            &[0, 1],
            &[(0, &mp)],
            &MatchParams::default(),
        );
        assert_eq!(ok.len(), 1);
        let mut twin = features.clone();
        twin[1].descriptor = Some([0u8; 32]);
        let (amb, _) = match_points(
            &cam,
            &pose,
            &Matrix6::zeros(),
            &twin,
            &[0, 1],
            &[(0, &mp)],
            &MatchParams::default(),
        );
        assert!(amb.is_empty(), "{amb:?}");
    }
}
