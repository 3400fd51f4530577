//! x86_64 builds of the softmax row kernel: [`super::kernel::softmax_rows_baseline`]
//! compiled with AVX-512F or AVX2 enabled, so its lane loops use 16- or 8-float vectors.
//! The arithmetic is the same multiplies and adds in the same order (no fused
//! multiply-add: Rust does not contract), so the bits of the baseline build.

/// # Safety
/// The CPU must support AVX-512F.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn softmax_rows_avx512(data: &mut [f32], cols: usize) {
    super::kernel::softmax_rows_baseline(data, cols)
}

/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn softmax_rows_avx2(data: &mut [f32], cols: usize) {
    super::kernel::softmax_rows_baseline(data, cols)
}
