//! Kernels of `PixelGather` on one batch item.
//!
//! `choose` holds row-major pixel indices; `out` is `(c, n)`: channel-major, like the
//! `(C, N, 1)` map the node returns.

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
}
