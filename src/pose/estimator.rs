//! [`PoseEstimator`]: load the exported TriCons-Pose graph once, estimate per frame.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use tract_onnx::pb::ModelProto;
use tract_onnx::prelude::*;

use crate::error::{Error, Result};
use crate::frame::RgbdFrame;
use crate::geometry::{Mat3, Pose, Vec3};
use crate::pose::card::{KeypointFit, ModelCard, card_path_for};
use crate::pose::preprocess::{PoseInput, PreprocessConfig, build_input, prepare_instance, sample_indices};
use crate::quant::rewrite::ApplyReport;
use crate::quant::{ModelKind, QuantProfile};
use crate::rng::Rng;

/// The pose of one instance as the network estimates it.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseEstimate {
    /// `camera_from_object` (rotation re-orthonormalised in f64).
    pub camera_from_object: Pose,
    /// Box size along the object axes, metres.
    pub size_m: [f64; 3],
    /// The M keypoints in the camera frame, metres.
    pub keypoints_camera_m: Vec<[f32; 3]>,
    /// The keypoints' predicted NOCS coordinates (object frame over the box diagonal), when
    /// the graph outputs them (`kpt_nocs`); empty otherwise.
    pub keypoints_nocs: Vec<[f32; 3]>,
}

impl PoseEstimate {
    /// The rotation of the least-squares similarity from the keypoints' NOCS coordinates
    /// to their camera-frame positions (Umeyama), `None` without NOCS outputs or for a
    /// degenerate keypoint spread.
    pub fn keypoint_rotation(&self) -> Option<Mat3> {
        self.keypoint_rotation_with(KeypointFit::LeastSquares)
    }

    /// [`Self::keypoint_rotation`] with the card's choice of fit.
    pub fn keypoint_rotation_with(&self, fit: KeypointFit) -> Option<Mat3> {
        let f = |p: &[f32; 3]| Vec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        let nocs: Vec<Vec3> = self.keypoints_nocs.iter().map(f).collect();
        let camera: Vec<Vec3> = self.keypoints_camera_m.iter().map(f).collect();
        match fit {
            KeypointFit::LeastSquares => crate::geometry::fit_similarity(&nocs, &camera),
            KeypointFit::Robust => crate::geometry::fit_similarity_robust(&nocs, &camera),
        }
        .map(|fit| fit.pose.rotation)
    }
}

/// Why an instance got no estimate.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Skipped {
    /// The mask has no pixel.
    EmptyMask,
    /// Too few pixels with both mask and depth (the count found).
    TooFewValidPixels(usize),
    /// The network returned a non-finite value.
    NonFiniteOutput,
}

/// Outcome for one instance.
pub type InstanceOutcome = std::result::Result<PoseEstimate, Skipped>;

/// The network inputs of one frame's instances ([`PoseEstimator::prepare`]).
#[derive(Clone, Debug, PartialEq)]
pub struct PreparedFrame {
    /// Inputs of the usable instances, in mask order (one batch).
    pub inputs: Vec<PoseInput>,
    /// Per mask: its index into `inputs`, or why it was skipped.
    pub slots: Vec<std::result::Result<usize, Skipped>>,
}

