//! Predictions JSON Lines (`tricons eval --pred`, the sinks' output format).

/// One input; errors are fine, panics, aborts and hangs are the bugs.
pub fn run(data: &[u8]) {
    let path = crate::scratch::file("predictions.jsonl", data);
    let _ = tricons::output::read_predictions(&path);
}
