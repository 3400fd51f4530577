"""ONNX export of the whole network, the shipped model and its card, and the golden fixtures."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch

from conftest import REPO
from tricons_pose import export
from tricons_pose.onnx_export_ops import NODE_SIGNATURES, run_node
from tricons_pose import ops_reference as ref
from tricons_pose.config import ModelConfig
from tricons_pose.data import InstanceDataset, backproject, normalise_rgb, remap_choose, resize_bilinear

MODELS = REPO / "models"
SHIPPED_ONNX = MODELS / "tricons-pose.onnx"
SHIPPED_CARD = MODELS / "tricons-pose.card.json"
FIXTURES = REPO / "tests" / "fixtures"
DEMO = REPO / "tests" / "data" / "synthnocs-demo"


def tiny_config(**kw) -> ModelConfig:
    """Shipped sizes cut down further so an export + reference evaluation takes seconds."""
    return ModelConfig.shipped().replace(name="tiny", n_points=128, n_keypoints=12, pn2_npoints=(64, 32, 8), **kw)


@pytest.fixture(scope="module")
def tiny_export():
    cfg = tiny_config()
    model = export.random_model(cfg, seed=3)
    return cfg, model, export.to_onnx_bytes(model, cfg)


def _dims(vi) -> list:
    return [d.dim_param or d.dim_value for d in vi.type.tensor_type.shape.dim]


def test_graph_io_opset_and_custom_nodes(tiny_export):
    cfg, _, data = tiny_export
    proto = onnx.load_from_string(data)
    onnx.checker.check_model(proto)
    assert {o.domain: o.version for o in proto.opset_import} == {"": 17, "ai.tricons": 1}
    assert [i.name for i in proto.graph.input] == ["rgb", "pts", "choose"]
    assert [o.name for o in proto.graph.output] == ["R", "t", "s", "kpt_3d", "kpt_nocs"]
    ins = {i.name: _dims(i) for i in proto.graph.input}
    assert ins == {"rgb": ["batch", 3, cfg.crop_size, cfg.crop_size], "pts": ["batch", cfg.n_points, 3],
                   "choose": ["batch", cfg.n_points]}
    outs = {o.name: _dims(o) for o in proto.graph.output}
    assert outs["R"] == ["batch", 3, 3] and outs["kpt_3d"] == ["batch", cfg.n_keypoints, 3]
    counts = export.custom_node_counts(data)
    # every PointNet++ level samples (FPS + gather) and groups; the FP levels interpolate; PIGA uses the descriptor
    L = len(cfg.pn2_npoints)
    assert counts["FurthestPointSample"] == L and counts["ThreeNN"] == L
    assert counts["TriangleDescriptor"] == cfg.blocks
    assert set(counts) == set(ops_names()), counts


def ops_names():
    return sorted(NODE_SIGNATURES)


@pytest.mark.parametrize("batch,seed", [(1, 11), (3, 12)])
def test_reference_evaluation_matches_pytorch_at_other_batch_sizes(tiny_export, batch, seed):
    cfg, model, data = tiny_export
    x = export.example_inputs(cfg, batch, seed)
    with torch.no_grad():
        want = model(x)
    got = export.reference_run(data, x)
    assert export.rotation_angle_deg(got["R"], want["R"].numpy()).max() < 1e-3
    for k in ("t", "s", "kpt_3d", "kpt_nocs"):
        np.testing.assert_allclose(got[k], want[k].numpy(), atol=2e-5, err_msg=k)


def test_ablation_without_piga_exports_without_the_descriptor():
    cfg = tiny_config().without_piga()
    data = export.to_onnx_bytes(export.random_model(cfg, 0), cfg)
    counts = export.custom_node_counts(data)
    assert "TriangleDescriptor" not in counts and counts["FurthestPointSample"] == len(cfg.pn2_npoints)


def _rodrigues(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * k + (1 - np.cos(angle_rad)) * (k @ k)


def test_rotation_angle_is_accurate_near_zero():
    rng = np.random.default_rng(0)
    axes = rng.standard_normal((4, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    for deg in (1e-3, 0.05, 3.0, 120.0):
        Rb = np.stack([_rodrigues(a, np.radians(deg)) for a in axes])
        Ra = np.repeat(np.eye(3)[None], 4, 0)
        np.testing.assert_allclose(export.rotation_angle_deg(Ra, Rb), deg, rtol=1e-6)


def test_cli_random_init_writes_onnx_and_card(tmp_path, monkeypatch):
    cfg = tiny_config()
    cfg_file = tmp_path / "tiny.json"
    cfg_file.write_text(cfg.to_json())
    metrics = tmp_path / "m.json"
    metrics.write_text(json.dumps({"mean": {"5deg2cm": 12.5}}))
    out = tmp_path / "sub" / "m.onnx"
    assert export.main(["--config", str(cfg_file), "--random-init", "5", "--out", str(out),
                        "--metrics", f"published={metrics}", "--consistency-score-scale", "0.3", "--min-score", "0.6",
                        "--rotation-from-keypoints", "bowl", "--rotation-keypoint-blend", "mug=0.5,camera=0.25"]) == 0
    card = json.loads((tmp_path / "sub" / "m.card.json").read_text())
    assert card["consistency_score_scale"] == 0.3 and card["min_score"] == 0.6
    assert card["rotation_from_keypoints"] == ["bowl"]
    assert card["rotation_keypoint_blend"] == {"camera": 0.25, "mug": 0.5}
    data = out.read_bytes()
    assert card["onnx"]["sha256"] == hashlib.sha256(data).hexdigest() and card["onnx"]["bytes"] == len(data)
    assert card["weights"] == {"kind": "random", "seed": 5}
    assert card["metrics"]["published"]["mean"]["5deg2cm"] == 12.5
    assert card["preprocessing"]["n_points"] == cfg.n_points and card["preprocessing"]["crop_size"] == cfg.crop_size
    assert card["export_check"]["max_rotation_diff_deg"] < 1e-3
    assert ModelConfig.from_dict(card["config"]) == cfg
    assert not list((tmp_path / "sub").glob("*.tmp*"))


def test_cli_errors_are_clear(tmp_path, capsys):
    with pytest.raises(SystemExit):
        export.main(["--config", "shipped", "--out", str(tmp_path / "x.onnx")])
    assert "--random-init" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(SystemExit, match="bad.json"):
        export.main(["--config", "shipped", "--random-init", "0", "--out", str(tmp_path / "x.onnx"),
                     "--metrics", f"published={bad}"])
    assert not (tmp_path / "x.onnx").exists()
    with pytest.raises(SystemExit):
        export.main(["--config", "shipped", "--random-init", "0", "--out", str(tmp_path / "x.onnx"),
                     "--consistency-score-scale", "0"])
    assert "--consistency-score-scale" in capsys.readouterr().err
    assert not (tmp_path / "x.onnx").exists()
    for blend in ("mug=1", "cup=0.5", "mug"):
        with pytest.raises(SystemExit):
            export.main(["--config", "shipped", "--random-init", "0", "--out", str(tmp_path / "x.onnx"),
                         "--rotation-keypoint-blend", blend])
        assert "--rotation-keypoint-blend" in capsys.readouterr().err
    assert not (tmp_path / "x.onnx").exists()


# ------------------------------------------------------------------ shipped model and card


@pytest.fixture(scope="module")
def shipped():
    card = json.loads(SHIPPED_CARD.read_text(encoding="utf-8"))
    data = SHIPPED_ONNX.read_bytes()
    return card, data


def test_shipped_card_matches_its_graph(shipped):
    card, data = shipped
    assert card["format"] == "tricons-model-card" and card["version"] == 1
    assert card["onnx"]["sha256"] == hashlib.sha256(data).hexdigest()
    assert card["onnx"]["custom_nodes"] == export.custom_node_counts(data)
    cfg = ModelConfig.from_dict(card["config"])
    proto = onnx.load_from_string(data)
    ins = {i.name: _dims(i) for i in proto.graph.input}
    assert ins["pts"] == ["batch", cfg.n_points, 3] == [s for s in card["inputs"][1]["shape"]]
    assert ins["rgb"] == ["batch", 3, cfg.crop_size, cfg.crop_size]
    assert card["weights"]["kind"] == "trained"
    for mode in ("published", "corrected"):
        assert 0.0 <= card["metrics"][mode]["mean"]["IoU50"] <= 100.0


def _load_case(d: Path) -> tuple[dict, dict]:
    case = json.loads((d / "case.json").read_text(encoding="utf-8"))
    arrays = {e["name"]: np.load(d / e["file"]) for e in case["inputs"] + case["outputs"]}
    for e in case["inputs"] + case["outputs"]:
        assert list(arrays[e["name"]].shape) == e["shape"] and str(arrays[e["name"]].dtype) == e["dtype"]
    return case, arrays


def _net_cases():
    index = json.loads((FIXTURES / "pose_net" / "index.json").read_text(encoding="utf-8"))
    return index["cases"]


@pytest.mark.parametrize("name", _net_cases())
def test_shipped_onnx_reproduces_the_network_fixtures(shipped, name):
    card, data = shipped
    case, a = _load_case(FIXTURES / "pose_net" / name)
    assert case["onnx_sha256"] == card["onnx"]["sha256"], "fixtures are stale: regenerate them from the shipped model"
    x = {k: torch.from_numpy(a[k]) for k in ("rgb", "pts", "choose")}
    got = export.reference_run(data, x)
    assert export.rotation_angle_deg(got["R"], a["R"][None]).max() < 1e-3
    for k in ("t", "s", "kpt_3d"):
        np.testing.assert_allclose(got[k][0], a[k], atol=1e-5, err_msg=k)
    np.testing.assert_allclose(got["kpt_nocs"][0], a["kpt_nocs"], atol=1e-5)
    # a proper rotation and a positive size
    R = a["R"].astype(np.float64)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-5)
    assert np.linalg.det(R) > 0.99 and (a["s"] > 0).all()


@pytest.mark.parametrize("name", _net_cases())
def test_network_fixture_inputs_are_the_training_preprocessing_of_the_demo_frames(name):
    case, a = _load_case(FIXTURES / "pose_net" / name)
    cfg = ModelConfig.from_dict(json.loads(SHIPPED_CARD.read_text(encoding="utf-8"))["config"])
    ds = InstanceDataset([REPO / case["recording"]], n_points=cfg.n_points, crop_size=cfg.crop_size, augment=None)
    hits = [i for i, r in enumerate(ds.index)
            if ds.recordings[0].frames[r.frame].id == case["frame"] and ds._anns[(r.rec, r.frame)][r.pos].id == case["instance_id"]]
    assert len(hits) == 1
    prep = ds.prepared(hits[0])
    assert list(prep.window) == case["window"] and prep.n_valid == case["n_valid"]
    idx = a["sample_idx"]
    assert idx.min() >= 0 and idx.max() < prep.n_valid
    choose = prep.choose_all[idx]
    pts = backproject(choose, prep.depth_all[idx], prep.window, prep.intrinsics, prep.depth_scale_m)
    assert np.array_equal(pts, a["pts"][0])
    assert np.array_equal(remap_choose(choose, prep.side, cfg.crop_size), a["choose"][0])
    assert np.array_equal(normalise_rgb(resize_bilinear(prep.rgb_crop, cfg.crop_size)), a["rgb"][0])


# ------------------------------------------------------------------ op fixtures

OP_CASES = sorted(p.name for p in (FIXTURES / "pose_ops").iterdir() if (p / "case.json").exists())


def test_every_op_has_fixtures():
    ops_covered = {json.loads((FIXTURES / "pose_ops" / c / "case.json").read_text())["op"] for c in OP_CASES}
    assert ops_covered == set(ops_names())


@pytest.mark.parametrize("name", OP_CASES)
def test_op_fixtures_match_the_torch_ops(name):
    case, a = _load_case(FIXTURES / "pose_ops" / name)
    inputs = {e["name"]: a[e["name"]] for e in case["inputs"]}
    got = run_node(case["op"], inputs, case["attributes"], "torch")
    for e in case["outputs"]:
        g, w = got[e["name"]], a[e["name"]]
        if w.dtype.kind == "i":
            assert np.array_equal(g, w), e["name"]
        else:
            np.testing.assert_allclose(g, w, rtol=1e-5, atol=1e-6, err_msg=e["name"])


def test_fixture_edge_cases_are_what_they_claim():
    _, a = _load_case(FIXTURES / "pose_ops" / "ball_query_mixed")
    assert (a["idx"][:, 10:] == 0).all()          # centres far from the cloud: no hit -> zeros
    padded = [(row == row[0]).sum() > 1 for row in a["idx"][:, :10].reshape(-1, 16)]
    assert any(padded)                              # some balls have fewer than nsample hits
    _, a = _load_case(FIXTURES / "pose_ops" / "fps_duplicates")
    assert len(set(a["idx"][0].tolist())) < 10     # ran out of distinct points
    _, a = _load_case(FIXTURES / "pose_ops" / "triangle_coincident_k16")
    assert np.isfinite(a["phi"]).all()
    phi, _ = ref.triangle_descriptor(a["query"], a["points"], 16)
    np.testing.assert_allclose(phi, a["phi"], rtol=1e-5, atol=1e-6)


def test_card_weights_name_the_checkpoints_an_average_came_from():
    model = {"w": torch.zeros(2)}
    ck = {"model": model, "step": 3000, "epoch": 1, "batchnorm": "averaged running statistics",
          "averaged_from": ["../models/checkpoints/tricons-pose-e12/model-step3000.pt", "/x/e13/model-step3000.pt"]}
    w = export._weights_from_checkpoint(ck, "runs/swa.pt", "note")
    assert w["averaged_from"] == ["tricons-pose-e12/model-step3000.pt", "e13/model-step3000.pt"]
    assert w["batchnorm"] == "averaged running statistics" and w["checkpoint"] == "swa.pt" and w["step"] == 3000
    assert "averaged_from" not in export._weights_from_checkpoint({"model": model}, "m.pt", None)
