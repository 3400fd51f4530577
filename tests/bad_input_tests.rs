//! The bad-input suite (issue 17): hostile or broken files given to the `tricons` binary as a
//! user would run it. Every case asserts a non-zero exit, no panic or abort, an error that
//! names the file or field, and that nothing already written is lost (files that existed
//! before the run keep their bytes, outputs of a failed run are not left half written).
//! The service's own handling of bad frames (skipped and counted, not fatal) is the last test.

mod common;

use common::cli::{demo_subset, repo, stderr, tricons};
use std::fs;
use std::path::{Path, PathBuf};

/// A header declaring `w` x `h` 16-bit RGBA pixels and no pixel data (a PNG size bomb).
fn size_bomb(w: u32, h: u32) -> Vec<u8> {
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, w, h);
    encoder.set_color(png::ColorType::Rgba);
    encoder.set_depth(png::BitDepth::Sixteen);
    let mut writer = encoder.write_header().unwrap();
    writer.write_chunk(png::chunk::IDAT, &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01]).unwrap();
    drop(writer);
    out
}

/// An 8-bit greyscale PNG of the given size (a depth image of the wrong bit depth).
fn gray8(w: u32, h: u32) -> Vec<u8> {
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, w, h);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().unwrap();
    writer.write_image_data(&vec![7u8; (w * h) as usize]).unwrap();
    drop(writer);
    out
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Edits a JSON file in place.
fn edit_json(path: &Path, f: impl FnOnce(&mut serde_json::Value)) {
    let mut v: serde_json::Value = serde_json::from_str(&fs::read_to_string(path).unwrap()).unwrap();
    f(&mut v);
    fs::write(path, serde_json::to_string_pretty(&v).unwrap()).unwrap();
}

/// The cases run so far and the ones that did not behave.
struct Suite {
    root: tempfile::TempDir,
    cases: usize,
    failures: Vec<String>,
}

impl Suite {
    fn new() -> Suite {
        Suite { root: tempfile::tempdir().unwrap(), cases: 0, failures: Vec::new() }
    }

    /// A fresh directory for one case.
    fn dir(&self, name: &str) -> PathBuf {
        let d = self.root.path().join(name);
        fs::create_dir_all(&d).unwrap();
        d
    }

    /// A fresh copy of the first two demo frames with their annotations, in `name/rec`.
    fn recording(&self, name: &str) -> PathBuf {
        demo_subset(&self.dir(name), 2, true)
    }

    /// A predictions file with two complete lines, as a run before this one left it.
    fn previous_output(&self, name: &str) -> PathBuf {
        let p = self.dir(name).join("previous.jsonl");
        fs::write(&p, "{\"frame\":\"000000\",\"instances\":[]}\n{\"frame\":\"000002\",\"instances\":[]}\n").unwrap();
        p
    }

    /// Runs `tricons args`; checks a clean failure naming every `needle`, that every file
    /// of `kept` has the bytes it had before, and that no path of `absent` exists after.
    fn case(&mut self, name: &str, args: &[&str], needles: &[&str], kept: &[&Path], absent: &[&Path]) {
        self.cases += 1;
        let before: Vec<(PathBuf, Option<Vec<u8>>)> =
            kept.iter().map(|p| (p.to_path_buf(), fs::read(p).ok())).collect();
        let o = tricons(args);
        let err = stderr(&o);
        let mut problems = Vec::new();
        if o.status.success() {
            problems.push("exit 0".to_string());
        }
        match o.status.code() {
            None => problems.push(format!("killed by a signal ({:?})", o.status)),
            Some(c) if c >= 100 => problems.push(format!("exit code {c}")),
            _ => {}
        }
        if err.contains("panicked") || err.contains("memory allocation") {
            problems.push("panic or allocation failure".to_string());
        }
        for n in needles {
            if !err.contains(n) {
                problems.push(format!("error does not name {n:?}"));
            }
        }
        for (path, bytes) in &before {
            if fs::read(path).ok() != *bytes {
                problems.push(format!("{} changed", path.display()));
            }
        }
        for path in absent {
            if path.exists() {
                problems.push(format!("{} was written", path.display()));
            }
        }
        if !problems.is_empty() {
            self.failures.push(format!(
                "case {} ({name}): {}\n  stderr: {}",
                self.cases,
                problems.join("; "),
                err.trim()
            ));
        }
    }
}

