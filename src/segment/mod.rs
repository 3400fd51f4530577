//! Instance segmentation with any torchvision Mask R-CNN ONNX export.
//!
//! [`Segmenter::load`] reads the user's file unmodified, rewrites what tract lacks
//! ([`rewrite`]: the NMS `If`, un-clamped `Slice`, the mask-pasting `Loop`), registers
//! `RoiAlign` and the fast `NonMaxSuppression` ([`crate::ops`]), and plans the graph
//! once per image size. [`Segmenter::segment`] returns [`SegInstance`]s with
//! full-resolution masks pasted in Rust ([`paste`]).

pub mod card;
pub mod depth_outliers;
pub mod duplicates;
pub mod erode;
pub mod paste;
pub mod published;
pub mod rewrite;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use tract_onnx::prelude::*;

pub use card::{InputSpec, OutputNames, SegmenterCard};
pub use rewrite::{RewriteReport, rewrite};

use tract_onnx::pb::ModelProto;

use crate::category::Category;
use crate::error::{Error, Result};
use crate::frame::{ColorImage, RgbdFrame};
use crate::quant::rewrite::ApplyReport;
use crate::quant::{ModelKind, QuantProfile};

/// One detected instance.
#[derive(Clone, Debug, PartialEq)]
pub struct SegInstance {
    /// The model's label id.
    pub label: i64,
    /// The card's class name for the label, if any.
    pub class_name: Option<String>,
    /// The NOCS category, when the class name is one.
    pub category: Option<Category>,
    /// Detection score.
    pub score: f32,
    /// Box `(x0, y0, x1, y1)` in image pixels.
    pub box_xyxy: [f32; 4],
    /// Full-image mask (row-major, `width * height`): probability >= the card's threshold.
    pub mask: Vec<bool>,
}

impl SegInstance {
    /// Number of mask pixels.
    pub fn mask_pixels(&self) -> usize {
        self.mask.iter().filter(|&&m| m).count()
    }
}

/// Where the graph's results are among its outputs.
#[derive(Clone, Debug)]
struct OutputSlots {
    boxes: usize,
    labels: usize,
    scores: usize,
    /// Full masks `(N, 1, H, W)` when the graph pastes itself without a Loop.
    masks: Option<usize>,
    /// Padded mask probabilities and integer boxes, when the Loop was cut.
    paste: Option<(usize, usize)>,
}

/// A loaded Mask R-CNN.
pub struct Segmenter {
    card: SegmenterCard,
    onnx_path: PathBuf,
    /// The graph after the load-time rewrites (and the int8 profile), score floor as exported.
    proto: ModelProto,
    /// The graph's own detection score floor, when found (raised to the card's threshold
    /// in the plans [`Segmenter::segment`] runs).
    score_floor: Option<f32>,
    input_index: usize,
    slots: OutputSlots,
    report: RewriteReport,
    sha256: String,
    quantized: Option<ApplyReport>,
    /// tract's matrix-product executor for this model's runs (`--threads`).
    executor: tract_linalg::multithread::Executor,
    /// Plans per (width, height, raised score floor bits).
    plans: Mutex<HashMap<PlanKey, Arc<TypedRunnableModel>>>,
    /// Detections [`Segmenter::segment`] dropped as duplicates so far.
    duplicates_dropped: AtomicU64,
    /// Detections [`Segmenter::segment_nocs`] left out as of no NOCS category so far.
    not_nocs_dropped: AtomicU64,
}

/// A plan's image width and height and the bits of its raised score floor (`None`: the
/// graph's own).
type PlanKey = (usize, usize, Option<u32>);

impl std::fmt::Debug for Segmenter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Segmenter").field("model", &self.onnx_path).field("rewrites", &self.report).finish()
    }
}

/// The raw (unthresholded) results of one run, in the graph's order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RawDetections {
    /// `(N, 4)` boxes.
    pub boxes: Vec<[f32; 4]>,
    /// Labels.
    pub labels: Vec<i64>,
    /// Scores.
    pub scores: Vec<f32>,
    /// Per detection, the full-image mask probabilities (`width * height`).
    pub masks: Vec<Vec<f32>>,
}

