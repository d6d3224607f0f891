//! MCAP logs: TUM <-> MCAP round trips, runs on logs, interoperability with the Python
//! `mcap` packages (an independent implementation), and bad logs.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{data, data_lines, mcap_python, run, run_ok, scratch};
use std::path::{Path, PathBuf};
use std::process::Command;
use stride_datasets::mcap::ros2::{Header, ImageMsg, Time};
use stride_datasets::mcap::schema::Ros2Type;
use stride_datasets::mcap::{McapSequence, McapTopics};
use stride_datasets::png_io::{decode_depth_raw, read_rgb};
use stride_datasets::stream::StreamError;
use stride_datasets::trajectory_file::read_tum_trajectory;
use stride_datasets::tum::AssociationOptions;

fn teddy() -> Option<PathBuf> {
    data("tum/rgbd_dataset_freiburg3_teddy_200")
}

/// A TUM folder with the first `n` colour and depth images of `src` (copied), its camera
/// and its ground truth over those frames.
fn small_tum(src: &Path, dst: &Path, n: usize) {
    for sub in ["rgb", "depth"] {
        std::fs::create_dir_all(dst.join(sub)).unwrap();
        let lines: Vec<String> = data_lines(&src.join(format!("{sub}.txt")))
            .into_iter()
            .take(n)
            .collect();
        for l in &lines {
            let file = l.split_whitespace().nth(1).unwrap();
            std::fs::copy(src.join(file), dst.join(file)).unwrap();
        }
        std::fs::write(dst.join(format!("{sub}.txt")), lines.join("\n") + "\n").unwrap();
    }
    let gt: Vec<String> = data_lines(&src.join("groundtruth.txt"))
        .into_iter()
        .take(40)
        .collect();
    std::fs::write(dst.join("groundtruth.txt"), gt.join("\n") + "\n").unwrap();
    std::fs::write(
        dst.join("camera.json"),
        r#"{"fx": 535.4, "fy": 539.2, "cx": 320.1, "cy": 247.6, "width": 640, "height": 480, "depth_scale": 5000.0}"#,
    )
    .unwrap();
}

