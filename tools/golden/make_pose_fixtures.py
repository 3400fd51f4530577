"""Golden fixtures of the TriCons-Pose model side for the Rust runtime (tests/fixtures, tests/data).

Three parts, each deterministic (run from the repository root with tools/ on PYTHONPATH)::

    # a small demo recording: frames 0, 2, 3, 5 of SynthNOCS-test (all six categories), no NOCS maps
    python tools/golden/make_pose_fixtures.py demo --test-split data/synthnocs-test --out tests/data/synthnocs-demo
    # inputs and outputs of every ai.tricons op on a few cases (PyTorch ops, checked against the numpy references)
    python tools/golden/make_pose_fixtures.py ops --out tests/fixtures/pose_ops
    # the whole network on real demo instances: pre-processed inputs, keypoints, R, t, s
    python tools/golden/make_pose_fixtures.py net --checkpoint data/runs/shipped/model.pt \\
        --onnx models/tricons-pose.onnx --recording tests/data/synthnocs-demo --out tests/fixtures/pose_net

Layout (docs/formats.md, "Golden fixtures"): one directory per case holding
``case.json`` and one ``.npy`` file (little-endian, C order) per tensor;
``case.json`` names the op or model, its attributes, the input and output files in
order, and the comparison tolerances.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tricons_pose.onnx_export_ops import run_node  # noqa: E402
from tricons_pose.data import InstanceDataset, backproject, normalise_rgb, remap_choose, resize_bilinear  # noqa: E402
from tricons_pose.predict import keypoint_rotation  # noqa: E402

DEMO_FRAMES = (0, 2, 3, 5)
FORMAT = "tricons-fixture"
VERSION = 1


def _save_case(root: Path, name: str, meta: dict, inputs: dict, outputs: dict) -> None:
    d = root / name
    if d.exists():
        shutil.rmtree(d)
    d.mkdir(parents=True)
    for k, v in {**inputs, **outputs}.items():
        np.save(d / f"{k}.npy", np.ascontiguousarray(v))
    case = {"format": FORMAT, "version": VERSION, **meta,
            "inputs": [{"name": k, "file": f"{k}.npy", "dtype": str(v.dtype), "shape": list(v.shape)}
                       for k, v in inputs.items()],
            "outputs": [{"name": k, "file": f"{k}.npy", "dtype": str(v.dtype), "shape": list(v.shape)}
                        for k, v in outputs.items()]}
    (d / "case.json").write_text(json.dumps(case, indent=2) + "\n", encoding="utf-8")


# --------------------------------------------------------------------------- demo


def make_demo(test_split: Path, out: Path, frames=DEMO_FRAMES) -> None:
    """Copy frames of SynthNOCS-test into a small recording (colour, depth, mask, gt; NOCS maps dropped)."""
    man = json.loads((test_split / "manifest.json").read_text(encoding="utf-8"))
    if "seed=20250003" not in (man.get("source") or ""):
        raise SystemExit(f"{test_split} is not SynthNOCS-test (source {man.get('source')!r})")
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    entries = []
    for fi in frames:
        e = man["frames"][fi]
        for key in ("color", "depth"):
            shutil.copy2(test_split / e[key], out / e[key])
        gt = json.loads((test_split / e["annotations"]).read_text(encoding="utf-8"))
        shutil.copy2(test_split / gt["mask"], out / gt["mask"])
        gt.pop("nocs", None)
        (out / e["annotations"]).write_text(json.dumps(gt, indent=2) + "\n", encoding="utf-8")
        entries.append(e)
    man["frames"] = entries
    man["source"] = man["source"] + " frames " + ",".join(str(f) for f in frames) + " (tricons demo subset)"
    (out / "manifest.json").write_text(json.dumps(man, indent=2) + "\n", encoding="utf-8")
    print(f"{len(entries)} frames -> {out}")


# ---------------------------------------------------------------------------- ops


def _cloud(rng, b, n, scale=0.1):
    return (rng.standard_normal((b, n, 3)) * scale).astype(np.float32)


def make_ops(out: Path) -> None:
    """Op cases: random clouds, duplicates and ties, empty balls, coincident triangle points."""
    rng = np.random.default_rng(20251122)
    tol_f = {"rel": 1e-5, "abs": 1e-6}
    cases = []

    # FurthestPointSample
    xyz = _cloud(rng, 2, 200)
    cases.append(("fps_random", "FurthestPointSample", {"npoint": 32}, {"xyz": xyz}))
    dup = np.repeat(_cloud(rng, 1, 6), 4, axis=1)  # 6 distinct points, each 4 times: FPS runs out of new points
    cases.append(("fps_duplicates", "FurthestPointSample", {"npoint": 10}, {"xyz": dup}))
    # GatherPoints
    feats, gidx = rng.standard_normal((2, 5, 40)).astype(np.float32), rng.integers(0, 40, (2, 12))
    cases.append(("gather_random", "GatherPoints", {}, {"features": feats, "idx": gidx}))
    # BallQuery: some centres far away (no hit -> zeros), some with fewer hits than nsample (padding)
    xyz = _cloud(rng, 2, 150)
    centres = np.concatenate([xyz[:, :10], _cloud(rng, 2, 4, 0.3) + np.float32(1.0)], axis=1)
    cases.append(("ball_query_mixed", "BallQuery", {"radius": 0.08, "nsample": 16}, {"xyz": xyz, "new_xyz": centres}))
    # GroupPoints
    feats, kidx = rng.standard_normal((2, 4, 30)).astype(np.float32), rng.integers(0, 30, (2, 7, 5))
    cases.append(("group_random", "GroupPoints", {}, {"features": feats, "idx": kidx}))
    # ThreeNN / ThreeInterpolate
    unknown, known = _cloud(rng, 2, 50), _cloud(rng, 2, 12)
    cases.append(("three_nn_random", "ThreeNN", {}, {"unknown": unknown, "known": known}))
    feats = rng.standard_normal((2, 6, 12)).astype(np.float32)
    tidx = rng.integers(0, 12, (2, 50, 3))
    w = rng.random((2, 50, 3)).astype(np.float32)
    w /= w.sum(-1, keepdims=True)
    cases.append(("three_interpolate_random", "ThreeInterpolate", {}, {"features": feats, "idx": tidx, "weight": w}))
    # TriangleDescriptor
    pts = _cloud(rng, 2, 128)
    query = pts[:, ::8][:, :12] + _cloud(rng, 2, 12, 0.01)
    cases.append(("triangle_random_k8", "TriangleDescriptor", {"k": 8}, {"query": query, "points": pts}))
    pts = _cloud(rng, 1, 64)
    pts[0, 5] = pts[0, 9]  # coincident points
    query = pts[:, [5, 20, 33]].copy()  # queries equal to points (kept as their own neighbours)
    cases.append(("triangle_coincident_k16", "TriangleDescriptor", {"k": 16}, {"query": query, "points": pts}))

    out.mkdir(parents=True, exist_ok=True)
    for name, op, attrs, inputs in cases:
        inputs = {k: (v.astype(np.int64) if v.dtype.kind == "i" else v) for k, v in inputs.items()}
        got = run_node(op, inputs, attrs, "torch")
        want = run_node(op, inputs, attrs, "reference")
        for k, v in got.items():
            if v.dtype.kind == "i":
                assert np.array_equal(v, want[k]), f"{name}.{k}: torch op != numpy reference"
            else:
                np.testing.assert_allclose(v, want[k], rtol=1e-5, atol=1e-6, err_msg=f"{name}.{k}")
        _save_case(out, name, {"kind": "op", "domain": "ai.tricons", "op": op, "attributes": attrs,
                               "tolerance": {"float": tol_f, "int": "exact"}}, inputs, got)
    print(f"{len(cases)} op cases -> {out}")


# ---------------------------------------------------------------------------- net


def make_net(checkpoint: Path, onnx_path: Path, recording: Path, out: Path, per_class: int = 1, seed: int = 0) -> None:
    """Whole-network cases on demo instances: one per category (first in frame order), plus the batch of all."""
    from tricons_pose.export import load_checkpoint

    model, cfg, _ = load_checkpoint(checkpoint)
    onnx_sha = hashlib.sha256(onnx_path.read_bytes()).hexdigest()
    ds = InstanceDataset([recording], n_points=cfg.n_points, crop_size=cfg.crop_size, seed=seed, augment=None)
    rec = ds.recordings[0]
    seen: dict[str, int] = {}
    picked = []
    for i in range(len(ds)):
        r = ds.index[i]
        inst = ds._anns[(r.rec, r.frame)][r.pos]
        prep = ds.prepared(i)
        if prep is None or prep.n_valid <= 16 or seen.get(inst.cls, 0) >= per_class:
            continue
        seen[inst.cls] = seen.get(inst.cls, 0) + 1
        picked.append((i, r, inst, prep))
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    names = []
    for i, r, inst, prep in picked:
        rng = np.random.default_rng((seed, 0, i))
        sample_idx = rng.choice(prep.n_valid, cfg.n_points, replace=prep.n_valid < cfg.n_points).astype(np.int64)
        choose = prep.choose_all[sample_idx]
        pts = backproject(choose, prep.depth_all[sample_idx], prep.window, prep.intrinsics, prep.depth_scale_m)
        rgb = normalise_rgb(resize_bilinear(prep.rgb_crop, cfg.crop_size))
        choose_s = remap_choose(choose, prep.side, cfg.crop_size).astype(np.int64)
        x = {"rgb": torch.from_numpy(rgb)[None], "pts": torch.from_numpy(pts)[None],
             "choose": torch.from_numpy(choose_s)[None]}
        with torch.no_grad():
            y = {k: v[0].numpy() for k, v in model(x).items()}
        frame = rec.frames[r.frame]
        name = f"{frame.id}_inst{inst.id}_{inst.cls}"
        meta = {"kind": "network", "model": "TriCons-Pose", "config_name": cfg.name, "onnx_sha256": onnx_sha,
                "recording": str(recording), "frame": frame.id, "instance_id": int(inst.id), "class": inst.cls,
                "window": [int(v) for v in prep.window], "n_valid": prep.n_valid,
                "note": "inputs carry a batch axis of 1; sample_idx indexes the ascending valid-pixel list "
                        "(choose_all) of the instance's crop window",
                "tolerance": {"rotation_deg": 0.1, "t_m": 0.001, "s_m": 0.001, "keypoints_m": 0.001,
                              "inputs_float_abs": 1e-6}}
        outputs = {"R": y["R"], "t": y["t"], "s": y["s"], "kpt_3d": y["kpt_3d"], "kpt_nocs": y["kpt_nocs"],
                   # the rotation a card's rotation_from_keypoints reports (Umeyama in float64, stored as float32)
                   "R_kpt": keypoint_rotation(torch.from_numpy(y["kpt_nocs"])[None].double(),
                                              torch.from_numpy(y["kpt_3d"])[None].double())[0].float().numpy()}
        _save_case(out, name, meta, {"sample_idx": sample_idx, "rgb": x["rgb"].numpy(), "pts": x["pts"].numpy(),
                                     "choose": x["choose"].numpy()}, outputs)
        names.append(name)
    (out / "index.json").write_text(json.dumps({"format": FORMAT, "version": VERSION, "cases": names}, indent=2) + "\n",
                                    encoding="utf-8")
    print(f"{len(names)} network cases -> {out}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("demo")
    d.add_argument("--test-split", type=Path, required=True)
    d.add_argument("--out", type=Path, required=True)
    o = sub.add_parser("ops")
    o.add_argument("--out", type=Path, required=True)
    n = sub.add_parser("net")
    n.add_argument("--checkpoint", type=Path, required=True)
    n.add_argument("--onnx", type=Path, required=True)
    n.add_argument("--recording", type=Path, required=True)
    n.add_argument("--out", type=Path, required=True)
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    if a.cmd == "demo":
        make_demo(a.test_split, a.out)
    elif a.cmd == "ops":
        make_ops(a.out)
    else:
        make_net(a.checkpoint, a.onnx, a.recording, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
