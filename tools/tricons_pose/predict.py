"""Run a trained TriCons-Pose checkpoint on a recording and write predictions.

Uses the recording's ground-truth instance masks (segmentation is the
runtime's job), the same deterministic preprocessing as training without
augmentation, and writes the tricons predictions format (JSON Lines, one line
per frame, docs/formats.md) for ``tricons eval``::

    python -m tricons_pose.predict --checkpoint ../data/runs/shipped/checkpoint.pt \\
        --data ../data/synthnocs-test --out ../data/shipped-test.jsonl
    cargo run --release -- eval --gt data/synthnocs-test --pred data/shipped-test.jsonl

Instances with at most 16 valid pixels (mask AND depth) get no prediction, as
AG-Pose skips them; they count as misses in the evaluation. Scores are 1.
"""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Collection, Mapping
from pathlib import Path

import numpy as np
import torch

from .config import ModelConfig
from .recording import CLASSES
from .data import InstanceDataset, make_sample
from .model import TriConsPose
from .tricons_rng import instance_rng

MIN_VALID_PIXELS = 16
"""An instance needs more than this many valid pixels to be estimated."""


def load_model(path: str | os.PathLike) -> tuple[TriConsPose, ModelConfig]:
    """A model in eval mode from a training checkpoint or a final ``model.pt``."""
    ck = torch.load(path, map_location="cpu", weights_only=False)
    cfg = ModelConfig.from_dict(ck["config"])
    model = TriConsPose(cfg)
    model.load_state_dict(ck["model"])
    model.eval()
    return model, cfg


@torch.no_grad()
def predict_recording(
    model: TriConsPose, cfg: ModelConfig, data: str | os.PathLike, batch_size: int = 32, seed: int = 0,
    cache_dir: str | os.PathLike | None = None, sampler: str = "numpy",
    rotation_from_keypoints: Collection[str] = (), consistency_score_scale: float | None = None,
    rotation_keypoint_blend: Mapping[str, float] | None = None,
) -> list[dict]:
    """Predictions for every frame of recording ``data``, in frame order.

    ``sampler="numpy"`` samples points as training does (``default_rng((seed, 0, i))``
    for instance ``i`` of the recording); ``sampler="tricons"`` draws exactly the
    points ``tricons replay --seed seed`` draws (:mod:`tricons_rng`), so the two
    runtimes see identical inputs.

    ``cache_dir`` keeps the decoded, cropped instances (as in training) so that
    evaluating several checkpoints on one recording decodes its PNGs once.

    Instances of the classes in ``rotation_from_keypoints`` report the least-squares
    rotation between the keypoints' predicted NOCS coordinates and their camera-frame
    positions (:func:`keypoint_rotation`) instead of the pose head's, as the runtime does
    for the classes its model card lists (``rotation_from_keypoints``, tools/MODEL.md).
    Instances of the classes in ``rotation_keypoint_blend`` (class -> weight w in (0, 1))
    report the weighted chordal mean of the two, :func:`blend_rotations` (the card field).

    Scores are 1 (ground-truth masks), or with ``consistency_score_scale`` the runtime's
    ``exp(-r / scale)`` of :func:`keypoint_residual` (the card field of that name).
    """
    unknown = set(rotation_from_keypoints) - set(CLASSES)
    if unknown:
        raise ValueError(f"rotation_from_keypoints: unknown classes {sorted(unknown)} (known: {CLASSES})")
    blend = dict(rotation_keypoint_blend or {})
    check_blend(blend, rotation_from_keypoints)
    ds = InstanceDataset([data], n_points=cfg.n_points, crop_size=cfg.crop_size, seed=seed, augment=None,
                         cache_dir=cache_dir)
    rec = ds.recordings[0]
    usable = []
    for i in range(len(ds)):
        prep = ds.prepared(i)
        if prep is not None and prep.n_valid > MIN_VALID_PIXELS:
            usable.append(i)
    per_frame: dict[int, list[dict]] = {}
    for start in range(0, len(usable), batch_size):
        idx = usable[start : start + batch_size]
        samples = [make_sample(ds.prepared(i), cfg.n_points, cfg.crop_size, _rng(ds, i, seed, sampler), None)
                   for i in idx]
        inputs = {k: torch.stack([s[k] for s in samples]) for k in ("rgb", "pts", "choose", "class_id")}
        out = model(inputs)
        R_kpt64 = keypoint_rotation(out["kpt_nocs"], out["kpt_3d"], torch.float64) \
            if rotation_from_keypoints or blend else None
        scores = torch.ones(len(idx), dtype=torch.float64)
        if consistency_score_scale is not None:
            r = keypoint_residual(out["R"], out["t"], out["s"], out["kpt_nocs"], out["kpt_3d"])
            scores = torch.exp(-r / consistency_score_scale)
        for b, i in enumerate(idx):
            ref = ds.index[i]
            inst = ds._anns[(ref.rec, ref.frame)][ref.pos]
            per_frame.setdefault(ref.frame, []).append(
                {
                    "class": inst.cls,
                    "score": float(scores[b]),
                    "R": _reported_rotation(out["R"][b], R_kpt64, b, inst.cls, rotation_from_keypoints,
                                            blend).tolist(),
                    "t": out["t"][b].double().tolist(),
                    "s": out["s"][b].double().tolist(),
                }
            )
    return [
        {"frame": fr.id, "timestamp_s": fr.timestamp_s, "instances": per_frame.get(fi, [])}
        for fi, fr in enumerate(rec.frames)
    ]


