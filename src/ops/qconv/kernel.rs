//! Pure kernels of `QConv` on slices.

pub use crate::ops::conv_geometry::ConvGeometry;
use crate::ops::{OpError, OpResult, check_len};
use crate::quant::{Int8Layer, LayerInput, LayerOutput};

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

/// Convolve one image, the reference: `x` `(c_in, h, w)` -> `out` `(n, ho, wo)` floats, with
/// `layer`'s weight rows in the ONNX order `(ci, ky, kx)`: the whole image unfolded by
/// [`im2col_u7`], then one product. [`qconv`] gives its bits.
pub fn qconv_reference(layer: &Int8Layer, x: LayerInput<'_>, g: &ConvGeometry, out: &mut [f32]) -> OpResult {
    let (ho, wo) = g.output_hw()?;
    check_len("QConv", "weight rows", layer.k(), g.patch_len())?;
    check_len("QConv", "output", out.len(), layer.n() * ho * wo)?;
    let quantized;
    let xq: &[u8] = match x {
        LayerInput::U7(a) => a,
        LayerInput::F32(x) => {
            let mut q = vec![0u8; x.len()];
            layer.quantize_input(x, &mut q).map_err(kernel_error)?;
            quantized = q;
            &quantized
        }
    };
    let mut patches = vec![0u8; ho * wo * g.patch_len()];
    im2col_u7(xq, g, layer.input_params().zero_point as u8, &mut patches)?;
    layer.run_u7(&patches, ho * wo, LayerOutput::F32Transposed(out)).map_err(kernel_error)
}

fn kernel_error(e: crate::quant::gemm::GemmError) -> OpError {
    OpError::Kernel { op: "QConv", message: e.to_string() }
}

/// Output positions per unfolded block: a block's patches (`BLOCK_ROWS * c_in * kh * kw`
/// bytes, 288 KiB for a 3x3 convolution of 128 channels) are multiplied while they are
/// still in cache.
const BLOCK_ROWS: usize = 256;

/// Below this many input channels a convolution is unfolded plane by plane
/// ([`im2col_u7`]): a channels-last tap would copy only a few bytes (the RGB stem's 3),
/// and the transpose costs more than it saves (measured: `cargo bench --bench qgemm --
/// qconv`, docs/results.md).
pub const CHANNELS_LAST_MIN_C_IN: usize = 8;

/// The order of a patch's columns, and of the weight rows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PatchOrder {
    /// ONNX's `(ci, ky, kx)`: unfolded from the planar image ([`im2col_u7`]).
    Planar,
    /// `(ky, kx, ci)`: each tap one contiguous run of `c_in` bytes of the channels-last
    /// image ([`im2col_hwc_u7`]).
    ChannelsLast,
}

/// A `QConv` layer prepared for [`qconv`]: its weight rows in the patch order its input
/// is unfolded in (channels-last from [`CHANNELS_LAST_MIN_C_IN`] input channels on).
#[derive(Debug)]
pub struct ConvLayer {
    layer: Int8Layer,
    kernel: [usize; 2],
    order: PatchOrder,
}

impl ConvLayer {
    /// From the layer in ONNX row order and the kernel size; the order by channel count.
    pub fn new(layer: &Int8Layer, kernel: [usize; 2]) -> OpResult<Self> {
        let taps = kernel[0] * kernel[1];
        let order = if taps > 0 && layer.k() / taps >= CHANNELS_LAST_MIN_C_IN {
            PatchOrder::ChannelsLast
        } else {
            PatchOrder::Planar
        };
        Self::with_order(layer, kernel, order)
    }

    /// With a given patch order (tests, benchmarks).
    pub fn with_order(layer: &Int8Layer, kernel: [usize; 2], order: PatchOrder) -> OpResult<Self> {
        let [kh, kw] = kernel;
        let taps = kh * kw;
        if taps == 0 || !layer.k().is_multiple_of(taps) {
            return Err(OpError::BadLength { op: "QConv", what: "weight rows", got: layer.k(), expected: taps });
        }
        let layer = match order {
            PatchOrder::Planar => layer.clone(),
            PatchOrder::ChannelsLast => {
                let c_in = layer.k() / taps;
                // row (tap, ci) of the result is row (ci, tap) of the ONNX order
                let perm: Vec<usize> = (0..taps).flat_map(|t| (0..c_in).map(move |ci| ci * taps + t)).collect();
                layer.with_rows_permuted(&perm).map_err(kernel_error)?
            }
        };
        Ok(Self { layer, kernel, order })
    }

    /// The layer (rows in [`Self::order`]).
    pub fn layer(&self) -> &Int8Layer {
        &self.layer
    }

    /// The patch order.
    pub fn order(&self) -> PatchOrder {
        self.order
    }
}

/// Transposes a `(c, hw)` u8 image to `(hw, c)`, a block of positions at a time (the
/// strided writes stay within `64 * c` bytes).
pub fn chw_to_hwc_u8(x: &[u8], c: usize, hw: usize, out: &mut [u8]) -> OpResult {
    check_len("QConv", "input", x.len(), c * hw)?;
    check_len("QConv", "channels-last input", out.len(), c * hw)?;
    const BLOCK: usize = 64;
    for p0 in (0..hw).step_by(BLOCK) {
        let p1 = (p0 + BLOCK).min(hw);
        let dst = &mut out[p0 * c..p1 * c];
        for (ci, plane) in x.chunks_exact(hw).enumerate() {
            for (d, &v) in dst[ci..].iter_mut().step_by(c).zip(&plane[p0..p1]) {
                *d = v;
            }
        }
    }
    Ok(())
}

