//! Pyramidal Lucas-Kanade tracking with a forward-backward check.

use crate::config::VoConfig;
use crate::error::FrontendError;
use opencv::core::{
    Mat, Point2f, Size, TermCriteria, TermCriteria_Type, Vector, BORDER_CONSTANT,
    BORDER_REFLECT_101,
};
use opencv::prelude::*;
use opencv::video::{
    build_optical_flow_pyramid, calc_optical_flow_pyr_lk, OPTFLOW_USE_INITIAL_FLOW,
};
use stride_core::image::GrayImage;

/// Pyramid levels above full resolution used by the backward check.
const BACK_LEVELS: i32 = 1;
/// Pyramid levels above full resolution used by the re-alignment.
const REALIGN_LEVELS: i32 = 0;

/// An image pyramid with derivatives, built once per frame and used for tracking both ways.
pub struct Pyramid {
    levels: Vector<Mat>,
    /// The full-resolution grey image (owned, so the pyramid may reference it).
    pub gray: Mat,
}

impl Pyramid {
    /// Builds the pyramid of a grey image.
    pub fn new(gray: &GrayImage, config: &VoConfig) -> Result<Self, FrontendError> {
        let rows = gray.height() as i32;
        let mat = Mat::new_rows_cols_with_data(rows, gray.width() as i32, gray.as_slice())?
            .try_clone()?;
        let mut levels = Vector::<Mat>::new();
        build_optical_flow_pyramid(
            &mat,
            &mut levels,
            Size::new(config.klt_window, config.klt_window),
            config.klt_levels,
            true,
            BORDER_REFLECT_101,
            BORDER_CONSTANT,
            true,
        )?;
        Ok(Self { levels, gray: mat })
    }
}

fn lk(
    prev: &Pyramid,
    next: &Pyramid,
    from: &Vector<Point2f>,
    guess: &mut Vector<Point2f>,
    config: &VoConfig,
) -> Result<Vector<u8>, FrontendError> {
    lk_levels(prev, next, from, guess, config, config.klt_levels)
}

fn lk_levels(
    prev: &Pyramid,
    next: &Pyramid,
    from: &Vector<Point2f>,
    guess: &mut Vector<Point2f>,
    config: &VoConfig,
    levels: i32,
) -> Result<Vector<u8>, FrontendError> {
    let mut status = Vector::<u8>::new();
    let mut err = Vector::<f32>::new();
    let criteria = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        config.klt_iterations,
        0.01,
    )?;
    calc_optical_flow_pyr_lk(
        &prev.levels,
        &next.levels,
        from,
        guess,
        &mut status,
        &mut err,
        Size::new(config.klt_window, config.klt_window),
        levels,
        criteria,
        OPTFLOW_USE_INITIAL_FLOW,
        1e-4,
    )?;
    Ok(status)
}

/// A point tracked forward and back.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tracked {
    /// Its position in the next image (px).
    pub px: Point2f,
    /// Distance between its start and where tracking it back from `px` ends (px).
    pub fb_error_px: f32,
}

/// Tracks `points` from `prev` to `next`, starting from `guesses` (predicted positions), then
/// back from the result to `prev`. Returns, for each point that both trackings found and that
/// stays inside the image, its new position and forward-backward error; the caller decides
/// how much error to accept.
pub fn track(
    prev: &Pyramid,
    next: &Pyramid,
    points: &[Point2f],
    guesses: &[Point2f],
    config: &VoConfig,
) -> Result<Vec<Option<Tracked>>, FrontendError> {
    if points.is_empty() {
        return Ok(Vec::new());
    }
    let from: Vector<Point2f> = points.iter().copied().collect();
    let mut fwd: Vector<Point2f> = guesses.iter().copied().collect();
    let st_f = lk(prev, next, &from, &mut fwd, config)?;
    // Back from the forward result, seeded at the start point: a correct track comes back
    // with almost no displacement, so the two finest levels suffice.
    let mut back: Vector<Point2f> = from.clone();
    let st_b = lk_levels(
        next,
        prev,
        &fwd,
        &mut back,
        config,
        config.klt_levels.min(BACK_LEVELS),
    )?;
    let (w, h) = (next.gray.cols() as f32, next.gray.rows() as f32);
    Ok((0..points.len())
        .map(|i| {
            let ok = st_f.get(i).ok()? == 1 && st_b.get(i).ok()? == 1;
            let p = fwd.get(i).ok()?;
            let b = back.get(i).ok()?;
            let o = points.get(i)?;
            let fb = ((b.x - o.x).powi(2) + (b.y - o.y).powi(2)).sqrt();
            let inside = p.x >= 0.0 && p.y >= 0.0 && p.x <= w - 1.0 && p.y <= h - 1.0;
            (ok && inside && fb.is_finite()).then_some(Tracked {
                px: p,
                fb_error_px: fb,
            })
        })
        .collect())
}

/// Re-aligns tracked points with their appearance in the keyframe where they were first
/// detected: Lucas-Kanade from `keyframe` (at `origins`) to `current`, seeded by the
/// frame-to-frame positions `tracked`, at full resolution only (the seed is within a
/// few pixels). Frame-to-frame
/// tracking drifts like a random walk on real images; this removes the drift. A point whose
/// re-aligned position moves by more than `max_correction_px` (its appearance changed, or it
/// slid along an edge) is reported as `None`.
pub fn realign(
    keyframe: &Pyramid,
    current: &Pyramid,
    origins: &[Point2f],
    tracked: &[Point2f],
    max_correction_px: f32,
    config: &VoConfig,
) -> Result<Vec<Option<Point2f>>, FrontendError> {
    if origins.is_empty() {
        return Ok(Vec::new());
    }
    let from: Vector<Point2f> = origins.iter().copied().collect();
    let mut refined: Vector<Point2f> = tracked.iter().copied().collect();
    let status = lk_levels(
        keyframe,
        current,
        &from,
        &mut refined,
        config,
        config.klt_levels.min(REALIGN_LEVELS),
    )?;
    let max2 = max_correction_px * max_correction_px;
    Ok((0..origins.len())
        .map(|i| {
            let p = refined.get(i).ok()?;
            let t = tracked.get(i)?;
            let d2 = (p.x - t.x).powi(2) + (p.y - t.y).powi(2);
            (status.get(i).ok()? == 1 && d2 <= max2).then_some(p)
        })
        .collect())
}
