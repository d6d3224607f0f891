//! Camera motion from 3-D-to-3-D correspondences: Umeyama without scale on minimal 3-point
//! samples inside RANSAC (adaptive iteration count, seeded), inliers by Mahalanobis or
//! Euclidean distance, a refit on all inliers, then Gauss-Newton on SE(3) minimising the
//! covariance-weighted 3-D error `sum r_i^T (Sigma_ref,i + R Sigma_cur,i R^T)^-1 r_i` with
//! `r_i = p_ref,i - (R p_cur,i + t)`.

use crate::config::InlierTest;
use crate::points::Measurement;
use nalgebra::{
    Isometry3, Matrix3, Matrix6, Point3, Translation3, UnitQuaternion, Vector3, Vector6,
};
use stride_core::geometry::umeyama;
use stride_core::rng::SplitMix64;

/// A correspondence: the same scene point known in a reference frame and measured in the
/// current frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correspondence {
    /// In the reference frame, the one [`MotionEstimate::ref_from_cur`] maps into: the
    /// world for the odometry (a track's fused world point), another keyframe's camera
    /// frame for keyframe-to-keyframe estimates.
    pub reference: Measurement,
    /// In the current camera frame.
    pub current: Measurement,
}

/// How [`estimate`] works: inlier test, RANSAC and refinement settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionParams {
    /// Inlier test.
    pub test: InlierTest,
    /// Probability of drawing at least one all-inlier sample.
    pub confidence: f64,
    /// Most RANSAC iterations.
    pub max_iterations: usize,
    /// Fewest RANSAC iterations, whatever the adaptive count says (see
    /// [`crate::VoConfig::ransac_min_iterations`]).
    pub min_iterations: usize,
    /// Fewest inliers accepted.
    pub min_inliers: usize,
    /// Gauss-Newton iterations.
    pub refine_iterations: usize,
    /// Isotropic standard deviation (m) added to every correspondence's covariance for the
    /// errors the sensor model does not describe (see [`crate::VoConfig::model_noise_m`]).
    pub model_noise_m: f64,
}

impl MotionParams {
    /// The parameters of a [`crate::VoConfig`].
    pub fn from_config(c: &crate::VoConfig) -> Self {
        Self {
            test: c.inlier_test,
            confidence: c.ransac_confidence,
            max_iterations: c.ransac_max_iterations,
            min_iterations: c.ransac_min_iterations,
            min_inliers: c.min_inliers,
            refine_iterations: c.refine_iterations,
            model_noise_m: c.model_noise_m,
        }
    }
}

/// Combined covariance of a correspondence's residual under rotation `r`:
/// `Sigma_ref + R Sigma_cur R^T + sigma_model^2 I`.
fn residual_cov(c: &Correspondence, r: &Matrix3<f64>, model_noise_m: f64) -> Matrix3<f64> {
    c.reference.cov
        + r * c.current.cov * r.transpose()
        + Matrix3::identity() * (model_noise_m * model_noise_m)
}

/// The estimated motion.
#[derive(Debug, Clone, PartialEq)]
pub struct MotionEstimate {
    /// `ref_from_cur`: maps current-frame points into the reference frame.
    pub ref_from_cur: Isometry3<f64>,
    /// Inlier flag per correspondence.
    pub inliers: Vec<bool>,
    /// Number of inliers.
    pub inlier_count: usize,
    /// RANSAC iterations run.
    pub iterations: usize,
    /// Information matrix (6x6, translation then rotation, left perturbation) of the refined
    /// pose; its inverse approximates the pose covariance.
    pub information: Matrix6<f64>,
    /// Mean squared Mahalanobis distance of the inliers after refinement.
    pub mean_chi2: f64,
}