/// A loaded pose model: card, preprocessing and an optimised tract plan of one instance
/// with every dimension concrete (tract's fast paths need it: broadcast arithmetic, lazy
/// im2col and bias/BatchNorm fusion all fall back with a symbolic batch). A frame's
/// instances run on [`Self::with_threads`] worker threads sharing that plan (one tract
/// state each).
///
/// Load once, estimate per frame:
///
/// ```no_run
/// use std::path::Path;
/// use tricons::pose::PoseEstimator;
/// use tricons::recording::open_recording;
///
/// # fn main() -> Result<(), Box<dyn std::error::Error>> {
/// let estimator = PoseEstimator::load(Path::new("models/tricons-pose.card.json"))?;
/// let rec = open_recording(Path::new("tests/data/synthnocs-demo"))?;
/// let frame = rec.read_frame(0)?;
/// // One boolean mask per object (frame-sized, row-major), e.g. from the segmenter;
/// // here the recording's ground truth.
/// let masks = rec.read_annotations(0)?.and_then(|a| a.instance_masks()).unwrap_or_default();
/// let masks: Vec<&[bool]> = masks.iter().map(Vec::as_slice).collect();
/// for outcome in estimator.estimate(&frame, &masks, 0)? {
///     match outcome {
///         Ok(pose) => println!("t = {:?} m, size = {:?} m", pose.camera_from_object.translation_m, pose.size_m),
///         Err(skipped) => println!("no estimate: {skipped:?}"),
///     }
/// }
/// # Ok(())
/// # }
/// ```
pub struct PoseEstimator {
    card: ModelCard,
    card_path: PathBuf,
    cfg: PreprocessConfig,
    /// The graph at batch 1, every dimension concrete.
    plan: Arc<TypedRunnableModel>,
    quantized: Option<ApplyReport>,
    /// Worker threads for a frame's instances (`None`: the calling thread).
    pool: Option<Arc<rayon::ThreadPool>>,
}

impl std::fmt::Debug for PoseEstimator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PoseEstimator").field("card", &self.card_path).field("config", &self.card.config_name).finish()
    }
}

impl PoseEstimator {
    /// Load a model from its card (`*.card.json`), graph (`*.onnx`, card beside it) or
    /// int8 quantization profile (`tricons quantize` output; the float model it names is
    /// loaded and its listed nodes run in int8).
    ///
    /// Checks the graph's hash against the card (and the profile) and its input shapes
    /// against the card's N and S; a graph using an operator this build lacks is an
    /// error naming it.
    pub fn load(model: &Path) -> Result<PoseEstimator> {
        if crate::quant::is_profile(model) {
            let profile = QuantProfile::read(model)?;
            if profile.kind != ModelKind::Pose {
                return Err(Error::model(model, "field kind: this profile is not for a pose model"));
            }
            return Self::load_impl(&profile.model_path(model), Some((profile, model.to_path_buf())));
        }
        Self::load_impl(model, None)
    }

    fn load_impl(model: &Path, profile: Option<(QuantProfile, PathBuf)>) -> Result<PoseEstimator> {
        let card_path = card_path_for(model);
        let card = ModelCard::read(&card_path)?;
        let bytes = card.read_verified_graph(&card_path)?;
        let onnx_path = card.onnx_path(&card_path);
        let model_err = |e: TractError| Error::model(&onnx_path, format!("{e:#}"));
        let onnx = crate::ops::onnx_with_custom_ops();
        let mut proto = crate::ops::read_onnx_proto(&bytes).map_err(|m| Error::model(&onnx_path, m))?;
        let quantized = match &profile {
            None => None,
            Some((p, path)) => {
                if !p.onnx_sha256.eq_ignore_ascii_case(&card.onnx.sha256) {
                    return Err(Error::model(
                        path,
                        format!(
                            "onnx_sha256 {} is not the graph of {} ({})",
                            p.onnx_sha256,
                            card_path.display(),
                            card.onnx.sha256
                        ),
                    ));
                }
                Some(crate::quant::rewrite::apply(&mut proto, p).map_err(|m| Error::model(path, m))?)
            }
        };
        let kernels = crate::pose::rewrite::rewrite(&mut proto);
        log::debug!("{}: {kernels:?}", onnx_path.display());
        let cfg = card.preprocess_config();
        // the graph's declared inputs are checked against the card, then it is typed with
        // every input dimension concrete (one instance)
        check_inputs(&proto, &cfg).map_err(|m| Error::model(&onnx_path, m))?;
        let mut folded = proto.clone();
        let report = crate::pose::fold::fold(&mut folded);
        let concrete = |proto: &ModelProto| {
            onnx.model_for_proto_model(proto).and_then(|m| concrete_batch1(m, &cfg)).and_then(optimise)
        };
        let plan = match concrete(&folded) {
            Ok(plan) => {
                log::debug!("{}: {report:?}", onnx_path.display());
                plan
            }
            // a folded product whose input is not rank 2, or a mean over the contracted axis
            // (see pose::fold): the graph as it was
            Err(e) if report != crate::pose::fold::FoldReport::default() => {
                log::warn!("{}: loaded without the folds of pose::fold ({e:#})", onnx_path.display());
                concrete(&proto).map_err(model_err)?
            }
            Err(e) => return Err(model_err(e)),
        };
        Ok(PoseEstimator { card, card_path, cfg, plan, quantized, pool: None })
    }

