#!/usr/bin/env bash
# 2 threads, paper config: this binary then onnxruntime, on both cores. First pass while the E6 pose
# training kept running on core 0 (not paused), so both runtimes shared core 0 with it; second
# pass (paper-t2.txt after "second") with the training finished and a nice-10 build on core 1.
set -u
cd "$(dirname "$0")/../../.."
out=docs/bench/softmax-2026-12-03
echo "== paper sm 2 threads $(date +%H:%M:%S)" >> $out/paper-t2.txt
taskset -c 0,1 /tmp/tricons-sm bench --model data/models/tricons-pose-paper.card.json --runs 5 --threads 2 \
  --json $out/paper-sm-t2.json 2>/dev/null | grep -E "^per (object|frame)" >> $out/paper-t2.txt
echo "== paper onnxruntime 2 threads $(date +%H:%M:%S)" >> $out/paper-t2.txt
(cd tools && taskset -c 0,1 .venv/bin/python -m tricons_pose.bench --config paper --random-init 0 \
  --standard-onnx ../data/models/tricons-pose-paper-standard.onnx --runs 5 --threads 2 \
  --json ../$out/ort-paper-t2.json) 2>&1 | grep -E "onnxruntime" >> $out/paper-t2.txt
echo "== done $(date +%H:%M:%S)" >> $out/paper-t2.txt
