//! An IMU through MCAP: the synthetic lab's accelerometer and gyroscope survive a TUM
//! folder -> MCAP log -> TUM folder round trip (one `sensor_msgs/Imu` topic, each message
//! carrying one of the two, the other marked "not given" as ROS does), and the log's reader
//! hands both to the pipeline.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{run_ok, scratch};
use stride_datasets::accelerometer::{read_accelerometer, read_gyroscope};
use stride_datasets::mcap::{McapSequence, McapTopics};
use stride_datasets::synth::{generate, SynthConfig};
use stride_datasets::tum::AssociationOptions;

#[test]
fn the_labs_gyroscope_and_accelerometer_survive_the_round_trip_through_mcap() {
    let dir = scratch("mcap-imu");
    let (lab, log, back) = (dir.join("lab"), dir.join("lab.mcap"), dir.join("back"));
    let cfg = SynthConfig {
        camera: common::quarter_vga(0.02),
        frames: 4,
        blur: false,
        ..SynthConfig::default()
    };
    generate(&cfg, &lab, true, &mut |_, _| {}).unwrap();
    let t = |p: &std::path::Path| p.to_str().unwrap().to_owned();
    run_ok(&["convert", "--from", &t(&lab), "--to", &t(&log)]);
    let gyro = read_gyroscope(&lab.join("gyroscope.txt")).unwrap();
    let acc = read_accelerometer(&lab.join("accelerometer.txt")).unwrap();
    assert!(
        gyro.len() > 40 && acc.len() > 5,
        "{} {}",
        gyro.len(),
        acc.len()
    );
    let seq = McapSequence::open(
        &log,
        &McapTopics::default(),
        None,
        AssociationOptions::default(),
    )
    .unwrap();
    let same = |a: &[(f64, nalgebra::Vector3<f64>)], b: &[(f64, nalgebra::Vector3<f64>)]| {
        a.len() == b.len()
            && a.iter()
                .zip(b)
                .all(|(x, y)| (x.0 - y.0).abs() < 1e-6 && (x.1 - y.1).norm() < 1e-9)
    };
    assert!(
        same(seq.gyroscope.as_deref().unwrap(), &gyro),
        "the log's gyroscope"
    );
    assert!(
        same(seq.accelerometer.as_deref().unwrap(), &acc),
        "the log's accelerometer"
    );
    run_ok(&["convert", "--from", &t(&log), "--to", &t(&back)]);
    assert!(same(
        &read_gyroscope(&back.join("gyroscope.txt")).unwrap(),
        &gyro
    ));
    assert!(same(
        &read_accelerometer(&back.join("accelerometer.txt")).unwrap(),
        &acc
    ));
    std::fs::remove_dir_all(&dir).unwrap();
}
