"""The segmentation side: AP arithmetic on exact cases, run-length masks, and the
runtime against onnxruntime on an unmodified torchvision maskrcnn_resnet50_fpn export
(random weights, generated here, not committed)."""

import json
import subprocess

import numpy as np
import pytest

from conftest import REPO, find_tricons
from tricons_pose import maskrcnn as mr


def test_ap_exact_cases():
    gb = np.array([[0, 0, 10, 10], [20, 20, 30, 30]], np.float32)
    gl = np.array([1, 1])
    gm = np.zeros((2, 4, 4), bool)
    perfect = (gb, gl, np.array([0.9, 0.8], np.float32), gm, gb, gl, gm)
    ap = mr.average_precision([perfect])
    assert ap["bbox"][0.5] == pytest.approx(1.0)
    # A false positive scored above both hits: precision 1/2 then 2/3 -> envelope 2/3 over all recall.
    fp = np.array([[50, 50, 60, 60]], np.float32)
    pb = np.concatenate([fp, gb])
    frame = (pb, np.array([1, 1, 1]), np.array([0.95, 0.9, 0.8], np.float32), np.zeros((3, 4, 4), bool), gb, gl, gm)
    assert mr.average_precision([frame])["bbox"][0.5] == pytest.approx(2 / 3)
    # One of two found, no false positive: recall reaches 0.5 -> AP = 51/101.
    half = (gb[:1], gl[:1], np.array([0.9], np.float32), gm[:1], gb, gl, gm)
    assert mr.average_precision([half])["bbox"][0.5] == pytest.approx(51 / 101)
    # IoU 0.6 hits at 0.5, misses at 0.75.
    shifted = np.array([[0, 0, 10, 10]], np.float32) + np.array([2.5, 0, 2.5, 0], np.float32)
    one = (shifted, gl[:1], np.array([0.9], np.float32), gm[:1], gb[:1], gl[:1], gm[:1])
    ap = mr.average_precision([one])
    assert ap["bbox"][0.5] == pytest.approx(1.0) and ap["bbox"][0.75] == pytest.approx(0.0)


def test_rle_round_trip():
    rng = np.random.default_rng(0)
    m = rng.random(1000) < 0.3
    runs = mr.rle(m)
    assert sum(runs) == 1000
    assert (mr.decode_rle(runs, 1000) == m).all()
    assert mr.rle(np.array([True, True, False])) == [0, 2, 1]


@pytest.fixture(scope="module")
def r50(tmp_path_factory):
    path = tmp_path_factory.mktemp("r50") / "maskrcnn_resnet50_fpn.onnx"
    mr.export_r50_cmd(type("A", (), {"out": str(path), "seed": 0, "opset": mr.OPSET})())
    return path


def test_r50_export_runs_in_tricons_like_onnxruntime(r50, tmp_path):
    image = REPO / "tests" / "data" / "synthnocs-demo" / "000000_color.png"
    fx = mr.ort_fixture(str(r50), str(image))
    assert len(fx["instances"]) == 100  # torchvision's detections_per_img
    cmp = mr.compare_detections(fx, _segment(r50, image, tmp_path / "seg"))
    assert cmp["unmatched"] == 0, cmp
    assert cmp["box_px"] <= 0.5, cmp
    assert cmp["score"] <= 1e-3, cmp
    assert cmp["mask_iou"] >= 0.98, cmp


def _segment(model, image, out):
    subprocess.run(
        [str(find_tricons()), "segment", "--model", str(model), "--image", str(image), "--min-score", "0",
         "--out", str(out)],
        check=True,
        capture_output=True,
    )
    return json.loads((out / "segments.jsonl").read_text().splitlines()[0])


