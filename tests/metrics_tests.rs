//! Integration tests of the NOCS metrics through the public API.

use nalgebra::Matrix3;
use std::path::Path;
use tricons::Category;
use tricons::frame::{Intrinsics, RgbdFrame};
use tricons::geometry::{Mat3, Pose, Vec3, rotation_axis_angle, rotation_y};
use tricons::metrics::{
    EvalConfig, EvalReport, IouMode, PoseThreshold, evaluate, evaluate_recording, evaluate_recordings, iou_3d,
    pose_error, symmetric_iou_3d, voc_ap,
};
use tricons::output::{FramePredictions, PredInstance};
use tricons::recording::{FrameAnnotations, GtInstance, Recording};

const MODES: [IouMode; 2] = [IouMode::Published, IouMode::Corrected];
const IOU_METRICS: [&str; 3] = ["IoU25", "IoU50", "IoU75"];
const POSE_METRICS: [&str; 4] = ["5deg2cm", "5deg5cm", "10deg2cm", "10deg5cm"];

fn gt(class: Category, pose: Pose, size: [f64; 3], handle_visible: bool) -> GtInstance {
    GtInstance { id: 1, class, camera_from_object: pose, size_m: size, handle_visible }
}

fn pred(class: Category, score: f64, pose: Pose, size: [f64; 3]) -> PredInstance {
    PredInstance { class, score, camera_from_object: pose, size_m: size, box2d: None, mask: None }
}

fn pred_of(g: &GtInstance, score: f64) -> PredInstance {
    pred(g.class, score, g.camera_from_object, g.size_m)
}

/// A typical tabletop pose: tilted view, object about 0.7 m in front.
fn pose_at(x: f64, y: f64, yaw: f64) -> Pose {
    let tilt = rotation_axis_angle(&Vec3::x(), 0.9);
    Pose::new(tilt * rotation_y(yaw), Vec3::new(x, y, 0.7))
}

fn size_of(class: Category) -> [f64; 3] {
    match class {
        Category::Bottle => [0.08, 0.22, 0.08],
        Category::Bowl => [0.16, 0.07, 0.16],
        Category::Camera => [0.12, 0.09, 0.07],
        Category::Can => [0.07, 0.12, 0.07],
        Category::Laptop => [0.32, 0.22, 0.25],
        Category::Mug => [0.13, 0.1, 0.09],
    }
}

fn one_frame(gts: &[GtInstance], preds: &[PredInstance], cfg: &EvalConfig) -> EvalReport {
    evaluate([(gts, preds)], cfg)
}

fn assert_all(report: &EvalReport, class: Category, metrics: &[&str], expected: f64) {
    for m in metrics {
        let ap = report.class_ap(class, m);
        assert!(ap.is_some_and(|v| (v - expected).abs() < 1e-9), "{class} {m}: {ap:?}, expected {expected}");
    }
}

#[test]
fn perfect_predictions_score_100_everywhere_in_both_modes() {
    let mut frames: Vec<(Vec<GtInstance>, Vec<PredInstance>)> = Vec::new();
    for f in 0..3 {
        let mut gts = Vec::new();
        for (k, class) in Category::ALL.into_iter().enumerate() {
            // Two instances per class in frame 1, mugs with and without handle.
            for copy in 0..if f == 1 { 2 } else { 1 } {
                let x = -0.5 + 0.2 * k as f64;
                let y = -0.1 + 0.3 * copy as f64;
                let handle_visible = (f + copy) % 2 == 0;
                gts.push(gt(class, pose_at(x, y, 0.3 * (f + k) as f64), size_of(class), handle_visible));
            }
        }
        let preds = gts.iter().enumerate().map(|(i, g)| pred_of(g, 0.3 + 0.05 * i as f64)).collect();
        frames.push((gts, preds));
    }
    for mode in MODES {
        let report = evaluate(frames.iter().map(|(g, p)| (g.as_slice(), p.as_slice())), &EvalConfig::standard(mode));
        assert_eq!(report.frames_evaluated, 3);
        assert_eq!(report.iou_mode, mode);
        for class in Category::ALL {
            assert_all(&report, class, &IOU_METRICS, 100.0);
            assert_all(&report, class, &POSE_METRICS, 100.0);
        }
        for m in IOU_METRICS.iter().chain(&POSE_METRICS) {
            assert_eq!(report.mean(m), Some(100.0), "{mode} {m}");
        }
        let mugs = &report.classes[5];
        assert_eq!((mugs.num_gt, mugs.num_pred, mugs.num_gt_pose, mugs.num_pred_pose), (4, 4, 4, 4));
    }
}

