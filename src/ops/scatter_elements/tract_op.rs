//! tract runtime of `ScatterElements`.

use tract_onnx::tract_hir::internal::*;

use super::kernel::{scatter_elements, scatter_rows};
use super::{ScatterElements, ScatterRows};
use crate::ops::tract_glue::TractKernel;

impl ScatterElements {
    fn run<T: Datum + Copy>(&self, data: TValue, indices: &[i64], updates: &TValue) -> TractResult<TValue> {
        let shape = data.shape().to_vec();
        let mut data = data.into_tensor();
        let updates_shape = updates.shape().to_vec();
        let updates = updates.try_as_plain_ram()?.as_slice::<T>()?;
        scatter_elements(
            data.try_as_plain_ram_mut()?.as_slice_mut::<T>()?,
            &shape,
            indices,
            updates,
            &updates_shape,
            self.axis,
        )?;
        Ok(data.into_tvalue())
    }
}

impl TractKernel for ScatterElements {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        Ok(tvec![inputs[0].datum_type.fact(inputs[0].shape.clone())])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let [data, indices, updates]: [TValue; 3] =
            inputs.into_iter().collect::<Vec<_>>().try_into().map_err(|_| format_err!("ScatterElements: 3 inputs"))?;
        ensure!(
            data.datum_type() == updates.datum_type(),
            "ScatterElements: data is {:?}, updates {:?}",
            data.datum_type(),
            updates.datum_type()
        );
        let indices = indices.cast_to::<i64>()?;
        let indices = indices.try_as_plain_ram()?.as_slice::<i64>()?;
        use DatumType::*;
        let out = match data.datum_type() {
            F32 => self.run::<f32>(data, indices, &updates),
            F64 => self.run::<f64>(data, indices, &updates),
            I64 => self.run::<i64>(data, indices, &updates),
            I32 => self.run::<i32>(data, indices, &updates),
            I16 => self.run::<i16>(data, indices, &updates),
            I8 => self.run::<i8>(data, indices, &updates),
            U64 => self.run::<u64>(data, indices, &updates),
            U32 => self.run::<u32>(data, indices, &updates),
            U16 => self.run::<u16>(data, indices, &updates),
            U8 => self.run::<u8>(data, indices, &updates),
            Bool => self.run::<bool>(data, indices, &updates),
            dt => bail!("ScatterElements: element type {dt:?} is not handled here"),
        }?;
        Ok(tvec![out])
    }
}

impl ScatterRows {
    fn run<T: Datum + Copy>(data: TValue, indices: &[i64], updates: &TValue) -> TractResult<TValue> {
        let shape = data.shape().to_vec();
        let mut data = data.into_tensor();
        let updates_shape = updates.shape().to_vec();
        let updates = updates.try_as_plain_ram()?.as_slice::<T>()?;
        scatter_rows(data.try_as_plain_ram_mut()?.as_slice_mut::<T>()?, &shape, indices, updates, &updates_shape)?;
        Ok(data.into_tvalue())
    }
}

impl TractKernel for ScatterRows {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        Ok(tvec![inputs[0].datum_type.fact(inputs[0].shape.clone())])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let [data, indices, updates]: [TValue; 3] =
            inputs.into_iter().collect::<Vec<_>>().try_into().map_err(|_| format_err!("ScatterRows: 3 inputs"))?;
        ensure!(
            data.datum_type() == updates.datum_type(),
            "ScatterRows: data is {:?}, updates {:?}",
            data.datum_type(),
            updates.datum_type()
        );
        let indices = indices.cast_to::<i64>()?;
        let indices = indices.try_as_plain_ram()?.as_slice::<i64>()?;
        use DatumType::*;
        let out = match data.datum_type() {
            F32 => Self::run::<f32>(data, indices, &updates),
            F64 => Self::run::<f64>(data, indices, &updates),
            I64 => Self::run::<i64>(data, indices, &updates),
            I32 => Self::run::<i32>(data, indices, &updates),
            I8 => Self::run::<i8>(data, indices, &updates),
            U8 => Self::run::<u8>(data, indices, &updates),
            Bool => Self::run::<bool>(data, indices, &updates),
            dt => bail!("ScatterRows: element type {dt:?} is not handled"),
        }?;
        Ok(tvec![out])
    }
}
