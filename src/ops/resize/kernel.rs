//! Pure kernels of `Resize2d` on one `(h, w)` f32 plane, written to an `(ho, wo)` one.

use crate::ops::{OpError, OpResult, check_len};

/// The interpolation (ONNX `Resize` attributes in brackets).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ResizeMode {
    /// `mode = linear`, `coordinate_transformation_mode = half_pixel`.
    LinearHalfPixel,
    /// `mode = nearest`, `coordinate_transformation_mode = asymmetric`, `nearest_mode = floor`.
    NearestAsymmetricFloor,
}

/// One axis's source of output index `o` (ONNX's formulas in f32, the scale being
/// `out / in` as ONNX derives it from `sizes`): the two taps and the weight of the second.
fn source(mode: ResizeMode, o: usize, len_in: usize, len_out: usize) -> (usize, usize, f32) {
    let scale = len_out as f32 / len_in as f32;
    let last = len_in - 1;
    match mode {
        ResizeMode::LinearHalfPixel => {
            let x = ((o as f32 + 0.5) / scale - 0.5).max(0.0);
            let i0 = (x.floor() as usize).min(last);
            let i1 = (i0 + 1).min(last);
            (i0, i1, if i0 == last { 0.0 } else { x - i0 as f32 })
        }
        ResizeMode::NearestAsymmetricFloor => {
            let i = ((o as f32 / scale).floor() as usize).min(last);
            (i, i, 0.0)
        }
    }
}

fn check(x: &[f32], h: usize, w: usize, out: &[f32], ho: usize, wo: usize) -> OpResult<bool> {
    check_len("Resize2d", "input", x.len(), h * w)?;
    check_len("Resize2d", "output", out.len(), ho * wo)?;
    if ho * wo > 0 && h * w == 0 {
        return Err(OpError::BadLength { op: "Resize2d", what: "input plane", got: 0, expected: 1 });
    }
    Ok(ho * wo > 0)
}

/// The definition, one output element at a time: linear is
/// `(1 - fy) * ((1 - fx) * x00 + fx * x01) + fy * ((1 - fx) * x10 + fx * x11)`, nearest
/// the source element.
pub fn resize_plane_reference(
    mode: ResizeMode,
    x: &[f32],
    [h, w]: [usize; 2],
    out: &mut [f32],
    [ho, wo]: [usize; 2],
) -> OpResult {
    if !check(x, h, w, out, ho, wo)? {
        return Ok(());
    }
    for oy in 0..ho {
        let (y0, y1, fy) = source(mode, oy, h, ho);
        for ox in 0..wo {
            let (x0, x1, fx) = source(mode, ox, w, wo);
            out[oy * wo + ox] = match mode {
                ResizeMode::NearestAsymmetricFloor => x[y0 * w + x0],
                ResizeMode::LinearHalfPixel => {
                    let top = (1.0 - fx) * x[y0 * w + x0] + fx * x[y0 * w + x1];
                    let bottom = (1.0 - fx) * x[y1 * w + x0] + fx * x[y1 * w + x1];
                    (1.0 - fy) * top + fy * bottom
                }
            };
        }
    }
    Ok(())
}

/// The column taps of a `w` -> `wo` resize, for [`resize_plane`] (the same for every plane).
pub fn resize_columns(mode: ResizeMode, w: usize, wo: usize) -> Vec<(usize, usize, f32)> {
    if w == 0 {
        return Vec::new();
    }
    (0..wo).map(|ox| source(mode, ox, w, wo)).collect()
}

/// [`resize_plane_reference`]'s bits: the column taps given ([`resize_columns`] of the same
/// mode and widths), each output row from its two source rows (the same expression per
/// element).
pub fn resize_plane(
    mode: ResizeMode,
    x: &[f32],
    [h, w]: [usize; 2],
    out: &mut [f32],
    [ho, wo]: [usize; 2],
    columns: &[(usize, usize, f32)],
) -> OpResult {
    if !check(x, h, w, out, ho, wo)? {
        return Ok(());
    }
    check_len("Resize2d", "column taps", columns.len(), wo)?;
    for (oy, orow) in out.chunks_exact_mut(wo).enumerate() {
        let (y0, y1, fy) = source(mode, oy, h, ho);
        let (r0, r1) = (&x[y0 * w..(y0 + 1) * w], &x[y1 * w..(y1 + 1) * w]);
        match mode {
            ResizeMode::NearestAsymmetricFloor => {
                for (o, &(x0, _, _)) in orow.iter_mut().zip(columns.iter()) {
                    *o = r0[x0];
                }
            }
            ResizeMode::LinearHalfPixel => {
                for (o, &(x0, x1, fx)) in orow.iter_mut().zip(columns.iter()) {
                    let top = (1.0 - fx) * r0[x0] + fx * r0[x1];
                    let bottom = (1.0 - fx) * r1[x0] + fx * r1[x1];
                    *o = (1.0 - fy) * top + fy * bottom;
                }
            }
        }
    }
    Ok(())
}