#[test]
fn camera_rotated_seven_degrees_passes_ten_fails_five() {
    let size = size_of(Category::Camera);
    let g = gt(Category::Camera, pose_at(0.05, -0.02, 0.4), size, true);
    let rotated = rotation_axis_angle(&Vec3::new(0.3, -0.5, 0.8), 7f64.to_radians()) * g.camera_from_object.rotation;
    let p = pred(Category::Camera, 0.8, Pose::new(rotated, g.camera_from_object.translation_m), size);
    let (deg, cm) = pose_error(&p.camera_from_object, &g.camera_from_object, false);
    assert!((deg - 7.0).abs() < 1e-9 && cm == 0.0, "{deg} {cm}");
    for mode in MODES {
        let iou = iou_3d(&p.camera_from_object, &size, &g.camera_from_object, &size, mode);
        assert!(iou > 0.1, "{mode}: {iou}");
        let report = one_frame(std::slice::from_ref(&g), std::slice::from_ref(&p), &EvalConfig::standard(mode));
        assert_all(&report, Category::Camera, &["10deg2cm", "10deg5cm"], 100.0);
        assert_all(&report, Category::Camera, &["5deg2cm", "5deg5cm"], 0.0);
    }
}

#[test]
fn camera_shifted_three_cm_passes_five_fails_two() {
    let size = size_of(Category::Camera);
    let g = gt(Category::Camera, pose_at(0.05, -0.02, 0.4), size, true);
    let mut p = pred_of(&g, 0.8);
    p.camera_from_object.translation_m += Vec3::new(0.0, 0.03, 0.0);
    let (deg, cm) = pose_error(&p.camera_from_object, &g.camera_from_object, false);
    assert!(deg < 1e-6 && (cm - 3.0).abs() < 1e-9, "{deg} {cm}");
    for mode in MODES {
        let iou = iou_3d(&p.camera_from_object, &size, &g.camera_from_object, &size, mode);
        assert!(iou > 0.1, "{mode}: {iou}");
        let report = one_frame(std::slice::from_ref(&g), std::slice::from_ref(&p), &EvalConfig::standard(mode));
        assert_all(&report, Category::Camera, &["5deg5cm", "10deg5cm"], 100.0);
        assert_all(&report, Category::Camera, &["5deg2cm", "10deg2cm"], 0.0);
    }
}

#[test]
fn symmetric_objects_ignore_rotation_about_their_y_axis() {
    for (class, handle_visible) in
        [(Category::Bottle, true), (Category::Can, true), (Category::Bowl, true), (Category::Mug, false)]
    {
        for angle_deg in [37.0, 90.0, 143.0, 180.0, 251.0] {
            let g = gt(class, pose_at(0.02, 0.03, 0.7), size_of(class), handle_visible);
            let mut p = pred_of(&g, 0.9);
            p.camera_from_object.rotation = g.camera_from_object.rotation * rotation_y(f64::to_radians(angle_deg));
            for mode in MODES {
                let report = one_frame(std::slice::from_ref(&g), std::slice::from_ref(&p), &EvalConfig::standard(mode));
                assert_all(&report, class, &IOU_METRICS, 100.0);
                assert_all(&report, class, &POSE_METRICS, 100.0);
            }
        }
    }
}

#[test]
fn mug_with_visible_handle_is_not_symmetric() {
    let size = size_of(Category::Mug);
    let g = gt(Category::Mug, pose_at(0.02, 0.03, 0.2), size, true);
    let mut p = pred_of(&g, 0.9);
    p.camera_from_object.rotation = g.camera_from_object.rotation * rotation_y(f64::to_radians(90.0));
    let (deg, _) = pose_error(&p.camera_from_object, &g.camera_from_object, g.class.is_symmetric(g.handle_visible));
    assert!((deg - 90.0).abs() < 1e-9, "{deg}");
    for mode in MODES {
        let iou = iou_3d(&p.camera_from_object, &size, &g.camera_from_object, &size, mode);
        assert!(iou > 0.1, "{mode}: {iou}");
        let report = one_frame(std::slice::from_ref(&g), std::slice::from_ref(&p), &EvalConfig::standard(mode));
        assert_eq!(report.classes[5].num_gt_pose, 1, "{mode}: the pair passes the IoU gate");
        assert_all(&report, Category::Mug, &POSE_METRICS, 0.0);
        // The same prediction against a hidden-handle mug is perfect in pose.
        let hidden = GtInstance { handle_visible: false, ..g.clone() };
        let report = one_frame(&[hidden], std::slice::from_ref(&p), &EvalConfig::standard(mode));
        assert_all(&report, Category::Mug, &POSE_METRICS, 100.0);
    }
}