    /// Run a frame's instances on `threads` worker threads (1: on the calling thread, the
    /// default). Outcomes do not depend on the count: each instance runs alone.
    pub fn with_threads(mut self, threads: usize) -> Result<PoseEstimator> {
        self.set_threads(threads)?;
        Ok(self)
    }

    /// Change the worker thread count ([`Self::with_threads`]).
    pub fn set_threads(&mut self, threads: usize) -> Result<()> {
        self.pool = crate::workers::pool(threads, "pose")?;
        Ok(())
    }

    /// Worker threads a frame's instances run on.
    pub fn threads(&self) -> usize {
        self.pool.as_ref().map_or(1, |p| p.current_num_threads())
    }

    /// The float graph as loaded (hash-checked), for calibration.
    pub fn float_proto(&self) -> Result<ModelProto> {
        let bytes = self.card.read_verified_graph(&self.card_path)?;
        crate::ops::read_onnx_proto(&bytes).map_err(|m| Error::model(self.card.onnx_path(&self.card_path), m))
    }

    /// A runnable plan of another version of this graph (e.g. with calibration outputs),
    /// as given (symbolic batch, no [`crate::pose::rewrite`]).
    pub fn plan_variant(&self, proto: &ModelProto) -> Result<Arc<TypedRunnableModel>> {
        let err = |e: TractError| Error::model(self.card.onnx_path(&self.card_path), format!("{e:#}"));
        crate::ops::onnx_with_custom_ops()
            .model_for_proto_model(proto)
            .and_then(|m| m.into_typed())
            .and_then(optimise)
            .map_err(err)
    }

    /// What the int8 rewrite did, when loaded from a quantization profile.
    pub fn quantized(&self) -> Option<&ApplyReport> {
        self.quantized.as_ref()
    }

    /// The model card.
    pub fn card(&self) -> &ModelCard {
        &self.card
    }

    /// Replace the card's `min_score` (`None`: report every pose).
    pub fn set_min_score(&mut self, min_score: Option<f64>) {
        self.card.min_score = min_score;
    }

    /// The pose to report for an instance of `class`: the head's rotation, for the card's
    /// `rotation_from_keypoints` classes the one solved from the keypoints, for its
    /// `rotation_keypoint_blend` classes the weighted chordal mean of the two (the head's
    /// alone when the keypoint fit is degenerate); translation always the head's.
    pub fn camera_from_object(&self, estimate: &PoseEstimate, class: crate::category::Category) -> Pose {
        let head = estimate.camera_from_object;
        let w = self.card.keypoint_rotation_weight(class);
        if w <= 0.0 {
            return head;
        }
        let Some(keypoints) = estimate.keypoint_rotation_with(self.card.keypoint_fit) else {
            return head;
        };
        let rotation = if w >= 1.0 {
            keypoints
        } else {
            crate::geometry::weighted_chordal_mean(&[(head.rotation, 1.0 - w), (keypoints, w)])
        };
        Pose::new(rotation, head.translation_m)
    }

