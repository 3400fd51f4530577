//! `tricons synth`: render SynthNOCS frames.

use crate::progress;
use anyhow::{Result, bail};
use std::path::PathBuf;
use tricons::synth::{Split, SynthConfig, generate};

/// Arguments of `tricons synth`.
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    tricons synth --split test --out data/synthnocs-test        # the fixed 500-frame benchmark split\n  \
    tricons synth --split val --out data/synthnocs-val\n  \
    tricons synth --out data/train --frames 20000 --seed 7       # training data, any seed and size\n  \
    tricons synth --out data/train-dis --frames 4000 --seed 5 --max-distractors 8   # more no-objects\n  \
    tricons synth --out data/train-dis2 --frames 4000 --seed 9 --max-distractors 8 --distractor-masks   # and their masks\n\n\
    The same seed gives byte-identical files (same binary and platform). See docs/synthnocs.md.")]
pub struct Args {
    /// Output recording directory.
    #[arg(long)]
    out: PathBuf,
    /// A fixed split: `val` and `test` have fixed seeds and sizes; `train` takes --seed and --frames.
    #[arg(long)]
    split: Option<Split>,
    /// Number of frames (train split only).
    #[arg(long)]
    frames: Option<usize>,
    /// Random seed (train split only).
    #[arg(long)]
    seed: Option<u64>,
    /// Replace a recording already in --out.
    #[arg(long)]
    overwrite: bool,
    /// Fewest annotated objects per scene.
    #[arg(long, default_value_t = SynthConfig::default().min_objects)]
    min_objects: usize,
    /// Most annotated objects per scene.
    #[arg(long, default_value_t = SynthConfig::default().max_objects)]
    max_objects: usize,
    /// Most unannotated distractors (boxes, spheres, cylinders, tori) per scene; each scene
    /// draws 0 to this many. Training data with more teaches a segmenter what is no object.
    #[arg(long, default_value_t = SynthConfig::default().max_distractors)]
    max_distractors: usize,
    /// Render perfect depth (no sensor noise or holes).
    #[arg(long)]
    no_depth_noise: bool,
    /// Also write `{id}_distractors.png`, the visible distractors' mask (ids 1..=n), to
    /// train a segmenter's "other" class; the other files do not change.
    #[arg(long)]
    distractor_masks: bool,
}

pub fn run(args: Args) -> Result<()> {
    let split = args.split.unwrap_or(Split::Train);
    if split != Split::Train && (args.seed.is_some() || args.frames.is_some()) {
        bail!("the {split:?} split has a fixed seed and size; --seed and --frames apply to the train split only");
    }
    if args.min_objects == 0 || args.min_objects > args.max_objects {
        bail!("--min-objects must be at least 1 and at most --max-objects");
    }
    let seed = args.seed.unwrap_or(split.seed());
    let frames = args.frames.unwrap_or(split.default_frames());
    let cfg = SynthConfig {
        min_objects: args.min_objects,
        max_objects: args.max_objects,
        max_distractors: args.max_distractors,
        depth_noise: !args.no_depth_noise,
        distractor_masks: args.distractor_masks,
        ..SynthConfig::default()
    };
    let pb = progress::bar(frames, "rendering");
    let start = std::time::Instant::now();
    generate(&args.out, &cfg, seed, frames, args.overwrite, &|done| pb.set_position(done as u64))?;
    pb.finish_and_clear();
    log::info!(
        "wrote {frames} frames (seed {seed}) to {} in {:.1} s",
        args.out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