/// Two cameras, detected by TPs scored 0.9 and `tp2`, and one FP far from both.
fn two_gt_one_fp(fp_score: f64, tp2: f64, mode: IouMode) -> EvalReport {
    let size = size_of(Category::Camera);
    let a = gt(Category::Camera, pose_at(-0.2, 0.0, 0.1), size, true);
    let b = gt(Category::Camera, pose_at(0.2, 0.0, 0.5), size, true);
    let fp = pred(Category::Camera, fp_score, pose_at(0.0, 0.4, 0.0), size);
    // The TPs are in separate frames, the FP in the first: AP pools frames.
    let frame1_gt = vec![a.clone()];
    let frame1_pred = vec![pred_of(&a, 0.9), fp];
    let frame2_gt = vec![b.clone()];
    let frame2_pred = vec![pred_of(&b, tp2)];
    evaluate(
        [(frame1_gt.as_slice(), frame1_pred.as_slice()), (frame2_gt.as_slice(), frame2_pred.as_slice())],
        &EvalConfig::standard(mode),
    )
}

#[test]
fn false_positive_lowers_ap_by_the_voc_amount_but_not_pose_ap() {
    for mode in MODES {
        // TP 0.9, FP 0.8, TP 0.7: 0.5 * 1 + 0.5 * 2/3.
        let report = two_gt_one_fp(0.8, 0.7, mode);
        let expected = 100.0 * (0.5 + 0.5 * 2.0 / 3.0);
        assert_all(&report, Category::Camera, &IOU_METRICS, expected);
        assert!((expected - 83.333_333_333).abs() < 1e-6);
        // The FP finds the only GT of its frame taken by the TP scored 0.9: it
        // is unmatched at IoU 0.1 too, so it is not in the pose ranking.
        assert_all(&report, Category::Camera, &POSE_METRICS, 100.0);
        assert_eq!(report.classes[2].num_pred, 3);
        assert_eq!(report.classes[2].num_pred_pose, 2);
        // With the lowest score the FP costs nothing.
        let report = two_gt_one_fp(0.1, 0.7, mode);
        assert_all(&report, Category::Camera, &IOU_METRICS, 100.0);
    }
    assert_eq!(voc_ap(&[(0.9, true), (0.8, false), (0.7, true)], 2).map(|v| (v * 3.0 * 1e9).round()), Some(2.5e9));
}

#[test]
fn pose_recall_counts_only_ground_truth_passing_the_iou_gate() {
    // Reference quirk: a missed GT lowers IoU AP but not pose AP.
    let size = size_of(Category::Laptop);
    let a = gt(Category::Laptop, pose_at(-0.4, 0.0, 0.1), size, true);
    let b = gt(Category::Laptop, pose_at(0.4, 0.0, 0.5), size, true);
    for mode in MODES {
        let report = one_frame(&[a.clone(), b.clone()], &[pred_of(&a, 0.6)], &EvalConfig::standard(mode));
        assert_all(&report, Category::Laptop, &IOU_METRICS, 50.0);
        assert_all(&report, Category::Laptop, &POSE_METRICS, 100.0);
        let laptop = &report.classes[4];
        assert_eq!((laptop.num_gt, laptop.num_gt_pose), (2, 1));
    }
}

/// Identity-rotation box at `t`.
fn axis_pose(t: [f64; 3]) -> Pose {
    Pose::new(Mat3::identity(), Vec3::new(t[0], t[1], t[2]))
}

