//! Fixed indexing of a [`Problem`] for the solver: free cameras, point edges grouped by
//! point, observations grouped by camera, the block pattern of the reduced system; and the
//! estimate ([`Vars`]) that the solver steps.

use super::problem::Problem;
use super::reduced::BlockPattern;
use crate::se3::{is_finite, point_is_finite, retract};
use nalgebra::{Isometry3, Matrix3, Point3, Vector3, Vector6};

/// The estimate, apart from the edges: every pose (`world_from_camera`) and point
/// (`p_world`).
#[derive(Debug, Clone)]
pub(crate) struct Vars {
    pub(crate) poses: Vec<Isometry3<f64>>,
    pub(crate) points: Vec<Point3<f64>>,
}

impl Vars {
    pub(crate) fn of(p: &Problem) -> Self {
        Self {
            poses: p.poses.iter().map(|v| v.world_from_camera).collect(),
            points: p.points.iter().map(|v| v.p_world).collect(),
        }
    }

    /// The estimate stepped by `(dc, dp)`, or `None` if any value would not be finite.
    pub(crate) fn stepped(
        &self,
        layout: &Layout,
        dc: &[Vector6<f64>],
        dp: &[Vector3<f64>],
    ) -> Option<Self> {
        let mut out = self.clone();
        for (i, pose) in out.poses.iter_mut().enumerate() {
            if let Some(c) = layout.cam(i) {
                let next = retract(pose, dc.get(c as usize)?);
                if !is_finite(&next) {
                    return None;
                }
                *pose = next;
            }
        }
        for (pt, d) in out.points.iter_mut().zip(dp) {
            let next: Point3<f64> = *pt + d;
            if !point_is_finite(&next) {
                return None;
            }
            *pt = next;
        }
        Some(out)
    }
}

/// Fixed indexing of a problem: free cameras, edges grouped by point, observations by camera.
pub(crate) struct Layout {
    pub(crate) cam_of_pose: Vec<Option<u32>>,
    /// Point-edge indices ordered by point.
    pub(crate) edge_order: Vec<usize>,
    /// For each point, its range in `edge_order`.
    pub(crate) point_ranges: Vec<std::ops::Range<usize>>,
    /// For each free camera, positions in `edge_order` of its edges, and their points.
    pub(crate) obs_of_cam: Vec<Vec<(usize, usize)>>,
    /// The points split into [`PARTITIONS`] contiguous ranges of about equal work (the
    /// square of each point's observation count), for sums done in parallel and then
    /// added in a fixed order.
    pub(crate) partitions: Vec<std::ops::Range<usize>>,
    /// For each partition, its range of positions in `edge_order` (consecutive, covering
    /// them all).
    pub(crate) partition_obs: Vec<std::ops::Range<usize>>,
}

/// The camera index of an edge whose pose is fixed.
pub(crate) const NO_CAM: u32 = u32::MAX;

/// `s` cut into the consecutive `ranges` (which must start at 0 and follow each other; a
/// range past the end gets what is left).
pub(crate) fn split_by_ranges<'a, T>(
    mut s: &'a mut [T],
    ranges: &[std::ops::Range<usize>],
) -> Vec<&'a mut [T]> {
    let mut out = Vec::with_capacity(ranges.len());
    for r in ranges {
        let (head, tail) = s.split_at_mut(r.len().min(s.len()));
        out.push(head);
        s = tail;
    }
    out
}

/// Every pose's `camera_from_world` as a rotation matrix and the camera's position: the
/// per-edge transform is then a matrix-vector product instead of a quaternion rotation.
pub(crate) struct Frames(Vec<(Matrix3<f64>, Vector3<f64>)>);

impl Frames {
    pub(crate) fn of(x: &Vars) -> Self {
        Self(
            x.poses
                .iter()
                .map(|p| {
                    (
                        p.rotation.to_rotation_matrix().into_inner().transpose(),
                        p.translation.vector,
                    )
                })
                .collect(),
        )
    }

    /// `p_world` in the camera of pose `pose` (m), and that camera's `R^T` (the point
    /// Jacobian of a pose-point edge).
    pub(crate) fn to_camera(
        &self,
        pose: usize,
        p_world: &Point3<f64>,
    ) -> Option<(Vector3<f64>, &Matrix3<f64>)> {
        let (rt, t) = self.0.get(pose)?;
        Some((rt * (p_world.coords - t), rt))
    }
}

