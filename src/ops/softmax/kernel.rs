//! Kernel of `SoftmaxLastAxis` on row-major rows of `cols` values, in place.

use crate::ops::{OpError, OpResult};

/// Partial maxima and sums kept side by side (the compiler vectorises the lanes: 16 floats
/// fill an AVX-512 vector, two AVX2 or four SSE2 ones).
const LANES: usize = 16;

/// Below this `exp` would leave the normal range of f32: inputs are clamped to it, so the
/// result is about `2^-126` where the exact one would be smaller (an absolute error
/// under `2.4e-38`, see [`error_bounds`]).
const MIN_EXPONENT: f32 = -87.336_54;

/// Relative error of [`exp_nonpositive`] against the exact `e^t` for `t` in
/// `[MIN_EXPONENT, 0]`: Cody-Waite reduction to `|r| <= ln 2 / 2`, Cephes' degree-7
/// minimax polynomial (its stated maximum 1.7e-7 in single precision), the exact scaling
/// by `2^k`; `4u` with `u = 2^-24` covers it and is checked on a dense grid in the tests.
pub const EXP_RELATIVE_ERROR: f64 = 4.0 * U;

const U: f64 = f32::EPSILON as f64 / 2.0;

/// `e^t` for `t <= 0` (larger `t` are not used: the row's maximum is subtracted first),
/// without branches so that the lane loops vectorise. NaN stays NaN.
#[inline(always)]
fn exp_nonpositive(t: f32) -> f32 {
    const LOG2_E: f32 = std::f32::consts::LOG2_E;
    // 1.5 * 2^23: adding and subtracting it rounds to the nearest integer
    const ROUND: f32 = 12_582_912.0;
    // ln 2 = C1 + C2, C1 with 9 significant bits so that k * C1 is exact for |k| <= 127
    const C1: f32 = 0.693_359_4;
    const C2: f32 = -2.121_944_4e-4;
    let t = if t < MIN_EXPONENT { MIN_EXPONENT } else { t };
    let k = (t * LOG2_E + ROUND) - ROUND;
    let r = (t - k * C1) - k * C2;
    let z = r * r;
    let p = (((((1.987_569_1e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r + 1.666_666_5e-1)
        * r
        + 0.5)
        * z
        + r
        + 1.0;
    // k in [-126, 0]: 2^k is a normal f32 built from its exponent bits (NaN: k casts to 0)
    let scale = f32::from_bits(((k as i32 + 127) as u32) << 23);
    p * scale
}

/// Maximum of a row in [`LANES`] partial maxima (NaN entries are skipped here and
/// propagate through the exponentials instead).
#[inline(always)]
fn row_max(row: &[f32]) -> f32 {
    let mut acc = [f32::NEG_INFINITY; LANES];
    let chunks = row.chunks_exact(LANES);
    let rest = chunks.remainder();
    for c in chunks {
        for (a, &v) in acc.iter_mut().zip(c) {
            *a = if v > *a { v } else { *a };
        }
    }
    for (a, &v) in acc.iter_mut().zip(rest) {
        *a = if v > *a { v } else { *a };
    }
    acc.iter().fold(f32::NEG_INFINITY, |m, &v| if v > m { v } else { m })
}

/// `row[i] = e^(row[i] - max)` in place; returns their sum, in [`LANES`] partial sums
/// combined pairwise.
#[inline(always)]
fn exp_in_place_sum(row: &mut [f32], max: f32) -> f32 {
    let mut acc = [0f32; LANES];
    let mut chunks = row.chunks_exact_mut(LANES);
    for c in chunks.by_ref() {
        for (a, v) in acc.iter_mut().zip(c) {
            *v = exp_nonpositive(*v - max);
            *a += *v;
        }
    }
    for (a, v) in acc.iter_mut().zip(chunks.into_remainder()) {
        *v = exp_nonpositive(*v - max);
        *a += *v;
    }
    let mut n = LANES;
    while n > 1 {
        n /= 2;
        for i in 0..n {
            acc[i] += acc[i + n];
        }
    }
    acc[0]
}

/// The row loop for the instruction set it is compiled for (the baseline build here; the
/// x86_64 builds in `x86.rs`). `data.len()` must be a multiple of `cols > 0`.
#[inline(always)]
pub(super) fn softmax_rows_baseline(data: &mut [f32], cols: usize) {
    for row in data.chunks_exact_mut(cols) {
        let max = row_max(row);
        let inv = 1.0 / exp_in_place_sum(row, max);
        for v in row.iter_mut() {
            *v *= inv;
        }
    }
}

/// `softmax` over each row of `cols` values of `data`, in place: `e^(x - max) / sum`, the
/// exponential by [`exp_nonpositive`], the sum in [`LANES`] lanes, one multiplication by
/// its reciprocal. Within [`error_bounds`] of the exact result. On x86_64 the same code
/// built with AVX-512F or AVX2, chosen at run time (the same bits).
pub fn softmax_rows(data: &mut [f32], cols: usize) -> OpResult {
    if cols == 0 {
        return if data.is_empty() { Ok(()) } else { Err(shape_error(data.len(), cols)) };
    }
    if !data.len().is_multiple_of(cols) {
        return Err(shape_error(data.len(), cols));
    }
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has AVX-512F (checked above).
            unsafe { super::x86::softmax_rows_avx512(data, cols) };
            return Ok(());
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked above).
            unsafe { super::x86::softmax_rows_avx2(data, cols) };
            return Ok(());
        }
    }
    softmax_rows_baseline(data, cols);
    Ok(())
}

