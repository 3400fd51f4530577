//! int8 GEMM with a fused output stage: the matrix kernels of the int8 quantization.
//!
//! # Numbers
//!
//! * Activations are *u7*: `u8` values in `0..=127` with a per-tensor zero point `za`
//!   ([`quantize_u7`]). Keeping them below 128 means x86 `vpmaddubsw` pair sums cannot
//!   saturate (`2 * 127 * 128 < 32767`) and the bytes are also valid signed `i8` for the
//!   aarch64 `sdot` / `smull` instructions. Values above 127 are a caller bug: the result is
//!   then memory-safe but kernel-dependent.
//! * Weights are `i8`, symmetric per output channel (normally `-127..=127`; `-128` does no
//!   harm either), packed once by [`PackedWeights::new`].
//! * `acc[i][j] = sum_k a[i][k] * w[k][j]` is exact in `i32`, then the [`OutputStage`]:
//!   `v = ((acc - za * col_sums[j]) as f32) * scale[j]`, `v += bias[j]` (a separate add:
//!   no fused multiply-add anywhere), `v = relu(v)`, and an optional requantisation to u7
//!   ([`Output::U7`]). Every SIMD kernel gives results bit-identical to [`qgemm_reference`].
//!
//! # Reading order
//!
//! This file holds the API, the argument checks, the weight packing and the scalar
//! reference ([`quantize_u7_reference`], [`qgemm_reference`]): the definition of
//! correctness. The kernels follow in `gemm/scalar.rs` (portable, armv7),
//! `gemm/x86.rs` (AVX-512 VNNI, AVX-VNNI, AVX2) and `gemm/aarch64.rs` (NEON `sdot` and
//! baseline NEON). [`qgemm`] runs the kernel chosen when the weights were packed (the
//! fastest one of the running CPU unless [`PackedWeights::with_kernel`] picked another).
//! Everything is single-threaded.

use std::fmt;

use thiserror::Error;

#[cfg(target_arch = "aarch64")]
mod aarch64;
mod scalar;
#[cfg(target_arch = "x86_64")]
mod x86;

/// What a GEMM or quantisation entry point rejects (it never panics on its arguments).
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum GemmError {
    /// A slice is shorter (or, where an exact length is required, longer) than its dims need.
    #[error("{what}: {expected} elements needed, got {got}")]
    Len {
        /// Which argument.
        what: &'static str,
        /// The length the dims require (the minimum for strided 2-D buffers).
        expected: usize,
        /// The slice's length.
        got: usize,
    },
    /// A row stride smaller than the row it must hold.
    #[error("{what}: stride {ld} is smaller than the row length {min}")]
    Stride {
        /// Which argument.
        what: &'static str,
        /// The stride given.
        ld: usize,
        /// The smallest valid stride.
        min: usize,
    },
    /// `k` or `n` is zero.
    #[error("empty weight matrix ({k} x {n})")]
    EmptyWeights {
        /// Rows of the weight matrix.
        k: usize,
        /// Columns of the weight matrix.
        n: usize,
    },
    /// A u7 zero point outside `0..=127`.
    #[error("u7 zero point {0} is outside 0..=127")]
    ZeroPoint(i32),
    /// The dims overflow `usize`.
    #[error("matrix dims overflow usize")]
    Overflow,
    /// The kernel asked for does not run on this CPU.
    #[error("kernel {0} is not available on this CPU")]
    Unavailable(Kernel),
}

/// The GEMM kernels; [`Kernel::available`] lists those the running CPU supports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Kernel {
    /// Portable Rust loops (every target; armv7 uses it).
    Scalar,
    /// x86_64 AVX2: `vpmaddubsw` + `vpmaddwd`.
    Avx2,
    /// x86_64 AVX-VNNI: 256-bit `vpdpbusd`.
    AvxVnni,
    /// x86_64 AVX-512 VNNI: 512-bit `vpdpbusd`.
    Avx512Vnni,
    /// aarch64 baseline NEON: `smull` / `smlal` + `sadalp`.
    Neon,
    /// aarch64 NEON dot product (`sdot`, Armv8.2 `dotprod`).
    NeonDot,
}

