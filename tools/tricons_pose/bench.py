"""PyTorch and onnxruntime latency on the inputs ``tricons bench`` uses, and the side-by-side table.

The same network three ways, on the same inputs (the demo recording's instances,
points drawn with the runtime's sampler, :mod:`tricons_rng`):

* ``pytorch``: the model in eager mode, custom ops as ``torch.library`` ops (CPU);
* ``onnxruntime``: the ``--standard-ops`` export (standard ONNX ops in place of
  the ``ai.tricons`` nodes, FPS unrolled), CPU execution provider, all graph
  optimisations;
* tract: ``tricons bench --json`` (run it first), whose report this script reads
  with ``--tract-json`` to print one markdown table (with ``tricons bench --int8``,
  tract's int8 row too);
* ``--ort-int8 OUT``: onnxruntime's own static int8 quantization of the same
  standard-op graph (QDQ, per-channel int8 weights, uint8 activations, MinMax
  calibration on the ``--calibration`` recording's instances, the MatMul / Gemm /
  Conv nodes as in tricons), written to OUT and timed like the float graph.

Per object: the first usable instance alone (batch 1). Per frame: each frame's
usable instances in one batch (graph only; preprocessing is reported by tract).
Medians over ``--runs`` after ``--warmup``; ``--threads`` for every runtime::

    cargo run --release -- bench --runs 20 --json ../data/bench/shipped-tract.json
    python -m tricons_pose.bench --checkpoint ../models/checkpoints/tricons-pose-v2/model-step6000.pt \\
        --standard-onnx ../data/models/tricons-pose-standard.onnx --tract-json ../data/bench/shipped-tract.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path
from typing import Callable, Dict, List, Sequence

import numpy as np
import torch

from .data import InstanceDataset, make_sample
from .export import INPUT_NAMES, OUTPUT_NAMES, load_checkpoint, random_model
from .predict import MIN_VALID_PIXELS
from .tricons_rng import instance_rng


def frame_batches(recording: str | os.PathLike, n_points: int, crop_size: int, seed: int) -> List[Dict[str, np.ndarray]]:
    """One input batch per frame with a usable instance, drawn exactly as ``tricons bench`` draws."""
    ds = InstanceDataset([recording], n_points=n_points, crop_size=crop_size, seed=seed, augment=None)
    per_frame: Dict[int, list] = {}
    for i in range(len(ds)):
        prep = ds.prepared(i)
        if prep is None or prep.n_valid <= MIN_VALID_PIXELS:
            continue
        ref = ds.index[i]
        per_frame.setdefault(ref.frame, []).append(
            make_sample(prep, n_points, crop_size, instance_rng(seed, ref.frame, ref.pos), None))
    return [{k: torch.stack([s[k] for s in samples]).numpy() for k in INPUT_NAMES}
            for _, samples in sorted(per_frame.items())]


def _time(fn: Callable[[], object], runs: int, warmup: int) -> List[float]:
    for _ in range(warmup):
        fn()
    out = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        out.append((time.perf_counter() - t) * 1e3)
    return out


def _stats(ms: Sequence[float]) -> dict:
    s = sorted(ms)
    q = lambda p: s[round((len(s) - 1) * p)]  # noqa: E731
    return {"median_ms": statistics.median(s), "p10_ms": q(0.1), "p90_ms": q(0.9), "samples": len(s)}


def bench_runtime(run: Callable[[Dict[str, np.ndarray]], object], batches, runs: int, warmup: int) -> dict:
    """Per-object (first instance, batch 1) and per-frame (graph on each frame's batch) latency."""
    one = {k: v[:1] for k, v in batches[0].items()}
    per_frame: List[float] = []
    for b in batches:
        per_frame += _time(lambda: run(b), runs, warmup)
    n_inst = sum(len(b["pts"]) for b in batches) / len(batches)
    return {"per_object": _stats(_time(lambda: run(one), runs, warmup)), "per_frame_graph": _stats(per_frame),
            "instances_per_frame": n_inst}


def quantize_ort(model_in: str, model_out: str, calibration: List[Dict[str, np.ndarray]]) -> None:
    """onnxruntime static quantization (QDQ) of the standard-op graph, one instance per calibration run."""
    from onnxruntime.quantization import (CalibrationDataReader, CalibrationMethod, QuantFormat, QuantType,
                                          quantize_static)

    class Reader(CalibrationDataReader):
        def __init__(self):
            self.items = iter([{k: v[i:i + 1] for k, v in b.items()} for b in calibration
                               for i in range(len(b["pts"]))])

        def get_next(self):
            return next(self.items, None)

    Path(model_out).parent.mkdir(parents=True, exist_ok=True)
    quantize_static(model_in, model_out, Reader(), quant_format=QuantFormat.QDQ, per_channel=True,
                    activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                    op_types_to_quantize=["MatMul", "Gemm", "Conv"], calibrate_method=CalibrationMethod.MinMax)


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point (see the module docstring)."""
    p = argparse.ArgumentParser(prog="python -m tricons_pose.bench", description=__doc__.split("\n")[0])
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--checkpoint", help="trained model (checkpoint.pt / model.pt)")
    src.add_argument("--config", help="configuration name with random weights (--random-init), e.g. paper")
    p.add_argument("--random-init", type=int, default=0, help="seed of the random weights (with --config)")
    p.add_argument("--standard-onnx", help="the --standard-ops export of the same weights (for onnxruntime)")
    p.add_argument("--recording", default=str(Path(__file__).resolve().parents[2] / "tests/data/synthnocs-demo"))
    p.add_argument("--runs", type=int, default=20)
    p.add_argument("--warmup", type=int, default=2)
    p.add_argument("--seed", type=int, default=0, help="point sampling seed (as tricons bench --seed)")
    p.add_argument("--threads", type=int, default=1, help="threads of every runtime (tract runs on 1)")
    p.add_argument("--tract-json", help="report of `tricons bench --json` to put in the table")
    p.add_argument("--json", help="write this script's measurements here")
    p.add_argument("--ort-int8", help="quantize --standard-onnx with onnxruntime to this file and time it too")
    p.add_argument("--calibration", default=str(Path(__file__).resolve().parents[2] / "calibration/synthnocs-calib"),
                   help="calibration recording of --ort-int8")
    args = p.parse_args(argv)

    torch.set_num_threads(args.threads)
    if args.checkpoint:
        model, cfg, _ = load_checkpoint(args.checkpoint)
    else:
        from .train import build_config

        cfg = build_config(args.config)
        model = random_model(cfg, args.random_init)
    batches = frame_batches(args.recording, cfg.n_points, cfg.crop_size, args.seed)
    if not batches:
        raise SystemExit(f"{args.recording}: no frame with a usable instance")

    @torch.no_grad()
    def run_torch(b):
        return model({k: torch.from_numpy(v) for k, v in b.items()})

    results = {"config_name": cfg.name, "threads": args.threads, "machine": platform.processor() or platform.machine(),
               "torch": torch.__version__, "pytorch": bench_runtime(run_torch, batches, args.runs, args.warmup)}
    if args.standard_onnx:
        import onnxruntime as ort

        so = ort.SessionOptions()
        so.intra_op_num_threads = args.threads
        so.inter_op_num_threads = 1
        sess = ort.InferenceSession(args.standard_onnx, so, providers=["CPUExecutionProvider"])
        ref = run_torch(batches[0])
        got = sess.run(list(OUTPUT_NAMES), batches[0])
        results["onnxruntime_max_abs_diff_t_m"] = float(np.abs(got[1] - ref["t"].numpy()).max())
        results["onnxruntime"] = bench_runtime(lambda b: sess.run(list(OUTPUT_NAMES), b), batches, args.runs,
                                               args.warmup)
        results["onnxruntime_version"] = ort.__version__
        if args.ort_int8:
            quantize_ort(args.standard_onnx, args.ort_int8,
                         frame_batches(args.calibration, cfg.n_points, cfg.crop_size, args.seed))
            qsess = ort.InferenceSession(args.ort_int8, so, providers=["CPUExecutionProvider"])
            got = qsess.run(list(OUTPUT_NAMES), batches[0])
            results["onnxruntime_int8_max_abs_diff_t_m"] = float(np.abs(got[1] - ref["t"].numpy()).max())
            results["onnxruntime_int8"] = bench_runtime(lambda b: qsess.run(list(OUTPUT_NAMES), b), batches,
                                                        args.runs, args.warmup)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(results, indent=2) + "\n")
    print(table(results, json.loads(Path(args.tract_json).read_text()) if args.tract_json else None))
    return 0


def table(results: dict, tract: dict | None) -> str:
    """Markdown table: runtime, per-object and per-frame medians (ms)."""
    rows = ["| runtime | per object, ms (p10-p90) | per frame graph, ms | per frame incl. preprocessing, ms |",
            "| --- | --- | --- | --- |"]
    fmt = lambda s: f"{s['median_ms']:.1f} ({s['p10_ms']:.1f}-{s['p90_ms']:.1f})"  # noqa: E731
    if tract:
        rows.append(f"| tract + tricons ops (1 thread) | {fmt(tract['per_object'])} | "
                    f"{tract['per_frame_graph']['median_ms']:.1f} | {tract['per_frame']['median_ms']:.1f} |")
        if tract.get("int8"):
            q = tract["int8"]
            rows.append(f"| tract + tricons int8 (1 thread) | {fmt(q['per_object'])} | "
                        f"{q['per_frame_graph']['median_ms']:.1f} | - |")
    names = {"onnxruntime": f"onnxruntime {results.get('onnxruntime_version', '')}, standard-op export",
             "onnxruntime_int8": f"onnxruntime {results.get('onnxruntime_version', '')} int8 (QDQ), same graph",
             "pytorch": f"PyTorch {results['torch']} eager"}
    for key in ("onnxruntime", "onnxruntime_int8", "pytorch"):
        if key in results:
            r = results[key]
            rows.append(f"| {names[key]} ({results['threads']} thread{'s' if results['threads'] > 1 else ''}) | "
                        f"{fmt(r['per_object'])} | {r['per_frame_graph']['median_ms']:.1f} | - |")
    head = f"{results['config_name']} config, {results['pytorch']['instances_per_frame']:.2f} instances/frame"
    return head + "\n\n" + "\n".join(rows)


if __name__ == "__main__":
    raise SystemExit(main())
