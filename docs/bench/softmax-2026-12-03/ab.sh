#!/usr/bin/env bash
# A/B on core 1: the binary before SoftmaxLastAxis (/tmp/tricons-nosm, commit 8d8abaa's
# tree plus the bench's module grouping) against this one (/tmp/tricons-sm), paper config
# and shipped model, float, alternated, then onnxruntime on the same graphs and inputs.
# Pose training (E6) ran on core 0 throughout except where it says paused.
set -u
cd "$(dirname "$0")/../../.."
out=docs/bench/softmax-2026-12-03
run() { echo "== $* $(date +%H:%M:%S)"; }
for pass in 1 2 3; do
  for b in nosm sm; do
    run paper $b pass $pass >> $out/paper.txt
    taskset -c 1 /tmp/tricons-$b bench --model data/models/tricons-pose-paper.card.json --runs 5 --threads 1 \
      --json $out/paper-$b-$pass.json 2>/dev/null | grep -E "^per (object|frame)" >> $out/paper.txt
  done
  run paper onnxruntime pass $pass >> $out/paper.txt
  (cd tools && taskset -c 1 .venv/bin/python -m tricons_pose.bench --config paper --random-init 0 \
    --standard-onnx ../data/models/tricons-pose-paper-standard.onnx --runs 5 --threads 1 \
    --json ../$out/ort-paper-$pass.json) 2>&1 | grep -E "onnxruntime" >> $out/paper.txt
done
for pass in 1 2; do
  for b in nosm sm; do
    run shipped $b pass $pass >> $out/shipped.txt
    taskset -c 1 /tmp/tricons-$b bench --runs 10 --threads 1 2>/dev/null | grep -E "^per (object|frame)" >> $out/shipped.txt
  done
done
run done >> $out/paper.txt