/// Squared Mahalanobis distance of a correspondence under `ref_from_cur`.
fn chi2(c: &Correspondence, t: &Isometry3<f64>, model_noise_m: f64) -> Option<f64> {
    let q = t * c.current.p;
    let r = c.reference.p - q;
    let rot = t.rotation.to_rotation_matrix();
    let inv = residual_cov(c, rot.matrix(), model_noise_m).try_inverse()?;
    Some((r.transpose() * inv * r)[(0, 0)])
}

pub(crate) fn is_inlier(
    c: &Correspondence,
    t: &Isometry3<f64>,
    test: InlierTest,
    model_noise_m: f64,
) -> bool {
    match test {
        InlierTest::Mahalanobis { chi2: bound } => {
            chi2(c, t, model_noise_m).is_some_and(|d| d < bound)
        }
        InlierTest::Euclidean { max_m } => (c.reference.p - t * c.current.p).norm() < max_m,
    }
}

/// Inlier count and truncated cost of a hypothesis (MSAC): each inlier contributes its
/// squared distance (Mahalanobis, or Euclidean over the bound, scaled to the same bound),
/// each outlier the bound. `None` as soon as the cost exceeds `give_up_above` (the best
/// cost so far: such a hypothesis cannot win, since the cost only grows).
fn msac(
    corrs: &[Correspondence],
    t: &Isometry3<f64>,
    test: InlierTest,
    model_noise_m: f64,
    give_up_above: f64,
) -> Option<(usize, f64)> {
    let (mut count, mut score) = (0, 0.0);
    for c in corrs {
        let (d, bound) = match test {
            InlierTest::Mahalanobis { chi2: b } => {
                (chi2(c, t, model_noise_m).unwrap_or(f64::INFINITY), b)
            }
            InlierTest::Euclidean { max_m } => (
                (c.reference.p - t * c.current.p).norm_squared(),
                max_m * max_m,
            ),
        };
        if d < bound {
            count += 1;
            score += d;
        } else {
            score += bound;
        }
        if score > give_up_above {
            return None;
        }
    }
    Some((count, score))
}

fn fit(corrs: &[Correspondence], idx: impl Iterator<Item = usize>) -> Option<Isometry3<f64>> {
    let (mut src, mut dst) = (Vec::new(), Vec::new());
    for i in idx {
        let c = corrs.get(i)?;
        src.push(c.current.p);
        dst.push(c.reference.p);
    }
    let f = umeyama(&src, &dst, false).ok()?;
    if f.rank() < 2 {
        return None;
    }
    let iso = Isometry3::from_parts(
        Translation3::from(f.translation),
        UnitQuaternion::from_rotation_matrix(&f.rotation),
    );
    is_finite(&iso).then_some(iso)
}

/// True when every number of the pose is finite.
pub fn is_finite(t: &Isometry3<f64>) -> bool {
    t.translation.vector.iter().all(|v| v.is_finite())
        && t.rotation.coords.iter().all(|v| v.is_finite())
}

