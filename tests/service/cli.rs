//! `tricons serve` and `tricons record` as a user runs them: results in order,
//! SIGTERM/SIGINT finish cleanly with everything completed on disk, bad input.

use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;
use std::time::Duration;

use crate::common::cli::{assert_clean_failure, demo_subset, repo, signal, spawn_tricons, tricons, wait_for};
use tricons::output::FramePredictions;
use tricons::recording::open_recording;

/// Generous: the aarch64 suite runs under qemu.
const PATIENCE: Duration = Duration::from_secs(300);

fn lines(path: &Path) -> Vec<FramePredictions> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("bad line {l:?}: {e}")))
        .collect()
}

#[test]
fn serve_replays_a_recording_in_order_and_appends() {
    let dir = tempfile::tempdir().unwrap();
    let rec = demo_subset(dir.path(), 2, true);
    let out = dir.path().join("poses.jsonl");
    let stats = dir.path().join("stats.json");
    let (rec, out_s, stats_s) = (rec.to_str().unwrap(), out.to_str().unwrap(), stats.to_str().unwrap());
    let args = ["serve", "--recording", rec, "--rate", "max", "--masks", "gt", "--no-listen", "--out", out_s];
    let o = tricons(&[&args[..], &["--stats-out", stats_s]].concat());
    assert!(o.status.success(), "{}", crate::common::cli::stderr(&o));
    assert!(o.stdout.is_empty(), "--out given: nothing on stdout");
    let first = lines(&out);
    assert_eq!(first.iter().map(|f| f.frame.as_str()).collect::<Vec<_>>(), ["000000", "000002"]);
    assert!(first.iter().all(|f| !f.instances.is_empty()));
    let health: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    assert_eq!((health["frames_published"].as_u64(), health["frames_dropped"].as_u64()), (Some(2), Some(0)));
    assert_eq!(health["status"], "ended");

    // A second run appends: what the first wrote is kept. It goes through the
    // example serve config (docs/deploy/): it must parse; its camera and model
    // paths are a board's, so the flags replace them.
    let example = repo("docs/deploy/serve.example.json");
    let model = repo("models/tricons-pose.card.json");
    let o = tricons(&[&args[..], &["--config", &example, "--model", &model]].concat());
    assert!(o.status.success(), "{}", crate::common::cli::stderr(&o));
    let both = lines(&out);
    assert_eq!(both.len(), 4);
    assert_eq!(both[..2], first[..]);
}

#[test]
fn sigterm_drains_flushes_and_exits_zero() {
    let dir = tempfile::tempdir().unwrap();
    let rec = demo_subset(dir.path(), 2, true);
    let out = dir.path().join("poses.jsonl");
    let stats = dir.path().join("stats.json");
    let mut child = spawn_tricons(&[
        "serve",
        "--recording",
        rec.to_str().unwrap(),
        "--loop",
        "0",
        "--rate",
        "max",
        "--masks",
        "gt",
        "--listen",
        "127.0.0.1:0",
        "--out",
        out.to_str().unwrap(),
        "--stats-out",
        stats.to_str().unwrap(),
    ]);
    // The log names the bound port.
    let mut stderr = BufReader::new(child.stderr.take().unwrap());
    let mut addr = None;
    let mut log = String::new();
    while addr.is_none() {
        let mut line = String::new();
        if stderr.read_line(&mut line).unwrap() == 0 {
            panic!("serve ended early: {log}");
        }
        log.push_str(&line);
        addr = line.split("http://").nth(1).and_then(|s| s.split_whitespace().next()).map(str::to_string);
    }
    let addr = addr.unwrap();
    let drain = std::thread::spawn(move || {
        let mut rest = String::new();
        stderr.read_to_string(&mut rest).ok();
        rest
    });
    wait_for("a first result", PATIENCE, || !lines(&out).is_empty());
    let mut s = std::net::TcpStream::connect(&addr).unwrap();
    write!(s, "GET /health HTTP/1.1\r\n\r\n").unwrap();
    let mut health = String::new();
    s.read_to_string(&mut health).unwrap();
    assert!(health.starts_with("HTTP/1.1 200"), "{health}");
    assert!(health.contains("\"status\": \"ok\""), "{health}");

    signal(&child, "TERM");
    let status = child.wait().unwrap();
    let log = log + &drain.join().unwrap();
    assert!(status.success(), "exit {status:?}: {log}");
    assert!(!log.contains("panicked"), "{log}");
    let published = lines(&out);
    let final_stats: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    assert_eq!(final_stats["frames_published"].as_u64(), Some(published.len() as u64));
    assert_eq!(
        final_stats["frames_captured"], final_stats["frames_published"],
        "a frame read before the signal was not published"
    );
    let ids: Vec<&str> = published.iter().map(|f| f.frame.as_str()).collect();
    for (k, id) in ids.iter().enumerate() {
        assert_eq!(*id, ["000000", "000002"][k % 2], "order: {ids:?}");
    }
}

