//! Keypoints spread evenly over the image (FAST with grid bucketing) and ORB descriptors.

use crate::config::VoConfig;
use crate::error::FrontendError;
use opencv::core::{KeyPoint, Mat, Point2f, Ptr, Vector};
use opencv::features2d::{
    FastFeatureDetector, FastFeatureDetector_DetectorType, Feature2DTrait, ORB_ScoreType, ORB,
};
use opencv::prelude::*;
use stride_core::image::GrayImage;

/// An owned OpenCV copy of a grey image (8-bit, one channel).
pub fn gray_mat(gray: &GrayImage) -> Result<Mat, FrontendError> {
    Ok(
        Mat::new_rows_cols_with_data(gray.height() as i32, gray.width() as i32, gray.as_slice())?
            .try_clone()?,
    )
}

/// A 256-bit ORB descriptor.
pub type OrbDescriptor = [u8; 32];

/// FAST detection with grid bucketing, and ORB description.
pub struct Detector {
    fast: Ptr<FastFeatureDetector>,
    orb: Ptr<ORB>,
}

/// A detected corner: position (px) and FAST response.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Corner {
    /// Pixel position (column, row).
    pub px: Point2f,
    /// FAST response (larger is stronger).
    pub response: f32,
}

impl Detector {
    /// A detector with the configured FAST threshold.
    pub fn new(config: &VoConfig) -> Result<Self, FrontendError> {
        let fast = FastFeatureDetector::create(
            config.fast_threshold,
            true,
            FastFeatureDetector_DetectorType::TYPE_9_16,
        )?;
        let orb = ORB::create(
            config.target_features as i32,
            1.2,
            1,
            31,
            0,
            2,
            ORB_ScoreType::HARRIS_SCORE,
            31,
            config.fast_threshold,
        )?;
        Ok(Self { fast, orb })
    }

    fn fast(&mut self, gray: &Mat, threshold: i32) -> Result<Vec<Corner>, FrontendError> {
        self.fast.set_threshold(threshold)?;
        let mut kps = Vector::<KeyPoint>::new();
        self.fast
            .detect(gray, &mut kps, &opencv::core::no_array())?;
        Ok(kps
            .iter()
            .map(|k| Corner {
                px: k.pt(),
                response: k.response(),
            })
            .collect())
    }

    /// New corners to add to `existing` tracked points so that every grid cell holds about
    /// `target_features / cells` points, strongest first, none closer than
    /// `min_feature_distance_px` to another. Cells short of corners are searched again with a
    /// lower FAST threshold. Deterministic (ties broken by position).
    pub fn detect(
        &mut self,
        gray: &Mat,
        existing: &[Point2f],
        config: &VoConfig,
    ) -> Result<Vec<Corner>, FrontendError> {
        let (w, h) = (gray.cols().max(1) as f32, gray.rows().max(1) as f32);
        let (gc, gr) = (config.grid_cols.max(1), config.grid_rows.max(1));
        let per_cell = config.target_features.div_ceil(gc * gr);
        let cell_of = |p: &Point2f| {
            let c = ((p.x / w * gc as f32) as usize).min(gc - 1);
            let r = ((p.y / h * gr as f32) as usize).min(gr - 1);
            r * gc + c
        };
        let mut counts = vec![0usize; gc * gr];
        for p in existing {
            if let Some(c) = counts.get_mut(cell_of(p)) {
                *c += 1;
            }
        }
        // Occupancy grid at the minimum distance for spacing.
        let spacing = config.min_feature_distance_px.max(1.0);
        let (ow, oh) = (
            (w / spacing).ceil() as usize + 1,
            (h / spacing).ceil() as usize + 1,
        );
        let mut occupied = vec![false; ow * oh];
        let occ_index = |p: &Point2f| {
            ((p.y / spacing) as usize).min(oh - 1) * ow + ((p.x / spacing) as usize).min(ow - 1)
        };
        let near_occupied = |occ: &[bool], p: &Point2f| {
            let (cx, cy) = ((p.x / spacing) as i64, (p.y / spacing) as i64);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (x, y) = (cx + dx, cy + dy);
                    if x >= 0
                        && y >= 0
                        && (x as usize) < ow
                        && (y as usize) < oh
                        && occ[y as usize * ow + x as usize]
                    {
                        return true;
                    }
                }
            }
            false
        };
        for p in existing {
            if let Some(o) = occupied.get_mut(occ_index(p)) {
                *o = true;
            }
        }
        let mut out = Vec::new();
        let mut threshold = config.fast_threshold;
        loop {
            let mut corners = self.fast(gray, threshold)?;
            corners.sort_by(|a, b| {
                b.response
                    .total_cmp(&a.response)
                    .then(a.px.y.total_cmp(&b.px.y))
                    .then(a.px.x.total_cmp(&b.px.x))
            });
            for c in corners {
                let cell = cell_of(&c.px);
                if counts.get(cell).is_none_or(|&n| n >= per_cell)
                    || near_occupied(&occupied, &c.px)
                {
                    continue;
                }
                counts[cell] += 1;
                occupied[occ_index(&c.px)] = true;
                out.push(c);
            }
            let short = counts.iter().filter(|&&n| n < per_cell / 2).count();
            if short == 0 || threshold <= config.min_fast_threshold {
                break;
            }
            threshold = (threshold / 2).max(config.min_fast_threshold);
        }
        Ok(out)
    }

    /// ORB descriptors of keypoints (oriented by their intensity centroid). Returns one
    /// descriptor per input point, `None` for points too close to the border to describe.
    pub fn describe(
        &mut self,
        gray: &Mat,
        gray_img: &GrayImage,
        points: &[Point2f],
    ) -> Result<Vec<Option<OrbDescriptor>>, FrontendError> {
        let mut kps = Vector::<KeyPoint>::new();
        for (i, p) in points.iter().enumerate() {
            let angle = ic_angle_deg(gray_img, p.x, p.y, 15);
            kps.push(KeyPoint::new_point(*p, 31.0, angle, 0.0, 0, i as i32)?);
        }
        let mut desc = Mat::default();
        self.orb.compute(gray, &mut kps, &mut desc)?;
        let mut out = vec![None; points.len()];
        for (row, k) in kps.iter().enumerate() {
            let Ok(bytes) = desc.at_row::<u8>(row as i32) else {
                continue;
            };
            if let (Some(slot), Ok(d)) = (
                out.get_mut(k.class_id() as usize),
                <OrbDescriptor>::try_from(bytes),
            ) {
                *slot = Some(d);
            }
        }
        Ok(out)
    }
}

