//! Pure kernels of `QConv` on slices.

use crate::ops::{OpError, OpResult, check_len};
use crate::quant::{Int8Layer, LayerInput, LayerOutput};

/// Geometry of a 2-D convolution on one `(c_in, h, w)` image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ConvGeometry {
    /// Input channels.
    pub c_in: usize,
    /// Input height.
    pub h: usize,
    /// Input width.
    pub w: usize,
    /// Kernel height and width.
    pub kernel: [usize; 2],
    /// Strides (y, x).
    pub strides: [usize; 2],
    /// Padding (top, left, bottom, right), ONNX order.
    pub pads: [usize; 4],
    /// Dilations (y, x).
    pub dilations: [usize; 2],
}

impl ConvGeometry {
    /// Output height and width, or an error when the kernel does not fit.
    pub fn output_hw(&self) -> OpResult<(usize, usize)> {
        let axis = |size: usize, pad: usize, k: usize, s: usize, d: usize| -> OpResult<usize> {
            let span = d * (k - 1) + 1;
            let padded = size + pad;
            if k == 0 || s == 0 || d == 0 || padded < span {
                return Err(OpError::BadLength { op: "QConv", what: "input spatial size", got: size, expected: span });
            }
            Ok((padded - span) / s + 1)
        };
        let [kh, kw] = self.kernel;
        Ok((
            axis(self.h, self.pads[0] + self.pads[2], kh, self.strides[0], self.dilations[0])?,
            axis(self.w, self.pads[1] + self.pads[3], kw, self.strides[1], self.dilations[1])?,
        ))
    }

    /// Patch length `c_in * kh * kw`.
    pub fn patch_len(&self) -> usize {
        self.c_in * self.kernel[0] * self.kernel[1]
    }
}

/// Unfold a u7 image `(c_in, h, w)` into patches `[ho * wo][c_in * kh * kw]`
/// (columns ordered `(ci, ky, kx)`, as the weight rows), `pad_value` outside the image.
///
/// One output patch at a time, so the writes are contiguous (the reference's walk wrote
/// each patch's bytes `c_in * kh * kw` apart, a cache line each); the reads stay within
/// `kh` rows of each channel plane. The same bytes as [`im2col_u7_reference`].
pub fn im2col_u7(x: &[u8], g: &ConvGeometry, pad_value: u8, out: &mut [u8]) -> OpResult {
    let (ho, wo) = g.output_hw()?;
    let k = g.patch_len();
    check_len("QConv", "input", x.len(), g.c_in * g.h * g.w)?;
    check_len("QConv", "patches", out.len(), ho * wo * k)?;
    if k == 0 {
        return Ok(());
    }
    let [kh, kw] = g.kernel;
    let [sy, sx] = g.strides;
    let [dy, dx] = g.dilations;
    let (h, w) = (g.h as isize, g.w as isize);
    let plane_len = g.h * g.w;
    for (pos, patch) in out.chunks_exact_mut(k).enumerate() {
        let (oy, ox) = (pos / wo, pos % wo);
        let iy0 = (oy * sy) as isize - g.pads[0] as isize;
        let ix0 = (ox * sx) as isize - g.pads[1] as isize;
        let x_inside = ix0 >= 0 && ix0 + (((kw - 1) * dx) as isize) < w;
        for (ci, rows) in patch.chunks_exact_mut(kh * kw).enumerate() {
            let plane = &x[ci * plane_len..(ci + 1) * plane_len];
            for (ky, dst) in rows.chunks_exact_mut(kw).enumerate() {
                let iy = iy0 + (ky * dy) as isize;
                if iy < 0 || iy >= h {
                    dst.fill(pad_value);
                    continue;
                }
                let line = &plane[iy as usize * g.w..(iy as usize + 1) * g.w];
                if x_inside {
                    for (kx, d) in dst.iter_mut().enumerate() {
                        *d = line[ix0 as usize + kx * dx];
                    }
                } else {
                    for (kx, d) in dst.iter_mut().enumerate() {
                        let ix = ix0 + (kx * dx) as isize;
                        *d = if ix >= 0 && ix < w { line[ix as usize] } else { pad_value };
                    }
                }
            }
        }
    }
    Ok(())
}

/// The reference unfolding ([`im2col_u7`]'s arguments): one `(ci, ky, kx)` column at a
/// time over every output position, each byte's bounds checked on its own.
pub fn im2col_u7_reference(x: &[u8], g: &ConvGeometry, pad_value: u8, out: &mut [u8]) -> OpResult {
    let (ho, wo) = g.output_hw()?;
    let k = g.patch_len();
    check_len("QConv", "input", x.len(), g.c_in * g.h * g.w)?;
    check_len("QConv", "patches", out.len(), ho * wo * k)?;
    let [kh, kw] = g.kernel;
    for ci in 0..g.c_in {
        let plane = &x[ci * g.h * g.w..(ci + 1) * g.h * g.w];
        for ky in 0..kh {
            for kx in 0..kw {
                let col = (ci * kh + ky) * kw + kx;
                for oy in 0..ho {
                    let iy = (oy * g.strides[0] + ky * g.dilations[0]) as isize - g.pads[0] as isize;
                    let row_ok = iy >= 0 && (iy as usize) < g.h;
                    for ox in 0..wo {
                        let ix = (ox * g.strides[1] + kx * g.dilations[1]) as isize - g.pads[1] as isize;
                        out[(oy * wo + ox) * k + col] = if row_ok && ix >= 0 && (ix as usize) < g.w {
                            plane[iy as usize * g.w + ix as usize]
                        } else {
                            pad_value
                        };
                    }
                }
            }
        }
    }
    Ok(())
}

/// Convolve one image: `x` `(c_in, h, w)` -> `out` `(n, ho, wo)` floats.
pub fn qconv(layer: &Int8Layer, x: LayerInput<'_>, g: &ConvGeometry, out: &mut [f32]) -> OpResult {
    let (ho, wo) = g.output_hw()?;
    check_len("QConv", "weight rows", layer.k(), g.patch_len())?;
    check_len("QConv", "output", out.len(), layer.n() * ho * wo)?;
    let quantized;
    let xq: &[u8] = match x {
        LayerInput::U7(a) => a,
        LayerInput::F32(x) => {
            let mut q = vec![0u8; x.len()];
            layer.quantize_input(x, &mut q).map_err(|e| OpError::Kernel { op: "QConv", message: e.to_string() })?;
            quantized = q;
            &quantized
        }
    };
    let mut patches = vec![0u8; ho * wo * g.patch_len()];
    im2col_u7(xq, g, layer.input_params().zero_point as u8, &mut patches)?;
    layer
        .run_u7(&patches, ho * wo, LayerOutput::F32Transposed(out))
        .map_err(|e| OpError::Kernel { op: "QConv", message: e.to_string() })
}
