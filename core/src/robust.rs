//! Robust kernels shared by the estimators (bundle adjustment, depth alignment).

/// Robust weight of a residual with squared (Mahalanobis) norm `chi2` under Huber's kernel
/// of threshold `delta2` (on `chi2`): 1 inside, `sqrt(delta2 / chi2)` outside. The matching
/// cost is [`huber_cost`].
pub fn huber_weight(chi2: f64, delta2: Option<f64>) -> f64 {
    match delta2 {
        Some(d2) if chi2 > d2 => (d2 / chi2).sqrt(),
        _ => 1.0,
    }
}

/// Huber's cost of a squared Mahalanobis distance: `chi2` inside the threshold,
/// `2 sqrt(delta2 chi2) - delta2` outside (continuous, with a continuous derivative).
pub fn huber_cost(chi2: f64, delta2: Option<f64>) -> f64 {
    match delta2 {
        Some(d2) if chi2 > d2 => 2.0 * (d2 * chi2).sqrt() - d2,
        _ => chi2,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn huber_cost_and_weight_agree() {
        let d2 = Some(5.991);
        for chi2 in [0.5, 5.0, 6.0, 40.0, 400.0] {
            // d cost / d chi2 = weight.
            let h = 1e-6;
            let slope = (huber_cost(chi2 + h, d2) - huber_cost(chi2 - h, d2)) / (2.0 * h);
            assert!((slope - huber_weight(chi2, d2)).abs() < 1e-6, "{chi2}");
        }
        assert_eq!(huber_cost(40.0, None), 40.0);
    }
}
