"""Export TriCons-Pose to ONNX (opset 17, custom nodes in ``ai.tricons``) with a model card.

Trained weights (a ``model.pt`` or ``checkpoint.pt`` from :mod:`tricons_pose.train`)::

    python -m tricons_pose.export --checkpoint ../data/runs/shipped/model.pt \\
        --out ../models/tricons-pose.onnx \\
        --metrics published=../data/shipped-published.json --metrics corrected=../data/shipped-corrected.json

Random weights of a configuration (speed and memory work, e.g. the paper size)::

    python -m tricons_pose.export --config paper --random-init 0 --out ../data/models/tricons-pose-paper.onnx

The same network with standard ONNX ops in place of the ``ai.tricons`` nodes
(:mod:`ops_standard`; for onnxruntime, e.g. in the benchmark; checked against
PyTorch with onnxruntime instead of the reference evaluator)::

    python -m tricons_pose.export --checkpoint ../models/checkpoints/tricons-pose-v2/model-step6000.pt \
        --standard-ops --out ../data/models/tricons-pose-standard.onnx

Writes the ``.onnx`` file and ``<stem>.card.json`` beside it (both atomically:
temporary file, then rename). The graph takes a dynamic instance batch::

    rgb    float32 (batch, 3, crop, crop)  ImageNet-normalised crop (tools/README.md, Preprocessing)
    pts    float32 (batch, N, 3)           camera-frame points, metres
    choose int64   (batch, N)              row-major pixel index on the crop x crop grid

and returns ``R`` (batch, 3, 3) camera_from_object rotation, ``t`` (batch, 3)
metres, ``s`` (batch, 3) box size in metres, ``kpt_3d`` (batch, M, 3) keypoints in
the camera frame and ``kpt_nocs`` (batch, M, 3). Before writing, the export is
checked: ``onnx.checker`` and an evaluation of the graph by the onnx reference
evaluator (custom nodes through :func:`onnx_export_ops.reference_ops`) against
PyTorch on a seeded random batch; the differences go into the card.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import os
import platform
import warnings
from collections import Counter
from pathlib import Path
from typing import Dict, Sequence

import numpy as np
import torch
from torch import Tensor, nn

from .config import ModelConfig
from .data import CROP_STEP, IMAGENET_MEAN, IMAGENET_STD, MAX_CROP, MIN_VALID_PIXELS
from .model import TriConsPose
from .ops_standard import standard_ops
from .onnx_export_ops import CUSTOM_OPSETS, DOMAIN, DOMAIN_VERSION, OPSET, register_symbolics
from .recording import CLASSES

CARD_FORMAT = "tricons-model-card"
CARD_VERSION = 1
INPUT_NAMES = ("rgb", "pts", "choose")
OUTPUT_NAMES = ("R", "t", "s", "kpt_3d", "kpt_nocs")
BATCH_DIM = "batch"


class ExportWrapper(nn.Module):
    """Positional inputs/outputs around :class:`TriConsPose` for the exporter."""

    def __init__(self, model: TriConsPose):
        super().__init__()
        self.model = model

    def forward(self, rgb: Tensor, pts: Tensor, choose: Tensor):  # noqa: D102
        out = self.model({"rgb": rgb, "pts": pts, "choose": choose})
        return tuple(out[k] for k in OUTPUT_NAMES)


def load_checkpoint(path: str | os.PathLike) -> tuple[TriConsPose, ModelConfig, dict]:
    """Model (eval mode), config and the raw checkpoint dict of a ``model.pt`` / ``checkpoint.pt``."""
    ck = torch.load(path, map_location="cpu", weights_only=False)
    cfg = ModelConfig.from_dict(ck["config"])
    model = TriConsPose(cfg)
    model.load_state_dict(ck["model"])
    model.eval()
    return model, cfg, ck


def random_model(cfg: ModelConfig, seed: int) -> TriConsPose:
    """A model with seeded random initialisation (eval mode)."""
    torch.manual_seed(seed)
    model = TriConsPose(cfg)
    model.eval()
    return model


def example_inputs(cfg: ModelConfig, batch: int, seed: int) -> Dict[str, Tensor]:
    """A seeded, plausible input batch: an object-sized cloud 0.5-1 m away, random crop pixels."""
    g = torch.Generator().manual_seed(seed)
    centre = torch.tensor([0.0, 0.0, 0.7]) + 0.1 * (torch.rand(batch, 1, 3, generator=g) - 0.5)
    pts = centre + 0.08 * torch.randn(batch, cfg.n_points, 3, generator=g)
    rgb = torch.randn(batch, 3, cfg.crop_size, cfg.crop_size, generator=g)
    choose = torch.randint(0, cfg.crop_size * cfg.crop_size, (batch, cfg.n_points), generator=g)
    return {"rgb": rgb, "pts": pts.float(), "choose": choose}


def to_onnx_bytes(model: TriConsPose, cfg: ModelConfig, standard: bool = False) -> bytes:
    """The serialised ONNX model (TorchScript exporter, opset 17, dynamic batch).

    ``standard``: export inside :func:`ops_standard.standard_ops` (no ``ai.tricons`` nodes).
    """
    register_symbolics(OPSET)
    wrapper = ExportWrapper(model).eval()
    x = example_inputs(cfg, 2, 0)
    dyn = {name: {0: BATCH_DIM} for name in INPUT_NAMES + OUTPUT_NAMES}
    buf = io.BytesIO()
    swap = standard_ops() if standard else contextlib.nullcontext()
    with warnings.catch_warnings(), torch.no_grad(), swap:
        warnings.simplefilter("ignore")  # the TorchScript exporter is deprecated; it is the one with custom symbolics
        torch.onnx.export(wrapper, tuple(x[k] for k in INPUT_NAMES), buf, dynamo=False, opset_version=OPSET,
                          custom_opsets=None if standard else CUSTOM_OPSETS, input_names=list(INPUT_NAMES),
                          output_names=list(OUTPUT_NAMES), dynamic_axes=dyn, do_constant_folding=True)
    return _fix_output_shapes(buf.getvalue(), cfg)


def onnxruntime_run(onnx_bytes: bytes, inputs: Dict[str, Tensor]) -> Dict[str, np.ndarray]:
    """Evaluate a standard-op graph with onnxruntime (CPU)."""
    import onnxruntime as ort

    sess = ort.InferenceSession(onnx_bytes, providers=["CPUExecutionProvider"])
    outs = sess.run(list(OUTPUT_NAMES), {k: inputs[k].numpy() for k in INPUT_NAMES})
    return dict(zip(OUTPUT_NAMES, outs))


def _fix_output_shapes(onnx_bytes: bytes, cfg: ModelConfig) -> bytes:
    """Declare the outputs' static dims (the exporter leaves M symbolic after the custom nodes)."""
    import onnx

    proto = onnx.load_from_string(onnx_bytes)
    m = cfg.n_keypoints
    want = {"R": [3, 3], "t": [3], "s": [3], "kpt_3d": [m, 3], "kpt_nocs": [m, 3]}
    for out in proto.graph.output:
        shape = out.type.tensor_type.shape
        del shape.dim[:]
        shape.dim.add().dim_param = BATCH_DIM
        for d in want[out.name]:
            shape.dim.add().dim_value = d
    return proto.SerializeToString()


