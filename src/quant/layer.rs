//! [`Int8Layer`]: one fused int8 layer as the `QLinear` and `QConv` operators run it,
//! on plain slices: weights quantized per output channel and packed once, the input
//! quantized once (unless it already arrives as u7), then the int8 GEMM with the
//! dequantisation, bias, folded normalisation and ReLU in its output stage, writing
//! `f32` or u7 for the next int8 layer.

use super::gemm::{GemmError, Output, OutputStage, PackedWeights, qgemm, qgemm_reference, quantize_u7};
use super::params::{QParams, quantize_weights_per_channel};

/// A layer's input rows.
#[derive(Clone, Copy, Debug)]
pub enum LayerInput<'a> {
    /// Float activations, quantized with the layer's input parameters.
    F32(&'a [f32]),
    /// Already-quantized u7 activations (with the layer's input parameters).
    U7(&'a [u8]),
}

/// Where a layer writes.
#[derive(Debug)]
pub enum LayerOutput<'a> {
    /// Row-major `[m][n]` floats.
    F32(&'a mut [f32]),
    /// Transposed `[n][m]` floats (NCHW convolution output).
    F32Transposed(&'a mut [f32]),
    /// Rows of a wider transposed output: element (i, j) at `out[j * ld + i]` (a block of
    /// output positions of an NCHW convolution whose planes hold `ld` positions).
    F32TransposedRows {
        /// The output from this block's first position on.
        out: &'a mut [f32],
        /// Positions per output plane.
        ld: usize,
    },
    /// Row-major `[m][n]` u7 in the layer's output parameters.
    U7(&'a mut [u8]),
}

/// What the output stage applies after the product: `relu?(post_scale * acc + bias)`.
#[derive(Clone, Copy, Debug)]
pub struct OutputFold<'a> {
    /// Per output channel multiplier (a folded normalisation; 1 if none).
    pub post_scale: &'a [f32],
    /// Per output channel bias.
    pub bias: &'a [f32],
    /// Clamp at zero.
    pub relu: bool,
}

/// One int8 layer: `y = relu?(post_scale * (x W) + bias)` with `x` and `W` quantized.
#[derive(Clone)]
pub struct Int8Layer {
    k: usize,
    n: usize,
    packed: PackedWeights,
    /// Per output channel: input scale * weight scale * post_scale.
    scale: Vec<f32>,
    bias: Vec<f32>,
    relu: bool,
    input: QParams,
    output: Option<QParams>,
}

impl std::fmt::Debug for Int8Layer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Int8Layer")
            .field("k", &self.k)
            .field("n", &self.n)
            .field("relu", &self.relu)
            .field("input", &self.input)
            .field("output", &self.output)
            .finish()
    }
}

impl Int8Layer {
    /// Build from a float weight `[k][n]`, what the output stage folds in, the input's
    /// parameters and, for u7 output, the output's.
    pub fn new(
        weight: &[f32],
        k: usize,
        n: usize,
        fold: &OutputFold<'_>,
        input: QParams,
        output: Option<QParams>,
    ) -> Result<Int8Layer, GemmError> {
        let OutputFold { post_scale, bias, relu } = *fold;
        for (what, got, want) in
            [("weight", weight.len(), k * n), ("post_scale", post_scale.len(), n), ("bias", bias.len(), n)]
        {
            if got != want {
                return Err(GemmError::Len { what, got, expected: want });
            }
        }
        let (q, w_scale) = quantize_weights_per_channel(weight, k, n);
        let packed = PackedWeights::new(&q, k, n)?;
        let scale = w_scale.iter().zip(post_scale).map(|(w, p)| input.scale * w * p).collect();
        Ok(Int8Layer { k, n, packed, scale, bias: bias.to_vec(), relu, input, output })
    }

    /// Reduction length.
    pub fn k(&self) -> usize {
        self.k
    }

    /// Output channels.
    pub fn n(&self) -> usize {
        self.n
    }

    /// The input's quantization.
    pub fn input_params(&self) -> QParams {
        self.input
    }

    /// The output's quantization, when the layer writes u7.
    pub fn output_params(&self) -> Option<QParams> {
        self.output
    }

    /// The same layer with its weight rows reordered: row `r` of the result is row
    /// `perm[r]` of this one (a convolution's patch order changed to match another
    /// unfolding). Quantization is per output channel, so the int8 weights, scales and
    /// column sums are the same; the integer products sum the same terms, so outputs are
    /// bit for bit those of this layer on inputs reordered the same way.
    pub fn with_rows_permuted(&self, perm: &[usize]) -> Result<Int8Layer, GemmError> {
        let mut seen = vec![false; self.k];
        if perm.len() != self.k || !perm.iter().all(|&r| r < self.k && !std::mem::replace(&mut seen[r], true)) {
            return Err(GemmError::Len { what: "row permutation", got: perm.len(), expected: self.k });
        }
        let mut q = Vec::with_capacity(self.k * self.n);
        for &r in perm {
            q.extend((0..self.n).map(|j| self.packed.weight(r, j).unwrap_or(0)));
        }
        let packed = PackedWeights::with_kernel(&q, self.k, self.n, self.packed.kernel())?;
        Ok(Int8Layer { packed, scale: self.scale.clone(), bias: self.bias.clone(), ..*self })
    }

    /// Quantize float activations with the layer's input parameters.
    pub fn quantize_input(&self, x: &[f32], out: &mut [u8]) -> Result<(), GemmError> {
        quantize_u7(x, self.input.inv_scale(), self.input.zero_point, out)
    }

    /// Run on `m` rows of u7 input (`[m][k]`, row stride `k`).
    pub fn run_u7(&self, a: &[u8], m: usize, out: LayerOutput<'_>) -> Result<(), GemmError> {
        self.run_with(a, m, out, false)
    }

    /// The same with the scalar reference kernel (the definition the fast one matches).
    pub fn run_u7_reference(&self, a: &[u8], m: usize, out: LayerOutput<'_>) -> Result<(), GemmError> {
        self.run_with(a, m, out, true)
    }

    fn run_with(&self, a: &[u8], m: usize, out: LayerOutput<'_>, reference: bool) -> Result<(), GemmError> {
        let stage = OutputStage {
            a_zero_point: self.input.zero_point,
            scale: &self.scale,
            bias: Some(&self.bias),
            relu: self.relu,
        };
        let out = match out {
            LayerOutput::F32(out) => Output::F32 { out, ld: self.n },
            LayerOutput::F32Transposed(out) => Output::F32Transposed { out, ld: m },
            LayerOutput::F32TransposedRows { out, ld } => Output::F32Transposed { out, ld },
            LayerOutput::U7(out) => {
                let q = self.output.unwrap_or(QParams { scale: 1.0, zero_point: 0 });
                Output::U7 { out, ld: self.n, inv_scale: q.inv_scale(), zero_point: q.zero_point }
            }
        };
        if reference {
            qgemm_reference(a, m, self.k, &self.packed, &stage, out)
        } else {
            qgemm(a, m, self.k, &self.packed, &stage, out)
        }
    }

    /// Run on `m` rows of input, quantizing float input first.
    pub fn run(&self, x: LayerInput<'_>, m: usize, out: LayerOutput<'_>) -> Result<(), GemmError> {
        match x {
            LayerInput::U7(a) => self.run_u7(a, m, out),
            LayerInput::F32(x) => {
                let mut a = vec![0u8; x.len()];
                self.quantize_input(x, &mut a)?;
                self.run_u7(&a, m, out)
            }
        }
    }
}
