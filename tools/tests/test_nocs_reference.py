"""The NOCS authors' own code reads what tricons writes in the NOCS layout (issue 19).

Runs only where a checkout of https://github.com/hughw19/NOCS_CVPR2019 is named by the
environment variable ``NOCS_CVPR2019`` (nothing of it is copied into this project; its
functions are read from the checkout with ``ast``, as tools/golden/make_nocs_metric_fixtures.py
does) and OpenCV is installed (the loader reads every image with ``cv2.imread``):

    pip install opencv-python-headless==4.14.0.94
    NOCS_CVPR2019=PATH/NOCS_CVPR2019 tools/pytest.sh tests/test_nocs_reference.py

What it checks, on a SynthNOCS recording written as REAL275's test split (and, for the
loader, as CAMERA25's val split: ten frames a folder, four-word meta lines, ``bbox.txt``):

* ``NOCSDataset.load_real_scenes``, ``load_image``, ``load_depth`` and ``load_mask`` (with
  ``process_data``) of the checkout's dataset.py find every frame and give back its
  colour, depth in millimetres, each instance's class id, mask, NOCS coordinates (within
  the 8-bit quantisation) and normalised box size;
* the ground-truth pose pickles (``gts/``), loaded with ``pickle`` as AG-Pose's and SPD's
  evaluations load them, completed with predictions and scored by the checkout's
  ``compute_degree_cm_mAP`` (utils.py), give the APs ``tricons eval`` gives on the
  recording for the same predictions.
"""

from __future__ import annotations

import ast
import glob
import importlib.util
import json
import os
import pickle
import subprocess
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO
from tricons_pose.nocs_layout import write_nocs_layout
from tricons_pose.recording import CLASSES, Recording

CHECKOUT = os.environ.get("NOCS_CVPR2019")
pytestmark = pytest.mark.skipif(not CHECKOUT, reason="NOCS_CVPR2019 (a checkout of hughw19/NOCS_CVPR2019) not set")


def _golden():
    """tools/golden/make_nocs_metric_fixtures.py as a module (its reference loader and
    tricons -> reference conversion)."""
    path = REPO / "tools" / "golden" / "make_nocs_metric_fixtures.py"
    spec = importlib.util.spec_from_file_location("make_nocs_metric_fixtures", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


class _Config:
    """The fields of the checkout's ``Config`` the loader reads."""

    def __init__(self, obj_model_dir: Path):
        self.OBJ_MODEL_DIR = str(obj_model_dir)
        self.IMAGE_MAX_DIM = 640
        self.IMAGE_MIN_DIM = 480


class _DatasetBase:
    """What ``NOCSDataset`` uses of Mask R-CNN's ``utils.Dataset``: ``add_image`` appends
    the image's dict to ``image_info``."""

    def __init__(self, subset: str, config: _Config):
        self.subset, self.config = subset, config
        self.image_info: list[dict] = []
        self.source_image_ids: dict = {}

    def add_image(self, source, image_id, path, **kwargs):
        self.image_info.append({"id": image_id, "source": source, "path": path, **kwargs})


def _nocs_dataset_class():
    """The checkout's ``NOCSDataset`` loader methods on :class:`_DatasetBase`."""
    import cv2

    path = Path(CHECKOUT) / "dataset.py"
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "NOCSDataset")
    wanted = ("load_real_scenes", "load_camera_scenes", "load_image", "load_depth", "process_data", "load_mask")
    methods = {n.name: n for n in cls.body if isinstance(n, ast.FunctionDef)}
    missing = [m for m in wanted if m not in methods]
    assert not missing, f"{path}: NOCSDataset lacks {missing}"
    namespace = {"np": np, "cv2": cv2, "os": os, "glob": glob, "__name__": "nocs_dataset"}
    exec(compile(ast.Module(body=[methods[m] for m in wanted], type_ignores=[]), str(path), "exec"), namespace)
    return type("NOCSDataset", (_DatasetBase,), {m: namespace[m] for m in wanted})


@pytest.fixture(scope="module")
def layout(recording, tmp_path_factory):
    pytest.importorskip("cv2")
    root = tmp_path_factory.mktemp("nocs-ref") / "NOCS"
    write_nocs_layout(recording, root, split="real_test", scene="scene_1")
    return root


def test_the_nocs_loader_reads_every_frame_as_recorded(recording, layout):
    rec = Recording(recording)
    ds = _nocs_dataset_class()("test", _Config(layout / "obj_models"))
    ds.load_real_scenes(str(layout / "Real"))
    assert [Path(i["path"]).name for i in ds.image_info] == [f.id for f in rec.frames]
    for k, info in enumerate(ds.image_info):
        ann = rec.annotations(k)
        np.testing.assert_array_equal(ds.load_image(k), rec.color(k))
        depth_mm = np.rint(rec.depth_raw(k).astype(np.float64) * rec.depth_scale_m / 0.001)
        np.testing.assert_array_equal(ds.load_depth(k), np.clip(depth_mm, 0, 65535).astype(np.uint16))
        masks, coords, class_ids, scales, domain = ds.load_mask(k)
        label, nocs = rec.mask(k, ann), rec.nocs(k, ann)
        want = [g for g in ann.instances if (label == g.id).any()]
        assert domain == 0
        assert class_ids.tolist() == [CLASSES.index(g.cls) + 1 for g in want], f"frame {info['path']}"
        for i, g in enumerate(want):
            inside = label == g.id
            np.testing.assert_array_equal(masks[:, :, i].astype(bool), inside)
            # 8-bit coordinates: within half a step of the recording's NOCS map
            assert np.abs(coords[:, :, i][inside] - nocs[inside]).max() <= 0.5 / 255 + 1e-6
            assert not coords[:, :, i][~inside].any()
            s = np.asarray(g.s, dtype=np.float64)
            np.testing.assert_allclose(scales[i], s / np.linalg.norm(s), rtol=1e-6)