/// RANSAC over minimal samples. `None` when no hypothesis reaches `min_inliers`.
pub fn ransac(
    corrs: &[Correspondence],
    params: &MotionParams,
    rng: &mut SplitMix64,
) -> Option<(Isometry3<f64>, Vec<bool>, usize)> {
    let MotionParams {
        test,
        confidence,
        max_iterations,
        min_iterations,
        min_inliers,
        model_noise_m,
        ..
    } = *params;
    let n = corrs.len();
    if n < 3 || n < min_inliers {
        return None;
    }
    // MSAC: hypotheses are ranked by their truncated cost (each correspondence's squared
    // Mahalanobis distance, or the bound for an outlier), which prefers the hypothesis
    // that fits its inliers best among those with as many inliers. The adaptive count
    // trusts the best inlier ratio so far; `min_iterations` keeps drawing when a cluster
    // of wrong correspondences that agree with each other got there first.
    let mut best: Option<(Isometry3<f64>, usize, f64)> = None;
    let mut needed = max_iterations;
    let mut it = 0;
    while it < needed.max(min_iterations).min(max_iterations) {
        it += 1;
        let a = rng.below(n);
        let mut b = rng.below(n);
        while b == a {
            b = rng.below(n);
        }
        let mut c = rng.below(n);
        while c == a || c == b {
            c = rng.below(n);
        }
        let Some(t) = fit(corrs, [a, b, c].into_iter()) else {
            continue;
        };
        let best_score = best.as_ref().map_or(f64::INFINITY, |(_, _, bs)| *bs);
        let Some((count, score)) = msac(corrs, &t, test, model_noise_m, best_score) else {
            continue;
        };
        if score < best_score {
            best = Some((t, count, score));
            // Adaptive iteration count for the best inlier ratio so far.
            let w = count as f64 / n as f64;
            let p_good = w * w * w;
            needed = if p_good >= 1.0 - 1e-12 {
                it
            } else if p_good <= 1e-12 {
                max_iterations
            } else {
                ((1.0 - confidence).ln() / (1.0 - p_good).ln())
                    .ceil()
                    .max(1.0) as usize
            };
        }
    }
    let (t, count, _) = best?;
    if count < min_inliers {
        return None;
    }
    // No unweighted refit on all inliers: it lets far, depth-uncertain points pull the pose
    // (by centimetres on real data); the covariance-weighted refinement (`polish`) starts
    // from the best hypothesis instead.
    let flags: Vec<bool> = corrs
        .iter()
        .map(|c| is_inlier(c, &t, test, model_noise_m))
        .collect();
    (count >= min_inliers).then_some((t, flags, it))
}

fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Gauss-Newton refinement of `ref_from_cur` over the inliers, minimising the
/// covariance-weighted 3-D error. Returns the refined pose, its information matrix and the
/// mean squared Mahalanobis distance.
pub fn refine(
    corrs: &[Correspondence],
    inliers: &[bool],
    initial: Isometry3<f64>,
    iterations: usize,
    model_noise_m: f64,
) -> (Isometry3<f64>, Matrix6<f64>, f64) {
    let mut t = initial;
    let mut info = Matrix6::zeros();
    let mut mean = f64::NAN;
    for _ in 0..iterations.max(1) {
        let rot = t.rotation.to_rotation_matrix();
        let mut h = Matrix6::zeros();
        let mut g = Vector6::zeros();
        let (mut sum, mut n) = (0.0, 0usize);
        for (c, _) in corrs.iter().zip(inliers).filter(|(_, &f)| f) {
            let q = t * c.current.p;
            let r: Vector3<f64> = c.reference.p - q;
            let Some(w) = residual_cov(c, rot.matrix(), model_noise_m).try_inverse() else {
                continue;
            };
            // r(xi) = p_ref - (exp(xi) q) ~ r - v - omega x q  =>  J = [-I, [q]x]
            let mut j = nalgebra::Matrix3x6::zeros();
            j.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&(-Matrix3::identity()));
            j.fixed_view_mut::<3, 3>(0, 3).copy_from(&skew(&q.coords));
            let jtw = j.transpose() * w;
            h += jtw * j;
            g += jtw * r;
            sum += (r.transpose() * w * r)[(0, 0)];
            n += 1;
        }
        info = h;
        mean = if n > 0 { sum / n as f64 } else { f64::NAN };
        let Some(delta) = h.lu().solve(&(-g)) else {
            break;
        };
        if !delta.iter().all(|v| v.is_finite()) {
            break;
        }
        let v = Vector3::new(delta[0], delta[1], delta[2]);
        let w = Vector3::new(delta[3], delta[4], delta[5]);
        let step =
            Isometry3::from_parts(Translation3::from(v), UnitQuaternion::from_scaled_axis(w));
        let next = step * t;
        if !is_finite(&next) {
            break;
        }
        t = next;
        if v.norm() < 1e-7 && w.norm() < 1e-7 {
            break;
        }
    }
    (t, info, mean)
}

/// Rounds of refinement and inlier re-selection at most in [`polish`].
const POLISH_ROUNDS: usize = 3;

