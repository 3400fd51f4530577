//! `tricons serve`: the on-device pose service.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result};
use serde::Deserialize;
use tricons::output::http::{DEFAULT_LISTEN, HttpServer, HubSink, StreamHub};
use tricons::output::sink::{JsonLinesSink, Sink};
use tricons::pipeline::{
    DEFAULT_CAPTURE_QUEUE, GroundTruthMasks, PipelineBuilder, PipelineStats, PoseStage, Segment, StatsSnapshot,
    StopHandle,
};
use tricons::pose::PoseEstimator;
use tricons::segment::Segmenter;

use crate::common::{DEFAULT_MODEL, DEFAULT_SEGMENTER, MaskSource};
use crate::source_args::{SourceArgs, stop_on_signals};

/// Default seconds between two stats lines in the log.
const DEFAULT_STATS_INTERVAL_S: f64 = 10.0;

/// Arguments of `tricons serve` (every one can also come from --config).
#[derive(clap::Args, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
#[command(after_help = "Examples:\n  \
    tricons serve --color /dev/video4 --depth /dev/video0 --camera camera.json\n  \
    tricons serve --recording tests/data/synthnocs-demo --loop 0 --out poses.jsonl\n  \
    tricons serve --config /etc/tricons/serve.json\n  \
    curl -s localhost:7878/health; curl -sN localhost:7878/stream\n\n\
    Capture -> Mask R-CNN -> TriCons-Pose -> JSON Lines, each stage a thread, bounded queues between;\n\
    a live source drops its oldest frame when inference is behind (counted in /health).\n\
    SIGINT/SIGTERM finish the frames in flight, flush the outputs and exit 0.")]
pub struct Args {
    /// JSON file with any of these options (keys as the long flags, with '_' for '-'); flags win.
    #[arg(long, value_name = "FILE")]
    #[serde(skip)]
    config: Option<PathBuf>,
    #[command(flatten)]
    #[serde(flatten)]
    source: SourceArgs,
    /// Pose model: card, graph, or int8 profile [default: the shipped model].
    #[arg(long)]
    model: Option<PathBuf>,
    /// Instance masks: Mask R-CNN, or a recording's ground truth [default: model].
    #[arg(long, value_enum)]
    masks: Option<MaskSource>,
    /// Mask R-CNN: card, graph, or int8 profile [default: the shipped one].
    #[arg(long)]
    segmenter: Option<PathBuf>,
    /// Seed of the point sampling (frame k of the stream draws from (seed, k)).
    #[arg(long)]
    seed: Option<u64>,
    /// Write results here as JSON Lines, appending ('-' = stdout; repeatable) [default: -].
    #[arg(long, value_name = "PATH")]
    #[serde(default)]
    out: Vec<PathBuf>,
    /// HTTP endpoint (/health /metrics /latest /stream) [default: 127.0.0.1:7878]; an address
    /// other than loopback (e.g. 0.0.0.0:PORT) also needs --listen-any.
    #[arg(long, value_name = "ADDR")]
    listen: Option<String>,
    /// Allow --listen on an address reachable from other machines (logged at WARN).
    #[arg(long)]
    #[serde(default)]
    listen_any: bool,
    /// No HTTP endpoint.
    #[arg(long)]
    #[serde(default)]
    no_listen: bool,
    /// Frames waiting between capture and segmentation (newest win) [default: 2].
    #[arg(long, value_name = "N")]
    queue: Option<usize>,
    /// Stop after this many frames from the source.
    #[arg(long, value_name = "N")]
    frames: Option<u64>,
    /// Seconds between stats lines in the log (0: none) [default: 10].
    #[arg(long, value_name = "SECS")]
    stats_interval: Option<f64>,
    /// Write the final stats (the /health view) to this JSON file at exit.
    #[arg(long, value_name = "FILE")]
    stats_out: Option<PathBuf>,
    /// Worker threads in all: with Mask R-CNN masks --segmenter-threads of them segment
    /// and the rest (at least 1) run a frame's objects, the two stages side by side on
    /// different frames; with ground-truth masks all run objects [default: the cores available].
    #[arg(long, value_name = "N")]
    threads: Option<usize>,
    /// Of --threads, those of the Mask R-CNN's matrix products [default: 1].
    #[arg(long, value_name = "N")]
    segmenter_threads: Option<usize>,
}

impl Args {
    /// The flags, completed from --config.
    fn resolve(self) -> Result<Args> {
        let Some(path) = &self.config else {
            return Ok(self);
        };
        let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let file: Args = tricons::error::from_json_str(path, &text).context("not a serve config")?;
        Ok(Args {
            config: self.config,
            source: self.source.or(file.source),
            model: self.model.or(file.model),
            masks: self.masks.or(file.masks),
            segmenter: self.segmenter.or(file.segmenter),
            seed: self.seed.or(file.seed),
            out: if self.out.is_empty() { file.out } else { self.out },
            listen: self.listen.or(file.listen),
            listen_any: self.listen_any || file.listen_any,
            no_listen: self.no_listen || file.no_listen,
            queue: self.queue.or(file.queue),
            frames: self.frames.or(file.frames),
            stats_interval: self.stats_interval.or(file.stats_interval),
            stats_out: self.stats_out.or(file.stats_out),
            threads: self.threads.or(file.threads),
            segmenter_threads: self.segmenter_threads.or(file.segmenter_threads),
        })
    }
}

