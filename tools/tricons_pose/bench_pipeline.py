"""onnxruntime running the whole per-frame work, for ``tricons bench --pipeline``.

    python -m tricons_pose.bench_pipeline --segmenter ../models/maskrcnn-light.onnx \\
        --pose ../data/models/tricons-pose-standard.onnx --threads 1,2 [--json OUT]

Per frame of the recording: the Mask R-CNN on the colour image (the graph as exported,
or with ``--score-floor S`` its score floor raised to S as tricons does at load), then
the pose graph (``export --standard-ops``) on as many instances as the Mask R-CNN kept
(score >= --score-threshold). The pose inputs are the frame's ground-truth instances,
drawn as ``tricons bench`` draws them and repeated in order when there are more
detections than objects: the pose graph's cost depends only on the instance count.
Medians over --runs after --warmup, at each thread count (intra-op threads; one
inter-op thread).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from .bench import frame_batches
from .export import OUTPUT_NAMES


def raise_score_floor(model_path: str, floor: float) -> bytes:
    """The graph with torchvision's ``scores > box_score_thresh`` constant replaced by the
    largest float below ``floor`` (so ``>`` keeps ``>= floor``), as bytes."""
    import onnx
    from onnx import numpy_helper

    m = onnx.load(model_path)
    g = m.graph
    producers = {o: n for n in g.node for o in n.output}
    consts = {t.name: t for t in g.initializer}
    for n in g.node:
        if n.op_type == "Constant":
            consts[n.output[0]] = n.attribute[0].t

    def from_softmax(name: str) -> bool:
        for _ in range(16):
            p = producers.get(name)
            if p is None:
                return False
            if p.op_type == "Softmax":
                return True
            if p.op_type not in ("Reshape", "Slice", "Flatten", "Gather", "Squeeze", "Unsqueeze", "Identity"):
                return False
            name = p.input[0]
        return False

    floors = [n for n in g.node if n.op_type == "Greater" and n.input[1] in consts and from_softmax(n.input[0])]
    if len(floors) != 1:
        raise SystemExit(f"{model_path}: {len(floors)} score floors found, expected one")
    value = np.nextafter(np.float32(floor), np.float32(-np.inf)).astype(np.float32)
    name = "bench.score_floor"
    g.initializer.append(numpy_helper.from_array(np.array(value, np.float32), name))
    floors[0].input[1] = name
    return m.SerializeToString()


def _median_ms(times: Sequence[float]) -> float:
    return float(statistics.median(times)) * 1e3


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point (see the module docstring)."""
    import onnxruntime as ort
    from PIL import Image

    from .recording import Recording

    root = Path(__file__).resolve().parents[2]
    p = argparse.ArgumentParser(prog="python -m tricons_pose.bench_pipeline", description=__doc__.split("\n")[0])
    p.add_argument("--segmenter", default=str(root / "models/maskrcnn-light.onnx"))
    p.add_argument("--pose", required=True, help="the pose graph with standard ops (export --standard-ops)")
    p.add_argument("--recording", default=str(root / "tests/data/synthnocs-demo"))
    p.add_argument("--threads", default="1,2", help="comma-separated intra-op thread counts")
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--warmup", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--score-threshold", type=float, default=0.5, help="detections kept (the card's threshold)")
    p.add_argument("--score-floor", type=float, default=None,
                   help="raise the graph's score floor to this before NMS and the mask head (tricons' rewrite)")
    p.add_argument("--n-points", type=int, default=512)
    p.add_argument("--crop-size", type=int, default=96)
    p.add_argument("--json")
    args = p.parse_args(argv)
    threads = [int(t) for t in args.threads.split(",")]

    rec = Recording(args.recording)
    images = [(np.asarray(Image.open(rec.root / f.color).convert("RGB")).astype(np.float32) / 255.0)
              .transpose(2, 0, 1).copy() for f in rec.frames]
    batches = frame_batches(args.recording, args.n_points, args.crop_size, args.seed)
    seg_model = raise_score_floor(args.segmenter, args.score_floor) if args.score_floor is not None else args.segmenter
    results = []
    for t in threads:
        so = ort.SessionOptions()
        so.intra_op_num_threads = t
        so.inter_op_num_threads = 1
        seg = ort.InferenceSession(seg_model, so, providers=["CPUExecutionProvider"])
        pose = ort.InferenceSession(args.pose, so, providers=["CPUExecutionProvider"])
        seg_ms, pose_ms, total_ms, dets = [], [], [], []
        for run in range(args.warmup + args.runs):
            for img, batch in zip(images, batches):
                t0 = time.perf_counter()
                out = seg.run(None, {"image": img})
                t1 = time.perf_counter()
                n = int((out[2] >= args.score_threshold).sum())
                if n:
                    idx = np.arange(n) % len(batch["pts"])
                    pose.run(list(OUTPUT_NAMES), {k: v[idx] for k, v in batch.items()})
                t2 = time.perf_counter()
                if run >= args.warmup:
                    seg_ms.append(t1 - t0)
                    pose_ms.append(t2 - t1)
                    total_ms.append(t2 - t0)
                    dets.append(n)
        frame = _median_ms(total_ms)
        results.append({"threads": t, "per_frame_ms": frame, "segment_ms": _median_ms(seg_ms),
                        "pose_ms": _median_ms(pose_ms), "detections_per_frame": float(np.mean(dets)),
                        "frames_per_s": 1e3 / frame})
    report = {"runtime": f"onnxruntime {ort.__version__}", "segmenter": args.segmenter, "pose": args.pose,
              "score_floor": args.score_floor, "recording": args.recording, "frames": len(images),
              "machine": platform.processor() or platform.machine(), "results": results}
    print(f"onnxruntime pipeline: {args.segmenter} (score floor {args.score_floor or 'as exported'}) + {args.pose}")
    print(f"{'threads':>7} {'frame ms':>10} {'segment ms':>11} {'pose ms':>9} {'detections':>11} {'frames/s':>9}")
    for r in results:
        print(f"{r['threads']:>7} {r['per_frame_ms']:>10.1f} {r['segment_ms']:>11.1f} {r['pose_ms']:>9.1f} "
              f"{r['detections_per_frame']:>11.2f} {r['frames_per_s']:>9.2f}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
