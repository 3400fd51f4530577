//! Depth-to-colour registration and colour/depth pairing against SynthNOCS
//! ground truth: the depth sensor's view is rendered from its own pose, then
//! registered and compared with the depth the colour camera sees.

use tricons::capture::{CameraConfig, FramePairer, Timed, register_depth};
use tricons::frame::Intrinsics;
use tricons::geometry::{Pose, Vec3, rotation_axis_angle};
use tricons::synth::{SynthConfig, render_frame, render_sensor_depth};

const SEED: u64 = 20_250_007;

/// A small colour camera (fast renders) and a wider-angle depth sensor beside it, as on a D4xx.
fn rig() -> (SynthConfig, CameraConfig) {
    let color = Intrinsics { width: 320, height: 240, fx: 300.0, fy: 300.0, cx: 160.3, cy: 119.6 };
    let depth = Intrinsics { width: 256, height: 200, fx: 190.0, fy: 191.0, cx: 127.1, cy: 100.4 };
    let rotation = rotation_axis_angle(&Vec3::new(0.3, 1.0, 0.1).normalize(), 0.8_f64.to_radians());
    let color_from_depth = Pose::new(rotation, Vec3::new(0.015, -0.0004, 0.0012));
    let cfg = SynthConfig { intrinsics: color, depth_noise: false, color_noise: false, ..SynthConfig::default() };
    let camera = CameraConfig { color_from_depth, depth, ..CameraConfig::registered(color, 0.001) };
    (cfg, camera)
}

/// What the depth sensor measures (mm) for frame `index`.
fn sensor_depth_mm(cfg: &SynthConfig, camera: &CameraConfig, index: u64) -> Vec<u16> {
    let depth_from_color = camera.color_from_depth.inverse();
    render_sensor_depth(cfg, SEED, index, &camera.depth, &depth_from_color)
        .iter()
        .map(|&z| if z > 0.0 { (f64::from(z) * 1000.0).round() as u16 } else { 0 })
        .collect()
}

/// Over colour pixels away from depth edges: (fraction with a registered depth,
/// fraction of those within 3 mm (plus the local slope) of the colour camera's own depth).
fn agreement(truth: &[u16], registered: &[u16], width: usize) -> (f64, f64) {
    let height = truth.len() / width;
    let (mut smooth, mut covered, mut close) = (0usize, 0usize, 0usize);
    for v in 4..height - 4 {
        for u in 4..width - 4 {
            let z = truth[v * width + u];
            if z == 0 {
                continue;
            }
            // Away from depth edges: no jump between neighbours in a 7x7 window
            // (sloped surfaces such as the table change steadily, edges jump).
            let step_limit = (u32::from(z) / 50).max(8);
            let mut smooth_here = true;
            for dv in 0..7 {
                for du in 0..7 {
                    let (y, x) = (v + dv - 3, u + du - 3);
                    let n = u32::from(truth[y * width + x]);
                    let right = u32::from(truth[y * width + x + 1]);
                    let down = u32::from(truth[(y + 1) * width + x]);
                    if n == 0 || n.abs_diff(right) > step_limit || n.abs_diff(down) > step_limit {
                        smooth_here = false;
                    }
                }
            }
            if !smooth_here {
                continue; // a depth edge or a hole: occlusion decides there
            }
            smooth += 1;
            let r = registered[v * width + u];
            if r != 0 {
                covered += 1;
                // 3 mm, plus the surface's own depth change per colour pixel (a depth
                // pixel covers ~1.6 colour pixels here, all given its one depth).
                let local_step = [
                    truth[v * width + u + 1],
                    truth[v * width + u - 1],
                    truth[(v + 1) * width + u],
                    truth[(v - 1) * width + u],
                ]
                .iter()
                .map(|n| n.abs_diff(z))
                .max()
                .unwrap_or(0);
                close += usize::from(r.abs_diff(z) <= 3 + local_step);
            }
        }
    }
    assert!(smooth > 20_000, "only {smooth} smooth pixels");
    eprintln!("smooth {smooth}, covered {covered}, within 3 mm {close}");
    (covered as f64 / smooth as f64, close as f64 / covered.max(1) as f64)
}