#[test]
fn iou_exactly_at_threshold_does_not_match() {
    // Extent 0.75 along x, shifted by 0.25: overlap 0.5 = 2/3 of the extent,
    // IoU = (2/3) / (4/3) = 0.5, exact in binary floating point.
    let size = [0.75, 0.25, 0.25];
    let g = gt(Category::Camera, axis_pose([0.0, 0.0, 1.0]), size, true);
    let p = pred(Category::Camera, 0.9, axis_pose([0.25, 0.0, 1.0]), size);
    assert_eq!(iou_3d(&p.camera_from_object, &size, &g.camera_from_object, &size, IouMode::Corrected), 0.5);
    let at = |t: f64| EvalConfig { iou_mode: IouMode::Corrected, iou_thresholds: vec![t], pose_thresholds: vec![] };
    let report = one_frame(std::slice::from_ref(&g), std::slice::from_ref(&p), &at(0.5));
    assert_eq!(report.class_ap(Category::Camera, "IoU50"), Some(0.0));
    let report = one_frame(std::slice::from_ref(&g), std::slice::from_ref(&p), &at(0.49));
    assert_eq!(report.class_ap(Category::Camera, "IoU49"), Some(100.0));
}

#[test]
fn published_iou_matches_hand_computation() {
    // A: identity, size (2, 4, 2) at (0, 0, 5): corner (sx, sy, sz) -> (sx, 2sy, 5+sz).
    // B: same size rotated 90 deg about z: corner -> (-2sy, sx, 5+sz).
    // Per corner the max is the z coordinate; the mins are min(sx, 2sy) for A
    // and min(-2sy, sx) for B. Corners in order (+++, ++-, -++, -+-, +-+, +--, --+, ---):
    //   A extents 5 3 7 5 8 6 8 6   (product 1_209_600)
    //   B extents 8 6 8 6 5 3 7 5   (product 1_209_600)
    //   overlap   5 3 7 5 5 3 7 5   (product 525^2 = 275_625)
    // IoU = 275_625 / (2 * 1_209_600 - 275_625) = 175 / 1361.
    let size = [2.0, 4.0, 2.0];
    let a = axis_pose([0.0, 0.0, 5.0]);
    let b = Pose::new(Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0), Vec3::new(0.0, 0.0, 5.0));
    let published = iou_3d(&a, &size, &b, &size, IouMode::Published);
    assert!((published - 175.0 / 1361.0).abs() < 1e-12, "{published}");
    // Corrected: boxes 2x4x2 and 4x2x2 sharing a 2x2x2 core: 8 / (16 + 16 - 8).
    let corrected = iou_3d(&a, &size, &b, &size, IouMode::Corrected);
    assert!((corrected - 1.0 / 3.0).abs() < 1e-12, "{corrected}");
    // Identity-aligned equal boxes: 1 in both modes.
    for mode in MODES {
        assert_eq!(iou_3d(&a, &size, &a, &size, mode), 1.0, "{mode}");
    }
}

#[test]
fn published_iou_of_disjoint_side_by_side_boxes_is_high() {
    // The reference flaw in numbers: two disjoint boxes 20 cm (or 50 cm) apart
    // at the same depth. Expected value from an independent plain-Python
    // evaluation of the per-corner formula.
    let size = [0.12, 0.09, 0.07];
    let a = axis_pose([0.0, 0.0, 0.7]);
    for dx in [0.2, 0.5] {
        let b = axis_pose([dx, 0.0, 0.7]);
        let published = iou_3d(&a, &size, &b, &size, IouMode::Published);
        assert!((published - 0.713_154_227_811_150_6).abs() < 1e-9, "{published}");
        assert_eq!(iou_3d(&a, &size, &b, &size, IouMode::Corrected), 0.0);
    }
}