    /// The score to report for an estimate of a detection scored `detection_score`: as is,
    /// or with the card's `consistency_score_scale` times the factor
    /// [`crate::pose::consistency::consistency_score`] of the estimate's keypoint residual.
    pub fn score(&self, estimate: &PoseEstimate, detection_score: f64) -> f64 {
        match self.card.consistency_score_scale {
            None => detection_score,
            Some(scale) => {
                let residual = crate::pose::consistency::keypoint_residual(
                    &estimate.camera_from_object,
                    estimate.size_m,
                    &estimate.keypoints_nocs,
                    &estimate.keypoints_camera_m,
                );
                detection_score * crate::pose::consistency::consistency_score(residual, scale)
            }
        }
    }

    /// Where the card was read from.
    pub fn card_path(&self) -> &Path {
        &self.card_path
    }

    /// The preprocessing configuration (from the card).
    pub fn preprocess_config(&self) -> &PreprocessConfig {
        &self.cfg
    }

    /// Estimate every instance of `frame` given its masks (row-major, frame-sized), in one
    /// batched run: [`Self::prepare`], then [`Self::run_inputs`]. Outcomes come in mask order.
    pub fn estimate(&self, frame: &RgbdFrame, masks: &[&[bool]], seed: u64) -> Result<Vec<InstanceOutcome>> {
        let prepared = self.prepare(frame, masks, seed)?;
        let mut estimates = self.run_inputs(&prepared.inputs)?.into_iter();
        Ok(prepared
            .slots
            .into_iter()
            .map(|slot| match slot {
                Ok(_) => estimates.next().unwrap_or(Err(Skipped::NonFiniteOutput)),
                Err(why) => Err(why),
            })
            .collect())
    }

    /// The network inputs of every usable instance of `frame`, exactly as training built
    /// them. Point sampling draws from `Rng::from_words(&[seed, i])` for instance `i`.
    pub fn prepare(&self, frame: &RgbdFrame, masks: &[&[bool]], seed: u64) -> Result<PreparedFrame> {
        let (w, h) = (frame.depth.width as usize, frame.depth.height as usize);
        let mut prepared = PreparedFrame { inputs: Vec::new(), slots: Vec::with_capacity(masks.len()) };
        for (i, mask) in masks.iter().enumerate() {
            if mask.len() != w * h {
                return Err(Error::InvalidArgument(format!("mask {i} has {} pixels, the frame {w}x{h}", mask.len())));
            }
            let Some(prep) = prepare_instance(&frame.depth, mask, &self.cfg) else {
                prepared.slots.push(Err(Skipped::EmptyMask));
                continue;
            };
            if prep.n_valid() <= self.cfg.min_valid_pixels {
                prepared.slots.push(Err(Skipped::TooFewValidPixels(prep.n_valid())));
                continue;
            }
            let idx = sample_indices(prep.n_valid(), self.cfg.n_points, &mut Rng::from_words(&[seed, i as u64]));
            prepared.slots.push(Ok(prepared.inputs.len()));
            prepared.inputs.push(build_input(
                &frame.color,
                frame.depth.depth_scale_m,
                &frame.intrinsics,
                &prep,
                &idx,
                &self.cfg,
            ));
        }
        Ok(prepared)
    }

    /// Run the graph on prepared inputs, one instance per run, on the worker threads
    /// (in input order), decoding R, t, s and keypoints.
    pub fn run_inputs(&self, inputs: &[PoseInput]) -> Result<Vec<InstanceOutcome>> {
        use rayon::prelude::*;
        let run_one = |x: &PoseInput| -> Result<InstanceOutcome> {
            let tensors = self.input_tensors(std::slice::from_ref(x))?;
            let out = self.plan.run(tensors).map_err(|e| Error::Inference(format!("{e:#}")))?;
            decode_outputs(&out, 1)?.pop().ok_or_else(|| Error::Inference("the graph returned no instance".into()))
        };
        match &self.pool {
            Some(pool) if inputs.len() > 1 => pool.install(|| inputs.par_iter().map(run_one).collect()),
            _ => inputs.iter().map(run_one).collect(),
        }
    }

