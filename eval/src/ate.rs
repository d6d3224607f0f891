//! Absolute trajectory error (ATE): the distance between associated positions after
//! alignment (paper 004, eq. 3; Sturm et al. 2012). evo calls it APE w.r.t. the translation
//! part.

use crate::align::{compute_alignment, Alignment};
use crate::error::EvalError;
use crate::options::{Align, Preset};
use crate::stats::Statistics;
use crate::sync::{associate, check_association, too_few_pairs};
use nalgebra::Point3;
use stride_core::pose::{rotation_angle_rad, Pose};
use stride_core::trajectory::Trajectory;

/// How to compute the ATE.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AteOptions {
    /// Whose semantics to reproduce.
    pub preset: Preset,
    /// Alignment of the estimate onto the ground truth.
    pub align: Align,
    /// Association window (s).
    pub t_max_diff_s: f64,
    /// Added to the estimate's stamps before associating (s).
    pub offset_s: f64,
}

impl AteOptions {
    /// The preset's defaults (evo: no alignment, 0.01 s; TUM: SE(3), 0.02 s; no offset).
    pub fn for_preset(preset: Preset) -> Self {
        Self {
            preset,
            align: preset.default_ate_align(),
            t_max_diff_s: preset.default_t_max_diff_s(),
            offset_s: 0.0,
        }
    }
}

/// The ATE of an estimate against ground truth.
#[derive(Debug, Clone)]
pub struct AteResult {
    /// The options used.
    pub options: AteOptions,
    /// Statistics of the position error (metres).
    pub trans_m: Statistics,
    /// Statistics of the orientation error (degrees): the angle of `est⁻¹ · gt` after
    /// alignment (evo's APE `angle_deg`; the TUM tool reports none).
    pub rot_deg: Statistics,
    /// The alignment applied to the estimate.
    pub alignment: Alignment,
    /// Ground-truth stamp (s) of each associated pair, in the tool's order.
    pub stamps_s: Vec<f64>,
    /// Position error of each pair (metres).
    pub errors_m: Vec<f64>,
    /// Ground-truth positions of the pairs (metres, ground-truth frame).
    pub gt_positions: Vec<Point3<f64>>,
    /// Aligned estimate positions of the pairs (metres, ground-truth frame).
    pub est_positions: Vec<Point3<f64>>,
    /// Things the user should know (degenerate alignment tolerated, departures from a preset).
    pub warnings: Vec<String>,
}

/// Computes the ATE of `est` against `gt`.
pub fn ate(
    gt: &Trajectory,
    est: &Trajectory,
    options: &AteOptions,
) -> Result<AteResult, EvalError> {
    let o = *options;
    check_association(o.t_max_diff_s, o.offset_s)?;
    let mut warnings = Vec::new();
    if o.preset == Preset::Tum && o.align != Align::Se3 {
        warnings.push(format!(
            "the TUM tool always aligns with SE(3); alignment {} departs from it",
            o.align
        ));
    }
    let pairs = associate(gt, est, o.preset, o.t_max_diff_s, o.offset_s);
    let needed = match (o.preset, o.align) {
        (_, Align::Se3 | Align::Sim3) => 3,
        (Preset::Tum, _) => 2, // evaluate_ate.py refuses fewer than two matches
        (Preset::Evo, _) => 1,
    };
    if pairs.len() < needed {
        return Err(too_few_pairs(
            gt,
            est,
            pairs.len(),
            needed,
            o.t_max_diff_s,
            o.offset_s,
        ));
    }
    let (gt_poses, est_poses, stamps_s) = gather(gt, est, &pairs);
    let (alignment, mut align_warnings) =
        compute_alignment(&gt_poses, &est_poses, o.align, o.preset)?;
    warnings.append(&mut align_warnings);

    let mut errors_m = Vec::with_capacity(pairs.len());
    let mut rot_deg = Vec::with_capacity(pairs.len());
    let mut gt_positions = Vec::with_capacity(pairs.len());
    let mut est_positions = Vec::with_capacity(pairs.len());
    for (g, e) in gt_poses.iter().zip(&est_poses) {
        let e = alignment.apply(e);
        let (pg, pe) = (g.translation.vector, e.translation.vector);
        errors_m.push((pe - pg).norm());
        rot_deg.push(rotation_angle_rad(&(e.rotation.inverse() * g.rotation)).to_degrees());
        gt_positions.push(pg.into());
        est_positions.push(pe.into());
    }
    let (Some(trans_m), Some(rot)) = (
        Statistics::from_errors(&errors_m),
        Statistics::from_errors(&rot_deg),
    ) else {
        return Err(too_few_pairs(
            gt,
            est,
            0,
            needed,
            o.t_max_diff_s,
            o.offset_s,
        ));
    };
    Ok(AteResult {
        options: o,
        trans_m,
        rot_deg: rot,
        alignment,
        stamps_s,
        errors_m,
        gt_positions,
        est_positions,
        warnings,
    })
}

