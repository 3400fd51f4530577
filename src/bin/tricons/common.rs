//! What several commands share: the shipped files they default to, the thread count, the
//! mask source.

/// The shipped demo recording (four SynthNOCS-test frames).
pub const DEFAULT_RECORDING: &str = "tests/data/synthnocs-demo";
/// The shipped pose model's card.
pub const DEFAULT_MODEL: &str = "models/tricons-pose.card.json";
/// The shipped Mask R-CNN's card.
pub const DEFAULT_SEGMENTER: &str = "models/maskrcnn-light.card.json";

/// The cores this process may run on (affinity and cgroup limits included).
pub fn available_threads() -> usize {
    std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
}

/// Worker threads of the Mask R-CNN's matrix products when `--segmenter-threads` is not
/// given: tract's threaded products made the shipped graph slower at 2 threads than at 1
/// (docs/results.md, "Speed"), so the segmenter runs on one and the cores go to the pose
/// instances (and, in the service, to the stages running side by side).
pub const DEFAULT_SEGMENTER_THREADS: usize = 1;

/// `--threads`, or the cores available when it is not given (at least 1).
pub fn threads(flag: Option<usize>) -> usize {
    flag.unwrap_or_else(available_threads).max(1)
}

/// Where the instance masks come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MaskSource {
    /// The Mask R-CNN (--segmenter) on the colour image: the full pipeline.
    Model,
    /// The recording's ground-truth instance masks (isolates the pose model).
    Gt,
}
