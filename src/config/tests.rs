//! The defaults file is the defaults, every key is in it, and bad files are refused by key.

use super::*;

/// The keys of a TOML table, recursively, as `section.sub.key`.
fn keys(v: &toml::Value, prefix: &str, out: &mut Vec<String>) {
    if let toml::Value::Table(t) = v {
        for (k, v) in t {
            let key = if prefix.is_empty() {
                k.clone()
            } else {
                format!("{prefix}.{k}")
            };
            keys(v, &key, out);
            out.push(key);
        }
    }
}

#[test]
fn the_documented_defaults_are_the_defaults_and_hold_every_key() {
    let parsed = Config::from_toml(DEFAULTS_TOML, "defaults.toml").unwrap();
    assert_eq!(parsed, Config::default());
    let mut documented = Vec::new();
    keys(&toml::from_str(DEFAULTS_TOML).unwrap(), "", &mut documented);
    let mut all = Vec::new();
    let written = Config::default().to_toml().unwrap();
    keys(&toml::from_str(&written).unwrap(), "", &mut all);
    documented.sort();
    all.sort();
    assert_eq!(documented, all);
    assert!(all.len() > 90, "{} keys", all.len());
    // What a run writes reads back to the same configuration.
    assert_eq!(
        Config::from_toml(&written, "written").unwrap(),
        Config::default()
    );
}

#[test]
fn a_partial_file_keeps_the_other_defaults_and_false_turns_stages_off() {
    let c = Config::from_toml(
        "backend = false\n[map.stack]\nresolution_m = 0.02\nedge_filter = false\n[odometry]\nseed = 7\n",
        "partial.toml",
    )
    .unwrap();
    assert!(c.backend.is_none());
    assert_eq!(c.odometry.seed, 7);
    assert_eq!(
        c.odometry.target_features,
        VoConfig::default().target_features
    );
    let map = c.map.unwrap();
    assert_eq!(map.stack.resolution_m, 0.02);
    assert!(map.stack.edge_filter.is_none() && map.stack.median_filter.is_some());
    assert_eq!(map.every_frames, TerrainConfig::default().every_frames);
    let no_map = Config::from_toml("map = false\n", "m.toml").unwrap();
    assert!(no_map.map.is_none() && no_map.backend.is_some());
}

#[test]
fn an_unknown_key_is_named_with_its_line() {
    let err = Config::from_toml("[odometry]\nseed = 1\ntarget_feature = 500\n", "typo.toml")
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("typo.toml") && err.contains("target_feature") && err.contains("line 3"),
        "{err}"
    );
    let err = Config::from_toml("[mapping]\n", "section.toml")
        .unwrap_err()
        .to_string();
    assert!(err.contains("mapping"), "{err}");
    let err = Config::from_toml("[odometry]\nseed = \"one\"\n", "type.toml")
        .unwrap_err()
        .to_string();
    assert!(err.contains("seed") || err.contains("line 2"), "{err}");
    // Inside a table that can be turned off, the table's own errors come through.
    let err = Config::from_toml("[map.stack.edge_filter]\nsigma = 3.0\n", "inner.toml")
        .unwrap_err()
        .to_string();
    assert!(err.contains("sigma") && err.contains("line 2"), "{err}");
    let err = Config::from_toml("[map.stack]\nedge_filter = true\n", "on.toml")
        .unwrap_err()
        .to_string();
    assert!(err.contains("`false` to turn it off"), "{err}");
}

