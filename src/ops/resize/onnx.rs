//! ONNX parsing and shape rules of `Resize2d`: the node takes `(X, sizes)`; the sizes must
//! be known when the plan is made (tract folds the Mask R-CNN's shape arithmetic for a
//! given image size), and the planned op keeps only `X`.

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use super::kernel::ResizeMode;
use crate::ops::tract_glue::{TypedWrapper, onnx_rules};

/// The planned op: `(N, C, H, W)` f32 -> `(N, C, out_h, out_w)`.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct Resize2d {
    /// The interpolation.
    pub mode: ResizeMode,
    /// Output height.
    pub out_h: usize,
    /// Output width.
    pub out_w: usize,
}

/// The node as parsed: `mode` attribute `linear` or `nearest`.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
struct Resize2dNode {
    mode: ResizeMode,
}

/// Build the node (attribute `mode`: `linear` for linear/half-pixel, `nearest` for
/// nearest/asymmetric/floor).
pub fn parse(_ctx: &ParsingContext, node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    let mode = match node.get_attr::<&str>("mode")? {
        "linear" => ResizeMode::LinearHalfPixel,
        "nearest" => ResizeMode::NearestAsymmetricFloor,
        other => bail!("{}: Resize2d mode {other:?} (linear or nearest)", node.name),
    };
    Ok((expand(Resize2dNode { mode }), vec![]))
}

/// `sizes` as (N, C, H, W), from a value known at planning.
fn sizes(t: &Tensor) -> TractResult<[usize; 4]> {
    let v = t.cast_to::<i64>()?;
    let v = v.try_as_plain_ram()?.as_slice::<i64>()?.to_vec();
    ensure!(v.len() == 4 && v.iter().all(|&d| d >= 0), "Resize2d: sizes {v:?}, expected 4 non-negative values");
    Ok([v[0] as usize, v[1] as usize, v[2] as usize, v[3] as usize])
}

impl Expansion for Resize2dNode {
    fn name(&self) -> StaticName {
        "Resize2d".into()
    }

    fn rules<'r, 'p: 'r, 's: 'r>(
        &'s self,
        s: &mut Solver<'r>,
        inputs: &'p [TensorProxy],
        outputs: &'p [TensorProxy],
    ) -> InferenceResult {
        check_input_arity(inputs, 2)?;
        check_output_arity(outputs, 1)?;
        s.equals(&inputs[0].datum_type, f32::datum_type())?;
        s.equals(&outputs[0].datum_type, f32::datum_type())?;
        s.equals(&inputs[0].rank, 4)?;
        s.equals(&outputs[0].rank, 4)?;
        s.equals(&inputs[0].shape[0], &outputs[0].shape[0])?;
        s.equals(&inputs[0].shape[1], &outputs[0].shape[1])?;
        s.given(&inputs[1].value, move |s, v| {
            let [_, _, h, w] = sizes(&v)?;
            s.equals(&outputs[0].shape[2], h.to_dim())?;
            s.equals(&outputs[0].shape[3], w.to_dim())
        })
    }

    fn wire(&self, prefix: &str, model: &mut TypedModel, inputs: &[OutletId]) -> TractResult<TVec<OutletId>> {
        let x = model.outlet_fact(inputs[0])?.clone();
        let known = model.outlet_fact(inputs[1])?.konst.clone();
        let known = known.ok_or_else(|| format_err!("Resize2d {prefix}: sizes not known when planning"))?;
        let sizes = sizes(&known)?;
        ensure!(
            x.shape.rank() == 4 && x.shape[0] == sizes[0].to_dim() && x.shape[1] == sizes[1].to_dim(),
            "Resize2d {prefix}: sizes {sizes:?} change N or C of {:?}",
            x.shape
        );
        model.wire_node(
            prefix,
            TypedWrapper(Resize2d { mode: self.mode, out_h: sizes[2], out_w: sizes[3] }),
            &inputs[..1],
        )
    }
}

// The planned op's rules (it is never parsed from a node: `Resize2dNode` wires it).
onnx_rules!(Resize2d, "Resize2d", inputs: 1, outputs: 1, |op, s, inputs, outputs| {
    s.equals(&inputs[0].datum_type, f32::datum_type())?;
    s.equals(&outputs[0].datum_type, f32::datum_type())?;
    s.equals(&outputs[0].shape[2], op.out_h.to_dim())?;
    s.equals(&outputs[0].shape[3], op.out_w.to_dim())
});
