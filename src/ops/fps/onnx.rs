//! ONNX parsing and shape rules of `FurthestPointSample`.

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use crate::ops::tract_glue::{OnnxRules, expand_op, points_rule};

/// `FurthestPointSample(xyz (B, N, 3) f32) -> idx (B, npoint) i64`, attribute `npoint`.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct FurthestPointSample {
    /// Number of points to pick.
    pub npoint: usize,
}

/// Build the op from its ONNX node.
pub fn parse(_ctx: &ParsingContext, node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    let npoint: i64 = node.get_attr("npoint")?;
    ensure!(npoint > 0, "FurthestPointSample {}: npoint must be positive, got {npoint}", node.name);
    expand_op(FurthestPointSample { npoint: npoint as usize })
}

impl OnnxRules for FurthestPointSample {
    const NAME: &'static str = "FurthestPointSample";
    const N_INPUTS: usize = 1;
    const N_OUTPUTS: usize = 1;

    fn rules<'r, 'p: 'r, 's: 'r>(
        &'s self,
        s: &mut Solver<'r>,
        inputs: &'p [TensorProxy],
        outputs: &'p [TensorProxy],
    ) -> InferenceResult {
        points_rule(s, &inputs[0])?;
        s.equals(&outputs[0].datum_type, i64::datum_type())?;
        s.equals(&outputs[0].rank, 2)?;
        s.equals(&outputs[0].shape[0], &inputs[0].shape[0])?;
        s.equals(&outputs[0].shape[1], self.npoint.to_dim())
    }
}
