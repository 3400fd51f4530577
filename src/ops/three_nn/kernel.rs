//! Scalar kernels of `ThreeNN` and `ThreeInterpolate` (one batch item).

use crate::ops::{KnnIndex, OpError, OpResult, check_len, checked_index};

/// Number of neighbours of `ThreeNN`.
pub const NEIGHBOURS: usize = 3;

/// For each point of `unknown` (`(n, 3)`), its three nearest points of `known` (`(m, 3)`,
/// `m >= 3`): `dist` (`(n, 3)`, Euclidean, ascending) and `idx` (`(n, 3)`), ties to the lower index.
pub fn three_nn(unknown: &[f32], known: &[f32], dist: &mut [f32], idx: &mut [i64]) -> OpResult {
    let m = known.len() / 3;
    if m < NEIGHBOURS {
        return Err(OpError::TooFewPoints { op: "ThreeNN", need: NEIGHBOURS, got: m });
    }
    let n = unknown.len() / 3;
    check_len("ThreeNN", "unknown", unknown.len(), 3 * n)?;
    check_len("ThreeNN", "known", known.len(), 3 * m)?;
    check_len("ThreeNN", "dist", dist.len(), 3 * n)?;
    check_len("ThreeNN", "idx", idx.len(), 3 * n)?;
    let (mut nn, mut d2) = ([0usize; NEIGHBOURS], [0f32; NEIGHBOURS]);
    let mut index = KnnIndex::new(known, n);
    for ((q, d_row), i_row) in unknown.chunks_exact(3).zip(dist.chunks_exact_mut(3)).zip(idx.chunks_exact_mut(3)) {
        index.knn(q, NEIGHBOURS, &mut nn, &mut d2);
        for t in 0..NEIGHBOURS {
            d_row[t] = d2[t].sqrt();
            i_row[t] = nn[t] as i64;
        }
    }
    Ok(())
}

/// `out[c, j] = (f[c, i0] * w0 + f[c, i1] * w1) + f[c, i2] * w2` with `i`, `w` the rows of
/// `idx` and `weight` (`(n, 3)`), features `(c, m)`; `out` is `(c, n)`.
pub fn three_interpolate(features: &[f32], m: usize, idx: &[i64], weight: &[f32], out: &mut [f32]) -> OpResult {
    const OP: &str = "ThreeInterpolate";
    let n = idx.len() / 3;
    check_len(OP, "idx", idx.len(), 3 * n)?;
    check_len(OP, "weight", weight.len(), 3 * n)?;
    let channels = features.len().checked_div(m).unwrap_or(0);
    check_len(OP, "features", features.len(), channels * m)?;
    check_len(OP, "out", out.len(), channels * n)?;
    let cols: Vec<usize> = idx.iter().map(|&i| checked_index(OP, i, m)).collect::<OpResult<_>>()?;
    if m == 0 || n == 0 {
        return Ok(());
    }
    for (f, o) in features.chunks_exact(m).zip(out.chunks_exact_mut(n)) {
        for j in 0..n {
            let (i, w) = (&cols[3 * j..3 * j + 3], &weight[3 * j..3 * j + 3]);
            o[j] = (f[i[0]] * w[0] + f[i[1]] * w[1]) + f[i[2]] * w[2];
        }
    }
    Ok(())
}
