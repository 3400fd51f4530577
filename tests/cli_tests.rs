//! The `tricons` binary as a user runs it: help texts, the synth -> inspect ->
//! eval oracle path, and clear non-zero exits on bad input.

mod common;

use std::fs;
use std::path::Path;

use common::cli::{assert_clean_failure, demo_subset, repo, stderr, tricons};

fn synth(dir: &Path, frames: &str, seed: &str) {
    let o = tricons(&["synth", "--out", dir.to_str().unwrap(), "--frames", frames, "--seed", seed]);
    assert!(o.status.success(), "synth failed: {}", stderr(&o));
}

#[test]
fn every_command_has_help_with_an_example() {
    for cmd in [
        &["--help"][..],
        &["synth", "--help"],
        &["eval", "--help"],
        &["inspect", "--help"],
        &["replay", "--help"],
        &["segment", "--help"],
        &["bench", "--help"],
        &["quantize", "--help"],
        &["validate", "--help"],
    ] {
        let o = tricons(cmd);
        assert!(o.status.success());
        let text = String::from_utf8_lossy(&o.stdout);
        assert!(text.contains("Example"), "{cmd:?}: {text}");
    }
}

#[test]
fn ground_truth_as_predictions_scores_100_everywhere_in_both_iou_modes() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec");
    synth(&rec, "4", "11");
    let o = tricons(&["inspect", rec.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("frames with ground truth: 4 of 4"));

    let o = tricons(&["inspect", rec.to_str().unwrap(), "--predictions"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let pred = dir.path().join("gt.jsonl");
    fs::write(&pred, &o.stdout).unwrap();
    assert_eq!(String::from_utf8_lossy(&o.stdout).lines().count(), 4);

    for mode in ["published", "corrected"] {
        let json = dir.path().join(format!("{mode}.json"));
        let o = tricons(&[
            "eval",
            "--gt",
            rec.to_str().unwrap(),
            "--pred",
            pred.to_str().unwrap(),
            "--iou",
            mode,
            "--json",
            json.to_str().unwrap(),
            "--pose-threshold",
            "15deg5cm",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let table = String::from_utf8_lossy(&o.stdout);
        assert!(table.contains(mode), "table must name the IoU variant: {table}");
        let report: serde_json::Value = serde_json::from_str(&fs::read_to_string(&json).unwrap()).unwrap();
        let means = report["mean"].as_object().expect("report has a mean object");
        assert!(means.len() >= 8, "7 standard metrics + 1 extra: {means:?}");
        for (metric, v) in means {
            assert_eq!(v.as_f64(), Some(100.0), "{mode} {metric}");
        }
    }
}

#[test]
fn synth_is_deterministic_and_never_clobbers_a_recording() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    synth(&a, "2", "5");
    synth(&b, "2", "5");
    let mut names: Vec<_> = fs::read_dir(&a).unwrap().map(|e| e.unwrap().file_name()).collect();
    names.sort();
    assert!(names.len() >= 9, "{names:?}");
    for n in &names {
        assert_eq!(fs::read(a.join(n)).unwrap(), fs::read(b.join(n)).unwrap(), "{n:?} differs");
    }
    let before = fs::read(a.join("manifest.json")).unwrap();
    let o = tricons(&["synth", "--out", a.to_str().unwrap(), "--frames", "1", "--seed", "9"]);
    assert_clean_failure(&o, "not empty");
    assert_eq!(fs::read(a.join("manifest.json")).unwrap(), before);

    let o = tricons(&["synth", "--split", "test", "--seed", "3", "--out", dir.path().join("t").to_str().unwrap()]);
    assert_clean_failure(&o, "fixed seed");

    // --max-distractors reaches the generator: no distractor changes the frames, too many is refused
    let c = dir.path().join("c");
    let o = tricons(&["synth", "--out", c.to_str().unwrap(), "--frames", "2", "--seed", "5", "--max-distractors", "0"]);
    assert!(o.status.success(), "synth failed: {}", stderr(&o));
    assert!(names.iter().any(|n| fs::read(a.join(n)).unwrap() != fs::read(c.join(n)).unwrap()));
    let o = tricons(&[
        "synth",
        "--out",
        dir.path().join("d").to_str().unwrap(),
        "--frames",
        "1",
        "--max-distractors",
        "65",
    ]);
    assert_clean_failure(&o, "max_distractors");
}

#[test]
fn bad_input_fails_cleanly_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec");
    synth(&rec, "2", "3");
    let rec_s = rec.to_str().unwrap();

    let o = tricons(&["inspect", dir.path().join("missing").to_str().unwrap()]);
    assert_clean_failure(&o, "missing");

    // Malformed predictions: the file and the line are named.
    let pred = dir.path().join("pred.jsonl");
    fs::write(&pred, "{\"frame\":\"000000\",\"instances\":[]}\n{\"frame\": 12\n").unwrap();
    let o = tricons(&["eval", "--gt", rec_s, "--pred", pred.to_str().unwrap()]);
    assert_clean_failure(&o, "pred.jsonl line 2");

    // A prediction for a frame the recording does not have.
    fs::write(&pred, "{\"frame\":\"999999\",\"instances\":[]}\n").unwrap();
    let o = tricons(&["eval", "--gt", rec_s, "--pred", pred.to_str().unwrap()]);
    assert_clean_failure(&o, "999999");

    // Corrupt colour PNG, 8-bit depth, wrong manifest version.
    let color = rec.join("000000_color.png");
    fs::write(&color, b"\x89PNG\r\n\x1a\nbroken").unwrap();
    let o = tricons(&["inspect", rec_s]);
    assert_clean_failure(&o, "000000_color.png");

    let manifest = rec.join("manifest.json");
    let text = fs::read_to_string(&manifest).unwrap();
    fs::write(&manifest, text.replace("\"version\": 1", "\"version\": 2")).unwrap();
    let o = tricons(&["eval", "--gt", rec_s, "--pred", pred.to_str().unwrap()]);
    assert_clean_failure(&o, "version 2");
}

#[test]
fn replay_of_the_demo_recording_writes_predictions_overlays_and_scores_them() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("pred.jsonl");
    let overlays = dir.path().join("overlays");
    let o = tricons(&[
        "replay",
        "--recording",
        &repo("tests/data/synthnocs-demo"),
        "--model",
        &repo("models/tricons-pose.card.json"),
        "--masks",
        "gt",
        "--out",
        out.to_str().unwrap(),
        "--overlays",
        overlays.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(table.contains("NOCS metrics") && table.contains("mean"), "{table}");
    let text = fs::read_to_string(&out).unwrap();
    let lines: Vec<serde_json::Value> = text.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 4, "one line per frame");
    let n: usize = lines.iter().map(|l| l["instances"].as_array().unwrap().len()).sum();
    assert_eq!(n, 18, "every demo instance is estimated");
    assert!(out.with_extension("eval.json").is_file());
    for l in &lines {
        let png = overlays.join(format!("{}_overlay.png", l["frame"].as_str().unwrap()));
        let img = tricons::image_io::read_color_png(&png, tricons::image_io::SizeLimit::Capped).unwrap();
        assert_eq!((img.width, img.height), (640, 480));
    }
    // the same seed gives the same predictions
    let out2 = dir.path().join("pred2.jsonl");
    let o = tricons(&[
        "replay",
        "--recording",
        &repo("tests/data/synthnocs-demo"),
        "--model",
        &repo("models/tricons-pose.onnx"),
        "--masks",
        "gt",
        "--out",
        out2.to_str().unwrap(),
        "--no-eval",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(fs::read_to_string(&out2).unwrap(), text);
}

#[test]
fn replay_fails_cleanly_on_a_missing_model_or_a_recording_without_masks() {
    let dir = tempfile::tempdir().unwrap();
    let o =
        tricons(&["replay", "--recording", &repo("tests/data/synthnocs-demo"), "--model", "no/such/model.card.json"]);
    assert_clean_failure(&o, "no/such/model.card.json");
    // a recording whose frames have no annotations
    let rec = demo_subset(dir.path(), 1, false);
    let out = dir.path().join("p.jsonl");
    let o = tricons(&[
        "replay",
        "--recording",
        rec.to_str().unwrap(),
        "--model",
        &repo("models/tricons-pose.card.json"),
        "--masks",
        "gt",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_clean_failure(&o, "no instance masks");
    assert!(!out.exists(), "nothing written on failure");
    // With the segmentation model (the default) the same raw RGB-D frame is fine.
    let o = tricons(&["replay", "--recording", rec.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(fs::read_to_string(&out).unwrap().lines().count(), 1);
}

#[test]
fn replay_runs_the_full_pipeline_from_raw_rgbd_by_default() {
    let dir = tempfile::tempdir().unwrap();
    // Frame 000000 (six objects) only: this test also runs under qemu.
    let rec = demo_subset(dir.path(), 1, true);
    let out = dir.path().join("pred.jsonl");
    let o = tricons(&["replay", "--recording", rec.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("NOCS metrics"));
    let text = fs::read_to_string(&out).unwrap();
    let lines: Vec<serde_json::Value> = text.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 1);
    let instances: Vec<&serde_json::Value> = lines.iter().flat_map(|l| l["instances"].as_array().unwrap()).collect();
    assert!(instances.len() >= 3, "the shipped segmenter finds at least half of the 6 objects");
    for inst in &instances {
        let score = inst["score"].as_f64().unwrap();
        assert!((0.5..=1.0).contains(&score), "score {score} below the card's threshold");
        assert_eq!(inst["box2d"].as_array().unwrap().len(), 4);
    }
    // Deterministic end to end.
    let out2 = dir.path().join("pred2.jsonl");
    let o = tricons(&["replay", "--recording", rec.to_str().unwrap(), "--out", out2.to_str().unwrap(), "--no-eval"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(fs::read_to_string(&out2).unwrap(), text);
}

#[test]
fn segment_writes_records_label_images_and_overlays() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("seg");
    let o = tricons(&[
        "segment",
        "--recording",
        &repo("tests/data/synthnocs-demo"),
        "--out",
        out.to_str().unwrap(),
        "--overlays",
        "--min-score",
        "0.3",
        "--json",
        dir.path().join("eval.json").to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = fs::read_to_string(out.join("segments.jsonl")).unwrap();
    let records: Vec<tricons::output::segments::SegRecord> =
        text.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(records.len(), 4);
    for r in &records {
        let labels = tricons::image_io::read_label_png(
            &out.join(format!("{}_labels.png", r.frame)),
            tricons::image_io::SizeLimit::Capped,
        )
        .unwrap();
        assert_eq!((labels.width, labels.height), (640, 480));
        for (k, inst) in r.instances.iter().enumerate() {
            let mask = tricons::output::segments::rle_to_mask(&inst.mask_rle, 640 * 480).unwrap();
            assert_eq!(mask.iter().filter(|&&m| m).count(), inst.pixels);
            assert!(inst.class.is_some(), "the shipped card names every label");
            // The label image shows the instance wherever no higher-scoring one covers it.
            if k == 0 {
                assert!(mask.iter().zip(&labels.data).all(|(&m, &l)| !m || l == 1));
            }
        }
        assert!(out.join(format!("{}_segments.png", r.frame)).is_file());
    }
    // The shipped card suppresses duplicates across classes: the demo frames have some at
    // a score threshold of 0.3 (one object under two labels; none at the card's 0.7 since the
    // segmenter's fifth fine-tuning); with --keep-duplicates they come back.
    let all = dir.path().join("all");
    let o = tricons(&[
        "segment",
        "--recording",
        &repo("tests/data/synthnocs-demo"),
        "--out",
        all.to_str().unwrap(),
        "--keep-duplicates",
        "--min-score",
        "0.3",
        "--json",
        dir.path().join("eval-all.json").to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let eval: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(dir.path().join("eval.json")).unwrap()).unwrap();
    let eval_all: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(dir.path().join("eval-all.json")).unwrap()).unwrap();
    let iou = eval["duplicate_mask_iou"].as_f64().expect("the shipped card sets duplicate_mask_iou");
    let inside = eval["duplicate_mask_inside"].as_f64().expect("the shipped card sets duplicate_mask_inside");
    assert!(eval_all["duplicate_mask_iou"].is_null() && eval_all["duplicate_mask_inside"].is_null());
    let dropped = eval["duplicates_dropped"].as_u64().unwrap();
    assert!(dropped > 0, "the demo frames hold duplicates: {eval}");
    // what suppression drops is of any label, NOCS or "other" (the card's label 7)
    let found = |e: &serde_json::Value| e["detections"].as_u64().unwrap() + e["other_detections"].as_u64().unwrap();
    assert_eq!(found(&eval) + dropped, found(&eval_all));
    assert!(eval_all["other_detections"].as_u64().unwrap() > 0, "the demo's distractors as \"other\": {eval_all}");
    assert_eq!(eval["objects"], eval_all["objects"]);
    for name in ["bbox_AP50", "bbox_AP75", "mask_AP50", "mask_AP75"] {
        let ap = eval["ap"][name].as_f64().unwrap();
        assert!((0.0..=100.0).contains(&ap), "{name} {ap}");
    }
    let all_records: Vec<tricons::output::segments::SegRecord> = fs::read_to_string(all.join("segments.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let masks = |r: &tricons::output::segments::SegRecord| -> Vec<(f32, Vec<bool>)> {
        r.instances
            .iter()
            .map(|i| (i.score, tricons::output::segments::rle_to_mask(&i.mask_rle, 640 * 480).unwrap()))
            .collect()
    };
    let overlap = |a: &[bool], b: &[bool]| {
        let inter = a.iter().zip(b).filter(|(x, y)| **x && **y).count() as f64;
        let union = a.iter().zip(b).filter(|(x, y)| **x || **y).count() as f64;
        inter / union.max(1.0)
    };
    // the fraction of `a`'s pixels inside `b`
    let within = |a: &[bool], b: &[bool]| {
        let inter = a.iter().zip(b).filter(|(x, y)| **x && **y).count() as f64;
        inter / (a.iter().filter(|x| **x).count() as f64).max(1.0)
    };
    for (kept, every) in records.iter().zip(&all_records) {
        let (kept, every) = (masks(kept), masks(every));
        // No two kept detections overlap above the threshold ...
        for (i, a) in kept.iter().enumerate() {
            for b in &kept[i + 1..] {
                assert!(overlap(&a.1, &b.1) <= iou);
            }
        }
        // ... each kept one is one of all, and each dropped one overlaps a better kept one
        // or lies mostly inside it.
        for e in &every {
            let is_kept = kept.iter().any(|k| k.0 == e.0 && k.1 == e.1);
            let duplicate = |k: &(f32, Vec<bool>)| overlap(&k.1, &e.1) > iou || within(&e.1, &k.1) > inside;
            assert!(is_kept || kept.iter().any(|k| k.0 >= e.0 && duplicate(k)));
        }
    }
    // A corrupt PNG: a clean error naming it, nothing written for it.
    let bad = dir.path().join("bad.png");
    fs::write(&bad, b"\x89PNG\r\n\x1a\nnot really").unwrap();
    let o = tricons(&["segment", "--image", bad.to_str().unwrap(), "--out", dir.path().join("b").to_str().unwrap()]);
    assert_clean_failure(&o, "bad.png");
}
