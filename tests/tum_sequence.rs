//! The TUM sequence reader on real data (fr3/teddy, first 200 frames): association, camera
//! inference, ground truth, background decoding, and frames that fail to load.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::data;
use stride_datasets::stream::StreamError;
use stride_datasets::tum::{AssociationOptions, CameraSource, TumSequence};

#[test]
fn teddy_200_opens_associates_and_decodes() {
    let Some(dir) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let seq = TumSequence::open(&dir, None, AssociationOptions::default()).unwrap();
    // The folder name says freiburg3: fr3 intrinsics, depth scale 5000.
    assert_eq!(seq.camera_source, CameraSource::FolderName("fr3"));
    assert_eq!(seq.camera.camera.fx(), 535.4);
    // 200 colour and 200 depth images; TUM's rule (|dt| < 0.02 s, one-to-one) pairs 193.
    assert_eq!(seq.len(), 193);
    assert_eq!(seq.unmatched_rgb, 7);
    for f in &seq.frames {
        assert!((f.t_rgb_s - f.t_depth_s).abs() < 0.02);
    }
    let gt = seq.groundtruth.as_ref().unwrap();
    assert_eq!(gt.len(), 8080);
    // Ground truth starts 0.14 s after the first image (data README).
    let first_gt = gt.stamps_s()[0];
    assert!(
        (first_gt - seq.frames[0].t_rgb_s - 0.14).abs() < 0.01,
        "{first_gt}"
    );

    let mut n = 0;
    let mut valid_depth = 0usize;
    for item in seq.stream(Some(20), 4) {
        let d = item.unwrap();
        assert_eq!(d.frame.index, n);
        assert_eq!((d.frame.rgb.width(), d.frame.rgb.height()), (640, 480));
        assert!(d.decode_s > 0.0);
        for &z in d.frame.depth_m.as_slice() {
            assert!(
                z == 0.0 || (0.3..10.0).contains(&z),
                "depth {z} m out of the sensor's range"
            );
            valid_depth += usize::from(z > 0.0);
        }
        n += 1;
    }
    assert_eq!(n, 20);
    assert!(valid_depth > 20 * 640 * 480 / 2, "most pixels have depth");
}

#[test]
fn missing_corrupt_and_wrongly_sized_frames_are_reported_and_skipped() {
    let Some(src) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("copy");
    std::fs::create_dir_all(dir.join("rgb")).unwrap();
    std::fs::create_dir_all(dir.join("depth")).unwrap();
    let seq = TumSequence::open(&src, Some("fr3"), AssociationOptions::default()).unwrap();
    let (mut rgb_txt, mut depth_txt) = (String::new(), String::new());
    for f in seq.frames.iter().take(4) {
        let rn = f.rgb_path.file_name().unwrap().to_str().unwrap();
        let dn = f.depth_path.file_name().unwrap().to_str().unwrap();
        std::fs::copy(&f.rgb_path, dir.join("rgb").join(rn)).unwrap();
        std::fs::copy(&f.depth_path, dir.join("depth").join(dn)).unwrap();
        rgb_txt += &format!("{:.6} rgb/{rn}\n", f.t_rgb_s);
        depth_txt += &format!("{:.6} depth/{dn}\n", f.t_depth_s);
    }
    std::fs::write(dir.join("rgb.txt"), rgb_txt).unwrap();
    std::fs::write(dir.join("depth.txt"), depth_txt).unwrap();
    // Frame 1: corrupt colour PNG. Frame 2: depth PNG missing. Frame 3 stays good.
    let f1 = &seq.frames[1];
    std::fs::write(
        dir.join("rgb").join(f1.rgb_path.file_name().unwrap()),
        b"\x89PNG garbage",
    )
    .unwrap();
    std::fs::remove_file(
        dir.join("depth")
            .join(seq.frames[2].depth_path.file_name().unwrap()),
    )
    .unwrap();
    // A camera file of another size makes every frame's size mismatch.
    let copy = TumSequence::open(&dir, Some("fr3"), AssociationOptions::default()).unwrap();
    let results: Vec<_> = copy.stream(None, 2).collect();
    assert_eq!(results.len(), 4);
    assert!(results[0].is_ok() && results[3].is_ok());
    let Err(StreamError::Frame(e1)) = &results[1] else {
        panic!("frame 1 fails");
    };
    assert_eq!(e1.index, 1);
    assert!(
        e1.error
            .to_string()
            .contains(f1.rgb_path.file_name().unwrap().to_str().unwrap()),
        "{}",
        e1.error
    );
    let Err(StreamError::Frame(e2)) = &results[2] else {
        panic!("frame 2 fails");
    };
    assert!(e2.error.to_string().contains("depth/"), "{}", e2.error);

    std::fs::write(
        dir.join("camera.json"),
        r#"{"fx": 300, "fy": 300, "cx": 160, "cy": 120, "width": 320, "height": 240, "depth_scale": 5000}"#,
    )
    .unwrap();
    let small = TumSequence::open(&dir, None, AssociationOptions::default()).unwrap();
    assert!(matches!(small.camera_source, CameraSource::SequenceFile(_)));
    let e = small.load_frame(0).unwrap_err().to_string();
    assert!(
        e.contains("image is 640x480 but the camera is 320x240"),
        "{e}"
    );
}

