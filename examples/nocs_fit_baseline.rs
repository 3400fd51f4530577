//! Pose recovery from ground-truth NOCS maps + sensor depth, as predictions.
//!
//! This is what the NOCS-layout reader does to obtain REAL275 poses (the
//! dataset keeps its own in Python pickles). Run on a SynthNOCS recording,
//! whose true poses are known, `tricons eval` then measures how accurate that
//! recovery is under the sensor model: an upper bound for any method that
//! predicts NOCS maps and fits them to depth.
//!
//! ```sh
//! cargo run --release --example nocs_fit_baseline -- data/synthnocs-test > fit.jsonl
//! cargo run --release -- eval --gt data/synthnocs-test --pred fit.jsonl
//! ```

use anyhow::{Context, Result, bail};
use rayon::prelude::*;
use std::io::Write;
use tricons::output::predictions::{FramePredictions, PredInstance, to_json_line};
use tricons::recording::nocs_layout::recover_instances;
use tricons::recording::open_recording;

fn main() -> Result<()> {
    let Some(path) = std::env::args().nth(1) else {
        bail!("usage: nocs_fit_baseline RECORDING > predictions.jsonl");
    };
    let rec = open_recording(path.as_ref())?;
    let lines: Vec<Result<String>> = (0..rec.len())
        .into_par_iter()
        .map(|i| {
            let id = rec.frame_id(i);
            let ann = rec.read_annotations(i)?.with_context(|| format!("frame {id} has no ground truth"))?;
            let (Some(mask), Some(nocs)) = (&ann.mask, &ann.nocs) else {
                bail!("frame {id} has no mask or NOCS map");
            };
            let frame = rec.read_frame(i)?;
            let meta: Vec<_> = ann.instances.iter().map(|g| (g.id, g.class)).collect();
            let fitted = recover_instances(&meta, mask, nocs, &frame.depth, &frame.intrinsics)?;
            let instances = fitted.iter().map(PredInstance::from_ground_truth).collect();
            Ok(to_json_line(&FramePredictions { frame: id.to_string(), timestamp_s: None, instances }))
        })
        .collect();
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    for line in lines {
        writeln!(out, "{}", line?)?;
    }
    Ok(out.flush()?)
}
