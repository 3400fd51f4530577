//! Pure kernels of `DepthwiseConv2d` on slices: one image `(c, h, w)`, weights
//! `(c, kh, kw)`, bias `(c)`, output `(c, ho, wo)`, all f32.

use crate::ops::conv_geometry::ConvGeometry;
use crate::ops::{OpResult, check_len};

fn check(x: &[f32], weight: &[f32], bias: &[f32], g: &ConvGeometry, out: &[f32]) -> OpResult<(usize, usize)> {
    let (ho, wo) = g.output_hw()?;
    check_len("DepthwiseConv2d", "input", x.len(), g.c_in * g.h * g.w)?;
    check_len("DepthwiseConv2d", "weight", weight.len(), g.patch_len())?;
    check_len("DepthwiseConv2d", "bias", bias.len(), g.c_in)?;
    check_len("DepthwiseConv2d", "output", out.len(), g.c_in * ho * wo)?;
    Ok((ho, wo))
}

/// The definition: output `(c, oy, ox)` is the sum, from `0.0`, over the taps `(ky, kx)` in
/// that order of `w[c][ky][kx] * x[c][iy][ix]` (`x` = 0 in the padding: its zeros are
/// multiplied like any input, as ONNX's zero padding defines), plus `bias[c]` last. Plain
/// f32 multiplies and adds, no fused multiply-add.
pub fn depthwise_reference(x: &[f32], weight: &[f32], bias: &[f32], g: &ConvGeometry, out: &mut [f32]) -> OpResult {
    let (ho, wo) = check(x, weight, bias, g, out)?;
    let [kh, kw] = g.kernel;
    for c in 0..g.c_in {
        let plane = &x[c * g.h * g.w..(c + 1) * g.h * g.w];
        let taps = &weight[c * kh * kw..(c + 1) * kh * kw];
        for oy in 0..ho {
            for ox in 0..wo {
                let mut acc = 0.0f32;
                for ky in 0..kh {
                    for kx in 0..kw {
                        let iy = (oy * g.strides[0] + ky * g.dilations[0]) as isize - g.pads[0] as isize;
                        let ix = (ox * g.strides[1] + kx * g.dilations[1]) as isize - g.pads[1] as isize;
                        let inside = iy >= 0 && ix >= 0 && (iy as usize) < g.h && (ix as usize) < g.w;
                        let v = if inside { plane[iy as usize * g.w + ix as usize] } else { 0.0 };
                        acc += taps[ky * kw + kx] * v;
                    }
                }
                out[(c * ho + oy) * wo + ox] = acc + bias[c];
            }
        }
    }
    Ok(())
}

/// [`depthwise_reference`]'s bits, a row of outputs at a time, with the widest vectors of
/// the CPU (AVX-512 or AVX2 on x86_64, checked at run time; the baseline build elsewhere:
/// NEON on aarch64). Every version is [`depthwise_rows`], compiled for its instruction set:
/// the same multiplies and adds in the same order (Rust never fuses them), so the same bits.
pub fn depthwise(x: &[f32], weight: &[f32], bias: &[f32], g: &ConvGeometry, out: &mut [f32]) -> OpResult {
    // every build checks the lengths itself (`depthwise_rows`)
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has AVX-512F (checked above).
            return unsafe { super::x86::depthwise_avx512(x, weight, bias, g, out) };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked above).
            return unsafe { super::x86::depthwise_avx2(x, weight, bias, g, out) };
        }
    }
    depthwise_rows(x, weight, bias, g, out)
}

/// The row kernel for the baseline instruction set (see [`depthwise`]). Per channel the
/// plane is copied once into a zero-padded buffer whose columns are split into the `sx`
/// stride phases (`[ph][sx][plen]`, phase `p` holding padded columns `p, p + sx, ...`):
/// the input of tap `(ky, kx)` for output row `oy` is then the contiguous run at row
/// `oy * sy + ky * dy`, phase `(kx * dx) % sx`, offset `(kx * dx) / sx`. Each output
/// element still sums its taps from `0.0` in `(ky, kx)` order and adds the bias last.
#[inline(always)]
pub fn depthwise_rows(x: &[f32], weight: &[f32], bias: &[f32], g: &ConvGeometry, out: &mut [f32]) -> OpResult {
    let (ho, wo) = check(x, weight, bias, g, out)?;
    if ho * wo == 0 {
        return Ok(());
    }
    let [kh, kw] = g.kernel;
    let [sy, sx] = g.strides;
    let [dy, dx] = g.dilations;
    let [top, left, bottom, right] = g.pads;
    let ph = g.h + top + bottom;
    let pw = g.w + left + right;
    let plen = pw.div_ceil(sx);
    let mut padded = vec![0f32; ph * sx * plen];
    for c in 0..g.c_in {
        let plane = &x[c * g.h * g.w..(c + 1) * g.h * g.w];
        // interior rows; the padding rows and columns stay zero from the allocation
        for (y, row) in plane.chunks_exact(g.w).enumerate() {
            let dst = &mut padded[(top + y) * sx * plen..(top + y + 1) * sx * plen];
            if sx == 1 {
                dst[left..left + g.w].copy_from_slice(row);
                continue;
            }
            for phase in 0..sx {
                // the first input column whose padded column falls in this phase
                let first = (phase + sx - left % sx) % sx;
                if first >= g.w {
                    continue;
                }
                let start = phase * plen + (left + first) / sx;
                for (d, &v) in dst[start..].iter_mut().zip(row[first..].iter().step_by(sx)) {
                    *d = v;
                }
            }
        }
        let taps = &weight[c * kh * kw..(c + 1) * kh * kw];
        let b = bias[c];
        for (oy, orow) in out[c * ho * wo..(c + 1) * ho * wo].chunks_exact_mut(wo).enumerate() {
            orow.fill(0.0);
            for ky in 0..kh {
                let iy = oy * sy + ky * dy;
                let phases = &padded[iy * sx * plen..(iy + 1) * sx * plen];
                for kx in 0..kw {
                    let (phase, offset) = ((kx * dx) % sx, (kx * dx) / sx);
                    let src = &phases[phase * plen + offset..phase * plen + offset + wo];
                    let t = taps[ky * kw + kx];
                    for (o, &v) in orow.iter_mut().zip(src) {
                        *o += t * v;
                    }
                }
            }
            for o in orow.iter_mut() {
                *o += b;
            }
        }
    }
    Ok(())
}
