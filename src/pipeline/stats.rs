//! Small statistics for reports.

/// Median and 95th percentile of a series (NaNs ignored); `(NaN, NaN)` when empty.
pub fn median_p95(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let mut v: Vec<f64> = values.filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    v.sort_by(f64::total_cmp);
    let at = |q: f64| {
        v.get(((v.len() - 1) as f64 * q).round() as usize)
            .copied()
            .unwrap_or(f64::NAN)
    };
    let n = v.len();
    let median = if n % 2 == 1 {
        at(0.5)
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    };
    (median, at(0.95))
}

/// The ATE every SLAM report states: evo's preset (`evo_ape tum GT EST -a`), SE(3)
/// alignment.
pub fn slam_ate_options() -> stride_eval::AteOptions {
    stride_eval::AteOptions {
        align: stride_eval::Align::Se3,
        ..stride_eval::AteOptions::for_preset(stride_eval::Preset::Evo)
    }
}
