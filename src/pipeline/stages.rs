//! The two inference stages and their built-in implementations.
//!
//! [`Segment`] turns a frame into instance masks (Mask R-CNN, or the
//! recording's ground truth); [`Estimate`] turns masks into poses (the
//! TriCons-Pose network). `tricons replay` and `tricons serve` share them.

use crate::capture::SourceFrame;
use crate::category::Category;
use crate::error::{Error, Result};
use crate::frame::RgbdFrame;
use crate::output::PredInstance;
use crate::pose::{PoseEstimator, Skipped};
use crate::recording::FrameAnnotations;
use crate::segment::Segmenter;
use crate::segment::published::PublishedDetections;

/// One instance to estimate: category, score, optional 2D box and full-image mask.
#[derive(Clone, Debug, PartialEq)]
pub struct Detection {
    /// NOCS category.
    pub class: Category,
    /// Detection confidence in [0, 1].
    pub score: f64,
    /// Box `[x0, y0, x1, y1]` in pixels, when the segmenter gives one.
    pub box2d: Option<[f64; 4]>,
    /// Row-major mask of the colour image's size.
    pub mask: Vec<bool>,
}

/// The masks stage.
pub trait Segment: Send {
    /// The frame's instances.
    fn segment(&mut self, frame: &SourceFrame) -> Result<Vec<Detection>>;
    /// Detections dropped as duplicates so far (0 for a stage that never drops any).
    /// Workers made by [`Segment::fork`] share one count.
    fn duplicates_dropped(&self) -> u64 {
        0
    }
    /// Detections of no NOCS category (a segmenter's "other") left out so far, after they
    /// took part in the duplicate suppression (0 for a stage that has none). Workers made by
    /// [`Segment::fork`] share one count.
    fn not_nocs_dropped(&self) -> u64 {
        0
    }
    /// Another worker of this stage, sharing its model, so that several frames are
    /// segmented at once ([`crate::pipeline::PipelineBuilder::segment_workers`]); `None`
    /// (the default) when the stage cannot run side by side with itself.
    fn fork(&self) -> Option<Box<dyn Segment>> {
        None
    }
}

/// The pose stage.
pub trait Estimate: Send {
    /// Poses of the frame's detections; a detection that cannot be estimated
    /// (too few depth pixels) is left out.
    fn estimate(&mut self, frame: &SourceFrame, detections: &[Detection]) -> Result<Vec<PredInstance>>;
    /// Poses left unreported so far because their score lay below the pose card's
    /// `min_score` (0 for a stage that never drops any).
    fn low_scores_dropped(&self) -> u64 {
        0
    }
}

/// Detections from a Mask R-CNN on `frame`'s colour image: instances of a NOCS category
/// only ([`Segmenter::segment_nocs`]), each mask as the pose stage takes it
/// ([`Segmenter::pose_mask`]: eroded and without depth outliers when the card says so).
pub fn detections_from_segmenter(segmenter: &Segmenter, frame: &RgbdFrame) -> Result<Vec<Detection>> {
    Ok(segmenter
        .segment_nocs(&frame.color)?
        .into_iter()
        .map(|(class, d)| Detection {
            class,
            score: f64::from(d.score),
            box2d: Some(d.box_xyxy.map(f64::from)),
            mask: segmenter.pose_mask(d.mask, frame, class),
        })
        .collect())
}

impl Segment for Segmenter {
    fn segment(&mut self, frame: &SourceFrame) -> Result<Vec<Detection>> {
        detections_from_segmenter(self, &frame.frame)
    }
    fn duplicates_dropped(&self) -> u64 {
        Segmenter::duplicates_dropped(self)
    }
    fn not_nocs_dropped(&self) -> u64 {
        Segmenter::not_nocs_dropped(self)
    }
}

/// A Mask R-CNN shared by several segment workers: its plans are built once and each
/// run has its own state, so the workers only share read-only weights.
impl Segment for std::sync::Arc<Segmenter> {
    fn segment(&mut self, frame: &SourceFrame) -> Result<Vec<Detection>> {
        detections_from_segmenter(self, &frame.frame)
    }
    fn duplicates_dropped(&self) -> u64 {
        Segmenter::duplicates_dropped(self)
    }
    fn not_nocs_dropped(&self) -> u64 {
        Segmenter::not_nocs_dropped(self)
    }
    fn fork(&self) -> Option<Box<dyn Segment>> {
        Some(Box::new(std::sync::Arc::clone(self)))
    }
}

/// Ground-truth instance masks (score 1) from the source's annotations.
#[derive(Clone, Copy, Debug, Default)]
pub struct GroundTruthMasks;

impl Segment for GroundTruthMasks {
    fn fork(&self) -> Option<Box<dyn Segment>> {
        Some(Box::new(*self))
    }
    fn segment(&mut self, frame: &SourceFrame) -> Result<Vec<Detection>> {
        let missing = |what: &str| {
            Error::InvalidArgument(format!(
                "frame {}: {what} (ground-truth masks need an annotated recording)",
                frame.id
            ))
        };
        let ann = frame.annotations.as_ref().ok_or_else(|| missing("no annotations"))?;
        detections_from_annotations(ann).ok_or_else(|| missing("annotations without an instance mask"))
    }
}

