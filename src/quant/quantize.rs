//! `tricons quantize` as a library call: run the float model over a calibration
//! recording through its real preprocessing (pose: ground-truth or segmenter masks,
//! the runtime's point sampling and crops, custom ops included; segmenter: whole
//! images), collect the candidates' activation statistics and build the profile.

use std::path::{Path, PathBuf};

use tract_onnx::prelude::*;

use std::collections::HashMap;

use tract_onnx::pb::ModelProto;

use super::calibrate::{
    ProfileTarget, QuantizeOptions, StatsCollector, build_profile, keep_most_sensitive_float, output_error,
    single_node_profile,
};
use super::params::TensorStats;
use super::profile::{CalibrationInfo, ModelKind, QuantProfile};
use crate::error::{Error, Result};
use crate::pose::PoseEstimator;
use crate::recording::{Recording, open_recording};
use crate::segment::Segmenter;

/// What to quantize and with which data.
#[derive(Clone, Debug)]
pub struct QuantizeJob {
    /// The float model: a pose card/graph or a segmenter card/graph.
    pub model: PathBuf,
    /// The calibration recording.
    pub calibration: PathBuf,
    /// Where the profile will be written (the model path is stored relative to it).
    pub out: PathBuf,
    /// Use at most this many frames (all when `None`).
    pub max_frames: Option<usize>,
    /// Pose only: masks for frames without ground truth come from this segmenter.
    pub segmenter: Option<PathBuf>,
    /// Pose only: seed of the point sampling.
    pub seed: u64,
    /// Range method, SQNR floor, forced-float nodes, chaining.
    pub options: QuantizeOptions,
}

/// Which runtime model `path` is: a pose card (or graph with its card) or a segmenter.
pub fn model_kind(path: &Path) -> ModelKind {
    let card = crate::pose::card::card_path_for(path);
    if crate::pose::ModelCard::read(&card).is_ok() { ModelKind::Pose } else { ModelKind::Segmenter }
}

/// Run the calibration and build the profile (not written; see [`QuantProfile::write`]).
/// `progress(done, total)` is called after every frame.
pub fn quantize(job: &QuantizeJob, progress: &dyn Fn(usize, usize)) -> Result<QuantProfile> {
    let rec = open_recording(&job.calibration)?;
    let frames = job.max_frames.map_or(rec.len(), |m| m.min(rec.len()));
    if frames == 0 {
        return Err(Error::InvalidArgument(format!("calibration set {}: no frames", job.calibration.display())));
    }
    let kind = model_kind(&job.model);
    let (proto, stats, runs, sha, samples) = match kind {
        ModelKind::Pose => calibrate_pose(job, rec.as_ref(), frames, progress)?,
        ModelKind::Segmenter => calibrate_segmenter(job, rec.as_ref(), frames, progress)?,
    };
    if runs == 0 {
        return Err(Error::InvalidArgument(format!(
            "calibration set {}: none of its {frames} frames is usable ({})",
            job.calibration.display(),
            match kind {
                ModelKind::Pose =>
                    "no frame has an instance with enough valid depth; frames without ground-truth \
                                    masks need --segmenter",
                ModelKind::Segmenter => "no image could be read",
            }
        )));
    }
    let graph = proto.graph.as_ref().ok_or_else(|| Error::model(&job.model, "the file holds no graph"))?;
    let target = ProfileTarget { kind, model: relative_to(&job.model, &job.out), onnx_sha256: sha };
    let info = CalibrationInfo { data: job.calibration.display().to_string(), frames, runs };
    let mut profile = build_profile(target, graph, &stats, &job.options, info)?;
    if job.options.sensitivity > 0 {
        if kind != ModelKind::Pose {
            return Err(Error::InvalidArgument("--sensitivity works on pose models only".into()));
        }
        let errors = pose_sensitivity(job, &proto, &profile, &samples, progress)?;
        let chain = job.options.chain;
        keep_most_sensitive_float(&mut profile, graph, &errors, job.options.sensitivity, chain);
    }
    Ok(profile)
}

/// Calibration instances kept for the sensitivity runs.
const SENSITIVITY_SAMPLES: usize = 8;

/// Per profile node, the output error when it alone runs in int8.
fn pose_sensitivity(
    job: &QuantizeJob,
    proto: &ModelProto,
    profile: &QuantProfile,
    samples: &[TVec<TValue>],
    progress: &dyn Fn(usize, usize),
) -> Result<Vec<f64>> {
    let estimator = PoseEstimator::load(&job.model)?;
    let run = |plan: &std::sync::Arc<TypedRunnableModel>, x: &TVec<TValue>| {
        plan.run(x.clone()).map_err(|e| Error::Inference(format!("{e:#}")))
    };
    let float = estimator.plan_variant(proto)?;
    let want: Vec<TVec<TValue>> = samples.iter().map(|x| run(&float, x)).collect::<Result<_>>()?;
    let mut errors = Vec::with_capacity(profile.nodes.len());
    for i in 0..profile.nodes.len() {
        let mut one = proto.clone();
        crate::quant::rewrite::apply(&mut one, &single_node_profile(profile, i))
            .map_err(|m| Error::model(&job.model, m))?;
        let plan = estimator.plan_variant(&one)?;
        let mut e = 0.0;
        for (x, w) in samples.iter().zip(&want) {
            e += output_error(w, &run(&plan, x)?);
        }
        errors.push(e / samples.len().max(1) as f64);
        progress(i + 1, profile.nodes.len());
    }
    Ok(errors)
}