#[test]
fn iou_translation_invariance() {
    let sa = [0.12, 0.09, 0.07];
    let sb = [0.1, 0.1, 0.08];
    let a = pose_at(0.03, -0.02, 0.4);
    let b = Pose::new(rotation_axis_angle(&Vec3::new(0.2, 1.0, -0.3), 0.7), Vec3::new(0.05, 0.0, 0.72));
    let moved = |p: &Pose, d: Vec3| Pose::new(p.rotation, p.translation_m + d);
    let iou = |a: &Pose, b: &Pose, mode| iou_3d(a, &sa, b, &sb, mode);
    for mode in MODES {
        assert!(iou(&a, &b, mode) > 0.1, "{mode}");
        // A shift along (1, 1, 1) moves every coordinate alike: both modes invariant.
        let d = Vec3::new(0.25, 0.25, 0.25);
        assert!((iou(&a, &b, mode) - iou(&moved(&a, d), &moved(&b, d), mode)).abs() < 1e-12, "{mode}");
    }
    // Any translation: the corrected IoU is invariant ...
    let d = Vec3::new(0.3, -0.2, 0.5);
    let c0 = iou(&a, &b, IouMode::Corrected);
    assert!((c0 - iou(&moved(&a, d), &moved(&b, d), IouMode::Corrected)).abs() < 1e-12);
    // ... and so is it under a rotation keeping the camera axes aligned (90 deg about z) ...
    let rz = Pose::new(Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0), Vec3::zeros());
    assert!((c0 - iou(&rz.compose(&a), &rz.compose(&b), IouMode::Corrected)).abs() < 1e-12);
    // ... while the published IoU depends on where the pair sits (the reference flaw).
    let p0 = iou(&a, &b, IouMode::Published);
    assert!((p0 - iou(&moved(&a, d), &moved(&b, d), IouMode::Published)).abs() > 1e-3);
}

#[test]
fn symmetric_iou_takes_best_of_twenty_steps() {
    let size = size_of(Category::Can);
    let g = pose_at(0.0, 0.0, 0.2);
    let p = Pose::new(g.rotation * rotation_y(f64::to_radians(36.0)), g.translation_m);
    for mode in MODES {
        let sym = symmetric_iou_3d((&p, &size), (&g, &size), true, mode);
        let plain = symmetric_iou_3d((&p, &size), (&g, &size), false, mode);
        assert!((sym - 1.0).abs() < 1e-9, "{mode}: {sym}");
        assert!(plain < sym - 1e-3, "{mode}: {plain}");
    }
}

#[test]
fn classes_without_ground_truth_are_null_and_left_out_of_the_mean() {
    let cam = gt(Category::Camera, pose_at(0.0, 0.0, 0.3), size_of(Category::Camera), true);
    let laptop = gt(Category::Laptop, pose_at(0.4, 0.0, 0.3), size_of(Category::Laptop), true);
    let stray_mug = pred(Category::Mug, 0.7, pose_at(-0.4, 0.0, 0.0), size_of(Category::Mug));
    for mode in MODES {
        let report = one_frame(
            &[cam.clone(), laptop.clone()],
            &[pred_of(&cam, 0.9), stray_mug.clone()],
            &EvalConfig::standard(mode),
        );
        for m in IOU_METRICS.iter().chain(&POSE_METRICS) {
            assert_eq!(report.class_ap(Category::Camera, m), Some(100.0));
            assert_eq!(report.class_ap(Category::Laptop, m), Some(0.0), "GT without predictions is 0");
            for class in [Category::Bottle, Category::Bowl, Category::Can, Category::Mug] {
                assert_eq!(report.class_ap(class, m), None, "{class} {m}");
            }
            assert_eq!(report.mean(m), Some(50.0), "{m}");
        }
        assert_eq!(report.mean("IoU90"), None);
        let json = serde_json::to_value(&report).unwrap();
        assert_eq!(json["iou_mode"], mode.to_string());
        assert_eq!(json["metrics"][3], "5deg2cm");
        assert_eq!(json["classes"][5]["class"], "mug");
        assert_eq!(json["classes"][5]["num_pred"], 1);
        assert!(json["classes"][5]["ap"]["IoU25"].is_null());
        assert_eq!(json["classes"][4]["ap"]["10deg5cm"], 0.0);
        assert_eq!(json["mean"]["IoU50"], 50.0);
        let table = report.to_table();
        assert!(table.lines().next().is_some_and(|l| l.contains(&format!("IoU mode: {mode}"))), "{table}");
        let mug_row = table.lines().find(|l| l.starts_with("mug")).unwrap_or_default();
        assert_eq!(
            mug_row.split_whitespace().collect::<Vec<_>>(),
            ["mug", "0", "1", "-", "-", "-", "-", "-", "-", "-", "-", "-"]
        );
        let mean_row = table.lines().find(|l| l.starts_with("mean")).unwrap_or_default();
        assert_eq!(mean_row.split_whitespace().filter(|v| *v == "50.0").count(), 7, "{table}");
        assert!(table.contains("5°2cm") && table.contains("IoU75"), "{table}");
    }
}

