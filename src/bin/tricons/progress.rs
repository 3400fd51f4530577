//! Progress bars for long commands (hidden when stderr is not a terminal).

use indicatif::{ProgressBar, ProgressStyle};

/// A bar counting `total` items of `what`.
pub fn bar(total: usize, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(total as u64);
    let style = ProgressStyle::with_template(&format!(
        "{{spinner}} {what} [{{elapsed_precise}}] {{wide_bar}} {{pos}}/{{len}} ({{per_sec}}, eta {{eta}})"
    ))
    .unwrap_or_else(|_| ProgressStyle::default_bar());
    pb.set_style(style);
    pb
}

/// A counter without a known total (frames recorded until stopped).
pub fn spinner(what: &str) -> ProgressBar {
    let pb = ProgressBar::new_spinner();
    let style =
        ProgressStyle::with_template(&format!("{{spinner}} {what} [{{elapsed_precise}}] {{pos}} frames ({{per_sec}})"))
            .unwrap_or_else(|_| ProgressStyle::default_spinner());
    pb.set_style(style);
    pb
}
