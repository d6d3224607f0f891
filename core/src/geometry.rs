//! Closed-form alignment of corresponding 3-D point sets (Umeyama 1991).
//!
//! Given points `src[i]` and `dst[i]`, [`umeyama`] finds the rotation `R`, translation `t`
//! and (optionally) scale `s` minimising `sum_i |dst[i] - (s R src[i] + t)|^2`. It is used
//! to align an estimated trajectory to ground truth (stride-eval) and, inside RANSAC, to
//! estimate the camera motion between two RGB-D frames (stride-frontend).

use nalgebra::{Matrix3, Point3, Rotation3, Similarity3, Translation3, UnitQuaternion, Vector3};

/// Why two point sets cannot be aligned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AlignError {
    /// The two sets differ in size.
    #[error("point sets differ in size ({src} vs {dst})")]
    SizeMismatch {
        /// Number of source points.
        src: usize,
        /// Number of destination points.
        dst: usize,
    },
    /// There are fewer points than the model needs.
    #[error("{found} point pairs, need at least {needed}")]
    TooFewPoints {
        /// Points given.
        found: usize,
        /// Points needed.
        needed: usize,
    },
    /// The source points do not spread at all, so no scale can be estimated.
    #[error("the source points all coincide: scale is undefined")]
    ZeroVariance,
    /// A point holds a NaN or infinite coordinate.
    #[error("point pair #{index} holds a non-finite coordinate")]
    NonFinite {
        /// Index of the pair.
        index: usize,
    },
}

/// The result of [`umeyama`]: `dst ≈ scale * rotation * src + translation`.
#[derive(Debug, Clone, PartialEq)]
pub struct UmeyamaFit {
    /// Rotation `R` taking source directions into the destination frame.
    pub rotation: Rotation3<f64>,
    /// Translation `t` (destination units, usually metres).
    pub translation: Vector3<f64>,
    /// Scale `s`; exactly 1.0 when scale was not estimated.
    pub scale: f64,
    /// Singular values of the cross-covariance matrix, largest first. Their count above
    /// round-off tells whether the fit is well-posed: fewer than two non-zero singular
    /// values means the points are collinear and the rotation about that line is arbitrary.
    pub singular_values: Vector3<f64>,
}

impl UmeyamaFit {
    /// Number of singular values greater than `f64::EPSILON` (the rank test evo applies).
    pub fn rank(&self) -> usize {
        self.singular_values
            .iter()
            .filter(|&&d| d > f64::EPSILON)
            .count()
    }

    /// The fit as a similarity transform `dst_from_src`.
    pub fn to_similarity(&self) -> Similarity3<f64> {
        Similarity3::from_parts(
            Translation3::from(self.translation),
            UnitQuaternion::from_rotation_matrix(&self.rotation),
            self.scale,
        )
    }

    /// Applies the fit to a point: `s R p + t`.
    pub fn transform_point(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.scale * (self.rotation * p.coords) + self.translation)
    }
}

/// Least-squares rigid (or similarity, with `with_scale`) alignment of `src` onto `dst`.
///
/// Follows Umeyama (1991), eqs. 34-43: centroids, cross-covariance `Σ_xy`, its SVD
/// `U D Vᵀ`, `S = diag(1, 1, ±1)` to keep a proper rotation, `R = U S Vᵀ`,
/// `s = tr(D S) / σ_x²`, `t = μ_y - s R μ_x`. Needs at least three pairs. A degenerate
/// configuration (collinear points) still returns a fit; inspect [`UmeyamaFit::rank`].
pub fn umeyama(
    src: &[Point3<f64>],
    dst: &[Point3<f64>],
    with_scale: bool,
) -> Result<UmeyamaFit, AlignError> {
    if src.len() != dst.len() {
        return Err(AlignError::SizeMismatch {
            src: src.len(),
            dst: dst.len(),
        });
    }
    if src.len() < 3 {
        return Err(AlignError::TooFewPoints {
            found: src.len(),
            needed: 3,
        });
    }
    for (index, (a, b)) in src.iter().zip(dst).enumerate() {
        if !(a.coords.iter().all(|v| v.is_finite()) && b.coords.iter().all(|v| v.is_finite())) {
            return Err(AlignError::NonFinite { index });
        }
    }
    let n = src.len() as f64;
    let mean_x = src.iter().fold(Vector3::zeros(), |acc, p| acc + p.coords) / n;
    let mean_y = dst.iter().fold(Vector3::zeros(), |acc, p| acc + p.coords) / n;
    let mut cov = Matrix3::zeros();
    let mut sigma_x = 0.0;
    for (x, y) in src.iter().zip(dst) {
        let dx = x.coords - mean_x;
        let dy = y.coords - mean_y;
        cov += dy * dx.transpose();
        sigma_x += dx.norm_squared();
    }
    cov /= n;
    sigma_x /= n;
    fit_from_moments(&cov, sigma_x, &mean_x, &mean_y, with_scale)
}

