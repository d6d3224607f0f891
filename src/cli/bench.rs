//! `stride bench ...`: speed measurements reported as medians of repeated runs, with the
//! ratio to a peer measured in the same session (these machines are noisy).

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;
use stride_core::trajectory::Trajectory;
use stride_datasets::trajectory_file::{read_tum_trajectory, write_tum_trajectory};
use stride_eval::{ate, rpe, Align, AteOptions, Preset, RpeOptions};

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// ATE + RPE on a large synthetic trajectory pair, against evo on the same files.
    Eval(EvalBenchArgs),
    /// Rendering speed of the synthetic generator at 640x480, without and with motion blur.
    Synth(SynthBenchArgs),
    /// Visual odometry speed and accuracy on a sequence decoded up front (PNG decoding timed
    /// separately), median of several runs.
    Vo(VoBenchArgs),
    /// Elevation-map update time for full depth frames, ours and the Fankhauser baseline,
    /// frames decoded up front.
    Map(MapBenchArgs),
}

#[derive(Debug, Args)]
pub struct MapBenchArgs {
    /// Sequence folder with ground-truth poses (TUM layout) [default: a synthetic sequence
    /// rendered into a temporary folder].
    #[arg(long)]
    dataset: Option<PathBuf>,
    /// Frames mapped (the median update time is reported).
    #[arg(long, default_value_t = 60)]
    frames: usize,
    /// Which mappers to time.
    #[arg(long, value_enum, default_value = "both")]
    mapper: crate::cli::map::MapperArg,
    /// Time the stack mapper without its depth-edge filter.
    #[arg(long)]
    no_edge_filter: bool,
    /// Time the stack mapper without the visibility check.
    #[arg(long)]
    no_visibility: bool,
    /// Time the stack mapper without the see-through check.
    #[arg(long)]
    no_see_through: bool,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

#[derive(Debug, Args)]
pub struct VoBenchArgs {
    /// Sequence folder (TUM layout).
    #[arg(long)]
    dataset: PathBuf,
    /// Camera preset or file [default: from the folder].
    #[arg(long)]
    camera: Option<String>,
    /// Runs (the median is reported).
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// OpenCV threads.
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Python of a throwaway venv with pyorbslam3 and evo: also run ORB-SLAM3 on the same
    /// frames in this session through ../shared/tools/peers/orbslam3_tum.py (never a
    /// project dependency) and report both.
    #[arg(long, value_name = "PYTHON")]
    orbslam3: Option<PathBuf>,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

/// Runs the ORB-SLAM3 peer harness and returns its summary JSON (last stdout line).
fn orbslam3_summary(
    python: &Path,
    dataset: &Path,
    camera: &str,
    runs: usize,
) -> Result<serde_json::Value> {
    let harness = stride_datasets::data_root::shared_data_dir()
        .map(|d| d.join("../tools/peers/orbslam3_tum.py"))
        .filter(|p| p.is_file())
        .context("the ORB-SLAM3 harness ../shared/tools/peers/orbslam3_tum.py was not found")?;
    let out_dir = std::env::temp_dir().join(format!("stride-orbslam3-{}", std::process::id()));
    let out = std::process::Command::new(python)
        .arg(&harness)
        .arg(dataset)
        .args(["--camera", camera, "--repeat", &runs.to_string(), "--out"])
        .arg(&out_dir)
        .output()
        .with_context(|| format!("running {}", python.display()))?;
    let text = String::from_utf8_lossy(&out.stdout);
    let last = text.lines().last().unwrap_or("");
    if !out.status.success() {
        bail!(
            "the ORB-SLAM3 harness failed ({}): {}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
                .lines()
                .last()
                .unwrap_or("")
        );
    }
    serde_json::from_str(last).with_context(|| format!("parsing the harness output: {last}"))
}

#[derive(Debug, Args)]
pub struct SynthBenchArgs {
    /// Frames rendered per configuration (the median is reported).
    #[arg(long, default_value_t = 15)]
    frames: usize,
    /// Walking speed (m/s) of the tripod gait used for the blurred frames.
    #[arg(long, default_value_t = 0.15)]
    speed: f64,
}

#[derive(Debug, Args)]
pub struct EvalBenchArgs {
    /// Poses in each trajectory.
    #[arg(long, default_value_t = 100_000)]
    poses: usize,
    /// Repetitions (the median is reported).
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// Python interpreter of a venv with evo, to time evo on the same files. Default: the
    /// STRIDE_EVO_PYTHON environment variable, if set.
    #[arg(long, value_name = "PYTHON")]
    evo_python: Option<PathBuf>,
    /// Repetitions for evo (it is slow).
    #[arg(long, default_value_t = 3)]
    evo_runs: usize,
    /// Where to write the generated trajectories (default: a temporary folder, removed after).
    #[arg(long, value_name = "DIR")]
    keep: Option<PathBuf>,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
}

pub fn run(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Eval(a) => bench_eval(a),
        BenchCommand::Synth(a) => bench_synth(a),
        BenchCommand::Vo(a) => bench_vo(a),
        BenchCommand::Map(a) => bench_map(a),
    }
}

fn bench_map(a: MapBenchArgs) -> Result<()> {
    use stride_datasets::tum::{AssociationOptions, TumSequence};
    use stride_mapping::fankhauser::{FankhauserConfig, FankhauserMapper};
    use stride_mapping::input::{Cloud, SensorFrame};
    use stride_mapping::stack::{StackConfig, StackMapper};
    use stride_mapping::ElevationMapper;
    let tmp = tempfile::tempdir()?;
    let dir = match &a.dataset {
        Some(d) => d.clone(),
        None => {
            let d = tmp.path().join("seq");
            let cfg = stride_datasets::synth::SynthConfig {
                frames: a.frames,
                blur: false,
                ..Default::default()
            };
            stride_datasets::synth::generate(&cfg, &d, false, &mut |_, _| {})?;
            d
        }
    };
    let seq = TumSequence::open(&dir, None, AssociationOptions::default())?;
    let gt = seq
        .groundtruth
        .clone()
        .context("the sequence has no ground truth poses")?;
    let mut frames = Vec::new();
    for i in 0..seq.len().min(a.frames) {
        let f = seq.load_frame(i)?;
        if let Some(pose) = gt.interpolate(f.t_depth_s) {
            frames.push((f, pose));
        }
    }
    if frames.is_empty() {
        bail!("no frame of {} has a ground-truth pose", dir.display());
    }
    let valid: f64 = frames
        .iter()
        .map(|(f, _)| f.depth_m.as_slice().iter().filter(|&&z| z > 0.0).count() as f64)
        .sum::<f64>()
        / frames.len() as f64;
    use crate::cli::map::MapperArg;
    let mut mappers: Vec<Box<dyn ElevationMapper>> = Vec::new();
    if a.mapper != MapperArg::Fankhauser {
        let d = StackConfig::default();
        mappers.push(Box::new(StackMapper::new(StackConfig {
            edge_filter: d.edge_filter.filter(|_| !a.no_edge_filter),
            visibility_check: !a.no_visibility,
            see_through_check: !a.no_see_through,
            ..d
        })));
    }
    if a.mapper != MapperArg::Stack {
        mappers.push(Box::new(FankhauserMapper::new(FankhauserConfig::default())));
    }
    let mut out = serde_json::Map::new();
    // The mappers take turns frame by frame, so that both see the same machine state (these
    // VMs drift by tens of percent within a minute); the ratio of medians is the figure to
    // trust.
    let mut times: Vec<Vec<f64>> = vec![Vec::new(); mappers.len()];
    let mut phases: Vec<[Vec<f64>; 2]> = vec![[Vec::new(), Vec::new()]; mappers.len()];
    let mut used = vec![0usize; mappers.len()];
    for (f, pose) in &frames {
        let sf = SensorFrame {
            cloud: Cloud::Depth {
                depth_m: &f.depth_m,
                camera: &seq.camera.camera,
            },
            map_from_sensor: *pose,
            time_s: f.t_depth_s,
        };
        for (((m, t), u), ph) in mappers
            .iter_mut()
            .zip(&mut times)
            .zip(&mut used)
            .zip(&mut phases)
        {
            let s = m.integrate(&sf);
            t.push(s.update_s);
            let [p, c] = ph;
            p.push(s.prepare_s);
            c.push(s.checks_s);
            *u += s.points_used;
        }
    }
    for (((m, t), u), [p, c]) in mappers.iter().zip(&times).zip(&used).zip(&phases) {
        let total: f64 = t.iter().sum();
        let (med, p95) = crate::pipeline::median_p95(t.iter().copied());
        let (pm, _) = crate::pipeline::median_p95(p.iter().copied());
        let (cm, _) = crate::pipeline::median_p95(c.iter().copied());
        out.insert(
            m.name().into(),
            json!({"update_ms_median": med * 1e3, "update_ms_p95": p95 * 1e3, "prepare_ms_median": pm * 1e3, "checks_ms_median": cm * 1e3, "points_per_s": *u as f64 / total}),
        );
    }
    if a.json {
        crate::outln!(
            "{}",
            json!({"frames": frames.len(), "pixels_per_frame": frames[0].0.depth_m.as_slice().len(), "valid_depth_per_frame": valid, "threads": rayon::current_num_threads(), "mappers": out})
        )?;
        return Ok(());
    }
    crate::outln!("{} frames of {} ({} pixels, {:.0} with depth on average), 1 cm cells, 4 x 4 m window, {} threads", frames.len(), dir.display(), frames[0].0.depth_m.as_slice().len(), valid, rayon::current_num_threads())?;
    let g = |k: &str, f: &str| {
        out.get(k)
            .and_then(|v| v.get(f))
            .and_then(|v| v.as_f64())
            .unwrap_or(f64::NAN)
    };
    for k in ["stack", "fankhauser"] {
        crate::outln!(
            "{k:<11} update {:>7.2} ms median, {:>7.2} ms p95, {:.2e} points/s",
            g(k, "update_ms_median"),
            g(k, "update_ms_p95"),
            g(k, "points_per_s")
        )?;
    }
    crate::outln!(
        "fankhauser / stack update time: {:.2}",
        g("fankhauser", "update_ms_median") / g("stack", "update_ms_median")
    )?;
    Ok(())
}

fn bench_vo(a: VoBenchArgs) -> Result<()> {
    use stride_datasets::tum::{AssociationOptions, TumSequence};
    use stride_frontend::{VisualOdometry, VoConfig};
    if a.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let seq = TumSequence::open(
        &a.dataset,
        a.camera.as_deref(),
        AssociationOptions::default(),
    )?;
    stride_frontend::set_opencv_threads(a.threads)?;
    let mut frames = Vec::with_capacity(seq.len());
    let mut decode = Vec::with_capacity(seq.len());
    for i in 0..seq.len() {
        let t = Instant::now();
        match seq.load_frame(i) {
            Ok(f) => {
                decode.push(t.elapsed().as_secs_f64());
                frames.push(f);
            }
            Err(e) => tracing::warn!("frame {i} skipped: {e}"),
        }
    }
    let (mut fps, mut ate_rmse, mut frame_ms) = (Vec::new(), Vec::new(), Vec::new());
    let mut first: Option<Trajectory> = None;
    let mut repeatable = true;
    for _ in 0..a.runs {
        let mut vo = VisualOdometry::new(seq.camera.camera, VoConfig::default())?;
        let mut traj = Trajectory::new();
        let t0 = Instant::now();
        for f in &frames {
            let r = vo.process(f)?;
            frame_ms.push(r.timing.total_s * 1e3);
            traj.push(r.t_s, r.world_from_camera)?;
        }
        fps.push(frames.len() as f64 / t0.elapsed().as_secs_f64());
        if let Some(gt) = &seq.groundtruth {
            ate_rmse.push(
                ate(
                    gt,
                    &traj,
                    &AteOptions {
                        align: Align::Se3,
                        ..AteOptions::for_preset(Preset::Evo)
                    },
                )?
                .trans_m
                .rmse,
            );
        }
        match &first {
            None => first = Some(traj),
            Some(f) => repeatable &= *f == traj,
        }
    }
    let fps_range = (
        fps.iter().copied().fold(f64::INFINITY, f64::min),
        fps.iter().copied().fold(0.0, f64::max),
    );
    let ate_range = (
        ate_rmse.iter().copied().fold(f64::INFINITY, f64::min),
        ate_rmse.iter().copied().fold(0.0, f64::max),
    );
    let orb = match &a.orbslam3 {
        Some(py) => {
            let camera = match (&a.camera, &seq.camera_source) {
                (Some(c), _) => c.clone(),
                (None, stride_datasets::tum::CameraSource::FolderName(p)) => (*p).to_owned(),
                _ => bail!("--orbslam3 needs --camera fr1|fr2|fr3 for this folder"),
            };
            Some(orbslam3_summary(py, &a.dataset, &camera, a.runs)?)
        }
        None => None,
    };
    let stat = |v: &Option<serde_json::Value>, k: &str, s: &str| {
        v.as_ref()
            .and_then(|j| j.get(k))
            .and_then(|x| x.get(s))
            .and_then(|x| x.as_f64())
            .unwrap_or(f64::NAN)
    };
    let (fps_med, decode_med, frame_med) = (median(fps), median(decode) * 1e3, median(frame_ms));
    let have_gt = !ate_rmse.is_empty();
    let ate_med = if have_gt { median(ate_rmse) } else { f64::NAN };
    if a.json {
        crate::outln!(
            "{}",
            json!({"frames": frames.len(), "runs": a.runs, "fps_median": fps_med, "fps_min": fps_range.0, "fps_max": fps_range.1, "frame_ms_median": frame_med, "decode_ms_median": decode_med, "ate_rmse_median": ate_med, "repeatable": repeatable, "orbslam3": orb})
        )?;
        return Ok(());
    }
    crate::outln!(
        "{} frames of {}, {} runs, {} OpenCV thread(s)",
        frames.len(),
        a.dataset.display(),
        a.runs,
        a.threads
    )?;
    crate::outln!("VO: {fps_med:.1} frames/s median (range {:.1}-{:.1}), {frame_med:.2} ms/frame median; PNG decoding (excluded) {decode_med:.2} ms/frame", fps_range.0, fps_range.1)?;
    if have_gt {
        crate::outln!("ATE rmse {ate_med:.4} m (evo, SE(3)); runs identical: {repeatable}")?;
    }
    if orb.is_some() {
        let (ofps, oate) = (
            stat(&orb, "fps_track", "median"),
            stat(&orb, "ate_rmse_final", "median"),
        );
        crate::outln!(
            "{:<28}{:>16}{:>20}{:>12}",
            "",
            "ATE rmse (m)",
            "frames/s",
            "lost"
        )?;
        crate::outln!(
            "{:<28}{:>16}{:>20}{:>12}",
            "stride VO",
            format!("{ate_med:.4} [{:.4}-{:.4}]", ate_range.0, ate_range.1),
            format!("{fps_med:.1} [{:.0}-{:.0}]", fps_range.0, fps_range.1),
            "-"
        )?;
        crate::outln!(
            "{:<28}{:>16}{:>20}{:>12}",
            "ORB-SLAM3 (full SLAM)",
            format!(
                "{oate:.4} [{:.4}-{:.4}]",
                stat(&orb, "ate_rmse_final", "min"),
                stat(&orb, "ate_rmse_final", "max")
            ),
            format!(
                "{ofps:.1} [{:.0}-{:.0}]",
                stat(&orb, "fps_track", "min"),
                stat(&orb, "fps_track", "max")
            ),
            format!("{:.0}", stat(&orb, "lost_frames", "median"))
        )?;
        crate::outln!("stride / ORB-SLAM3 frame rate: {:.2} (medians of {} runs each, same session; ORB-SLAM3 tracking time per frame, stride odometry time, decoding excluded for both)", fps_med / ofps, a.runs)?;
    }
    Ok(())
}

fn bench_synth(a: SynthBenchArgs) -> Result<()> {
    use stride_datasets::png_io::{encode_depth_u16, encode_rgb};
    use stride_datasets::synth::{motion::MotionConfig, Synth, SynthConfig};
    if a.frames == 0 {
        bail!("--frames must be at least 1");
    }
    crate::outln!("synthetic rendering, 640x480, procedural 'mixed' terrain, tripod at {} m/s; medians of {} frames", a.speed, a.frames)?;
    for blur in [false, true] {
        let config = SynthConfig {
            frames: a.frames,
            blur,
            motion: MotionConfig {
                speed_m_s: a.speed,
                ..MotionConfig::default()
            },
            ..SynthConfig::default()
        };
        let synth = Synth::new(config)?;
        let renderer = synth.renderer();
        let (mut render, mut encode, mut sub) = (Vec::new(), Vec::new(), Vec::new());
        for i in 0..a.frames {
            let f = synth.render_frame(&renderer, i);
            let t = Instant::now();
            let _ = encode_rgb(&f.rgb);
            let _ = encode_depth_u16(&f.depth_raw);
            encode.push(t.elapsed().as_secs_f64());
            render.push(f.render_s);
            sub.push(f.info.subframes as f64);
        }
        let r = median(render);
        crate::outln!(
            "{:<12} render {:>7.1} ms/frame ({:>5.1} frames/s), PNG encoding {:>5.1} ms/frame, sub-frames {:.0}",
            if blur { "with blur" } else { "no blur" },
            r * 1e3,
            1.0 / r,
            median(encode) * 1e3,
            median(sub)
        )?;
    }
    Ok(())
}

/// SplitMix64: a tiny, well-known deterministic generator, enough for benchmark data.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [-1, 1).
    fn symmetric(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

/// A 100 Hz ground truth on a smooth 3-D path and an estimate with random-walk drift, noise,
/// stamp jitter below the association window and a different world frame.
fn make_pair(n: usize, seed: u64) -> Result<(Trajectory, Trajectory)> {
    let mut rng = SplitMix64(seed);
    let world_est_from_gt = Isometry3::from_parts(
        Translation3::new(1.0, -2.0, 0.5),
        UnitQuaternion::from_euler_angles(0.1, -0.2, 0.7),
    );
    let (mut gt_t, mut gt_p, mut est_t, mut est_p) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    let mut drift = Vector3::zeros();
    for i in 0..n {
        let t = 1_700_000_000.0 + i as f64 * 0.01;
        let s = i as f64 * 0.01;
        let pos = Vector3::new(
            3.0 * (0.05 * s).sin(),
            2.0 * (0.031 * s).cos(),
            0.4 + 0.2 * (0.2 * s).sin(),
        );
        let rot = UnitQuaternion::from_euler_angles(
            0.05 * (0.7 * s).sin(),
            0.1 * (0.3 * s).cos(),
            0.05 * s,
        );
        let gt = Isometry3::from_parts(pos.into(), rot);
        drift += Vector3::new(rng.symmetric(), rng.symmetric(), rng.symmetric()) * 2e-4;
        let noise = Vector3::new(rng.symmetric(), rng.symmetric(), rng.symmetric()) * 3e-3;
        let rot_noise = UnitQuaternion::from_euler_angles(
            rng.symmetric() * 2e-3,
            rng.symmetric() * 2e-3,
            rng.symmetric() * 2e-3,
        );
        let est = world_est_from_gt
            * Isometry3::from_parts((pos + drift + noise).into(), rot * rot_noise);
        gt_t.push(t);
        gt_p.push(gt);
        est_t.push(t + rng.symmetric() * 0.002);
        est_p.push(est);
    }
    Ok((
        Trajectory::from_parts(gt_t, gt_p)?,
        Trajectory::from_parts(est_t, est_p)?,
    ))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

fn evo_timing(python: &Path, gt: &Path, est: &Path, runs: usize) -> Result<serde_json::Value> {
    let script = include_str!("../../scripts/peers/evo_bench.py");
    let out = std::process::Command::new(python)
        .arg("-c")
        .arg(script)
        .arg(gt)
        .arg(est)
        .arg(runs.to_string())
        .output()
        .with_context(|| format!("running {}", python.display()))?;
    if !out.status.success() {
        bail!(
            "evo benchmark failed ({}): {}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
                .lines()
                .last()
                .unwrap_or("")
        );
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let last = text.lines().last().unwrap_or("");
    serde_json::from_str(last).with_context(|| format!("parsing evo's output: {last}"))
}

fn bench_eval(a: EvalBenchArgs) -> Result<()> {
    if a.poses < 10 || a.runs == 0 {
        bail!("--poses must be at least 10 and --runs at least 1");
    }
    let tmp;
    let dir = match &a.keep {
        Some(d) => {
            std::fs::create_dir_all(d)?;
            d.clone()
        }
        None => {
            tmp = tempfile::tempdir()?;
            tmp.path().to_path_buf()
        }
    };
    let (gt, est) = make_pair(a.poses, 42)?;
    let (gt_path, est_path) = (dir.join("bench_gt.txt"), dir.join("bench_est.txt"));
    write_tum_trajectory(&gt_path, &gt)?;
    write_tum_trajectory(&est_path, &est)?;

    let ate_opts = AteOptions {
        align: Align::Se3,
        ..AteOptions::for_preset(Preset::Evo)
    };
    let rpe_opts = RpeOptions::for_preset(Preset::Evo);
    let (mut load, mut ate_t, mut rpe_t) = (Vec::new(), Vec::new(), Vec::new());
    let (mut ate_rmse, mut rpe_rmse) = (f64::NAN, f64::NAN);
    for _ in 0..a.runs {
        let t0 = Instant::now();
        let g = read_tum_trajectory(&gt_path)?;
        let e = read_tum_trajectory(&est_path)?;
        let t1 = Instant::now();
        ate_rmse = ate(&g, &e, &ate_opts)?.trans_m.rmse;
        let t2 = Instant::now();
        rpe_rmse = rpe(&g, &e, &rpe_opts)?.trans_m.rmse;
        let t3 = Instant::now();
        load.push((t1 - t0).as_secs_f64());
        ate_t.push((t2 - t1).as_secs_f64());
        rpe_t.push((t3 - t2).as_secs_f64());
    }
    let ours = json!({
        "load_s": median(load),
        "ate_s": median(ate_t),
        "rpe_s": median(rpe_t),
        "ate_rmse": ate_rmse,
        "rpe_rmse": rpe_rmse,
        "runs": a.runs,
    });
    let python = a
        .evo_python
        .clone()
        .or_else(|| std::env::var_os("STRIDE_EVO_PYTHON").map(PathBuf::from));
    let evo = match &python {
        Some(p) => Some(evo_timing(p, &gt_path, &est_path, a.evo_runs)?),
        None => None,
    };
    let f = |v: &serde_json::Value, k: &str| v.get(k).and_then(|x| x.as_f64()).unwrap_or(f64::NAN);
    if a.json {
        crate::outln!("{}", json!({"poses": a.poses, "stride": ours, "evo": evo}))?;
        return Ok(());
    }
    crate::outln!(
        "ATE (SE(3), evo preset) + RPE (1 frame) on {} poses per trajectory; medians",
        a.poses
    )?;
    crate::outln!(
        "{:<22}{:>14}{:>14}{:>14}",
        "",
        "stride (ms)",
        "evo (ms)",
        "evo / stride"
    )?;
    for (label, key) in [
        ("load both files", "load_s"),
        ("ATE", "ate_s"),
        ("RPE", "rpe_s"),
    ] {
        let s = f(&ours, key) * 1e3;
        match &evo {
            Some(e) => crate::outln!(
                "{label:<22}{s:>14.2}{:>14.1}{:>14.1}",
                f(e, key) * 1e3,
                f(e, key) * 1e3 / s
            )?,
            None => crate::outln!("{label:<22}{s:>14.2}{:>14}{:>14}", "-", "-")?,
        }
    }
    let total = |v: &serde_json::Value| f(v, "load_s") + f(v, "ate_s") + f(v, "rpe_s");
    match &evo {
        Some(e) => {
            crate::outln!(
                "{:<22}{:>14.2}{:>14.1}{:>14.1}",
                "total",
                total(&ours) * 1e3,
                total(e) * 1e3,
                total(e) / total(&ours)
            )?;
            crate::outln!(
                "results agree: ATE rmse {:.9} vs {:.9} m, RPE rmse {:.9} vs {:.9} m",
                ate_rmse,
                f(e, "ate_rmse"),
                rpe_rmse,
                f(e, "rpe_rmse")
            )?;
        }
        None => crate::outln!(
            "{:<22}{:>14.2}   (pass --evo-python to time evo on the same files)",
            "total",
            total(&ours) * 1e3
        )?,
    }
    Ok(())
}