impl Kernel {
    /// Every kernel; within one architecture, slowest first.
    pub const ALL: [Kernel; 6] =
        [Kernel::Scalar, Kernel::Avx2, Kernel::AvxVnni, Kernel::Avx512Vnni, Kernel::Neon, Kernel::NeonDot];

    /// Whether this kernel runs on this CPU (runtime feature detection).
    pub fn is_available(self) -> bool {
        match self {
            Kernel::Scalar => true,
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => is_x86_feature_detected!("avx2"),
            #[cfg(target_arch = "x86_64")]
            Kernel::AvxVnni => is_x86_feature_detected!("avx2") && is_x86_feature_detected!("avxvnni"),
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512Vnni => {
                is_x86_feature_detected!("avx512f")
                    && is_x86_feature_detected!("avx512bw")
                    && is_x86_feature_detected!("avx512vl")
                    && is_x86_feature_detected!("avx512vnni")
            }
            #[cfg(target_arch = "aarch64")]
            Kernel::Neon => std::arch::is_aarch64_feature_detected!("neon"),
            #[cfg(target_arch = "aarch64")]
            Kernel::NeonDot => {
                std::arch::is_aarch64_feature_detected!("neon") && std::arch::is_aarch64_feature_detected!("dotprod")
            }
            #[allow(unreachable_patterns)]
            _ => false,
        }
    }

    /// The kernels that run on this CPU, slowest first ([`Kernel::Scalar`] is always there).
    pub fn available() -> Vec<Kernel> {
        Kernel::ALL.into_iter().filter(|k| k.is_available()).collect()
    }

    /// The fastest kernel of this CPU (what [`PackedWeights::new`] picks).
    pub fn best() -> Kernel {
        Kernel::ALL.into_iter().rev().find(|k| k.is_available()).unwrap_or(Kernel::Scalar)
    }

    /// The kernel's name as shown in logs and benchmarks.
    pub fn name(self) -> &'static str {
        match self {
            Kernel::Scalar => "scalar",
            Kernel::Avx2 => "avx2",
            Kernel::AvxVnni => "avx-vnni",
            Kernel::Avx512Vnni => "avx512-vnni",
            Kernel::Neon => "neon",
            Kernel::NeonDot => "neon-dotprod",
        }
    }

    /// The packed weight layout the kernel reads (see [`Layout`]).
    fn layout(self) -> Layout {
        let (nr, vw, kg, kq) = match self {
            Kernel::Scalar => (usize::MAX, 1, 1, 1),
            Kernel::Avx2 | Kernel::AvxVnni => (16, 8, 4, 4),
            Kernel::Avx512Vnni => (64, 16, 4, 4),
            Kernel::Neon => (8, 4, 4, 8),
            Kernel::NeonDot => (16, 4, 4, 16),
        };
        Layout { nr, vw, kg, kq }
    }
}

impl fmt::Display for Kernel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

// ---------------------------------------------------------------------------------------
// Quantisation
// ---------------------------------------------------------------------------------------

/// Row pointers of a tile: rows past `rows` repeat the last valid row.
///
/// # Safety
/// Rows `i0..i0 + rows` of `a` exist (`rows >= 1`).
#[cfg(any(target_arch = "x86_64", target_arch = "aarch64"))]
#[inline(always)]
unsafe fn row_ptrs<const MR: usize>(job: &Job<'_>, i0: usize, rows: usize) -> [*const u8; MR] {
    let mut p = [job.a; MR];
    for (r, p) in p.iter_mut().enumerate() {
        // SAFETY: i0 + min(r, rows - 1) < m, and row starts are in bounds (check_args).
        *p = unsafe { job.a.add((i0 + r.min(rows - 1)) * job.lda) };
    }
    p
}

