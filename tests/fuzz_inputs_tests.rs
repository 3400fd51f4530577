//! Every fuzz harness (fuzz/harness/) on its seed corpus and on the inputs fuzzing once
//! found a bug with (fuzz/regressions/TARGET/): the same code the libFuzzer targets
//! run, without the sanitizer build, so CI replays each input on every commit.

#[path = "../fuzz/harness/scratch.rs"]
mod scratch;
#[path = "../fuzz/harness/tiny_frame.rs"]
mod tiny_frame;

#[path = "../fuzz/harness/annotations.rs"]
mod annotations;
#[path = "../fuzz/harness/camera_config.rs"]
mod camera_config;
#[path = "../fuzz/harness/http_request.rs"]
mod http_request;
#[path = "../fuzz/harness/manifest.rs"]
mod manifest;
#[path = "../fuzz/harness/model_card.rs"]
mod model_card;
#[path = "../fuzz/harness/nocs_meta.rs"]
mod nocs_meta;
#[path = "../fuzz/harness/onnx_graph.rs"]
mod onnx_graph;
#[path = "../fuzz/harness/png.rs"]
mod png;
#[path = "../fuzz/harness/predictions.rs"]
mod predictions;
#[path = "../fuzz/harness/quant_profile.rs"]
mod quant_profile;
#[cfg(feature = "ros2")]
#[path = "../fuzz/harness/ros2_bag.rs"]
mod ros2_bag;
#[path = "../fuzz/harness/segment_results.rs"]
mod segment_results;
#[path = "../fuzz/harness/segmenter_card.rs"]
mod segmenter_card;
#[path = "../fuzz/harness/v4l2_decode.rs"]
mod v4l2_decode;

use std::path::{Path, PathBuf};

type Harness = fn(&[u8]);

const HARNESSES: &[(&str, Harness)] = &[
    ("annotations", annotations::run),
    ("camera_config", camera_config::run),
    ("http_request", http_request::run),
    ("manifest", manifest::run),
    ("model_card", model_card::run),
    ("nocs_meta", nocs_meta::run),
    ("onnx_graph", onnx_graph::run),
    ("png", png::run),
    ("predictions", predictions::run),
    ("quant_profile", quant_profile::run),
    #[cfg(feature = "ros2")]
    ("ros2_bag", ros2_bag::run),
    ("segment_results", segment_results::run),
    ("segmenter_card", segmenter_card::run),
    ("v4l2_decode", v4l2_decode::run),
];

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The seed and regression inputs of `target`: fuzz/seeds.txt's shipped files,
/// fuzz/seeds/TARGET/* and fuzz/regressions/TARGET/*.
fn inputs(target: &str) -> Vec<PathBuf> {
    let list = std::fs::read_to_string(root().join("fuzz/seeds.txt")).unwrap();
    let mut paths: Vec<PathBuf> = list
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .filter_map(|l| l.split_once(' '))
        .filter(|(t, _)| *t == target)
        .map(|(_, p)| root().join(p.trim()))
        .collect();
    for dir in ["fuzz/seeds", "fuzz/regressions"] {
        if let Ok(entries) = std::fs::read_dir(root().join(dir).join(target)) {
            paths.extend(entries.map(|e| e.unwrap().path()).filter(|p| p.is_file()));
        }
    }
    paths.sort();
    paths
}

#[test]
fn every_harness_survives_its_seeds_and_regressions() {
    for &(target, run) in HARNESSES {
        let paths = inputs(target);
        assert!(!paths.is_empty(), "{target}: no seed inputs");
        for path in paths {
            let data = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            run(&data);
            // Truncations too: every parser meets cut-off files in practice.
            for cut in [0, 1, data.len() / 2, data.len().saturating_sub(1)] {
                run(&data[..cut.min(data.len())]);
            }
        }
    }
    std::fs::remove_dir_all(scratch::dir()).unwrap();
}

#[test]
fn every_fuzz_target_has_a_harness_and_a_cargo_entry() {
    let manifest = std::fs::read_to_string(root().join("fuzz/Cargo.toml")).unwrap();
    let targets: Vec<&str> = HARNESSES.iter().map(|h| h.0).collect();
    // Targets whose harness needs a feature this build lacks (the aarch64 qemu suite is
    // built without `ros2`); the host's default build replays them.
    let gated: &[&str] = if cfg!(feature = "ros2") { &[] } else { &["ros2_bag"] };
    let mut found = 0;
    for entry in std::fs::read_dir(root().join("fuzz/fuzz_targets")).unwrap() {
        let name = entry.unwrap().path().file_stem().unwrap().to_string_lossy().into_owned();
        assert!(manifest.contains(&format!("path = \"fuzz_targets/{name}.rs\"")), "{name} missing in fuzz/Cargo.toml");
        if gated.contains(&name.as_str()) {
            continue;
        }
        assert!(targets.contains(&name.as_str()), "fuzz target {name} is not replayed here");
        found += 1;
    }
    assert_eq!(found, targets.len());
}

/// The shipped files parse: the seeds exercise the success paths, not only errors.
#[test]
fn the_shipped_seed_files_are_accepted() {
    let path = |p: &str| root().join(p);
    tricons::pose::card::ModelCard::read(&path("models/tricons-pose.card.json")).unwrap();
    tricons::segment::SegmenterCard::read(&path("models/maskrcnn-light.card.json")).unwrap();
    tricons::quant::QuantProfile::read(&path("models/tricons-pose.int8.json")).unwrap();
    tricons::capture::CameraConfig::read(&path("docs/deploy/camera.example.json")).unwrap();
    tricons::recording::Manifest::read(&path("tests/data/synthnocs-demo/manifest.json")).unwrap();
    let seeds = inputs("predictions");
    assert!(tricons::output::read_predictions(&seeds[0]).unwrap().len() == 2);
    #[cfg(feature = "ros2")]
    for seed in inputs("ros2_bag").into_iter().filter(|p| !p.starts_with(root().join("fuzz/regressions"))) {
        use tricons::recording::{BagTopics, McapBag, Recording};
        let topics =
            BagTopics { color: "/c".into(), depth: "/d".into(), camera_info: "/i".into(), ..BagTopics::default() };
        let bag = McapBag::open(&seed, &topics).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(bag.len(), 2, "{}", seed.display());
        for i in 0..2 {
            let frame = bag.read_frame(i).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!((frame.color.width, frame.depth.data[0]), (4, 500), "{}", seed.display());
        }
    }
}
