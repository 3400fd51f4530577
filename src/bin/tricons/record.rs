//! `tricons record`: write frames from a camera (or a recording) as a recording.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use tricons::pipeline::{DEFAULT_BACKOFF_INITIAL, DEFAULT_BACKOFF_MAX, StopHandle, reopen_with_backoff};
use tricons::recording::{Manifest, RecordingWriter, WriteMode};

use crate::source_args::{BagTopicArgs, SourceArgs, stop_on_signals};

/// Arguments of `tricons record`.
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    tricons record --color /dev/video4 --depth /dev/video0 --camera camera.json --out data/rec1 --duration 30\n  \
    tricons record --recording data/nocs-real/scene_1 --rate max --out data/scene_1   # convert to the tricons format\n  \
    tricons record --color /dev/video4 --depth /dev/video0 --camera camera.json --out data/rec1 --append --skip-bad-frames\n\n\
    Depth is registered to colour before it is written; the camera config goes into the manifest.\n\
    Every frame is written atomically; Ctrl-C (or SIGTERM) stops with every completed frame on disk.")]
pub struct Args {
    #[command(flatten)]
    source: SourceArgs,
    #[command(flatten)]
    bag: BagTopicArgs,
    /// Output recording directory.
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Stop after this many frames.
    #[arg(long)]
    frames: Option<u64>,
    /// Stop after this many seconds.
    #[arg(long, value_name = "SECS")]
    duration: Option<f64>,
    /// Add the frames to the recording already in --out (same camera; nothing already
    /// there is overwritten). Without it --out must be missing or empty.
    #[arg(long)]
    append: bool,
    /// Count a frame the source could not deliver (logged), reopen the source and go on;
    /// without it such a frame ends the recording with an error (what was written is kept).
    #[arg(long)]
    skip_bad_frames: bool,
    /// Keep a replayed recording's ground truth.
    #[arg(long)]
    annotations: bool,
}

pub fn run(args: Args) -> Result<()> {
    let mut source = args.source.open(args.annotations, &args.bag)?;
    let camera = source.camera();
    let mut manifest = Manifest::new(camera.color, camera.depth_scale_m);
    if !camera.is_registered() {
        manifest.depth_intrinsics = Some(camera.depth);
        manifest.color_from_depth = Some(camera.color_from_depth);
    }
    manifest.source = Some(format!("tricons record: {}", source.describe()));
    let mode = if args.append { WriteMode::Append } else { WriteMode::New };
    let mut writer = RecordingWriter::create(&args.out, manifest, mode)
        .with_context(|| format!("creating the recording {} (--append to add to it)", args.out.display()))?;
    // ids follow the source's sequence numbers (a gap is a frame the camera dropped),
    // after what the directory holds and never backwards (a reopened source restarts them)
    let first_id = writer.next_numeric_id()?;
    let mut next_id = first_id;
    let already = writer.len();
    let mut lost = 0u64;
    let mut failure = None;
    let stop = StopHandle::default();
    stop_on_signals(stop.clone())?;
    let deadline = args.duration.map(|s| Instant::now() + Duration::from_secs_f64(s.max(0.0)));
    let bar = crate::progress::spinner("record");
    log::info!("recording {} -> {}", source.describe(), args.out.display());
    while !stop.is_stopped()
        && args.frames.is_none_or(|n| ((writer.len() - already) as u64) < n)
        && deadline.is_none_or(|d| Instant::now() < d)
    {
        match source.next_frame() {
            Ok(Some(f)) => {
                let n = next_id.max(first_id + f.seq);
                next_id = n + 1;
                let id = format!("{n:06}");
                if let Err(e) = writer.write_frame(&id, &f.frame, f.annotations.as_ref()) {
                    failure = Some(anyhow::Error::new(e).context(format!("writing frame {id}")));
                    break;
                }
                bar.inc(1);
            }
            Ok(None) => break,
            Err(e) if args.skip_bad_frames => {
                lost += 1;
                log::warn!("source error: {e}; frame lost ({lost} so far, --skip-bad-frames); reopening");
                if !reopen_with_backoff(source.as_mut(), &stop, DEFAULT_BACKOFF_INITIAL, DEFAULT_BACKOFF_MAX) {
                    break;
                }
            }
            Err(e) => {
                failure = Some(anyhow::Error::new(e).context("the source lost a frame (--skip-bad-frames to go on)"));
                break;
            }
        }
    }
    bar.finish_and_clear();
    let n = writer.len() - already;
    // what was written stays listed, whatever ended the recording
    writer.finish()?;
    log::info!("{n} frames written to {}", args.out.display());
    if lost > 0 {
        log::warn!("{lost} frames lost (--skip-bad-frames)");
    }
    match failure {
        Some(e) => Err(e.context(format!("{n} frames were written to {} before it", args.out.display()))),
        None => Ok(()),
    }
}
