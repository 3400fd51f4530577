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
//! Three standard ONNX operators are registered too, for the Mask R-CNN graph:
//! [`roi_align`] (`RoiAlign`, which tract lacks), [`nms`] (`NonMaxSuppression`,
//! replacing tract's pairwise one with a grid kernel) and [`scatter_elements`]
//! (`ScatterElements`, replacing tract's per-element coordinate walk). Two more replace standard nodes
//! tract runs slowly, put in by the pose loader's rewrite ([`crate::pose::rewrite`]):
//! [`reduce_max`] (`ReduceMaxAxis` for a single-axis `ReduceMax`), [`upsample`]
//! (`BilinearUpsample2x` for a linear half-pixel x2 `Resize`), [`layer_norm`]
//! (`LayerNormLastAxis` for a last-axis `LayerNormalization`) and [`softmax`]
//! (`SoftmaxLastAxis` for a last-axis `Softmax`). The Mask R-CNN loader's
//! rewrite ([`crate::segment::rewrite`]) puts in [`depthwise`] (`DepthwiseConv2d` for a
//! `Conv` with one input channel per group) and [`resize`] (`Resize2d` for its linear
//! half-pixel and nearest asymmetric `Resize`s).
//!
//! Kernels work on one batch item: points are `(n, 3)` row-major `f32`
//! slices, features `(c, n)` row-major, indices `i64`. Squared distances are
//! `(dx*dx + dy*dy) + dz*dz` in `f32` (no fused multiply-add) so that index
//! results are bit-identical with the PyTorch reference; ties go to the lower
//! index.

pub mod ball_query;
pub mod conv_geometry;
pub mod depthwise;
pub mod fps;
pub mod gather;
pub mod knn;
pub mod layer_norm;
pub mod nms;
pub mod pixel_gather;
pub mod profile;
pub mod proto;
pub mod qconv;
pub mod qlinear;
pub mod reduce_max;
pub mod resize;
pub mod roi_align;
pub mod scatter_elements;
pub mod softmax;
pub mod three_nn;
pub mod tract_glue;
pub mod triangle;
pub mod upsample;

pub use knn::{KnnIndex, PointsSoa, knn_brute_force};

/// Node types whose wall time [`profile`] accounts: the `ai.tricons` ones of the
/// exported graph, the two standard operators implemented here (`RoiAlign`,
/// `NonMaxSuppression`), the int8 nodes of the quantization rewrite, then the two
/// replacements of the pose rewrite, the two of the Mask R-CNN rewrite, the pose
/// rewrite's pixel gather, the Mask R-CNN rewrite's row scatter and the pose rewrite's
/// layer normalisation, resampled pixel gather and last-axis softmax.
pub const PROFILED_NODE_TYPES: [&str; 21] = [
    "FurthestPointSample",
    "GatherPoints",
    "BallQuery",
    "GroupPoints",
    "ThreeNN",
    "ThreeInterpolate",
    "TriangleDescriptor",
    "RoiAlign",
    "NonMaxSuppression",
    "QLinear",
    "QConv",
    "ReduceMaxAxis",
    "BilinearUpsample2x",
    "ScatterElements",
    "DepthwiseConv2d",
    "Resize2d",
    "PixelGather",
    "ScatterRows",
    "LayerNormLastAxis",
    "ResampledPixelGather",
    "SoftmaxLastAxis",
];

/// ONNX node types of the `ai.tricons` domain, as registered by [`register`].
pub const NODE_TYPES: &[&str] = PROFILED_NODE_TYPES.split_at(7).0;

/// Register every `ai.tricons` operator, `RoiAlign` and the fast `NonMaxSuppression` and `ScatterElements`
/// with a tract ONNX loader.
///
/// tract keys its op register by node type only (not domain); the `ai.tricons` names
/// do not collide with standard ONNX operators, the two standard ones override on purpose.
pub fn register(onnx: &mut tract_onnx::Onnx) {
    let reg = &mut onnx.op_register;
    reg.insert("FurthestPointSample", fps::onnx::parse);
    reg.insert("GatherPoints", gather::onnx::parse_gather);
    reg.insert("BallQuery", ball_query::onnx::parse);
    reg.insert("GroupPoints", gather::onnx::parse_group);
    reg.insert("ThreeNN", three_nn::onnx::parse_three_nn);
    reg.insert("ThreeInterpolate", three_nn::onnx::parse_three_interpolate);
    reg.insert("TriangleDescriptor", triangle::onnx::parse);
    reg.insert("RoiAlign", roi_align::onnx::parse);
    reg.insert("NonMaxSuppression", nms::onnx::parse);
    reg.insert("ScatterElements", scatter_elements::onnx::parse);
    reg.insert("QLinear", qlinear::onnx::parse);
    reg.insert("QConv", qconv::onnx::parse);
    reg.insert("ReduceMaxAxis", reduce_max::onnx::parse);
    reg.insert("BilinearUpsample2x", upsample::onnx::parse);
    reg.insert("DepthwiseConv2d", depthwise::onnx::parse);
    reg.insert("Resize2d", resize::onnx::parse);
    reg.insert("PixelGather", pixel_gather::onnx::parse);
    reg.insert("ScatterRows", scatter_elements::onnx::parse_rows);
    reg.insert("LayerNormLastAxis", layer_norm::onnx::parse);
    reg.insert("ResampledPixelGather", pixel_gather::onnx::parse_resampled);
    reg.insert("SoftmaxLastAxis", softmax::onnx::parse);
}

/// A tract ONNX loader with the standard operators and the `ai.tricons` ones.
pub fn onnx_with_custom_ops() -> tract_onnx::Onnx {
    let mut onnx = tract_onnx::onnx();
    register(&mut onnx);
    onnx
}

/// Parses an ONNX file's bytes and refuses what tract's loader would panic on (a graph
/// output nothing defines, [`proto::undefined_output`]); the message says what is wrong.
pub fn read_onnx_proto(bytes: &[u8]) -> std::result::Result<tract_onnx::pb::ModelProto, String> {
    use tract_onnx::prelude::Framework;
    let proto = onnx_with_custom_ops()
        .proto_model_for_read(&mut &bytes[..])
        .map_err(|e| format!("not a readable ONNX model: {e:#}"))?;
    let graph = proto.graph.as_ref().ok_or("not a readable ONNX model: it holds no graph")?;
    if let Some(what) = proto::undefined_output(graph) {
        return Err(format!("not a valid ONNX model: {what} is produced by no node, input or initializer"));
    }
    Ok(proto)
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
    /// A kernel below the operator failed.
    #[error("{op}: {message}")]
    Kernel {
        /// Node name.
        op: &'static str,
        /// What failed.
        message: String,
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
