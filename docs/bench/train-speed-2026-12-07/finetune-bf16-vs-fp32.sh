#!/bin/bash
# bf16 vs fp32 from a trained checkpoint: 750 steps (one full lr cycle), then the ablation's eval
set -e
cd /work/main/tools
INIT=/work/main/data/runs/ablation/shipped-s1/cycle2/model-step3000.pt
for m in fp32-eager fp32-compile bf16-compile; do
  out=/work/main/data/speed/ft/$m
  [ -f $out/model-step750.pt ] && continue
  extra=""
  case $m in fp32-compile) extra="--compile";; bf16-compile) extra="--compile --autocast bf16";; esac
  taskset -c 1 .venv/bin/python -m tricons_pose.train --data ../data/synthnocs-train ../data/synthnocs-train2 --config shipped \
    --out $out --epochs 100 --batch-size 16 --seed 31 --workers 1 --threads 1 --cache-dir ../data/cache-train \
    --frame-cache disk --lr 5e-5 --max-lr 3e-4 --lr-mode triangular --cycle-steps 375 --keep-cycle-ends \
    --max-steps 750 --ckpt-every 250 --mask-perturb 0.2 --log-every 50 --init-from $INIT $extra > $out.log 2>&1
done
cd /work/main
for m in fp32-eager fp32-compile bf16-compile; do
  d=data/speed/ft/$m
  [ -f $d/eval-val/gt-seed2.eval.json ] && continue
  MASKS=gt SEEDS="0 1 2" EXPORT_ARGS=--no-check ROTATION_KEYPOINT_BLEND=none MIN_SCORE=none \
    taskset -c 1 tools/eval_runtime.sh $d/model-step750.pt $d/eval-val data/synthnocs-val > $d.eval.log 2>&1
done
echo done
