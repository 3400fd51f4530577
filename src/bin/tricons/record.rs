//! `tricons record`: write frames from a camera (or a recording) as a recording.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use tricons::pipeline::{DEFAULT_BACKOFF_INITIAL, DEFAULT_BACKOFF_MAX, StopHandle, reopen_with_backoff};
use tricons::recording::{Manifest, RecordingWriter};

use crate::source_args::{SourceArgs, stop_on_signals};

/// Arguments of `tricons record`.
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    tricons record --color /dev/video4 --depth /dev/video0 --camera camera.json --out data/rec1 --duration 30\n  \
    tricons record --recording data/nocs-real/scene_1 --rate max --out data/scene_1   # convert to the tricons format\n\n\
    Depth is registered to colour before it is written; the camera config goes into the manifest.\n\
    Every frame is written atomically; Ctrl-C (or SIGTERM) stops with every completed frame on disk.")]
pub struct Args {
    #[command(flatten)]
    source: SourceArgs,
    /// Output recording directory.
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Stop after this many frames.
    #[arg(long)]
    frames: Option<u64>,
    /// Stop after this many seconds.
    #[arg(long, value_name = "SECS")]
    duration: Option<f64>,
    /// Replace a recording already in --out.
    #[arg(long)]
    overwrite: bool,
    /// Keep a replayed recording's ground truth.
    #[arg(long)]
    annotations: bool,
}

pub fn run(args: Args) -> Result<()> {
    let mut source = args.source.open(args.annotations)?;
    let camera = source.camera();
    let mut manifest = Manifest::new(camera.color, camera.depth_scale_m);
    if !camera.is_registered() {
        manifest.depth_intrinsics = Some(camera.depth);
        manifest.color_from_depth = Some(camera.color_from_depth);
    }
    manifest.source = Some(format!("tricons record: {}", source.describe()));
    let mut writer = RecordingWriter::create(&args.out, manifest, args.overwrite)
        .with_context(|| format!("creating the recording {}", args.out.display()))?;
    let stop = StopHandle::default();
    stop_on_signals(stop.clone())?;
    let deadline = args.duration.map(|s| Instant::now() + Duration::from_secs_f64(s.max(0.0)));
    let bar = crate::progress::spinner("record");
    log::info!("recording {} -> {}", source.describe(), args.out.display());
    while !stop.is_stopped()
        && args.frames.is_none_or(|n| (writer.len() as u64) < n)
        && deadline.is_none_or(|d| Instant::now() < d)
    {
        match source.next_frame() {
            Ok(Some(f)) => {
                let id = format!("{:06}", f.seq);
                writer.write_frame(&id, &f.frame, f.annotations.as_ref())?;
                bar.inc(1);
            }
            Ok(None) => break,
            Err(e) => {
                log::warn!("source error: {e}; reopening");
                if !reopen_with_backoff(source.as_mut(), &stop, DEFAULT_BACKOFF_INITIAL, DEFAULT_BACKOFF_MAX) {
                    break;
                }
            }
        }
    }
    bar.finish_and_clear();
    let n = writer.len();
    writer.finish()?;
    log::info!("{n} frames written to {}", args.out.display());
    Ok(())
}