#[test]
fn median_errors_are_those_of_the_objects_matched_at_the_gate() {
    // Cameras 7° and 1° off (and 3 cm / 1 cm), a third camera missed; the median of two is their mean.
    let size = size_of(Category::Camera);
    let cams: Vec<GtInstance> =
        (0..3).map(|k| gt(Category::Camera, pose_at(-0.3 + 0.3 * k as f64, 0.0, 0.2 * k as f64), size, true)).collect();
    let off = |g: &GtInstance, deg: f64, shift_m: f64, score: f64| {
        let r = rotation_axis_angle(&Vec3::new(0.2, 0.9, -0.4), deg.to_radians()) * g.camera_from_object.rotation;
        pred(
            Category::Camera,
            score,
            Pose::new(r, g.camera_from_object.translation_m + Vec3::new(shift_m, 0.0, 0.0)),
            size,
        )
    };
    // A mug with its handle hidden, turned 40° about its axis: symmetric, so 0°; a lower-scoring
    // duplicate 30° off does not count (the object was taken by the first).
    let mug = gt(Category::Mug, pose_at(0.0, 0.3, 0.5), size_of(Category::Mug), false);
    let mug_pred = {
        let mut p = pred_of(&mug, 0.9);
        p.camera_from_object.rotation *= rotation_y(40f64.to_radians());
        p
    };
    let mug_dup = off(&mug, 30.0, 0.0, 0.5);
    let mug_dup = PredInstance { class: Category::Mug, size_m: mug.size_m, ..mug_dup };
    // A laptop whose prediction is far away: no pair passes the gate.
    let laptop = gt(Category::Laptop, pose_at(0.4, 0.4, 0.0), size_of(Category::Laptop), true);
    let far = pred(Category::Laptop, 0.9, pose_at(-2.0, 2.0, 0.0), size_of(Category::Laptop));
    let gts = vec![cams[0].clone(), cams[1].clone(), cams[2].clone(), mug.clone(), laptop];
    let preds = vec![off(&cams[0], 7.0, 0.03, 0.8), off(&cams[1], 1.0, 0.01, 0.7), mug_pred, mug_dup, far];
    for mode in MODES {
        let report = one_frame(&gts, &preds, &EvalConfig::standard(mode));
        let cam = &report.classes[2];
        assert_eq!(cam.num_gt_pose, 2, "{mode}");
        let (deg, cm) = (cam.median_rotation_deg.unwrap_or(f64::NAN), cam.median_translation_cm.unwrap_or(f64::NAN));
        assert!((deg - 4.0).abs() < 1e-9 && (cm - 2.0).abs() < 1e-9, "{mode}: {deg} {cm}");
        let mug_row = &report.classes[5];
        assert!(mug_row.median_rotation_deg.is_some_and(|d| d < 1e-6), "{mode}: {:?}", mug_row.median_rotation_deg);
        assert!(mug_row.median_translation_cm.is_some_and(|c| c < 1e-9));
        assert_eq!((report.classes[4].median_rotation_deg, report.classes[4].median_translation_cm), (None, None));
        assert_eq!(report.classes[0].median_rotation_deg, None, "no bottles");
        let json = serde_json::to_value(&report).unwrap();
        assert!((json["classes"][2]["median_rotation_deg"].as_f64().unwrap_or(f64::NAN) - 4.0).abs() < 1e-9);
        assert!(json["classes"][4]["median_translation_cm"].is_null());
        let table = report.to_table();
        let cam_row: Vec<&str> =
            table.lines().find(|l| l.starts_with("camera")).unwrap_or_default().split_whitespace().collect();
        assert_eq!(cam_row[cam_row.len() - 2..], ["4.0", "2.0"], "{table}");
    }
    // An odd count takes the middle value.
    let report = one_frame(
        &cams,
        &[off(&cams[0], 7.0, 0.0, 0.8), off(&cams[1], 1.0, 0.0, 0.7), off(&cams[2], 3.0, 0.0, 0.6)],
        &EvalConfig::default(),
    );
    assert!(report.classes[2].median_rotation_deg.is_some_and(|d| (d - 3.0).abs() < 1e-9));
}

#[test]
fn no_ground_truth_at_all_gives_no_mean() {
    let stray = pred(Category::Bowl, 0.7, pose_at(0.0, 0.0, 0.0), size_of(Category::Bowl));
    let report = one_frame(&[], &[stray], &EvalConfig::default());
    assert!(report.classes.iter().all(|c| c.ap.iter().all(|(_, v)| v.is_none())));
    assert_eq!(report.mean("IoU25"), None);
}