/// Orientation (degrees, OpenCV's convention) of the intensity centroid in a disc of
/// `radius` around `(x, y)`, as ORB uses; 0 when the disc leaves the image.
pub fn ic_angle_deg(img: &GrayImage, x: f32, y: f32, radius: i32) -> f32 {
    let (cx, cy) = (x.round() as i32, y.round() as i32);
    let (w, h) = (img.width() as i32, img.height() as i32);
    if cx - radius < 0 || cy - radius < 0 || cx + radius >= w || cy + radius >= h {
        return 0.0;
    }
    let (mut m01, mut m10) = (0i64, 0i64);
    let r2 = radius * radius;
    let data = img.as_slice();
    for dy in -radius..=radius {
        let row = ((cy + dy) * w) as usize;
        for dx in -radius..=radius {
            if dx * dx + dy * dy > r2 {
                continue;
            }
            let v = i64::from(data.get(row + (cx + dx) as usize).copied().unwrap_or(0));
            m10 += i64::from(dx) * v;
            m01 += i64::from(dy) * v;
        }
    }
    let a = (m01 as f32).atan2(m10 as f32).to_degrees();
    if a < 0.0 {
        a + 360.0
    } else {
        a
    }
}

/// Hamming distance between two ORB descriptors.
pub fn hamming(a: &OrbDescriptor, b: &OrbDescriptor) -> u32 {
    // Four 64-bit words: four popcounts instead of 32.
    a.chunks_exact(8)
        .zip(b.chunks_exact(8))
        .map(|(x, y)| {
            let word = |c: &[u8]| u64::from_le_bytes(c.try_into().unwrap_or([0; 8]));
            (word(x) ^ word(y)).count_ones()
        })
        .sum()
}

/// Unguided matches `(query, reference)` between two sets of descriptors: each query's
/// nearest reference by Hamming distance, kept when within `max_hamming`, below `ratio`
/// times the second nearest (Lowe's test), and the only query claiming that reference (the
/// closer wins, the first on a tie). In reference order.
pub fn match_descriptors(
    query: &[OrbDescriptor],
    reference: &[OrbDescriptor],
    max_hamming: u32,
    ratio: f64,
) -> Vec<(usize, usize)> {
    let mut claimed: Vec<Option<(usize, u32)>> = vec![None; reference.len()];
    for (qi, q) in query.iter().enumerate() {
        let (mut best, mut second) = ((u32::MAX, usize::MAX), u32::MAX);
        for (ri, r) in reference.iter().enumerate() {
            let d = hamming(q, r);
            if d < best.0 {
                second = best.0;
                best = (d, ri);
            } else if d < second {
                second = d;
            }
        }
        let (d, ri) = best;
        if d > max_hamming || f64::from(d) >= ratio * f64::from(second) {
            continue;
        }
        if let Some(slot) = claimed.get_mut(ri) {
            if slot.is_none_or(|(_, od)| d < od) {
                *slot = Some((qi, d));
            }
        }
    }
    claimed
        .iter()
        .enumerate()
        .filter_map(|(ri, c)| c.map(|(qi, _)| (qi, ri)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use stride_core::rng::SplitMix64;

    #[test]
    fn hamming_counts_every_differing_bit() {
        let mut rng = SplitMix64::new(3);
        let mut random = || {
            let mut d = [0u8; 32];
            for b in &mut d {
                *b = (rng.next_u64() & 0xFF) as u8;
            }
            d
        };
        for _ in 0..100 {
            let (a, b) = (random(), random());
            let bytewise: u32 = a.iter().zip(&b).map(|(x, y)| (x ^ y).count_ones()).sum();
            assert_eq!(hamming(&a, &b), bytewise);
        }
        assert_eq!(hamming(&[0; 32], &[0xFF; 32]), 256);
    }
}
