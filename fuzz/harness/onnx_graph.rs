//! ONNX loading with tricons' custom operators (`ai.tricons`): protobuf parsing, the
//! custom ops' attribute and shape rules, and typing.

use tract_onnx::prelude::*;

/// One input; errors are fine, panics, aborts and hangs are the bugs.
pub fn run(data: &[u8]) {
    let onnx = tricons::ops::onnx_with_custom_ops();
    if let Ok(model) = onnx.model_for_read(&mut &data[..])
        && let Ok(typed) = model.into_typed()
    {
        let _ = typed.into_decluttered();
    }
}