#[test]
fn record_stops_on_sigint_with_every_completed_frame_on_disk() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rec");
    let child = spawn_tricons(&[
        "record",
        "--recording",
        &repo("tests/data/synthnocs-demo"),
        "--rate",
        "recorded",
        "--speed",
        "0.5",
        "--loop",
        "0",
        "--annotations",
        "--out",
        out.to_str().unwrap(),
    ]);
    let listed = || {
        std::fs::read_to_string(out.join("manifest.json"))
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .map_or(0, |m| m["frames"].as_array().map_or(0, |f| f.len()))
    };
    wait_for("three recorded frames", PATIENCE, || listed() >= 3);
    signal(&child, "INT");
    let output = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{err}");
    let rec = open_recording(&out).unwrap();
    assert!(rec.len() >= 3);
    let demo = open_recording(Path::new(&repo("tests/data/synthnocs-demo"))).unwrap();
    for i in 0..rec.len() {
        let (got, want) = (rec.read_frame(i).unwrap(), demo.read_frame(i % 4).unwrap());
        assert_eq!(got.color, want.color, "frame {i}");
        assert_eq!(got.depth, want.depth, "frame {i}");
        assert_eq!(rec.read_instances(i).unwrap(), demo.read_instances(i % 4).unwrap());
    }
    let manifest = std::fs::read_to_string(out.join("manifest.json")).unwrap();
    assert!(manifest.contains("tricons record"), "{manifest}");
    // Nothing left half-written.
    let leftovers: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");

    // Recording again into it is refused and keeps the recording; --append adds to it.
    let again = tricons(&["record", "--recording", &repo("tests/data/synthnocs-demo"), "--out", out.to_str().unwrap()]);
    assert_clean_failure(&again, "not empty");
    assert_eq!(open_recording(&out).unwrap().len(), rec.len());
    let more = tricons(&[
        "record",
        "--recording",
        &repo("tests/data/synthnocs-demo"),
        "--rate",
        "max",
        "--frames",
        "2",
        "--append",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(more.status.success(), "{}", String::from_utf8_lossy(&more.stderr));
    let appended = open_recording(&out).unwrap();
    assert_eq!(appended.len(), rec.len() + 2);
    assert_eq!(appended.read_frame(rec.len()).unwrap().color, demo.read_frame(0).unwrap().color);
    assert_eq!(appended.read_frame(0).unwrap().color, rec.read_frame(0).unwrap().color);
}

/// Converting a recording with an unreadable frame: an error (exit non-zero) that keeps
/// the frames before it, unless --skip-bad-frames, which counts the frame and goes on.
#[test]
fn record_fails_on_a_lost_frame_unless_told_to_skip_it() {
    let dir = tempfile::tempdir().unwrap();
    let src = demo_subset(dir.path(), 4, false);
    std::fs::write(src.join("000003_color.png"), b"not a png").unwrap(); // the third frame (ids 0, 2, 3, 5)
    let run = |out: &str, extra: &[&str]| {
        let out = dir.path().join(out);
        let mut args = vec!["record", "--recording", src.to_str().unwrap(), "--rate", "max", "--out"];
        args.push(out.to_str().unwrap());
        args.extend_from_slice(extra);
        (tricons(&args), out)
    };
    let (o, out) = run("strict", &[]);
    assert_clean_failure(&o, "000003_color.png");
    assert_clean_failure(&o, "--skip-bad-frames");
    assert_eq!(open_recording(&out).unwrap().len(), 2, "the frames before the bad one are kept");
    let (o, out) = run("lenient", &["--skip-bad-frames"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stderr).contains("1 frames lost"), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(open_recording(&out).unwrap().len(), 3);
}

#[test]
fn serve_and_record_reject_bad_sources_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let o = tricons(&["serve", "--no-listen"]);
    assert_clean_failure(&o, "no source");

    let camera = dir.path().join("camera.json");
    std::fs::write(&camera, "{\"format\": \"tricons-camera\", \"version\": 1, \"color\": 3}").unwrap();
    let cam = camera.to_str().unwrap();
    let o = tricons(&[
        "serve",
        "--color",
        "/dev/video-none",
        "--depth",
        "/dev/video-none2",
        "--camera",
        cam,
        "--no-listen",
    ]);
    if cfg!(all(feature = "v4l", target_os = "linux")) {
        assert_clean_failure(&o, "camera.json");
        let example = repo("docs/deploy/camera.example.json");
        let o = tricons(&[
            "record",
            "--color",
            "/dev/video-none",
            "--depth",
            "/dev/video-none2",
            "--camera",
            &example,
            "--out",
            dir.path().join("r").to_str().unwrap(),
        ]);
        assert_clean_failure(&o, "/dev/video-none");
    } else {
        assert_clean_failure(&o, "feature `v4l`");
    }

    let config = dir.path().join("serve.json");
    std::fs::write(&config, "{\"recording\": \"x\", \"bogus\": 1}").unwrap();
    let o = tricons(&["serve", "--config", config.to_str().unwrap()]);
    assert_clean_failure(&o, "serve.json");
    assert_clean_failure(&o, "bogus");

    let o = tricons(&["serve", "--recording", dir.path().join("nothing").to_str().unwrap(), "--no-listen"]);
    assert_clean_failure(&o, "nothing");
}