/// One value: `clamp(round_ties_even(x * inv_scale) + zero_point, 0, 127)`, NaN -> zero point.
/// `zero_point` must be in `0..=127` (checked by the public entry points).
#[inline]
fn quantize_one(x: f32, inv_scale: f32, zero_point: i32) -> u8 {
    let r = (x * inv_scale).round_ties_even();
    if r.is_nan() {
        return zero_point as u8;
    }
    // `as i64` saturates (±inf included); the sum cannot overflow after saturating_add.
    (r as i64).saturating_add(i64::from(zero_point)).clamp(0, 127) as u8
}

fn check_zero_point(zero_point: i32) -> Result<(), GemmError> {
    if (0..=127).contains(&zero_point) { Ok(()) } else { Err(GemmError::ZeroPoint(zero_point)) }
}

/// Scalar reference of [`quantize_u7`]: `out[i] = clamp(round_ties_even(x[i] * inv_scale) +
/// zero_point, 0, 127)`, NaN -> `zero_point`. `out` must be as long as `x`; `zero_point` in
/// `0..=127`.
pub fn quantize_u7_reference(x: &[f32], inv_scale: f32, zero_point: i32, out: &mut [u8]) -> Result<(), GemmError> {
    check_zero_point(zero_point)?;
    if out.len() != x.len() {
        return Err(GemmError::Len { what: "quantize output", expected: x.len(), got: out.len() });
    }
    for (o, &v) in out.iter_mut().zip(x) {
        *o = quantize_one(v, inv_scale, zero_point);
    }
    Ok(())
}

