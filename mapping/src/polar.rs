//! The polar frame of paper 000's visibility check (section 3.2): azimuth bins around the
//! sensor and radial steps, with a cheap monotonic stand-in for the azimuth.

/// A monotonic stand-in for the azimuth of `(x, y)` in `[0, 4)` (the "diamond angle",
/// counter-clockwise from +x), cheaper than `atan2`. Near +x and -x it changes like the angle
/// itself; at 45 degrees half as fast.
pub(crate) fn diamond_angle(x: f64, y: f64) -> f64 {
    let s = x.abs() + y.abs();
    if s == 0.0 {
        return 0.0;
    }
    let p = y / s; // in [-1, 1]
    if x >= 0.0 {
        if y >= 0.0 {
            p
        } else {
            4.0 + p
        }
    } else {
        2.0 - p
    }
}

/// The polar frame of the visibility check: azimuth bins around the sensor (the seam behind
/// it) and radial steps of one cell.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Polar {
    pub(crate) sx: f64,
    pub(crate) sy: f64,
    /// Unit horizontal heading of the sensor.
    pub(crate) hx: f64,
    pub(crate) hy: f64,
    pub(crate) bins_per_unit: f64,
    /// 1 / radial step (1/m); the step is two cells.
    pub(crate) inv_step: f64,
}

impl Polar {
    /// (azimuth bin, radial step index, horizontal distance in m) of map point `(x, y)`.
    #[inline]
    pub(crate) fn of(&self, x: f64, y: f64) -> (i64, usize, f64) {
        let (dx, dy) = (x - self.sx, y - self.sy);
        let f = dx * self.hx + dy * self.hy;
        let l = dy * self.hx - dx * self.hy;
        // Heading at 2.0, the seam straight behind the sensor.
        let q = diamond_angle(-f, -l);
        let d = (dx * dx + dy * dy).sqrt();
        (
            (q * self.bins_per_unit) as i64,
            (d * self.inv_step) as usize,
            d,
        )
    }
}