#[test]
fn a_value_out_of_range_is_named_by_its_key_with_the_allowed_range() {
    for (text, key, allowed) in [
        (
            "[odometry]\nklt_levels = 12\n",
            "odometry.klt_levels",
            "0 to 8",
        ),
        (
            "[odometry.inlier_test]\nkind = \"euclidean\"\nmax_m = -1.0\n",
            "odometry.inlier_test.max_m",
            "positive",
        ),
        (
            "[backend]\nwindow_keyframes = 1\n",
            "backend.window_keyframes",
            ">= 2",
        ),
        ("[map]\ndecimation = 0\n", "map.decimation", "1 to 8"),
        (
            "[map.stack]\nresolution_m = 0.0\n",
            "map.stack.resolution_m",
            "positive",
        ),
        ("[map.align]\ngain = 1.5\n", "map.align.gain", "0 to 1"),
        (
            "[map.stack.depth_smoothing]\nradius_px = 9\n",
            "map.stack.depth_smoothing.radius_px",
            "1 to 4",
        ),
        (
            "[map.stack.edge_filter]\nsigmas = -1.0\n",
            "map.stack.edge_filter.sigmas",
            "not negative",
        ),
        (
            "[map.stack.sensor]\nmin_depth_m = 5.0\nmax_depth_m = 1.0\n",
            "map.stack.sensor.max_depth_m",
            "must exceed sensor.min_depth_m",
        ),
        (
            "[schedule]\nlag_frames = 1000\n",
            "schedule.lag_frames",
            "0 to 100",
        ),
    ] {
        let err = Config::from_toml(text, "range.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains(key) && err.contains(allowed), "{text}: {err}");
    }
}

/// The SLAM's odometry and the odometry alone weigh their measurements as bundle adjustment
/// does (their documented reason): 2 mm of isotropic noise, and depth trusted 3 times less
/// than the sensor model, applied once (in the odometry's covariances, which the back end
/// receives), so a change to one of the noise models shows here. The pose graph keeps the
/// odometry's own model.
#[test]
fn the_odometry_and_bundle_adjustment_share_one_noise_model() {
    let slam = Config::default();
    let backend = slam.backend.clone().unwrap();
    let trust = BackendConfig::default().depth_noise_scale;
    assert_eq!(backend.mode, BackendMode::BundleAdjustment);
    assert_eq!(slam.odometry.model_noise_m, backend.model_noise_m);
    for depth_m in [0.5, 1.5, 4.0] {
        let ratio =
            slam.odometry.uncertainty.sigma_d(depth_m) / backend.depth_model.sigma_d(depth_m);
        assert!(
            (ratio * backend.depth_noise_scale - trust).abs() < 1e-9,
            "depth {depth_m} m: sigma ratio {ratio}, back end's scale {}",
            backend.depth_noise_scale
        );
    }
    // The odometry alone differs from the SLAM's only in its keyframe rate.
    let alone = VoConfig::odometry_only();
    assert_ne!(alone.redetect_fraction, slam.odometry.redetect_fraction);
    let same = VoConfig {
        redetect_fraction: slam.odometry.redetect_fraction,
        ..alone
    };
    assert_eq!(same, slam.odometry);
    // The pose graph: the sensor's model in the odometry (points behind occluding edges
    // at full weight), the factor in the back end.
    let pg = Config::defaults_for(Some(BackendMode::PoseGraph));
    let full_weight = VoConfig {
        occluded_sigma_px: 0.0,
        ..VoConfig::default()
    };
    assert_eq!(pg.odometry, full_weight);
    assert_eq!(pg.backend.map(|b| b.depth_noise_scale), Some(trust));
}

/// A file read for the odometry alone keeps its settings where it is silent, takes the
/// file's values where it is not, and still names an unknown key.
#[test]
fn a_file_for_the_odometry_alone_changes_only_the_keys_it_sets() {
    let base = Config::odometry_alone();
    assert_eq!(
        Config::from_toml_over("", "empty.toml", &base).unwrap(),
        base
    );
    let text = "[odometry]\nmodel_noise_m = 0.01\n[odometry.uncertainty]\nvar_u_px2 = 2.0\n";
    let c = Config::from_toml_over(text, "f.toml", &base).unwrap();
    assert_eq!(c.odometry.model_noise_m, 0.01);
    assert_eq!(c.odometry.uncertainty.var_u_px2, 2.0);
    let vo = VoConfig::odometry_only();
    assert_eq!(c.odometry.redetect_fraction, vo.redetect_fraction);
    assert_eq!(
        c.odometry.uncertainty.depth_sigma_coeffs,
        vo.uncertainty.depth_sigma_coeffs
    );
    assert_eq!(c.schedule, base.schedule);
    // Over the SLAM's defaults the same file leaves the SLAM's keyframe rate where it is
    // silent.
    let slam = Config::from_toml(text, "f.toml").unwrap();
    assert_eq!(
        slam.odometry.redetect_fraction,
        Config::default().odometry.redetect_fraction
    );
    let err = Config::from_toml_over("[odometry]\nmodel_noise = 1\n", "bad.toml", &base)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("bad.toml") && err.contains("model_noise"),
        "{err}"
    );
}

