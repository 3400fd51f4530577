//! Scalar kernel of `TriangleDescriptor` (one batch item).

use crate::ops::{KnnIndex, OpError, OpResult, check_len};

/// Epsilon added to squared norms before the square root (finite angles for zero-length sides).
pub const NORM_EPS2: f64 = 1e-12;

/// Number of triangles for `k` neighbours: `k (k - 1) / 2`.
pub const fn triangle_count(k: usize) -> usize {
    k * k.saturating_sub(1) / 2
}

/// For each query of `query` (`(m, 3)`): its `k` nearest points of `points` (`(n, 3)`;
/// ascending, ties to the lower index, a point equal to the query kept) into `knn_idx`
/// (`(m, k)`), and over all pairs `a < b` of them (row-major) the inner angles of the
/// triangle (query, q_a, q_b) weighted by the softmax of the triangle areas into `phi`
/// (`(m, T, 3)`, `T = k (k - 1) / 2`). Geometry in `f64`, rounded to `f32` at the end.
pub fn triangle_descriptor(query: &[f32], points: &[f32], k: usize, phi: &mut [f32], knn_idx: &mut [i64]) -> OpResult {
    let n = points.len() / 3;
    if k == 0 || k > n {
        return Err(OpError::TooFewPoints { op: "TriangleDescriptor", need: k.max(1), got: n });
    }
    let t_count = triangle_count(k);
    let m = query.len() / 3;
    const OP: &str = "TriangleDescriptor";
    check_len(OP, "points", points.len(), 3 * n)?;
    check_len(OP, "query", query.len(), 3 * m)?;
    check_len(OP, "phi", phi.len(), 3 * t_count * m)?;
    check_len(OP, "knn_idx", knn_idx.len(), k * m)?;
    let (mut nn, mut d2) = (vec![0usize; k], vec![0f32; k]);
    let mut angles = vec![[0f64; 3]; t_count];
    let mut areas = vec![0f64; t_count];
    let mut index = KnnIndex::new(points, m);
    for i in 0..m {
        let q = &query[3 * i..3 * i + 3];
        index.knn(q, k, &mut nn, &mut d2);
        for (o, &j) in knn_idx[k * i..k * (i + 1)].iter_mut().zip(&nn) {
            *o = j as i64;
        }
        if t_count == 0 {
            continue;
        }
        let phi_row = &mut phi[3 * t_count * i..3 * t_count * (i + 1)];
        let p = to_f64(q);
        let mut t = 0;
        for a in 0..k {
            let qa = to_f64(&points[3 * nn[a]..3 * nn[a] + 3]);
            for &jb in &nn[a + 1..] {
                let qb = to_f64(&points[3 * jb..3 * jb + 3]);
                let (pa, pb, ab) = (sub(qa, p), sub(qb, p), sub(qb, qa));
                angles[t] = [angle(pa, pb), angle(neg(pa), ab), angle(neg(pb), neg(ab))];
                areas[t] = 0.5 * norm(cross(pa, pb));
                t += 1;
            }
        }
        let max_area = areas.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let mut sum = 0.0;
        for a in areas.iter_mut() {
            *a = (*a - max_area).exp();
            sum += *a;
        }
        for (t, out) in phi_row.chunks_exact_mut(3).enumerate() {
            let w = areas[t] / sum;
            for (o, ang) in out.iter_mut().zip(angles[t]) {
                *o = (w * ang) as f32;
            }
        }
    }
    Ok(())
}

type V3 = [f64; 3];

fn to_f64(p: &[f32]) -> V3 {
    [p[0] as f64, p[1] as f64, p[2] as f64]
}

fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn neg(a: V3) -> V3 {
    [-a[0], -a[1], -a[2]]
}

fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: V3, b: V3) -> V3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn norm(a: V3) -> f64 {
    dot(a, a).sqrt()
}

/// Angle between `u` and `v` from the clipped cosine with epsilon norms.
fn angle(u: V3, v: V3) -> f64 {
    let c = dot(u, v) / ((dot(u, u) + NORM_EPS2).sqrt() * (dot(v, v) + NORM_EPS2).sqrt());
    c.clamp(-1.0, 1.0).acos()
}