/// Unfolds output positions `p0..p0 + rows` of a channels-last u7 image `(h, w, c_in)` into
/// patches `[rows][kh * kw * c_in]` (columns ordered `(ky, kx, ci)`, as
/// [`PatchOrder::ChannelsLast`] weight rows), `pad_value` outside the image: one `c_in`-byte copy
/// per kernel tap.
pub fn im2col_hwc_u7(x: &[u8], g: &ConvGeometry, pad_value: u8, p0: usize, rows: usize, out: &mut [u8]) -> OpResult {
    let (ho, wo) = g.output_hw()?;
    let (c, k) = (g.c_in, g.patch_len());
    check_len("QConv", "channels-last input", x.len(), c * g.h * g.w)?;
    check_len("QConv", "patches", out.len(), rows * k)?;
    if p0 + rows > ho * wo {
        return Err(OpError::BadLength { op: "QConv", what: "patch rows", got: p0 + rows, expected: ho * wo });
    }
    if k == 0 {
        return Ok(());
    }
    let kw = g.kernel[1];
    let [sy, sx] = g.strides;
    let [dy, dx] = g.dilations;
    let (h, w) = (g.h as isize, g.w as isize);
    for (pos, patch) in (p0..p0 + rows).zip(out.chunks_exact_mut(k)) {
        let (oy, ox) = (pos / wo, pos % wo);
        let iy0 = (oy * sy) as isize - g.pads[0] as isize;
        let ix0 = (ox * sx) as isize - g.pads[1] as isize;
        for (ky, row) in patch.chunks_exact_mut(kw * c).enumerate() {
            let iy = iy0 + (ky * dy) as isize;
            if iy < 0 || iy >= h {
                row.fill(pad_value);
                continue;
            }
            let line = &x[iy as usize * g.w * c..(iy as usize + 1) * g.w * c];
            for (kx, tap) in row.chunks_exact_mut(c).enumerate() {
                let ix = ix0 + (kx * dx) as isize;
                if ix < 0 || ix >= w {
                    tap.fill(pad_value);
                } else {
                    tap.copy_from_slice(&line[ix as usize * c..(ix as usize + 1) * c]);
                }
            }
        }
    }
    Ok(())
}

thread_local! {
    /// [`qconv`]'s buffers (the quantized or channels-last image, patches), kept between
    /// calls of the thread.
    static SCRATCH: std::cell::RefCell<(Vec<u8>, Vec<u8>)> = const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
}

/// Convolve one image: `x` `(c_in, h, w)` -> `out` `(n, ho, wo)` floats, the bits of
/// [`qconv_reference`] with the layer `conv` was made from.
///
/// The input is quantized once if it arrives as floats. Channels-last ([`ConvLayer`]):
/// the image is transposed once; a 1x1 convolution of stride 1 without padding multiplies
/// it as it is, any other is unfolded [`BLOCK_ROWS`] output positions at a time
/// ([`im2col_hwc_u7`]), each block multiplied into its columns of the NCHW output before
/// the next is unfolded. Planar: unfolded by [`im2col_u7`] and multiplied, as the
/// reference, into buffers kept between calls.
pub fn qconv(conv: &ConvLayer, x: LayerInput<'_>, g: &ConvGeometry, out: &mut [f32]) -> OpResult {
    let layer = &conv.layer;
    let (ho, wo) = g.output_hw()?;
    let m = ho * wo;
    let k = g.patch_len();
    check_len("QConv", "weight rows", layer.k(), k)?;
    if conv.kernel != g.kernel {
        let taps = |k: [usize; 2]| k[0] * k[1];
        return Err(OpError::BadLength {
            op: "QConv",
            what: "kernel taps",
            got: taps(g.kernel),
            expected: taps(conv.kernel),
        });
    }
    check_len("QConv", "output", out.len(), layer.n() * m)?;
    let hw = g.h * g.w;
    let image_len = g.c_in * hw;
    match x {
        LayerInput::U7(a) => check_len("QConv", "input", a.len(), image_len)?,
        LayerInput::F32(a) => check_len("QConv", "input", a.len(), image_len)?,
    }
    if m == 0 {
        return Ok(());
    }
    let pad = layer.input_params().zero_point as u8;
    SCRATCH.with_borrow_mut(|(image, patches)| {
        // the quantized image, planar (in `image`, or the input itself)
        let planar: &[u8] = match x {
            LayerInput::U7(a) => a,
            LayerInput::F32(a) => {
                image.resize(image_len, 0);
                layer.quantize_input(a, image).map_err(kernel_error)?;
                image
            }
        };
        if conv.order == PatchOrder::Planar {
            patches.resize(m * k, 0);
            im2col_u7(planar, g, pad, patches)?;
            return layer.run_u7(patches, m, LayerOutput::F32Transposed(out)).map_err(kernel_error);
        }
        // channels-last, in `patches` first
        patches.resize(image_len, 0);
        chw_to_hwc_u8(planar, g.c_in, hw, patches)?;
        let pointwise = g.kernel == [1, 1] && g.strides == [1, 1] && g.pads == [0; 4];
        if pointwise {
            return layer.run_u7(patches, m, LayerOutput::F32Transposed(out)).map_err(kernel_error);
        }
        std::mem::swap(image, patches);
        let hwc = &image[..image_len];
        patches.resize(BLOCK_ROWS.min(m) * k, 0);
        for p0 in (0..m).step_by(BLOCK_ROWS) {
            let rows = BLOCK_ROWS.min(m - p0);
            let block = &mut patches[..rows * k];
            im2col_hwc_u7(hwc, g, pad, p0, rows, block)?;
            layer
                .run_u7(block, rows, LayerOutput::F32TransposedRows { out: &mut out[p0..], ld: m })
                .map_err(kernel_error)?;
        }
        Ok(())
    })
}
