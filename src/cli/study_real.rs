//! `stride study blur --real DIR`: the real side of the blur study (table, plots, runs).

use anyhow::{Context, Result};
use indicatif::ProgressBar;
use std::path::{Path, PathBuf};
use stride::study::real::{run_blurred, RealRun};
use stride::PipelineConfig;
use stride_core::frame::RgbdFrame;
use stride_datasets::motion_blur::MotionBlur;
use stride_datasets::sequence::Sequence;
use stride_eval::plot::{Chart, Series, Style, PALETTE};
use stride_eval::report::Report;

/// ORB-SLAM3 on the same blurred frames: per blur length (px), the harness's summary.
pub(crate) type PeerRuns = Vec<(f64, serde_json::Value)>;

/// The real side's runs: each length (px) with each `(seed, mitigation)` variant; with
/// `orbslam3` (the Python of a throwaway venv with the peer), ORB-SLAM3 too, one run per
/// seed and length, on the same
/// blurred frames written as a TUM folder (camera `peer_camera`: fr1, fr2 or fr3).
pub(crate) fn runs(
    seq: &Sequence,
    lengths_px: &[f64],
    variants: &[(u64, bool)],
    config: &PipelineConfig,
    max_frames: Option<usize>,
    orbslam3: Option<(&Path, &str)>,
    bar: &ProgressBar,
) -> Result<(Vec<RealRun>, PeerRuns)> {
    let (mut runs, mut peer) = (Vec::new(), Vec::new());
    for &length_px in lengths_px {
        let blur = MotionBlur {
            length_px,
            ..MotionBlur::default()
        };
        // The peer reads files: the blurred colour frames beside the recorded depth.
        let folder = match orbslam3 {
            Some(_) => Some(PeerFolder::new(seq.path(), length_px)?),
            None => None,
        };
        let mut listed = Vec::new();
        let r = run_blurred(seq, &blur, variants, config, max_frames, |frame| {
            bar.inc(1);
            match (&folder, frame) {
                (Some(dir), Some(f)) => dir.write(f, &mut listed),
                _ => Ok(()),
            }
        })
        .with_context(|| format!("{} blurred to {length_px} px", seq.path().display()))?;
        for x in &r {
            tracing::info!(
                "blur {length_px} px, seed {}, mitigation {}: ATE {:.2} mm, {} of {} frames tracked ({} by depth)",
                x.seed,
                super::study::on_off(x.mitigation),
                x.scores.ate_m * 1e3,
                x.tracked,
                x.frames,
                x.depth_aligned
            );
        }
        runs.extend(r);
        if let (Some(dir), Some((python, camera))) = (&folder, orbslam3) {
            dir.finish(&listed)?;
            let mut seeds: Vec<u64> = variants.iter().map(|v| v.0).collect();
            seeds.dedup();
            let summary = super::bench::orbslam3_summary(python, &dir.path, camera, seeds.len())
                .with_context(|| format!("ORB-SLAM3 on the frames blurred to {length_px} px"))?;
            peer.push((length_px, summary));
        }
    }
    Ok((runs, peer))
}

/// A TUM folder of blurred colour frames for the peer, beside the recording's depth (the
/// depth list and ground truth copied, the depth images linked); removed when dropped.
struct PeerFolder {
    path: PathBuf,
    source: PathBuf,
}

impl PeerFolder {
    fn new(source: &Path, length_px: f64) -> Result<Self> {
        if !source.join("depth.txt").is_file() {
            anyhow::bail!(
                "--orbslam3 needs --real to be a TUM folder: {} has no depth.txt",
                source.display()
            );
        }
        let path = std::env::temp_dir().join(format!(
            "stride-study-blur-{}-{length_px}px",
            std::process::id()
        ));
        if path.exists() {
            std::fs::remove_dir_all(&path)
                .with_context(|| format!("clearing {}", path.display()))?;
        }
        std::fs::create_dir_all(path.join("rgb"))
            .with_context(|| format!("creating {}", path.display()))?;
        Ok(Self {
            path,
            source: source.to_path_buf(),
        })
    }

    /// Writes one blurred colour frame and lists it.
    fn write(&self, f: &RgbdFrame, listed: &mut Vec<String>) -> Result<(), String> {
        let name = format!("rgb/{:.6}.png", f.t_s);
        let png = stride_datasets::png_io::encode_rgb(&f.rgb)?;
        std::fs::write(self.path.join(&name), png).map_err(|e| format!("{name}: {e}"))?;
        listed.push(format!("{:.6} {name}", f.t_s));
        Ok(())
    }

