"""nocs_layout.py: SynthNOCS written in the NOCS dataset layout reads back as the same
ground truth, trains, predicts, and replays through the runtime's NOCS-layout reader."""

import json
import pickle
import subprocess

import numpy as np
import pytest
import torch

from conftest import REPO
from tricons_pose.config import ModelConfig
from tricons_pose.data import InstanceDataset
from tricons_pose.model import TriConsPose
from tricons_pose.nocs_layout import (MASK_BACKGROUND, NocsLayoutRecording, is_nocs_layout, open_any, scene_dirs,
                                      write_nocs_layout)
from tricons_pose.predict import predict_recording, write_jsonl
from tricons_pose.recording import Recording, RecordingError


@pytest.fixture(scope="module")
def layout(recording, tmp_path_factory):
    root = tmp_path_factory.mktemp("nocs") / "NOCS"
    scene = write_nocs_layout(recording, root, split="real_test", scene="scene_1")
    return root, scene


def test_files_follow_the_dataset_conventions(recording, layout):
    root, scene = layout
    rec = Recording(recording)
    assert scene == root / "Real" / "test" / "scene_1"
    assert sorted(p.name for p in scene.glob("*_color.png")) == [f"{f.id}_color.png" for f in rec.frames]
    for i in range(len(rec)):
        ann = rec.annotations(i)
        nid = rec.frames[i].id
        meta = [ln.split() for ln in (scene / f"{nid}_meta.txt").read_text().splitlines()]
        assert [(int(a), int(b)) for a, b, _ in meta] == [(x.id, x.class_id + 1) for x in ann.instances]
        from PIL import Image
        mask = np.asarray(Image.open(scene / f"{nid}_mask.png"))
        label = rec.mask(i, ann)
        assert np.array_equal(mask == MASK_BACKGROUND, label == 0)
        coord = np.asarray(Image.open(scene / f"{nid}_coord.png")).astype(np.float64) / 255.0
        # the NOCS repository's load_coord: z = 1 - stored z
        coord[..., 2] = 1.0 - coord[..., 2]
        fg = label > 0
        assert np.abs(coord[fg] - rec.nocs(i, ann)[fg]).max() <= 0.5 / 255 + 1e-6
        with open(root / "gts" / "real_test" / f"results_real_test_scene_1_{nid}.pkl", "rb") as f:
            gt = pickle.load(f)
        for k, inst in enumerate(ann.instances):
            RT = gt["gt_RTs"][k]
            scale = np.cbrt(np.linalg.det(RT[:3, :3]))
            assert np.allclose(RT[:3, :3] / scale, inst.R, atol=1e-12)
            assert np.allclose(RT[:3, 3], inst.t, atol=1e-12)
            assert np.allclose(scale * gt["gt_scales"][k], inst.s, atol=1e-12)
            assert np.isclose(np.linalg.norm(gt["gt_scales"][k]), 1.0)
        with open(root / "segmentation_results" / "real_test" / f"results_test_scene_1_{nid}.pkl", "rb") as f:
            seg = pickle.load(f)
        assert seg["pred_masks"].shape == label.shape + (len(ann.instances),)
        for k, inst in enumerate(ann.instances):
            assert np.array_equal(seg["pred_masks"][..., k], label == inst.id)
            y1, x1, y2, x2 = seg["pred_bboxes"][k]
            ys, xs = np.nonzero(label == inst.id)
            assert (y1, x1, y2, x2) == (ys.min(), xs.min(), ys.max() + 1, xs.max() + 1)
        assert list(seg["pred_class_ids"]) == [x.class_id + 1 for x in ann.instances]


def test_the_reader_gives_back_the_recording(recording, layout):
    root, scene = layout
    rec, nl = Recording(recording), NocsLayoutRecording(scene)
    assert is_nocs_layout(scene) and is_nocs_layout(scene.parent) and not is_nocs_layout(recording)
    assert scene_dirs(scene.parent) == [scene]
    assert len(nl) == len(rec) and nl.intrinsics == rec.intrinsics
    for i in range(len(rec)):
        a, b = rec.annotations(i), nl.annotations(i)
        assert np.array_equal(nl.color(i), rec.color(i))
        assert np.array_equal(nl.depth_m(i), rec.depth_m(i))
        assert np.array_equal(nl.mask(i, b), rec.mask(i, a))
        fg = rec.mask(i, a) > 0
        assert np.abs(nl.nocs(i, b)[fg] - rec.nocs(i, a)[fg]).max() <= 0.5 / 255 + 1e-6
        assert [(x.id, x.cls, x.handle_visible) for x in b.instances] == \
            [(x.id, x.cls, x.cls != "mug" or x.handle_visible) for x in a.instances]
        for x, y in zip(a.instances, b.instances):
            # float32 in the label pickle, as SPD writes it
            assert np.allclose(y.R, x.R, atol=1e-6) and np.allclose(y.t, x.t, atol=1e-6)
            assert np.allclose(y.s, x.s, rtol=1e-6)


