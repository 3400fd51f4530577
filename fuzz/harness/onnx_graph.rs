//! ONNX loading as the pose and segmenter loaders do it: `ops::read_onnx_proto` (protobuf
//! parsing and the checks before tract), then tract's loader with the `ai.tricons`
//! operators (their attribute and shape rules), typing and decluttering; the same for the
//! graph after the pose loader's rewrite (`pose::rewrite`: node replacements and the
//! early pixel gather).

use tract_onnx::prelude::*;

/// One input; errors are fine, panics, aborts and hangs are the bugs.
pub fn run(data: &[u8]) {
    let Ok(proto) = tricons::ops::read_onnx_proto(data) else { return };
    let onnx = tricons::ops::onnx_with_custom_ops();
    let mut rewritten = proto.clone();
    let changed = tricons::pose::rewrite::rewrite(&mut rewritten) != Default::default();
    for proto in std::iter::once(&proto).chain(changed.then_some(&rewritten)) {
        if let Ok(model) = onnx.model_for_proto_model(proto)
            && let Ok(typed) = model.into_typed()
        {
            let _ = typed.into_decluttered();
        }
    }
}