impl Segmenter {
    /// Load a model: a `*.card.json`, a `*.onnx` (with its `<stem>.card.json` if
    /// present, else as a bare torchvision export), or an int8 quantization profile
    /// (`tricons quantize` output) naming one of those.
    pub fn load(model: &Path) -> Result<Segmenter> {
        if crate::quant::is_profile(model) {
            let profile = QuantProfile::read(model)?;
            if profile.kind != ModelKind::Segmenter {
                return Err(Error::model(model, "field kind: this profile is not for a segmenter"));
            }
            let (card, onnx_path) = card::resolve(&profile.model_path(model))?;
            return Self::load_impl(&onnx_path, card, Some((profile, model.to_path_buf())));
        }
        let (card, onnx_path) = card::resolve(model)?;
        Self::load_with_card(&onnx_path, card)
    }

    /// Load `onnx_path` with an explicit card.
    pub fn load_with_card(onnx_path: &Path, card: SegmenterCard) -> Result<Segmenter> {
        Self::load_impl(onnx_path, card, None)
    }

    /// Read `onnx_path`, check its hash against the card, apply the load-time rewrites.
    fn read_rewritten(onnx_path: &Path, card: &SegmenterCard) -> Result<(ModelProto, RewriteReport, String)> {
        let bytes = std::fs::read(onnx_path).map_err(|e| Error::io(onnx_path, e))?;
        let err = |m: String| Error::model(onnx_path, m);
        let hex = crate::atomic::sha256_hex(&bytes);
        if let Some(want) = card.sha256.as_ref().filter(|w| !hex.eq_ignore_ascii_case(w)) {
            return Err(err(format!("sha256 {hex} does not match its card ({want}): graph and card differ")));
        }
        let mut proto = crate::ops::read_onnx_proto(&bytes).map_err(&err)?;
        let report = rewrite(&mut proto).map_err(&err)?;
        Ok((proto, report, hex))
    }

    fn load_impl(onnx_path: &Path, card: SegmenterCard, profile: Option<(QuantProfile, PathBuf)>) -> Result<Segmenter> {
        let err = |m: String| Error::model(onnx_path, m);
        let onnx = crate::ops::onnx_with_custom_ops();
        let (mut proto, report, sha256) = Self::read_rewritten(onnx_path, &card)?;
        let quantized = match &profile {
            None => None,
            Some((p, path)) => {
                if !p.onnx_sha256.eq_ignore_ascii_case(&sha256) {
                    return Err(Error::model(
                        path,
                        format!("onnx_sha256 {} is not the graph {} ({sha256})", p.onnx_sha256, onnx_path.display()),
                    ));
                }
                Some(crate::quant::rewrite::apply(&mut proto, p).map_err(|m| Error::model(path, m))?)
            }
        };
        let graph = proto.graph.as_ref().ok_or_else(|| err("the file holds no graph".into()))?;
        let outputs: Vec<&str> = graph.output.iter().map(|o| o.name.as_str()).collect();
        let find = |name: &str, what: &str| {
            outputs.iter().position(|o| *o == name).ok_or_else(|| {
                err(format!(
                    "no graph output named {name:?} ({what}); the graph's outputs are {outputs:?}. \
                     A torchvision Mask R-CNN export names them in its card's `outputs` \
                     (torch.onnx.export(..., output_names=[\"boxes\", \"labels\", \"scores\", \"masks\"]))"
                ))
            })
        };
        let o = &card.outputs;
        let (boxes, labels, scores) =
            (find(&o.boxes, "boxes")?, find(&o.labels, "labels")?, find(&o.scores, "scores")?);
        let slots = match &report.pasted_output {
            Some(_) => OutputSlots {
                boxes,
                labels,
                scores,
                masks: None,
                paste: Some((
                    find(rewrite::PASTE_MASKS_OUTPUT, "pasted masks")?,
                    find(rewrite::PASTE_BOXES_OUTPUT, "paste boxes")?,
                )),
            },
            None => OutputSlots { boxes, labels, scores, masks: Some(find(&o.masks, "masks")?), paste: None },
        };
        let inputs: Vec<&str> = graph
            .input
            .iter()
            .map(|i| i.name.as_str())
            .filter(|n| !graph.initializer.iter().any(|t| t.name == *n))
            .collect();
        let input_index = match &card.input.name {
            Some(name) => inputs.iter().position(|i| i == name).ok_or_else(|| {
                err(format!("no graph input named {name:?} (field input.name); the inputs are {inputs:?}"))
            })?,
            None if inputs.len() == 1 => 0,
            None => return Err(err(format!("expected one image input, the graph has {inputs:?}"))),
        };
        // parse once now so that an unloadable graph fails at load, not at the first frame
        onnx.model_for_proto_model(&proto).map_err(|e| err(format!("{e:#}")))?;
        let score_floor = rewrite::score_floor(&proto).map_err(&err)?;
        log::info!(
            "{}: {} If inlined, {} Slice clamped, {} depthwise Conv as DepthwiseConv2d, {} Resize as Resize2d, \
             {} ScatterElements as ScatterRows, masks {}, score floor {}",
            onnx_path.display(),
            report.ifs_inlined,
            report.slices_clamped,
            report.depthwise,
            report.resize,
            report.scatter_rows,
            if report.pasted_output.is_some() { "pasted in Rust" } else { "from the graph" },
            match score_floor {
                Some(f) => format!("{f} raised to the card's {} before NMS and the mask head", card.score_threshold),
                None => "not found (all detections reach the mask head)".into(),
            }
        );
        Ok(Segmenter {
            card,
            onnx_path: onnx_path.to_path_buf(),
            proto,
            score_floor,
            input_index,
            slots,
            report,
            sha256,
            quantized,
            executor: tract_linalg::multithread::Executor::SingleThread,
            plans: Mutex::new(HashMap::new()),
            duplicates_dropped: AtomicU64::new(0),
            not_nocs_dropped: AtomicU64::new(0),
        })
    }