    /// Run the graph on each of `inputs` (one at a time, on the calling thread) timing
    /// every node: per node in plan order, tract's optimised op name (e.g. `OptMatMul`,
    /// `ThreeNN`), the node's name and its wall time summed over the inputs.
    pub fn profile_nodes(&self, inputs: &[PoseInput]) -> Result<Vec<(String, String, std::time::Duration)>> {
        let err = |e: TractError| Error::Inference(format!("{e:#}"));
        let mut per_node: Vec<(String, String, std::time::Duration)> = Vec::new();
        for x in inputs {
            let tensors = self.input_tensors(std::slice::from_ref(x))?;
            let mut state = tract_onnx::tract_core::plan::SimpleState::new(&self.plan).map_err(err)?;
            let mut i = 0;
            state
                .run_plan_with_eval(tensors, |ctx, op_state, node, input| {
                    let start = std::time::Instant::now();
                    let out = tract_onnx::tract_core::plan::eval(ctx, op_state, node, input);
                    match per_node.get_mut(i) {
                        Some(slot) => slot.2 += start.elapsed(),
                        None => per_node.push((node.op().name().to_string(), node.name.clone(), start.elapsed())),
                    }
                    i += 1;
                    out
                })
                .map_err(err)?;
        }
        Ok(per_node)
    }

    /// The graph's input tensors for `inputs` (one batch): rgb, pts, choose.
    pub fn input_tensors(&self, inputs: &[PoseInput]) -> Result<TVec<TValue>> {
        let (n, s, b) = (self.cfg.n_points, self.cfg.crop_size, inputs.len());
        for (i, x) in inputs.iter().enumerate() {
            if x.rgb.len() != 3 * s * s || x.pts.len() != 3 * n || x.choose.len() != n {
                return Err(Error::InvalidArgument(format!("input {i} does not have the card's sizes (N {n}, S {s})")));
            }
        }
        let cat_f =
            |f: fn(&PoseInput) -> &[f32]| inputs.iter().flat_map(|x| f(x).iter().copied()).collect::<Vec<f32>>();
        let choose: Vec<i64> = inputs.iter().flat_map(|x| x.choose.iter().copied()).collect();
        let tensor_err = |e: TractError| Error::Inference(format!("{e:#}"));
        Ok(tvec![
            Tensor::from_shape(&[b, 3, s, s], &cat_f(|x| &x.rgb)).map_err(tensor_err)?.into_tvalue(),
            Tensor::from_shape(&[b, n, 3], &cat_f(|x| &x.pts)).map_err(tensor_err)?.into_tvalue(),
            Tensor::from_shape(&[b, n], &choose).map_err(tensor_err)?.into_tvalue(),
        ])
    }
}

/// `model` with its three inputs fixed to one instance: rgb (1, 3, S, S), pts (1, N, 3),
/// choose (1, N).
fn concrete_batch1(model: InferenceModel, cfg: &PreprocessConfig) -> TractResult<TypedModel> {
    let (n, s) = (cfg.n_points, cfg.crop_size);
    model
        .with_input_fact(0, f32::fact([1, 3, s, s]).into())?
        .with_input_fact(1, f32::fact([1, n, 3]).into())?
        .with_input_fact(2, i64::fact([1, n]).into())?
        .into_typed()
}

fn optimise(typed: TypedModel) -> TractResult<Arc<TypedRunnableModel>> {
    typed.into_decluttered().and_then(|m| m.into_optimized()).and_then(|m| m.into_runnable())
}