#[test]
fn every_bad_input_is_a_clean_error_that_loses_nothing() {
    let mut t = Suite::new();
    let model = repo("models/tricons-pose.card.json");

    // --- recordings: the manifest -------------------------------------------------------
    let missing = t.dir("missing").join("no-such-recording");
    t.case("missing recording", &["inspect", s(&missing)], &["no-such-recording"], &[], &[]);

    let rec = t.recording("manifest-not-json");
    fs::write(rec.join("manifest.json"), "{\"format\": \"tricons-recording\", ").unwrap();
    t.case("manifest cut short", &["inspect", s(&rec)], &["manifest.json"], &[], &[]);

    let rec = t.recording("manifest-empty");
    fs::write(rec.join("manifest.json"), "").unwrap();
    t.case("empty manifest", &["inspect", s(&rec)], &["manifest.json"], &[], &[]);

    let rec = t.recording("version-string");
    edit_json(&rec.join("manifest.json"), |v| v["version"] = "1".into());
    t.case("version as a string", &["inspect", s(&rec)], &["manifest.json", "version"], &[], &[]);

    let rec = t.recording("version-2");
    edit_json(&rec.join("manifest.json"), |v| v["version"] = 2.into());
    t.case("unknown manifest version", &["inspect", s(&rec)], &["manifest.json", "version 2"], &[], &[]);

    let rec = t.recording("negative-height");
    edit_json(&rec.join("manifest.json"), |v| v["intrinsics"]["height"] = (-480).into());
    t.case("negative height", &["inspect", s(&rec)], &["manifest.json", "height"], &[], &[]);

    let rec = t.recording("zero-width");
    edit_json(&rec.join("manifest.json"), |v| v["intrinsics"]["width"] = 0.into());
    t.case("zero width", &["inspect", s(&rec)], &["manifest.json", "width"], &[], &[]);

    let rec = t.recording("huge-size");
    edit_json(&rec.join("manifest.json"), |v| {
        v["intrinsics"]["width"] = 4_000_000.into();
        v["intrinsics"]["height"] = 4_000_000.into();
    });
    t.case("frame size beyond the cap", &["inspect", s(&rec)], &["manifest.json", "width"], &[], &[]);

    let rec = t.recording("no-frames-field");
    edit_json(&rec.join("manifest.json"), |v| {
        v.as_object_mut().unwrap().remove("frames");
    });
    t.case("manifest without frames", &["inspect", s(&rec)], &["manifest.json", "frames"], &[], &[]);

    let rec = t.recording("absolute-path");
    edit_json(&rec.join("manifest.json"), |v| v["frames"][0]["color"] = "/etc/passwd".into());
    t.case("absolute image path", &["inspect", s(&rec)], &["manifest.json", "/etc/passwd"], &[], &[]);

    let rec = t.recording("dotdot-path");
    edit_json(&rec.join("manifest.json"), |v| v["frames"][1]["depth"] = "../rec/000000_depth.png".into());
    t.case("image path with ..", &["inspect", s(&rec)], &["manifest.json", "../rec/000000_depth.png"], &[], &[]);

    let rec = t.recording("duplicate-id");
    edit_json(&rec.join("manifest.json"), |v| v["frames"][1]["id"] = "000000".into());
    t.case("duplicate frame id", &["inspect", s(&rec)], &["manifest.json", "000000"], &[], &[]);

    let rec = t.recording("depth-scale");
    edit_json(&rec.join("manifest.json"), |v| v["depth_scale_m"] = (-0.001).into());
    t.case("negative depth scale", &["inspect", s(&rec)], &["manifest.json", "depth_scale_m"], &[], &[]);

    // --- recordings: the images ---------------------------------------------------------
    // A replay reads every frame: an unreadable second frame fails it, and the predictions
    // file a previous run left keeps its bytes (written to a temporary file, renamed at the end).
    let rec = t.recording("missing-color");
    fs::remove_file(rec.join("000002_color.png")).unwrap();
    let prev = t.previous_output("missing-color-out");
    t.case(
        "missing colour image of the second frame",
        &["replay", "--recording", s(&rec), "--model", &model, "--masks", "gt", "--out", s(&prev), "--threads", "1"],
        &["000002_color.png"],
        &[&prev],
        &[],
    );

    let rec = t.recording("truncated-color");
    let png = fs::read(rec.join("000000_color.png")).unwrap();
    fs::write(rec.join("000000_color.png"), &png[..png.len() / 3]).unwrap();
    t.case("truncated colour PNG", &["inspect", s(&rec)], &["000000_color.png"], &[], &[]);

    let rec = t.recording("not-png");
    fs::write(rec.join("000000_color.png"), b"GIF89a not a png").unwrap();
    t.case("colour file not a PNG", &["inspect", s(&rec)], &["000000_color.png"], &[], &[]);

    let rec = t.recording("color-bomb");
    fs::write(rec.join("000000_color.png"), size_bomb(60_000, 60_000)).unwrap();
    t.case("colour PNG size bomb", &["inspect", s(&rec)], &["000000_color.png", "60000x60000"], &[], &[]);

    let rec = t.recording("depth-bomb");
    fs::write(rec.join("000002_depth.png"), size_bomb(60_000, 60_000)).unwrap();
    let prev = t.previous_output("depth-bomb-out");
    t.case(
        "depth PNG size bomb in the second frame",
        &["replay", "--recording", s(&rec), "--model", &model, "--masks", "gt", "--out", s(&prev), "--threads", "1"],
        &["000002_depth.png", "60000x60000"],
        &[&prev],
        &[],
    );

    // A manifest declaring the bomb's own size: the cap on pixels holds whatever is expected.
    let rec = t.recording("consistent-bomb");
    edit_json(&rec.join("manifest.json"), |v| {
        v["intrinsics"]["width"] = 60_000.into();
        v["intrinsics"]["height"] = 60_000.into();
    });
    fs::write(rec.join("000000_color.png"), size_bomb(60_000, 60_000)).unwrap();
    t.case("manifest and PNG both 60000x60000", &["inspect", s(&rec)], &["manifest.json", "60000x60000"], &[], &[]);

    let rec = t.recording("color-size");
    fs::write(rec.join("000000_color.png"), size_bomb(641, 480)).unwrap();
    t.case("colour size unlike the manifest", &["inspect", s(&rec)], &["000000_color.png", "641x480"], &[], &[]);

    let rec = t.recording("depth-8bit");
    fs::write(rec.join("000000_depth.png"), gray8(640, 480)).unwrap();
    t.case("8-bit depth", &["inspect", s(&rec)], &["000000_depth.png"], &[], &[]);

    // --- recordings: the annotations ----------------------------------------------------
    let rec = t.recording("gt-not-json");
    fs::write(rec.join("000000_gt.json"), "{\"instances\": [").unwrap();
    t.case("annotations cut short", &["inspect", s(&rec), "--predictions"], &["000000_gt.json"], &[], &[]);

    let rec = t.recording("gt-passwd");
    edit_json(&rec.join("000000_gt.json"), |v| v["mask"] = "/etc/passwd".into());
    t.case(
        "annotation mask /etc/passwd",
        &["inspect", s(&rec), "--predictions"],
        &["000000_gt.json", "mask"],
        &[],
        &[],
    );

    let rec = t.recording("gt-dotdot");
    edit_json(&rec.join("000000_gt.json"), |v| v["mask"] = "../../000000_mask.png".into());
    t.case("annotation mask with ..", &["inspect", s(&rec), "--predictions"], &["000000_gt.json", "mask"], &[], &[]);

    let rec = t.recording("gt-class");
    edit_json(&rec.join("000000_gt.json"), |v| v["instances"][0]["class"] = "teapot".into());
    t.case("unknown class", &["inspect", s(&rec), "--predictions"], &["000000_gt.json", "teapot"], &[], &[]);

    let rec = t.recording("gt-rotation");
    edit_json(&rec.join("000000_gt.json"), |v| v["instances"][0]["R"] = serde_json::json!([[1, 0], [0, 1]]));
    t.case("rotation not 3x3", &["inspect", s(&rec), "--predictions"], &["000000_gt.json", "R"], &[], &[]);

    let rec = t.recording("mask-bomb");
    fs::write(rec.join("000000_mask.png"), size_bomb(60_000, 60_000)).unwrap();
    let prev = t.previous_output("mask-bomb");
    t.case(
        "instance mask size bomb (replay --masks gt)",
        &["replay", "--recording", s(&rec), "--model", &model, "--masks", "gt", "--out", s(&prev), "--threads", "1"],
        &["000000_mask.png", "60000x60000"],
        &[&prev],
        &[],
    );

    // --- predictions and eval -----------------------------------------------------------
    let rec = t.recording("eval");
    let pred = rec.parent().unwrap().join("pred.jsonl");
    fs::write(&pred, "{\"frame\":\"000000\",\"instances\":[]}\n{\"frame\": 12\n").unwrap();
    t.case(
        "malformed predictions line",
        &["eval", "--gt", s(&rec), "--pred", s(&pred)],
        &["pred.jsonl line 2"],
        &[],
        &[],
    );

    fs::write(&pred, "{\"frame\":\"999999\",\"instances\":[]}\n").unwrap();
    t.case("prediction for an unknown frame", &["eval", "--gt", s(&rec), "--pred", s(&pred)], &["999999"], &[], &[]);

    fs::write(&pred, "{\"frame\":\"000000\",\"instances\":[{\"class\":\"bottle\",\"score\":0.9,\"R\":[[1,0,0],[0,1,0]],\"t\":[0,0,1],\"s\":[0.1,0.1,0.1]}]}\n").unwrap();
    t.case(
        "predicted rotation not 3x3",
        &["eval", "--gt", s(&rec), "--pred", s(&pred)],
        &["pred.jsonl line 1"],
        &[],
        &[],
    );

    fs::write(&pred, "{\"frame\":\"000000\",\"instances\":[{\"class\":\"bottle\",\"score\":\"high\",\"R\":[[1,0,0],[0,1,0],[0,0,1]],\"t\":[0,0,1],\"s\":[0.1,0.1,0.1]}]}\n").unwrap();
    t.case(
        "score as a string",
        &["eval", "--gt", s(&rec), "--pred", s(&pred)],
        &["pred.jsonl line 1", "score"],
        &[],
        &[],
    );

    let json_out = rec.parent().unwrap().join("report.json");
    fs::write(&json_out, "{\"kept\": true}").unwrap();
    fs::write(&pred, "\u{0}\u{1}binary").unwrap();
    t.case(
        "binary predictions, report not overwritten",
        &["eval", "--gt", s(&rec), "--pred", s(&pred), "--json", s(&json_out)],
        &["pred.jsonl"],
        &[&json_out],
        &[],
    );

    let missing_pred = rec.parent().unwrap().join("none.jsonl");
    t.case(
        "missing predictions file",
        &["eval", "--gt", s(&rec), "--pred", s(&missing_pred)],
        &["none.jsonl"],
        &[],
        &[],
    );

    // --- pose model cards, graphs and int8 profiles --------------------------------------
    let d = t.dir("cards");
    let prev = t.previous_output("cards-out");
    let demo = repo("tests/data/synthnocs-demo");
    let replay_with = |card: &Path| -> Vec<String> {
        ["replay", "--recording", &demo, "--masks", "gt", "--threads", "1", "--model", s(card), "--out", s(&prev)]
            .iter()
            .map(|a| a.to_string())
            .collect()
    };
    let run = |t: &mut Suite, name: &str, card: &Path, needles: &[&str]| {
        let args = replay_with(card);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        t.case(name, &args, needles, &[&prev], &[]);
    };

    run(&mut t, "missing model card", &d.join("none.card.json"), &["none.card.json"]);

    let card = d.join("garbage.card.json");
    fs::write(&card, "not json").unwrap();
    run(&mut t, "model card not JSON", &card, &["garbage.card.json"]);

    let shipped_card = fs::read_to_string(repo("models/tricons-pose.card.json")).unwrap();
    let card_copy = |t: &Suite, name: &str, f: &dyn Fn(&mut serde_json::Value)| -> PathBuf {
        let d = t.dir(name);
        fs::copy(repo("models/tricons-pose.onnx"), d.join("tricons-pose.onnx")).unwrap();
        let p = d.join("tricons-pose.card.json");
        let mut v: serde_json::Value = serde_json::from_str(&shipped_card).unwrap();
        f(&mut v);
        fs::write(&p, serde_json::to_string_pretty(&v).unwrap()).unwrap();
        p
    };
    let card = card_copy(&t, "card-version", &|v| v["version"] = 9.into());
    run(&mut t, "model card version 9", &card, &["tricons-pose.card.json", "version"]);
    let card = card_copy(&t, "card-sha", &|v| v["onnx"]["sha256"] = "00".repeat(32).into());
    run(&mut t, "graph checksum unlike the card", &card, &["sha256"]);
    let card = card_copy(&t, "card-file", &|v| v["onnx"]["file"] = "elsewhere.onnx".into());
    run(&mut t, "card naming a missing graph", &card, &["elsewhere.onnx"]);
    let card = card_copy(&t, "card-keypoints", &|v| v["n_keypoints"] = (-3).into());
    run(&mut t, "negative keypoint count", &card, &["tricons-pose.card.json", "n_keypoints"]);
    let card = card_copy(&t, "card-rgb-scale", &|v| v["preprocessing"]["rgb_scale"] = "one".into());
    run(&mut t, "preprocessing field of the wrong type", &card, &["tricons-pose.card.json", "preprocessing.rgb_scale"]);
    let card = card_copy(&t, "card-class", &|v| v["rotation_from_keypoints"] = serde_json::json!(["teapot"]));
    run(&mut t, "unknown class in rotation_from_keypoints", &card, &["rotation_from_keypoints", "teapot"]);

    let card = card_copy(&t, "graph-garbage", &|_| {});
    fs::write(card.with_file_name("tricons-pose.onnx"), b"\x08\x07garbage protobuf").unwrap();
    run(&mut t, "graph not ONNX", &card.with_file_name("tricons-pose.onnx"), &["tricons-pose.onnx"]);

    let card = card_copy(&t, "graph-truncated", &|_| {});
    let graph = card.with_file_name("tricons-pose.onnx");
    let bytes = fs::read(&graph).unwrap();
    fs::write(&graph, &bytes[..bytes.len() / 2]).unwrap();
    run(&mut t, "graph cut in half", &graph, &["tricons-pose.onnx"]);

    let profile = d.join("broken.int8.json");
    fs::write(&profile, "{\"format\": \"tricons-quant-profile\", \"version\": 1, \"kind\": \"pose\"}").unwrap();
    run(&mut t, "int8 profile without its fields", &profile, &["broken.int8.json"]);

    let profile = d.join("segmenter-profile.int8.json");
    fs::copy(repo("models/maskrcnn-light.int8.json"), &profile).unwrap();
    fs::copy(repo("models/maskrcnn-light.card.json"), d.join("maskrcnn-light.card.json")).unwrap();
    run(&mut t, "segmenter profile given as the pose model", &profile, &["kind"]);

    // --- segmenter cards, graphs and images ----------------------------------------------
    let seg = t.dir("segmenter");
    let seg_card = seg.join("bad.card.json");
    fs::write(&seg_card, "{\"format\": \"tricons-segmenter-card\", \"version\": 1}").unwrap();
    let out = seg.join("out");
    t.case(
        "segmenter card without its fields",
        &["segment", "--model", s(&seg_card), "--out", s(&out), "--limit", "1"],
        &["bad.card.json"],
        &[],
        &[],
    );
    for (name, field, value) in [
        ("erosion.card.json", "pose_mask_erode_px", "99"),
        ("radius.card.json", "pose_mask_max_radius_m", "{\"cup\": 0.1}"),
    ] {
        let card = seg.join(name);
        let text = fs::read_to_string(repo("models/maskrcnn-light.card.json")).unwrap();
        let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
        v[field] = serde_json::from_str(value).unwrap();
        fs::write(&card, v.to_string()).unwrap();
        t.case(
            &format!("segmenter card with a bad {field}"),
            &["segment", "--model", s(&card), "--out", s(&out), "--limit", "1"],
            &[name, field],
            &[],
            &[],
        );
    }
    let seg_graph = t.dir("segmenter-graph").join("bad.onnx");
    fs::write(&seg_graph, b"\x0a\xff\xff\xff\xff\x0f").unwrap();
    t.case(
        "segmenter graph not ONNX",
        &["segment", "--model", s(&seg_graph), "--out", s(&out), "--limit", "1"],
        &["bad.onnx"],
        &[],
        &[],
    );
    let bomb = seg.join("bomb.png");
    fs::write(&bomb, size_bomb(60_000, 60_000)).unwrap();
    t.case("segment a PNG size bomb", &["segment", "--image", s(&bomb), "--out", s(&out)], &["bomb.png"], &[], &[]);

    // --- recording with `record` ----------------------------------------------------------
    let d = t.dir("record-nonempty");
    let src = demo_subset(&d, 2, false);
    let target = d.join("target");
    fs::create_dir_all(&target).unwrap();
    let existing = target.join("000000_color.png");
    fs::write(&existing, b"an earlier recording's frame").unwrap();
    t.case(
        "record into a non-empty directory",
        &["record", "--recording", s(&src), "--rate", "max", "--out", s(&target)],
        &["not empty"],
        &[&existing],
        &[&target.join("manifest.json")],
    );

    let d = t.dir("record-bad-frame");
    let src = demo_subset(&d, 2, false);
    fs::write(src.join("000002_color.png"), size_bomb(60_000, 60_000)).unwrap();
    t.case(
        "record from a source with a size bomb",
        &["record", "--recording", s(&src), "--rate", "max", "--out", s(&d.join("out"))],
        &["000002_color.png", "--skip-bad-frames"],
        &[],
        &[],
    );

    // --- the service's configuration -------------------------------------------------------
    let d = t.dir("serve");
    let config = d.join("serve.json");
    fs::write(&config, "{\"recording\": \"x\", \"queue\": -2}").unwrap();
    t.case(
        "serve config with a negative queue",
        &["serve", "--config", s(&config)],
        &["serve.json", "queue"],
        &[],
        &[],
    );
    fs::write(&config, "{\"recording\": ").unwrap();
    t.case("serve config cut short", &["serve", "--config", s(&config)], &["serve.json"], &[], &[]);
    fs::write(&config, format!("{{\"recording\": {demo:?}, \"masks\": \"gt\", \"listen\": \"not-an-address\"}}"))
        .unwrap();
    t.case("serve config with a bad address", &["serve", "--config", s(&config)], &["serve.json", "listen"], &[], &[]);
    let prev = t.previous_output("serve-any");
    t.case(
        "serve on every interface without --listen-any",
        &["serve", "--recording", &demo, "--masks", "gt", "--listen", "0.0.0.0:0", "--out", s(&prev), "--frames", "1"],
        &["--listen-any"],
        &[&prev],
        &[],
    );
    let prev = t.previous_output("serve-model");
    t.case(
        "serve with a missing model",
        &[
            "serve",
            "--recording",
            &demo,
            "--masks",
            "gt",
            "--model",
            "no/such.card.json",
            "--no-listen",
            "--out",
            s(&prev),
        ],
        &["no/such.card.json"],
        &[&prev],
        &[],
    );

    // --- camera configs ---------------------------------------------------------------------
    let camera = d.join("camera.json");
    fs::write(&camera, "{\"format\": \"tricons-camera\", \"version\": 1, \"color\": 3}").unwrap();
    let camera_needle = if cfg!(all(feature = "v4l", target_os = "linux")) { "camera.json" } else { "v4l" };
    t.case(
        "camera config with a wrong field type",
        &[
            "record",
            "--color",
            "/dev/video-none",
            "--depth",
            "/dev/video-none2",
            "--camera",
            s(&camera),
            "--out",
            s(&d.join("cam")),
        ],
        &[camera_needle],
        &[],
        &[],
    );

    // --- other sources: ROS 2 bags, the NOCS layout, published Mask R-CNN results ------------
    let d = t.dir("sources");
    let bag = d.join("garbage.mcap");
    fs::write(&bag, b"\x89MCAP0\r\n this is not a bag").unwrap();
    let prev = t.previous_output("sources-out");
    if cfg!(feature = "ros2") {
        t.case(
            "replay of a garbage bag",
            &["replay", "--recording", s(&bag), "--masks", "gt", "--model", &model, "--out", s(&prev)],
            &["garbage.mcap"],
            &[&prev],
            &[],
        );
    }
    let results = d.join("results");
    fs::create_dir_all(&results).unwrap();
    fs::write(results.join("results_test_scene_1_0000.pkl"), b"\x80\x02}q\x00(X\x05\x00\x00\x00").unwrap();
    t.case(
        "published results: no pickle for the frames",
        &[
            "replay",
            "--recording",
            &demo,
            "--masks",
            &format!("results:{}", s(&results)),
            "--model",
            &model,
            "--out",
            s(&prev),
        ],
        &["results"],
        &[&prev],
        &[],
    );

    let n = t.cases;
    assert!(
        t.failures.is_empty(),
        "{} of {n} bad-input cases misbehaved:\n{}",
        t.failures.len(),
        t.failures.join("\n")
    );
    assert!(n >= 40, "the suite holds {n} cases");
    println!("{n} bad-input cases: each a clean error naming the file or field, nothing lost");
}

