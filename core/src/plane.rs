//! Planes in 3-D: a least-squares fit and a seeded RANSAC search (e.g. the floor under a
//! walking robot's camera, which gives the direction of gravity).

use crate::rng::SplitMix64;
use nalgebra::{Matrix3, Point3, SymmetricEigen, Unit, Vector3};

/// The plane `normal . p = offset_m` (unit normal; `offset_m` in metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Unit normal.
    pub normal: Unit<Vector3<f64>>,
    /// Signed distance of the plane from the origin along the normal (m).
    pub offset_m: f64,
}

impl Plane {
    /// Signed distance of `p` from the plane, positive on the normal's side (m).
    pub fn distance_m(&self, p: &Point3<f64>) -> f64 {
        self.normal.dot(&p.coords) - self.offset_m
    }

    /// The same plane with its normal pointing towards `p`'s side.
    pub fn facing(self, p: &Point3<f64>) -> Self {
        if self.distance_m(p) >= 0.0 {
            self
        } else {
            Self {
                normal: -self.normal,
                offset_m: -self.offset_m,
            }
        }
    }
}

/// The least-squares plane through points (smallest eigenvector of their scatter about the
/// centroid). `None` for fewer than 3 points or non-finite input.
pub fn fit_plane(points: &[Point3<f64>]) -> Option<Plane> {
    if points.len() < 3 {
        return None;
    }
    let n = points.len() as f64;
    let centroid = points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let scatter = points.iter().fold(Matrix3::zeros(), |a, p| {
        let d = p.coords - centroid;
        a + d * d.transpose()
    });
    if !scatter.iter().all(|v| v.is_finite()) {
        return None;
    }
    let eig = SymmetricEigen::new(scatter);
    let (k, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let normal = Unit::try_new(eig.eigenvectors.column(k).into_owned(), 1e-12)?;
    Some(Plane {
        normal,
        offset_m: normal.dot(&centroid),
    })
}

/// Seeded RANSAC for the plane with the most points within `threshold_m` (m) among those
/// `accept` admits, refitted by least squares on its inliers: the plane and its inlier
/// count. `iterations` samples of three points, drawn from `rng` (same seed, same plane).
pub fn ransac_plane(
    points: &[Point3<f64>],
    threshold_m: f64,
    iterations: usize,
    rng: &mut SplitMix64,
    accept: impl Fn(&Plane) -> bool,
) -> Option<(Plane, usize)> {
    if points.len() < 3 {
        return None;
    }
    let count = |plane: &Plane| {
        points
            .iter()
            .filter(|p| plane.distance_m(p).abs() <= threshold_m)
            .count()
    };
    let mut best: Option<(Plane, usize)> = None;
    for _ in 0..iterations {
        let [a, b, c] = [0; 3].map(|_| points.get(rng.below(points.len())).copied());
        let (Some(a), Some(b), Some(c)) = (a, b, c) else {
            continue;
        };
        let Some(normal) = Unit::try_new((b - a).cross(&(c - a)), 1e-9) else {
            continue;
        };
        let plane = Plane {
            normal,
            offset_m: normal.dot(&a.coords),
        };
        if !accept(&plane) {
            continue;
        }
        let n = count(&plane);
        if best.as_ref().is_none_or(|(_, m)| n > *m) {
            best = Some((plane, n));
        }
    }
    let (plane, _) = best?;
    let inliers: Vec<Point3<f64>> = points
        .iter()
        .filter(|p| plane.distance_m(p).abs() <= threshold_m)
        .copied()
        .collect();
    // The least-squares normal's sign is arbitrary: orient it as the sampled plane's.
    let refined = fit_plane(&inliers).map(|p| {
        if p.normal.dot(&plane.normal) < 0.0 {
            Plane {
                normal: -p.normal,
                offset_m: -p.offset_m,
            }
        } else {
            p
        }
    });
    let plane = refined.filter(|p| accept(p)).unwrap_or(plane);
    Some((plane, count(&plane)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_the_floor_among_clutter_and_refits_it() {
        let mut rng = SplitMix64::new(4);
        // A floor 0.5 m below the origin (z up), tilted by 0.1 rad about x, with 2 mm
        // noise, and a third as many points on a wall and in the air.
        let tilt = nalgebra::Rotation3::from_euler_angles(0.1, 0.0, 0.0);
        let mut points: Vec<Point3<f64>> = (0..600)
            .map(|_| {
                let p = Point3::new(rng.range(-1.0, 1.0), rng.range(0.5, 2.5), -0.5);
                tilt * Point3::new(p.x, p.y, p.z + 0.002 * rng.normal())
            })
            .collect();
        points
            .extend((0..200).map(|_| Point3::new(1.5, rng.range(0.0, 2.0), rng.range(-0.5, 1.0))));
        points
            .extend((0..100).map(|_| Point3::new(rng.range(-1.0, 1.0), 1.0, rng.range(0.0, 1.0))));
        let up = tilt * Vector3::z();
        let (plane, inliers) = ransac_plane(&points, 0.01, 200, &mut rng, |p| {
            p.normal.dot(&up).abs() > 0.9
        })
        .unwrap();
        let plane = plane.facing(&Point3::origin());
        assert!((590..=610).contains(&inliers), "{inliers}");
        assert!(plane.normal.dot(&up) > 0.99999, "{:?}", plane.normal);
        assert!((plane.distance_m(&Point3::origin()) - 0.5).abs() < 1e-3);
        // Same seed, same plane.
        let again = ransac_plane(&points, 0.01, 200, &mut SplitMix64::new(4), |p| {
            p.normal.dot(&up).abs() > 0.9
        });
        let first = ransac_plane(&points, 0.01, 200, &mut SplitMix64::new(4), |p| {
            p.normal.dot(&up).abs() > 0.9
        });
        assert_eq!(again, first);
        assert!(fit_plane(&points[..2]).is_none());
    }
}