def test_a_layout_trains_predicts_and_replays(recording, layout, tricons_bin, tmp_path):
    root, scene = layout
    cfg = ModelConfig.shipped().replace(n_points=256, n_keypoints=8, crop_size=32)
    ds_rec, ds_nl = InstanceDataset([recording], n_points=256, crop_size=32), InstanceDataset([scene.parent], n_points=256,
                                                                                             crop_size=32)
    assert len(ds_nl) == len(ds_rec) > 0
    # a training step on NOCS-layout samples
    torch.manual_seed(0)
    model = TriConsPose(cfg)
    loader = torch.utils.data.DataLoader(ds_nl, batch_size=2, shuffle=False)
    batch = next(iter(loader))
    out = model({k: batch[k] for k in ("rgb", "pts", "choose")})
    assert torch.isfinite(out["R"]).all()
    # predictions on the layout are frame for frame those on the recording (same samples)
    model.eval()
    pa = predict_recording(model, cfg, recording, batch_size=4)
    pb = predict_recording(model, cfg, scene, batch_size=4)
    assert [len(f["instances"]) for f in pa] == [len(f["instances"]) for f in pb]
    for fa, fb in zip(pa, pb):
        for x, y in zip(fa["instances"], fb["instances"]):
            assert x["class"] == y["class"]
            assert np.allclose(x["t"], y["t"], atol=1e-3)
    write_jsonl(tmp_path / "pred.jsonl", pb)
    # the runtime reads the same scene (poses fitted from its NOCS maps) and replays it
    res = subprocess.run([str(tricons_bin), "replay", "--recording", str(scene), "--masks", "gt", "--out",
                          str(tmp_path / "replay.jsonl"), "--no-eval"], capture_output=True, text=True, cwd=REPO)
    assert res.returncode == 0, res.stderr
    lines = [json.loads(ln) for ln in (tmp_path / "replay.jsonl").read_text().splitlines()]
    assert [ln["frame"] for ln in lines] == [f.id for f in Recording(recording).frames]
    assert [len(ln["instances"]) for ln in lines] == [len(f["instances"]) for f in pb]


def test_bad_layouts_are_clear_errors(recording, layout, tmp_path):
    root, scene = layout
    with pytest.raises(RecordingError, match="neither a NOCS scene"):
        scene_dirs(tmp_path)
    # sizes need the object models
    lone = tmp_path / "lone"
    lone.mkdir()
    first = sorted(scene.glob("*_color.png"))[0].name[: -len("_color.png")]
    for p in scene.glob(f"{first}_*"):
        (lone / p.name).write_bytes(p.read_bytes())
    with pytest.raises(RecordingError, match="object models"):
        NocsLayoutRecording(lone).annotations(0)
    assert len(open_any(lone)) == 1
    with pytest.raises(ValueError, match="split"):
        write_nocs_layout(recording, tmp_path / "x", split="real_val")