    /// Writes rgb.txt and brings in the recording's depth and ground truth.
    fn finish(&self, listed: &[String]) -> Result<()> {
        let ctx = |what: &str| format!("preparing {} for ORB-SLAM3: {what}", self.path.display());
        std::fs::write(self.path.join("rgb.txt"), listed.join("\n") + "\n")
            .with_context(|| ctx("rgb.txt"))?;
        for file in ["depth.txt", "groundtruth.txt"] {
            std::fs::copy(self.source.join(file), self.path.join(file))
                .with_context(|| ctx(file))?;
        }
        let depth =
            std::fs::canonicalize(self.source.join("depth")).with_context(|| ctx("depth"))?;
        std::os::unix::fs::symlink(depth, self.path.join("depth")).with_context(|| ctx("depth"))?;
        Ok(())
    }
}

impl Drop for PeerFolder {
    fn drop(&mut self) {
        if let Err(e) = std::fs::remove_dir_all(&self.path) {
            tracing::warn!("could not remove {}: {e}", self.path.display());
        }
    }
}

/// The peer's camera for `seq`: `camera` when it names a TUM preset, else the preset its
/// folder's name implies.
pub(crate) fn peer_camera(seq: &Sequence, camera: Option<&str>) -> Result<String> {
    let name = seq.path().to_string_lossy().to_lowercase();
    match camera {
        Some(c @ ("fr1" | "fr2" | "fr3")) => Ok(c.to_owned()),
        _ => ["1", "2", "3"]
            .iter()
            .find(|k| name.contains(&format!("freiburg{k}")))
            .map(|k| format!("fr{k}"))
            .context("--orbslam3 needs --camera fr1|fr2|fr3 for this sequence"),
    }
}

/// Per blur length, over the seeds: length, ATE mean and worst (mm), ATE over the
/// unblurred run's, ATE after Sim(3) (mm), how far the length is off (%), RPE (mm),
/// tracked, lost, sharpness; and ORB-SLAM3's ATE (median and range of its runs' final
/// trajectories) and tracked frames when it ran.
pub(crate) fn table(runs: &[RealRun], peer: &PeerRuns) -> Vec<Vec<String>> {
    let mut lengths: Vec<f64> = runs.iter().map(|r| r.length_px).collect();
    lengths.sort_by(f64::total_cmp);
    lengths.dedup();
    let mut mitigations: Vec<bool> = runs.iter().map(|r| r.mitigation).collect();
    mitigations.sort();
    mitigations.dedup();
    let mean_ate = |l: f64, m: bool| {
        let set: Vec<f64> = runs
            .iter()
            .filter(|r| r.length_px == l && r.mitigation == m)
            .map(|r| r.scores.ate_m)
            .collect();
        set.iter().sum::<f64>() / set.len().max(1) as f64
    };
    let has_reference = lengths.contains(&0.0);
    lengths
        .iter()
        .flat_map(|&l| mitigations.iter().map(move |&m| (l, m)))
        .map(|(l, m)| {
            let set: Vec<&RealRun> = runs
                .iter()
                .filter(|r| r.length_px == l && r.mitigation == m)
                .collect();
            let n = set.len().max(1) as f64;
            let mean = |f: &dyn Fn(&RealRun) -> f64| set.iter().map(|r| f(r)).sum::<f64>() / n;
            let worst = set.iter().map(|r| r.scores.ate_m).fold(0.0, f64::max);
            let frames: usize = set.iter().map(|r| r.frames).sum();
            let tracked: usize = set.iter().map(|r| r.tracked).sum();
            let by_depth: usize = set.iter().map(|r| r.depth_aligned).sum();
            let mut row = vec![
                format!("{l:.0}"),
                super::study::on_off(m).to_owned(),
                format!("{:.2}, {:.2}", mean_ate(l, m) * 1e3, worst * 1e3),
                match has_reference {
                    true => format!("{:.2}", mean_ate(l, m) / mean_ate(0.0, m)),
                    false => "-".into(),
                },
                format!("{:.2}", mean(&|r| r.scores.ate_sim3_m) * 1e3),
                format!("{:.2}", mean(&|r| super::study::scale_off_pct(&r.scores))),
                format!("{:.2}", mean(&|r| r.scores.rpe_m) * 1e3),
                format!("{:.1} %", 100.0 * tracked as f64 / frames.max(1) as f64),
                format!("{by_depth}"),
                format!("{}", frames - tracked),
                format!(
                    "{:.0}",
                    set.first().map_or(f64::NAN, |r| r.sharpness_median)
                ),
            ];
            if !peer.is_empty() {
                let summary = peer.iter().find(|(pl, _)| *pl == l).map(|(_, s)| s);
                let stat = |k: &str, s: &str| {
                    summary
                        .and_then(|j| j.get(k))
                        .and_then(|x| x.get(s))
                        .and_then(serde_json::Value::as_f64)
                        .unwrap_or(f64::NAN)
                };
                row.push(format!(
                    "{:.2} [{:.2}-{:.2}]",
                    stat("ate_rmse_final", "median") * 1e3,
                    stat("ate_rmse_final", "min") * 1e3,
                    stat("ate_rmse_final", "max") * 1e3
                ));
                row.push(format!("{:.1} %", 100.0 * stat("ok_ratio", "median")));
            }
            row
        })
        .collect()
}