/// The associated poses of both trajectories and the ground-truth stamps, in pair order.
pub(crate) fn gather(
    gt: &Trajectory,
    est: &Trajectory,
    pairs: &[(usize, usize)],
) -> (Vec<Pose>, Vec<Pose>, Vec<f64>) {
    let mut g = Vec::with_capacity(pairs.len());
    let mut e = Vec::with_capacity(pairs.len());
    let mut t = Vec::with_capacity(pairs.len());
    for &(i, j) in pairs {
        if let (Some(pg), Some(pe), Some(tg)) =
            (gt.poses().get(i), est.poses().get(j), gt.stamps_s().get(i))
        {
            g.push(*pg);
            e.push(*pe);
            t.push(*tg);
        }
    }
    (g, e, t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

    /// A non-degenerate 3-D path: a helix with some attitude change.
    fn helix(n: usize, dt: f64, t0: f64) -> Trajectory {
        let stamps: Vec<f64> = (0..n).map(|i| t0 + i as f64 * dt).collect();
        let poses = (0..n)
            .map(|i| {
                let a = i as f64 * 0.1;
                Isometry3::from_parts(
                    Translation3::new(a.cos(), a.sin(), 0.05 * i as f64),
                    UnitQuaternion::from_euler_angles(0.1 * a.sin(), 0.05, a),
                )
            })
            .collect();
        Trajectory::from_parts(stamps, poses).unwrap()
    }

    fn transformed(t: &Trajectory, f: impl Fn(&Pose) -> Pose) -> Trajectory {
        Trajectory::from_parts(t.stamps_s().to_vec(), t.poses().iter().map(f).collect()).unwrap()
    }

    fn opts(preset: Preset, align: Align) -> AteOptions {
        AteOptions {
            align,
            ..AteOptions::for_preset(preset)
        }
    }

    #[test]
    fn pure_offset_is_the_offset_unaligned_and_zero_aligned() {
        let gt = helix(50, 0.1, 100.0);
        let shift = Vector3::new(0.3, -0.4, 0.0); // |shift| = 0.5 m
        let est = transformed(&gt, |p| {
            Isometry3::from_parts((p.translation.vector + shift).into(), p.rotation)
        });
        for preset in [Preset::Evo, Preset::Tum] {
            let r = ate(&gt, &est, &opts(preset, Align::None)).unwrap();
            assert_relative_eq!(r.trans_m.rmse, 0.5, epsilon = 1e-12);
            assert_relative_eq!(r.trans_m.std, 0.0, epsilon = 1e-12);
            assert_eq!(r.trans_m.count, 50);
            assert_relative_eq!(r.rot_deg.max, 0.0, epsilon = 1e-9);
            let r = ate(&gt, &est, &opts(preset, Align::Se3)).unwrap();
            assert_relative_eq!(r.trans_m.rmse, 0.0, epsilon = 1e-9);
            assert_relative_eq!(r.alignment.translation, -shift, epsilon = 1e-9);
            let r = ate(&gt, &est, &opts(preset, Align::Origin)).unwrap();
            assert_relative_eq!(r.trans_m.max, 0.0, epsilon = 1e-9);
        }
    }

    #[test]
    fn pure_rotation_of_the_world_frame() {
        let gt = helix(60, 0.1, 0.0);
        let world = Isometry3::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.5),
        );
        let est = transformed(&gt, |p| world * p);
        // Unaligned: each position moved by the rotation about the origin: |R p - p|.
        let r = ate(&gt, &est, &opts(Preset::Evo, Align::None)).unwrap();
        let expected: Vec<f64> = gt
            .poses()
            .iter()
            .map(|p| (world.rotation * p.translation.vector - p.translation.vector).norm())
            .collect();
        assert_relative_eq!(r.errors_m.as_slice(), expected.as_slice(), epsilon = 1e-12);
        assert_relative_eq!(r.rot_deg.mean, 0.5f64.to_degrees(), epsilon = 1e-9);
        // Aligned: recovered exactly, orientation errors vanish too.
        let r = ate(&gt, &est, &opts(Preset::Evo, Align::Se3)).unwrap();
        assert_relative_eq!(r.trans_m.rmse, 0.0, epsilon = 1e-9);
        assert_relative_eq!(r.rot_deg.max, 0.0, epsilon = 1e-6);
        assert_relative_eq!(r.alignment.rotation.angle(), 0.5, epsilon = 1e-12);
    }

    #[test]
    fn scale_needs_sim3() {
        let gt = helix(40, 0.1, 0.0);
        let est = transformed(&gt, |p| {
            Isometry3::from_parts((p.translation.vector * 0.5).into(), p.rotation)
        });
        let se3 = ate(&gt, &est, &opts(Preset::Evo, Align::Se3)).unwrap();
        assert!(se3.trans_m.rmse > 0.1);
        let sim3 = ate(&gt, &est, &opts(Preset::Evo, Align::Sim3)).unwrap();
        assert_relative_eq!(sim3.trans_m.rmse, 0.0, epsilon = 1e-9);
        assert_relative_eq!(sim3.alignment.scale, 2.0, epsilon = 1e-12);
    }

    #[test]
    fn timestamp_offset_is_recovered_with_offset_option() {
        let gt = helix(50, 0.1, 100.0);
        // Same poses, clock 0.25 s late, plus a 0.1 m offset to make errors visible.
        let est = Trajectory::from_parts(
            gt.stamps_s().iter().map(|t| t + 0.25).collect(),
            gt.poses()
                .iter()
                .map(|p| {
                    Isometry3::from_parts(
                        (p.translation.vector + Vector3::new(0.1, 0.0, 0.0)).into(),
                        p.rotation,
                    )
                })
                .collect(),
        )
        .unwrap();
        for preset in [Preset::Evo, Preset::Tum] {
            // Without the offset, stamps are 0.05 s away from any ground-truth stamp: no pairs.
            let e = ate(&gt, &est, &opts(preset, Align::None)).unwrap_err();
            assert!(matches!(e, EvalError::TooFewPairs { found: 0, .. }), "{e}");
            let r = ate(
                &gt,
                &est,
                &AteOptions {
                    offset_s: -0.25,
                    ..opts(preset, Align::None)
                },
            )
            .unwrap();
            assert_eq!(r.trans_m.count, 50);
            assert_relative_eq!(r.trans_m.rmse, 0.1, epsilon = 1e-9);
        }
    }

    #[test]
    fn partial_overlap_uses_only_the_common_span() {
        let gt = helix(100, 0.1, 0.0); // 0.0 .. 9.9 s
        let est_full = helix(100, 0.1, 0.0);
        let est = Trajectory::from_parts(
            est_full.stamps_s()[60..]
                .iter()
                .map(|t| t + 0.003)
                .collect(),
            est_full.poses()[60..].to_vec(),
        )
        .unwrap(); // 6.003 .. 9.903 s
        let r = ate(&gt, &est, &opts(Preset::Evo, Align::Se3)).unwrap();
        assert_eq!(r.trans_m.count, 40);
        assert_relative_eq!(r.trans_m.rmse, 0.0, epsilon = 1e-9);
        assert_relative_eq!(r.stamps_s[0], 6.0, epsilon = 1e-9);
        let r = ate(&gt, &est, &opts(Preset::Tum, Align::Se3)).unwrap();
        assert_eq!(r.trans_m.count, 40);
    }

    #[test]
    fn collinear_positions_error_for_evo_and_warn_for_tum() {
        let stamps: Vec<f64> = (0..10).map(|i| i as f64).collect();
        let line: Vec<Pose> = (0..10)
            .map(|i| Isometry3::translation(i as f64 * 0.1, 0.0, 0.0))
            .collect();
        let gt = Trajectory::from_parts(stamps.clone(), line.clone()).unwrap();
        let est = Trajectory::from_parts(
            stamps,
            line.iter()
                .map(|p| Isometry3::translation(0.0, 0.0, 1.0) * p)
                .collect(),
        )
        .unwrap();
        let e = ate(&gt, &est, &opts(Preset::Evo, Align::Se3)).unwrap_err();
        assert!(
            matches!(e, EvalError::DegenerateAlignment { rank: 1, .. }),
            "{e}"
        );
        let r = ate(&gt, &est, &opts(Preset::Tum, Align::Se3)).unwrap();
        assert_relative_eq!(r.trans_m.rmse, 0.0, epsilon = 1e-9);
        assert_eq!(r.warnings.len(), 1);
        // Origin alignment needs no rank.
        let r = ate(&gt, &est, &opts(Preset::Evo, Align::Origin)).unwrap();
        assert_relative_eq!(r.trans_m.rmse, 0.0, epsilon = 1e-12);
    }

    #[test]
    fn evo_association_may_reuse_a_ground_truth_pose_tum_does_not() {
        // Ground truth at 1 Hz, estimate at 10 Hz: evo matches each gt pose to its nearest
        // estimate (gt is shorter); both tools then give one pair per gt pose here.
        let gt = helix(5, 1.0, 0.0);
        let est = helix(50, 0.1, 0.0);
        let r = ate(&gt, &est, &opts(Preset::Evo, Align::None)).unwrap();
        assert_eq!(r.trans_m.count, 5);
        // Estimate shorter than gt but denser in one place: two estimate stamps nearest to the
        // same gt stamp are both kept by evo, only one by TUM's one-to-one rule.
        let gt = Trajectory::from_parts(
            vec![0.0, 1.0, 2.0, 3.0, 4.0],
            helix(5, 1.0, 0.0).poses().to_vec(),
        )
        .unwrap();
        let est =
            Trajectory::from_parts(vec![0.995, 1.004, 3.0], helix(3, 1.0, 0.0).poses().to_vec())
                .unwrap();
        let evo = ate(&gt, &est, &opts(Preset::Evo, Align::None)).unwrap();
        assert_eq!(evo.trans_m.count, 3);
        let tum = ate(&gt, &est, &opts(Preset::Tum, Align::None)).unwrap();
        assert_eq!(tum.trans_m.count, 2);
    }

    #[test]
    fn bad_options_are_rejected() {
        let gt = helix(10, 0.1, 0.0);
        let e = ate(
            &gt,
            &gt,
            &AteOptions {
                t_max_diff_s: -1.0,
                ..opts(Preset::Evo, Align::None)
            },
        )
        .unwrap_err();
        assert!(matches!(e, EvalError::InvalidOption { .. }));
        let e = ate(
            &gt,
            &gt,
            &AteOptions {
                offset_s: f64::NAN,
                ..opts(Preset::Evo, Align::None)
            },
        )
        .unwrap_err();
        assert!(matches!(e, EvalError::InvalidOption { .. }));
    }
}
