//! Image sharpness metrics for the gait-dependent motion-blur study (paper 004).
//!
//! Both fall as blur rises: [`laplacian_variance`] (the variance of the 4-neighbour Laplacian,
//! as `cv::Laplacian(img, CV_64F).var()` with aperture 1) and [`gradient_energy`] (the mean
//! squared central-difference gradient). Use them on grey images of the same scene type; their
//! absolute values depend on texture and noise.

use stride_core::image::GrayImage;

/// Variance of the 4-neighbour Laplacian over the interior pixels (grey levels²).
pub fn laplacian_variance(img: &GrayImage) -> f64 {
    let (w, h) = (img.width() as usize, img.height() as usize);
    if w < 3 || h < 3 {
        return 0.0;
    }
    let p = img.as_slice();
    let (mut s, mut s2) = (0.0f64, 0.0f64);
    for y in 1..h - 1 {
        let row = y * w;
        for x in 1..w - 1 {
            let i = row + x;
            let l = i32::from(p[i - 1])
                + i32::from(p[i + 1])
                + i32::from(p[i - w])
                + i32::from(p[i + w])
                - 4 * i32::from(p[i]);
            let l = f64::from(l);
            s += l;
            s2 += l * l;
        }
    }
    let n = ((w - 2) * (h - 2)) as f64;
    let mean = s / n;
    s2 / n - mean * mean
}

/// Mean of `gx² + gy²` with central differences over the interior pixels (grey levels²).
pub fn gradient_energy(img: &GrayImage) -> f64 {
    let (w, h) = (img.width() as usize, img.height() as usize);
    if w < 3 || h < 3 {
        return 0.0;
    }
    let p = img.as_slice();
    let mut s = 0.0f64;
    for y in 1..h - 1 {
        let row = y * w;
        for x in 1..w - 1 {
            let i = row + x;
            let gx = (f64::from(p[i + 1]) - f64::from(p[i - 1])) / 2.0;
            let gy = (f64::from(p[i + w]) - f64::from(p[i - w])) / 2.0;
            s += gx * gx + gy * gy;
        }
    }
    s / ((w - 2) * (h - 2)) as f64
}

/// The frequency (Hz) with the largest amplitude in the discrete Fourier transform of a
/// series sampled at `rate_hz`, among the frequencies of at least `min_hz` (Hz; the mean,
/// bin 0, never counts). `None` for fewer than 4 samples or when no frequency up to half the
/// rate reaches `min_hz`.
pub fn dominant_frequency_hz(series: &[f64], rate_hz: f64, min_hz: f64) -> Option<f64> {
    let n = series.len();
    if n < 4 {
        return None;
    }
    let mean = series.iter().sum::<f64>() / n as f64;
    // The lowest bin at or above `min_hz` (bin k is k rate / n Hz).
    let first = (min_hz * n as f64 / rate_hz).ceil().max(1.0) as usize;
    if first > n / 2 {
        return None;
    }
    let mut best = (0.0f64, first);
    for k in first..=n / 2 {
        let (mut re, mut im) = (0.0, 0.0);
        for (i, v) in series.iter().enumerate() {
            let a = std::f64::consts::TAU * (k * i) as f64 / n as f64;
            re += (v - mean) * a.cos();
            im -= (v - mean) * a.sin();
        }
        let p = re * re + im * im;
        if p > best.0 {
            best = (p, k);
        }
    }
    Some(best.1 as f64 * rate_hz / n as f64)
}

/// Pearson correlation of two equally long series; `None` if either is constant or shorter
/// than 2.
pub fn correlation(a: &[f64], b: &[f64]) -> Option<f64> {
    let n = a.len().min(b.len());
    if n < 2 {
        return None;
    }
    let (ma, mb) = (
        a[..n].iter().sum::<f64>() / n as f64,
        b[..n].iter().sum::<f64>() / n as f64,
    );
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a[..n].iter().zip(&b[..n]) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    (saa > 0.0 && sbb > 0.0).then(|| sab / (saa * sbb).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;
    use stride_core::image::Image;

    fn checker(w: u32, h: u32, blur: usize) -> GrayImage {
        let sharp: Vec<f64> = (0..w * h)
            .map(|i| {
                if ((i % w) / 4 + (i / w) / 4) % 2 == 0 {
                    40.0
                } else {
                    200.0
                }
            })
            .collect();
        // Horizontal box blur of `blur` pixels.
        let mut out = vec![0u8; (w * h) as usize];
        for y in 0..h as usize {
            for x in 0..w as usize {
                let mut s = 0.0;
                for k in 0..blur.max(1) {
                    s += sharp[y * w as usize + (x + k).min(w as usize - 1)];
                }
                out[y * w as usize + x] = (s / blur.max(1) as f64).round() as u8;
            }
        }
        Image::from_vec(w, h, out).unwrap()
    }

    #[test]
    fn sharpness_falls_with_blur() {
        let a = checker(64, 64, 1);
        let b = checker(64, 64, 5);
        assert!(laplacian_variance(&a) > 2.0 * laplacian_variance(&b));
        assert!(gradient_energy(&a) > 1.5 * gradient_energy(&b));
        assert_eq!(laplacian_variance(&Image::filled(10, 10, 7u8)), 0.0);
    }

    #[test]
    fn finds_the_dominant_frequency_and_correlation() {
        let s: Vec<f64> = (0..120)
            .map(|i| (std::f64::consts::TAU * 2.5 * i as f64 / 30.0).sin())
            .collect();
        assert!((dominant_frequency_hz(&s, 30.0, 0.0).unwrap() - 2.5).abs() < 0.26);
        // A slow swing four times stronger (turns along a path) wins without a floor; above
        // 0.5 Hz the step frequency is found again.
        let walk: Vec<f64> = (0..300)
            .map(|i| {
                let t = i as f64 / 10.0;
                4.0 * (std::f64::consts::TAU * 0.13 * t).sin()
                    + (std::f64::consts::TAU * 1.9 * t).sin()
            })
            .collect();
        let slow = dominant_frequency_hz(&walk, 10.0, 0.0).unwrap();
        assert!((slow - 0.13).abs() < 0.04, "{slow}");
        let step = dominant_frequency_hz(&walk, 10.0, 0.5).unwrap();
        assert!((step - 1.9).abs() < 0.04, "{step}");
        assert_eq!(dominant_frequency_hz(&walk, 10.0, 6.0), None);
        let neg: Vec<f64> = s.iter().map(|v| -2.0 * v + 1.0).collect();
        assert!((correlation(&s, &neg).unwrap() + 1.0).abs() < 1e-12);
    }
}