/// A frame the service cannot read is a source error: counted, logged with the file's name,
/// skipped; the service goes on with the next frames and exits 0.
#[test]
fn a_size_bomb_in_a_served_recording_is_skipped_and_counted() {
    let dir = tempfile::tempdir().unwrap();
    let rec = demo_subset(dir.path(), 3, true);
    fs::write(rec.join("000002_color.png"), size_bomb(60_000, 60_000)).unwrap();
    let out = dir.path().join("poses.jsonl");
    let stats = dir.path().join("stats.json");
    let o = tricons(&[
        "serve",
        "--recording",
        s(&rec),
        "--masks",
        "gt",
        "--rate",
        "max",
        "--no-listen",
        "--threads",
        "1",
        "--out",
        s(&out),
        "--stats-out",
        s(&stats),
    ]);
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("000002_color.png") && !err.contains("panicked"), "{err}");
    let lines = fs::read_to_string(&out).unwrap();
    let frames: Vec<String> = lines
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["frame"].as_str().unwrap().to_string())
        .collect();
    assert_eq!(frames, ["000000", "000003"], "the two readable frames are published, in order");
    let stats: serde_json::Value = serde_json::from_str(&fs::read_to_string(&stats).unwrap()).unwrap();
    let errors = stats.get("source_errors").or_else(|| stats.pointer("/counters/source_errors"));
    assert_eq!(errors.and_then(|v| v.as_u64()), Some(1), "one source error counted: {stats}");
}
