//! Mask pasting: the per-instance mask probabilities into the full image.
//!
//! Reproduces torchvision's ONNX mask pasting (`_onnx_paste_mask_in_image`, run by
//! onnxruntime): the padded `(M + 2) x (M + 2)` probabilities are resized bilinearly
//! (`align_corners=False`, exported as `half_pixel`; onnxruntime's arithmetic) to the
//! integer box's `(y1 - y0 + 1) x (x1 - x0 + 1)` and written where the box overlaps
//! the image; everything else is 0. Only pixels inside the image are computed.

/// Linear-resize taps of one output coordinate: two source indices and their weights.
#[derive(Clone, Copy, Debug)]
struct Tap {
    lo: usize,
    hi: usize,
    w_lo: f32,
    w_hi: f32,
}

/// onnxruntime's `half_pixel` bilinear taps (what torch exports for `align_corners=False`)
/// for output index `x` of `out` from `input`. A 1-pixel-wide box samples the centre.
fn tap(x: usize, out: usize, input: usize) -> Tap {
    let scale = out as f32 / input as f32;
    let mut src = (x as f32 + 0.5) / scale - 0.5;
    src = src.min((input - 1) as f32).max(0.0);
    let lo = (src as usize).min(input - 1);
    let hi = (lo + 1).min(input - 1);
    let (mut w_hi, mut w_lo) = ((src - lo as f32).abs(), (src - hi as f32).abs());
    if lo == hi {
        w_hi = 0.5;
        w_lo = 0.5;
    }
    Tap { lo, hi, w_lo, w_hi }
}

/// Paste one instance. `mask` is the padded `m x m` probability map, `box_xyxy` the
/// integer paste box (inclusive corners, as the graph computes them), `out` the
/// `height x width` probability image (written where the box covers it, zero elsewhere).
pub fn paste_mask(mask: &[f32], m: usize, box_xyxy: [i64; 4], height: usize, width: usize, out: &mut [f32]) {
    out.fill(0.0);
    if m == 0 || mask.len() < m * m {
        return;
    }
    let [x0, y0, x1, y1] = box_xyxy;
    let w = (x1 - x0 + 1).max(1);
    let h = (y1 - y0 + 1).max(1);
    let cx0 = x0.max(0);
    let cx1 = (x1 + 1).min(width as i64);
    let cy0 = y0.max(0);
    let cy1 = (y1 + 1).min(height as i64);
    if cx1 <= cx0 || cy1 <= cy0 {
        return;
    }
    let x_taps: Vec<Tap> = (cx0..cx1).map(|x| tap((x - x0) as usize, w as usize, m)).collect();
    for y in cy0..cy1 {
        let ty = tap((y - y0) as usize, h as usize, m);
        let (r_lo, r_hi) = (&mask[ty.lo * m..(ty.lo + 1) * m], &mask[ty.hi * m..(ty.hi + 1) * m]);
        let row = &mut out[y as usize * width..(y as usize + 1) * width];
        for (o, tx) in row[cx0 as usize..cx1 as usize].iter_mut().zip(&x_taps) {
            // onnxruntime's order: dx2*dy2*X11 + dx1*dy2*X21 + dx2*dy1*X12 + dx1*dy1*X22.
            *o = tx.w_lo * ty.w_lo * r_lo[tx.lo]
                + tx.w_hi * ty.w_lo * r_lo[tx.hi]
                + tx.w_lo * ty.w_hi * r_hi[tx.lo]
                + tx.w_hi * ty.w_hi * r_hi[tx.hi];
        }
    }
}