@pytest.mark.parametrize("opset", [11, 14, 17])
def test_light_random_export_matches_onnxruntime_across_opsets(opset, tmp_path):
    """The light architecture with random weights at the opsets torchvision supports
    (RoiAlign's coordinate mode changes at 16)."""
    import torch

    torch.manual_seed(opset)
    model = mr.build_light()
    path = tmp_path / f"light-op{opset}.onnx"
    mr.export_onnx(model, path, opset=opset)
    image = REPO / "tests" / "data" / "synthnocs-demo" / "000003_color.png"
    fx = mr.ort_fixture(str(path), str(image))
    assert fx["instances"], "random light model detected nothing"
    cmp = mr.compare_detections(fx, _segment(path, image, tmp_path / "seg"))
    assert cmp["unmatched"] == 0 and cmp["box_px"] <= 0.5 and cmp["score"] <= 1e-3, cmp
    assert cmp["mask_iou"] >= 0.98, cmp


def test_no_detection_runs_the_empty_branch(tmp_path):
    """Nothing above the graph's score floor: the inlined empty-guard branch (ReduceMax over
    zero boxes, NMS on nothing) must give zero instances, as onnxruntime does."""
    path = tmp_path / "light-none.onnx"
    mr.export_onnx(mr.build_light(score_thresh=0.99), path)
    image = REPO / "tests" / "fixtures" / "segment" / "blank.png"
    assert mr.ort_fixture(str(path), str(image))["instances"] == []
    assert _segment(path, image, tmp_path / "seg")["instances"] == []


