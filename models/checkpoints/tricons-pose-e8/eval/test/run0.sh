#!/usr/bin/env bash
set -euo pipefail; cd /work/main
for s in 0 1 2; do
  taskset -c 0 target/release/tricons replay --recording data/synthnocs-test --model data/eval/e8-gt/tricons-pose.card.json --masks model --seed $s --threads 1 --out data/eval/test-cmp/e8-model-seed$s.jsonl > data/eval/test-cmp/e8-model-seed$s.txt 2>&1
done; echo finished
