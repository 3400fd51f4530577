//! The `tricons` command-line tool.

mod bench;
mod bench_pipeline;
mod bench_segment;
mod common;
mod devices;
mod eval;
mod inspect;
mod progress;
mod quantize;
mod record;
mod replay;
mod segment;
mod serve;
mod source_args;
mod synth;
mod validate;

use clap::{Parser, Subcommand};

/// tricons: category-level 6D object pose estimation on edge boards.
#[derive(Parser)]
#[command(name = "tricons", version, about, long_about = None, propagate_version = true)]
#[command(
    after_help = "Examples:\n  tricons replay                 # the shipped pose model on the shipped demo recording\n  tricons synth --split test --out data/synthnocs-test\n  \
    tricons inspect data/synthnocs-test --predictions > gt.jsonl\n  \
    tricons eval --gt data/synthnocs-test --pred gt.jsonl --iou corrected\n\n\
    Set RUST_LOG=debug for more detail."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render SynthNOCS frames (RGB-D with ground truth) into a recording.
    Synth(synth::Args),
    /// Score predictions against a recording's ground truth with the NOCS protocol.
    Eval(eval::Args),
    /// Print what a recording holds, or its ground truth as predictions.
    Inspect(inspect::Args),
    /// Replay a recording: Mask R-CNN masks (or ground truth) -> pose model -> predictions -> NOCS metrics.
    Replay(replay::Args),
    /// Segment frames with a Mask R-CNN (any torchvision export): masks and overlays out.
    Segment(segment::Args),
    /// Measure pose-model latency per object and per frame, with each custom op's share.
    Bench(bench::Args),
    /// Quantize a pose or segmentation model to int8 from calibration frames (writes a profile).
    Quantize(quantize::Args),
    /// Compare a float model and its int8 profile on a recording: metrics, output errors, latency.
    Validate(validate::Args),
    /// List V4L2 capture devices: formats and frame sizes.
    Devices(devices::Args),
    /// The on-device pose service: camera or recording -> masks -> poses -> JSON Lines + HTTP.
    Serve(Box<serve::Args>),
    /// Record RGB-D frames from a camera (or a recording) into a recording.
    Record(record::Args),
}

/// The error and its causes on one line, like `{:#}`, without repeating a cause that the
/// message before it already quotes (the library's I/O errors name their source).
fn error_chain(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let part = cause.to_string();
        if text.contains(&part) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&part);
    }
    text
}

fn main() -> std::process::ExitCode {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("info")).format_timestamp(None).init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Synth(args) => synth::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Inspect(args) => inspect::run(args),
        Command::Replay(args) => replay::run(args),
        Command::Segment(args) => segment::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Quantize(args) => quantize::run(args),
        Command::Validate(args) => validate::run(args),
        Command::Devices(args) => devices::run(args),
        Command::Serve(args) => serve::run(*args),
        Command::Record(args) => record::run(args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", error_chain(&e));
            std::process::ExitCode::FAILURE
        }
    }
}
