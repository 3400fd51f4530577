"""Weight averaging of cycle ends (stochastic weight averaging, Izmailov et al. 2018): the mean of
several checkpoints of one model configuration, then optionally the BatchNorm statistics
recomputed on training batches (the running statistics of a mean of weights are not the mean of
the running statistics)::

    # from tools/
    .venv/bin/python -m tricons_pose.average --checkpoints A.pt B.pt C.pt --out swa.pt \\
        --bn-data ../data/synthnocs-train ../data/synthnocs-train2 --cache-dir ../data/cache-train

Every input is a ``model-step<N>.pt`` or ``checkpoint.pt`` of ``tricons_pose.train``; the output
has the ``model-step<N>.pt`` layout (``config``, ``model``, ``step``; ``averaged_from`` lists the
inputs), which ``export`` and ``predict`` read.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Sequence

import torch
from torch.utils.data import DataLoader

from .config import ModelConfig
from .data import split_batch
from .nocs_layout import open_any


def average_states(states: Sequence[dict], weights: Sequence[float] | None = None) -> dict:
    """The weighted mean of state dicts with the same keys and shapes; integer buffers (BatchNorm's
    ``num_batches_tracked``) are taken from the first."""
    if not states:
        raise ValueError("no state dicts to average")
    w = list(weights) if weights is not None else [1.0] * len(states)
    if len(w) != len(states) or any(x < 0 for x in w) or sum(w) <= 0:
        raise ValueError(f"weights {w}: need one non-negative weight per state, not all zero")
    keys = list(states[0])
    for i, s in enumerate(states[1:], 1):
        if list(s) != keys:
            raise ValueError(f"state {i} has other keys than state 0")
        for k in keys:
            if s[k].shape != states[0][k].shape:
                raise ValueError(f"state {i}: {k} has shape {tuple(s[k].shape)}, state 0 {tuple(states[0][k].shape)}")
    total = float(sum(w))
    out = {}
    for k in keys:
        t0 = states[0][k]
        if not t0.is_floating_point():
            out[k] = t0.clone()
            continue
        acc = torch.zeros_like(t0, dtype=torch.float64)
        for wi, s in zip(w, states):
            acc += (wi / total) * s[k].to(torch.float64)
        out[k] = acc.to(t0.dtype)
    return out


@torch.no_grad()
def recompute_batchnorm(model: torch.nn.Module, loader, batches: int) -> int:
    """Reset every BatchNorm's running statistics and set them to the plain mean over ``batches``
    training batches (``forward_train``, as training feeds it); returns the batches used."""
    bns = [m for m in model.modules() if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]
    if not bns:
        return 0
    saved = {m: m.momentum for m in bns}
    for m in bns:
        m.reset_running_stats()
        m.momentum = None  # cumulative average
    was_training = model.training
    model.train()
    used = 0
    try:
        for batch in loader:
            if used >= batches:
                break
            inputs, aug, _ = split_batch(batch)
            model.forward_train(inputs, aug)
            used += 1
    finally:
        for m, mom in saved.items():
            m.momentum = mom
        model.train(was_training)
    return used


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m tricons_pose.average", description=__doc__.split("::")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--checkpoints", nargs="+", required=True, metavar="PT", help="two or more checkpoints to average")
    p.add_argument("--weights", nargs="+", type=float, default=None, help="one weight per checkpoint (default equal)")
    p.add_argument("--out", required=True, help="the averaged model-step<N>.pt-style file")
    p.add_argument("--bn-data", nargs="+", default=None, metavar="DIR",
                   help="recordings to recompute the BatchNorm statistics on (default: average them too)")
    p.add_argument("--bn-batches", type=int, default=100, help="training batches for the statistics")
    p.add_argument("--batch-size", type=int, default=16)
    p.add_argument("--mask-perturb", type=float, default=0.2, help="as the shipped model's training")
    p.add_argument("--cache-dir", default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1)
    return p.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    from .train import build_config, default_model_factory, save_atomic, training_dataset

    args = parse_args(argv)
    torch.set_num_threads(max(args.threads, 1))
    cks = []
    for path in args.checkpoints:
        try:
            cks.append(torch.load(path, map_location="cpu", weights_only=False))
        except (OSError, RuntimeError) as e:
            raise SystemExit(f"--checkpoints: {path}: {e}")
    cfgs = [ModelConfig.from_dict(ck.get("config") or {}).to_dict() for ck in cks]
    for path, c in zip(args.checkpoints[1:], cfgs[1:]):
        if c != cfgs[0]:
            raise SystemExit(f"--checkpoints: {path} has another model configuration than {args.checkpoints[0]}")
    try:
        state = average_states([ck["model"] for ck in cks], args.weights)
    except ValueError as e:
        raise SystemExit(f"--checkpoints: {e}")
    cfg = ModelConfig.from_dict(cks[0]["config"])
    note = "averaged running statistics"
    if args.bn_data:
        torch.manual_seed(args.seed)
        model = default_model_factory(cfg)
        model.load_state_dict(state)
        ds = training_dataset([rec for r in args.bn_data for rec in open_any(r)], cfg, args.seed, args.cache_dir,
                              mask_perturb=args.mask_perturb)
        from .train import EpochDataset, EpochSampler

        loader = DataLoader(EpochDataset(ds), batch_size=args.batch_size, sampler=EpochSampler(len(ds), args.seed))
        used = recompute_batchnorm(model, loader, args.bn_batches)
        state = model.state_dict()
        note = f"BatchNorm statistics of {used} batches of {args.batch_size}"
    out = {"config": cks[0]["config"], "model": state, "step": max(int(ck.get("step") or 0) for ck in cks),
           "epoch": cks[0].get("epoch"), "averaged_from": [str(Path(p)) for p in args.checkpoints],
           "averaged_weights": args.weights, "batchnorm": note}
    save_atomic(out, Path(args.out))
    print(f"{args.out}: mean of {len(cks)} checkpoints; {note}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