def reference_run(onnx_bytes: bytes, inputs: Dict[str, Tensor]) -> Dict[str, np.ndarray]:
    """Evaluate the graph with the onnx reference evaluator and the numpy custom ops."""
    import onnx
    from onnx.reference import ReferenceEvaluator

    from .onnx_export_ops import reference_ops

    proto = onnx.load_from_string(onnx_bytes)
    sess = ReferenceEvaluator(proto, new_ops=reference_ops())
    feeds = {k: inputs[k].numpy() for k in INPUT_NAMES}
    outs = sess.run(None, feeds)
    return dict(zip(OUTPUT_NAMES, outs))


def rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle of Ra^T Rb per batch item, degrees: 2 asin(|Ra - Rb|_F / sqrt(8)).

    Well conditioned near zero, unlike acos((trace - 1) / 2), which turns float32
    rounding (1e-7 in the trace) into a spurious 0.02 degrees.
    """
    d = np.linalg.norm((Ra.astype(np.float64) - Rb.astype(np.float64)).reshape(len(Ra), -1), axis=1)
    return np.degrees(2.0 * np.arcsin(np.clip(d / np.sqrt(8.0), 0.0, 1.0)))


def check_export(model: TriConsPose, cfg: ModelConfig, onnx_bytes: bytes, batch: int = 3, seed: int = 1,
                 standard: bool = False) -> dict:
    """Compare PyTorch and the reference evaluation of the graph on a seeded batch (batch != export batch);
    a ``standard`` graph is evaluated with onnxruntime."""
    import onnx

    onnx.checker.check_model(onnx.load_from_string(onnx_bytes))
    x = example_inputs(cfg, batch, seed)
    with torch.no_grad():
        ref = {k: v.numpy() for k, v in model(x).items()}
    got = onnxruntime_run(onnx_bytes, x) if standard else reference_run(onnx_bytes, x)
    diffs = {k: float(np.max(np.abs(got[k].astype(np.float64) - ref[k].astype(np.float64)))) for k in OUTPUT_NAMES}
    return {
        "batch": batch,
        "seed": seed,
        "evaluator": "onnxruntime" if standard else "onnx.reference + tricons_pose.ops_reference",
        "max_abs_diff": diffs,
        "max_rotation_diff_deg": float(rotation_angle_deg(got["R"], ref["R"]).max()),
    }


def custom_node_counts(onnx_bytes: bytes) -> Dict[str, int]:
    """How many nodes of each ``ai.tricons`` type the graph has."""
    import onnx

    proto = onnx.load_from_string(onnx_bytes)
    return dict(sorted(Counter(n.op_type for n in proto.graph.node if n.domain == DOMAIN).items()))


def standard_op_types(onnx_bytes: bytes) -> list[str]:
    """Sorted standard (default-domain) op types used by the graph."""
    import onnx

    proto = onnx.load_from_string(onnx_bytes)
    return sorted({n.op_type for n in proto.graph.node if n.domain in ("", "ai.onnx")})


def build_card(cfg: ModelConfig, onnx_name: str, onnx_bytes: bytes, weights: dict, check: dict | None,
               metrics: Dict[str, dict], n_params: int, rotation_from_keypoints: Sequence[str] = (),
               consistency_score_scale: float | None = None,
               rotation_keypoint_blend: Dict[str, float] | None = None,
               min_score: float | None = None) -> dict:
    """The model card (docs/formats.md, "Model card")."""
    from .predict import check_blend

    unknown = sorted(set(rotation_from_keypoints) - set(CLASSES))
    if unknown:
        raise ValueError(f"rotation_from_keypoints: unknown classes {unknown} (known: {CLASSES})")
    blend = dict(rotation_keypoint_blend or {})
    check_blend(blend, rotation_from_keypoints)
    if consistency_score_scale is not None and not (0 < consistency_score_scale < float("inf")):
        raise ValueError(f"consistency_score_scale: must be a positive number, found {consistency_score_scale}")
    if min_score is not None and not 0 <= min_score < 1:
        raise ValueError(f"min_score: must lie in [0, 1), found {min_score}")
    crop, n, m = cfg.crop_size, cfg.n_points, cfg.n_keypoints
    return {
        "format": CARD_FORMAT,
        "version": CARD_VERSION,
        "model": "TriCons-Pose",
        "config_name": cfg.name,
        "onnx": {
            "file": onnx_name,
            "sha256": hashlib.sha256(onnx_bytes).hexdigest(),
            "bytes": len(onnx_bytes),
            "opset": OPSET,
            "custom_domain": DOMAIN,
            "custom_domain_version": DOMAIN_VERSION,
            "custom_nodes": custom_node_counts(onnx_bytes),
            "standard_ops": standard_op_types(onnx_bytes),
        },
        "inputs": [
            {"name": "rgb", "dtype": "float32", "shape": [BATCH_DIM, 3, crop, crop],
             "meaning": "colour crop, bilinear-resized, (v/255 - mean)/std, channels RGB"},
            {"name": "pts", "dtype": "float32", "shape": [BATCH_DIM, n, 3],
             "meaning": "camera-frame points of the sampled valid pixels, metres"},
            {"name": "choose", "dtype": "int64", "shape": [BATCH_DIM, n],
             "meaning": "row-major index of each point's pixel on the crop x crop grid"},
        ],
        "outputs": [
            {"name": "R", "dtype": "float32", "shape": [BATCH_DIM, 3, 3], "meaning": "camera_from_object rotation"},
            {"name": "t", "dtype": "float32", "shape": [BATCH_DIM, 3], "meaning": "camera_from_object translation, metres"},
            {"name": "s", "dtype": "float32", "shape": [BATCH_DIM, 3], "meaning": "box size (x, y, z), metres"},
            {"name": "kpt_3d", "dtype": "float32", "shape": [BATCH_DIM, m, 3], "meaning": "keypoints, camera frame, metres"},
            {"name": "kpt_nocs", "dtype": "float32", "shape": [BATCH_DIM, m, 3], "meaning": "keypoints' NOCS coordinates"},
        ],
        "preprocessing": {
            "spec": "tools/README.md#preprocessing-exact-specification",
            "n_points": n,
            "crop_size": crop,
            "min_valid_pixels": MIN_VALID_PIXELS,
            "crop_step_px": CROP_STEP,
            "max_crop_px": MAX_CROP,
            "rgb_scale": 1.0 / 255.0,
            "rgb_mean": list(IMAGENET_MEAN),
            "rgb_std": list(IMAGENET_STD),
            "resize": "bilinear, half-pixel centres, no antialiasing",
            "sampling": "n_points of the valid pixels, with replacement only when fewer",
        },
        "categories": list(CLASSES),
        "rotation_from_keypoints": [c for c in CLASSES if c in set(rotation_from_keypoints)],
        **({"rotation_keypoint_blend": {c: blend[c] for c in CLASSES if c in blend}} if blend else {}),
        **({} if consistency_score_scale is None else {"consistency_score_scale": consistency_score_scale}),
        **({} if min_score is None else {"min_score": min_score}),
        "n_keypoints": m,
        "parameters": n_params,
        "config": cfg.to_dict(),
        "weights": weights,
        "export_check": check,
        "metrics": metrics,
        "exported_with": {"torch": torch.__version__, "python": platform.python_version()},
    }


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file and rename."""
    tmp = path.with_name(f"{path.name}.tmp{os.getpid()}")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def card_path(onnx_path: Path) -> Path:
    """``models/x.onnx`` -> ``models/x.card.json``."""
    return onnx_path.with_name(onnx_path.stem + ".card.json")