/// Refines a hypothesis and its inlier set together: Gauss-Newton over the inliers, then
/// the inliers are selected again at the refined pose, and refined again, until the set no
/// longer changes (at most three rounds). A few far, depth-uncertain correspondences that
/// happened to agree with a poor hypothesis are dropped this way instead of pulling the
/// refined pose towards it. `None` when fewer than `min_inliers` remain.
pub fn polish(
    corrs: &[Correspondence],
    hypothesis: Isometry3<f64>,
    inliers: Vec<bool>,
    iterations: usize,
    params: &MotionParams,
) -> Option<MotionEstimate> {
    let mut pose = hypothesis;
    let mut inliers = inliers;
    let (mut information, mut mean_chi2) = (Matrix6::zeros(), f64::NAN);
    for _ in 0..POLISH_ROUNDS {
        let (refined, info, chi2) = refine(corrs, &inliers, pose, iterations, params.model_noise_m);
        if !is_finite(&refined) {
            break;
        }
        pose = refined;
        information = info;
        mean_chi2 = chi2;
        let again: Vec<bool> = corrs
            .iter()
            .map(|c| is_inlier(c, &pose, params.test, params.model_noise_m))
            .collect();
        let same = again == inliers;
        inliers = again;
        if same {
            break;
        }
    }
    let inlier_count = inliers.iter().filter(|&&f| f).count();
    (inlier_count >= params.min_inliers && is_finite(&pose)).then_some(MotionEstimate {
        ref_from_cur: pose,
        inliers,
        inlier_count,
        iterations: 0,
        information,
        mean_chi2,
    })
}

/// RANSAC, then [`polish`], in one call. `None` when no motion with enough inliers
/// exists.
pub fn estimate(
    corrs: &[Correspondence],
    params: &MotionParams,
    rng: &mut SplitMix64,
) -> Option<MotionEstimate> {
    let (t, flags, iterations) = ransac(corrs, params, rng)?;
    polish(corrs, t, flags, params.refine_iterations, params)
        .map(|e| MotionEstimate { iterations, ..e })
}

