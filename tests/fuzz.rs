//! Fuzzing on stable Rust: every parser of user files gets random bytes and mutations of
//! real files (bit flips, inserted and deleted bytes, truncation, repeated chunks, odd
//! numeric tokens), `CASES` cases each, seeded so that a failure repeats. A parser may
//! refuse its input, never panic, and must answer each case well within a second (a hang
//! shows as a case over `SLOW_S`).
//!
//! Parsers: TUM trajectories, image lists, camera files (JSON, TOML, YAML, ORB-SLAM
//! settings), colour images (PNG, JPEG), depth PNGs, `.npy` layers and grid headers, scan
//! logs, ROS 2 CDR messages and MCAP logs.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;
use std::time::Instant;
use stride_core::image::Image;
use stride_core::rng::SplitMix64;
use stride_datasets::camera_config::CameraConfig;
use stride_datasets::grid_file::{decode_npy_f32, encode_npy_f32, parse_grid_header};
use stride_datasets::mcap::images::{depth_image, rgb_image, ImagePayload};
use stride_datasets::mcap::ros2::{
    CameraInfoMsg, CompressedImageMsg, Header, ImageMsg, ImuMsg, LaserScanMsg, TfMessage, Time,
    TransformStamped,
};
use stride_datasets::mcap::schema::Ros2Type;
use stride_datasets::mcap::{McapSequence, McapTopics};
use stride_datasets::orbslam_settings;
use stride_datasets::png_io::{
    decode_depth, decode_rgb, encode_depth_u16, encode_gray, encode_rgb,
};
use stride_datasets::scan_log::parse_scan_log;
use stride_datasets::trajectory_file::parse_tum_trajectory;
use stride_datasets::tum::parse_image_list;

/// Cases per parser.
const CASES: usize = 10_000;
/// A case slower than this counts as a hang.
const SLOW_S: f64 = 2.0;

const TOKENS: [&[u8]; 14] = [
    b"nan",
    b"inf",
    b"-inf",
    b"1e309",
    b"-0",
    b"0",
    b"18446744073709551616",
    b"1e-320",
    b"\n",
    b" ",
    b"#",
    b",",
    b"\"",
    b"\xff\xfe",
];

/// A mutation of `seed` (or random bytes, one case in eight).
fn mutate(seed: &[u8], rng: &mut SplitMix64) -> Vec<u8> {
    if seed.is_empty() || rng.below(8) == 0 {
        let n = rng.below(256);
        return (0..n).map(|_| rng.next_u64() as u8).collect();
    }
    let mut b = seed.to_vec();
    for _ in 0..1 + rng.below(4) {
        let at = rng.below(b.len() + 1);
        match rng.below(6) {
            0 if !b.is_empty() => {
                let i = at.min(b.len() - 1);
                b[i] ^= 1 << rng.below(8);
            }
            1 => b.insert(at, rng.next_u64() as u8),
            2 if at < b.len() => {
                b.remove(at);
            }
            3 => b.truncate(at),
            4 => {
                let end = (at + rng.below(64)).min(b.len());
                let chunk = b[at..end].to_vec();
                b.splice(at..at, chunk);
            }
            _ => {
                let t = TOKENS[rng.below(TOKENS.len())];
                b.splice(at..at, t.iter().copied());
            }
        }
    }
    b
}

