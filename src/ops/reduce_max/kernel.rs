//! Kernel of `ReduceMaxAxis` on a row-major `(outer, k, inner)` view.

use crate::ops::{OpResult, check_len};

/// `out[o, j] = max over r of input[o, r, j]`, folded from `f32::MIN` in index order with
/// `acc = if acc > v { acc } else { v }`: tract's `Reduce<Max>` fold, so the results
/// (NaN and -inf included) are the same bits. `out` is `(outer, inner)`.
pub fn reduce_max_axis(input: &[f32], outer: usize, k: usize, inner: usize, out: &mut [f32]) -> OpResult {
    check_len("ReduceMaxAxis", "input", input.len(), outer * k * inner)?;
    check_len("ReduceMaxAxis", "out", out.len(), outer * inner)?;
    if inner == 0 {
        return Ok(());
    }
    out.fill(f32::MIN);
    if k == 0 {
        return Ok(());
    }
    for (block, acc) in input.chunks_exact(k * inner).zip(out.chunks_exact_mut(inner)) {
        for row in block.chunks_exact(inner) {
            for (a, &v) in acc.iter_mut().zip(row) {
                *a = if *a > v { *a } else { v };
            }
        }
    }
    Ok(())
}

/// The reference: one output element at a time, the fold written out.
pub fn reduce_max_axis_reference(input: &[f32], outer: usize, k: usize, inner: usize) -> Vec<f32> {
    let mut out = vec![0f32; outer * inner];
    for o in 0..outer {
        for j in 0..inner {
            let mut acc = f32::MIN;
            for r in 0..k {
                let v = input[(o * k + r) * inner + j];
                acc = if acc > v { acc } else { v };
            }
            out[o * inner + j] = acc;
        }
    }
    out
}
