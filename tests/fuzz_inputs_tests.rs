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

/// Mutated inputs per target in the smoke run below (`TRICONS_FUZZ_SMOKE=N` for more).
const SMOKE_MUTATIONS: usize = 48;

/// One test, because the harnesses share the process's scratch directory: the seeds and
/// regressions, their truncations, then a fuzz smoke run.
///
/// The smoke run is CI's fuzzing: libFuzzer's instrumented build of the 14 targets takes
/// most of an hour of a core here (docs/results.md "Fuzzing"), more than CI's time, so CI
/// runs the same harnesses on `SMOKE_MUTATIONS` deterministic mutations of their seeds per
/// target instead (bit flips, boundary values in 1-8 byte fields, deletions, duplications,
/// insertions, splices of two seeds; seeded by the target name, so a failure reproduces).
/// It finds what a shallow mutation finds, without coverage guidance; `fuzz/run.sh` is the
/// coverage-guided run. A panicking input is written to the temporary directory and named.
#[test]
fn every_harness_survives_its_seeds_regressions_and_a_mutation_smoke_run() {
    let mutations = std::env::var("TRICONS_FUZZ_SMOKE").ok().and_then(|v| v.parse().ok()).unwrap_or(SMOKE_MUTATIONS);
    for &(target, run) in HARNESSES {
        let paths = inputs(target);
        assert!(!paths.is_empty(), "{target}: no seed inputs");
        let mut seeds = Vec::new();
        for path in paths {
            let data = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            run(&data);
            // Truncations too: every parser meets cut-off files in practice.
            for cut in [0, 1, data.len() / 2, data.len().saturating_sub(1)] {
                run(&data[..cut.min(data.len())]);
            }
            seeds.push(data);
        }
        let mut rng = mutate::Rng::for_target(target);
        for i in 0..mutations {
            let data = mutate::mutated(&seeds, &mut rng);
            if std::panic::catch_unwind(|| run(&data)).is_err() {
                let kept = std::env::temp_dir().join(format!("tricons-fuzz-smoke-{target}-{i}.bin"));
                std::fs::write(&kept, &data).unwrap();
                panic!("{target}: mutation {i} panicked; the input is {}", kept.display());
            }
        }
    }
    std::fs::remove_dir_all(scratch::dir()).unwrap();
}

/// The smoke run's mutator: a few stacked edits of one seed, as libFuzzer's default
/// mutations do, from a seeded generator.
mod mutate {
    /// SplitMix64.
    pub struct Rng(u64);

    impl Rng {
        /// Seeded by an FNV-1a hash of the target name.
        pub fn for_target(target: &str) -> Self {
            Self(target.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)))
        }

        pub fn next(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            z ^ (z >> 31)
        }

        /// Uniform in `0..n` (`n > 0`; the modulo bias is irrelevant here).
        pub fn below(&mut self, n: usize) -> usize {
            (self.next() % n as u64) as usize
        }
    }

    /// Values at the edges of 8-64 bit fields (sizes, counts, offsets).
    const BOUNDARY: [u64; 10] = [0, 1, 0x7f, 0x80, 0xff, 0x7fff, 0xffff, 0x7fff_ffff, 0xffff_ffff, u64::MAX];

    pub fn mutated(seeds: &[Vec<u8>], rng: &mut Rng) -> Vec<u8> {
        let mut data = seeds[rng.below(seeds.len())].clone();
        for _ in 0..1 + rng.below(4) {
            let len = data.len();
            match rng.below(7) {
                0 if len > 0 => {
                    let at = rng.below(len);
                    data[at] ^= 1 << rng.below(8);
                }
                1 if len > 0 => {
                    let width = [1, 2, 4, 8][rng.below(4)].min(len);
                    let at = rng.below(len - width + 1);
                    let value = BOUNDARY[rng.below(BOUNDARY.len())];
                    let bytes = if rng.below(2) == 0 { value.to_le_bytes() } else { value.to_be_bytes() };
                    data[at..at + width].copy_from_slice(&bytes[..width]);
                }
                2 if len > 0 => {
                    let at = rng.below(len);
                    let n = 1 + rng.below((len - at).min(64));
                    data.drain(at..at + n);
                }
                3 if len > 0 => {
                    let at = rng.below(len);
                    let n = 1 + rng.below((len - at).min(64));
                    let copy = data[at..at + n].to_vec();
                    let to = rng.below(len + 1);
                    data.splice(to..to, copy);
                }
                4 => {
                    let to = rng.below(len + 1);
                    let n = 1 + rng.below(16);
                    let bytes: Vec<u8> = (0..n).map(|_| rng.next() as u8).collect();
                    data.splice(to..to, bytes);
                }
                5 => {
                    // the head of this input, the tail of another seed
                    let other = &seeds[rng.below(seeds.len())];
                    let cut = rng.below(len + 1);
                    let from = rng.below(other.len() + 1);
                    data.truncate(cut);
                    data.extend_from_slice(&other[from..]);
                }
                _ => {
                    let at = rng.below(len + 1);
                    data[at..].iter_mut().for_each(|b| *b = b.wrapping_add(1));
                }
            }
        }
        data
    }
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
