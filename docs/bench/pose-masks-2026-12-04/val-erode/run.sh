#!/usr/bin/env bash
# erosion sweep on SynthNOCS-val, shipped models, 3 sampling seeds
set -euo pipefail
cd /work/main
for e in 0 1 2 3; do for s in 0 1 2; do
  taskset -c 1 target/release/tricons replay --recording data/synthnocs-val --masks model --pose-mask-erode $e --seed $s --threads 1 \
    --out data/eval/erode-val/e$e-seed$s.jsonl > data/eval/erode-val/e$e-seed$s.txt 2>&1
done; done
echo finished