/// A correspondence from two points with isotropic covariance `sigma^2 I` (for tests and
/// callers without a sensor model).
pub fn isotropic(reference: Point3<f64>, current: Point3<f64>, sigma: f64) -> Correspondence {
    let cov = Matrix3::identity() * sigma * sigma;
    Correspondence {
        reference: Measurement { p: reference, cov },
        current: Measurement { p: current, cov },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(test: InlierTest, min_inliers: usize) -> MotionParams {
        MotionParams {
            test,
            confidence: 0.999,
            max_iterations: 300,
            min_iterations: 0,
            min_inliers,
            refine_iterations: 10,
            model_noise_m: 0.0,
        }
    }

    fn scene(n: usize, rng: &mut SplitMix64) -> Vec<Point3<f64>> {
        (0..n)
            .map(|_| {
                Point3::new(
                    rng.range(-2.0, 2.0),
                    rng.range(-1.5, 1.5),
                    rng.range(1.0, 4.0),
                )
            })
            .collect()
    }

    #[test]
    fn recovers_the_motion_despite_noise_and_outliers() {
        let mut rng = SplitMix64::new(9);
        let truth = Isometry3::from_parts(
            Translation3::new(0.05, -0.02, 0.1),
            UnitQuaternion::from_euler_angles(0.02, -0.05, 0.03),
        );
        let pts = scene(300, &mut rng);
        let sigma = 0.005;
        let corrs: Vec<Correspondence> = pts
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let cur = truth.inverse() * p;
                let noisy = |q: Point3<f64>, r: &mut SplitMix64| {
                    q + Vector3::new(r.normal(), r.normal(), r.normal()) * sigma
                };
                let reference = if i % 4 == 0 {
                    p + Vector3::new(0.3, -0.2, 0.5)
                } else {
                    noisy(*p, &mut rng)
                };
                isotropic(reference, noisy(cur, &mut rng), sigma)
            })
            .collect();
        let est = estimate(
            &corrs,
            &params(InlierTest::Mahalanobis { chi2: 11.34 }, 12),
            &mut rng,
        )
        .unwrap();
        let err = truth.inverse() * est.ref_from_cur;
        assert!(
            err.translation.vector.norm() < 2e-3,
            "{}",
            err.translation.vector.norm()
        );
        assert!(err.rotation.angle() < 2e-3);
        // All 75 outliers rejected, nearly all inliers kept.
        assert!(est
            .inliers
            .iter()
            .enumerate()
            .all(|(i, &f)| i % 4 != 0 || !f));
        assert!(est.inlier_count > 210, "{}", est.inlier_count);
        assert!(est.iterations < 60, "adaptive count: {}", est.iterations);
        assert!(
            (est.mean_chi2 - 3.0).abs() < 1.0,
            "chi2 per point ~ 3 dof: {}",
            est.mean_chi2
        );
    }

    #[test]
    fn fails_cleanly_on_degenerate_or_random_data() {
        let mut rng = SplitMix64::new(1);
        let few: Vec<_> = (0..2)
            .map(|i| {
                isotropic(
                    Point3::new(i as f64, 0.0, 1.0),
                    Point3::new(i as f64, 0.0, 1.0),
                    0.01,
                )
            })
            .collect();
        assert!(estimate(
            &few,
            &params(InlierTest::Euclidean { max_m: 0.02 }, 3),
            &mut rng
        )
        .is_none());
        let random: Vec<_> = (0..50)
            .map(|_| {
                isotropic(
                    Point3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), 2.0),
                    Point3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), 2.0),
                    0.005,
                )
            })
            .collect();
        assert!(estimate(
            &random,
            &params(InlierTest::Mahalanobis { chi2: 11.34 }, 20),
            &mut rng
        )
        .is_none());
        let collinear: Vec<_> = (0..30)
            .map(|i| {
                isotropic(
                    Point3::new(i as f64 * 0.1, 0.0, 2.0),
                    Point3::new(i as f64 * 0.1, 0.0, 2.0),
                    0.005,
                )
            })
            .collect();
        assert!(estimate(
            &collinear,
            &params(InlierTest::Mahalanobis { chi2: 11.34 }, 12),
            &mut rng
        )
        .is_none());
    }

    /// 100 scene points seen 1 cm further along x, every correspondence exact.
    fn shifted_scene() -> Vec<Correspondence> {
        let mut rng = SplitMix64::new(4);
        scene(100, &mut rng)
            .iter()
            .map(|p| isotropic(*p, Point3::new(p.x + 0.01, p.y, p.z), 0.01))
            .collect()
    }

    #[test]
    fn the_search_draws_at_least_min_iterations_samples() {
        // Every correspondence exact: the first sample is all inliers and the adaptive
        // count stops there.
        let corrs = shifted_scene();
        let p = params(InlierTest::Mahalanobis { chi2: 11.34 }, 12);
        let quick = estimate(&corrs, &p, &mut SplitMix64::new(5)).unwrap();
        assert!(quick.iterations < 5, "{}", quick.iterations);
        let p = MotionParams {
            min_iterations: 40,
            ..p
        };
        let thorough = estimate(&corrs, &p, &mut SplitMix64::new(5)).unwrap();
        assert_eq!(thorough.iterations, 40);
        let moved = thorough.ref_from_cur.translation.vector - Vector3::new(-0.01, 0.0, 0.0);
        assert!(moved.norm() < 1e-9, "{moved}");
    }

    #[test]
    fn same_seed_same_result() {
        let corrs = shifted_scene();
        let p = params(InlierTest::Mahalanobis { chi2: 11.34 }, 12);
        let a = estimate(&corrs, &p, &mut SplitMix64::new(5)).unwrap();
        let b = estimate(&corrs, &p, &mut SplitMix64::new(5)).unwrap();
        assert_eq!(a, b);
    }
}
