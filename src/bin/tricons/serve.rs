//! `tricons serve`: the on-device pose service.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result};
use serde::Deserialize;
use tricons::output::http::{DEFAULT_LISTEN, HttpServer, HubSink, StreamHub};
use tricons::output::sink::{JsonLinesSink, Sink};
use tricons::pipeline::{
    DEFAULT_CAPTURE_QUEUE, GroundTruthMasks, PipelineBuilder, PipelineStats, PoseStage, PublishedMasks, Segment,
    StatsSnapshot, StopHandle,
};
use tricons::pose::PoseEstimator;
use tricons::segment::Segmenter;

use crate::common::{DEFAULT_MODEL, DEFAULT_SEGMENTER, MaskSource};
use crate::source_args::{BagTopicArgs, SourceArgs, stop_on_signals};

/// Default seconds between two stats lines in the log.
const DEFAULT_STATS_INTERVAL_S: f64 = 10.0;

/// Arguments of `tricons serve` (every one can also come from --config).
#[derive(clap::Args, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
#[command(after_help = "Examples:\n  \
    tricons serve --color /dev/video4 --depth /dev/video0 --camera camera.json\n  \
    tricons serve --recording tests/data/synthnocs-demo --loop 0 --out poses.jsonl\n  \
    tricons serve --config /etc/tricons/serve.json\n  \
    tricons serve --recording bag.mcap --ros2 --mcap poses.mcap   # ROS 2 bag in, DDS + MCAP out\n  \
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
    #[command(flatten)]
    #[serde(flatten)]
    bag: BagTopicArgs,
    /// Pose model: card, graph, or int8 profile [default: the shipped model].
    #[arg(long)]
    model: Option<PathBuf>,
    /// Instance masks: `model` (the Mask R-CNN), `gt` (a recording's ground truth) or
    /// `results:DIR` (published Mask R-CNN result pickles of the recording's frames) [default: model].
    #[arg(long, value_parser = clap::value_parser!(MaskSource), value_name = "model|gt|results:DIR")]
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
    /// Frames the Mask R-CNN segments at once, each on its own thread (with
    /// --segmenter-threads for its products), results kept in frame order: the segment
    /// stage then also uses the time the pose stage leaves a core idle [default: 2 when
    /// --threads is 2 or more, else 1].
    #[arg(long, value_name = "N")]
    segment_workers: Option<usize>,
    /// Also write the results as a ROS 2 bag (detections, markers, overlay images), completed at exit.
    #[cfg(feature = "ros2")]
    #[arg(long, value_name = "OUT.mcap")]
    mcap: Option<PathBuf>,
    #[cfg(feature = "ros2")]
    #[command(flatten)]
    #[serde(flatten)]
    ros2: Ros2Args,
}

/// ROS 2 publishing flags of `tricons serve` (feature `ros2`).
#[cfg(feature = "ros2")]
#[derive(clap::Args, Debug, Default, Deserialize)]
pub struct Ros2Args {
    /// Publish vision_msgs/Detection3DArray and visualization_msgs/MarkerArray over DDS
    /// (loopback only unless --ros2-interface).
    #[arg(long)]
    #[serde(default)]
    ros2: bool,
    /// Topic of the detections [default: /tricons/detections].
    #[arg(long, value_name = "TOPIC")]
    ros2_topic: Option<String>,
    /// Topic of the RViz markers ('none': no markers) [default: /tricons/markers].
    #[arg(long, value_name = "TOPIC")]
    ros2_markers_topic: Option<String>,
    /// DDS domain id [default: $ROS_DOMAIN_ID, else 0].
    #[arg(long, value_name = "ID")]
    ros2_domain: Option<u16>,
    /// Also use this network interface (a name such as eth0, or its address) for discovery
    /// and data: reachable from that network (logged at WARN) [default: loopback only].
    #[arg(long, value_name = "IFACE")]
    ros2_interface: Option<String>,
    /// QoS reliability [default: reliable].
    #[arg(long, value_enum)]
    ros2_reliability: Option<tricons::output::ros2_sink::Ros2Reliability>,
    /// QoS durability; transient_local keeps the last --ros2-depth samples for late subscribers [default: volatile].
    #[arg(long, value_enum)]
    ros2_durability: Option<tricons::output::ros2_sink::Ros2Durability>,
    /// QoS history depth (keep last N) [default: 10].
    #[arg(long, value_name = "N")]
    ros2_depth: Option<usize>,
}

