//! Kernels of `PixelGather` and `ResampledPixelGather` on one batch item.
//!
//! `choose` holds row-major pixel indices; `out` is `(c, n)`: channel-major, like the
//! `(C, N, 1)` map the nodes return.

use crate::ops::upsample::kernel::{lerp, taps};
use crate::ops::{OpResult, check_len, checked_index};

/// `out[k, i] = x[k, choose[i]]` for `x` `(c, h, w)`.
pub fn gather_pixels(x: &[f32], c: usize, h: usize, w: usize, choose: &[i64], out: &mut [f32]) -> OpResult {
    let plane = h * w;
    check_len("PixelGather", "x", x.len(), c * plane)?;
    check_len("PixelGather", "out", out.len(), c * choose.len())?;
    let at: Vec<usize> = choose.iter().map(|&p| checked_index("PixelGather", p, plane)).collect::<OpResult<_>>()?;
    if at.is_empty() {
        return Ok(());
    }
    for (src, dst) in x.chunks_exact(plane).zip(out.chunks_exact_mut(at.len())) {
        for (o, &p) in dst.iter_mut().zip(&at) {
            *o = src[p];
        }
    }
    Ok(())
}

/// The bilinear x2 upsampling of `x` `(c, h, w)` (as `BilinearUpsample2x`:
/// [`crate::ops::upsample::kernel`]) at the pixels `choose` of the `(2h, 2w)` grid:
/// `out[k, i] = up(x)[k, choose[i]]`. Each value is computed as that kernel computes it
/// (the two row taps at each of the two column taps, then the column taps), so the
/// results are the same bits.
pub fn gather_upsampled_pixels(x: &[f32], c: usize, h: usize, w: usize, choose: &[i64], out: &mut [f32]) -> OpResult {
    let plane = h * w;
    check_len("PixelGather", "x", x.len(), c * plane)?;
    check_len("PixelGather", "out", out.len(), c * choose.len())?;
    // per pixel: the four source offsets and the row / column weights
    let taps_at = |p: i64| -> OpResult<([usize; 4], [f32; 4])> {
        let p = checked_index("PixelGather", p, 4 * plane)?;
        let ((i0, w0), (i1, w1)) = taps(p / (2 * w), h);
        let ((j0, v0), (j1, v1)) = taps(p % (2 * w), w);
        Ok(([i0 * w + j0, i1 * w + j0, i0 * w + j1, i1 * w + j1], [w0, w1, v0, v1]))
    };
    let at: Vec<([usize; 4], [f32; 4])> = choose.iter().map(|&p| taps_at(p)).collect::<OpResult<_>>()?;
    if at.is_empty() {
        return Ok(());
    }
    for (src, dst) in x.chunks_exact(plane).zip(out.chunks_exact_mut(at.len())) {
        for (o, (k, [w0, w1, v0, v1])) in dst.iter_mut().zip(&at) {
            let left = lerp(*w0, src[k[0]], *w1, src[k[1]]);
            let right = lerp(*w0, src[k[2]], *w1, src[k[3]]);
            *o = lerp(*v0, left, *v1, right);
        }
    }
    Ok(())
}

/// The nonzero entries `(index, weight)` of row `r` of a row-major `(_, len)` matrix taken
/// with stride `step` from `start` (a row: step 1; a column: step = row length).
fn nonzero_taps(m: &[f32], start: usize, len: usize, step: usize) -> Vec<(usize, f32)> {
    (0..len).map(|k| (k, m[start + k * step])).filter(|&(_, v)| v != 0.0).collect()
}