/// Finishes an Umeyama fit from precomputed moments: the cross-covariance
/// `Σ_xy = 1/n Σ (y - μ_y)(x - μ_x)ᵀ`, the source variance `σ_x² = 1/n Σ |x - μ_x|²` and
/// both centroids. Exposed for callers that accumulate moments themselves (weighted or
/// streaming fits).
pub fn fit_from_moments(
    cov: &Matrix3<f64>,
    sigma_x: f64,
    mean_x: &Vector3<f64>,
    mean_y: &Vector3<f64>,
    with_scale: bool,
) -> Result<UmeyamaFit, AlignError> {
    let svd = cov.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        // nalgebra always computes U and Vᵀ when asked; treat absence as non-finite input.
        return Err(AlignError::NonFinite { index: 0 });
    };
    // Sort singular values (and vectors) in decreasing order so that the reflection fix
    // below acts on the smallest one.
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    let d = Vector3::new(
        svd.singular_values[order[0]],
        svd.singular_values[order[1]],
        svd.singular_values[order[2]],
    );
    let u = Matrix3::from_columns(&[u.column(order[0]), u.column(order[1]), u.column(order[2])]);
    let v_t = Matrix3::from_rows(&[v_t.row(order[0]), v_t.row(order[1]), v_t.row(order[2])]);
    let mut s = Vector3::new(1.0, 1.0, 1.0);
    if u.determinant() * v_t.determinant() < 0.0 {
        s.z = -1.0;
    }
    let r = u * Matrix3::from_diagonal(&s) * v_t;
    let scale = if with_scale {
        if sigma_x.is_nan() || sigma_x <= 0.0 {
            return Err(AlignError::ZeroVariance);
        }
        d.dot(&s) / sigma_x
    } else {
        1.0
    };
    let translation = mean_y - scale * (r * mean_x);
    Ok(UmeyamaFit {
        rotation: Rotation3::from_matrix_unchecked(r),
        translation,
        scale,
        singular_values: d,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn cloud() -> Vec<Point3<f64>> {
        vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 2.0, 0.0),
            Point3::new(0.0, 0.0, 3.0),
            Point3::new(1.0, 1.0, 1.0),
        ]
    }

    #[test]
    fn recovers_a_known_similarity() {
        let truth = Similarity3::from_parts(
            Translation3::new(0.5, -1.0, 2.0),
            UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1),
            1.7,
        );
        let src = cloud();
        let dst: Vec<_> = src.iter().map(|p| truth * p).collect();
        let fit = umeyama(&src, &dst, true).unwrap();
        assert_relative_eq!(fit.scale, 1.7, epsilon = 1e-12);
        for (a, b) in src.iter().zip(&dst) {
            assert_relative_eq!(fit.transform_point(a), *b, epsilon = 1e-12);
        }
        assert_eq!(fit.rank(), 3);
        let rigid = umeyama(&src, &dst, false).unwrap();
        assert_eq!(rigid.scale, 1.0);
        assert_relative_eq!(
            rigid.rotation.matrix(),
            truth.isometry.rotation.to_rotation_matrix().matrix(),
            epsilon = 1e-12
        );
    }

    #[test]
    fn reports_collinear_points_as_rank_one() {
        let src: Vec<_> = (0..5).map(|i| Point3::new(i as f64, 0.0, 0.0)).collect();
        let dst: Vec<_> = (0..5).map(|i| Point3::new(0.0, i as f64, 1.0)).collect();
        let fit = umeyama(&src, &dst, false).unwrap();
        assert_eq!(fit.rank(), 1);
        // Even so the aligned points coincide with the targets.
        for (a, b) in src.iter().zip(&dst) {
            assert_relative_eq!(fit.transform_point(a), *b, epsilon = 1e-12);
        }
    }

    #[test]
    fn rejects_bad_input() {
        let c = cloud();
        assert!(matches!(
            umeyama(&c[..2], &c[..2], false),
            Err(AlignError::TooFewPoints { .. })
        ));
        assert!(matches!(
            umeyama(&c, &c[..3], false),
            Err(AlignError::SizeMismatch { .. })
        ));
        let same = vec![Point3::new(1.0, 1.0, 1.0); 4];
        assert!(matches!(
            umeyama(&same, &same, true),
            Err(AlignError::ZeroVariance)
        ));
        let mut bad = c.clone();
        bad[2].y = f64::NAN;
        assert!(matches!(
            umeyama(&bad, &c, false),
            Err(AlignError::NonFinite { index: 2 })
        ));
    }
}