/// Published Mask R-CNN detections (the result pickles distributed with SPD, DualPoseNet,
/// AG-Pose), looked up by the frame's id in scene `scene`.
pub struct PublishedMasks {
    detections: PublishedDetections,
    scene: String,
}

impl PublishedMasks {
    /// The detections of `detections`' files for the frames of `scene` (the recording's name).
    pub fn new(detections: PublishedDetections, scene: &str) -> PublishedMasks {
        PublishedMasks { detections, scene: scene.to_string() }
    }
}

impl Segment for PublishedMasks {
    fn segment(&mut self, frame: &SourceFrame) -> Result<Vec<Detection>> {
        let path = self.detections.file_for(&self.scene, &frame.id)?;
        PublishedDetections::read(&path, frame.frame.color.width, frame.frame.color.height)
    }
}

/// Ground-truth detections (score 1) of an annotated frame; `None` without an instance mask.
pub fn detections_from_annotations(ann: &FrameAnnotations) -> Option<Vec<Detection>> {
    let masks = ann.instance_masks()?;
    Some(
        ann.instances
            .iter()
            .zip(masks)
            .map(|(g, mask)| Detection { class: g.class, score: 1.0, box2d: None, mask })
            .collect(),
    )
}

/// The pose network as a stage; frame `seq` samples its points from `(seed, seq)`.
pub struct PoseStage {
    estimator: PoseEstimator,
    seed: u64,
    low_scores_dropped: u64,
}

impl PoseStage {
    /// Wraps a loaded estimator.
    pub fn new(estimator: PoseEstimator, seed: u64) -> PoseStage {
        PoseStage { estimator, seed, low_scores_dropped: 0 }
    }
}

/// Why a detection has no reported pose.
#[derive(Clone, Debug, PartialEq)]
pub enum NotReported {
    /// The pose network could not run on it.
    Skipped(Skipped),
    /// Its reported score (given here) lies below the pose card's `min_score`.
    BelowMinScore(f64),
}

impl std::fmt::Display for NotReported {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            NotReported::Skipped(Skipped::EmptyMask) => write!(f, "empty mask"),
            NotReported::Skipped(Skipped::TooFewValidPixels(n)) => write!(f, "{n} valid pixels"),
            NotReported::Skipped(Skipped::NonFiniteOutput) => write!(f, "non-finite network output"),
            NotReported::BelowMinScore(score) => write!(f, "score {score:.3} below the card's min_score"),
        }
    }
}

/// A detection without a reported pose: its index and why.
pub type SkippedDetection = (usize, NotReported);

/// Poses of `detections` in `frame` with the point sampling seeded by `seed`;
/// also returns each unreported instance's index and reason (skipped by the network, or
/// scored below the pose card's `min_score`).
pub fn estimate_detections(
    estimator: &PoseEstimator,
    frame: &crate::frame::RgbdFrame,
    detections: &[Detection],
    seed: u64,
) -> Result<(Vec<PredInstance>, Vec<SkippedDetection>)> {
    let masks: Vec<&[bool]> = detections.iter().map(|d| d.mask.as_slice()).collect();
    let outcomes = estimator.estimate(frame, &masks, seed)?;
    let (mut instances, mut skipped) = (Vec::new(), Vec::new());
    for (k, (d, o)) in detections.iter().zip(outcomes).enumerate() {
        match o {
            Ok(e) => {
                let score = estimator.score(&e, d.score);
                if estimator.card().min_score.is_some_and(|min| score < min) {
                    skipped.push((k, NotReported::BelowMinScore(score)));
                    continue;
                }
                instances.push(PredInstance {
                    class: d.class,
                    score,
                    camera_from_object: estimator.camera_from_object(&e, d.class),
                    size_m: e.size_m,
                    box2d: d.box2d,
                    mask: None,
                })
            }
            Err(why) => skipped.push((k, NotReported::Skipped(why))),
        }
    }
    Ok((instances, skipped))
}

impl Estimate for PoseStage {
    fn estimate(&mut self, frame: &SourceFrame, detections: &[Detection]) -> Result<Vec<PredInstance>> {
        let seed = crate::rng::mix_seed(&[self.seed, frame.seq]);
        let (instances, skipped) = estimate_detections(&self.estimator, &frame.frame, detections, seed)?;
        for (k, why) in skipped {
            if matches!(why, NotReported::BelowMinScore(_)) {
                self.low_scores_dropped += 1;
            }
            log::debug!("frame {} instance {k}: not reported ({why})", frame.id);
        }
        Ok(instances)
    }
    fn low_scores_dropped(&self) -> u64 {
        self.low_scores_dropped
    }
}
