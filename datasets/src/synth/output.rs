//! Writing a rendered sequence as a TUM-layout folder, atomically.

use super::motion::{Gait, PathKind};
use super::{FrameInfo, Synth, SynthConfig, SynthError, TerrainSource};
use crate::error::DatasetError;
use crate::grid_file::{relief_png, write_header, write_layer};
use crate::png_io::{encode_depth_u16, encode_rgb};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;
use stride_core::image::{Image, RgbImage};
use stride_core::trajectory::Trajectory;
use stride_output::fs::write_atomic;

/// What [`generate`] produced.
#[derive(Debug, Clone)]
pub struct SynthSummary {
    /// The output folder.
    pub out_dir: PathBuf,
    /// Per-frame facts.
    pub frames: Vec<FrameInfo>,
    /// Rendering time per frame (s), PNG encoding and writing excluded.
    pub render_s: Vec<f64>,
    /// Wall time of the whole generation (s).
    pub total_s: f64,
    /// Gait cycle frequency (Hz).
    pub cycle_hz: f64,
    /// Touchdown frequency (Hz).
    pub step_hz: f64,
    /// Ground-truth trajectory (`world_from_camera`).
    pub groundtruth: Trajectory,
}

fn gait_name(g: Gait) -> &'static str {
    match g {
        Gait::Tripod => "tripod",
        Gait::Crawl => "crawl",
    }
}

fn path_name(p: PathKind) -> &'static str {
    match p {
        PathKind::Straight => "straight",
        PathKind::Square => "square",
        PathKind::Turn => "turn",
    }
}

fn write(path: &Path, bytes: &[u8]) -> Result<(), DatasetError> {
    write_atomic(path, bytes).map_err(|e| DatasetError::io(path, e))
}

/// Renders the sequence and writes it into `out` (see the module documentation). The folder
/// is assembled under a temporary name beside `out` and renamed at the end, so `out` is
/// either complete or absent. An existing non-empty `out` is an error unless `overwrite`.
/// `progress(done, total)` is called after each frame.
pub fn generate(
    config: &SynthConfig,
    out: &Path,
    overwrite: bool,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SynthSummary, SynthError> {
    let start = Instant::now();
    config.validate()?;
    if out.exists()
        && !overwrite
        && std::fs::read_dir(out)
            .map(|mut d| d.next().is_some())
            .unwrap_or(true)
    {
        return Err(SynthError::NotEmpty(out.to_path_buf()));
    }
    let synth = Synth::new(config.clone())?;
    let tmp = stride_output::fs::temp_path_for(out);
    let _ = std::fs::remove_dir_all(&tmp);
    for sub in ["rgb", "depth"] {
        std::fs::create_dir_all(tmp.join(sub)).map_err(|e| DatasetError::io(tmp.join(sub), e))?;
    }
    let result = generate_into(&synth, &tmp, progress);
    let mut summary = match result {
        Ok(s) => s,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(e);
        }
    };
    if out.exists() {
        std::fs::remove_dir_all(out).map_err(|e| DatasetError::io(out, e))?;
    }
    std::fs::rename(&tmp, out).map_err(|e| DatasetError::io(out, e))?;
    summary.out_dir = out.to_path_buf();
    summary.total_s = start.elapsed().as_secs_f64();
    Ok(summary)
}