    /// Split the graph's matrix products and convolutions over `threads` workers (1: the
    /// calling thread only, the default). Results do not depend on the count.
    pub fn with_threads(mut self, threads: usize) -> Result<Segmenter> {
        self.set_threads(threads)?;
        Ok(self)
    }

    /// Change the worker thread count ([`Self::with_threads`]).
    pub fn set_threads(&mut self, threads: usize) -> Result<()> {
        self.executor = match crate::workers::pool(threads, "segment")? {
            None => tract_linalg::multithread::Executor::SingleThread,
            Some(pool) => tract_linalg::multithread::Executor::MultiThread(pool),
        };
        Ok(())
    }

    /// Worker threads of the graph's products.
    pub fn threads(&self) -> usize {
        match &self.executor {
            tract_linalg::multithread::Executor::MultiThread(pool) => pool.current_num_threads(),
            _ => 1,
        }
    }

    /// The card in use.
    pub fn card(&self) -> &SegmenterCard {
        &self.card
    }

    /// Keep detections scoring at least `score` (overrides the card).
    pub fn set_score_threshold(&mut self, score: f32) {
        self.card.score_threshold = score;
    }

    /// The graph file.
    pub fn onnx_path(&self) -> &Path {
        &self.onnx_path
    }

    /// What the load-time rewrite changed.
    pub fn rewrites(&self) -> &RewriteReport {
        &self.report
    }

    /// The graph's own detection score floor (torchvision's `box_score_thresh`), if found.
    pub fn score_floor(&self) -> Option<f32> {
        self.score_floor
    }

    /// The optimised plan for `width x height` images (built on first use, then cached);
    /// `min_score`: the score floor raised to it ([`rewrite::raise_score_floor`]), or the
    /// graph's own floor (`None`).
    fn plan(&self, width: usize, height: usize, min_score: Option<f32>) -> Result<Arc<TypedRunnableModel>> {
        let min_score = min_score.filter(|&s| self.score_floor.is_some_and(|f| s > f));
        let key = (width, height, min_score.map(f32::to_bits));
        let mut plans = self.plans.lock().map_err(|_| Error::Inference("segmenter plan cache poisoned".into()))?;
        if let Some(p) = plans.get(&key) {
            return Ok(p.clone());
        }
        let err = |m: String| Error::model(&self.onnx_path, m);
        let model = match min_score {
            None => crate::ops::onnx_with_custom_ops().model_for_proto_model(&self.proto),
            Some(s) => {
                let mut proto = self.proto.clone();
                rewrite::raise_score_floor(&mut proto, s).map_err(err)?;
                crate::ops::onnx_with_custom_ops().model_for_proto_model(&proto)
            }
        }
        .map_err(|e| err(format!("{e:#}")))?;
        let plan = self.plan_for(model, width, height)?;
        plans.insert(key, plan.clone());
        Ok(plan)
    }

