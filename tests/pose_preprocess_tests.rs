//! The Rust preprocessing rebuilds, bit for bit, the inputs the PyTorch pipeline made for the
//! network fixtures (tests/fixtures/pose_net) from the demo recording's frames.

mod common;

use std::path::Path;

use common::npy::cases;
use tricons::pose::preprocess::{
    PreprocessConfig, build_input, crop_window, mask_bbox, prepare_instance, sample_indices,
};
use tricons::recording::open_recording;
use tricons::rng::Rng;

fn shipped_config() -> PreprocessConfig {
    let card: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("models/tricons-pose.card.json")).unwrap(),
    )
    .unwrap();
    let p = &card["preprocessing"];
    PreprocessConfig::new(p["n_points"].as_u64().unwrap() as usize, p["crop_size"].as_u64().unwrap() as usize)
}

#[test]
fn inputs_of_every_network_fixture_are_rebuilt_exactly() {
    let cfg = shipped_config();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let all = cases("pose_net");
    assert!(!all.is_empty());
    for case in &all {
        let rec = open_recording(&root.join(case.meta["recording"].as_str().unwrap())).unwrap();
        let fi = (0..rec.len()).find(|&i| rec.frame_id(i) == case.meta["frame"].as_str().unwrap()).unwrap();
        let frame = rec.read_frame(fi).unwrap();
        let ann = rec.read_annotations(fi).unwrap().unwrap();
        let id = case.meta["instance_id"].as_u64().unwrap() as u8;
        let mask: Vec<bool> = ann.mask.as_ref().unwrap().data.iter().map(|&v| v == id).collect();
        let prep = prepare_instance(&frame.depth, &mask, &cfg).unwrap();
        let w = &prep.window;
        let name = case.dir.display().to_string();
        assert_eq!(
            [w.rmin, w.rmax, w.cmin, w.cmax].map(|v| v as u64).to_vec(),
            case.meta["window"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect::<Vec<_>>(),
            "{name}: window"
        );
        assert_eq!(prep.n_valid() as u64, case.meta["n_valid"].as_u64().unwrap(), "{name}: valid pixels");
        let idx: Vec<usize> = case.get("sample_idx").i64().iter().map(|&i| i as usize).collect();
        let input = build_input(&frame.color, frame.depth.depth_scale_m, &frame.intrinsics, &prep, &idx, &cfg);
        assert_eq!(input.choose, case.get("choose").i64(), "{name}: choose");
        assert_eq!(input.pts, case.get("pts").f32(), "{name}: points (bit-exact)");
        assert_eq!(input.rgb, case.get("rgb").f32(), "{name}: rgb (bit-exact)");
    }
}

#[test]
fn crop_window_follows_ag_pose_and_stays_inside_the_image() {
    let cfg = PreprocessConfig::new(512, 96);
    // the worked example of tools/README.md: bbox rows 100..150, cols 200..260
    let w = crop_window((100, 150, 200, 260), 480, 640, &cfg);
    assert_eq!((w.rmin, w.rmax, w.cmin, w.cmax), (85, 165, 190, 270));
    // a box in the corner is shifted inside, not shrunk
    let w = crop_window((0, 30, 620, 640), 480, 640, &cfg);
    assert_eq!((w.rmin, w.rmax, w.cmin, w.cmax), (0, 40, 600, 640));
    // a huge box is capped at 440
    let w = crop_window((0, 480, 0, 640), 480, 640, &cfg);
    assert_eq!(w.side(), 440);
    let mut mask = vec![false; 8 * 6];
    assert_eq!(mask_bbox(&mask, 8), None);
    mask[8 + 2] = true;
    mask[4 * 8 + 5] = true;
    assert_eq!(mask_bbox(&mask, 8), Some((1, 5, 2, 6)));
}

#[test]
fn sampling_is_seeded_distinct_when_possible_and_covers_short_instances() {
    let a = sample_indices(1000, 512, &mut Rng::new(3));
    assert_eq!(a, sample_indices(1000, 512, &mut Rng::new(3)));
    assert_ne!(a, sample_indices(1000, 512, &mut Rng::new(4)));
    let mut s = a.clone();
    s.sort();
    s.dedup();
    assert_eq!(s.len(), 512);
    assert!(a.iter().all(|&i| i < 1000));
    let short = sample_indices(40, 512, &mut Rng::new(3));
    assert_eq!(short.len(), 512);
    assert!(short.iter().all(|&i| i < 40));
    let mut seen = short.clone();
    seen.sort();
    seen.dedup();
    assert!(seen.len() > 35, "draws with replacement reach most of the pixels");
}