fn decode_outputs(out: &TVec<TValue>, b: usize) -> Result<Vec<InstanceOutcome>> {
    let tensor_err = |e: TractError| Error::Inference(format!("{e:#}"));
    let slice = |k: usize| -> Result<&[f32]> {
        out.get(k)
            .ok_or_else(|| Error::Inference(format!("the graph returned {} outputs", out.len())))?
            .try_as_plain_ram()
            .and_then(|v| v.as_slice::<f32>())
            .map_err(tensor_err)
    };
    let (r, t, sz, kpt) = (slice(0)?, slice(1)?, slice(2)?, slice(3)?);
    // kpt_nocs, when the graph has it (the same length as kpt_3d)
    let nocs = if out.len() > 4 { slice(4)? } else { &[] };
    let m = kpt.len() / b;
    if !nocs.is_empty() && nocs.len() != kpt.len() {
        return Err(Error::Inference(format!("kpt_nocs has {} values, kpt_3d {}", nocs.len(), kpt.len())));
    }
    Ok((0..b)
        .map(|j| {
            let kn = if nocs.is_empty() { &[][..] } else { &nocs[m * j..m * (j + 1)] };
            decode(&r[9 * j..9 * j + 9], &t[3 * j..3 * j + 3], &sz[3 * j..3 * j + 3], &kpt[m * j..m * (j + 1)], kn)
        })
        .collect())
}

/// The graph's inputs must be rgb (batch, 3, S, S), pts (batch, N, 3), choose (batch, N).
/// The graph's declared inputs (initializers left out) against the card: `rgb (B, 3, S, S)`,
/// `pts (B, N, 3)`, `choose (B, N)`, whatever the batch dimension.
fn check_inputs(proto: &ModelProto, cfg: &PreprocessConfig) -> std::result::Result<(), String> {
    let graph = proto.graph.as_ref().ok_or("the file holds no graph")?;
    let initializers: std::collections::HashSet<&str> = graph.initializer.iter().map(|t| t.name.as_str()).collect();
    let inputs: Vec<_> = graph.input.iter().filter(|i| !initializers.contains(i.name.as_str())).collect();
    let (n, s) = (cfg.n_points as i64, cfg.crop_size as i64);
    let want: [(&str, Vec<i64>); 3] = [("rgb", vec![3, s, s]), ("pts", vec![n, 3]), ("choose", vec![n])];
    if inputs.len() != 3 {
        return Err(format!("the graph has {} inputs, its card 3 (rgb, pts, choose)", inputs.len()));
    }
    for (input, (name, dims)) in inputs.iter().zip(want) {
        let shape = crate::ops::proto::declared_dims(input);
        let show: Vec<String> = shape.iter().map(|d| d.map_or_else(|| "?".into(), |v| v.to_string())).collect();
        let ok = shape.len() == dims.len() + 1 && shape[1..].iter().zip(&dims).all(|(g, w)| *g == Some(*w));
        if !ok {
            return Err(format!(
                "input {name} (graph input {:?}) has shape [{}], its card says (batch, {dims:?})",
                input.name,
                show.join(", ")
            ));
        }
    }
    Ok(())
}

fn decode(r: &[f32], t: &[f32], s: &[f32], kpt: &[f32], kpt_nocs: &[f32]) -> InstanceOutcome {
    if r.iter().chain(t).chain(s).chain(kpt).chain(kpt_nocs).any(|v| !v.is_finite()) {
        return Err(Skipped::NonFiniteOutput);
    }
    let m = Mat3::from_row_slice(&r.iter().map(|&v| v as f64).collect::<Vec<_>>());
    Ok(PoseEstimate {
        camera_from_object: Pose::new(orthonormalise(&m), Vec3::new(t[0] as f64, t[1] as f64, t[2] as f64)),
        size_m: [s[0] as f64, s[1] as f64, s[2] as f64],
        keypoints_camera_m: kpt.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect(),
        keypoints_nocs: kpt_nocs.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect(),
    })
}

/// Gram-Schmidt on the columns (first column kept in direction), third = first x second.
fn orthonormalise(m: &Mat3) -> Mat3 {
    let a = m.column(0).normalize();
    let b = (m.column(1) - a * a.dot(&m.column(1))).normalize();
    let c = a.cross(&b);
    Mat3::from_columns(&[a, b, c])
}