    fn plan_for(&self, model: InferenceModel, width: usize, height: usize) -> Result<Arc<TypedRunnableModel>> {
        let err = |e: TractError| Error::model(&self.onnx_path, format!("{e:#}"));
        model
            .with_input_fact(self.input_index, f32::fact([3, height, width]).into())
            .and_then(|m| m.into_typed())
            .and_then(|m| m.into_decluttered())
            .and_then(|m| m.into_optimized())
            .and_then(|m| m.into_runnable())
            .map_err(err)
    }

    /// The float graph after the load-time rewrites (hash-checked), for calibration.
    pub fn float_proto(&self) -> Result<ModelProto> {
        Self::read_rewritten(&self.onnx_path, &self.card).map(|(p, _, _)| p)
    }

    /// A runnable plan of another version of this graph (e.g. with calibration
    /// outputs) for `width x height` images.
    pub fn plan_variant(&self, proto: &ModelProto, width: usize, height: usize) -> Result<Arc<TypedRunnableModel>> {
        let model = crate::ops::onnx_with_custom_ops()
            .model_for_proto_model(proto)
            .map_err(|e| Error::model(&self.onnx_path, format!("{e:#}")))?;
        self.plan_for(model, width, height)
    }

    /// sha256 of the graph file as loaded.
    pub fn onnx_sha256(&self) -> &str {
        &self.sha256
    }

    /// What the int8 rewrite did, when loaded from a quantization profile.
    pub fn quantized(&self) -> Option<&ApplyReport> {
        self.quantized.as_ref()
    }

    /// Build the plan [`Self::segment`] runs for `width x height` now (loading is
    /// otherwise lazy).
    pub fn prepare(&self, width: usize, height: usize) -> Result<()> {
        self.plan(width, height, Some(self.card.score_threshold)).map(|_| ())
    }

    /// The image tensor `(3, H, W)` as the card says.
    pub fn input_tensor(&self, image: &ColorImage) -> Tensor {
        let (w, h) = (image.width as usize, image.height as usize);
        let spec = &self.card.input;
        let order = if spec.color == "bgr" { [2, 1, 0] } else { [0, 1, 2] };
        let mut data = vec![0f32; 3 * w * h];
        for (c, plane) in data.chunks_exact_mut(w * h).enumerate() {
            let src = order[c];
            let (mean, std) = (spec.mean[c], spec.std[c]);
            for (o, px) in plane.iter_mut().zip(image.data.chunks_exact(3)) {
                *o = (px[src] as f32 * spec.scale - mean) / std;
            }
        }
        tract_ndarray::Array3::from_shape_vec((3, h, w), data).map(Tensor::from).unwrap_or_else(|_| Tensor::default())
    }

    /// Every detection the graph returns (its own score floor only), masks as probabilities.
    pub fn detect_raw(&self, image: &ColorImage) -> Result<RawDetections> {
        self.detect(image, None)
    }

    /// Detections scoring at least the card's threshold, with thresholded masks. The graph
    /// runs with its score floor raised to that threshold, so NMS and the mask head only
    /// work on what is kept (the same detections as filtering the unchanged graph's).
    /// With the card's `duplicate_mask_iou` or `duplicate_mask_inside`, duplicates across
    /// classes are then dropped ([`duplicates`]; counted in [`Self::duplicates_dropped`]).
    pub fn segment(&self, image: &ColorImage) -> Result<Vec<SegInstance>> {
        let raw = self.detect(image, Some(self.card.score_threshold))?;
        let (w, h) = (image.width as usize, image.height as usize);
        let t = self.card.mask_threshold;
        let mut instances: Vec<SegInstance> = (0..raw.scores.len())
            .map(|i| SegInstance {
                label: raw.labels[i],
                class_name: self.card.class_name(raw.labels[i]).map(str::to_owned),
                category: self.card.category(raw.labels[i]),
                score: raw.scores[i],
                box_xyxy: raw.boxes[i],
                mask: raw
                    .masks
                    .get(i)
                    .map(|m| m.iter().map(|&p| p >= t).collect())
                    .unwrap_or_else(|| vec![false; w * h]),
            })
            .collect();
        let rule = self.duplicate_rule();
        if rule.is_on() {
            let dropped = duplicates::suppress_duplicates(&mut instances, w, rule);
            self.duplicates_dropped.fetch_add(dropped as u64, Ordering::Relaxed);
        }
        Ok(instances)
    }

