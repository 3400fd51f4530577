//! RoiAlign kernels on slices.
//!
//! Per ROI the sampling positions and bilinear weights are computed once
//! (they do not depend on the channel), then every channel is pooled from
//! them, exactly as onnxruntime's `RoiAlignForward` does (same float order):
//! [`roi_align_reference`], one channel plane at a time. [`roi_align`] gives the same
//! bits with the feature map transposed to channels-last once per call, so that each
//! bilinear tap reads a contiguous channel vector and the per-channel arithmetic (the
//! same operations in the same order, no fused multiply-add) runs as one vectorisable
//! loop over the channels.

use crate::ops::{OpResult, check_len, checked_index};

/// How a bin's samples are combined.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PoolMode {
    /// Mean of the bilinear samples.
    Avg,
    /// onnxruntime's max: per sample the largest weighted corner, then the largest sample.
    Max,
}

/// Attributes of one RoiAlign node.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RoiAlignParams {
    /// Output bins per ROI, vertically.
    pub output_height: usize,
    /// Output bins per ROI, horizontally.
    pub output_width: usize,
    /// Samples per bin and axis; 0 = adaptive (`ceil(roi_size / bins)`).
    pub sampling_ratio: usize,
    /// Multiplies ROI coordinates (image pixels) into feature-map pixels.
    pub spatial_scale: f32,
    /// `half_pixel` shifts by -0.5 (torchvision `aligned=True`); `output_half_pixel`
    /// does not and makes every ROI at least 1 x 1.
    pub half_pixel: bool,
    /// Pooling mode.
    pub mode: PoolMode,
}

/// One bilinear sample: four flat positions in the channel plane and their weights.
#[derive(Clone, Copy, Debug, Default)]
struct Sample {
    pos: [usize; 4],
    w: [f32; 4],
}

/// onnxruntime's clamping of one sample coordinate on an axis of `size` cells: the two
/// neighbouring cells and the fractional weight of the upper one.
fn axis_taps(mut v: f32, size: usize) -> (usize, usize, f32) {
    if v <= 0.0 {
        v = 0.0;
    }
    let low = v as usize;
    if low >= size - 1 { (size - 1, size - 1, 0.0) } else { (low, low + 1, v - low as f32) }
}

fn bilinear_sample(y: f32, x: f32, height: usize, width: usize) -> Sample {
    if y < -1.0 || y > height as f32 || x < -1.0 || x > width as f32 {
        return Sample::default();
    }
    let (y_low, y_high, ly) = axis_taps(y, height);
    let (x_low, x_high, lx) = axis_taps(x, width);
    let (hy, hx) = (1.0 - ly, 1.0 - lx);
    Sample {
        pos: [y_low * width + x_low, y_low * width + x_high, y_high * width + x_low, y_high * width + x_high],
        w: [hy * hx, hy * lx, ly * hx, ly * lx],
    }
}

/// The geometry of one ROI: the samples of every bin (bin-major), samples per bin, and
/// the averaging divisor.
fn roi_samples(
    roi: &[f32],
    height: usize,
    width: usize,
    p: &RoiAlignParams,
    samples: &mut Vec<Sample>,
) -> (usize, f32) {
    let (ph_n, pw_n) = (p.output_height, p.output_width);
    let offset = if p.half_pixel { 0.5f32 } else { 0.0 };
    let start_w = roi[0] * p.spatial_scale - offset;
    let start_h = roi[1] * p.spatial_scale - offset;
    let end_w = roi[2] * p.spatial_scale - offset;
    let end_h = roi[3] * p.spatial_scale - offset;
    let (mut roi_w, mut roi_h) = (end_w - start_w, end_h - start_h);
    if !p.half_pixel {
        roi_w = roi_w.max(1.0);
        roi_h = roi_h.max(1.0);
    }
    let bin_h = roi_h / ph_n as f32;
    let bin_w = roi_w / pw_n as f32;
    let grid_h = if p.sampling_ratio > 0 { p.sampling_ratio } else { (roi_h / ph_n as f32).ceil().max(0.0) as usize };
    let grid_w = if p.sampling_ratio > 0 { p.sampling_ratio } else { (roi_w / pw_n as f32).ceil().max(0.0) as usize };
    let count = (grid_h * grid_w).max(1) as f32;
    samples.clear();
    for ph in 0..ph_n {
        for pw in 0..pw_n {
            for iy in 0..grid_h {
                let y = start_h + ph as f32 * bin_h + (iy as f32 + 0.5) * bin_h / grid_h as f32;
                for ix in 0..grid_w {
                    let x = start_w + pw as f32 * bin_w + (ix as f32 + 0.5) * bin_w / grid_w as f32;
                    samples.push(bilinear_sample(y, x, height, width));
                }
            }
        }
    }
    (grid_h * grid_w, count)
}

/// Argument checks shared by both kernels.
fn check_args(
    features: &[f32],
    (n, c, height, width): (usize, usize, usize, usize),
    rois: &[f32],
    batch_indices: &[i64],
    p: &RoiAlignParams,
    out: &[f32],
) -> OpResult {
    let r = batch_indices.len();
    check_len(OP, "features", features.len(), n * c * height * width)?;
    check_len(OP, "rois", rois.len(), r * 4)?;
    check_len(OP, "output", out.len(), r * c * p.output_height * p.output_width)?;
    for &b in batch_indices {
        checked_index(OP, b, n)?;
    }
    Ok(())
}

const OP: &str = "RoiAlign";

