#!/usr/bin/env bash
set -euo pipefail; cd /work/main
for s in 0 1 2; do
  taskset -c 1 target/release/tricons replay --recording data/synthnocs-test --model data/eval/e8-gt/tricons-pose.card.json --masks gt --seed $s --threads 1 --out data/eval/test-cmp/e8-gt-seed$s.jsonl > data/eval/test-cmp/e8-gt-seed$s.txt 2>&1
  taskset -c 1 target/release/tricons replay --recording data/synthnocs-test --masks gt --seed $s --threads 1 --out data/eval/test-cmp/shipped-gt-seed$s.jsonl > data/eval/test-cmp/shipped-gt-seed$s.txt 2>&1
done; echo finished