def _reported_rotation(R_head: torch.Tensor, R_kpt64: torch.Tensor | None, b: int, cls: str,
                       rotation_from_keypoints: Collection[str], blend: Mapping[str, float]) -> torch.Tensor:
    """The float64 (3, 3) rotation reported for instance ``b`` of class ``cls``: the head's, the
    keypoint fit's (rounded to float32, the graph's precision, as before the blend existed) or
    the blend of the head's and the unrounded fit (in float64, as the runtime computes it)."""
    if cls in rotation_from_keypoints:
        return R_kpt64[b].float().double()
    if cls in blend:
        return blend_rotations(R_head.double(), R_kpt64[b], blend[cls])
    return R_head.double()


def check_blend(blend: Mapping[str, float], rotation_from_keypoints: Collection[str] = ()) -> None:
    """The runtime's rules for the card's ``rotation_keypoint_blend``: known classes, weights
    strictly between 0 and 1, no class also in ``rotation_from_keypoints``."""
    for cls, w in blend.items():
        if cls not in CLASSES:
            raise ValueError(f"rotation_keypoint_blend: unknown class {cls!r} (known: {CLASSES})")
        if not 0.0 < w < 1.0:
            raise ValueError(f"rotation_keypoint_blend: the weight of {cls} must lie strictly between 0 and 1, "
                             f"found {w}")
        if cls in rotation_from_keypoints:
            raise ValueError(f"rotation_keypoint_blend: {cls} is also in rotation_from_keypoints")


def blend_rotations(R_head: torch.Tensor, R_kpt: torch.Tensor, w: float) -> torch.Tensor:
    """The weighted chordal mean of two rotations (..., 3, 3): the proper rotation nearest to
    ``(1 - w) R_head + w R_kpt`` (SVD, the sign of the last singular direction fixed); the
    runtime's ``geometry::weighted_chordal_mean``."""
    return nearest_rotation((1.0 - w) * R_head + w * R_kpt)


