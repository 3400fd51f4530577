//! Quantization numerics: activation parameters from calibration ranges, per-channel
//! weight quantization, calibration statistics and the error measure that decides
//! what stays float.
//!
//! Activations are "u7": `u8` in `0..=127` with a per-tensor zero point, so that the
//! x86 `vpmaddubsw` pair sums cannot saturate and the same bytes are valid `i8` for
//! aarch64 `sdot` (see [`super::gemm`]). Weights are symmetric `i8` in `-127..=127`,
//! one scale per output channel.

use serde::{Deserialize, Serialize};

/// Largest quantized activation value (u7) and largest weight magnitude.
pub const Q_MAX: i32 = 127;

/// Affine quantization of one activation tensor: `x ≈ scale * (q - zero_point)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct QParams {
    /// Real value of one quantization step.
    pub scale: f32,
    /// Quantized value of real zero, in `0..=127`.
    pub zero_point: i32,
}

impl QParams {
    /// Parameters covering `[lo, hi]` widened to include zero (so that zero, the
    /// padding value, is exact). A degenerate range (all zeros) gets scale 1.
    pub fn from_range(lo: f32, hi: f32) -> QParams {
        let lo = lo.min(0.0);
        let hi = hi.max(0.0);
        let span = hi - lo;
        if !(span.is_finite() && span > 0.0) {
            return QParams { scale: 1.0, zero_point: 0 };
        }
        let scale = span / Q_MAX as f32;
        let zero_point = ((-lo / scale).round_ties_even() as i32).clamp(0, Q_MAX);
        QParams { scale, zero_point }
    }

    /// `1 / scale`, what the quantizer multiplies by.
    pub fn inv_scale(&self) -> f32 {
        1.0 / self.scale
    }

    /// Quantize one value (the scalar definition [`super::gemm::quantize_u7`] follows).
    pub fn quantize(&self, x: f32) -> u8 {
        if x.is_nan() {
            return self.zero_point as u8;
        }
        let q = (x * self.inv_scale()).round_ties_even();
        (q.clamp(-1e9, 1e9) as i64 + self.zero_point as i64).clamp(0, Q_MAX as i64) as u8
    }

    /// The real value of `q`.
    pub fn dequantize(&self, q: u8) -> f32 {
        self.scale * (q as i32 - self.zero_point) as f32
    }
}

/// Symmetric per-output-channel quantization of a row-major `[k][n]` weight
/// (column `j` is output channel `j`): `(q, scale)` with `w[i][j] ≈ scale[j] * q[i][j]`.
/// An all-zero channel gets scale 1 (and zero weights).
pub fn quantize_weights_per_channel(w: &[f32], k: usize, n: usize) -> (Vec<i8>, Vec<f32>) {
    let mut scales = vec![0f32; n];
    for row in w.chunks_exact(n).take(k) {
        for (s, &v) in scales.iter_mut().zip(row) {
            *s = s.max(v.abs());
        }
    }
    for s in &mut scales {
        *s = if s.is_finite() && *s > 0.0 { *s / Q_MAX as f32 } else { 1.0 };
    }
    let q = w
        .chunks_exact(n)
        .take(k)
        .flat_map(|row| {
            row.iter().zip(&scales).map(|(&v, &s)| (v / s).round_ties_even().clamp(-(Q_MAX as f32), Q_MAX as f32) as i8)
        })
        .collect();
    (q, scales)
}

/// Signal-to-quantization-noise ratio in dB of representing `values` by `dequant(quant(x))`
/// (infinite when exact, e.g. all zeros).
pub fn sqnr_db(values: impl Iterator<Item = (f32, f32)>) -> f64 {
    let (mut signal, mut noise) = (0f64, 0f64);
    for (x, y) in values {
        if x.is_finite() {
            signal += (x as f64).powi(2);
            noise += (x as f64 - y as f64).powi(2);
        }
    }
    if noise == 0.0 { f64::INFINITY } else { 10.0 * (signal / noise).log10() }
}

/// How a calibration range is chosen from the observed values.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "method")]
pub enum RangeMethod {
    /// The observed minimum and maximum.
    MinMax,
    /// The `percentile`-th and `(100 - percentile)`-th percentiles of the sampled values
    /// (outlier-robust), e.g. 99.99.
    Percentile {
        /// Upper percentile, in (50, 100].
        percentile: f64,
    },
}

