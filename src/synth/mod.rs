//! SynthNOCS: a deterministic generator of NOCS-style synthetic RGB-D frames
//! with ground truth (poses, sizes, instance masks, NOCS maps) for the six
//! NOCS categories. See docs/synthnocs.md for conventions and the sensor model.
//!
//! - [`mesh`] / [`shapes`]: procedural per-category meshes normalised to the NOCS frame;
//! - [`scene`]: objects on a table, distractors, room, lights, camera;
//! - [`raster`]: the z-buffer rasterizer and G-buffer;
//! - [`shading`]: materials, procedural textures, lighting;
//! - [`sensor`]: RealSense-like depth noise and colour noise;
//! - the deterministic RNG is [`crate::rng`] (shared with the runtime's point sampler).

pub mod mesh;
pub mod raster;
pub mod scene;
pub mod sensor;
pub mod shading;
pub mod shapes;

use crate::category::Category;
use crate::error::{Error, Result};
use crate::frame::{DEPTH_SCALE_MM, Intrinsics, LabelImage, NOCS_MAP_MAX, NocsMap, RgbdFrame};
use crate::geometry::Pose;
use crate::image_io::write_label_png;
use crate::recording::annotations::{FrameAnnotations, GtInstance};
use crate::recording::manifest::Manifest;
use crate::recording::writer::{RecordingWriter, WriteMode, write_frame_files};
use crate::rng::Rng;
use raster::NO_ITEM;
use rayon::prelude::*;
use std::path::Path;
use std::str::FromStr;

/// Version of the generator; bumped whenever the same seed would give different frames.
pub const GENERATOR_VERSION: u32 = 1;
/// Default fewest visible pixels for an instance to be annotated.
pub const MIN_VISIBLE_PX: usize = 200;
/// Fewest visible handle pixels for a mug's `handle_visible` to be true.
pub const MIN_HANDLE_PX: usize = 40;
/// Scene resamplings tried before a frame is accepted without annotations.
pub const MAX_SCENE_ATTEMPTS: u64 = 64;
/// Frame rate used for the recording's timestamps (frame i at i / FPS seconds).
pub const TIMESTAMP_FPS: f64 = 30.0;
/// Default seed of the train split (used when the user gives none).
pub const DEFAULT_TRAIN_SEED: u64 = 1;
/// Seed of SynthNOCS-val.
pub const VAL_SEED: u64 = 20_250_002;
/// Seed of SynthNOCS-test.
pub const TEST_SEED: u64 = 20_250_003;

const STREAM_SCENE: u64 = 0x5C3E;
const STREAM_SENSOR: u64 = 0x5E45;

/// Generator settings. [`Default`] gives the benchmark's settings.
#[derive(Clone, Debug, PartialEq)]
pub struct SynthConfig {
    /// Camera intrinsics (and image size) of the rendered frames.
    pub intrinsics: Intrinsics,
    /// Fewest NOCS objects sampled per scene (>= 1).
    pub min_objects: usize,
    /// Most NOCS objects sampled per scene (<= 255).
    pub max_objects: usize,
    /// Most distractor objects per scene.
    pub max_distractors: usize,
    /// Apply the RealSense-like depth noise and dropouts (otherwise exact depth, mm-quantised).
    pub depth_noise: bool,
    /// Add mild noise to the colour image.
    pub color_noise: bool,
    /// Fewest visible pixels for an instance to be annotated.
    pub min_visible_px: usize,
    /// Also make a mask of the distractors ([`SynthFrame::distractors`], written as
    /// `{id}_distractors.png`): training data for a segmenter's "other" class. The frame's
    /// other files do not change.
    pub distractor_masks: bool,
}

impl Default for SynthConfig {
    fn default() -> Self {
        SynthConfig {
            intrinsics: Intrinsics::REAL275,
            min_objects: 1,
            max_objects: 6,
            max_distractors: 4,
            depth_noise: true,
            color_noise: true,
            min_visible_px: MIN_VISIBLE_PX,
            distractor_masks: false,
        }
    }
}

impl SynthConfig {
    /// Checks the settings.
    pub fn validate(&self) -> std::result::Result<(), String> {
        self.intrinsics.validate()?;
        if self.min_objects == 0 || self.min_objects > self.max_objects || self.max_objects > 255 {
            return Err(format!(
                "objects per scene {}..={} must satisfy 1 <= min <= max <= 255",
                self.min_objects, self.max_objects
            ));
        }
        if self.max_distractors > 64 {
            return Err(format!("max_distractors {} is more than 64", self.max_distractors));
        }
        Ok(())
    }
}

/// One rendered frame with its ground truth.
#[derive(Clone, Debug, PartialEq)]
pub struct SynthFrame {
    /// Colour and (noisy) depth, registered; timestamp `index / 30` s.
    pub frame: RgbdFrame,
    /// Annotated instances, instance mask and NOCS map.
    pub annotations: FrameAnnotations,
    /// With [`SynthConfig::distractor_masks`]: the distractors with at least
    /// `min_visible_px` visible pixels, ids 1..=n in scene order (0: no distractor).
    pub distractors: Option<LabelImage>,
}

