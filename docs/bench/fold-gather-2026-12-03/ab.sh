#!/usr/bin/env bash
# A/B on core 1: LN-only binary (before) vs this binary (after), paper config + shipped, float, then onnxruntime.
set -u
cd /work/main
out=docs/bench/fold-gather-2026-12-03
before=/tmp/tricons-ln
after=/tmp/tricons-new
py=tools/.venv/bin/python
run() { echo "== $* $(date +%H:%M:%S)"; }
for pass in 1 2; do
  for b in before after; do
    bin=$before; [ $b = after ] && bin=$after
    run shipped $b pass $pass >> $out/shipped.txt
    taskset -c 1 $bin bench --runs 10 --threads 1 2>/dev/null | grep -E "^per (object|frame)" >> $out/shipped.txt
  done
done
for b in before after; do
  bin=$before; [ $b = after ] && bin=$after
  run paper $b >> $out/paper.txt
  taskset -c 1 $bin bench --model data/models/tricons-pose-paper.card.json --runs 5 --threads 1 --json $out/paper-$b.json 2>/dev/null | grep -E "^per (object|frame)" >> $out/paper.txt
done
run paper onnxruntime 1 thread >> $out/paper.txt
(cd tools && taskset -c 1 .venv/bin/python -m tricons_pose.bench --config paper --random-init 0 --standard-onnx ../data/models/tricons-pose-paper-standard.onnx --runs 5 --threads 1 --json ../$out/ort-paper-t1.json) >> $out/paper.txt 2>&1
train=$(pgrep -f "tricons_pose.maskrcnn train" | head -1); [ -n "$train" ] && kill -STOP $train
run paper after 2 threads, training paused >> $out/paper.txt
taskset -c 0,1 $after bench --model data/models/tricons-pose-paper.card.json --runs 5 --threads 2 --json $out/paper-after-t2.json 2>/dev/null | grep -E "^per (object|frame)" >> $out/paper.txt
run paper onnxruntime 2 threads >> $out/paper.txt
(cd tools && taskset -c 0,1 .venv/bin/python -m tricons_pose.bench --config paper --random-init 0 --standard-onnx ../data/models/tricons-pose-paper-standard.onnx --runs 5 --threads 2 --json ../$out/ort-paper-t2.json) >> $out/paper.txt 2>&1
[ -n "$train" ] && kill -CONT $train
run done >> $out/paper.txt