def _parse_metrics(items: Sequence[str]) -> Dict[str, dict]:
    out: Dict[str, dict] = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise SystemExit(f"--metrics: expected NAME=FILE, got {item!r}")
        try:
            out[name] = json.loads(Path(path).read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as e:
            raise SystemExit(f"--metrics {name}: cannot read {path}: {e}")
    return out


def _weights_from_checkpoint(ck: dict, path: str, note: str | None) -> dict:
    args = ck.get("args") or {}
    w = {"kind": "trained", "checkpoint": os.path.basename(path), "epoch": ck.get("epoch"), "step": ck.get("step"),
         "state_sha256": hashlib.sha256(
             b"".join(t.detach().numpy().tobytes() for t in ck["model"].values())).hexdigest()}
    if args:
        w["training_args"] = {k: args[k] for k in ("data", "config", "epochs", "batch_size", "seed", "lr", "max_lr",
                                                "dinov2_checkpoint")
                              if k in args}
    if ck.get("averaged_from"):
        # python -m tricons_pose.average: the mean of these checkpoints' weights
        w["averaged_from"] = [os.path.basename(os.path.dirname(p)) + "/" + os.path.basename(p)
                              for p in ck["averaged_from"]]
        w["batchnorm"] = ck.get("batchnorm")
    if note:
        w["training_note"] = note
    return w


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point (see the module docstring)."""
    p = argparse.ArgumentParser(prog="python -m tricons_pose.export", description=__doc__.split("\n")[0])
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--checkpoint", help="model.pt or checkpoint.pt from tricons_pose.train")
    src.add_argument("--config", help="configuration name (shipped, paper, ...) or JSON file; needs --random-init")
    p.add_argument("--random-init", type=int, metavar="SEED", help="random weights from this seed (with --config)")
    p.add_argument("--dinov2-checkpoint", metavar="PTH",
                   help="with --config/--random-init: the official DINOv2 ViT-S/14 weights "
                        "(dinov2_vits14_pretrain.pth) in the ViT of a 'dinov2' configuration")
    p.add_argument("--out", required=True, help="ONNX file to write; the card goes to <stem>.card.json")
    p.add_argument("--metrics", action="append", default=[], metavar="NAME=FILE",
                   help="a `tricons eval --json` report to put in the card (repeatable), e.g. published=...")
    p.add_argument("--training-note", help="free text for the card (data command, machine, wall time)")
    p.add_argument("--no-check", action="store_true", help="skip the reference-evaluator comparison")
    p.add_argument("--standard-ops", action="store_true",
                   help="standard ONNX ops in place of the ai.tricons nodes (for onnxruntime; FPS unrolled)")
    p.add_argument("--rotation-from-keypoints", default="", metavar="CLASSES",
                   help="comma-separated classes (or 'all') whose rotation the runtime solves from the keypoints' "
                        "NOCS coordinates instead of taking the pose head's (card field; tools/MODEL.md)")
    p.add_argument("--rotation-keypoint-blend", default="", metavar="CLASS=W,...",
                   help="classes whose rotation the runtime takes as the weighted chordal mean of the head's "
                        "(1 - W) and the keypoints' (W), e.g. camera=0.5,laptop=0.5,mug=0.5 (card field; the "
                        "shipped card's; tools/MODEL.md, E15)")
    p.add_argument("--consistency-score-scale", type=float, metavar="SCALE",
                   help="the runtime reports each pose's score times exp(-r / SCALE), r the disagreement "
                        "between the pose head and the keypoints in box diagonals (card field; the shipped "
                        "card: 0.3; tools/MODEL.md, E11)")
    p.add_argument("--min-score", type=float, metavar="SCORE",
                   help="the runtime leaves out poses whose reported score lies below SCORE, counting them "
                        "(card field; the shipped card: 0.6; docs/results.md, \"Score floor\")")
    args = p.parse_args(argv)
    if args.min_score is not None and not 0 <= args.min_score < 1:
        p.error(f"--min-score: must lie in [0, 1), found {args.min_score}")
    scale = args.consistency_score_scale
    if scale is not None and not 0 < scale < float("inf"):
        p.error(f"--consistency-score-scale: must be a positive number, found {scale}")
    from .predict import check_blend, parse_blend, parse_classes

    try:
        blend = parse_blend(args.rotation_keypoint_blend)
        check_blend(blend, parse_classes(args.rotation_from_keypoints))
    except ValueError as e:
        p.error(f"--rotation-keypoint-blend: {e}")

    if args.config is not None:
        if args.random_init is None:
            p.error("--config needs --random-init SEED (trained weights come with --checkpoint)")
        from .train import build_config

        cfg = build_config(args.config)
        model = random_model(cfg, args.random_init)
        weights = {"kind": "random", "seed": args.random_init}
        if args.dinov2_checkpoint:
            from .dinov2 import load_official_dinov2

            try:
                load_official_dinov2(model, args.dinov2_checkpoint)
            except (OSError, ValueError) as e:
                p.error(f"--dinov2-checkpoint: {e}")
            with open(args.dinov2_checkpoint, "rb") as f:
                weights["dinov2"] = {"file": os.path.basename(args.dinov2_checkpoint),
                                     "sha256": hashlib.sha256(f.read()).hexdigest()}
    else:
        if args.random_init is not None:
            p.error("--random-init goes with --config, not --checkpoint")
        if args.dinov2_checkpoint:
            p.error("--dinov2-checkpoint goes with --config (a trained checkpoint holds its ViT weights)")
        model, cfg, ck = load_checkpoint(args.checkpoint)
        weights = _weights_from_checkpoint(ck, args.checkpoint, args.training_note)
    metrics = _parse_metrics(args.metrics)

    onnx_bytes = to_onnx_bytes(model, cfg, args.standard_ops)
    check = None if args.no_check else check_export(model, cfg, onnx_bytes, standard=args.standard_ops)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    n_params = sum(t.numel() for t in model.parameters())
    card = build_card(cfg, out.name, onnx_bytes, weights, check, metrics, n_params,
                      parse_classes(args.rotation_from_keypoints), args.consistency_score_scale, blend,
                      args.min_score)
    write_atomic(out, onnx_bytes)
    write_atomic(card_path(out), (json.dumps(card, indent=2) + "\n").encode("utf-8"))
    msg = f"{out} ({len(onnx_bytes) / 1e6:.2f} MB, {n_params} parameters) + {card_path(out).name}"
    if check:
        msg += f"; {check['evaluator'].split()[0]} check: max |dR| {check['max_rotation_diff_deg']:.2e} deg, " \
               f"max |dt| {check['max_abs_diff']['t']:.2e} m"
    print(msg)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