fn generate_into(
    synth: &Synth,
    dir: &Path,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SynthSummary, SynthError> {
    let cfg = synth.config();
    let renderer = synth.renderer();
    let total = cfg.frames;
    let (tx, rx) = std::sync::mpsc::sync_channel::<(String, RgbImage, Image<u16>)>(2);
    let writer_dir = dir.to_path_buf();
    // PNG encoding and writing run beside rendering.
    let writer = std::thread::spawn(move || -> Result<(), DatasetError> {
        for (stamp, rgb, depth) in rx {
            let rgb_path = writer_dir.join("rgb").join(format!("{stamp}.png"));
            let depth_path = writer_dir.join("depth").join(format!("{stamp}.png"));
            let rgb_png = encode_rgb(&rgb).map_err(|m| DatasetError::Image {
                path: rgb_path.clone(),
                message: m,
            })?;
            let depth_png = encode_depth_u16(&depth).map_err(|m| DatasetError::Image {
                path: depth_path.clone(),
                message: m,
            })?;
            std::fs::write(&rgb_path, rgb_png).map_err(|e| DatasetError::io(&rgb_path, e))?;
            std::fs::write(&depth_path, depth_png).map_err(|e| DatasetError::io(&depth_path, e))?;
        }
        Ok(())
    });
    let mut infos = Vec::with_capacity(total);
    let mut render_s = Vec::with_capacity(total);
    let mut send_failed = false;
    for i in 0..total {
        let f = synth.render_frame(&renderer, i);
        let stamp = format!("{:.6}", f.info.t_s);
        infos.push(f.info);
        render_s.push(f.render_s);
        if tx.send((stamp, f.rgb, f.depth_raw)).is_err() {
            send_failed = true;
            break;
        }
        progress(i + 1, total);
    }
    drop(tx);
    match writer.join() {
        Ok(r) => r?,
        Err(_) => return Err(SynthError::Invalid("the PNG writer thread panicked".into())),
    }
    if send_failed {
        return Err(SynthError::Invalid("the PNG writer stopped early".into()));
    }

    let mut rgb_txt = String::from("# color images\n# timestamp filename\n");
    let mut depth_txt = String::from("# depth maps\n# timestamp filename\n");
    let mut csv = String::from(
        "index,t,gait_phase,stance_legs,speed_m_s,angular_speed_rad_s,image_motion_px,subframes\n",
    );
    let mut gt = Trajectory::new();
    for f in &infos {
        let stamp = format!("{:.6}", f.t_s);
        let _ = writeln!(rgb_txt, "{stamp} rgb/{stamp}.png");
        let _ = writeln!(depth_txt, "{stamp} depth/{stamp}.png");
        let _ = writeln!(
            csv,
            "{},{stamp},{:.4},{},{:.5},{:.5},{:.3},{}",
            f.index,
            f.gait_phase,
            f.stance_legs,
            f.speed_m_s,
            f.angular_speed_rad_s,
            f.image_motion_px,
            f.subframes
        );
        let t: f64 = stamp.parse().unwrap_or(f.t_s);
        gt.push(t, f.world_from_camera)
            .map_err(|e| SynthError::Invalid(e.to_string()))?;
    }
    write(&dir.join("rgb.txt"), rgb_txt.as_bytes())?;
    write(&dir.join("depth.txt"), depth_txt.as_bytes())?;
    write(&dir.join("frames.csv"), csv.as_bytes())?;
    crate::trajectory_file::write_tum_trajectory(&dir.join("groundtruth.txt"), &gt)?;
    crate::accelerometer::write_accelerometer(
        &dir.join("accelerometer.txt"),
        &synth.accelerometer(),
    )?;
    crate::accelerometer::write_gyroscope(&dir.join("gyroscope.txt"), &synth.gyroscope())?;
    write(
        &dir.join("camera.json"),
        synth.camera_config().to_json().as_bytes(),
    )?;
    let elevation = synth.ground_truth_elevation();
    write_layer(&dir.join("terrain.npy"), &elevation)?;
    write_header(&dir.join("terrain.json"), &elevation.geometry)?;
    let preview = relief_png(&elevation, 1000).map_err(|m| DatasetError::Image {
        path: dir.join("terrain.png"),
        message: m,
    })?;
    write(&dir.join("terrain.png"), &preview)?;

    let terrain_desc = match &cfg.terrain {
        TerrainSource::Image {
            path,
            height_scale_m,
            resolution_m,
        } => {
            serde_json::json!({"image": path.display().to_string(), "height_scale_m": height_scale_m, "resolution_m": resolution_m})
        }
        TerrainSource::Procedural { name, resolution_m } => {
            serde_json::json!({"procedural": name, "resolution_m": resolution_m})
        }
    };
    let meta = serde_json::json!({
        "generator": "stride synth",
        "terrain": terrain_desc,
        "gait": gait_name(cfg.motion.gait),
        "path": path_name(cfg.motion.path),
        "speed_m_s": cfg.motion.speed_m_s,
        "square_side_m": cfg.motion.square_side_m,
        "camera_height_m": cfg.motion.camera_height_m,
        "camera_tilt_deg": cfg.motion.camera_tilt_deg,
        "shake": cfg.motion.shake,
        "frames": cfg.frames,
        "fps": cfg.fps,
        "seed": cfg.seed,
        "blur": cfg.blur,
        "exposure_s": cfg.exposure_s,
        "objects": cfg.objects,
        "depth_noise": cfg.depth_noise,
        "read_noise_dn": cfg.read_noise_dn,
        "rolling_shutter_s": cfg.camera.rolling_shutter_s,
        "exposure_flicker": cfg.exposure_flicker,
        "gait_cycle_hz": synth.motion().cycle_hz(),
        "gait_step_hz": synth.motion().step_hz(),
        "world_frame": "z up; origin at the robot's start, x along its initial heading",
    });
    write(
        &dir.join("synth.json"),
        serde_json::to_string_pretty(&meta)
            .unwrap_or_default()
            .as_bytes(),
    )?;
    Ok(SynthSummary {
        out_dir: dir.to_path_buf(),
        frames: infos,
        render_s,
        total_s: 0.0,
        cycle_hz: synth.motion().cycle_hz(),
        step_hz: synth.motion().step_hz(),
        groundtruth: gt,
    })
}