/// Renders frame `index` of the dataset with `seed`. Pure and deterministic:
/// the same (config, seed, index) gives the same frame on the same binary.
pub fn render_frame(cfg: &SynthConfig, seed: u64, index: u64) -> SynthFrame {
    let k = cfg.intrinsics;
    let mut attempt = 0;
    loop {
        let sc = frame_scene(cfg, seed, index, attempt);
        let gb = raster::render(&sc, &k);
        let n_obj = sc.objects.len();
        let mut visible = vec![0usize; n_obj];
        let mut handle_px = vec![0usize; n_obj];
        for (i, &it) in gb.item.iter().enumerate() {
            let it = usize::from(it);
            if it < n_obj {
                visible[it] += 1;
                if gb.handle[i] {
                    handle_px[it] += 1;
                }
            }
        }
        let annotated: Vec<usize> = (0..n_obj).filter(|&o| visible[o] >= cfg.min_visible_px.max(1)).collect();
        attempt += 1;
        if annotated.is_empty() && attempt < MAX_SCENE_ATTEMPTS {
            continue;
        }
        // Instance ids 1..=n in object order.
        let mut id_of = vec![0u8; usize::from(NO_ITEM) + 1];
        let mut instances = Vec::with_capacity(annotated.len());
        for (n, &o) in annotated.iter().enumerate() {
            let id = (n + 1) as u8;
            id_of[o] = id;
            let obj = &sc.objects[o];
            instances.push(GtInstance {
                id,
                class: obj.category,
                camera_from_object: obj.camera_from_object,
                size_m: obj.size_m,
                handle_visible: obj.category != Category::Mug || handle_px[o] >= MIN_HANDLE_PX,
            });
        }
        let (w, h) = (k.width, k.height);
        let mut mask = LabelImage::new(w, h);
        let mut nocs = NocsMap::new(w, h);
        let scale = f32::from(NOCS_MAP_MAX);
        for (i, &it) in gb.item.iter().enumerate() {
            let id = id_of[usize::from(it)];
            if id == 0 {
                continue;
            }
            mask.data[i] = id;
            for c in 0..3 {
                nocs.data[3 * i + c] = (gb.nocs[i][c].clamp(0.0, 1.0) * scale).round() as u16;
            }
        }
        let mut srng = Rng::from_words(&[seed, index, attempt - 1, STREAM_SENSOR]);
        let depth = sensor::depth_image(&gb, cfg.depth_noise, &mut srng);
        let color = sensor::color_image(&gb, cfg.color_noise.then_some(&mut srng));
        let frame = RgbdFrame { color, depth, intrinsics: k, timestamp_s: index as f64 / TIMESTAMP_FPS };
        let distractors = cfg.distractor_masks.then(|| distractor_mask(&sc, &gb.item, w, h, cfg.min_visible_px));
        return SynthFrame {
            frame,
            annotations: FrameAnnotations { instances, mask: Some(mask), nocs: Some(nocs) },
            distractors,
        };
    }
}

/// The label image of `sc`'s distractors from the rasterizer's per-pixel item indices:
/// those with at least `min_visible_px` pixels (at least 1) get ids 1..=n in scene order
/// (at most 255), the rest of the image 0.
fn distractor_mask(
    sc: &scene::Scene,
    item_of_pixel: &[u16],
    width: u32,
    height: u32,
    min_visible_px: usize,
) -> LabelImage {
    let mut visible = vec![0usize; sc.items.len()];
    for &it in item_of_pixel {
        if let Some(v) = visible.get_mut(usize::from(it)) {
            *v += 1;
        }
    }
    let mut id_of = vec![0u8; sc.items.len()];
    let mut next = 1u8;
    for (i, item) in sc.items.iter().enumerate() {
        if item.distractor && visible[i] >= min_visible_px.max(1) && next < u8::MAX {
            id_of[i] = next;
            next += 1;
        }
    }
    let mut mask = LabelImage::new(width, height);
    for (p, &it) in item_of_pixel.iter().enumerate() {
        mask.data[p] = id_of.get(usize::from(it)).copied().unwrap_or(0);
    }
    mask
}

/// The scene of attempt `attempt` of frame `index` (camera frame = colour camera).
fn frame_scene(cfg: &SynthConfig, seed: u64, index: u64, attempt: u64) -> scene::Scene {
    let params = scene::SceneParams {
        min_objects: cfg.min_objects.max(1),
        max_objects: cfg.max_objects.clamp(cfg.min_objects.max(1), 255),
        max_distractors: cfg.max_distractors,
    };
    let mut rng = Rng::from_words(&[seed, index, attempt, STREAM_SCENE]);
    scene::sample_scene(&params, &mut rng)
}

