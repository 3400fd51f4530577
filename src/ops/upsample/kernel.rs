//! Kernel of `BilinearUpsample2x` on one `(h, w)` plane.
//!
//! With `half_pixel` coordinates an output index `x` reads source `(x + 0.5) / 2 - 0.5`:
//! even `x = 2i` is `0.25 * in[i - 1] + 0.75 * in[i]`, odd `x = 2i + 1` is
//! `0.75 * in[i] + 0.25 * in[i + 1]`, indices clamped to the edge. Rows are resampled
//! first, then columns, each value as `(0 + w0 * a) + w1 * b` in f32: the order tract's
//! `Resize` evaluates, so the results are the same bits (the zero start only matters for
//! the sign of a zero).

use crate::ops::{OpResult, check_len};

/// The two taps `(index, weight)` of output `x` along an axis of length `n` (n > 0).
#[inline]
pub(crate) fn taps(x: usize, n: usize) -> ((usize, f32), (usize, f32)) {
    let i = x / 2;
    if x.is_multiple_of(2) { ((i.saturating_sub(1), 0.25), (i, 0.75)) } else { ((i, 0.75), ((i + 1).min(n - 1), 0.25)) }
}

#[inline]
pub(crate) fn lerp(w0: f32, a: f32, w1: f32, b: f32) -> f32 {
    (0.0 + w0 * a) + w1 * b
}

/// Upsample one row-major `(h, w)` plane into `out` `(2h, 2w)`; `scratch` holds the
/// row-resampled `(2h, w)` plane.
pub fn upsample2x_plane(input: &[f32], h: usize, w: usize, scratch: &mut Vec<f32>, out: &mut [f32]) -> OpResult {
    check_len("BilinearUpsample2x", "input", input.len(), h * w)?;
    check_len("BilinearUpsample2x", "out", out.len(), 4 * h * w)?;
    if h == 0 || w == 0 {
        return Ok(());
    }
    scratch.clear();
    scratch.resize(2 * h * w, 0.0);
    for (y, row) in scratch.chunks_exact_mut(w).enumerate() {
        let ((i0, w0), (i1, w1)) = taps(y, h);
        let (a, b) = (&input[i0 * w..(i0 + 1) * w], &input[i1 * w..(i1 + 1) * w]);
        for ((o, &a), &b) in row.iter_mut().zip(a).zip(b) {
            *o = lerp(w0, a, w1, b);
        }
    }
    for (src, dst) in scratch.chunks_exact(w).zip(out.chunks_exact_mut(2 * w)) {
        // interior columns: 2j reads (j-1, j), 2j+1 reads (j, j+1)
        dst[0] = lerp(0.25, src[0], 0.75, src[0]);
        for j in 1..w {
            dst[2 * j] = lerp(0.25, src[j - 1], 0.75, src[j]);
        }
        for j in 0..w - 1 {
            dst[2 * j + 1] = lerp(0.75, src[j], 0.25, src[j + 1]);
        }
        dst[2 * w - 1] = lerp(0.75, src[w - 1], 0.25, src[w - 1]);
    }
    Ok(())
}

/// The reference: every output value from its four taps via [`taps`], rows then columns
/// (the same arithmetic, written per element).
pub fn upsample2x_reference(input: &[f32], h: usize, w: usize) -> Vec<f32> {
    let mut rows = vec![0f32; 2 * h * w];
    for y in 0..2 * h {
        let ((i0, w0), (i1, w1)) = taps(y, h);
        for x in 0..w {
            rows[y * w + x] = lerp(w0, input[i0 * w + x], w1, input[i1 * w + x]);
        }
    }
    let mut out = vec![0f32; 4 * h * w];
    for y in 0..2 * h {
        for x in 0..2 * w {
            let ((j0, w0), (j1, w1)) = taps(x, w);
            out[y * 2 * w + x] = lerp(w0, rows[y * w + j0], w1, rows[y * w + j1]);
        }
    }
    out
}
