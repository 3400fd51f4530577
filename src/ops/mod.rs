//! Custom operators of the exported TriCons-Pose graph (ONNX domain `ai.tricons`).
//!
//! Each operator lives in its own module in three layers: a pure kernel on
//! slices (`kernel`, testable without tract, the scalar reference every faster
//! kernel is checked against), the tract op wrapper and the ONNX parsing with
//! its shape rules. The node table and exact semantics (tie-breaking, float
//! evaluation order) are those of `tools/tricons_pose/onnx_export_ops.py`:
//!
//! | node | module |
//! | --- | --- |
//! | `FurthestPointSample` | [`fps`] |
//! | `GatherPoints`, `GroupPoints` | [`gather`] |
//! | `BallQuery` | [`ball_query`] |
//! | `ThreeNN`, `ThreeInterpolate` | [`three_nn`] |
//! | `TriangleDescriptor` | [`triangle`] |
//!
//! Kernels work on one batch item: points are `(n, 3)` row-major `f32`
//! slices, features `(c, n)` row-major, indices `i64`. Squared distances are
//! `(dx*dx + dy*dy) + dz*dz` in `f32` (no fused multiply-add) so that index
//! results are bit-identical with the PyTorch reference; ties go to the lower
//! index.

pub mod ball_query;
pub mod fps;
pub mod gather;
pub mod profile;
pub mod three_nn;
pub mod tract_glue;
pub mod triangle;

/// ONNX node types of the `ai.tricons` domain, as registered by [`register`].
pub const NODE_TYPES: [&str; 7] = [
    "FurthestPointSample",
    "GatherPoints",
    "BallQuery",
    "GroupPoints",
    "ThreeNN",
    "ThreeInterpolate",
    "TriangleDescriptor",
];

/// Register every `ai.tricons` operator with a tract ONNX loader.
///
/// tract keys its op register by node type only (not domain); these names do not
/// collide with standard ONNX operators.
pub fn register(onnx: &mut tract_onnx::Onnx) {
    let reg = &mut onnx.op_register;
    reg.insert("FurthestPointSample", fps::onnx::parse);
    reg.insert("GatherPoints", gather::onnx::parse_gather);
    reg.insert("BallQuery", ball_query::onnx::parse);
    reg.insert("GroupPoints", gather::onnx::parse_group);
    reg.insert("ThreeNN", three_nn::onnx::parse_three_nn);
    reg.insert("ThreeInterpolate", three_nn::onnx::parse_three_interpolate);
    reg.insert("TriangleDescriptor", triangle::onnx::parse);
}

/// A tract ONNX loader with the standard operators and the `ai.tricons` ones.
pub fn onnx_with_custom_ops() -> tract_onnx::Onnx {
    let mut onnx = tract_onnx::onnx();
    register(&mut onnx);
    onnx
}

/// Why a kernel refused its inputs.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OpError {
    /// An index input points outside the indexed axis.
    #[error("{op}: index {index} out of range for an axis of length {len}")]
    IndexOutOfRange {
        /// Node name.
        op: &'static str,
        /// The offending index.
        index: i64,
        /// Length of the indexed axis.
        len: usize,
    },
    /// Fewer points than the operator needs.
    #[error("{op}: needs at least {need} points, got {got}")]
    TooFewPoints {
        /// Node name.
        op: &'static str,
        /// Minimum point count.
        need: usize,
        /// Actual point count.
        got: usize,
    },
    /// A slice length disagrees with the stated dimensions.
    #[error("{op}: {what} has length {got}, expected {expected}")]
    BadLength {
        /// Node name.
        op: &'static str,
        /// Which argument.
        what: &'static str,
        /// Actual length.
        got: usize,
        /// Expected length.
        expected: usize,
    },
}

/// Result of a kernel.
pub type OpResult<T = ()> = std::result::Result<T, OpError>;

/// Squared distance of two 3-vectors, in the fixed order `(dx*dx + dy*dy) + dz*dz`.
#[inline]
pub fn squared_distance(a: &[f32], b: &[f32]) -> f32 {
    let dx = a[0] - b[0];
    let dy = a[1] - b[1];
    let dz = a[2] - b[2];
    (dx * dx + dy * dy) + dz * dz
}

pub(crate) fn check_len(op: &'static str, what: &'static str, got: usize, expected: usize) -> OpResult {
    if got == expected { Ok(()) } else { Err(OpError::BadLength { op, what, got, expected }) }
}

pub(crate) fn checked_index(op: &'static str, index: i64, len: usize) -> OpResult<usize> {
    if index >= 0 && (index as u64) < len as u64 {
        Ok(index as usize)
    } else {
        Err(OpError::IndexOutOfRange { op, index, len })
    }
}

/// Indices of the `k` points of `points` (`(n, 3)`) nearest to `query`, ascending by squared
/// distance, ties to the lower index; also returns their squared distances.
///
/// Brute force with a bounded insertion buffer: `O(n k)`, the reference for the kNN of
/// [`three_nn`] and [`triangle`]. `k` must be at most `n`.
pub fn knn_brute_force(query: &[f32], points: &[f32], k: usize, idx: &mut [usize], d2: &mut [f32]) {
    let n = points.len() / 3;
    debug_assert!(k <= n && idx.len() >= k && d2.len() >= k);
    let mut len = 0usize;
    for j in 0..n {
        let d = squared_distance(query, &points[3 * j..3 * j + 3]);
        // NaN distances sort last (filled in below); strictly smaller than the current
        // k-th keeps the lower index on ties
        if d.is_nan() || (len == k && d >= d2[k - 1]) {
            continue;
        }
        let mut pos = if len < k { len } else { k - 1 };
        while pos > 0 && d < d2[pos - 1] {
            d2[pos] = d2[pos - 1];
            idx[pos] = idx[pos - 1];
            pos -= 1;
        }
        d2[pos] = d;
        idx[pos] = j;
        if len < k {
            len += 1;
        }
    }
    // fewer than k comparable points (NaN coordinates): the NaN ones follow in index order
    if len < k {
        let mut next = 0usize;
        while len < k {
            if !idx[..len].contains(&next) {
                idx[len] = next;
                d2[len] = f32::NAN;
                len += 1;
            }
            next += 1;
        }
    }
}