/// Exact depth (metres, 0 where nothing was hit) of frame `index`'s scene as a
/// second sensor sees it: a camera with intrinsics `sensor` placed at
/// `sensor_from_color` relative to the colour camera. This is what a depth
/// sensor beside the colour camera measures before registration; it exists to
/// test depth-to-colour registration against ground truth.
pub fn render_sensor_depth(
    cfg: &SynthConfig,
    seed: u64,
    index: u64,
    sensor: &Intrinsics,
    sensor_from_color: &Pose,
) -> Vec<f32> {
    // The same scene as render_frame: replay its attempts until one has an annotated object.
    let mut attempt = 0;
    let mut sc = loop {
        let sc = frame_scene(cfg, seed, index, attempt);
        attempt += 1;
        if attempt >= MAX_SCENE_ATTEMPTS {
            break sc;
        }
        let gb = raster::render(&sc, &cfg.intrinsics);
        let n_obj = sc.objects.len();
        let mut visible = vec![0usize; n_obj];
        for &it in &gb.item {
            if usize::from(it) < n_obj {
                visible[usize::from(it)] += 1;
            }
        }
        if visible.iter().any(|&v| v >= cfg.min_visible_px.max(1)) {
            break sc;
        }
    };
    for item in &mut sc.items {
        item.camera_from_local = sensor_from_color.compose(&item.camera_from_local);
    }
    raster::render(&sc, sensor).depth_m
}

/// Renders `frames` frames with `seed` and writes them as a tricons recording
/// in `out_dir` (frame ids `{index:06}`, timestamps index / 30 s). Frames are
/// rendered and encoded in parallel (rayon) in chunks, and entries are added
/// to the manifest in index order; `progress(frames_done)` is called after
/// each chunk. The output files depend only on (config, seed, frames).
pub fn generate(
    out_dir: &Path,
    cfg: &SynthConfig,
    seed: u64,
    frames: usize,
    overwrite: bool,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Manifest> {
    cfg.validate().map_err(Error::InvalidArgument)?;
    let mut manifest = Manifest::new(cfg.intrinsics, DEPTH_SCALE_MM);
    manifest.source = Some(format!("synthnocs seed={seed} frames={frames} generator=v{GENERATOR_VERSION}"));
    let mode = if overwrite { WriteMode::Overwrite } else { WriteMode::New };
    let mut writer = RecordingWriter::create(out_dir, manifest, mode)?;
    let chunk = (rayon::current_num_threads() * 4).max(8);
    let mut done = 0;
    while done < frames {
        let end = (done + chunk).min(frames);
        let entries: Vec<Result<_>> = (done..end)
            .into_par_iter()
            .map(|i| {
                let f = render_frame(cfg, seed, i as u64);
                let id = format!("{i:06}");
                if let Some(distractors) = &f.distractors {
                    write_label_png(&out_dir.join(format!("{id}_distractors.png")), distractors)?;
                }
                write_frame_files(out_dir, &id, &f.frame, Some(&f.annotations))
            })
            .collect();
        for e in entries {
            writer.push_entry(e?)?;
        }
        done = end;
        progress(done);
    }
    writer.finish()
}

/// The fixed SynthNOCS splits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Split {
    /// Training data: any size, user seed (default [`DEFAULT_TRAIN_SEED`]).
    Train,
    /// SynthNOCS-val: seed [`VAL_SEED`], 200 frames.
    Val,
    /// SynthNOCS-test: seed [`TEST_SEED`], 500 frames.
    Test,
}

impl Split {
    /// The split's seed (the default seed for train).
    pub const fn seed(self) -> u64 {
        match self {
            Split::Train => DEFAULT_TRAIN_SEED,
            Split::Val => VAL_SEED,
            Split::Test => TEST_SEED,
        }
    }

    /// The split's number of frames (a default for train).
    pub fn default_frames(self) -> usize {
        match self {
            Split::Train => 2000,
            Split::Val => 200,
            Split::Test => 500,
        }
    }

    /// "train", "val" or "test".
    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Val => "val",
            Split::Test => "test",
        }
    }
}

impl std::fmt::Display for Split {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Split {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, Self::Err> {
        match s {
            "train" => Ok(Split::Train),
            "val" => Ok(Split::Val),
            "test" => Ok(Split::Test),
            _ => Err(format!("unknown split {s:?} (expected train, val or test)")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_seeds_differ_and_parse() {
        assert_ne!(Split::Val.seed(), Split::Test.seed());
        assert_ne!(Split::Val.seed(), Split::Train.seed());
        assert_ne!(Split::Test.seed(), Split::Train.seed());
        for s in [Split::Train, Split::Val, Split::Test] {
            assert_eq!(s.name().parse::<Split>(), Ok(s));
        }
        assert!("dev".parse::<Split>().is_err());
        assert_eq!(Split::Val.default_frames(), 200);
        assert_eq!(Split::Test.default_frames(), 500);
    }

    #[test]
    fn small_frame_renders_with_annotations() {
        let cfg = SynthConfig {
            intrinsics: Intrinsics { width: 160, height: 120, fx: 147.75, fy: 147.54, cx: 80.6, cy: 61.0 },
            min_visible_px: 30,
            ..SynthConfig::default()
        };
        let f = render_frame(&cfg, 5, 0);
        assert!(!f.annotations.instances.is_empty());
        assert_eq!(f.frame.color.data.len(), 160 * 120 * 3);
    }
}