#[test]
fn registered_depth_lands_on_the_right_colour_pixels() {
    let (cfg, camera) = rig();
    for index in [0, 5] {
        let truth = render_frame(&cfg, SEED, index).frame.depth;
        let registered = register_depth(&sensor_depth_mm(&cfg, &camera, index), &camera).unwrap();
        assert_eq!((registered.width, registered.height), (320, 240));
        let (coverage, within_3mm) = agreement(&truth.data, &registered.data, 320);
        assert!(coverage > 0.97, "frame {index}: only {coverage:.3} of smooth colour pixels got depth");
        assert!(within_3mm > 0.98, "frame {index}: only {within_3mm:.3} within 3 mm");

        // Ignoring the extrinsics (treating the sensor as if it sat in the colour camera) is visibly wrong.
        let naive = CameraConfig { color_from_depth: Pose::IDENTITY, ..camera.clone() };
        let wrong = register_depth(&sensor_depth_mm(&cfg, &camera, index), &naive).unwrap();
        let (_, wrong_close) = agreement(&truth.data, &wrong.data, 320);
        assert!(wrong_close < within_3mm - 0.05, "frame {index}: extrinsics made no difference ({wrong_close:.3})");
    }
}

#[test]
fn registration_with_identical_sensors_is_a_copy() {
    let k = Intrinsics { width: 4, height: 3, fx: 5.0, fy: 5.0, cx: 1.5, cy: 1.0 };
    let camera = CameraConfig::registered(k, 0.001);
    let raw: Vec<u16> = (0..12).map(|i| i * 100).collect();
    assert_eq!(register_depth(&raw, &camera).unwrap().data, raw);
    let err = register_depth(&raw[..11], &camera).unwrap_err().to_string();
    assert!(err.contains("11 pixels") && err.contains("4x3"), "{err}");
}

#[test]
fn camera_config_file_round_trip_and_errors() {
    let (_, camera) = rig();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("camera.json");
    std::fs::write(&path, camera.to_json()).unwrap();
    assert_eq!(CameraConfig::read(&path).unwrap(), camera);

    let mut bad: serde_json::Value = serde_json::from_str(&camera.to_json()).unwrap();
    bad["depth_scale_m"] = serde_json::json!(0.0);
    std::fs::write(&path, bad.to_string()).unwrap();
    let err = CameraConfig::read(&path).unwrap_err().to_string();
    assert!(err.contains("camera.json") && err.contains("depth_scale_m"), "{err}");
    std::fs::write(&path, "{\"format\": \"tricons-camera\", \"version\": 1}").unwrap();
    let err = CameraConfig::read(&path).unwrap_err().to_string();
    assert!(err.contains("camera.json") && err.contains("color"), "{err}");
    bad["version"] = serde_json::json!(7);
    std::fs::write(&path, bad.to_string()).unwrap();
    let err = CameraConfig::read(&path).unwrap_err().to_string();
    assert!(err.contains("version") && err.contains('7'), "{err}");
}

/// Colour and depth streams of SynthNOCS frames with independent jitter, a
/// depth frame and a colour frame lost: every pair holds one frame's colour
/// and that frame's depth, and the registered depth matches the colour view.
#[test]
fn pairs_are_the_same_synthnocs_frame() {
    let (cfg, camera) = rig();
    let frames: Vec<u64> = (0..8).collect();
    let period_s = 1.0 / 30.0;
    let jitter = |i: u64, salt: u64| ((i * 7919 + salt * 104_729) % 9) as f64 * 1e-3 - 4e-3; // +-4 ms
    let mut pairer = FramePairer::new(0.012, 8);
    let mut pairs = Vec::new();
    for &i in &frames {
        // Depth leads colour by 5 ms; colour 6 and depth 3 never arrive.
        if i != 3 {
            pairer.push_depth(Timed { timestamp_s: i as f64 * period_s - 0.005 + jitter(i, 1), value: i });
        }
        if i != 6 {
            pairer.push_color(Timed { timestamp_s: i as f64 * period_s + jitter(i, 2), value: i });
        }
        while let Some(p) = pairer.pop_pair() {
            pairs.push(p);
        }
    }
    let ids: Vec<(u64, u64)> = pairs.iter().map(|p| (p.color.value, p.depth.value)).collect();
    assert_eq!(ids, vec![(0, 0), (1, 1), (2, 2), (4, 4), (5, 5), (7, 7)]);
    let stats = pairer.stats();
    assert_eq!((stats.paired, stats.dropped_color, stats.dropped_depth), (6, 1, 1));
    for p in pairs.iter().filter(|p| [1, 4].contains(&p.color.value)) {
        let truth = render_frame(&cfg, SEED, p.color.value).frame.depth;
        let registered = register_depth(&sensor_depth_mm(&cfg, &camera, p.depth.value), &camera).unwrap();
        let (coverage, close) = agreement(&truth.data, &registered.data, 320);
        assert!(coverage > 0.97 && close > 0.98, "pair {}: {coverage:.3} / {close:.3}", p.color.value);
    }
}