pub fn run(args: Args) -> Result<()> {
    let args = args.resolve()?;
    let masks = args.masks.unwrap_or(MaskSource::Model);
    let source = args.source.open(masks == MaskSource::Gt)?;
    let model = args.model.clone().unwrap_or_else(|| PathBuf::from(DEFAULT_MODEL));
    let segmenter_threads = args.segmenter_threads.unwrap_or(crate::common::DEFAULT_SEGMENTER_THREADS);
    let (segment_threads, pose_threads) = split_threads(crate::common::threads(args.threads), segmenter_threads, masks);
    let estimator = PoseEstimator::load(&model)
        .and_then(|e| e.with_threads(pose_threads))
        .with_context(|| "loading the pose model (--model)")?;
    let segment: Box<dyn Segment> = match masks {
        MaskSource::Gt => Box::new(GroundTruthMasks),
        MaskSource::Model => {
            let path = args.segmenter.clone().unwrap_or_else(|| PathBuf::from(DEFAULT_SEGMENTER));
            Box::new(
                Segmenter::load(&path)
                    .and_then(|s| s.with_threads(segment_threads))
                    .with_context(|| "loading the segmenter (--segmenter)")?,
            )
        }
    };
    log::info!("threads: segment {segment_threads}, pose {pose_threads}");
    let stats = Arc::new(PipelineStats::new());
    let stop = StopHandle::default();
    stop_on_signals(stop.clone())?;

    let mut sinks: Vec<Box<dyn Sink>> = Vec::new();
    let outs = if args.out.is_empty() { vec![PathBuf::from("-")] } else { args.out.clone() };
    for out in &outs {
        sinks.push(if out.as_os_str() == "-" {
            Box::new(JsonLinesSink::stdout())
        } else {
            Box::new(JsonLinesSink::append(out).with_context(|| "opening an output (--out)")?)
        });
    }
    let server = if args.no_listen {
        None
    } else {
        let hub = Arc::new(StreamHub::new(Arc::clone(&stats)));
        let addr = args.listen.as_deref().unwrap_or(DEFAULT_LISTEN);
        let server = HttpServer::start(addr, args.listen_any, Arc::clone(&stats), Arc::clone(&hub))
            .with_context(|| "starting the HTTP endpoint (--listen, --listen-any; --no-listen for none)")?;
        log::info!("http: listening on http://{} (/health /metrics /latest /stream)", server.local_addr());
        sinks.push(Box::new(HubSink(hub)));
        Some(server)
    };

    let mut builder =
        PipelineBuilder::new(source, segment, Box::new(PoseStage::new(estimator, args.seed.unwrap_or(0))))
            .capture_queue(args.queue.unwrap_or(DEFAULT_CAPTURE_QUEUE))
            .max_frames(args.frames)
            .stats(Arc::clone(&stats))
            .stop_handle(stop.clone());
    for sink in sinks {
        builder = builder.sink(sink);
    }
    let interval = args.stats_interval.unwrap_or(DEFAULT_STATS_INTERVAL_S);
    let reporter = (interval > 0.0).then(|| {
        let (stats, stop) = (Arc::clone(&stats), stop.clone());
        let done = StopHandle::default();
        let done2 = done.clone();
        let handle = std::thread::spawn(move || {
            let mut next = std::time::Instant::now() + Duration::from_secs_f64(interval);
            while !stop.is_stopped() && !done2.is_stopped() {
                std::thread::sleep(Duration::from_millis(50));
                if std::time::Instant::now() >= next {
                    log::info!("{}", stats_line(&stats.snapshot()));
                    next += Duration::from_secs_f64(interval);
                }
            }
        });
        (done, handle)
    });
    let result = builder.build().run();
    if let Some((done, handle)) = reporter {
        done.stop();
        let _ = handle.join();
    }
    if let Some(server) = server {
        server.shutdown();
    }
    let summary = result?;
    log::info!("done: {}", stats_line(&summary));
    if let Some(path) = &args.stats_out {
        let json = tricons::output::http::health_json(&summary);
        tricons::atomic::write_atomic(path, json.as_bytes())?;
    }
    Ok(())
}

/// (segment, pose) worker threads out of `total`, `segmenter` of them segmenting: the two
/// stages run at the same time on different frames, so each gets its own share.
fn split_threads(total: usize, segmenter: usize, masks: MaskSource) -> (usize, usize) {
    match masks {
        MaskSource::Gt => (0, total.max(1)),
        MaskSource::Model => {
            let segment = segmenter.clamp(1, total.max(1));
            (segment, total.saturating_sub(segment).max(1))
        }
    }
}

/// One log line of counters.
fn stats_line(s: &StatsSnapshot) -> String {
    let lat = |name: &str| s.latency.iter().find(|(n, _)| n == name).map(|(_, l)| l.p50_ms).unwrap_or(0.0);
    format!(
        "{} captured, {} published, {} dropped, {} failed, {:.2} fps (recent {:.2}); p50 ms: segment {:.1}, pose {:.1}, end-to-end {:.1}; source errors {}, reopens {}; rss {:.1} MiB (peak {:.1})",
        s.frames_captured,
        s.frames_published,
        s.frames_dropped,
        s.frames_failed,
        s.fps,
        s.fps_recent,
        lat("segment"),
        lat("pose"),
        lat("end_to_end"),
        s.source_errors,
        s.source_reopens,
        s.rss_kib as f64 / 1024.0,
        s.peak_rss_kib as f64 / 1024.0
    )
}