#[test]
fn a_tum_folder_survives_the_round_trip_through_mcap_exactly() {
    let Some(teddy) = teddy() else { return };
    let dir = scratch("roundtrip");
    for (images, compression, every) in [("raw", "zstd", 1), ("png", "lz4", 9)] {
        let log = dir.join(format!("teddy-{images}.mcap"));
        let back = dir.join(format!("back-{images}"));
        let t = |p: &Path| p.to_str().unwrap().to_owned();
        run_ok(&[
            "convert",
            "--from",
            &t(&teddy),
            "--to",
            &t(&log),
            "--images",
            images,
            "--compression",
            compression,
        ]);
        run_ok(&["convert", "--from", &t(&log), "--to", &t(&back)]);
        // Stamps and names, line for line.
        for list in ["rgb.txt", "depth.txt"] {
            let (a, b) = (data_lines(&teddy.join(list)), data_lines(&back.join(list)));
            assert_eq!(a.len(), 200, "{list}");
            assert_eq!(a, b, "{list} after {images}/{compression}");
        }
        // Pixels.
        for (k, line) in data_lines(&teddy.join("rgb.txt"))
            .iter()
            .enumerate()
            .step_by(every)
        {
            let file = line.split_whitespace().nth(1).unwrap();
            let (a, b) = (
                read_rgb(&teddy.join(file)).unwrap(),
                read_rgb(&back.join(file)).unwrap(),
            );
            assert!(
                a.as_slice() == b.as_slice(),
                "colour image {k} differs after {images}"
            );
        }
        for (k, line) in data_lines(&teddy.join("depth.txt"))
            .iter()
            .enumerate()
            .step_by(every)
        {
            let file = line.split_whitespace().nth(1).unwrap();
            let raw = |p: PathBuf| decode_depth_raw(&std::fs::read(&p).unwrap(), &p).unwrap();
            assert!(
                raw(teddy.join(file)).as_slice() == raw(back.join(file)).as_slice(),
                "depth image {k} differs after {images}"
            );
        }
        // Ground truth and camera.
        let (ga, gb) = (
            read_tum_trajectory(&teddy.join("groundtruth.txt")).unwrap(),
            read_tum_trajectory(&back.join("groundtruth.txt")).unwrap(),
        );
        assert_eq!(ga.len(), gb.len());
        for ((ta, pa), (tb, pb)) in ga.iter().zip(gb.iter()) {
            assert!((ta - tb).abs() < 1e-6, "{ta} vs {tb}");
            // groundtruth.txt is written with 9 decimals.
            assert!((pa.translation.vector - pb.translation.vector).norm() < 1e-9);
            let (qa, qb) = (pa.rotation.coords, pb.rotation.coords);
            assert!(
                (qa - qb).norm().min((qa + qb).norm()) < 1e-8,
                "{qa} vs {qb}"
            );
        }
        let camera = std::fs::read_to_string(back.join("camera.json")).unwrap();
        for v in ["535.4", "539.2", "320.1", "247.6", "5000"] {
            assert!(camera.contains(v), "{v} missing from {camera}");
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn stride_run_on_an_mcap_log_gives_the_tum_folders_trajectory() {
    let Some(teddy) = teddy() else { return };
    let dir = scratch("run");
    let log = dir.join("teddy.mcap");
    let t = |p: &Path| p.to_str().unwrap().to_owned();
    run_ok(&["convert", "--from", &t(&teddy), "--to", &t(&log)]);
    for (src, out) in [(&teddy, "tum"), (&log, "mcap")] {
        run_ok(&[
            "run",
            "--dataset",
            &t(src),
            "--out",
            &t(&dir.join(out)),
            "--no-map",
            "--max-frames",
            "90",
            "--deterministic",
            "-q",
        ]);
    }
    let traj = |o: &str| std::fs::read_to_string(dir.join(o).join("trajectory.tum")).unwrap();
    assert_eq!(
        traj("tum").lines().filter(|l| !l.starts_with('#')).count(),
        90
    );
    assert_eq!(traj("tum"), traj("mcap"), "the trajectories differ");
    let report = common::report(&dir.join("mcap"));
    assert!(
        report["camera"].as_str().unwrap().contains("camera_info"),
        "{}",
        report["camera"]
    );
    assert!(
        report.get("ate").is_some_and(|a| !a.is_null()),
        "the log's ground truth was not used"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_ros2_log_written_by_the_python_mcap_packages_is_read_exactly() {
    let Some(python) = mcap_python() else { return };
    let dir = scratch("from-python");
    let log = dir.join("py.mcap");
    let peer = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/peers/mcap_peer.py");
    let st = Command::new(&python)
        .args([peer, "write", log.to_str().unwrap(), "4"])
        .status()
        .unwrap();
    assert!(st.success());
    let topics = McapTopics {
        rgb: "/cam/color".into(),
        depth: "/cam/depth".into(),
        camera_info: Some("/cam/color/camera_info".into()),
        groundtruth_tf: Some(("odom".into(), "cam_gt".into())),
        ..McapTopics::default()
    };
    let seq = McapSequence::open(&log, &topics, None, AssociationOptions::default()).unwrap();
    let c = seq.camera.camera;
    assert_eq!(
        (c.fx(), c.fy(), c.cx(), c.cy(), c.width(), c.height()),
        (150.0, 151.0, 79.5, 59.5, 160, 120)
    );
    assert_eq!(seq.len(), 4);
    let gt = seq.groundtruth.as_ref().unwrap();
    assert_eq!(gt.len(), 4);
    let acc = seq
        .accelerometer
        .as_ref()
        .expect("/imu is in the colour frame: used");
    assert_eq!(acc.len(), 4);
    assert_eq!(acc[2].1.x, 0.2);
    // Its angular velocity is given (zero, covariance zero, not -1): a gyroscope too.
    assert_eq!(seq.gyroscope.as_ref().map(Vec::len), Some(4));
    for (k, item) in seq.stream(None, 2).enumerate() {
        let f = item.unwrap().frame;
        let ns = 123_456_789 + k as u64 * 33_333_333;
        let t = Time {
            sec: 1_700_000_000 + (ns / 1_000_000_000) as i32,
            nanosec: (ns % 1_000_000_000) as u32,
        };
        assert_eq!(f.t_s, t.seconds());
        assert!((gt.poses()[k].translation.x - 0.01 * k as f64).abs() < 1e-12);
        for v in 0..120u32 {
            for u in 0..160u32 {
                let (uu, vv, kk) = (u as usize, v as usize, k);
                let rgb = [
                    ((uu + kk) % 256) as u8,
                    (vv % 256) as u8,
                    ((uu * vv + kk) % 256) as u8,
                ];
                assert_eq!(f.rgb.get(u, v).unwrap(), rgb, "frame {k} pixel ({u}, {v})");
                let d = f.depth_m.get(u, v).unwrap();
                if u % 2 == 0 && v % 2 == 0 {
                    assert_eq!(d, 0.0, "a NaN depth is no return");
                } else {
                    let want = (0.5 + 0.001 * f64::from(u + v) + 0.01 * k as f64) as f32;
                    assert_eq!(d, want, "frame {k} depth ({u}, {v})");
                }
            }
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_log_written_by_stride_reads_back_in_the_python_mcap_packages() {
    let Some(teddy) = teddy() else { return };
    let Some(python) = mcap_python() else { return };
    let dir = scratch("to-python");
    small_tum(&teddy, &dir.join("tum"), 3);
    let log = dir.join("small.mcap");
    run_ok(&[
        "convert",
        "--from",
        dir.join("tum").to_str().unwrap(),
        "--to",
        log.to_str().unwrap(),
        "--compression",
        "zstd",
    ]);
    let peer = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/peers/mcap_peer.py");
    let out = Command::new(&python)
        .args([peer, "read", log.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let ch = &j["channels"];
    let expect = [
        ("/camera/rgb/image_color", Ros2Type::Image, 3),
        ("/camera/depth/image", Ros2Type::Image, 3),
        ("/camera/rgb/camera_info", Ros2Type::CameraInfo, 1),
        ("/tf", Ros2Type::TfMessage, 40),
    ];
    assert_eq!(ch.as_object().unwrap().len(), expect.len(), "{ch}");
    for (topic, ty, n) in expect {
        let c = &ch[topic];
        assert_eq!(c["schema"], ty.name(), "{topic}");
        assert_eq!(c["schema_encoding"], "ros2msg");
        assert_eq!(c["message_encoding"], "cdr");
        assert_eq!(c["count"], n, "{topic}");
        assert!(
            c.get("log_time_differs").is_none(),
            "{topic}: log_time is not the stamp"
        );
    }
    // Stamps: exactly the list's text.
    let rgb_lines = data_lines(&dir.join("tum/rgb.txt"));
    for (line, s) in rgb_lines
        .iter()
        .zip(ch["/camera/rgb/image_color"]["stamps"].as_array().unwrap())
    {
        let t = Time::parse_decimal(line.split_whitespace().next().unwrap()).unwrap();
        assert_eq!(s, &serde_json::json!([t.sec, t.nanosec]));
    }
    // Pixels: the first four of each image.
    let first_rgb = rgb_lines[0].split_whitespace().nth(1).unwrap();
    let img = read_rgb(&dir.join("tum").join(first_rgb)).unwrap();
    let head: Vec<u64> = img.as_slice()[..4]
        .iter()
        .flatten()
        .map(|&b| u64::from(b))
        .collect();
    let c = &ch["/camera/rgb/image_color"]["first"];
    assert_eq!(
        (
            c["encoding"].as_str(),
            c["step"].as_u64(),
            c["bytes"].as_u64()
        ),
        (Some("rgb8"), Some(1920), Some(921_600))
    );
    assert_eq!(c["head"], serde_json::json!(head));
    let first_depth = data_lines(&dir.join("tum/depth.txt"))[0]
        .split_whitespace()
        .nth(1)
        .unwrap()
        .to_owned();
    let p = dir.join("tum").join(first_depth);
    let d = decode_depth_raw(&std::fs::read(&p).unwrap(), &p).unwrap();
    let head: Vec<u64> = d.as_slice()[..6]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .map(u64::from)
        .collect();
    let c = &ch["/camera/depth/image"];
    assert_eq!(c["first"]["encoding"], "16UC1");
    assert_eq!(c["first"]["head"], serde_json::json!(head));
    assert_eq!(c["metadata"]["depth_units_per_m"], "5000");
    let info = &ch["/camera/rgb/camera_info"]["first"];
    assert_eq!(
        info["k"],
        serde_json::json!([535.4, 0.0, 320.1, 0.0, 539.2, 247.6, 0.0, 0.0, 1.0])
    );
    let tf = &ch["/tf"]["first"];
    assert_eq!(
        (tf["parent"].as_str(), tf["child"].as_str()),
        (Some("world"), Some("groundtruth"))
    );
    let gt = read_tum_trajectory(&dir.join("tum/groundtruth.txt")).unwrap();
    let t0 = gt.poses()[0].translation.vector;
    for (i, v) in tf["translation"].as_array().unwrap().iter().enumerate() {
        assert!((v.as_f64().unwrap() - t0[i]).abs() < 1e-12);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Writes a log with one colour image in `encoding` and a depth image, on stride's default
/// topics; the colour channel's message encoding is `message_encoding`.
fn odd_log(path: &Path, encoding: &str, message_encoding: &str) {
    odd_log_with(path, encoding, message_encoding, mcap::WriteOptions::new());
}

fn odd_log_with(path: &Path, encoding: &str, message_encoding: &str, options: mcap::WriteOptions) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = options.create(file).unwrap();
    let schema = w
        .add_schema(
            Ros2Type::Image.name(),
            "ros2msg",
            Ros2Type::Image.schema_text().as_bytes(),
        )
        .unwrap();
    let rgb = w
        .add_channel(
            schema,
            "/camera/rgb/image_color",
            message_encoding,
            &Default::default(),
        )
        .unwrap();
    let depth = w
        .add_channel(schema, "/camera/depth/image", "cdr", &Default::default())
        .unwrap();
    let header = Header {
        stamp: Time { sec: 5, nanosec: 0 },
        frame_id: "cam".into(),
    };
    let px = vec![0u8; 8 * 6 * 3];
    for (ch, enc) in [(rgb, encoding), (depth, "16UC1")] {
        let step = if enc == "rgb8" { 24 } else { 16 };
        let m = ImageMsg {
            header: header.clone(),
            height: 6,
            width: 8,
            encoding: enc.into(),
            is_bigendian: 0,
            step,
            data: &px,
        };
        let h = mcap::records::MessageHeader {
            channel_id: ch,
            sequence: 1,
            log_time: 5_000_000_000,
            publish_time: 5_000_000_000,
        };
        w.write_to_known_channel(&h, &m.encode()).unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn bad_logs_are_clear_errors_and_leave_no_output() {
    let dir = scratch("bad");
    let t = |p: &Path| p.to_str().unwrap().to_owned();
    // An odd pixel encoding: the frame fails, naming topic and message.
    let odd = dir.join("yuv.mcap");
    odd_log(&odd, "yuv422", "cdr");
    let seq = McapSequence::open(
        &odd,
        &McapTopics::default(),
        Some("fr1"),
        AssociationOptions::default(),
    )
    .unwrap();
    let items: Vec<_> = seq.stream(None, 1).collect();
    assert_eq!(items.len(), 1);
    let Err(StreamError::Frame(f)) = &items[0] else {
        panic!("expected a frame error")
    };
    let e = f.error.to_string();
    assert!(
        e.contains(
            "topic /camera/rgb/image_color, message 0: colour encoding 'yuv422' is not supported"
        ),
        "{e}"
    );
    // A wrong size against the camera is an error too, not a silently resized image.
    odd_log(&odd, "rgb8", "cdr");
    let seq = McapSequence::open(
        &odd,
        &McapTopics::default(),
        Some("fr1"),
        AssociationOptions::default(),
    )
    .unwrap();
    let e = seq
        .stream(None, 1)
        .next()
        .unwrap()
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("image_color, message 0: image is 8x6 but the camera is 640x480"),
        "{e}"
    );
    // An unindexed, unchunked log without a summary reads as well as an indexed one.
    let plain = dir.join("plain.mcap");
    let options = mcap::WriteOptions::new()
        .use_chunks(false)
        .emit_summary_records(false)
        .emit_summary_offsets(false);
    odd_log_with(&plain, "mono8", "cdr", options);
    let camera = dir.join("cam.json");
    std::fs::write(
        &camera,
        r#"{"fx": 9, "fy": 9, "cx": 4, "cy": 3, "width": 8, "height": 6, "depth_scale": 1000}"#,
    )
    .unwrap();
    let seq = McapSequence::open(
        &plain,
        &McapTopics::default(),
        camera.to_str(),
        AssociationOptions::default(),
    )
    .unwrap();
    let frames: Vec<_> = seq.stream(None, 1).map(|f| f.unwrap().frame).collect();
    assert_eq!(
        (frames.len(), frames[0].t_s, frames[0].rgb.width()),
        (1, 5.0, 8)
    );
    // Another message encoding than CDR.
    let json = dir.join("json.mcap");
    odd_log(&json, "rgb8", "json");
    let out = run(&[
        "convert",
        "--from",
        &t(&json),
        "--to",
        &t(&dir.join("out1")),
        "--camera",
        "fr1",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("message encoding 'json': only ROS 2's 'cdr'"),
        "{err}"
    );
    // No camera at all.
    let out = run(&["run", "--dataset", &t(&odd), "--out", &t(&dir.join("out2"))]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no camera"), "{err}");
    // A missing topic names the ones there are.
    let out = run(&[
        "run",
        "--dataset",
        &t(&odd),
        "--camera",
        "fr1",
        "--depth-topic",
        "/d",
        "--out",
        &t(&dir.join("out3")),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(
            "no depth topic /d; the log holds: /camera/depth/image (sensor_msgs/msg/Image)"
        ),
        "{err}"
    );
    // Truncated and corrupted logs.
    let Some(teddy) = teddy() else { return };
    let small = dir.join("tum");
    small_tum(&teddy, &small, 4);
    let log = dir.join("small.mcap");
    run_ok(&["convert", "--from", &t(&small), "--to", &t(&log)]);
    let bytes = std::fs::read(&log).unwrap();
    let cut = dir.join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let mut flipped = bytes.clone();
    flipped[bytes.len() / 2] ^= 0x10;
    let flip = dir.join("flip.mcap");
    std::fs::write(&flip, &flipped).unwrap();
    for (file, why) in [
        (&cut, "ended in the middle of a record"),
        (&flip, "CRC failed"),
    ] {
        let target = dir.join("never");
        let out = run(&["convert", "--from", &t(file), "--to", &t(&target)]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && err.contains("not a readable MCAP file") && err.contains(why),
            "{err}"
        );
        assert!(
            !target.exists(),
            "a failed conversion left {}",
            target.display()
        );
    }
    // A TUM folder with a broken image: an error naming it, and no log (nor temporary file).
    let first = data_lines(&small.join("depth.txt"))[2]
        .split_whitespace()
        .nth(1)
        .unwrap()
        .to_owned();
    std::fs::write(small.join(&first), b"not a png").unwrap();
    let log2 = dir.join("out.mcap");
    let out = run(&["convert", "--from", &t(&small), "--to", &t(&log2)]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains(&first), "{err}");
    let left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name())
        .filter(|n| n.to_string_lossy().contains("out.mcap"))
        .collect();
    assert!(left.is_empty(), "left behind: {left:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}