def nearest_rotation(m: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> the proper rotations nearest (Frobenius) to ``m``: SVD, the sign of the
    last singular direction fixed so that det = +1."""
    U, _, Vh = torch.linalg.svd(m)
    d = torch.sign(torch.linalg.det(U @ Vh))
    D = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], dim=-1))
    return U @ D @ Vh


def parse_blend(text: str) -> dict[str, float]:
    """``"camera=0.5,mug=0.25"`` -> ``{"camera": 0.5, "mug": 0.25}``; ``""`` -> ``{}``."""
    out: dict[str, float] = {}
    for item in (x.strip() for x in text.split(",")):
        if not item:
            continue
        cls, sep, w = item.partition("=")
        try:
            if not sep:
                raise ValueError
            out[cls.strip()] = float(w)
        except ValueError:
            raise ValueError(f"rotation_keypoint_blend: {item!r} is not CLASS=WEIGHT") from None
    return out


def keypoint_rotation(kpt_nocs: torch.Tensor, kpt_3d: torch.Tensor, dtype: torch.dtype | None = None) -> torch.Tensor:
    """(B, M, 3) NOCS coordinates and (B, M, 3) camera-frame keypoints -> (B, 3, 3)
    rotations R minimising sum |R s n_i + t - p_i|^2 over R, s, t (Umeyama 1991,
    with the reflection fix: det R = +1); in ``dtype`` (default: the keypoints')."""
    n = kpt_nocs.double() - kpt_nocs.double().mean(dim=1, keepdim=True)
    q = kpt_3d.double() - kpt_3d.double().mean(dim=1, keepdim=True)
    cov = q.transpose(1, 2) @ n  # (B, 3, 3): sum_i q_i n_i^T
    return nearest_rotation(cov).to(dtype or kpt_3d.dtype)


def keypoint_residual(R: torch.Tensor, t: torch.Tensor, s: torch.Tensor, kpt_nocs: torch.Tensor,
                      kpt_3d: torch.Tensor) -> torch.Tensor:
    """(B,) disagreement between the pose head and the keypoints, in box diagonals: the
    root mean square over the M keypoints of ``|d R n + t - p|`` over ``d``, ``d`` the
    diagonal of ``s`` (B, 3), ``n`` from ``kpt_nocs`` and ``p`` from ``kpt_3d`` (B, M, 3);
    float64. The runtime's ``pose::consistency::keypoint_residual``."""
    d = s.double().norm(dim=-1)
    carried = d[:, None, None] * (kpt_nocs.double() @ R.double().transpose(1, 2)) + t.double()[:, None, :]
    return (carried - kpt_3d.double()).pow(2).sum(-1).mean(-1).sqrt() / d


def parse_classes(text: str) -> tuple[str, ...]:
    """``"bottle,mug"`` -> ``("bottle", "mug")``; ``"all"`` -> every category; ``""`` -> none."""
    if text.strip() == "all":
        return tuple(CLASSES)
    return tuple(c.strip() for c in text.split(",") if c.strip())


def _rng(ds: InstanceDataset, i: int, seed: int, sampler: str):
    if sampler == "numpy":
        return np.random.default_rng((seed, 0, i))
    if sampler == "tricons":
        ref = ds.index[i]
        return instance_rng(seed, ref.frame, ref.pos)
    raise ValueError(f"unknown sampler {sampler!r} (numpy or tricons)")


def write_jsonl(path: str | os.PathLike, frames: list[dict]) -> None:
    """Write predictions atomically (temporary file, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.tmp{os.getpid()}")
    with open(tmp, "w", encoding="utf-8") as f:
        for frame in frames:
            f.write(json.dumps(frame) + "\n")
    os.replace(tmp, path)


def main(argv: list[str] | None = None) -> None:
    """Command-line entry point (see the module docstring)."""
    p = argparse.ArgumentParser(prog="python -m tricons_pose.predict", description=__doc__.split("\n")[0])
    p.add_argument("--checkpoint", required=True, help="checkpoint.pt or model.pt from tricons_pose.train")
    p.add_argument("--data", required=True, help="recording with instance masks (e.g. SynthNOCS-test)")
    p.add_argument("--out", required=True, help="predictions file to write (JSON Lines)")
    p.add_argument("--batch-size", type=int, default=32)
    p.add_argument("--seed", type=int, default=0, help="seed of the point sampling")
    p.add_argument("--sampler", choices=("numpy", "tricons"), default="numpy",
                   help="point sampling: numpy (as in training) or tricons (the points tricons replay draws)")
    p.add_argument("--cache-dir", help="cache of decoded instances (speeds up repeated evaluations)")
    p.add_argument("--threads", type=int, default=0, help="torch.set_num_threads (0: all cores)")
    p.add_argument("--rotation-from-keypoints", default="", metavar="CLASSES",
                   help="comma-separated classes (or 'all') whose rotation is solved from the keypoints' "
                        "predicted NOCS coordinates instead of taken from the pose head (the model card's "
                        "rotation_from_keypoints; tools/MODEL.md)")
    p.add_argument("--rotation-keypoint-blend", default="", metavar="CLASS=W,...",
                   help="classes whose rotation is the weighted chordal mean of the head's (1 - W) and the "
                        "keypoints' (W), e.g. camera=0.5,laptop=0.5,mug=0.5 (the model card's "
                        "rotation_keypoint_blend; tools/MODEL.md, E15)")
    p.add_argument("--consistency-score-scale", type=float, metavar="SCALE",
                   help="score each pose exp(-r / SCALE), r the pose head's disagreement with the keypoints "
                        "in box diagonals (the model card's consistency_score_scale; default: scores 1)")
    args = p.parse_args(argv)
    try:
        blend = parse_blend(args.rotation_keypoint_blend)
        check_blend(blend, parse_classes(args.rotation_from_keypoints))
    except ValueError as e:
        p.error(f"--rotation-keypoint-blend: {e}")
    if args.consistency_score_scale is not None and not 0 < args.consistency_score_scale < float("inf"):
        p.error(f"--consistency-score-scale: must be a positive number, found {args.consistency_score_scale}")
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    model, cfg = load_model(args.checkpoint)
    frames = predict_recording(model, cfg, args.data, args.batch_size, args.seed, args.cache_dir, args.sampler,
                                parse_classes(args.rotation_from_keypoints), args.consistency_score_scale, blend)
    write_jsonl(args.out, frames)
    n = sum(len(f["instances"]) for f in frames)
    print(f"{n} instances in {len(frames)} frames -> {args.out}")


if __name__ == "__main__":
    main()
