//! The int8 quantization profile (`*.int8.json`, `tricons quantize` output).

/// One input; errors are fine, panics, aborts and hangs are the bugs.
pub fn run(data: &[u8]) {
    let path = crate::scratch::file("model.int8.json", data);
    if let Ok(profile) = tricons::quant::QuantProfile::read(&path) {
        let _ = profile.model_path(&path);
    }
}