/// The map `rows · x · cols` (per channel, `rows` `(big_h, h)`, `x` `(c, h, w)`, `cols`
/// `(w, big_w)`, all row-major) at the pixels `choose` of its `(big_h, big_w)` grid:
/// `out[k, i] = sum_j (sum_r rows[y, r] x[k, r, j]) cols[j, x]` with `(y, x)` the pixel
/// `choose[i]`, each sum over the nonzero weights only, in index order (for finite `x`
/// the zero terms add nothing). That is what `MatMul(MatMul(rows, x), cols)` computes
/// for those pixels (a separable resampling, e.g. a bilinear one with two taps a side),
/// without the `(big_h, big_w)` map: within [`resampled_error_bound`] of it.
#[allow(clippy::too_many_arguments)]
pub fn gather_resampled_pixels(
    x: &[f32],
    (c, h, w): (usize, usize, usize),
    rows: &[f32],
    cols: &[f32],
    (big_h, big_w): (usize, usize),
    choose: &[i64],
    out: &mut [f32],
) -> OpResult {
    let plane = h * w;
    check_len("ResampledPixelGather", "x", x.len(), c * plane)?;
    check_len("ResampledPixelGather", "rows", rows.len(), big_h * h)?;
    check_len("ResampledPixelGather", "cols", cols.len(), w * big_w)?;
    check_len("ResampledPixelGather", "out", out.len(), c * choose.len())?;
    let mut row_taps: Vec<Option<Vec<(usize, f32)>>> = vec![None; big_h];
    let mut col_taps: Vec<Option<Vec<(usize, f32)>>> = vec![None; big_w];
    let mut at = Vec::with_capacity(choose.len());
    for &p in choose {
        let p = checked_index("ResampledPixelGather", p, big_h * big_w)?;
        let (y, xc) = (p / big_w, p % big_w);
        row_taps[y].get_or_insert_with(|| nonzero_taps(rows, y * h, h, 1));
        col_taps[xc].get_or_insert_with(|| nonzero_taps(cols, xc, w, big_w));
        at.push((y, xc));
    }
    if at.is_empty() {
        return Ok(());
    }
    for (src, dst) in x.chunks_exact(plane).zip(out.chunks_exact_mut(at.len())) {
        for (o, &(y, xc)) in dst.iter_mut().zip(&at) {
            let (ry, cx) = (row_taps[y].as_deref().unwrap_or(&[]), col_taps[xc].as_deref().unwrap_or(&[]));
            let mut acc = 0f32;
            for &(j, b) in cx {
                let mut t = 0f32;
                for &(r, a) in ry {
                    t += a * src[r * w + j];
                }
                acc += t * b;
            }
            *o = acc;
        }
    }
    Ok(())
}

/// The reference of [`gather_resampled_pixels`]: the dense products in f64, every term
/// (zeros included), rounded to f32 at the end.
pub fn gather_resampled_pixels_reference(
    x: &[f32],
    (c, h, w): (usize, usize, usize),
    rows: &[f32],
    cols: &[f32],
    big_w: usize,
    choose: &[i64],
) -> Vec<f32> {
    let mut out = Vec::with_capacity(c * choose.len());
    for k in 0..c {
        for &p in choose {
            let (y, xc) = (p as usize / big_w, p as usize % big_w);
            let mut acc = 0f64;
            for j in 0..w {
                let t: f64 = (0..h).map(|r| f64::from(rows[y * h + r]) * f64::from(x[k * h * w + r * w + j])).sum();
                acc += t * f64::from(cols[j * big_w + xc]);
            }
            out.push(acc as f32);
        }
    }
    out
}

