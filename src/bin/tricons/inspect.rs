//! `tricons inspect`: what a recording holds.

use anyhow::{Context, Result};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::PathBuf;
use tricons::Category;
use tricons::output::predictions::{FramePredictions, PredInstance, to_json_line};
use tricons::recording::open_recording;

/// Arguments of `tricons inspect`.
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  tricons inspect data/synthnocs-test\n  \
    tricons inspect data/synthnocs-test --predictions > gt.jsonl   # ground truth as predictions (score 1)\n  \
    tricons inspect ~/NOCS/real_test/scene_1 --frames")]
pub struct Args {
    /// Recording directory (tricons format or NOCS dataset layout).
    recording: PathBuf,
    /// Print the ground truth in the predictions format (JSON Lines, score 1.0)
    /// instead of a summary: an oracle for testing `tricons eval`.
    #[arg(long)]
    predictions: bool,
    /// Also list every frame with its instances.
    #[arg(long)]
    frames: bool,
}

pub fn run(args: Args) -> Result<()> {
    let rec = open_recording(&args.recording)?;
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    if args.predictions {
        for i in 0..rec.len() {
            let instances = rec
                .read_instances(i)?
                .with_context(|| format!("frame {} of {} has no ground truth", rec.frame_id(i), rec.describe()))?;
            let frame = FramePredictions {
                frame: rec.frame_id(i).to_string(),
                timestamp_s: None,
                instances: instances.iter().map(PredInstance::from_ground_truth).collect(),
            };
            writeln!(out, "{}", to_json_line(&frame))?;
        }
        return Ok(out.flush()?);
    }

    let k = rec.intrinsics();
    writeln!(out, "{}", rec.describe())?;
    writeln!(out, "camera: {}x{}  fx {:.3} fy {:.3} cx {:.3} cy {:.3}", k.width, k.height, k.fx, k.fy, k.cx, k.cy)?;
    let mut per_class: BTreeMap<Category, usize> = BTreeMap::new();
    let (mut annotated, mut hidden_handles) = (0, 0);
    for i in 0..rec.len() {
        let instances = rec.read_instances(i)?;
        if let Some(list) = &instances {
            annotated += 1;
            for g in list {
                *per_class.entry(g.class).or_default() += 1;
                hidden_handles += usize::from(g.class == Category::Mug && !g.handle_visible);
            }
        }
        if args.frames {
            let desc = instances
                .map(|l| l.iter().map(|g| format!("{}#{}", g.class, g.id)).collect::<Vec<_>>().join(" "))
                .unwrap_or_else(|| "(no ground truth)".into());
            writeln!(out, "  {}  {}", rec.frame_id(i), desc)?;
        }
    }
    writeln!(out, "frames with ground truth: {annotated} of {}", rec.len())?;
    if !rec.is_empty() {
        let f = rec.read_frame(0)?;
        let valid = f.depth.data.iter().filter(|&&d| d != 0).count();
        writeln!(
            out,
            "first frame: depth scale {} m/unit, {:.1}% pixels with depth, t = {:.3} s",
            f.depth.depth_scale_m,
            100.0 * valid as f64 / f.depth.data.len() as f64,
            f.timestamp_s
        )?;
    }
    for (class, n) in &per_class {
        writeln!(out, "  {class:<7} {n:>6} instances")?;
    }
    if hidden_handles > 0 {
        writeln!(out, "  mugs with hidden handle: {hidden_handles}")?;
    }
    Ok(out.flush()?)
}