def test_unnamed_outputs_fail_clearly_and_a_card_maps_them(tmp_path):
    """An export without output_names: tricons refuses it naming the outputs it found; a
    segmenter card that maps torch's names makes it run, with the card's class names."""
    import onnx

    path = tmp_path / "unnamed.onnx"
    mr.export_onnx(mr.build_light(), path, output_names=None)
    names = [o.name for o in onnx.load(str(path)).graph.output]
    assert "boxes" not in names and len(names) == 4
    image = REPO / "tests" / "data" / "synthnocs-demo" / "000000_color.png"
    cmd = [str(find_tricons()), "segment", "--image", str(image), "--out", str(tmp_path / "seg"), "--min-score", "0"]
    r = subprocess.run(cmd + ["--model", str(path)], capture_output=True, text=True)
    assert r.returncode != 0 and "panicked" not in r.stderr
    assert "no graph output named \"boxes\"" in r.stderr and names[0] in r.stderr, r.stderr
    card = tmp_path / "unnamed.card.json"
    card.write_text(json.dumps({
        "format": "tricons-segmenter-card", "version": 1, "model": path.name,
        "outputs": dict(zip(["boxes", "labels", "scores", "masks"], names)),
        "labels": {str(i + 1): c for i, c in enumerate(mr.CLASSES)},
    }))
    r = subprocess.run(cmd + ["--model", str(card)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    record = json.loads((tmp_path / "seg" / "segments.jsonl").read_text().splitlines()[0])
    assert record["instances"] and all(i["class"] in mr.CLASSES for i in record["instances"])


def test_raised_score_floor_keeps_the_same_detections_in_onnxruntime():
    """The score-floor rewrite tricons applies at load, done on the graph for onnxruntime
    (bench_pipeline.raise_score_floor): onnxruntime returns exactly the detections of the
    unchanged graph that score >= 0.5, with the same boxes and scores."""
    import onnxruntime as ort
    from PIL import Image

    from tricons_pose.bench_pipeline import raise_score_floor

    model = str(REPO / "models/maskrcnn-light.onnx")
    img = np.asarray(Image.open(REPO / "tests/data/synthnocs-demo/000000_color.png").convert("RGB"))
    x = (img.astype(np.float32) / 255.0).transpose(2, 0, 1).copy()
    so = ort.SessionOptions()
    so.log_severity_level = 3
    plain = ort.InferenceSession(model, so, providers=["CPUExecutionProvider"]).run(None, {"image": x})
    raised = ort.InferenceSession(raise_score_floor(model, 0.5), so, providers=["CPUExecutionProvider"]).run(
        None, {"image": x})
    keep = plain[2] >= 0.5
    assert 0 < keep.sum() < len(keep)
    np.testing.assert_array_equal(raised[1], plain[1][keep])
    np.testing.assert_allclose(raised[2], plain[2][keep], atol=1e-6)
    np.testing.assert_allclose(raised[0], plain[0][keep], atol=1e-3)
    assert np.abs(raised[3] - plain[3][keep]).max() < 1e-4


def test_import_onnx_reproduces_the_shipped_segmenter(tmp_path):
    """import-onnx rebuilds a PyTorch checkpoint from models/maskrcnn-light.onnx, whose
    export folded BatchNorm into the convs: in eval mode it detects what onnxruntime does."""
    import torch

    assert mr._scope_path("/backbone/body/body.1/block/block.0/block.0.0/Conv") == "backbone.body.1.block.0.0"
    assert mr._scope_path("/rpn/head/cls_logits_2/Conv") == "rpn.head.cls_logits"
    model_path = REPO / "models" / "maskrcnn-light.onnx"
    image = REPO / "tests" / "data" / "synthnocs-demo" / "000000_color.png"
    out = tmp_path / "init.pt"
    mr.main(["import-onnx", "--onnx", str(model_path), "--out", str(out), "--threads", "1"])
    state = torch.load(out, map_location="cpu")
    assert state["step"] == 0 and state["args"]["import_onnx"] == str(model_path)
    model = mr.build_light(other_class=mr.onnx_has_other_class(str(model_path)))
    assert mr.has_other_class(state["model"]) == mr.onnx_has_other_class(str(model_path))
    model.load_state_dict(state["model"])
    fx = mr.ort_fixture(str(model_path), str(image))
    assert len(fx["instances"]) > 5
    cmp = mr.compare_detections(fx, mr.torch_record(model, str(image)))
    assert cmp["unmatched"] == 0, cmp
    assert cmp["box_px"] <= 0.5, cmp
    assert cmp["score"] <= 1e-3, cmp
    assert cmp["mask_iou"] >= 0.98, cmp


def test_a_re_export_keeps_the_fields_chosen_for_the_shipped_card(tmp_path):
    """write_card over an existing card keeps its thresholds, duplicate suppression and
    pose-stage mask fields (chosen by evaluation) and records the new graph's hash."""
    shipped = json.loads((REPO / "models" / "maskrcnn-light.card.json").read_text())
    graph = tmp_path / "m.onnx"
    graph.write_bytes(b"not really a graph")
    card = tmp_path / "m.card.json"
    card.write_text(json.dumps(shipped))
    mr.write_card(card, graph.name, {"architecture": "test"})
    new = json.loads(card.read_text())
    # every field of the shipped card that the export does not write itself survives
    written = {"format", "version", "model", "sha256", "architecture", "input", "outputs", "labels", "training",
               "metrics"}
    for k in set(shipped) - written:
        assert k in mr.KEPT_CARD_FIELDS and new.get(k) == shipped[k], k
    assert new["pose_mask_erode_px"] == 1 and new["pose_mask_max_radius_m"]["mug"] == 0.14
    assert new["model"] == "m.onnx" and new["sha256"] != shipped["sha256"]
    fresh = tmp_path / "fresh.card.json"
    mr.write_card(fresh, graph.name, {"architecture": "test"})
    assert "pose_mask_erode_px" not in json.loads(fresh.read_text())


def test_training_data_spans_several_recordings_and_flips_consistently():
    """SegData takes frames from each recording in order (``limit`` per recording); a
    target's boxes are the tight bounds of its masks, also after a horizontal flip."""
    demo = str(REPO / "tests" / "data" / "synthnocs-demo")
    one = mr.SegData(demo)
    two = mr.SegData([demo, demo], limit=2)
    assert len(one) == 4 and len(two) == 4
    for i in range(2):
        a, ta = two.item(i, flip=False)
        b, tb = two.item(i + 2, flip=False)
        assert torch_equal(a, b) and all(torch_equal(ta[k], tb[k]) for k in ta)
    for flip in (False, True):
        img, t = one.item(0, flip=flip)
        assert img.shape[0] == 3 and t["masks"].shape[1:] == img.shape[1:]
        assert len(t["labels"]) >= 1 and int(t["labels"].min()) >= 1 and int(t["labels"].max()) <= 6
        for box, m in zip(t["boxes"].numpy(), t["masks"].numpy().astype(bool)):
            ys, xs = np.nonzero(m)
            assert m.sum() >= mr.MIN_TARGET_PIXELS
            assert box.tolist() == [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]
    plain, tp = one.item(0, flip=False)
    flipped, tf = one.item(0, flip=True)
    assert torch_equal(plain.flip(-1), flipped) and torch_equal(tp["masks"].flip(-1), tf["masks"])


def torch_equal(a, b) -> bool:
    import torch

    return bool(torch.equal(a, b))


def test_training_resumes_where_it_stopped(tmp_path):
    """Two steps on two recordings, then a resume to three continues from the checkpoint."""
    import argparse

    demo = str(REPO / "tests" / "data" / "synthnocs-demo")
    args = argparse.Namespace(data=[demo, demo], out=str(tmp_path), steps=2, batch=1, lr=1e-4, warmup=1,
                              threads=1, limit=2, seed=0, ckpt_every=1, min_size=160, max_size=224,
                              init=None, freeze_bn=False, other_class=False)
    mr.train(args)
    import torch

    assert torch.load(tmp_path / "last.pt", map_location="cpu")["step"] == 2
    mr.train(argparse.Namespace(**{**vars(args), "steps": 3}))
    log = (tmp_path / "train.log").read_text()
    assert "4 frames indexed" in log and "resumed at step 2" in log and "step 3/3" in log
    assert torch.load(tmp_path / "last.pt", map_location="cpu")["step"] == 3


def test_the_other_class_is_added_from_the_background_and_nothing_else_moves():
    """A six-class state_dict gains OTHER_LABEL: the six classes' rows are unchanged, the new
    classifier row is the background's, its box regression zero, its mask logits the six
    classes' mean; the result loads strictly into the seven-class model and back out."""
    import torch

    torch.manual_seed(0)
    six = mr.build_light().state_dict()
    assert not mr.has_other_class(six)
    seven = mr.add_other_class(six)
    assert mr.has_other_class(seven)
    model = mr.build_light(other_class=True)
    model.load_state_dict(seven)  # strict: every key and shape
    cls = "roi_heads.box_predictor.cls_score.weight"
    box = "roi_heads.box_predictor.bbox_pred.weight"
    mask = "roi_heads.mask_predictor.mask_fcn_logits.weight"
    assert torch.equal(seven[cls][: mr.NUM_LABELS], six[cls])
    assert torch.equal(seven[cls][mr.OTHER_LABEL], six[cls][0])
    assert torch.equal(seven[box][: 4 * mr.NUM_LABELS], six[box])
    assert not seven[box][4 * mr.OTHER_LABEL :].any()
    assert torch.allclose(seven[mask][mr.OTHER_LABEL], six[mask][1:].mean(0))
    assert all(torch.equal(seven[k], v) for k, v in six.items() if "predictor" not in k)


def test_distractor_masks_become_other_targets(tmp_path):
    """`tricons synth --distractor-masks` writes {id}_distractors.png; with ``other`` SegData
    adds each distractor as an OTHER_LABEL target that overlaps no annotated object, and
    without the file it says which file is missing and how to make it."""
    rec = tmp_path / "rec"
    subprocess.run(
        [str(find_tricons()), "synth", "--out", str(rec), "--frames", "6", "--seed", "3", "--max-distractors", "8",
         "--distractor-masks"],
        check=True,
        capture_output=True,
    )
    data = mr.SegData(str(rec), other=True)
    plain = mr.SegData(str(rec))
    others = 0
    for i in range(len(data)):
        _, t = data.item(i, flip=False)
        _, tp = plain.item(i, flip=False)
        labels = t["labels"].numpy()
        n = len(tp["labels"])
        assert (labels[:n] == tp["labels"].numpy()).all() and (labels[n:] == mr.OTHER_LABEL).all()
        objects = t["masks"][:n].numpy().any(0)
        for m in t["masks"][n:].numpy().astype(bool):
            assert m.sum() >= mr.MIN_TARGET_PIXELS and not (m & objects).any()
        others += len(labels) - n
    assert others > 0, "no distractor in 6 frames of up to 8"
    missing = data.distractors_path(0)
    missing.unlink()
    with pytest.raises(FileNotFoundError, match="--distractor-masks"):
        data.target(0)