/// Quantises `x` to u7 with the best SIMD of the CPU; bit-identical to
/// [`quantize_u7_reference`] (same arguments, same checks).
pub fn quantize_u7(x: &[f32], inv_scale: f32, zero_point: i32, out: &mut [u8]) -> Result<(), GemmError> {
    check_zero_point(zero_point)?;
    if out.len() != x.len() {
        return Err(GemmError::Len { what: "quantize output", expected: x.len(), got: out.len() });
    }
    #[cfg(target_arch = "x86_64")]
    if x86::quantize(x, inv_scale, zero_point, out) {
        return Ok(());
    }
    #[cfg(target_arch = "aarch64")]
    {
        aarch64::quantize(x, inv_scale, zero_point, out);
        return Ok(());
    }
    #[allow(unreachable_code)]
    {
        for (o, &v) in out.iter_mut().zip(x) {
            *o = quantize_one(v, inv_scale, zero_point);
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------
// Packed weights
// ---------------------------------------------------------------------------------------

/// Packed weight layout. Columns are cut into panels of `nr` (the last panel's width rounded
/// up to `vw`, the columns of one vector); inside a panel of width `pw`, k is cut into groups
/// of `kg` and stored `[kp / kg][pw][kg]`, with `kp` = k rounded up to `kq`. Padding is zero.
/// The panel starting at column `j0` starts at byte `j0 * kp`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Layout {
    nr: usize,
    vw: usize,
    kg: usize,
    kq: usize,
}

/// 64-byte aligned storage (whole cache lines), so a cloned `PackedWeights` stays aligned.
#[derive(Clone, Copy)]
#[repr(C, align(64))]
struct Line([i8; 64]);

/// Weights of a `[k][n]` int8 matrix, packed for one [`Kernel`], with their column sums.
#[derive(Clone)]
pub struct PackedWeights {
    kernel: Kernel,
    layout: Layout,
    k: usize,
    n: usize,
    /// k rounded up to `layout.kq`.
    kp: usize,
    /// n rounded up to whole panels (the sum of the panel widths).
    n_pad: usize,
    lines: Vec<Line>,
    col_sums: Vec<i32>,
}

impl fmt::Debug for PackedWeights {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("PackedWeights").field("kernel", &self.kernel).field("k", &self.k).field("n", &self.n).finish()
    }
}

impl PackedWeights {
    /// Packs the row-major `[k][n]` weights `w` (column j = output channel j) for the fastest
    /// kernel of the running CPU ([`Kernel::best`]).
    pub fn new(w: &[i8], k: usize, n: usize) -> Result<Self, GemmError> {
        Self::with_kernel(w, k, n, Kernel::best())
    }

    /// Packs for a given kernel; [`GemmError::Unavailable`] if the CPU lacks it.
    pub fn with_kernel(w: &[i8], k: usize, n: usize, kernel: Kernel) -> Result<Self, GemmError> {
        if !kernel.is_available() {
            return Err(GemmError::Unavailable(kernel));
        }
        if k == 0 || n == 0 {
            return Err(GemmError::EmptyWeights { k, n });
        }
        let len = k.checked_mul(n).ok_or(GemmError::Overflow)?;
        if w.len() != len {
            return Err(GemmError::Len { what: "weights", expected: len, got: w.len() });
        }
        let mut layout = kernel.layout();
        layout.nr = layout.nr.min(n.next_multiple_of(layout.vw));
        let kp = k.next_multiple_of(layout.kq);
        let full = n / layout.nr * layout.nr;
        let n_pad = full + (n - full).next_multiple_of(layout.vw);
        let bytes = kp.checked_mul(n_pad).ok_or(GemmError::Overflow)?;
        let mut packed = Self {
            kernel,
            layout,
            k,
            n,
            kp,
            n_pad,
            lines: vec![Line([0; 64]); bytes.div_ceil(64)],
            col_sums: vec![0; n],
        };
        let data = packed.data_mut();
        for kk in 0..k {
            for (j, &v) in w[kk * n..(kk + 1) * n].iter().enumerate() {
                data[layout_index(layout, kp, n, kk, j)] = v;
            }
        }
        for row in w.chunks_exact(n) {
            for (s, &v) in packed.col_sums.iter_mut().zip(row) {
                *s += i32::from(v);
            }
        }
        Ok(packed)
    }

    /// Rows of the weight matrix (the reduction length).
    pub fn k(&self) -> usize {
        self.k
    }

    /// Columns of the weight matrix (output channels).
    pub fn n(&self) -> usize {
        self.n
    }

    /// `col_sums()[j]` = sum over k of `w[k][j]` (for the activation zero point).
    pub fn col_sums(&self) -> &[i32] {
        &self.col_sums
    }

    /// The kernel these weights are packed for (the one [`qgemm`] runs).
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    /// `w[kk][j]` as given to [`PackedWeights::new`]; `None` outside the matrix.
    pub fn weight(&self, kk: usize, j: usize) -> Option<i8> {
        (kk < self.k && j < self.n).then(|| self.data()[layout_index(self.layout, self.kp, self.n, kk, j)])
    }

    /// The packed bytes (`kp * n_pad` of them, 64-byte aligned).
    fn data(&self) -> &[i8] {
        // SAFETY: `Line` is `repr(C)` around `[i8; 64]` (size 64, no padding), so the
        // vector's buffer is `64 * len` initialised bytes; `kp * n_pad <= 64 * len`.
        unsafe { std::slice::from_raw_parts(self.lines.as_ptr().cast::<i8>(), self.kp * self.n_pad) }
    }

    fn data_mut(&mut self) -> &mut [i8] {
        // SAFETY: as in `data`, and `&mut self` makes the borrow unique.
        unsafe { std::slice::from_raw_parts_mut(self.lines.as_mut_ptr().cast::<i8>(), self.kp * self.n_pad) }
    }

    /// The panels: (first column, width, byte offset into `data`).
    fn panels(&self) -> impl Iterator<Item = (usize, usize, usize)> + '_ {
        (0..self.n).step_by(self.layout.nr).map(|j0| {
            let pw = self.layout.nr.min((self.n - j0).next_multiple_of(self.layout.vw));
            (j0, pw, j0 * self.kp)
        })
    }
}

/// Byte index of `w[kk][j]` in a packing (see [`Layout`]).
fn layout_index(l: Layout, kp: usize, n: usize, kk: usize, j: usize) -> usize {
    let j0 = j / l.nr * l.nr;
    let pw = l.nr.min((n - j0).next_multiple_of(l.vw));
    j0 * kp + (kk / l.kg) * pw * l.kg + (j - j0) * l.kg + kk % l.kg
}

// ---------------------------------------------------------------------------------------
// Output stage and the reference GEMM
// ---------------------------------------------------------------------------------------