#[cfg(feature = "ros2")]
impl Ros2Args {
    fn or(self, other: Ros2Args) -> Ros2Args {
        Ros2Args {
            ros2: self.ros2 || other.ros2,
            ros2_topic: self.ros2_topic.or(other.ros2_topic),
            ros2_markers_topic: self.ros2_markers_topic.or(other.ros2_markers_topic),
            ros2_domain: self.ros2_domain.or(other.ros2_domain),
            ros2_interface: self.ros2_interface.or(other.ros2_interface),
            ros2_reliability: self.ros2_reliability.or(other.ros2_reliability),
            ros2_durability: self.ros2_durability.or(other.ros2_durability),
            ros2_depth: self.ros2_depth.or(other.ros2_depth),
        }
    }

    /// The publisher's settings, poses in `frame_id`.
    fn config(&self, frame_id: &str) -> Result<tricons::output::ros2_sink::Ros2Config> {
        use tricons::output::ros2_sink::{Ros2Config, Ros2Qos};
        let d = Ros2Config::default();
        let domain_id = match self.ros2_domain {
            Some(id) => id,
            None => match std::env::var("ROS_DOMAIN_ID") {
                Ok(v) if !v.trim().is_empty() => {
                    v.trim().parse().with_context(|| format!("ROS_DOMAIN_ID={v:?} is not a domain id"))?
                }
                _ => 0,
            },
        };
        let q = Ros2Qos::default();
        Ok(Ros2Config {
            domain_id,
            detections_topic: self.ros2_topic.clone().unwrap_or(d.detections_topic),
            markers_topic: match self.ros2_markers_topic.as_deref() {
                Some("none") => None,
                Some(t) => Some(t.to_string()),
                None => d.markers_topic,
            },
            interface: self.ros2_interface.clone(),
            qos: Ros2Qos {
                reliability: self.ros2_reliability.unwrap_or(q.reliability),
                durability: self.ros2_durability.unwrap_or(q.durability),
                depth: self.ros2_depth.unwrap_or(q.depth),
            },
            frame_id: frame_id.to_string(),
        })
    }
}

impl Args {
    /// The flags, completed from --config.
    fn resolve(self) -> Result<Args> {
        let Some(path) = &self.config else {
            return Ok(self);
        };
        let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let file: Args = tricons::error::from_json_str(path, &text).context("not a serve config")?;
        if let (None, Some(addr)) = (&self.listen, &file.listen) {
            tricons::output::http::check_listen_address(addr, self.listen_any || file.listen_any)
                .with_context(|| format!("{}: field listen", path.display()))?;
        }
        Ok(Args {
            config: self.config,
            source: self.source.or(file.source),
            bag: self.bag.or(file.bag),
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
            segment_workers: self.segment_workers.or(file.segment_workers),
            #[cfg(feature = "ros2")]
            mcap: self.mcap.or(file.mcap),
            #[cfg(feature = "ros2")]
            ros2: self.ros2.or(file.ros2),
        })
    }
}

