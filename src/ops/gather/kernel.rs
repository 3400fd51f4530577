//! Scalar kernels of `GatherPoints` and `GroupPoints` (one batch item).

use crate::ops::{OpResult, check_len, checked_index};

/// `out[c, s] = features[c, idx[s]]` for features `(c, n)` and `idx` `(s,)`; `out` is `(c, s)`.
pub fn gather_points(features: &[f32], n: usize, idx: &[i64], out: &mut [f32]) -> OpResult {
    index_gather("GatherPoints", features, n, idx, out)
}

/// `out[c, s, k] = features[c, idx[s, k]]` for features `(c, n)` and `idx` `(s, k)` (flattened);
/// `out` is `(c, s, k)`. The same loop as [`gather_points`] over the flattened index.
pub fn group_points(features: &[f32], n: usize, idx: &[i64], out: &mut [f32]) -> OpResult {
    index_gather("GroupPoints", features, n, idx, out)
}

fn index_gather(op: &'static str, features: &[f32], n: usize, idx: &[i64], out: &mut [f32]) -> OpResult {
    let cols: Vec<usize> = idx.iter().map(|&i| checked_index(op, i, n)).collect::<OpResult<_>>()?;
    if n == 0 {
        return check_len(op, "features", features.len(), 0);
    }
    let channels = features.len() / n;
    check_len(op, "features", features.len(), channels * n)?;
    check_len(op, "out", out.len(), channels * cols.len())?;
    for (row, out_row) in features.chunks_exact(n).zip(out.chunks_exact_mut(cols.len().max(1))) {
        for (o, &j) in out_row.iter_mut().zip(&cols) {
            *o = row[j];
        }
    }
    Ok(())
}
