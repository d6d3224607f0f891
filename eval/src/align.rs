//! Bringing the estimate into the ground truth's frame.

use crate::error::EvalError;
use crate::options::{Align, Preset};
use nalgebra::{Point3, UnitQuaternion, Vector3};
use serde::Serialize;
use stride_core::geometry::umeyama;
use stride_core::pose::Pose;

/// A similarity `gt_from_est`: `p_gt = scale * rotation * p_est + translation`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Alignment {
    /// Rotation from the estimate's world frame to the ground truth's.
    pub rotation: UnitQuaternion<f64>,
    /// Translation (metres, ground-truth frame).
    pub translation: Vector3<f64>,
    /// Scale (1 unless Sim(3)).
    pub scale: f64,
}

/// The alignment as JSON-friendly numbers.
#[derive(Debug, Clone, Serialize)]
pub struct AlignmentSummary {
    /// Rotation angle (degrees).
    pub rotation_deg: f64,
    /// Translation (metres).
    pub translation_m: [f64; 3],
    /// Scale factor.
    pub scale: f64,
}

impl Alignment {
    /// The identity (no alignment).
    pub fn identity() -> Self {
        Self {
            rotation: UnitQuaternion::identity(),
            translation: Vector3::zeros(),
            scale: 1.0,
        }
    }

    /// Applies the alignment to a pose `world_est_from_body`, giving `world_gt_from_body`:
    /// the position is scaled, rotated and shifted; the orientation only rotated.
    pub fn apply(&self, pose: &Pose) -> Pose {
        let p = self.scale * (self.rotation * pose.translation.vector) + self.translation;
        Pose::from_parts(p.into(), self.rotation * pose.rotation)
    }

    /// Numbers for reports.
    pub fn summary(&self) -> AlignmentSummary {
        AlignmentSummary {
            rotation_deg: self.rotation.angle().to_degrees(),
            translation_m: [self.translation.x, self.translation.y, self.translation.z],
            scale: self.scale,
        }
    }
}

/// Computes the alignment of associated estimate poses onto ground-truth poses.
///
/// SE(3)/Sim(3) fit the positions with Umeyama's method. A degenerate fit (fewer than two
/// non-zero singular values, evo's test) is an error with the evo preset, as in evo, and a
/// warning with the TUM preset, whose tool aligns regardless (the aligned positions are still
/// well defined). `origin` maps the first estimate pose onto the first ground-truth pose.
/// Returns the alignment and any warnings.
pub fn compute_alignment(
    gt: &[Pose],
    est: &[Pose],
    align: Align,
    preset: Preset,
) -> Result<(Alignment, Vec<String>), EvalError> {
    let mut warnings = Vec::new();
    let alignment = match align {
        Align::None => Alignment::identity(),
        Align::Origin => match (gt.first(), est.first()) {
            (Some(g), Some(e)) => {
                let t = g * e.inverse();
                Alignment {
                    rotation: t.rotation,
                    translation: t.translation.vector,
                    scale: 1.0,
                }
            }
            _ => Alignment::identity(),
        },
        Align::Se3 | Align::Sim3 => {
            let src: Vec<Point3<f64>> = est.iter().map(|p| p.translation.vector.into()).collect();
            let dst: Vec<Point3<f64>> = gt.iter().map(|p| p.translation.vector.into()).collect();
            let fit = umeyama(&src, &dst, align == Align::Sim3).map_err(|e| {
                EvalError::AlignmentFailed {
                    align,
                    reason: e.to_string(),
                }
            })?;
            let rank = fit.rank();
            if rank < 2 {
                match preset {
                    Preset::Evo => {
                        return Err(EvalError::DegenerateAlignment {
                            align,
                            pairs: src.len(),
                            rank,
                        })
                    }
                    Preset::Tum => warnings.push(format!(
                        "{align} alignment is degenerate (the {} associated positions are \
                         collinear): the rotation about their line is arbitrary; errors are \
                         still well defined, and the TUM tool proceeds the same way",
                        src.len()
                    )),
                }
            }
            Alignment {
                rotation: UnitQuaternion::from_rotation_matrix(&fit.rotation),
                translation: fit.translation,
                scale: fit.scale,
            }
        }
    };
    Ok((alignment, warnings))
}