/// Graph, statistics by tensor, runs, graph sha256, the first runs' inputs.
type Calibrated = (ModelProto, HashMap<String, TensorStats>, usize, String, Vec<TVec<TValue>>);

fn calibrate_pose(
    job: &QuantizeJob,
    rec: &dyn Recording,
    frames: usize,
    progress: &dyn Fn(usize, usize),
) -> Result<Calibrated> {
    let estimator = PoseEstimator::load(&job.model)?;
    let segmenter = job.segmenter.as_deref().map(Segmenter::load).transpose()?;
    let proto = estimator.float_proto()?;
    let (observed, mut collector) = StatsCollector::for_candidates(&proto)?;
    let plan = estimator.plan_variant(&observed)?;
    let mut samples = Vec::new();
    for i in 0..frames {
        let frame = rec.read_frame(i)?;
        let masks: Option<Vec<Vec<bool>>> = match rec.read_annotations(i)?.and_then(|a| a.instance_masks()) {
            Some(m) => Some(m),
            None => match &segmenter {
                Some(seg) => Some(
                    crate::pipeline::stages::detections_from_segmenter(seg, &frame)?
                        .into_iter()
                        .map(|d| d.mask)
                        .collect(),
                ),
                None => None,
            },
        };
        if let Some(masks) = masks {
            let refs: Vec<&[bool]> = masks.iter().map(Vec::as_slice).collect();
            let prepared = estimator.prepare(&frame, &refs, crate::rng::mix_seed(&[job.seed, i as u64]))?;
            // One instance per run: the statistics see each object as the runtime does.
            for input in prepared.inputs.chunks(1) {
                let tensors = estimator.input_tensors(input)?;
                if samples.len() < SENSITIVITY_SAMPLES {
                    samples.push(tensors.clone());
                }
                let out = plan.run(tensors.clone()).map_err(|e| Error::Inference(format!("{e:#}")))?;
                collector.observe(&tensors, &out)?;
            }
        }
        progress(i + 1, frames);
    }
    let runs = collector.runs();
    let sha = estimator.card().onnx.sha256.clone();
    Ok((proto, collector.into_stats(), runs, sha, samples))
}

fn calibrate_segmenter(
    job: &QuantizeJob,
    rec: &dyn Recording,
    frames: usize,
    progress: &dyn Fn(usize, usize),
) -> Result<Calibrated> {
    let seg = Segmenter::load(&job.model)?;
    let proto = seg.float_proto()?;
    let (observed, mut collector) = StatsCollector::for_candidates(&proto)?;
    let mut plans: std::collections::HashMap<(u32, u32), std::sync::Arc<TypedRunnableModel>> = Default::default();
    for i in 0..frames {
        let frame = rec.read_frame(i)?;
        let (w, h) = (frame.color.width, frame.color.height);
        let plan = match plans.get(&(w, h)) {
            Some(p) => p.clone(),
            None => {
                let p = seg.plan_variant(&observed, w as usize, h as usize)?;
                plans.insert((w, h), p.clone());
                p
            }
        };
        let inputs: TVec<TValue> = tvec![seg.input_tensor(&frame.color).into_tvalue()];
        let out = plan.run(inputs.clone()).map_err(|e| Error::Inference(format!("{e:#}")))?;
        collector.observe(&inputs, &out)?;
        progress(i + 1, frames);
    }
    let runs = collector.runs();
    Ok((proto, collector.into_stats(), runs, seg.onnx_sha256().to_string(), Vec::new()))
}

/// `target` relative to the directory of `from_file` when both are relative or both
/// absolute and they share a prefix; else `target` made absolute.
fn relative_to(target: &Path, from_file: &Path) -> PathBuf {
    let abs = |p: &Path| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    let (t, base) = (abs(target), abs(from_file.parent().unwrap_or(Path::new("."))));
    let (tc, bc): (Vec<_>, Vec<_>) = (t.components().collect(), base.components().collect());
    let common = tc.iter().zip(&bc).take_while(|(a, b)| a == b).count();
    if common <= 1 {
        // Nothing shared but the root: an absolute path reads better than ../../..
        return t;
    }
    let mut rel = PathBuf::new();
    for _ in common..bc.len() {
        rel.push("..");
    }
    for c in &tc[common..] {
        rel.push(c);
    }
    rel
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn model_paths_are_stored_relative_to_the_profile() {
        assert_eq!(
            relative_to(Path::new("models/a.card.json"), Path::new("models/a.int8.json")),
            PathBuf::from("a.card.json")
        );
        assert_eq!(
            relative_to(Path::new("models/a.card.json"), Path::new("data/q/a.int8.json")),
            PathBuf::from("../../models/a.card.json")
        );
    }
}