/// What happens to the i32 accumulators before they are stored.
#[derive(Debug, Clone, Copy)]
pub struct OutputStage<'a> {
    /// Zero point of the activations (`acc - a_zero_point * col_sums[j]`).
    pub a_zero_point: i32,
    /// Per output channel, length n: activation scale * weight scale of channel j.
    pub scale: &'a [f32],
    /// Per output channel bias (length n), added after the scale.
    pub bias: Option<&'a [f32]>,
    /// ReLU: `v > 0 ? v : +0.0` (what `v.max(0.0)` does, with NaN and -0.0 going to +0.0).
    pub relu: bool,
}

/// Where and how the result goes. Buffers may be longer than needed.
#[derive(Debug)]
pub enum Output<'a> {
    /// `out[i * ld + j]` (row-major `[m][n]`, `ld >= n`).
    F32 {
        /// Destination.
        out: &'a mut [f32],
        /// Row stride.
        ld: usize,
    },
    /// `out[j * ld + i]` (transposed: `[n][m]`, `ld >= m`: what an NCHW convolution wants).
    F32Transposed {
        /// Destination.
        out: &'a mut [f32],
        /// Stride between output channels.
        ld: usize,
    },
    /// Requantised for the next int8 op: `q = clamp(round_ties_even(v * inv_scale) +
    /// zero_point, 0, 127)` (NaN -> zero_point), row-major `out[i * ld + j]`.
    U7 {
        /// Destination.
        out: &'a mut [u8],
        /// Row stride.
        ld: usize,
        /// 1 / scale of the output tensor.
        inv_scale: f32,
        /// Zero point of the output tensor, in `0..=127`.
        zero_point: i32,
    },
}

/// Minimum length of a strided `[rows][cols]` buffer (rows >= 1).
fn strided_len(rows: usize, cols: usize, ld: usize, what: &'static str) -> Result<usize, GemmError> {
    if ld < cols {
        return Err(GemmError::Stride { what, ld, min: cols });
    }
    (rows - 1).checked_mul(ld).and_then(|x| x.checked_add(cols)).ok_or(GemmError::Overflow)
}

fn check_len(what: &'static str, expected: usize, got: usize) -> Result<(), GemmError> {
    if got < expected { Err(GemmError::Len { what, expected, got }) } else { Ok(()) }
}

/// Checks every argument of a GEMM call (m >= 1).
fn check_args(
    a: &[u8],
    m: usize,
    lda: usize,
    w: &PackedWeights,
    stage: &OutputStage<'_>,
    out: &Output<'_>,
) -> Result<(), GemmError> {
    let (k, n) = (w.k, w.n);
    if stage.scale.len() != n {
        return Err(GemmError::Len { what: "scale", expected: n, got: stage.scale.len() });
    }
    if let Some(bias) = stage.bias
        && bias.len() != n
    {
        return Err(GemmError::Len { what: "bias", expected: n, got: bias.len() });
    }
    if m == 0 {
        return Ok(());
    }
    check_len("a", strided_len(m, k, lda, "a")?, a.len())?;
    match out {
        Output::F32 { out, ld } => check_len("output", strided_len(m, n, *ld, "output")?, out.len()),
        Output::F32Transposed { out, ld } => check_len("output", strided_len(n, m, *ld, "output")?, out.len()),
        Output::U7 { out, ld, zero_point, .. } => {
            check_zero_point(*zero_point)?;
            check_len("output", strided_len(m, n, *ld, "output")?, out.len())
        }
    }
}