#[test]
fn custom_thresholds_become_metrics() {
    let cfg = EvalConfig {
        iou_mode: IouMode::Corrected,
        iou_thresholds: vec![0.1, 0.9],
        pose_thresholds: vec!["2deg1cm".parse::<PoseThreshold>().unwrap(), "15:10".parse().unwrap()],
    };
    assert!(cfg.validate().is_ok());
    let g = gt(Category::Camera, pose_at(0.0, 0.0, 0.3), size_of(Category::Camera), true);
    let mut p = pred_of(&g, 0.5);
    p.camera_from_object.translation_m += Vec3::new(0.015, 0.0, 0.0);
    let report = one_frame(&[g], &[p], &cfg);
    assert_eq!(report.metrics, ["IoU10", "IoU90", "2deg1cm", "15deg10cm"]);
    assert_eq!(report.class_ap(Category::Camera, "IoU10"), Some(100.0));
    assert_eq!(report.class_ap(Category::Camera, "2deg1cm"), Some(0.0));
    assert_eq!(report.class_ap(Category::Camera, "15deg10cm"), Some(100.0));
}

/// An in-memory recording: ids and optional ground truth per frame.
struct MockRecording {
    ids: Vec<String>,
    gt: Vec<Option<Vec<GtInstance>>>,
}

impl Recording for MockRecording {
    fn describe(&self) -> String {
        format!("mock recording, {} frames", self.ids.len())
    }
    fn len(&self) -> usize {
        self.ids.len()
    }
    fn frame_id(&self, index: usize) -> &str {
        &self.ids[index]
    }
    fn intrinsics(&self) -> Intrinsics {
        Intrinsics::REAL275
    }
    fn read_frame(&self, _index: usize) -> tricons::Result<RgbdFrame> {
        Err(tricons::Error::InvalidArgument("mock recording has no images".into()))
    }
    fn read_instances(&self, index: usize) -> tricons::Result<Option<Vec<GtInstance>>> {
        Ok(self.gt[index].clone())
    }
    fn read_annotations(&self, index: usize) -> tricons::Result<Option<FrameAnnotations>> {
        Ok(self.gt[index].clone().map(|instances| FrameAnnotations { instances, mask: None, nocs: None }))
    }
}

fn mock(gt_per_frame: Vec<Option<Vec<GtInstance>>>) -> MockRecording {
    MockRecording { ids: (0..gt_per_frame.len()).map(|i| format!("{i:06}")).collect(), gt: gt_per_frame }
}

fn frame_preds(id: &str, instances: Vec<PredInstance>) -> FramePredictions {
    FramePredictions { frame: id.into(), timestamp_s: None, instances }
}

/// Scenes scored together give one AP over all their frames (the reference code's dataset
/// AP), equal to scoring one recording that holds all the frames, and not the mean of the
/// scenes' own APs.
#[test]
fn recordings_scored_together_equal_one_recording_with_all_their_frames() {
    let (a, b) = (pose_at(0.0, 0.0, 0.2), pose_at(0.1, 0.0, 0.4));
    let (ga, gb) =
        (gt(Category::Can, a, size_of(Category::Can), true), gt(Category::Can, b, size_of(Category::Can), true));
    // scene 1: its object found with a low score, plus a confident false positive; scene 2:
    // its object found with a high score
    let fp = pred(Category::Can, 0.9, pose_at(-0.3, 0.1, 0.0), size_of(Category::Can));
    let s1 = mock(vec![Some(vec![ga.clone()])]);
    let s2 = mock(vec![Some(vec![gb.clone()])]);
    let p1 = vec![frame_preds("000000", vec![pred_of(&ga, 0.3), fp.clone()])];
    let p2 = vec![frame_preds("000000", vec![pred_of(&gb, 0.95)])];
    let whole =
        MockRecording { ids: vec!["a".into(), "b".into()], gt: vec![Some(vec![ga.clone()]), Some(vec![gb.clone()])] };
    let pw = vec![frame_preds("a", p1[0].instances.clone()), frame_preds("b", p2[0].instances.clone())];
    let cfg = EvalConfig::standard(IouMode::Corrected);
    let path = Path::new("p.jsonl");
    let together = evaluate_recordings(&[(&s1, &p1, path), (&s2, &p2, path)], &cfg).unwrap();
    let one = evaluate_recording(&whole, &pw, path, &cfg).unwrap();
    assert_eq!(serde_json::to_value(&together).unwrap(), serde_json::to_value(&one).unwrap());
    assert_eq!(together.frames_evaluated, 2);
    let mean_of_scenes = (evaluate_recording(&s1, &p1, path, &cfg).unwrap().class_ap(Category::Can, "IoU50").unwrap()
        + evaluate_recording(&s2, &p2, path, &cfg).unwrap().class_ap(Category::Can, "IoU50").unwrap())
        / 2.0;
    assert_ne!(together.class_ap(Category::Can, "IoU50"), Some(mean_of_scenes));
    // each scene's checks still name its predictions file
    let bad = vec![frame_preds("000009", vec![])];
    let err = evaluate_recordings(&[(&s1, &p1, path), (&s2, &bad, Path::new("s2.jsonl"))], &cfg).unwrap_err();
    assert!(err.to_string().contains("s2.jsonl"), "{err}");
}

