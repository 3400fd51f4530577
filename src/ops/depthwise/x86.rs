//! x86_64 builds of the depthwise row kernel: [`super::kernel::depthwise_rows`] compiled
//! with AVX-512F or AVX2 enabled, so its row loops use 16- or 8-float vectors. The
//! arithmetic is the same multiplies and adds in the same order (no fused multiply-add:
//! Rust does not contract), so the bits of the baseline build and of the reference.

use crate::ops::OpResult;
use crate::ops::conv_geometry::ConvGeometry;

/// # Safety
/// The CPU must support AVX-512F.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn depthwise_avx512(
    x: &[f32],
    weight: &[f32],
    bias: &[f32],
    g: &ConvGeometry,
    out: &mut [f32],
) -> OpResult {
    super::kernel::depthwise_rows(x, weight, bias, g, out)
}

/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn depthwise_avx2(
    x: &[f32],
    weight: &[f32],
    bias: &[f32],
    g: &ConvGeometry,
    out: &mut [f32],
) -> OpResult {
    super::kernel::depthwise_rows(x, weight, bias, g, out)
}