def test_replay_with_the_published_results_equals_the_recording_with_its_masks(recording, layout, tricons_bin,
                                                                                tmp_path):
    """`tricons replay --masks results:DIR` on the NOCS-layout scene gives the same
    predictions, and so the same metrics, as replaying the tricons recording with its
    ground-truth masks (the result pickles hold exactly those masks)."""
    root, scene = layout
    results = root / "segmentation_results" / "real_test"

    def replay(rec, masks, name):
        out = tmp_path / f"{name}.jsonl"
        res = subprocess.run([str(tricons_bin), "replay", "--recording", str(rec), "--masks", masks, "--out", str(out),
                              "--no-eval"], capture_output=True, text=True, cwd=REPO)
        assert res.returncode == 0, res.stderr
        report = tmp_path / f"{name}.json"
        res = subprocess.run([str(tricons_bin), "eval", "--gt", str(recording), "--pred", str(out), "--json",
                              str(report)], capture_output=True, text=True)
        assert res.returncode == 0, res.stderr
        frames = [json.loads(ln) for ln in out.read_text().splitlines()]
        return frames, json.loads(report.read_text())["mean"]

    published, m_pub = replay(scene, f"results:{results}", "published")
    own, m_own = replay(recording, "gt", "own")
    assert m_pub == m_own
    assert len(published) == len(own)
    for a, b in zip(published, own):
        assert a["frame"] == b["frame"]
        assert [(x["class"], x["R"], x["t"], x["s"]) for x in a["instances"]] == \
            [(x["class"], x["R"], x["t"], x["s"]) for x in b["instances"]]
    # the boxes come from the pickles: (y1, x1, y2, x2) -> [x0, y0, x1, y1]
    assert all("box2d" in x for f in published for x in f["instances"])
    # the pose service reads the same pickles (frame k samples from (seed, k) as replay's frame k)
    served = tmp_path / "served.jsonl"
    res = subprocess.run([str(tricons_bin), "serve", "--recording", str(scene), "--masks", f"results:{results}",
                          "--rate", "max", "--no-listen", "--out", str(served), "--threads", "1"],
                         capture_output=True, text=True, cwd=REPO, timeout=300)
    assert res.returncode == 0, res.stderr
    assert [json.loads(ln)["instances"] for ln in served.read_text().splitlines()] == [f["instances"] for f in published]
    # a directory without a frame's file names it
    lone = tmp_path / "partial"
    lone.mkdir()
    first = sorted(results.glob("*.pkl"))[0]
    (lone / first.name).write_bytes(first.read_bytes())
    res = subprocess.run([str(tricons_bin), "replay", "--recording", str(scene), "--masks", f"results:{lone}", "--out",
                          str(tmp_path / "x.jsonl"), "--no-eval"], capture_output=True, text=True, cwd=REPO)
    assert res.returncode != 0 and "no result file for frame" in res.stderr, res.stderr
    # a pickle that is not a result dict is a clear error naming the file and field
    bad = tmp_path / "bad"
    bad.mkdir()
    for p in results.glob("*.pkl"):
        with open(bad / p.name, "wb") as f:
            pickle.dump({"pred_class_ids": [1]}, f, protocol=4)
    res = subprocess.run([str(tricons_bin), "replay", "--recording", str(scene), "--masks", f"results:{bad}", "--out",
                          str(tmp_path / "y.jsonl"), "--no-eval"], capture_output=True, text=True, cwd=REPO)
    assert res.returncode != 0 and "pred_scores" in res.stderr and ".pkl" in res.stderr, res.stderr


def test_mixed_training_on_a_layout_exports_and_replays(recording, layout, tricons_bin, tmp_path):
    """The paper's recipe in miniature: `train --data <tricons recording> --real <NOCS split>`
    (CAMERA + Real's 3:1 batches, here 1:1) with the real network for a few steps, export
    the checkpoint, and replay the NOCS scene with the exported graph."""
    from tricons_pose import export
    from tricons_pose import train as T

    root, scene = layout
    cfg = ModelConfig.shipped().replace(n_points=256, n_keypoints=8, crop_size=32, name="tiny")
    cfg_file = tmp_path / "tiny.json"
    cfg_file.write_text(cfg.to_json())
    run = tmp_path / "run"
    args = T.parse_args(["--data", str(recording), "--real", str(scene.parent), "--real-per-batch", "2",
                         "--config", str(cfg_file), "--out", str(run), "--batch-size", "4", "--max-steps", "2",
                         "--threads", "1", "--workers", "0", "--seed", "3"])
    summary = T.train(args)
    assert summary["step"] == 2
    assert export.main(["--checkpoint", str(run / "checkpoint.pt"), "--out", str(tmp_path / "m.onnx"),
                        "--no-check"]) == 0
    res = subprocess.run([str(tricons_bin), "replay", "--recording", str(scene), "--masks", "gt", "--model",
                          str(tmp_path / "m.onnx"), "--out", str(tmp_path / "r.jsonl")],
                         capture_output=True, text=True, cwd=REPO)
    assert res.returncode == 0, res.stderr
    lines = [json.loads(ln) for ln in (tmp_path / "r.jsonl").read_text().splitlines()]
    assert len(lines) == len(Recording(recording).frames) and sum(len(ln["instances"]) for ln in lines) > 0
    # the replay evaluated against the layout's own ground truth
    assert (tmp_path / "r.eval.json").exists()


@pytest.fixture(scope="module")
def camera_layout(recording, tmp_path_factory):
    """The recording declared with CAMERA25's intrinsics (its frames stay SynthNOCS's: what
    is tested is the layout, not the geometry), written as CAMERA25's val split."""
    import shutil

    rec = tmp_path_factory.mktemp("camrec") / "rec"
    shutil.copytree(recording, rec)
    manifest = json.loads((rec / "manifest.json").read_text())
    manifest["intrinsics"].update({"fx": 577.5, "fy": 577.5, "cx": 319.5, "cy": 239.5})
    (rec / "manifest.json").write_text(json.dumps(manifest))
    root = tmp_path_factory.mktemp("nocs-camera") / "NOCS"
    split_dir = write_nocs_layout(rec, root, split="camera_val")
    return rec, root, split_dir