#[test]
fn a_folder_without_camera_or_lists_is_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let e = TumSequence::open(tmp.path(), None, AssociationOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("no camera given"), "{e}");
    let e = TumSequence::open(tmp.path(), Some("fr1"), AssociationOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("rgb.txt"), "{e}");
}

/// A TUM folder whose colour images are JPEG (as in re-distributed sequences), with one
/// rgb.txt line repeated: it opens with a warning, tracks like the PNG original, and a JPEG
/// in depth.txt is a clear error.
#[test]
fn jpeg_colour_images_and_a_repeated_list_line_are_read() {
    let Some(src) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let dst = tmp.path().join("teddy_jpeg");
    std::fs::create_dir_all(dst.join("rgb")).unwrap();
    let seq = TumSequence::open(&src, Some("fr3"), AssociationOptions::default()).unwrap();
    let (mut rgb_txt, mut depth_txt) = (String::new(), String::new());
    for (i, f) in seq.frames.iter().take(60).enumerate() {
        let img = stride_datasets::png_io::read_rgb(&f.rgb_path).unwrap();
        let bytes: Vec<u8> = img.as_slice().iter().flatten().copied().collect();
        let name = format!("rgb/{i:04}.jpg");
        jpeg_encoder::Encoder::new_file(dst.join(&name), 90)
            .unwrap()
            .encode(
                &bytes,
                img.width() as u16,
                img.height() as u16,
                jpeg_encoder::ColorType::Rgb,
            )
            .unwrap();
        let line = format!("{:.6} {name}\n", f.t_rgb_s);
        if i == 10 {
            rgb_txt += &line; // the same line twice
        }
        rgb_txt += &line;
        let depth = std::fs::canonicalize(&f.depth_path).unwrap();
        depth_txt += &format!("{:.6} {}\n", f.t_depth_s, depth.display());
    }
    std::fs::write(dst.join("rgb.txt"), rgb_txt).unwrap();
    std::fs::write(dst.join("depth.txt"), &depth_txt).unwrap();
    std::fs::copy(src.join("groundtruth.txt"), dst.join("groundtruth.txt")).unwrap();
    let run = |dir: &std::path::Path, out: &str| {
        let extra = ["--camera", "fr3", "--vo-only", "--max-frames", "60"];
        common::run_logged("run", dir, &tmp.path().join(out), &extra)
    };
    let (jpeg, err) = run(&dst, "jpeg");
    assert!(
        err.contains("rgb.txt: lines 11 and 12 have the same timestamp"),
        "{err}"
    );
    assert_eq!(jpeg["frames_tracked"], 60, "{jpeg}");
    let (png, _) = run(&src, "png");
    let (a, b) = (
        common::num(&jpeg["ate"], "rmse"),
        common::num(&png["ate"], "rmse"),
    );
    // JPEG at quality 90 changes corners a little: the same accuracy within a few mm.
    assert!(a < 0.02 && (a - b).abs() < 0.005, "JPEG {a} m, PNG {b} m");
    // Depth must stay lossless.
    let jpeg_depth = depth_txt.replacen(
        &std::fs::canonicalize(&seq.frames[0].depth_path)
            .unwrap()
            .display()
            .to_string(),
        &dst.join("rgb/0000.jpg").display().to_string(),
        1,
    );
    std::fs::write(dst.join("depth.txt"), jpeg_depth).unwrap();
    let out = common::run(&[
        "run",
        "--dataset",
        dst.to_str().unwrap(),
        "--camera",
        "fr3",
        "--out",
        tmp.path().join("bad").to_str().unwrap(),
        "--vo-only",
        "--max-frames",
        "5",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("0000.jpg") && err.contains("not a PNG"),
        "{err}"
    );
}
