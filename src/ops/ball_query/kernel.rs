//! Scalar kernel of `BallQuery` (one batch item).

use crate::ops::{OpResult, check_len, squared_distance};

/// For each centre of `centres` (`(s, 3)`), the first `nsample` indices of `xyz` (`(n, 3)`),
/// in index order, with squared distance `< radius * radius` (strict, in `f32`); unfilled
/// slots repeat the first hit; a centre with no hit gets zeros. `out` is `(s, nsample)`.
pub fn ball_query(xyz: &[f32], centres: &[f32], radius: f32, nsample: usize, out: &mut [i64]) -> OpResult {
    const OP: &str = "BallQuery";
    check_len(OP, "xyz", xyz.len(), xyz.len() / 3 * 3)?;
    check_len(OP, "centres", centres.len(), centres.len() / 3 * 3)?;
    check_len(OP, "out", out.len(), centres.len() / 3 * nsample)?;
    let r2 = radius * radius;
    if nsample == 0 {
        return Ok(());
    }
    for (c, row) in centres.chunks_exact(3).zip(out.chunks_exact_mut(nsample)) {
        let mut found = 0usize;
        for (j, p) in xyz.chunks_exact(3).enumerate() {
            if squared_distance(c, p) < r2 {
                row[found] = j as i64;
                found += 1;
                if found == nsample {
                    break;
                }
            }
        }
        let pad = if found == 0 { 0 } else { row[0] };
        row[found..].fill(pad);
    }
    Ok(())
}