/// How far [`gather_resampled_pixels`] (or any evaluation of the two products as sums in
/// f32) may be from the exact value at a pixel whose row and column have `row_taps` and
/// `col_taps` nonzero weights: each inner sum of `row_taps` products is within
/// `g(row_taps) sum|a x|`, the outer sum of `col_taps` products within `g(col_taps)` of its
/// terms, `g(n) = n u / (1 - n u)`, `u = 2^-24`, so in all
/// `|y - y*| <= g(row_taps + col_taps + 1) * magnitude`, with `magnitude =
/// sum_j |cols[j, x]| sum_r |rows[y, r] x[r, j]|`.
pub fn resampled_error_bound(row_taps: usize, col_taps: usize, magnitude: f64) -> f64 {
    let u = f64::from(f32::EPSILON) / 2.0;
    let n = (row_taps + col_taps + 1) as f64;
    n * u / (1.0 - n * u) * magnitude
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ops::upsample::kernel::upsample2x_reference;

    fn plane(c: usize, h: usize, w: usize) -> Vec<f32> {
        (0..c * h * w).map(|i| ((i * 7919) % 1013) as f32 * 0.37 - 150.0).collect()
    }

    #[test]
    fn gathers_the_chosen_pixels_of_every_channel() {
        let (c, h, w) = (3, 4, 5);
        let x = plane(c, h, w);
        let choose = [0i64, 19, 7, 7, 12];
        let mut out = vec![0f32; c * choose.len()];
        gather_pixels(&x, c, h, w, &choose, &mut out).unwrap();
        for k in 0..c {
            for (i, &p) in choose.iter().enumerate() {
                assert_eq!(out[k * choose.len() + i], x[k * h * w + p as usize]);
            }
        }
    }

    #[test]
    fn upsampled_pixels_are_the_bits_of_the_upsampled_map() {
        for (c, h, w) in [(2, 1, 1), (3, 4, 5), (1, 6, 2), (4, 12, 12)] {
            let x = plane(c, h, w);
            let full: Vec<f32> =
                (0..c).flat_map(|k| upsample2x_reference(&x[k * h * w..(k + 1) * h * w], h, w)).collect();
            let choose: Vec<i64> = (0..(4 * h * w) as i64).rev().step_by(3).chain([0, 0]).collect();
            let mut out = vec![0f32; c * choose.len()];
            gather_upsampled_pixels(&x, c, h, w, &choose, &mut out).unwrap();
            for k in 0..c {
                for (i, &p) in choose.iter().enumerate() {
                    let want = full[k * 4 * h * w + p as usize];
                    assert_eq!(out[k * choose.len() + i].to_bits(), want.to_bits(), "c{k} h{h} w{w} pixel {p}");
                }
            }
        }
    }

    #[test]
    fn indices_outside_the_map_are_errors() {
        let x = plane(1, 2, 2);
        let mut out = vec![0f32; 1];
        assert!(matches!(gather_pixels(&x, 1, 2, 2, &[4], &mut out), Err(crate::ops::OpError::IndexOutOfRange { .. })));
        assert!(gather_pixels(&x, 1, 2, 2, &[-1], &mut out).is_err());
        assert!(gather_upsampled_pixels(&x, 1, 2, 2, &[16], &mut out).is_err());
        assert!(gather_upsampled_pixels(&x, 1, 2, 2, &[15], &mut out).is_ok());
        assert!(gather_pixels(&x, 2, 2, 2, &[0], &mut out).is_err());
    }

    /// A bilinear (align-corners-free, half-pixel) resampling matrix `(out, inp)`, as the
    /// pose exporter builds it for the image features.
    fn bilinear(out: usize, inp: usize) -> Vec<f32> {
        let mut m = vec![0f32; out * inp];
        for o in 0..out {
            let src = ((o as f32 + 0.5) * inp as f32 / out as f32 - 0.5).clamp(0.0, (inp - 1) as f32);
            let i0 = src.floor() as usize;
            let i1 = (i0 + 1).min(inp - 1);
            let f = src - i0 as f32;
            m[o * inp + i0] += 1.0 - f;
            m[o * inp + i1] += f;
        }
        m
    }

    fn transpose(m: &[f32], rows: usize, cols: usize) -> Vec<f32> {
        (0..cols).flat_map(|j| (0..rows).map(move |i| m[i * cols + j])).collect()
    }

    #[test]
    fn resampled_pixels_are_within_their_bound_of_the_dense_products() {
        for (c, h, w, big_h, big_w, dense) in
            [(3, 4, 5, 9, 7, false), (2, 14, 14, 192, 192, false), (2, 3, 4, 5, 6, true)]
        {
            let x = plane(c, h, w);
            let (rows, cols) = if dense {
                (plane(1, big_h, h), plane(1, w, big_w))
            } else {
                (bilinear(big_h, h), transpose(&bilinear(big_w, w), big_w, w))
            };
            let choose: Vec<i64> = (0..(big_h * big_w) as i64).rev().step_by(5).chain([0, 0]).collect();
            let mut out = vec![0f32; c * choose.len()];
            gather_resampled_pixels(&x, (c, h, w), &rows, &cols, (big_h, big_w), &choose, &mut out).unwrap();
            let want = gather_resampled_pixels_reference(&x, (c, h, w), &rows, &cols, big_w, &choose);
            for k in 0..c {
                for (i, &p) in choose.iter().enumerate() {
                    let (y, xc) = (p as usize / big_w, p as usize % big_w);
                    let nz_r = (0..h).filter(|&r| rows[y * h + r] != 0.0).count();
                    let nz_c = (0..w).filter(|&j| cols[j * big_w + xc] != 0.0).count();
                    let magnitude: f64 = (0..w)
                        .map(|j| {
                            f64::from(cols[j * big_w + xc].abs())
                                * (0..h)
                                    .map(|r| f64::from((rows[y * h + r] * x[k * h * w + r * w + j]).abs()))
                                    .sum::<f64>()
                        })
                        .sum();
                    // the reference's own rounding to f32 is half an ulp of the result
                    let bound = resampled_error_bound(nz_r, nz_c, magnitude)
                        + f64::from(want[k * choose.len() + i].abs()) * 6e-8;
                    let got = out[k * choose.len() + i];
                    let d = (f64::from(got) - f64::from(want[k * choose.len() + i])).abs();
                    assert!(d <= bound, "c{k} pixel {p}: {got} vs {} ({d} > {bound})", want[k * choose.len() + i]);
                }
            }
        }
    }

    #[test]
    fn resampled_indices_and_sizes_are_checked() {
        let x = plane(1, 2, 2);
        let (rows, cols) = (bilinear(4, 2), transpose(&bilinear(4, 2), 4, 2));
        let mut out = vec![0f32; 1];
        assert!(gather_resampled_pixels(&x, (1, 2, 2), &rows, &cols, (4, 4), &[15], &mut out).is_ok());
        assert!(gather_resampled_pixels(&x, (1, 2, 2), &rows, &cols, (4, 4), &[16], &mut out).is_err());
        assert!(gather_resampled_pixels(&x, (1, 2, 2), &rows[1..], &cols, (4, 4), &[0], &mut out).is_err());
    }
}