#[test]
fn evaluate_recording_matches_frames_by_id() {
    let a = gt(Category::Can, pose_at(0.0, 0.0, 0.2), size_of(Category::Can), true);
    let b = gt(Category::Can, pose_at(0.1, 0.0, 0.4), size_of(Category::Can), true);
    let rec = mock(vec![Some(vec![a.clone()]), Some(vec![b.clone()]), Some(vec![])]);
    let path = Path::new("/tmp/pred.jsonl");
    // Frame 000001 has no prediction line: its GT counts as missed.
    let preds = vec![frame_preds("000002", vec![]), frame_preds("000000", vec![pred_of(&a, 0.8)])];
    let report = evaluate_recording(&rec, &preds, path, &EvalConfig::default()).unwrap();
    assert_eq!(report.frames_evaluated, 3);
    assert_eq!(report.classes[3].num_gt, 2);
    assert_eq!(report.class_ap(Category::Can, "IoU50"), Some(50.0));
    // Predictions in the wrong frame do not match.
    let swapped = vec![frame_preds("000001", vec![pred_of(&a, 0.8)]), frame_preds("000000", vec![pred_of(&b, 0.8)])];
    // (Corrected mode: the published IoU of side-by-side boxes at one depth is far from 0.)
    let cfg = EvalConfig::standard(IouMode::Corrected);
    let report = evaluate_recording(&rec, &swapped, path, &cfg).unwrap();
    assert_eq!(report.class_ap(Category::Can, "IoU25"), Some(0.0));
}

#[test]
fn evaluate_recording_errors_name_file_and_line() {
    let a = gt(Category::Can, pose_at(0.0, 0.0, 0.2), size_of(Category::Can), true);
    let rec = mock(vec![Some(vec![a.clone()]), Some(vec![])]);
    let path = Path::new("/tmp/run1/pred.jsonl");
    let cfg = EvalConfig::default();

    let unknown = vec![frame_preds("000000", vec![]), frame_preds("000007", vec![])];
    let err = evaluate_recording(&rec, &unknown, path, &cfg).unwrap_err();
    assert!(matches!(err, tricons::Error::Parse { line: Some(2), .. }), "{err:?}");
    let msg = err.to_string();
    assert!(msg.contains("/tmp/run1/pred.jsonl line 2") && msg.contains("000007"), "{msg}");

    let twice = vec![frame_preds("000001", vec![]), frame_preds("000000", vec![]), frame_preds("000001", vec![])];
    let msg = evaluate_recording(&rec, &twice, path, &cfg).unwrap_err().to_string();
    assert!(msg.contains("pred.jsonl line 3") && msg.contains("twice") && msg.contains("line 1"), "{msg}");

    let no_gt = mock(vec![Some(vec![a]), None]);
    let msg = evaluate_recording(&no_gt, &[], path, &cfg).unwrap_err().to_string();
    assert!(msg.contains("000001") && msg.contains("no ground truth"), "{msg}");

    let bad_cfg = EvalConfig { iou_thresholds: vec![0.5, 0.5], ..EvalConfig::default() };
    assert!(matches!(evaluate_recording(&rec, &[], path, &bad_cfg), Err(tricons::Error::InvalidArgument(_))));
}
