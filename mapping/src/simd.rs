//! The input stage's loops run compiled for AVX2 where the CPU has it: the workspace's
//! runtime dispatch ([`stride_core::simd`]), re-exported here with the test that the two
//! copies of the mappers' loops give the same maps.

pub(crate) use stride_core::simd::dispatch;
pub use stride_core::simd::{force_portable, instruction_set};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fankhauser::{FankhauserConfig, FankhauserMapper};
    use crate::input::SensorFrame;
    use crate::stack::{StackConfig, StackMapper};
    use crate::{ElevationMapper, MapLayers};
    use nalgebra::{Isometry3, Rotation3, Translation3, UnitQuaternion, Vector3};
    use stride_core::camera::PinholeCamera;
    use stride_core::image::DepthImage;

    /// A noisy floor 0.5 m below a camera that looks straight down, a 10 cm box on it
    /// (depth jumps for the edge filter), holes, and a width that is no multiple of any
    /// vector width (loop tails).
    fn scene() -> DepthImage {
        let mut state = 12345u64;
        let mut noise = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * 0.004
        };
        let (w, h) = (133u32, 97u32);
        let mut data = Vec::with_capacity((w * h) as usize);
        for v in 0..h {
            for u in 0..w {
                let on_box = (40..80).contains(&u) && (30..60).contains(&v);
                let d = if (u * 7 + v * 13) % 29 == 0 {
                    0.0
                } else if on_box {
                    0.4 + noise()
                } else {
                    0.5 + noise()
                };
                data.push(d);
            }
        }
        DepthImage::from_vec(w, h, data).unwrap()
    }

    fn bits(layers: &MapLayers) -> Vec<u32> {
        [
            &layers.elevation,
            &layers.variance,
            &layers.vitality,
            &layers.updates,
        ]
        .iter()
        .flat_map(|g| g.as_slice().iter().map(|v| v.to_bits()))
        .collect()
    }

    /// Both mappers, every filter on, over three frames: the same layers bit for bit and
    /// the same counts whichever copy of the loops runs. On a CPU without AVX2 both runs
    /// take the portable copy and the test says so.
    #[test]
    fn the_avx2_and_portable_loops_give_the_same_maps() {
        let depth = scene();
        let cam = PinholeCamera::new(110.0, 109.0, 66.2, 48.3, 133, 97).unwrap();
        let rot = Rotation3::from_basis_unchecked(&[Vector3::x(), -Vector3::y(), -Vector3::z()]);
        let run = |portable: bool| {
            force_portable(portable);
            let set = instruction_set();
            let mut mappers: Vec<Box<dyn ElevationMapper>> = vec![
                Box::new(StackMapper::new(StackConfig::default()).unwrap()),
                Box::new(FankhauserMapper::new(FankhauserConfig::default()).unwrap()),
            ];
            let mut out = Vec::new();
            for m in &mut mappers {
                let mut stats = Vec::new();
                for k in 0..3 {
                    let pose = Isometry3::from_parts(
                        Translation3::new(0.013 * f64::from(k), 0.004 * f64::from(k), 0.5),
                        UnitQuaternion::from_rotation_matrix(&rot),
                    );
                    let frame = SensorFrame::depth(&depth, &cam, pose, f64::from(k)).unwrap();
                    let s = m.integrate(&frame);
                    stats.push((s.points_used, s.rejected, s.cells_cleared));
                }
                out.push((bits(&m.export()), stats));
            }
            force_portable(false);
            (set, out)
        };
        let (set_p, portable) = run(true);
        let (set_f, fastest) = run(false);
        assert_eq!(set_p, "portable");
        eprintln!("compared the {set_p} loops with the {set_f} loops");
        assert!(portable[0].1[2].0 > 5000, "stack used {:?}", portable[0].1);
        assert!(
            portable == fastest,
            "the maps differ between {set_p} and {set_f}"
        );
    }
}