/// RoiAlign over a `(n, c, height, width)` feature map: [`roi_align_reference`]'s
/// results, bit for bit, computed channels-last.
///
/// `rois` is `(r, 4)` as `(x1, y1, x2, y2)` in image pixels, `batch_indices` `(r,)`;
/// `out` is `(r, c, output_height, output_width)`.
pub fn roi_align(
    features: &[f32],
    (n, c, height, width): (usize, usize, usize, usize),
    rois: &[f32],
    batch_indices: &[i64],
    p: &RoiAlignParams,
    out: &mut [f32],
) -> OpResult {
    check_args(features, (n, c, height, width), rois, batch_indices, p, out)?;
    if height == 0 || width == 0 {
        out.fill(0.0);
        return Ok(());
    }
    let plane = height * width;
    let bins = p.output_height * p.output_width;
    if c == 0 || bins == 0 {
        return Ok(()); // `out` is empty
    }
    // channels-last copies of the batch items the ROIs use, made on first use
    let mut hwc: Vec<Option<Vec<f32>>> = vec![None; n];
    let mut samples = Vec::new();
    let mut acc = vec![0f32; bins * c];
    for (ri, roi) in rois.chunks_exact(4).enumerate() {
        let b = batch_indices[ri] as usize;
        let map = hwc[b].get_or_insert_with(|| {
            let chw = &features[b * c * plane..(b + 1) * c * plane];
            let mut t = vec![0f32; plane * c];
            for (ci, src) in chw.chunks_exact(plane).enumerate() {
                for (pos, &v) in src.iter().enumerate() {
                    t[pos * c + ci] = v;
                }
            }
            t
        });
        let (per_bin, count) = roi_samples(roi, height, width, p, &mut samples);
        for (bin, a) in acc.chunks_exact_mut(c).enumerate() {
            a.fill(0.0);
            let row = |pos: usize| &map[pos * c..(pos + 1) * c];
            for (k, s) in samples[bin * per_bin..(bin + 1) * per_bin].iter().enumerate() {
                let (x0, x1, x2, x3) = (row(s.pos[0]), row(s.pos[1]), row(s.pos[2]), row(s.pos[3]));
                let [w0, w1, w2, w3] = s.w;
                match p.mode {
                    PoolMode::Avg => {
                        for ((((o, &v0), &v1), &v2), &v3) in a.iter_mut().zip(x0).zip(x1).zip(x2).zip(x3) {
                            *o += w0 * v0 + w1 * v1 + w2 * v2 + w3 * v3;
                        }
                    }
                    PoolMode::Max => {
                        for ((((o, &v0), &v1), &v2), &v3) in a.iter_mut().zip(x0).zip(x1).zip(x2).zip(x3) {
                            let v = (w0 * v0).max(w1 * v1).max(w2 * v2).max(w3 * v3);
                            *o = if k == 0 { v } else { o.max(v) };
                        }
                    }
                }
            }
            if p.mode == PoolMode::Avg {
                for o in a.iter_mut() {
                    *o /= count;
                }
            }
        }
        let dst = &mut out[ri * c * bins..(ri + 1) * c * bins];
        for (bin, a) in acc.chunks_exact(c).enumerate() {
            for (ci, &v) in a.iter().enumerate() {
                dst[ci * bins + bin] = v;
            }
        }
    }
    Ok(())
}

/// The reference: RoiAlign one channel plane at a time (arguments as [`roi_align`]).
pub fn roi_align_reference(
    features: &[f32],
    (n, c, height, width): (usize, usize, usize, usize),
    rois: &[f32],
    batch_indices: &[i64],
    p: &RoiAlignParams,
    out: &mut [f32],
) -> OpResult {
    check_args(features, (n, c, height, width), rois, batch_indices, p, out)?;
    let (ph_n, pw_n) = (p.output_height, p.output_width);
    if height == 0 || width == 0 {
        out.fill(0.0);
        return Ok(());
    }
    let plane = height * width;
    let mut samples = Vec::new();
    for (ri, roi) in rois.chunks_exact(4).enumerate() {
        let b = batch_indices[ri] as usize;
        let (per_bin, count) = roi_samples(roi, height, width, p, &mut samples);
        for ci in 0..c {
            let data = &features[(b * c + ci) * plane..(b * c + ci + 1) * plane];
            let dst = &mut out[(ri * c + ci) * ph_n * pw_n..(ri * c + ci + 1) * ph_n * pw_n];
            for (bin, o) in dst.iter_mut().enumerate() {
                let bin_samples = &samples[bin * per_bin..(bin + 1) * per_bin];
                *o = match p.mode {
                    PoolMode::Avg => {
                        let mut acc = 0f32;
                        for s in bin_samples {
                            acc += s.w[0] * data[s.pos[0]]
                                + s.w[1] * data[s.pos[1]]
                                + s.w[2] * data[s.pos[2]]
                                + s.w[3] * data[s.pos[3]];
                        }
                        acc / count
                    }
                    PoolMode::Max => {
                        let mut acc = 0f32;
                        for (k, s) in bin_samples.iter().enumerate() {
                            let v = (s.w[0] * data[s.pos[0]])
                                .max(s.w[1] * data[s.pos[1]])
                                .max(s.w[2] * data[s.pos[2]])
                                .max(s.w[3] * data[s.pos[3]]);
                            acc = if k == 0 { v } else { acc.max(v) };
                        }
                        acc
                    }
                };
            }
        }
    }
    Ok(())
}
