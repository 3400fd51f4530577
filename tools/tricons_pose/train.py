"""Train TriCons-Pose on tricons recordings (SynthNOCS).

    python -m tricons_pose.train --data data/train --config shipped --out runs/shipped \\
        --epochs 30 --batch-size 16 --seed 1 [--resume] [--device cpu|cuda|auto]

Adam (lr 1e-4 = the paper's initial rate) with a triangular2 cyclic schedule
(torch CyclicLR: from ``--lr`` up to ``--max-lr`` and back in 2 x
``--cycle-steps`` optimiser steps, the amplitude halving every cycle; default
half-cycle: 2 epochs); ``--lr-mode triangular`` keeps every cycle at full height (the
cycles that trained the shipped model, tools/MODEL.md E7-E13); ``--lr-mode anneal`` is no
cycle but a cosine decay from ``--lr`` to 0 over ``--max-steps`` (a cool-down after the
cycles, tools/MODEL.md E16). Writes to RUN_DIR:

- ``config.json``: model configuration and training arguments;
- ``log.jsonl``: one JSON line per step (step, epoch, lr, every loss term,
  samples_per_s, data_s, step_s, time_s);
- ``checkpoint.pt``: model, optimiser, scheduler, RNG states, epoch and step,
  written every ``--ckpt-every`` steps and at each epoch end (temporary file +
  rename, so a kill never leaves a torn checkpoint); ``--resume`` continues
  from it exactly (same data order, same per-sample randomness, same RNG);
- ``model.pt`` at the end: {"config", "model", "epoch", "step"} for export.

Data order is a permutation per epoch from numpy's default_rng((seed, epoch));
per-sample randomness is default_rng((seed, epoch, index)) (tricons_pose.data).

Mixed training as AG-Pose and the paper do on CAMERA25 + REAL275: ``--real DIR...``
adds a second set of recordings and every batch takes ``--real-per-batch`` instances
from it (default a quarter of the batch: AG-Pose's 30 synthetic + 10 real, the paper's
batch of 24 as 18 + 6), the rest from ``--data``, each set in its own seeded permutation
(default_rng((seed, epoch, 0)) and (seed, epoch, 1), wrapping around); an epoch is
``--steps-per-epoch`` batches (default: one pass over ``--data``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import sys
import time
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np
import torch
from torch.utils.data import DataLoader, Sampler

from .config import ModelConfig
from .data import AugmentConfig, InstanceDataset, split_batch
from .nocs_layout import open_any

CONFIGS = ("shipped", "paper", "baseline", "without_sckd", "without_piga")
LOG_FILE = "log.jsonl"
CKPT_FILE = "checkpoint.pt"
FINAL_FILE = "model.pt"


def build_config(name: str) -> ModelConfig:
    """``shipped`` | ``paper`` | ``baseline`` | ``without_sckd`` | ``without_piga``
    (ablations of the shipped sizes), or a path to a ModelConfig JSON file."""
    if name == "shipped":
        return ModelConfig.shipped()
    if name == "paper":
        return ModelConfig.paper()
    if name in ("baseline", "without_sckd", "without_piga"):
        return getattr(ModelConfig.shipped(), name)()
    if os.path.isfile(name):
        return ModelConfig.from_json(Path(name).read_text(encoding="utf-8"))
    raise SystemExit(f"--config: unknown configuration {name!r} (one of {', '.join(CONFIGS)} or a JSON file)")


def lr_schedule(opt, args, cycle: int):
    """The learning-rate scheduler of ``--lr-mode`` (stepped once per optimiser step)."""
    mode = getattr(args, "lr_mode", "triangular2")
    if mode == "anneal":
        if args.max_steps < 1:
            raise SystemExit("--lr-mode anneal needs --max-steps (the length of the decay)")
        total = args.max_steps
        return torch.optim.lr_scheduler.LambdaLR(
            opt, lambda k: 0.5 * (1.0 + math.cos(math.pi * min(k, total) / total)))
    return torch.optim.lr_scheduler.CyclicLR(opt, base_lr=args.lr, max_lr=args.max_lr, step_size_up=cycle,
                                             mode=mode, cycle_momentum=False)


def init_weights(init: dict, cfg: ModelConfig, path) -> dict:
    """The state dict of an ``--init-from`` checkpoint for a model of ``cfg``.

    The checkpoint's configuration must equal ``cfg`` (fields added since it was
    written take their defaults), except that a class-agnostic model may start a
    ``nocs_per_class`` one (whose name and notes may differ): the NOCS head's last layer is repeated once per class,
    so the new model starts with the old one's outputs for every class; and a CNN model may
    start one of another crop size (no weight changes shape)."""
    try:
        old = ModelConfig.from_dict(init.get("config") or {})
    except (TypeError, ValueError) as e:
        raise SystemExit(f"--init-from: {path}: unreadable model configuration ({e})") from None
    state = dict(init["model"])
    if cfg.nocs_per_class and not old.nocs_per_class:
        grown = old.replace(nocs_per_class=True, n_classes=cfg.n_classes, name=cfg.name, notes=cfg.notes)
        if grown.to_dict() != cfg.to_dict():
            raise SystemExit(f"--init-from: {path} differs from the configuration in more than nocs_per_class")
        last = max(int(k.split(".")[1]) for k in state if k.startswith("nocs_head."))
        for name in ("weight", "bias"):
            key = f"nocs_head.{last}.{name}"
            state[key] = state[key].repeat(cfg.n_classes, *([1] * (state[key].dim() - 1)))
        return state
    # the crop size changes no weight's shape (the image encoder is a fully convolutional
    # CNN; the ViT's resampling matrices are buffers rebuilt from the crop size)
    resized = old.replace(crop_size=cfg.crop_size, name=cfg.name, notes=cfg.notes)
    if old.crop_size != cfg.crop_size and cfg.image_encoder == "cnn" and resized.to_dict() == cfg.to_dict():
        return state
    if old.to_dict() != cfg.to_dict():
        raise SystemExit(f"--init-from: {path} was written with a different model configuration")
    return state


class EpochSampler(Sampler):
    """Yields (epoch, index) pairs: a seeded permutation per epoch, from position ``start``.

    The dataset receives the epoch with every index, so persistent DataLoader
    workers need no epoch broadcast.
    """

    def __init__(self, n: int, seed: int, epoch: int = 0, start: int = 0):
        self.n, self.seed, self.epoch, self.start = n, seed, epoch, start

    def order(self) -> np.ndarray:
        return np.random.default_rng((self.seed, self.epoch)).permutation(self.n)

    def __iter__(self) -> Iterator[tuple[int, int]]:
        for i in self.order()[self.start :]:
            yield (self.epoch, int(i))

    def __len__(self) -> int:
        return self.n - self.start


class MixedEpochSampler(Sampler):
    """Batches of ``per_a`` instances of set A (indices ``0..n_a``) then ``per_b`` of set B
    (indices ``n_a..n_a + n_b``), ``steps`` batches per epoch, each set in its own seeded
    permutation walked with wrap-around; yields (epoch, index) pairs from sample ``start``
    (a multiple of the batch size when resuming), like :class:`EpochSampler`."""

    def __init__(self, n_a: int, n_b: int, per_a: int, per_b: int, steps: int, seed: int, epoch: int = 0,
                 start: int = 0):
        if min(n_a, n_b, per_a, per_b, steps) < 1:
            raise ValueError("both sets, both shares of the batch and the epoch length must be positive")
        self.n_a, self.n_b, self.per_a, self.per_b, self.steps = n_a, n_b, per_a, per_b, steps
        self.seed, self.epoch, self.start = seed, epoch, start

    def order(self) -> np.ndarray:
        perm_a = np.random.default_rng((self.seed, self.epoch, 0)).permutation(self.n_a)
        perm_b = np.random.default_rng((self.seed, self.epoch, 1)).permutation(self.n_b) + self.n_a
        out = np.empty(self.steps * (self.per_a + self.per_b), dtype=np.int64)
        for b in range(self.steps):
            at = b * (self.per_a + self.per_b)
            out[at : at + self.per_a] = perm_a[(b * self.per_a + np.arange(self.per_a)) % self.n_a]
            out[at + self.per_a : at + self.per_a + self.per_b] = perm_b[(b * self.per_b + np.arange(self.per_b)) % self.n_b]
        return out

    def __iter__(self) -> Iterator[tuple[int, int]]:
        for i in self.order()[self.start :]:
            yield (self.epoch, int(i))

    def __len__(self) -> int:
        return self.steps * (self.per_a + self.per_b) - self.start


class EpochDataset(torch.utils.data.Dataset):
    """Wraps an :class:`InstanceDataset` so that ``ds[(epoch, i)]`` uses that epoch's RNG."""

    def __init__(self, ds: InstanceDataset):
        self.ds = ds

    def __len__(self) -> int:
        return len(self.ds)

    def __getitem__(self, key):
        epoch, i = key
        self.ds.epoch = epoch
        return self.ds[i]


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m tricons_pose.train", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", nargs="+", required=True,
                   help="recordings: tricons recordings, NOCS-layout scenes or split directories (CAMERA/train)")
    p.add_argument("--real", nargs="+", default=None, metavar="DIR",
                   help="a second set mixed into every batch (REAL275's Real/train beside CAMERA/train)")
    p.add_argument("--real-per-batch", type=int, default=0,
                   help="instances of each batch from --real (default: a quarter of the batch)")
    p.add_argument("--steps-per-epoch", type=int, default=0,
                   help="batches per epoch with --real (default: one pass over --data)")
    p.add_argument("--config", default="shipped", help=f"{' | '.join(CONFIGS)} or a ModelConfig JSON file")
    p.add_argument("--out", required=True, help="run directory (log, checkpoints)")
    p.add_argument("--epochs", type=int, default=30)
    p.add_argument("--batch-size", type=int, default=16)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--resume", action="store_true", help="continue from RUN_DIR/checkpoint.pt")
    p.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    p.add_argument("--threads", type=int, default=0, help="torch.set_num_threads (0: all cores)")
    p.add_argument("--workers", type=int, default=1, help="DataLoader worker processes (0: load in the main process)")
    p.add_argument("--lr", type=float, default=1e-4, help="initial = lowest learning rate of the cycle")
    p.add_argument("--max-lr", type=float, default=1e-3,
                   help="peak of the first cycle (triangular2 halves it per cycle, triangular keeps it)")
    p.add_argument("--lr-mode", choices=("triangular2", "triangular", "anneal"), default="triangular2",
                   help="CyclicLR mode: triangular2 halves the peak every cycle, triangular repeats it; anneal: "
                        "no cycle, a cosine decay from --lr to 0 over --max-steps (needs --max-steps)")
    p.add_argument("--cycle-steps", type=int, default=0, help="half-cycle length in steps (0: 2 epochs)")
    p.add_argument("--log-every", type=int, default=10, help="stdout line every N steps")
    p.add_argument("--ckpt-every", type=int, default=200, help="checkpoint every K steps (and at epoch ends)")
    p.add_argument("--max-steps", type=int, default=0, help="stop after this global step (0: run all epochs)")
    p.add_argument("--grad-clip", type=float, default=0.0, help="clip the gradient norm (0: off)")
    p.add_argument("--cache-dir", default=None, help="keep preprocessed instances here as .npz (optional)")
    p.add_argument("--frame-cache", choices=("memory", "disk"), default="memory",
                   help="memory: each loader worker also keeps every frame it has read (about 11 GB for SynthNOCS "
                        "train + train2); disk: read --cache-dir's .npz at every use, so that several training "
                        "processes share the OS page cache (needs --cache-dir; the samples are the same)")
    p.add_argument("--no-color-jitter", action="store_true")
    p.add_argument("--mask-perturb", type=float, default=0.0, metavar="P",
                   help="probability of a dilated / eroded / shifted instance mask per sample (0: off); "
                        "needs the crop windows' depth and masks, cached beside --cache-dir's files")
    p.add_argument("--init-from", default=None,
                   help="start from these weights (a checkpoint.pt or model.pt of the same configuration) with a "
                        "fresh optimiser and schedule: fine-tuning on new data; ignored with --resume")
    p.add_argument("--keep-cycle-ends", action="store_true",
                   help="also keep model-step<N>.pt at the end of every learning-rate cycle (lowest rate)")
    p.add_argument("--compile", action="store_true",
                   help="run the forward pass and losses through torch.compile (inductor: fused CPU kernels, "
                        "a few minutes of compilation at start; the custom point operators stay eager)")
    p.add_argument("--autocast", choices=("off", "bf16"), default="off",
                   help="bf16: the forward pass under torch.autocast(bfloat16) (matrix products and convolutions "
                        "in bfloat16, weights and losses float32); tools/MODEL.md has its measurement")
    p.add_argument("--dinov2-checkpoint", default=None, metavar="PTH",
                   help="official DINOv2 ViT-S/14 weights (dinov2_vits14_pretrain.pth, a local file) for the "
                        "'dinov2' image encoder (paper config): loaded into the ViT, which is then frozen")
    args = p.parse_args(argv)
    if args.epochs < 1 or args.batch_size < 1:
        p.error("--epochs and --batch-size must be positive")
    if args.frame_cache == "disk" and args.cache_dir is None:
        p.error("--frame-cache disk reads --cache-dir's files: give --cache-dir")
    if not 0.0 <= args.mask_perturb <= 1.0:
        p.error(f"--mask-perturb {args.mask_perturb} must lie in [0, 1]")
    if args.real is None and (args.real_per_batch or args.steps_per_epoch):
        p.error("--real-per-batch and --steps-per-epoch go with --real")
    if args.real is not None:
        args.real_per_batch = args.real_per_batch or max(1, args.batch_size // 4)
        if not 0 < args.real_per_batch < args.batch_size:
            p.error(f"--real-per-batch {args.real_per_batch} must be between 1 and the batch size - 1")
    return args


def training_dataset(recordings: list, cfg: ModelConfig, seed: int, cache_dir: str | None, color_jitter: bool = True,
                     mask_perturb: float = 0.0, memory_cache: bool = True) -> InstanceDataset:
    """The instances of ``recordings`` with the augmentation training applies to a model of ``cfg``
    (``memory_cache``: keep every frame read in memory, see ``--frame-cache``)."""
    n_views = 2 if cfg.use_sckd_loss else 1
    # view 0 drives the pose supervision in forward_train and is kept isotropic there
    augment = AugmentConfig(n_views=n_views, isotropic_views=(0,), scale_axes="camera",
                            color_jitter=color_jitter, mask_perturb=mask_perturb)
    return InstanceDataset(recordings, n_points=cfg.n_points, crop_size=cfg.crop_size, seed=seed,
                           augment=augment, cache=memory_cache, cache_dir=cache_dir)


def _rng_state() -> dict:
    st = {"python": random.getstate(), "numpy": np.random.get_state(), "torch": torch.get_rng_state()}
    if torch.cuda.is_available():
        st["cuda"] = torch.cuda.get_rng_state_all()
    return st


def _set_rng_state(st: dict) -> None:
    random.setstate(st["python"])
    np.random.set_state(st["numpy"])
    torch.set_rng_state(st["torch"])
    if "cuda" in st and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(st["cuda"])


def save_atomic(obj, path: Path) -> None:
    """torch.save to a temporary file in the same directory, fsync, rename."""
    tmp = path.with_name(f"{path.name}.tmp{os.getpid()}")
    with open(tmp, "wb") as f:
        torch.save(obj, f)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _to_device(x, device):
    if isinstance(x, torch.Tensor):
        return x.to(device, non_blocking=True)
    if isinstance(x, dict):
        return {k: _to_device(v, device) for k, v in x.items()}
    return x


def default_model_factory(cfg: ModelConfig) -> torch.nn.Module:
    from .model import TriConsPose

    return TriConsPose(cfg)


def default_loss_fn(outputs: dict, targets: dict, cfg: ModelConfig) -> dict:
    from .losses import compute_losses

    return compute_losses(outputs, targets, cfg)


def train(
    args: argparse.Namespace,
    model_factory: Callable[[ModelConfig], torch.nn.Module] = default_model_factory,
    loss_fn: Callable[[dict, dict, ModelConfig], dict] = default_loss_fn,
    cfg: ModelConfig | None = None,
) -> dict:
    """Run training as described in the module docstring; returns a summary dict.

    ``loss_fn(outputs, targets, cfg)`` must return a dict of scalar tensors with
    a "total" entry (the others are logged).
    """
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = cfg or build_config(args.config)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    else:
        torch.set_num_threads(os.cpu_count() or 1)
    if args.device == "auto":
        device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    else:
        if args.device == "cuda" and not torch.cuda.is_available():
            raise SystemExit("--device cuda: CUDA is not available")
        device = torch.device(args.device)

    random.seed(args.seed)
    np.random.seed(args.seed % 2**32)
    torch.manual_seed(args.seed)

    recs_a = [rec for r in args.data for rec in open_any(r)]
    recs_b = [rec for r in (getattr(args, "real", None) or []) for rec in open_any(r)]
    ds = training_dataset(recs_a + recs_b, cfg, args.seed, args.cache_dir, color_jitter=not args.no_color_jitter,
                          mask_perturb=args.mask_perturb,
                          memory_cache=getattr(args, "frame_cache", "memory") == "memory")
    if recs_b:
        n_a = sum(1 for ref in ds.index if ref.rec < len(recs_a))
        per_b = args.real_per_batch
        per_a = args.batch_size - per_b
        steps_per_epoch = args.steps_per_epoch or math.ceil(n_a / per_a)
        sampler: Sampler = MixedEpochSampler(n_a, len(ds) - n_a, per_a, per_b, steps_per_epoch, args.seed)
        print(f"mixed batches: {per_a} of {n_a} instances (--data) + {per_b} of {len(ds) - n_a} (--real)", flush=True)
    else:
        steps_per_epoch = math.ceil(len(ds) / args.batch_size)
        sampler = EpochSampler(len(ds), args.seed)
    cycle = args.cycle_steps or 2 * steps_per_epoch

    model = model_factory(cfg).to(device)
    dinov2 = getattr(args, "dinov2_checkpoint", None)
    if dinov2:
        from .dinov2 import load_official_dinov2

        try:
            info = load_official_dinov2(model, dinov2)
        except (OSError, ValueError) as e:
            raise SystemExit(f"--dinov2-checkpoint: {e}")
        print(f"DINOv2 weights: {info['tensors']} tensors from {dinov2}; the ViT is frozen", flush=True)
    opt = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=args.lr)
    sched = lr_schedule(opt, args, cycle)
    epoch, step_in_epoch, step = 0, 0, 0
    ckpt_path = out / CKPT_FILE
    if args.resume:
        if not ckpt_path.exists():
            raise SystemExit(f"--resume: {ckpt_path} does not exist")
        ck = torch.load(ckpt_path, map_location=device, weights_only=False)
        if ModelConfig.from_dict(ck["config"]).to_dict() != cfg.to_dict():
            raise SystemExit(f"--resume: {ckpt_path} was written with a different model configuration")
        if bool((ck.get("args") or {}).get("dinov2_checkpoint")) != bool(dinov2):
            # a frozen ViT changes the optimiser's parameter list
            raise SystemExit(f"--resume: {ckpt_path}'s run {'had' if not dinov2 else 'did not have'} "
                             "--dinov2-checkpoint; resume with the same setting")
        if ck["n_samples"] != len(ds):
            raise SystemExit(f"--resume: the data has {len(ds)} instances, the checkpoint's run had {ck['n_samples']}")
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        sched.load_state_dict(ck["scheduler"])
        _set_rng_state(ck["rng"])
        epoch, step_in_epoch, step = ck["epoch"], ck["step_in_epoch"], ck["step"]
        if step_in_epoch >= steps_per_epoch:
            epoch, step_in_epoch = epoch + 1, 0
        print(f"resumed from {ckpt_path}: epoch {epoch}, step {step}", flush=True)
    elif args.init_from:
        init = torch.load(args.init_from, map_location=device, weights_only=False)
        model.load_state_dict(init_weights(init, cfg, args.init_from))
        print(f"weights from {args.init_from} (its step {init.get('step')}); fresh optimiser and schedule", flush=True)
    run_info = {"model_config": cfg.to_dict(), "args": vars(args), "n_samples": len(ds),
                "steps_per_epoch": steps_per_epoch, "cycle_half_steps": cycle, "device": str(device),
                "torch_threads": torch.get_num_threads()}
    if args.resume and (out / "config.json").exists():
        # the run's first configuration stays (its --init-from, say); each resume's arguments are added
        first = json.loads((out / "config.json").read_text(encoding="utf-8"))
        first.setdefault("resumed_with", []).append({"args": vars(args), "step": step})
        run_info = first
    tmp = out / "config.json.tmp"
    tmp.write_text(json.dumps(run_info, indent=2, default=str) + "\n", encoding="utf-8")
    os.replace(tmp, out / "config.json")
    if not args.resume:
        print(f"{len(ds)} instances from {len(ds.recordings)} recording(s); {steps_per_epoch} steps/epoch; "
              f"config {cfg.name}; device {device}; {torch.get_num_threads()} threads", flush=True)

    def checkpoint(path: Path = ckpt_path) -> None:
        save_atomic({"model": model.state_dict(), "optimizer": opt.state_dict(), "scheduler": sched.state_dict(),
                     "rng": _rng_state(), "epoch": epoch, "step_in_epoch": step_in_epoch, "step": step,
                     "config": cfg.to_dict(), "n_samples": len(ds), "args": vars(args)}, path)

    # one loader for the whole run (persistent workers keep their frame cache); the
    # sampler is iterated in this process and told the epoch and start position
    loader = DataLoader(EpochDataset(ds), batch_size=args.batch_size, sampler=sampler, num_workers=args.workers,
                        persistent_workers=args.workers > 0, generator=torch.Generator().manual_seed(args.seed),
                        pin_memory=device.type == "cuda")
    bf16 = getattr(args, "autocast", "off") == "bf16"

    def forward_losses(inputs: dict, aug: dict, targets: dict) -> dict:
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16):
            outputs = model.forward_train(inputs, aug)
        if bf16:  # the losses in float32
            outputs = {k: v.float() if torch.is_tensor(v) and v.is_floating_point() else v
                       for k, v in outputs.items()}
        return loss_fn(outputs, targets, cfg)

    compiled_losses = torch.compile(forward_losses, dynamic=False) if getattr(args, "compile", False) else None
    log = open(out / LOG_FILE, "a", encoding="utf-8")
    t_start = time.time()
    last: dict = {}
    stop = False
    model.train()
    try:
        while epoch < args.epochs and not stop:
            sampler.epoch, sampler.start = epoch, step_in_epoch * args.batch_size
            t_data = time.time()
            for batch in loader:
                t0 = time.time()
                inputs, aug, targets = split_batch(batch)
                inputs, aug, targets = (_to_device(x, device) for x in (inputs, aug, targets))
                # the compiled graph is for full batches; an epoch's shorter last batch runs eager
                # (compiling its shape too cost 150 s, once per process)
                full = int(inputs["pts"].shape[0]) == args.batch_size
                losses = (compiled_losses if compiled_losses is not None and full else forward_losses)(
                    inputs, aug, targets)
                total = losses["total"]
                if not torch.isfinite(total):
                    raise FloatingPointError(f"non-finite loss at step {step + 1}: "
                                             + ", ".join(f"{k}={float(v):.4g}" for k, v in losses.items()))
                opt.zero_grad(set_to_none=True)
                total.backward()
                if args.grad_clip > 0:
                    torch.nn.utils.clip_grad_norm_(model.parameters(), args.grad_clip)
                lr = opt.param_groups[0]["lr"]
                opt.step()
                sched.step()
                step += 1
                step_in_epoch += 1
                t1 = time.time()
                n = int(inputs["pts"].shape[0])
                rec = {"step": step, "epoch": epoch, "lr": lr, **{k: float(v.detach()) for k, v in losses.items()},
                       "samples_per_s": n / max(t1 - t_data, 1e-9), "data_s": t0 - t_data, "step_s": t1 - t0,
                       "time_s": t1 - t_start}
                log.write(json.dumps(rec) + "\n")
                log.flush()
                last = rec
                if args.log_every > 0 and (step % args.log_every == 0 or step == 1):
                    parts = " ".join(f"{k} {float(v.detach()):.4f}" for k, v in losses.items() if k != "total")
                    print(f"epoch {epoch} step {step} loss {float(total.detach()):.4f} ({parts}) lr {lr:.2e} "
                          f"{rec['samples_per_s']:.1f} samples/s", flush=True)
                if args.keep_cycle_ends and step % (2 * cycle) == 0:
                    save_atomic({"config": cfg.to_dict(), "model": model.state_dict(), "epoch": epoch, "step": step},
                                out / f"model-step{step}.pt")
                if args.max_steps and step >= args.max_steps:
                    stop = True
                    break
                if args.ckpt_every > 0 and step % args.ckpt_every == 0:
                    checkpoint()
                t_data = time.time()
            if not stop:
                epoch, step_in_epoch = epoch + 1, 0
                checkpoint()
        if stop:
            checkpoint()
    finally:
        log.close()
    if not stop:
        save_atomic({"config": cfg.to_dict(), "model": model.state_dict(), "epoch": epoch, "step": step},
                    out / FINAL_FILE)
    summary = {"epoch": epoch, "step": step, "last": last, "skipped_instances": sorted(ds.skipped)}
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point."""
    args = parse_args(argv)
    summary = train(args)
    last = summary["last"]
    print(f"done: epoch {summary['epoch']} step {summary['step']}"
          + (f", last loss {last['total']:.4f}" if last else ""), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