/// A file that opens a section and sets one key keeps [`Config::default`]'s value for every
/// other key of that section, not the section type's own default: the SLAM's odometry
/// (2 mm of model noise, depth trusted 3 times less) and its back end (depth weight 1)
/// differ from [`VoConfig::default`] and [`BackendConfig::default`], and a file that only
/// turned one link off once swapped the whole noise model unseen.
#[test]
fn a_section_a_file_opens_keeps_the_slams_defaults_where_the_file_is_silent() {
    let text = "[odometry]\nkeyframe_depth_link_inliers = 0\n[backend]\nwindow_keyframes = 9\n";
    let c = Config::from_toml(text, "s.toml").unwrap();
    let mut expected = Config::default();
    expected.odometry.keyframe_depth_link_inliers = 0;
    if let Some(b) = expected.backend.as_mut() {
        b.window_keyframes = 9;
    }
    assert_ne!(expected, Config::default());
    assert_eq!(c, expected);
}

/// A back end a file configures over a base without one (the odometry alone's) takes its
/// mode's defaults for the keys the file leaves out, not `BackendConfig::default()`'s.
#[test]
fn a_back_end_a_file_adds_takes_its_modes_defaults() {
    let base = Config::odometry_alone();
    let c = Config::from_toml_over("[backend]\nwindow_keyframes = 9\n", "b.toml", &base).unwrap();
    let expected = BackendConfig {
        window_keyframes: 9,
        ..Config::default().backend.unwrap()
    };
    assert_eq!(c.backend, Some(expected));
    assert_eq!(c.odometry, base.odometry);
    let pg = "[backend]\nmode = \"pose_graph\"\n";
    let c = Config::from_toml_over(pg, "pg.toml", &base).unwrap();
    assert_eq!(
        c.backend,
        Config::defaults_for(Some(BackendMode::PoseGraph)).backend
    );
}

/// The odometry alone has its own defaults; the back ends share the SLAM's.
#[test]
fn the_defaults_follow_the_back_end() {
    let pg = Config::defaults_for(Some(BackendMode::PoseGraph));
    assert_eq!(
        pg.backend.as_ref().map(|b| b.mode),
        Some(BackendMode::PoseGraph)
    );
    assert_eq!(pg.odometry.occluded_sigma_px, 0.0);
    assert_eq!(
        VoConfig {
            occluded_sigma_px: VoConfig::default().occluded_sigma_px,
            ..pg.odometry
        },
        VoConfig::default()
    );
    assert_eq!(
        Config::defaults_for(Some(BackendMode::BundleAdjustment)),
        Config::default()
    );
    assert_eq!(Config::defaults_for(None), Config::odometry_alone());
    assert!(Config::odometry_alone().backend.is_none());
    // A file that turns the back end off, read over the odometry alone's defaults, keeps
    // them.
    let alone = Config::odometry_alone();
    let c = Config::from_toml_over("backend = false\n", "alone.toml", &alone).unwrap();
    assert_eq!(c, alone);
}

/// A command that asks for a back end the file turned off gets that back end's defaults,
/// weighted for the odometry they come with; a configured back end keeps its settings.
#[test]
fn a_back_end_asked_for_takes_its_modes_defaults() {
    let off = Config::from_toml("backend = false\n", "off.toml").unwrap();
    assert_eq!(
        off.backend_in(BackendMode::BundleAdjustment),
        Config::default().backend.unwrap()
    );
    assert_eq!(
        off.backend_in(BackendMode::PoseGraph),
        Config::defaults_for(Some(BackendMode::PoseGraph))
            .backend
            .unwrap()
    );
    let mut c = Config::default();
    if let Some(b) = c.backend.as_mut() {
        b.window_keyframes = 7;
    }
    let pg = c.backend_in(BackendMode::PoseGraph);
    assert_eq!((pg.mode, pg.window_keyframes), (BackendMode::PoseGraph, 7));
}
