//! Scalar kernel of `FurthestPointSample` (one batch item).

use crate::ops::{OpResult, check_len, squared_distance};

/// Farthest point sampling of `npoint` indices from `xyz` (`(n, 3)`) into `out`.
///
/// Starts at index 0; keeps for every point its smallest squared distance to the
/// chosen ones; the next index is the first maximum of those. With fewer distinct
/// points than `npoint`, once every remaining distance is 0 the first maximum is
/// index 0, which then repeats. An empty cloud gives zeros.
pub fn furthest_point_sample(xyz: &[f32], npoint: usize, out: &mut [i64]) -> OpResult {
    const OP: &str = "FurthestPointSample";
    let n = xyz.len() / 3;
    check_len(OP, "xyz", xyz.len(), 3 * n)?;
    check_len(OP, "out", out.len(), npoint)?;
    if n == 0 {
        out.fill(0);
        return Ok(());
    }
    let mut min_d2 = vec![f32::INFINITY; n];
    let mut cur = 0usize;
    for slot in out.iter_mut() {
        *slot = cur as i64;
        let c = [xyz[3 * cur], xyz[3 * cur + 1], xyz[3 * cur + 2]];
        let (mut best, mut best_i) = (-1.0f32, 0usize);
        for (j, m) in min_d2.iter_mut().enumerate() {
            let d = squared_distance(&xyz[3 * j..3 * j + 3], &c);
            if d < *m {
                *m = d;
            }
            if *m > best {
                best = *m;
                best_i = j;
            }
        }
        cur = best_i;
    }
    Ok(())
}