    /// [`Self::segment`]'s detections of a NOCS category, each with its category. Those of a
    /// class the card maps to no NOCS category (a model's "other" class, trained on what is no
    /// object) have done their part in the duplicate suppression, which lets them drop a NOCS
    /// detection they cover; they are left out here and counted in [`Self::not_nocs_dropped`].
    pub fn segment_nocs(&self, image: &ColorImage) -> Result<Vec<(Category, SegInstance)>> {
        let all = self.segment(image)?;
        let total = all.len();
        let nocs: Vec<(Category, SegInstance)> = all.into_iter().filter_map(|d| Some((d.category?, d))).collect();
        self.not_nocs_dropped.fetch_add((total - nocs.len()) as u64, Ordering::Relaxed);
        Ok(nocs)
    }

    /// The mask the pose stage gets for one of [`Self::segment`]'s detections of `category`
    /// in `frame`: eroded by the card's `pose_mask_erode_px` ([`erode::erode_for_pose`]), then
    /// without its depth outliers when the card gives the category a
    /// `pose_mask_max_radius_m` ([`depth_outliers::drop_far_pixels`]).
    pub fn pose_mask(&self, mask: Vec<bool>, frame: &RgbdFrame, category: Category) -> Vec<bool> {
        let mask = erode::erode_for_pose(mask, frame.color.width as usize, self.card.pose_mask_erode_px);
        match self.card.pose_mask_max_radius_m(category) {
            Some(radius_m) => depth_outliers::drop_far_pixels(mask, &frame.depth, &frame.intrinsics, radius_m),
            None => mask,
        }
    }

    /// Set the pose stage's mask erosion (pixels; 0: off), overriding the card.
    pub fn set_pose_mask_erode_px(&mut self, px: usize) {
        self.card.pose_mask_erode_px = px;
    }

    /// Turn the pose stage's depth-outlier step off, whatever the card says.
    pub fn clear_pose_mask_max_radius(&mut self) {
        self.card.pose_mask_max_radius_m.clear();
    }

    /// How many detections [`Self::segment`] has dropped as duplicates.
    pub fn duplicates_dropped(&self) -> u64 {
        self.duplicates_dropped.load(Ordering::Relaxed)
    }

    /// How many detections [`Self::segment_nocs`] has left out as of no NOCS category.
    pub fn not_nocs_dropped(&self) -> u64 {
        self.not_nocs_dropped.load(Ordering::Relaxed)
    }

    /// Turn duplicate suppression by mask IoU on at `iou` or off (`None`), overriding the card.
    pub fn set_duplicate_mask_iou(&mut self, iou: Option<f32>) {
        self.card.duplicate_mask_iou = iou;
    }

    /// Turn duplicate suppression by containment on at `inside` or off (`None`), overriding
    /// the card.
    pub fn set_duplicate_mask_inside(&mut self, inside: Option<f32>) {
        self.card.duplicate_mask_inside = inside;
    }

    /// The duplicate rule of the card (as overridden).
    pub fn duplicate_rule(&self) -> duplicates::DuplicateRule {
        duplicates::DuplicateRule {
            max_iou: self.card.duplicate_mask_iou.map(f64::from),
            max_inside: self.card.duplicate_mask_inside.map(f64::from),
        }
    }