/// Column names of [`table`] (with ORB-SLAM3's when it ran).
pub(crate) fn columns(peer: bool) -> Vec<&'static str> {
    let mut c = vec![
        "blur px (median)",
        "mitigation",
        "ATE mm (mean, worst)",
        "ATE / unblurred",
        super::study::SIM3_ATE_COLUMN,
        super::study::SCALE_OFF_COLUMN,
        "RPE mm",
        "tracked",
        "by depth",
        "lost",
        "sharpness",
    ];
    if peer {
        c.extend(["ORB-SLAM3 ATE mm (median [range])", "ORB-SLAM3 tracked"]);
    }
    c
}

/// ATE and tracked frames against the blur length, every seed (ORB-SLAM3's median ATE
/// beside when it ran).
pub(crate) fn charts(runs: &[RealRun], peer: &PeerRuns) -> Vec<Chart> {
    let pts = |f: &dyn Fn(&RealRun) -> f64| -> Vec<(f64, f64)> {
        runs.iter().map(|r| (r.length_px, f(r))).collect()
    };
    let both = runs.iter().any(|r| r.mitigation) && runs.iter().any(|r| !r.mitigation);
    let mut ate: Vec<Series> = match both {
        false => vec![Series::line(
            "stride",
            PALETTE[0],
            pts(&|r| r.scores.ate_m * 1e3),
        )],
        true => [false, true]
            .into_iter()
            .map(|m| {
                let on: Vec<(f64, f64)> = runs
                    .iter()
                    .filter(|r| r.mitigation == m)
                    .map(|r| (r.length_px, r.scores.ate_m * 1e3))
                    .collect();
                let name = format!("stride, mitigation {}", super::study::on_off(m));
                Series::line(name, PALETTE[if m { 0 } else { 3 }], on)
            })
            .collect(),
    }
    .into_iter()
    .map(|s| s.with_style(Style::Markers))
    .collect();
    if !peer.is_empty() {
        let orb = peer
            .iter()
            .filter_map(|(l, s)| {
                let v = s.get("ate_rmse_final")?.get("median")?.as_f64()?;
                Some((*l, v * 1e3))
            })
            .collect();
        ate.push(Series::line("ORB-SLAM3 (median)", PALETTE[2], orb).with_style(Style::Markers));
    }
    vec![
        Chart {
            title: "Real frames: ATE against blur (every seed)".into(),
            x_label: "median blur length (px)".into(),
            y_label: "ATE RMSE (mm)".into(),
            series: ate,
            y_from_zero: true,
            ..Chart::default()
        },
        Chart {
            title: "Real frames: tracked frames against blur".into(),
            x_label: "median blur length (px)".into(),
            y_label: "frames tracked (%)".into(),
            series: vec![Series::line(
                "stride",
                PALETTE[1],
                pts(&|r| 100.0 * r.tracked as f64 / r.frames.max(1) as f64),
            )
            .with_style(Style::Markers)],
            y_from_zero: true,
            ..Chart::default()
        },
    ]
}

/// The report's section on the real side.
pub(crate) fn section(
    rep: &mut Report,
    dataset: &str,
    seeds: u64,
    runs: &[RealRun],
    peer: &PeerRuns,
) {
    rep.heading("Real frames blurred along their motion");
    rep.paragraph(format!(
        "{dataset}: every colour frame blurred along each pixel's image motion (from the \
         ground truth and the pixel's depth, over 0.1 s before and after the frame), scaled \
         so that the frame's median blur is the length given; depth as recorded. Length 0 is \
         the sequence as recorded. The SLAM on each with {seeds} RANSAC seed{}. Mitigation \
         on: frames the features lose are placed by aligning their depth with the last \
         keyframe's ('by depth', counted as tracked); off: they are predicted ('lost'), \
         and a gyroscope, had the sequence one, would not be used.",
        if seeds == 1 { "" } else { "s" }
    ));
    if !peer.is_empty() {
        rep.paragraph(format!(
            "ORB-SLAM3 (RGB-D, through ../shared/tools/peers/orbslam3_tum.py in a throwaway \
             venv) on the same blurred frames in the same session, {seeds} run{} per length: \
             ATE of its final trajectory (evo_ape -a; frames it lost are left out of it), and \
             the share of frames it tracked.",
            if seeds == 1 { "" } else { "s" }
        ));
    }
    rep.table(&columns(!peer.is_empty()), table(runs, peer));
}