pub fn run(args: Args) -> Result<()> {
    let args = args.resolve()?;
    let masks = args.masks.clone().unwrap_or(MaskSource::Model);
    let source = args.source.open(masks == MaskSource::Gt, &args.bag)?;
    let model = args.model.clone().unwrap_or_else(|| PathBuf::from(DEFAULT_MODEL));
    let segmenter_threads = args.segmenter_threads.unwrap_or(crate::common::DEFAULT_SEGMENTER_THREADS);
    let total_threads = crate::common::threads(args.threads);
    let (segment_threads, pose_threads) = split_threads(total_threads, segmenter_threads, &masks);
    let segment_workers = args.segment_workers.unwrap_or(if total_threads >= 2 { 2 } else { 1 });
    if segment_workers == 0 {
        anyhow::bail!("--segment-workers must be at least 1");
    }
    let estimator = PoseEstimator::load(&model)
        .and_then(|e| e.with_threads(pose_threads))
        .with_context(|| "loading the pose model (--model)")?;
    let segment: Box<dyn Segment> = match &masks {
        MaskSource::Gt => Box::new(GroundTruthMasks),
        MaskSource::Results(dir) => {
            let Some(recording) = &args.source.recording else {
                anyhow::bail!(
                    "--masks results:DIR goes with --recording (the result files are named by scene and frame)"
                );
            };
            let scene = recording.file_name().and_then(|n| n.to_str()).unwrap_or_default();
            let published = tricons::segment::published::PublishedDetections::open(dir)
                .with_context(|| "opening --masks results:DIR")?;
            Box::new(PublishedMasks::new(published, scene))
        }
        MaskSource::Model => {
            let path = args.segmenter.clone().unwrap_or_else(|| PathBuf::from(DEFAULT_SEGMENTER));
            Box::new(std::sync::Arc::new(
                Segmenter::load(&path)
                    .and_then(|s| s.with_threads(segment_threads))
                    .with_context(|| "loading the segmenter (--segmenter)")?,
            ))
        }
    };
    let segment_workers = if masks == MaskSource::Model { segment_workers } else { 1 };
    log::info!("threads: segment {segment_workers} x {segment_threads}, pose {pose_threads}");
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
    #[cfg(feature = "ros2")]
    {
        let frame_id = source.camera().frame_id;
        if let Some(path) = &args.mcap {
            let sink =
                tricons::output::mcap_sink::McapSink::create(path, &frame_id).with_context(|| "creating --mcap")?;
            sinks.push(Box::new(sink));
        }
        if args.ros2.ros2 {
            let config = args.ros2.config(&frame_id)?;
            let sink = tricons::output::ros2_sink::Ros2Sink::start(config)
                .with_context(|| "starting ROS 2 publishing (--ros2, --ros2-interface, --ros2-domain)")?;
            log::info!("ros2: publishing {}", sink.describe());
            sinks.push(Box::new(sink));
        }
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
            .segment_workers(segment_workers)
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
fn split_threads(total: usize, segmenter: usize, masks: &MaskSource) -> (usize, usize) {
    match masks {
        MaskSource::Gt | MaskSource::Results(_) => (0, total.max(1)),
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

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(json: &str) -> std::result::Result<Args, String> {
        tricons::error::from_json_str(std::path::Path::new("serve.json"), json)
            .map_err(|e: tricons::Error| e.to_string())
    }

    /// Keys of every flattened group (source, bag topics, ROS 2) are read from one config
    /// object, and a key of none of them is still refused by name.
    #[test]
    fn config_keys_of_every_group_parse_and_unknown_keys_are_refused() {
        let args =
            parse(r#"{"recording": "bag.mcap", "color_topic": "/c", "queue": 3, "masks": "results:pkl"}"#).unwrap();
        assert_eq!(args.masks, Some(MaskSource::Results("pkl".into())));
        assert_eq!(args.source.recording.as_deref(), Some(std::path::Path::new("bag.mcap")));
        assert_eq!((args.bag.color_topic.as_deref(), args.queue), (Some("/c"), Some(3)));
        #[cfg(feature = "ros2")]
        {
            let args = parse(r#"{"ros2": true, "ros2_durability": "transient_local", "mcap": "o.mcap"}"#).unwrap();
            assert!(args.ros2.ros2);
            assert_eq!(args.ros2.ros2_durability, Some(tricons::output::ros2_sink::Ros2Durability::TransientLocal));
        }
        for bad in [r#"{"bogus": 1}"#, r#"{"recording": "x", "colour_topic": "/c"}"#] {
            let err = parse(bad).unwrap_err();
            assert!(err.contains("serve.json") && err.contains("unknown field"), "{err}");
        }
        let err = parse(r#"{"masks": "results:"}"#).unwrap_err();
        assert!(err.contains("masks") && err.contains("results:DIR"), "{err}");
    }
}