def test_a_camera_split_is_written_and_read_as_camera25_is(camera_layout):
    from PIL import Image

    from tricons_pose.nocs_layout import CAMERA25, SYNSETS

    rec_dir, root, split_dir = camera_layout
    rec = Recording(rec_dir)
    assert split_dir == root / "CAMERA" / "val"
    # ten frames a folder, NNNN names; the composed depth in camera_full_depths/
    assert sorted(p.relative_to(split_dir).as_posix() for p in split_dir.glob("*/*_color.png")) == \
        [f"00000/{k:04d}_color.png" for k in range(len(rec))]
    scene = split_dir / "00000"
    layout = open_any(split_dir)
    assert len(layout) == 1 and layout[0].intrinsics == CAMERA25
    got = layout[0]
    for k in range(len(rec)):
        ann = rec.annotations(k)
        label = rec.mask(k, ann)
        composed = root / "camera_full_depths" / "val" / "00000" / f"{k:04d}_composed.png"
        assert got.frames[k].depth == str(composed)
        # the reader takes the composed depth, which is the recording's whole depth ...
        np.testing.assert_array_equal(got.depth_m(k), rec.depth_m(k))
        # ... not _depth.png, which holds the objects only
        objects_only = np.asarray(Image.open(scene / f"{k:04d}_depth.png")).astype(np.int64)
        assert not objects_only[label == 0].any() and (objects_only[label > 0] > 0).any()
        meta = [ln.split() for ln in (scene / f"{k:04d}_meta.txt").read_text().splitlines()]
        assert [(int(a), int(b), c) for a, b, c, _ in meta] == \
            [(x.id, x.class_id + 1, SYNSETS[x.cls]) for x in ann.instances]
        mine = got.annotations(k)
        assert [x.id for x in mine.instances] == [x.id for x in ann.instances]
        for a, b in zip(mine.instances, ann.instances):
            assert a.cls == b.cls
            np.testing.assert_allclose(a.R, b.R, atol=1e-6)
            np.testing.assert_allclose(a.t, b.t, atol=1e-6)
            np.testing.assert_allclose(a.s, b.s, rtol=1e-5)
        np.testing.assert_array_equal(got.mask(k, mine), label)
        assert (root / "gts" / "val" / f"results_val_00000_{k:04d}.pkl").exists()
    # a pixel of 32001 in a composed file is no depth (SPD / AG-Pose), and a CAMERA frame
    # without its composed file is an error naming it, not a silent read of _depth.png
    composed = root / "camera_full_depths" / "val" / "00000" / "0000_composed.png"
    arr = np.asarray(Image.open(composed)).copy()
    keep = arr.copy()
    arr[0, 0] = (32001 & 0xFF, 32001 >> 8, 0)
    Image.fromarray(arr).save(composed)
    assert got.depth_raw(0)[0, 0] == 0
    Image.fromarray(keep).save(composed)
    lonely = root / "lonely" / "CAMERA" / "val" / "00000"
    lonely.mkdir(parents=True)
    for p in scene.glob("0000_*"):
        (lonely / p.name).write_bytes(p.read_bytes())
    with pytest.raises(RecordingError, match="_composed.png"):
        NocsLayoutRecording(lonely).depth_raw(0)


def test_lowercase_group_folders_are_the_same_split(camera_layout, tmp_path):
    """DualPoseNet / AG-Pose keep the data as camera/ and real/: the split, its intrinsics
    and its object models are found the same way."""
    import shutil

    from tricons_pose.nocs_layout import CAMERA25

    _, root, _ = camera_layout
    lower = tmp_path / "data"
    shutil.copytree(root / "CAMERA", lower / "camera")
    shutil.copytree(root / "camera_full_depths", lower / "camera_full_depths")
    shutil.copytree(root / "obj_models", lower / "obj_models")
    a, b = NocsLayoutRecording(root / "CAMERA" / "val" / "00000"), NocsLayoutRecording(lower / "camera" / "val" / "00000")
    assert b.intrinsics == CAMERA25
    np.testing.assert_array_equal(a.depth_raw(1), b.depth_raw(1))
    assert [x.s.tolist() for x in a.annotations(1).instances] == [x.s.tolist() for x in b.annotations(1).instances]