/// The definition of correctness: plain loops over `w[k][j]`, same signature and checks as
/// [`qgemm`]. `a` is row-major `[m][k]` with row stride `lda >= k`.
pub fn qgemm_reference(
    a: &[u8],
    m: usize,
    lda: usize,
    w: &PackedWeights,
    stage: &OutputStage<'_>,
    mut out: Output<'_>,
) -> Result<(), GemmError> {
    check_args(a, m, lda, w, stage, &out)?;
    for i in 0..m {
        for j in 0..w.n {
            let mut acc = 0i32;
            for kk in 0..w.k {
                let wv = w.data()[layout_index(w.layout, w.kp, w.n, kk, j)];
                acc = acc.wrapping_add(i32::from(a[i * lda + kk]) * i32::from(wv));
            }
            let corrected = acc.wrapping_sub(stage.a_zero_point.wrapping_mul(w.col_sums[j]));
            let mut v = corrected as f32 * stage.scale[j];
            if let Some(bias) = stage.bias {
                v += bias[j];
            }
            if stage.relu {
                v = if v > 0.0 { v } else { 0.0 };
            }
            match &mut out {
                Output::F32 { out, ld } => out[i * *ld + j] = v,
                Output::F32Transposed { out, ld } => out[j * *ld + i] = v,
                Output::U7 { out, ld, inv_scale, zero_point } => {
                    out[i * *ld + j] = quantize_one(v, *inv_scale, *zero_point)
                }
            }
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------
// Dispatch
// ---------------------------------------------------------------------------------------

/// The destination as raw pointers (bounds checked by [`check_args`]).
#[derive(Clone, Copy)]
enum Dst {
    F32 { ptr: *mut f32, ld: usize },
    F32T { ptr: *mut f32, ld: usize },
    U7 { ptr: *mut u8, ld: usize, inv_scale: f32, zp: i32 },
}

/// A checked GEMM call as the kernels see it. The per-column vectors are padded with zeros
/// to `w.n_pad`, so kernels load whole vectors; only the stores are masked to `n`.
struct Job<'a> {
    a: *const u8,
    lda: usize,
    m: usize,
    k: usize,
    n: usize,
    w: &'a PackedWeights,
    /// `a_zero_point * col_sums[j]`.
    zc: Vec<i32>,
    scale: Vec<f32>,
    bias: Option<Vec<f32>>,
    relu: bool,
    dst: Dst,
}

impl Job<'_> {
    /// The output stage of one element (for tails and the scalar kernel).
    #[inline]
    fn finish(&self, acc: i32, j: usize) -> f32 {
        let mut v = acc.wrapping_sub(self.zc[j]) as f32 * self.scale[j];
        if let Some(bias) = &self.bias {
            v += bias[j];
        }
        if self.relu {
            v = if v > 0.0 { v } else { 0.0 };
        }
        v
    }

    /// Stores `v` as element (i, j) of the output.
    ///
    /// # Safety
    /// `i < m`, `j < n` (the destination was checked for every such element).
    #[inline]
    unsafe fn store(&self, i: usize, j: usize, v: f32) {
        // SAFETY: the caller keeps i < m and j < n; `check_args` proved those offsets in bounds.
        unsafe {
            match self.dst {
                Dst::F32 { ptr, ld } => *ptr.add(i * ld + j) = v,
                Dst::F32T { ptr, ld } => *ptr.add(j * ld + i) = v,
                Dst::U7 { ptr, ld, inv_scale, zp } => *ptr.add(i * ld + j) = quantize_one(v, inv_scale, zp),
            }
        }
    }
}

/// Transposed output goes through a scratch block of about this many rows per panel: the
/// destination's columns are `ld` floats apart (often a multiple of 4 KiB for image sizes, so
/// they share cache sets), and a few floats per column per tile would thrash those sets. The
/// block gives each column a run of whole cache lines at once.
#[cfg(any(target_arch = "x86_64", target_arch = "aarch64"))]
const TRANSPOSED_BLOCK: usize = 64;

/// The blocks of rows a SIMD kernel runs through one panel, and where their tiles store.
#[cfg(any(target_arch = "x86_64", target_arch = "aarch64"))]
struct RowBlocks {
    /// Rows per block (a multiple of the tile height, or m for row-major outputs).
    rows: usize,
    /// `[pw][rows]` for transposed output, else empty.
    scratch: Vec<f32>,
}

#[cfg(any(target_arch = "x86_64", target_arch = "aarch64"))]
impl RowBlocks {
    fn new(job: &Job<'_>, mr: usize, pw: usize) -> Self {
        match job.dst {
            Dst::F32T { .. } => {
                let rows = TRANSPOSED_BLOCK.div_ceil(mr) * mr;
                Self { rows, scratch: vec![0.0; rows * pw] }
            }
            _ => Self { rows: job.m, scratch: Vec::new() },
        }
    }

    /// The destination of the block starting at row `ib` of the panel at column `j0`, and
    /// the output coordinates of (ib, j0) in it.
    fn target(&mut self, job: &Job<'_>, ib: usize, j0: usize) -> (Dst, usize, usize) {
        if self.scratch.is_empty() {
            (job.dst, ib, j0)
        } else {
            (Dst::F32T { ptr: self.scratch.as_mut_ptr(), ld: self.rows }, 0, 0)
        }
    }

    /// Copies a finished block (rows `ib..ib + rows`, columns `j0..j0 + cols`) to the
    /// transposed output; nothing for row-major outputs.
    ///
    /// # Safety
    /// The rows and columns are inside the output (i.e. below m and n).
    unsafe fn flush(&self, job: &Job<'_>, ib: usize, rows: usize, j0: usize, cols: usize) {
        if let (Dst::F32T { ptr, ld }, false) = (job.dst, self.scratch.is_empty()) {
            for c in 0..cols {
                // SAFETY: column c of the scratch holds `self.rows >= rows` floats; the
                // destination run is inside the output (check_args, forwarded bounds).
                unsafe {
                    std::ptr::copy_nonoverlapping(
                        self.scratch.as_ptr().add(c * self.rows),
                        ptr.add((j0 + c) * ld + ib),
                        rows,
                    )
                };
            }
        }
    }
}

/// int8 GEMM with fused output stage, with the kernel `w` was packed for. `a` is row-major
/// `[m][k]` u7 with row stride `lda >= k`; see the module docs for the arithmetic. Gives
/// the bits of [`qgemm_reference`].
pub fn qgemm(
    a: &[u8],
    m: usize,
    lda: usize,
    w: &PackedWeights,
    stage: &OutputStage<'_>,
    out: Output<'_>,
) -> Result<(), GemmError> {
    check_args(a, m, lda, w, stage, &out)?;
    if m == 0 {
        return Ok(());
    }
    if !w.kernel.is_available() {
        return Err(GemmError::Unavailable(w.kernel));
    }
    let pad = |v: &[f32]| {
        let mut p = v.to_vec();
        p.resize(w.n_pad, 0.0);
        p
    };
    let mut zc: Vec<i32> = w.col_sums.iter().map(|&s| stage.a_zero_point.wrapping_mul(s)).collect();
    zc.resize(w.n_pad, 0);
    let dst = match out {
        Output::F32 { out, ld } => Dst::F32 { ptr: out.as_mut_ptr(), ld },
        Output::F32Transposed { out, ld } => Dst::F32T { ptr: out.as_mut_ptr(), ld },
        Output::U7 { out, ld, inv_scale, zero_point } => {
            Dst::U7 { ptr: out.as_mut_ptr(), ld, inv_scale, zp: zero_point }
        }
    };
    let job = Job {
        a: a.as_ptr(),
        lda,
        m,
        k: w.k,
        n: w.n,
        w,
        zc,
        scale: pad(stage.scale),
        bias: stage.bias.map(pad),
        relu: stage.relu,
        dst,
    };
    // SAFETY (every arm): `check_args` proved `a` and the destination large enough for
    // (m, k, n, lda, ld), and the kernel runs on this CPU (checked above).
    match w.kernel {
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx512Vnni => unsafe { x86::gemm_avx512(&job) },
        #[cfg(target_arch = "x86_64")]
        Kernel::AvxVnni => unsafe { x86::gemm_avxvnni(&job) },
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx2 => unsafe { x86::gemm_avx2(&job) },
        #[cfg(target_arch = "aarch64")]
        Kernel::NeonDot => unsafe { aarch64::gemm_dot(&job) },
        #[cfg(target_arch = "aarch64")]
        Kernel::Neon => unsafe { aarch64::gemm_neon(&job) },
        _ => unsafe { scalar::gemm(&job) },
    }
    Ok(())
}