    /// Run the plan [`Self::segment`] runs once on `image`, timing every node: per node,
    /// tract's optimised op name, the node's name and its wall time, in plan order.
    pub fn profile_nodes(&self, image: &ColorImage) -> Result<Vec<(String, String, std::time::Duration)>> {
        let err = |e: TractError| Error::Inference(format!("{e:#}"));
        let plan = self.plan(image.width as usize, image.height as usize, Some(self.card.score_threshold))?;
        let mut times = Vec::new();
        let inputs: TVec<TValue> = tvec![self.input_tensor(image).into()];
        tract_linalg::multithread::multithread_tract_scope(self.executor.clone(), || {
            let mut state = tract_onnx::tract_core::plan::SimpleState::new(&plan)?;
            state.run_plan_with_eval(inputs, |ctx, op_state, node, input| {
                let start = std::time::Instant::now();
                let out = tract_onnx::tract_core::plan::eval(ctx, op_state, node, input);
                times.push((node.op().name().to_string(), node.name.clone(), start.elapsed()));
                out
            })
        })
        .map_err(err)?;
        Ok(times)
    }

    fn detect(&self, image: &ColorImage, min_score: Option<f32>) -> Result<RawDetections> {
        let (w, h) = (image.width as usize, image.height as usize);
        if w == 0 || h == 0 || image.data.len() != w * h * 3 {
            return Err(Error::InvalidArgument(format!("image {w}x{h} with {} bytes", image.data.len())));
        }
        let plan = self.plan(w, h, min_score)?;
        let min_score = min_score.unwrap_or(f32::NEG_INFINITY);
        let mut inputs: TVec<TValue> = tvec![];
        inputs.push(self.input_tensor(image).into());
        let out = tract_linalg::multithread::multithread_tract_scope(self.executor.clone(), || plan.run(inputs))
            .map_err(|e| Error::Inference(format!("{e:#}")))?;
        let view = |i: usize, what: &str| -> Result<&[f32]> {
            out[i]
                .try_as_plain_ram()
                .and_then(|t| t.as_slice::<f32>())
                .map_err(|e| Error::Inference(format!("{what}: {e:#}")))
        };
        let boxes = view(self.slots.boxes, "boxes")?;
        let scores = view(self.slots.scores, "scores")?;
        let labels = i64_values(&out[self.slots.labels], "labels")?;
        let n = scores.len();
        if boxes.len() != n * 4 || labels.len() != n {
            return Err(Error::Inference(format!(
                "inconsistent outputs: {} boxes values, {} labels, {n} scores",
                boxes.len(),
                labels.len()
            )));
        }
        let keep: Vec<usize> = (0..n).filter(|&i| scores[i] >= min_score).collect();
        let mut det = RawDetections::default();
        for &i in &keep {
            det.boxes.push([boxes[4 * i], boxes[4 * i + 1], boxes[4 * i + 2], boxes[4 * i + 3]]);
            det.labels.push(labels[i]);
            det.scores.push(scores[i]);
        }
        if let Some((mi, bi)) = self.slots.paste {
            let probs = view(mi, "pasted masks")?;
            let pbox = i64_values(&out[bi], "paste boxes")?;
            let shape = out[mi].shape();
            let m = shape.last().copied().unwrap_or(0);
            if shape.len() != 4 || shape[0] != n || m == 0 || pbox.len() != n * 4 {
                return Err(Error::Inference(format!(
                    "pasted masks {shape:?} / boxes {} for {n} detections",
                    pbox.len()
                )));
            }
            for &i in &keep {
                let mut full = vec![0f32; w * h];
                let b = [pbox[4 * i], pbox[4 * i + 1], pbox[4 * i + 2], pbox[4 * i + 3]];
                paste::paste_mask(&probs[i * m * m..(i + 1) * m * m], m, b, h, w, &mut full);
                det.masks.push(full);
            }
        } else if let Some(mi) = self.slots.masks {
            let probs = view(mi, "masks")?;
            if probs.len() != n * w * h {
                return Err(Error::Inference(format!(
                    "masks hold {} values for {n} detections of {w}x{h}",
                    probs.len()
                )));
            }
            for &i in &keep {
                det.masks.push(probs[i * w * h..(i + 1) * w * h].to_vec());
            }
        }
        Ok(det)
    }
}

/// An integer output (int64, or TDim where tract typed a shape computation) as `i64`s.
fn i64_values(t: &TValue, what: &str) -> Result<Vec<i64>> {
    let err = |e: TractError| Error::Inference(format!("{what}: {e:#}"));
    let t = t.cast_to::<i64>().map_err(err)?;
    t.try_as_plain_ram().and_then(|p| p.as_slice::<i64>().map(<[i64]>::to_vec)).map_err(err)
}