/// Values kept per observed tensor per calibration run (a strided subsample).
pub const SAMPLES_PER_RUN: usize = 8192;
/// Cap on the kept values per tensor; beyond it every other one is dropped.
pub const MAX_SAMPLES: usize = 1 << 18;

/// Running statistics of one activation tensor over the calibration runs.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TensorStats {
    /// Smallest finite value seen.
    pub min: f32,
    /// Largest finite value seen.
    pub max: f32,
    /// Values seen (all runs).
    pub count: u64,
    /// Rank of the tensor (the same in every run, else the first seen).
    pub rank: usize,
    /// Deterministic strided subsample of the values, for percentiles and SQNR.
    pub samples: Vec<f32>,
}

impl TensorStats {
    /// Account one observed tensor.
    pub fn observe(&mut self, values: &[f32], rank: usize) {
        if self.count == 0 {
            self.min = f32::INFINITY;
            self.max = f32::NEG_INFINITY;
            self.rank = rank;
        }
        for &v in values.iter().filter(|v| v.is_finite()) {
            self.min = self.min.min(v);
            self.max = self.max.max(v);
        }
        self.count += values.len() as u64;
        let stride = values.len().div_ceil(SAMPLES_PER_RUN).max(1);
        self.samples.extend(values.iter().step_by(stride).copied().filter(|v| v.is_finite()));
        while self.samples.len() > MAX_SAMPLES {
            self.samples = self.samples.iter().step_by(2).copied().collect();
        }
    }

    /// The calibration range by `method` (`None` if no finite value was seen).
    pub fn range(&self, method: RangeMethod) -> Option<(f32, f32)> {
        if self.count == 0 || self.min > self.max {
            return None;
        }
        match method {
            RangeMethod::MinMax => Some((self.min, self.max)),
            RangeMethod::Percentile { percentile } => {
                let mut s = self.samples.clone();
                if s.is_empty() {
                    return Some((self.min, self.max));
                }
                s.sort_by(f32::total_cmp);
                let at = |p: f64| s[((p / 100.0) * (s.len() - 1) as f64).round() as usize];
                let p = percentile.clamp(50.0, 100.0);
                Some((at(100.0 - p), at(p)))
            }
        }
    }

    /// SQNR (dB) of quantizing the sampled values with `q`.
    pub fn sqnr_db(&self, q: &QParams) -> f64 {
        sqnr_db(self.samples.iter().map(|&x| (x, q.dequantize(q.quantize(x)))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn range_includes_zero_and_round_trips_within_half_a_step() {
        let q = QParams::from_range(0.5, 3.0);
        assert_eq!(q.zero_point, 0);
        assert_eq!(q.dequantize(q.quantize(0.0)), 0.0);
        let q = QParams::from_range(-1.0, 3.0);
        for i in 0..=400 {
            let x = -1.0 + i as f32 * 0.01;
            assert!((q.dequantize(q.quantize(x)) - x).abs() <= q.scale / 2.0 + 1e-6, "{x}");
        }
        assert_eq!(q.quantize(100.0), 127);
        assert_eq!(q.quantize(-100.0), 0);
        assert_eq!(q.quantize(f32::NAN), q.zero_point as u8);
        assert_eq!(QParams::from_range(0.0, 0.0), QParams { scale: 1.0, zero_point: 0 });
    }

    #[test]
    fn weights_use_the_full_range_per_channel() {
        let w = [1.0, -0.005, -2.0, 0.02, 0.5, 0.0];
        let (q, s) = quantize_weights_per_channel(&w, 3, 2);
        assert_eq!(s, vec![2.0 / 127.0, 0.02 / 127.0]);
        assert_eq!(q, vec![64, -32, -127, 127, 32, 0]);
    }

    #[test]
    fn percentile_ignores_a_rare_outlier() {
        let mut st = TensorStats::default();
        let mut v: Vec<f32> = (0..10000).map(|i| (i % 100) as f32 / 100.0).collect();
        v[5000] = 1000.0;
        st.observe(&v, 2);
        assert_eq!(st.range(RangeMethod::MinMax), Some((0.0, 1000.0)));
        let (lo, hi) = st.range(RangeMethod::Percentile { percentile: 99.9 }).unwrap();
        assert!(lo == 0.0 && hi < 1.0, "{lo} {hi}");
    }
}