/// Parallel sums over points use this many partitions, whatever the thread count, so that
/// their order, and with it the result, never changes.
pub(crate) const PARTITIONS: usize = 8;

/// Contiguous ranges of `weights.len()` items with about equal total weight.
fn balanced(weights: &[usize], parts: usize) -> Vec<std::ops::Range<usize>> {
    let total: usize = weights.iter().sum();
    let parts = parts.max(1);
    let mut out = Vec::with_capacity(parts);
    let (mut start, mut acc) = (0, 0);
    for (i, w) in weights.iter().enumerate() {
        acc += w;
        if acc * parts >= total * (out.len() + 1) && out.len() + 1 < parts {
            out.push(start..i + 1);
            start = i + 1;
        }
    }
    out.push(start..weights.len());
    out
}

impl Layout {
    pub(crate) fn new(p: &Problem) -> Self {
        let mut cam_of_pose = Vec::with_capacity(p.poses.len());
        let mut n_cams = 0u32;
        for v in &p.poses {
            cam_of_pose.push((!v.fixed).then(|| {
                n_cams += 1;
                n_cams - 1
            }));
        }
        let mut edge_order: Vec<usize> = (0..p.point_edges.len())
            .filter(|&i| {
                p.point_edges
                    .get(i)
                    .is_some_and(|e| e.point < p.points.len() && e.pose < p.poses.len())
            })
            .collect();
        edge_order.sort_by_key(|&i| p.point_edges.get(i).map(|e| (e.point, e.pose)));
        // Every point's range, empty ones included, starts where the previous one ends, so
        // that a run of points always maps to a run of positions.
        let mut counts = vec![0usize; p.points.len()];
        for &i in &edge_order {
            if let Some(c) = p.point_edges.get(i).and_then(|e| counts.get_mut(e.point)) {
                *c += 1;
            }
        }
        let mut point_ranges = Vec::with_capacity(counts.len());
        let mut start = 0;
        for c in counts {
            point_ranges.push(start..start + c);
            start += c;
        }
        let mut obs_of_cam = vec![Vec::new(); n_cams as usize];
        for (pos, &i) in edge_order.iter().enumerate() {
            if let Some(e) = p.point_edges.get(i) {
                if let Some(Some(c)) = cam_of_pose.get(e.pose) {
                    if let Some(list) = obs_of_cam.get_mut(*c as usize) {
                        list.push((pos, e.point));
                    }
                }
            }
        }
        let weights: Vec<usize> = point_ranges.iter().map(|r| r.len() * r.len() + 1).collect();
        let partitions = balanced(&weights, PARTITIONS);
        let partition_obs = partitions
            .iter()
            .map(|r| {
                let start = point_ranges.get(r.start).map_or(0, |x| x.start);
                let end = r
                    .end
                    .checked_sub(1)
                    .and_then(|last| point_ranges.get(last))
                    .map_or(start, |x| x.end.max(start));
                start..end
            })
            .collect();
        Self {
            partitions,
            partition_obs,
            cam_of_pose,
            edge_order,
            point_ranges,
            obs_of_cam,
        }
    }

    /// The point-edge indices of a point's range.
    pub(crate) fn edges(&self, r: &std::ops::Range<usize>) -> &[usize] {
        self.edge_order.get(r.clone()).unwrap_or(&[])
    }

    pub(crate) fn cam(&self, pose: usize) -> Option<u32> {
        self.cam_of_pose.get(pose).copied().flatten()
    }

    pub(crate) fn pattern(&self, p: &Problem) -> BlockPattern {
        let mut pairs = Vec::new();
        for r in &self.point_ranges {
            let cams: Vec<usize> = self
                .edges(r)
                .iter()
                .filter_map(|&i| p.point_edges.get(i).and_then(|e| self.cam(e.pose)))
                .map(|c| c as usize)
                .collect();
            for (k, &a) in cams.iter().enumerate() {
                for &b in cams.iter().skip(k + 1) {
                    pairs.push((a, b));
                }
            }
        }
        for e in &p.pose_edges {
            if let (Some(a), Some(b)) = (self.cam(e.from), self.cam(e.to)) {
                pairs.push((a as usize, b as usize));
            }
        }
        BlockPattern::new(self.obs_of_cam.len(), pairs)
    }
}
