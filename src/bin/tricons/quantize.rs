//! `tricons quantize`: post-training static int8 quantization from calibration frames.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Args as ClapArgs, ValueEnum};
use tricons::quant::calibrate::QuantizeOptions;
use tricons::quant::{QuantizeJob, RangeMethod, quantize};

use crate::progress;

/// How activation ranges are chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Method {
    /// Observed minimum and maximum.
    Minmax,
    /// Percentiles of the observed values (outlier-robust; see --percentile).
    Percentile,
}

/// Arguments of `tricons quantize`.
#[derive(ClapArgs, Debug)]
#[command(after_help = "Examples:\n  \
    tricons quantize --model models/tricons-pose.card.json --calibration calibration/synthnocs-calib \\\n      \
    --out models/tricons-pose.int8.json\n  \
    tricons quantize --model models/maskrcnn-light.card.json --calibration calibration/synthnocs-calib \\\n      \
    --out models/maskrcnn-light.int8.json\n\n\
    The output is a quantization profile: the float model stays as it is, the profile names it (path and \
    sha256) and the runtime applies it at load. Use the profile wherever a model is accepted, e.g. \
    `tricons replay --model models/tricons-pose.int8.json`; compare with `tricons validate`.")]
pub struct Args {
    /// The float model: a pose card (or graph with its card beside it), or a Mask R-CNN card or graph.
    #[arg(long)]
    model: PathBuf,
    /// Calibration recording (frames with ground truth; see calibration/README.md).
    #[arg(long)]
    calibration: PathBuf,
    /// Where to write the quantization profile (JSON).
    #[arg(long)]
    out: PathBuf,
    /// Activation range method.
    #[arg(long, value_enum, default_value_t = Method::Minmax)]
    method: Method,
    /// Upper percentile of --method percentile (the lower one is 100 minus it).
    #[arg(long, default_value_t = 99.99)]
    percentile: f64,
    /// Nodes whose input or weight quantization SQNR is below this (dB) stay float.
    #[arg(long, default_value_t = 20.0)]
    min_sqnr_db: f64,
    /// Keep nodes whose name contains this in float (repeatable).
    #[arg(long)]
    keep_float: Vec<String>,
    /// Keep this many nodes float: those whose quantization alone changes the outputs most on
    /// calibration samples (pose models; one model build per int8 node).
    #[arg(long, default_value_t = 0)]
    sensitivity: usize,
    /// Every int8 node writes floats (no u7 hand-over between consecutive int8 layers).
    #[arg(long)]
    no_chain: bool,
    /// Use at most this many calibration frames.
    #[arg(long)]
    frames: Option<usize>,
    /// Pose model: segmenter giving the masks of frames without ground truth.
    #[arg(long)]
    segmenter: Option<PathBuf>,
    /// Pose model: seed of the point sampling.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

/// Run `tricons quantize`.
pub fn run(args: Args) -> Result<()> {
    if !(args.percentile > 50.0 && args.percentile <= 100.0) {
        anyhow::bail!("--percentile must be in (50, 100], got {}", args.percentile);
    }
    let range = match args.method {
        Method::Minmax => RangeMethod::MinMax,
        Method::Percentile => RangeMethod::Percentile { percentile: args.percentile },
    };
    let job = QuantizeJob {
        model: args.model.clone(),
        calibration: args.calibration.clone(),
        out: args.out.clone(),
        max_frames: args.frames,
        segmenter: args.segmenter.clone(),
        seed: args.seed,
        options: QuantizeOptions {
            range,
            min_sqnr_db: args.min_sqnr_db,
            keep_float: args.keep_float.clone(),
            chain: !args.no_chain,
            sensitivity: args.sensitivity,
        },
    };
    let bar = progress::bar(0, "calibrate");
    let t = std::time::Instant::now();
    let profile = quantize(&job, &|done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })
    .with_context(|| format!("quantizing {}", args.model.display()))?;
    bar.finish_and_clear();
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    profile.write(&args.out)?;
    let chained = profile.nodes.iter().filter(|n| n.output_u7.is_some()).count();
    let fused: usize = profile.nodes.iter().map(|n| n.fuse.len()).sum();
    log::info!(
        "{} calibration runs over {} frames in {:.1} s; {} nodes int8 ({fused} followers fused, {chained} hand u7 \
         to the next), {} stay float -> {}",
        profile.calibration.runs,
        profile.calibration.frames,
        t.elapsed().as_secs_f64(),
        profile.nodes.len(),
        profile.float.len(),
        args.out.display()
    );
    for f in &profile.float {
        log::info!("float: {} ({}): {}", f.node, f.op, f.reason);
    }
    Ok(())
}
