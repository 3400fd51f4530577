#!/usr/bin/env bash
# SynthNOCS-test, shipped models: the segmenter's masks as predicted vs the card's pose-stage mask handling
set -euo pipefail
cd /work/main
for s in 0 1 2; do
  taskset -c 1 target/release/tricons replay --recording data/synthnocs-test --masks model --seed $s --threads 1 \
    --out data/eval/masks-test/card-seed$s.jsonl > data/eval/masks-test/card-seed$s.txt 2>&1
  taskset -c 1 target/release/tricons replay --recording data/synthnocs-test --masks model --pose-mask-erode 0 --keep-depth-outliers --seed $s --threads 1 \
    --out data/eval/masks-test/raw-seed$s.jsonl > data/eval/masks-test/raw-seed$s.txt 2>&1
done
echo finished
