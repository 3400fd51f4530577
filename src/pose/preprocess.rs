//! Pose-network inputs from an RGB-D frame and an instance mask, exactly as the training
//! pipeline builds them (tools/README.md, "Preprocessing"; tools/tricons_pose/data.py).
//!
//! Steps 1-6 are deterministic and reproduce the Python bit for bit (float64 arithmetic in
//! the same order, rounded to float32 at the end); step 7, the choice of `n_points` of the
//! valid pixels, uses the project's own seeded RNG.

use crate::frame::{ColorImage, DepthImage, Intrinsics};
use crate::rng::Rng;

/// AG-Pose's crop sizes are multiples of this (pixels).
pub const CROP_STEP_PX: usize = 40;
/// Largest crop side (pixels).
pub const MAX_CROP_PX: usize = 440;
/// An instance needs MORE than this many valid pixels (mask AND depth > 0).
pub const MIN_VALID_PIXELS: usize = 16;
/// ImageNet mean of the RGB normalisation.
pub const IMAGENET_MEAN: [f64; 3] = [0.485, 0.456, 0.406];
/// ImageNet standard deviation of the RGB normalisation.
pub const IMAGENET_STD: [f64; 3] = [0.229, 0.224, 0.225];

/// Sizes and constants of the preprocessing (from the model card's `preprocessing`).
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
pub struct PreprocessConfig {
    /// Points per instance (N).
    pub n_points: usize,
    /// Side of the resized colour crop (S).
    pub crop_size: usize,
    /// Instances need more valid pixels than this.
    pub min_valid_pixels: usize,
    /// Crop sides are multiples of this.
    pub crop_step_px: usize,
    /// Largest crop side.
    pub max_crop_px: usize,
    /// RGB normalisation mean.
    pub rgb_mean: [f64; 3],
    /// RGB normalisation standard deviation.
    pub rgb_std: [f64; 3],
}

impl PreprocessConfig {
    /// AG-Pose constants with the given N and S.
    pub fn new(n_points: usize, crop_size: usize) -> PreprocessConfig {
        PreprocessConfig {
            n_points,
            crop_size,
            min_valid_pixels: MIN_VALID_PIXELS,
            crop_step_px: CROP_STEP_PX,
            max_crop_px: MAX_CROP_PX,
            rgb_mean: IMAGENET_MEAN,
            rgb_std: IMAGENET_STD,
        }
    }
}

/// A square crop window, end-exclusive: rows `rmin..rmax`, columns `cmin..cmax`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CropWindow {
    /// First row.
    pub rmin: usize,
    /// One past the last row.
    pub rmax: usize,
    /// First column.
    pub cmin: usize,
    /// One past the last column.
    pub cmax: usize,
}

impl CropWindow {
    /// Side length in pixels.
    pub fn side(&self) -> usize {
        self.rmax - self.rmin
    }
}

/// Bounding box `(y0, y1, x0, x1)` (end-exclusive) of the set pixels of a row-major mask.
pub fn mask_bbox(mask: &[bool], width: usize) -> Option<(usize, usize, usize, usize)> {
    let (mut y0, mut y1, mut x0, mut x1) = (usize::MAX, 0, usize::MAX, 0);
    for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        let (y, x) = (i / width, i % width);
        y0 = y0.min(y);
        y1 = y1.max(y + 1);
        x0 = x0.min(x);
        x1 = x1.max(x + 1);
    }
    (y0 != usize::MAX).then_some((y0, y1, x0, x1))
}

/// AG-Pose's square crop around a bbox, shifted (not shrunk) into the image.
pub fn crop_window(
    bbox: (usize, usize, usize, usize),
    img_h: usize,
    img_w: usize,
    cfg: &PreprocessConfig,
) -> CropWindow {
    let (y0, y1, x0, x1) = bbox;
    let side = ((y1 - y0).max(x1 - x0) / cfg.crop_step_px + 1) * cfg.crop_step_px;
    let side = side.min(cfg.max_crop_px).min(img_h).min(img_w);
    let (cy, cx) = ((y0 + y1) / 2, (x0 + x1) / 2);
    let place =
        |centre: usize, limit: usize| (centre as i64 - (side / 2) as i64).clamp(0, (limit - side) as i64) as usize;
    let (rmin, cmin) = (place(cy, img_h), place(cx, img_w));
    CropWindow { rmin, rmax: rmin + side, cmin, cmax: cmin + side }
}

/// The deterministic part for one instance: crop window and valid pixels.
#[derive(Clone, Debug, PartialEq)]
pub struct PreparedInstance {
    /// Crop window.
    pub window: CropWindow,
    /// Row-major indices in the `side x side` crop of the valid pixels, ascending.
    pub choose_all: Vec<u32>,
    /// Raw depth of those pixels (sensor units).
    pub depth_raw: Vec<u16>,
}

