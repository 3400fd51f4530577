//! Shared tract plumbing of the custom operators.
//!
//! An operator provides its ONNX side ([`OnnxRules`]: name, arity, shape rules; in the
//! op's `onnx.rs`, with the attribute parsing) and its runtime side ([`TractKernel`]:
//! output facts and evaluation on plain tensors; in the op's `tract_op.rs`, calling the
//! pure kernel). [`InferenceWrapper`] turns it into a tract-hir expansion that wires a
//! [`TypedWrapper`], the typed op that survives decluttering and optimisation.

use std::fmt::Debug;
use std::hash::Hash;

use tract_onnx::tract_hir::internal::*;

/// ONNX side of a custom operator.
pub trait OnnxRules {
    /// ONNX node type (domain `ai.tricons`).
    const NAME: &'static str;
    /// Number of inputs.
    const N_INPUTS: usize;
    /// Number of outputs.
    const N_OUTPUTS: usize;
    /// Type and shape rules (arity is checked before).
    fn rules<'r, 'p: 'r, 's: 'r>(
        &'s self,
        s: &mut Solver<'r>,
        inputs: &'p [TensorProxy],
        outputs: &'p [TensorProxy],
    ) -> InferenceResult;
}

/// Implements [`OnnxRules`] for an op type: its node name, arity, and the body of
/// `rules` with the op, the solver, the inputs and the outputs bound to the given names.
macro_rules! onnx_rules {
    ($ty:ty, $name:literal, inputs: $ni:literal, outputs: $no:literal, |$op:ident, $s:ident, $inputs:ident, $outputs:ident| $body:block) => {
        impl $crate::ops::tract_glue::OnnxRules for $ty {
            const NAME: &'static str = $name;
            const N_INPUTS: usize = $ni;
            const N_OUTPUTS: usize = $no;

            fn rules<'r, 'p: 'r, 's: 'r>(
                &'s self,
                $s: &mut Solver<'r>,
                $inputs: &'p [TensorProxy],
                $outputs: &'p [TensorProxy],
            ) -> InferenceResult {
                let $op = self;
                $body
            }
        }
    };
}
pub(crate) use onnx_rules;

/// Runtime side of a custom operator.
pub trait TractKernel {
    /// Output facts (dtype and shape, possibly symbolic) from the input facts.
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>>;
    /// Evaluate on concrete tensors.
    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>>;
}

/// A complete custom operator.
pub trait CustomOp: OnnxRules + TractKernel + Clone + Debug + PartialEq + Eq + Hash + Send + Sync + 'static {}
impl<T: OnnxRules + TractKernel + Clone + Debug + PartialEq + Eq + Hash + Send + Sync + 'static> CustomOp for T {}

/// The inference-time (tract-hir) form of a custom operator.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct InferenceWrapper<T>(pub T);

impl<T: CustomOp> Expansion for InferenceWrapper<T> {
    fn name(&self) -> StaticName {
        T::NAME.into()
    }

    fn nboutputs(&self) -> TractResult<usize> {
        Ok(T::N_OUTPUTS)
    }

    fn rules<'r, 'p: 'r, 's: 'r>(
        &'s self,
        s: &mut Solver<'r>,
        inputs: &'p [TensorProxy],
        outputs: &'p [TensorProxy],
    ) -> InferenceResult {
        check_input_arity(inputs, T::N_INPUTS)?;
        check_output_arity(outputs, T::N_OUTPUTS)?;
        self.0.rules(s, inputs, outputs)
    }

    fn wire(&self, prefix: &str, model: &mut TypedModel, inputs: &[OutletId]) -> TractResult<TVec<OutletId>> {
        model.wire_node(prefix, TypedWrapper(self.0.clone()), inputs)
    }
}

/// The typed (runtime) form of a custom operator.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct TypedWrapper<T>(pub T);

impl<T: CustomOp> Op for TypedWrapper<T> {
    fn name(&self) -> StaticName {
        T::NAME.into()
    }

    op_as_typed_op!();
}

impl<T: CustomOp> EvalOp for TypedWrapper<T> {
    op_out_of_plan!();

    fn eval(&self, _ctx: &EvalContext, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        super::profile::timed(T::NAME, || self.0.eval(inputs))
    }
}

impl<T: CustomOp> TypedOp for TypedWrapper<T> {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        self.0.output_facts(inputs)
    }

    as_op!();
}

/// Wrap an operator for the ONNX op register.
pub fn expand_op<T: CustomOp>(op: T) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    Ok((expand(InferenceWrapper(op)), vec![]))
}

/// A plain tensor's data as a slice of `T`, with a clear error naming the op and input.
pub fn input_slice<'a, T: Datum>(t: &'a TValue, op: &str, what: &str, rank: usize) -> TractResult<&'a [T]> {
    ensure!(t.datum_type() == T::datum_type(), "{op}: {what} is {:?}, expected {:?}", t.datum_type(), T::datum_type());
    ensure!(t.rank() == rank, "{op}: {what} has rank {}, expected {rank}", t.rank());
    t.try_as_plain_ram()?.as_slice::<T>()
}

/// Rank-3 point cloud `(B, N, 3)` rule.
pub fn points_rule<'r, 'p: 'r>(s: &mut Solver<'r>, t: &'p TensorProxy) -> InferenceResult {
    s.equals(&t.datum_type, f32::datum_type())?;
    s.equals(&t.rank, 3)?;
    s.equals(&t.shape[2], 3.to_dim())
}

/// A new tensor of `shape` from `data`.
pub fn output<T: Datum + Copy>(shape: &[usize], data: Vec<T>) -> TractResult<TValue> {
    Ok(tract_ndarray::ArrayD::from_shape_vec(shape, data)?.into_tvalue())
}
