//! Kernel of `LayerNormLastAxis` on a row-major `(rows, cols)` view.

use crate::ops::{OpResult, check_len};

/// Partial sums kept side by side (the compiler vectorises the lanes).
const LANES: usize = 8;

/// Sum of a slice in [`LANES`] partial sums (chunked so that it vectorises).
#[inline]
fn slice_sum(x: &[f32], f: impl Fn(f32) -> f32) -> f32 {
    let mut acc = [0f32; LANES];
    let chunks = x.chunks_exact(LANES);
    let rest = chunks.remainder();
    for c in chunks {
        for (a, &v) in acc.iter_mut().zip(c) {
            *a += f(v);
        }
    }
    for (a, &v) in acc.iter_mut().zip(rest) {
        *a += f(v);
    }
    ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]))
}

/// `out[r, c] = (x[r, c] - mean_r) / sqrt(var_r + epsilon) * scale[c] + bias[c]`, with
/// the mean and the (biased) variance of row `r` as ONNX defines them, in f32: each sum in
/// [`LANES`] partial sums, the variance from the centred values (two passes, as tract's
/// expansion and onnxruntime compute it, not `E[x^2] - mean^2`). Within
/// [`error_bound`] of the exact result.
pub fn layer_norm_rows(
    x: &[f32],
    rows: usize,
    cols: usize,
    scale: &[f32],
    bias: &[f32],
    epsilon: f32,
    out: &mut [f32],
) -> OpResult {
    check_len("LayerNormLastAxis", "input", x.len(), rows * cols)?;
    check_len("LayerNormLastAxis", "out", out.len(), rows * cols)?;
    check_len("LayerNormLastAxis", "scale", scale.len(), cols)?;
    check_len("LayerNormLastAxis", "bias", bias.len(), cols)?;
    if cols == 0 {
        return Ok(());
    }
    let n = cols as f32;
    for (row, y) in x.chunks_exact(cols).zip(out.chunks_exact_mut(cols)) {
        let mean = slice_sum(row, |v| v) / n;
        let var = slice_sum(row, |v| (v - mean) * (v - mean)) / n;
        let inv = 1.0 / (var + epsilon).sqrt();
        for (((o, &v), &s), &b) in y.iter_mut().zip(row).zip(scale).zip(bias) {
            *o = (v - mean) * inv * s + b;
        }
    }
    Ok(())
}

/// The reference: the same formula in f64, one element at a time, rounded to f32 at the end.
pub fn layer_norm_reference(x: &[f32], cols: usize, scale: &[f32], bias: &[f32], epsilon: f32) -> Vec<f32> {
    let mut out = Vec::with_capacity(x.len());
    if cols == 0 {
        return out;
    }
    for row in x.chunks_exact(cols) {
        let mean = row.iter().map(|&v| f64::from(v)).sum::<f64>() / cols as f64;
        let var = row.iter().map(|&v| (f64::from(v) - mean).powi(2)).sum::<f64>() / cols as f64;
        let inv = 1.0 / (var + f64::from(epsilon)).sqrt();
        for c in 0..cols {
            out.push(((f64::from(row[c]) - mean) * inv * f64::from(scale[c]) + f64::from(bias[c])) as f32);
        }
    }
    out
}

/// How far [`layer_norm_rows`] may be from the exact value of element `c` of a row with
/// mean `mean`, standard deviation `sigma` (of the exact statistics, epsilon included)
/// and mean absolute value `mean_abs`. With `u = 2^-24` and `g = (cols / 8 + 4) u` the
/// rounding of a sum of `cols` terms in 8 lanes (each lane `cols / 8` additions, three
/// combining levels, the division), to first order:
/// the mean is off by `g mean_abs`; a centred value `d` by that plus `u |d|`; the variance
/// relatively by `2 g` plus the centring error's share `2 g mean_abs / sigma`, so `1/sigma`
/// by half of it plus `2u` for the square root and the division; the product with the
/// scale and the bias add `2u` of their sizes. Summed with a factor 2 of margin for the
/// second-order terms:
/// `|y - y*| <= 2 |scale_c| (g mean_abs / sigma + (3g + 3u + g mean_abs / sigma) |d| / sigma) + 2u |bias_c|`.
pub fn error_bound(cols: usize, d: f64, sigma: f64, mean_abs: f64, scale: f32, bias: f32) -> f64 {
    let u = f64::from(f32::EPSILON) / 2.0;
    let g = (cols as f64 / LANES as f64 + 4.0) * u;
    let centring = g * mean_abs / sigma;
    2.0 * f64::from(scale.abs()) * (centring + (3.0 * g + 3.0 * u + centring) * d.abs() / sigma)
        + 2.0 * u * f64::from(bias.abs())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lane_sum_adds_everything() {
        let v: Vec<f32> = (1..=19).map(|i| i as f32).collect();
        assert_eq!(slice_sum(&v, |x| x), 190.0);
    }

    #[test]
    fn a_constant_row_normalises_to_the_bias() {
        let x = [3.0f32; 12];
        let mut out = [0f32; 12];
        layer_norm_rows(&x, 1, 12, &[2.0; 12], &[0.5; 12], 1e-5, &mut out).unwrap();
        assert!(out.iter().all(|&v| v == 0.5), "{out:?}");
    }

    #[test]
    fn lengths_are_checked() {
        let mut out = [0f32; 4];
        assert!(layer_norm_rows(&[0.0; 4], 2, 2, &[1.0; 3], &[0.0; 2], 1e-5, &mut out).is_err());
    }
}