/// Runs `parse` on `CASES` mutations of the seeds; fails on a panic or a hang. Returns how
/// many inputs were accepted (for the report).
fn fuzz(name: &str, seeds: &[Vec<u8>], parse: impl Fn(&[u8]) -> bool) -> usize {
    let mut rng = SplitMix64::new(name.bytes().fold(7, |h, c| h * 31 + u64::from(c)));
    let mut accepted = 0;
    let start = Instant::now();
    for case in 0..CASES {
        let seed = &seeds[case % seeds.len()];
        let input = mutate(seed, &mut rng);
        let t = Instant::now();
        let ok = catch_unwind(AssertUnwindSafe(|| parse(&input)));
        let elapsed = t.elapsed().as_secs_f64();
        match ok {
            Ok(a) => accepted += usize::from(a),
            Err(_) => panic!(
                "{name}: case {case} panicked on {:?}",
                String::from_utf8_lossy(&input)
            ),
        }
        assert!(elapsed < SLOW_S, "{name}: case {case} took {elapsed:.1} s");
    }
    eprintln!(
        "fuzz {name}: {CASES} cases, {accepted} accepted, 0 panics, {:.1} s",
        start.elapsed().as_secs_f64()
    );
    accepted
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

#[test]
fn trajectories_and_image_lists() {
    let real = common::data("trajectories/freiburg1_xyz-groundtruth.txt")
        .map(|p| std::fs::read(p).unwrap())
        .unwrap_or_default();
    // Short excerpts keep each case fast; the whole file is one seed among them.
    let excerpt: Vec<u8> = text(&real)
        .lines()
        .take(12)
        .flat_map(|l| format!("{l}\n").into_bytes())
        .collect();
    let seeds = vec![
        excerpt,
        b"1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n".to_vec(),
        real,
    ];
    let p = Path::new("traj.txt");
    fuzz("tum_trajectory", &seeds, |b| {
        parse_tum_trajectory(&text(b), p).is_ok()
    });
    let list = b"# rgb\n1305031102.175304 rgb/1305031102.175304.png\n1305031102.211214 rgb/x.jpg\n";
    fuzz("image_list", &[list.to_vec()], |b| {
        parse_image_list(&text(b), Path::new("rgb.txt")).is_ok()
    });
    let scans = b"# t tx ty tz qx qy qz qw angle_min angle_increment n r...\n\
        0.0 0 0 0.26 0 0.3007058 0 0.9537170 -0.5 0.25 5 0.45 0.46 nan 0 0.5\n\
        0.1 0.01 0 0.26 0 0.3007058 0 0.9537170 -0.5 0.25 5 0.45 0.46 0.47 0.48 0.5\n";
    let accepted = fuzz("scan_log", &[scans.to_vec()], |b| {
        parse_scan_log(&text(b), Path::new("scans.txt")).is_ok()
    });
    assert!(accepted > 0);
}

#[test]
fn camera_files() {
    let json = br#"{"fx": 535.4, "fy": 539.2, "cx": 320.1, "cy": 247.6, "width": 640, "height": 480, "depth_scale": 5000, "distortion": [0.1, -0.2, 0.0, 0.0, 0.01]}"#;
    let toml = b"fx = 535.4\nfy = 539.2\ncx = 320.1\ncy = 247.6\nwidth = 640\nheight = 480\ndepth_scale = 5000.0\n";
    let yaml =
        b"fx: 535.4\nfy: 539.2\ncx: 320.1\ncy: 247.6\nwidth: 640\nheight: 480\ndepth_scale: 5000\n";
    let orb = b"%YAML:1.0\nCamera.type: \"PinHole\"\nCamera1.fx: 517.3\nCamera1.fy: 516.4\nCamera1.cx: 318.6\nCamera1.cy: 255.3\nCamera1.k1: 0.26\nCamera.width: 640\nCamera.height: 480\nRGBD.DepthMapFactor: 5000.0\n";
    for (name, seed, file) in [
        ("camera_json", &json[..], "c.json"),
        ("camera_toml", &toml[..], "c.toml"),
        ("camera_yaml", &yaml[..], "c.yaml"),
        ("camera_orbslam", &orb[..], "c.yaml"),
    ] {
        let accepted = fuzz(name, &[seed.to_vec()], |b| {
            CameraConfig::from_text(&text(b), Path::new(file)).is_ok()
        });
        assert!(
            accepted > 0,
            "{name}: no mutation accepted: the seed itself is bad"
        );
    }
    fuzz("orbslam_settings", &[orb.to_vec()], |b| {
        orbslam_settings::parse(&text(b)).is_ok()
    });
}

#[test]
fn images_npy_and_grid_headers() {
    // Small images keep a case fast; a real teddy frame is a seed too.
    let rgb = Image::from_vec(
        16,
        12,
        (0..192u32).map(|i| [i as u8, (i * 3) as u8, 7]).collect(),
    )
    .unwrap();
    let grey = Image::from_vec(16, 12, (0..192u32).map(|i| i as u8).collect()).unwrap();
    let depth = Image::from_vec(16, 12, (0..192u16).map(|i| i * 300).collect()).unwrap();
    let jpeg = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/datasets/testdata/gradient_24x16.jpg"
    ))
    .unwrap();
    let mut colour_seeds = vec![encode_rgb(&rgb).unwrap(), encode_gray(&grey).unwrap(), jpeg];
    let mut depth_seeds = vec![encode_depth_u16(&depth).unwrap()];
    if let Some(teddy) = common::data("tum/rgbd_dataset_freiburg3_teddy_200") {
        let rgb_dir = teddy.join("rgb");
        let first = std::fs::read_dir(&rgb_dir)
            .unwrap()
            .next()
            .unwrap()
            .unwrap();
        colour_seeds.push(std::fs::read(first.path()).unwrap());
        let depth_dir = teddy.join("depth");
        let first = std::fs::read_dir(&depth_dir)
            .unwrap()
            .next()
            .unwrap()
            .unwrap();
        depth_seeds.push(std::fs::read(first.path()).unwrap());
    }
    fuzz("colour_image", &colour_seeds, |b| {
        decode_rgb(b, Path::new("rgb/x.png")).is_ok()
    });
    fuzz("depth_png", &depth_seeds, |b| {
        decode_depth(b, Path::new("depth/x.png"), 5000.0).is_ok()
    });
    let npy = encode_npy_f32(
        3,
        4,
        &[
            1.0,
            f32::NAN,
            2.0,
            3.0,
            4.0,
            5.0,
            6.0,
            7.0,
            8.0,
            9.0,
            0.5,
            -1.0,
        ],
    );
    fuzz("npy", &[npy], |b| {
        decode_npy_f32(b, Path::new("x.npy")).is_ok()
    });
    let header = br#"{"origin_x": -1.995, "origin_y": -1.995, "resolution": 0.01, "rows": 400, "cols": 400, "row_axis": "+y", "col_axis": "+x", "frame": "world"}"#;
    fuzz("grid_header", &[header.to_vec()], |b| {
        parse_grid_header(&text(b), Path::new("grid.json")).is_ok()
    });
}

