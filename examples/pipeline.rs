//! stride as a library: a TUM folder's frames fed to [`stride::Pipeline`] one at a time, as
//! a robot's camera driver would deliver them; each frame's live pose printed as it comes,
//! and at the end the optimized trajectory's length and the elevation map.
//!
//! ```sh
//! cargo run --release --example pipeline -- ../shared/data/tum/rgbd_dataset_freiburg3_teddy_200 [MAX_FRAMES]
//! ```

use std::path::Path;
use stride::{Pipeline, PipelineConfig};
use stride_datasets::tum::{AssociationOptions, TumSequence};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let dataset = args.next().ok_or("usage: pipeline DATASET [MAX_FRAMES]")?;
    let max_frames = args.next().map(|n| n.parse::<usize>()).transpose()?;
    let seq = TumSequence::open(Path::new(&dataset), None, AssociationOptions::default())?;

    // The SLAM with bundle adjustment, the world found from the floor, and the elevation
    // map on the optimized poses: every stage's defaults.
    let mut pipeline = Pipeline::new(&seq.camera, PipelineConfig::default())?;
    // A robot's gyroscope (here the folder's gyroscope.txt, when it has one) sharpens the
    // rolling-shutter correction; a driver may also hand samples over as they arrive.
    if let Some(samples) = &seq.gyroscope {
        pipeline.add_gyroscope(samples);
    }
    for (n, decoded) in seq.stream(max_frames, 4).enumerate() {
        let decoded = decoded?;
        let record = pipeline.process(&decoded.frame, decoded.decode_s)?;
        if n % 20 == 0 {
            // Live poses are in the first camera's frame until the world is known; the
            // final outputs are all in the gravity-aligned world.
            let p = record.live_world_from_camera.translation;
            println!(
                "frame {:4} at {:.3} s: {} (x {:+.3}, y {:+.3}, z {:+.3} m)",
                record.index,
                record.t_s,
                record.status.as_str(),
                p.x,
                p.y,
                p.z
            );
        }
        if n == 60 {
            // The map can be read at any time (it waits for the map's thread to catch up).
            if let Some(map) = pipeline.map() {
                println!("map after 61 frames: {} cells", map?.cells_observed());
            }
        }
    }
    let out = pipeline.finish()?;
    let trajectory = out.run.trajectory()?;
    let length_m: f64 = trajectory
        .positions()
        .windows(2)
        .map(|w| (w[1] - w[0]).norm())
        .sum();
    println!(
        "{} poses over {:.2} m; world frame: {}",
        trajectory.len(),
        length_m,
        out.run.world.describe()
    );
    if let Some(map) = out.map {
        let floor = stride_mapping::metrics::floor_fit(&map.layers.elevation, 0.10);
        println!(
            "elevation map: {} cells from {} views; floor tilt {}",
            map.layers.cells_observed(),
            map.stats.view_frames.len(),
            floor.map_or("-".into(), |f| format!("{:.2} deg", f.tilt_deg))
        );
    }
    Ok(())
}