impl PreparedInstance {
    /// Number of valid pixels.
    pub fn n_valid(&self) -> usize {
        self.choose_all.len()
    }
}

/// Steps 1-4: bbox of the mask, crop window, valid pixels (mask AND depth > 0) inside it.
/// `None` for an empty mask. `mask` is row-major at the depth image's size.
pub fn prepare_instance(depth: &DepthImage, mask: &[bool], cfg: &PreprocessConfig) -> Option<PreparedInstance> {
    let (w, h) = (depth.width as usize, depth.height as usize);
    let window = crop_window(mask_bbox(mask, w)?, h, w, cfg);
    let side = window.side();
    let mut choose_all = Vec::new();
    let mut depth_raw = Vec::new();
    for r in 0..side {
        let row = (window.rmin + r) * w + window.cmin;
        for c in 0..side {
            let d = depth.data[row + c];
            if mask[row + c] && d > 0 {
                choose_all.push((r * side + c) as u32);
                depth_raw.push(d);
            }
        }
    }
    Some(PreparedInstance { window, choose_all, depth_raw })
}

/// Step 7: `n` positions in `0..n_valid`: without replacement (a random subset in random
/// order) when there are enough valid pixels, else uniform draws with replacement.
pub fn sample_indices(n_valid: usize, n: usize, rng: &mut Rng) -> Vec<usize> {
    if n_valid >= n {
        let mut all: Vec<usize> = (0..n_valid).collect();
        for i in 0..n {
            let j = i + rng.below(n_valid - i);
            all.swap(i, j);
        }
        all.truncate(n);
        all
    } else {
        (0..n).map(|_| rng.below(n_valid)).collect()
    }
}

/// The three network inputs of one instance.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseInput {
    /// `(3, S, S)` normalised colour crop.
    pub rgb: Vec<f32>,
    /// `(N, 3)` camera-frame points, metres.
    pub pts: Vec<f32>,
    /// `(N,)` pixel index on the `S x S` grid.
    pub choose: Vec<i64>,
}

/// Steps 5-6 for the sampled positions `sample_idx` (into `prep.choose_all`).
pub fn build_input(
    color: &ColorImage,
    depth_scale_m: f64,
    intrinsics: &Intrinsics,
    prep: &PreparedInstance,
    sample_idx: &[usize],
    cfg: &PreprocessConfig,
) -> PoseInput {
    let win = prep.window;
    let side = win.side();
    let s = cfg.crop_size;
    let mut pts = Vec::with_capacity(3 * sample_idx.len());
    let mut choose = Vec::with_capacity(sample_idx.len());
    for &i in sample_idx {
        let k = prep.choose_all[i] as usize;
        let (row, col) = (k / side, k % side);
        let v = (row + win.rmin) as f64;
        let u = (col + win.cmin) as f64;
        let z = prep.depth_raw[i] as f64 * depth_scale_m;
        pts.push(((u - intrinsics.cx) * z / intrinsics.fx) as f32);
        pts.push(((v - intrinsics.cy) * z / intrinsics.fy) as f32);
        pts.push(z as f32);
        choose.push(((row * s / side) * s + col * s / side) as i64);
    }
    PoseInput { rgb: resize_normalise(color, win, cfg), pts, choose }
}

/// Bilinear resize (half-pixel centres, no antialiasing) of the window to `S x S` in f64,
/// then `(v / 255 - mean) / std`, as `(3, S, S)` float32.
fn resize_normalise(color: &ColorImage, win: CropWindow, cfg: &PreprocessConfig) -> Vec<f32> {
    let (side, s, w) = (win.side(), cfg.crop_size, color.width as usize);
    let scale = side as f64 / s as f64;
    let taps: Vec<(usize, usize, f64)> = (0..s)
        .map(|i| {
            let c = ((i as f64 + 0.5) * scale - 0.5).max(0.0);
            let i0 = (c.floor() as usize).min(side - 1);
            (i0, (i0 + 1).min(side - 1), c - i0 as f64)
        })
        .collect();
    let px = |r: usize, c: usize, ch: usize| color.data[((win.rmin + r) * w + win.cmin + c) * 3 + ch] as f64;
    let mut out = vec![0f32; 3 * s * s];
    for (y, &(r0, r1, ly)) in taps.iter().enumerate() {
        for (x, &(c0, c1, lx)) in taps.iter().enumerate() {
            for ch in 0..3 {
                let top = (1.0 - lx) * px(r0, c0, ch) + lx * px(r0, c1, ch);
                let bot = (1.0 - lx) * px(r1, c0, ch) + lx * px(r1, c1, ch);
                let v = (1.0 - ly) * top + ly * bot;
                out[(ch * s + y) * s + x] = ((v / 255.0 - cfg.rgb_mean[ch]) / cfg.rgb_std[ch]) as f32;
            }
        }
    }
    out
}