#[test]
fn ros2_messages_and_mcap_logs() {
    let header = Header {
        stamp: Time { sec: 3, nanosec: 7 },
        frame_id: "cam".into(),
    };
    let px: Vec<u8> = (0..4 * 3 * 4).map(|i| i as u8).collect();
    let image = |encoding: &str, step: u32| {
        ImageMsg {
            header: header.clone(),
            height: 3,
            width: 4,
            encoding: encoding.into(),
            is_bigendian: 0,
            step,
            data: &px,
        }
        .encode()
    };
    let png = encode_depth_u16(&Image::from_vec(4, 3, (0..12u16).collect()).unwrap()).unwrap();
    let seeds = vec![
        image("rgb8", 12),
        image("16UC1", 8),
        image("32FC1", 16),
        CompressedImageMsg {
            header: header.clone(),
            format: "png".into(),
            data: &png,
        }
        .encode(),
        TfMessage {
            transforms: vec![TransformStamped {
                header: header.clone(),
                child_frame_id: "gt".into(),
                translation: [1.0, 2.0, 3.0],
                rotation: [0.0, 0.0, 0.0, 1.0],
            }],
        }
        .encode(),
        LaserScanMsg {
            header: header.clone(),
            angle_min: -1.0,
            angle_max: 1.0,
            angle_increment: 0.5,
            time_increment: 0.0,
            scan_time: 0.1,
            range_min: 0.1,
            range_max: 4.0,
            ranges: vec![1.0, 2.0, 3.0, 4.0, 5.0],
            intensities: vec![],
        }
        .encode(),
    ];
    fuzz("ros2_messages", &seeds, |b| {
        let mut ok = false;
        if let Ok(m) = ImageMsg::decode(b) {
            let p = ImagePayload::Raw(m);
            ok |= rgb_image(&p).is_ok() | depth_image(&p, 1000.0).is_ok();
        }
        if let Ok(m) = CompressedImageMsg::decode(b) {
            let p = ImagePayload::Compressed(m);
            ok |= rgb_image(&p).is_ok() | depth_image(&p, 1000.0).is_ok();
        }
        ok |= CameraInfoMsg::decode(b).is_ok();
        ok |= ImuMsg::decode(b).is_ok();
        ok |= LaserScanMsg::decode(b).is_ok();
        ok |= TfMessage::decode(b).is_ok();
        ok
    });
    // A small log (one raw colour and one depth image, a transform), whole and mutated,
    // opened and streamed from a file.
    let mut log = std::io::Cursor::new(Vec::new());
    {
        let mut w = mcap::Writer::new(&mut log).unwrap();
        let mut channel = |ty: Ros2Type, topic: &str| {
            let s = w
                .add_schema(ty.name(), "ros2msg", ty.schema_text().as_bytes())
                .unwrap();
            w.add_channel(s, topic, "cdr", &Default::default()).unwrap()
        };
        let (rgb, depth, tf) = (
            channel(Ros2Type::Image, "/camera/rgb/image_color"),
            channel(Ros2Type::Image, "/camera/depth/image"),
            channel(Ros2Type::TfMessage, "/tf"),
        );
        for (ch, data) in [(rgb, &seeds[0]), (depth, &seeds[1]), (tf, &seeds[4])] {
            let h = mcap::records::MessageHeader {
                channel_id: ch,
                sequence: 1,
                log_time: 3_000_000_007,
                publish_time: 3_000_000_007,
            };
            w.write_to_known_channel(&h, data).unwrap();
        }
        w.finish().unwrap();
    }
    let camera = std::env::temp_dir().join(format!("stride-fuzz-cam-{}.json", std::process::id()));
    std::fs::write(
        &camera,
        r#"{"fx": 5, "fy": 5, "cx": 2, "cy": 1.5, "width": 4, "height": 3, "depth_scale": 1000}"#,
    )
    .unwrap();
    let file = std::env::temp_dir().join(format!("stride-fuzz-{}.mcap", std::process::id()));
    let accepted = fuzz("mcap_log", &[log.into_inner()], |b| {
        std::fs::write(&file, b).unwrap();
        let topics = McapTopics::default();
        let options = stride_datasets::tum::AssociationOptions::default();
        match McapSequence::open(&file, &topics, camera.to_str(), options) {
            Ok(seq) => seq.stream(None, 1).all(|f| f.is_ok()),
            Err(_) => false,
        }
    });
    assert!(accepted > 0, "not even the unmutated log was read");
    std::fs::remove_file(&file).unwrap();
    std::fs::remove_file(&camera).unwrap();
}