def test_the_nocs_loader_reads_a_camera_split_as_recorded(recording, tmp_path):
    pytest.importorskip("cv2")
    import shutil

    src = tmp_path / "rec"
    shutil.copytree(recording, src)
    manifest = json.loads((src / "manifest.json").read_text())
    manifest["intrinsics"].update({"fx": 577.5, "fy": 577.5, "cx": 319.5, "cy": 239.5})  # CAMERA25's
    (src / "manifest.json").write_text(json.dumps(manifest))
    root = tmp_path / "NOCS"
    write_nocs_layout(src, root, split="camera_val")
    rec = Recording(src)
    ds = _nocs_dataset_class()("val", _Config(root / "obj_models"))
    ds.load_camera_scenes(str(root / "CAMERA"))
    assert [Path(i["path"]).relative_to(root / "CAMERA" / "val").as_posix() for i in ds.image_info] == \
        [f"00000/{k:04d}" for k in range(len(rec))]
    for k in range(len(rec)):
        ann = rec.annotations(k)
        label, nocs = rec.mask(k, ann), rec.nocs(k, ann)
        np.testing.assert_array_equal(ds.load_image(k), rec.color(k))
        # CAMERA's _depth.png: the rendered objects only (the whole depth is the composed file)
        depth_mm = np.clip(np.rint(rec.depth_raw(k).astype(np.float64) * rec.depth_scale_m / 0.001), 0, 65535)
        np.testing.assert_array_equal(ds.load_depth(k), np.where(label > 0, depth_mm, 0).astype(np.uint16))
        masks, coords, class_ids, scales, domain = ds.load_mask(k)
        want = [g for g in ann.instances if (label == g.id).any()]
        assert class_ids.tolist() == [CLASSES.index(g.cls) + 1 for g in want]
        for i, g in enumerate(want):
            inside = label == g.id
            np.testing.assert_array_equal(masks[:, :, i].astype(bool), inside)
            assert np.abs(coords[:, :, i][inside] - nocs[inside]).max() <= 0.5 / 255 + 1e-6
            # CAMERA's scale is bbox.txt's corner difference, not normalised
            s = np.asarray(g.s, dtype=np.float64)
            np.testing.assert_allclose(scales[i], s / np.linalg.norm(s), rtol=1e-6)


def test_the_pose_pickles_score_as_tricons_eval_scores_the_recording(recording, layout, tricons_bin, tmp_path):
    golden = _golden()
    ns = golden.load_functions(str(Path(CHECKOUT) / "utils.py"), golden.NOCS_FUNCTIONS)
    rec = Recording(recording)
    rng = np.random.default_rng(19)
    frames_pred, results = [], []
    for k, fr in enumerate(rec.frames):
        with open(layout / "gts" / "real_test" / f"results_real_test_scene_1_{fr.id}.pkl", "rb") as f:
            result = pickle.load(f)
        preds = []
        for cid, rt, scale in zip(result["gt_class_ids"], result["gt_RTs"], result["gt_scales"]):
            diag = np.cbrt(np.linalg.det(rt[:3, :3]))
            angle = np.deg2rad(rng.uniform(0.0, 12.0))
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
            dR = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
            R = dR @ (rt[:3, :3] / diag)
            t = rt[:3, 3] + rng.normal(scale=0.02, size=3)
            s = scale * diag * rng.uniform(0.9, 1.1)
            preds.append({"class": CLASSES[int(cid) - 1], "score": float(rng.uniform(0.3, 1.0)),
                          "R": R.tolist(), "t": t.tolist(), "s": s.tolist()})
        frames_pred.append({"frame": fr.id, "timestamp_s": fr.timestamp_s, "instances": preds})
        ref = golden.to_reference_frame({"gt": [], "pred": preds})
        result.update({k2: v for k2, v in ref.items() if k2.startswith("pred_")})
        results.append(result)
    pred_path = tmp_path / "pred.jsonl"
    pred_path.write_text("".join(json.dumps(f) + "\n" for f in frames_pred), encoding="utf-8")
    report = tmp_path / "eval.json"
    res = subprocess.run([str(tricons_bin), "eval", "--gt", str(recording), "--pred", str(pred_path), "--iou",
                          "published", "--json", str(report)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    ours = {c["class"]: c["ap"] for c in json.loads(report.read_text())["classes"]}
    reference, _ = golden.run_reference_results(ns, results)
    compared = 0
    for cls, row in reference.items():
        if cls not in ours or ours[cls] is None:
            continue
        for metric, value in row.items():
            if ours[cls].get(metric) is None or np.isnan(value):
                continue
            assert abs(ours[cls][metric] - 100.0 * value) <= 1e-4, (cls, metric, ours[cls][metric], 100.0 * value)
            compared += 1
    assert compared >= 20