fn shape_error(len: usize, cols: usize) -> OpError {
    OpError::Kernel { op: "SoftmaxLastAxis", message: format!("{len} values are not rows of {cols}") }
}

/// The reference: each row's softmax in f64 from the f32 inputs, rounded to f32 at the end.
pub fn softmax_reference(x: &[f32], cols: usize) -> Vec<f64> {
    let mut out = Vec::with_capacity(x.len());
    for row in x.chunks_exact(cols.max(1)) {
        let max = row.iter().fold(f64::NEG_INFINITY, |m, &v| m.max(f64::from(v)));
        let e: Vec<f64> = row.iter().map(|&v| (f64::from(v) - max).exp()).collect();
        let sum: f64 = e.iter().sum();
        out.extend(e.iter().map(|v| v / sum));
    }
    out
}

/// How far [`softmax_rows`] may be from the exact softmax of `row`, element by element.
/// With `u = 2^-24`, `d_i = x_i - max` and `S = sum e^d_j` (exact), to first order:
/// the subtraction rounds `d_i` by `u |d_i|`, which moves `e^d_i` relatively by as much;
/// the exponential adds [`EXP_RELATIVE_ERROR`] (`E`); the sum of the computed terms is off
/// relatively by their own errors' weighted mean `W = sum e^d_j u |d_j| / S + E` and by
/// its rounding `g = (cols / 16 + 5) u` (the lanes' additions, four combining levels);
/// the reciprocal and the product add `2u`. With a factor 2 for the second-order terms,
/// and the clamp of `d` at `-87.34` (its exponential is `2^-126` within `E`; an absolute
/// `2^-125 / S` at most):
/// `|y_i - y_i*| <= 2 y_i* (u |d_i| + E + W + g + 2u) + 2^-125 / S`.
pub fn error_bounds(row: &[f32]) -> Vec<f64> {
    let max = row.iter().fold(f64::NEG_INFINITY, |m, &v| m.max(f64::from(v)));
    let d: Vec<f64> = row.iter().map(|&v| f64::from(v) - max).collect();
    let e: Vec<f64> = d.iter().map(|v| v.exp()).collect();
    let s: f64 = e.iter().sum();
    let w = e.iter().zip(&d).map(|(e, d)| e * U * d.abs()).sum::<f64>() / s + EXP_RELATIVE_ERROR;
    let g = (row.len() as f64 / LANES as f64 + 5.0) * U;
    let tiny = 2.0 * f64::from(f32::MIN_POSITIVE) / s;
    e.iter().zip(&d).map(|(e, d)| 2.0 * (e / s) * (U * d.abs() + EXP_RELATIVE_ERROR + w + g + 2.0 * U) + tiny).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_exponential_is_within_its_stated_error_on_a_dense_grid() {
        let mut worst = 0f64;
        let n = 2_000_000;
        for i in 0..=n {
            let t = MIN_EXPONENT * i as f32 / n as f32;
            let exact = f64::from(t).exp();
            let rel = (f64::from(exp_nonpositive(t)) - exact).abs() / exact;
            worst = worst.max(rel);
        }
        assert!(worst <= EXP_RELATIVE_ERROR, "worst relative error {worst:e}");
        assert_eq!(exp_nonpositive(0.0), 1.0);
        assert!(exp_nonpositive(f32::NAN).is_nan());
        assert!(exp_nonpositive(f32::NEG_INFINITY) <= 1.2e-38);
    }

    #[test]
    fn rows_sum_to_one_and_keep_their_order() {
        let mut x: Vec<f32> = (0..197 * 3).map(|i| ((i * 37 % 101) as f32 - 50.0) * 0.13).collect();
        let orig = x.clone();
        softmax_rows(&mut x, 197).unwrap();
        for (row, src) in x.chunks(197).zip(orig.chunks(197)) {
            let sum: f64 = row.iter().map(|&v| f64::from(v)).sum();
            assert!((sum - 1.0).abs() < 1e-5, "{sum}");
            for i in 1..197 {
                assert_eq!(src[i] > src[i - 1], row[i] > row[i - 1], "order at {i}");
            }
        }
    }

    #[test]
    fn lengths_that_are_not_rows_are_errors() {
        assert!(softmax_rows(&mut [0.0; 5], 2).is_err());
        assert!(softmax_rows(&mut [0.0; 2], 0).is_err());
        assert!(softmax_rows(&mut [], 0).is_ok());
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod isa_tests {
    use super::softmax_rows_baseline;

    #[test]
    fn the_avx_builds_give_the_baseline_bits() {
        let x: Vec<f32> = (0..197 * 5 + 35 * 3).map(|i| ((i * 7919 % 4001) as f32 - 2000.0) * 0.011).collect();
        for cols in [197, 35, 1, 16] {
            let n = x.len() / cols * cols;
            let mut base = x[..n].to_vec();
            softmax_rows_baseline(&mut base, cols);
            if std::arch::is_x86_feature_detected!("avx2") {
                let mut v = x[..n].to_vec();
                // SAFETY: AVX2 checked above.
                unsafe { super::super::x86::softmax_rows_avx2(&mut v, cols) };
                assert!(v.iter().zip(&base).all(|(a, b)| a.to_bits() == b.to_bits()), "avx2, cols {cols}");
            }
            if std::arch::is_x86_feature_detected!("avx512f") {
                let mut v = x[..n].to_vec();
                // SAFETY: AVX-512F checked above.
                unsafe { super::super::x86::softmax_rows_avx512(&mut v, cols) };
                assert!(v.iter().zip(&base).all(|(a, b)| a.to_bits() == b.to_bits()), "avx512, cols {cols}");
            }
        }
    }
}
