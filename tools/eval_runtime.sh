#!/usr/bin/env bash
# A pose checkpoint evaluated as the runtime serves it (tools/MODEL.md, "E6, second look"):
# export with the shipped card's rotation rules (the keypoint fit for bowls, a blend of the head
# and the fit for cameras, laptops and mugs), then `tricons replay` on one recording with
# ground-truth masks and with the shipped Mask R-CNN's, at three point-sampling seeds, one
# thread; then the mean (lowest-highest) over the seeds, overall and per class.
#
# Usage: tools/eval_runtime.sh CHECKPOINT OUT_DIR [RECORDING]   (from the repository root)
#   CHECKPOINT  model.pt or checkpoint.pt of tricons_pose.train
#   OUT_DIR     gets tricons-pose.onnx + card, <gt|model>-seed<S>.{jsonl,eval.json,txt}, summary.md
#   RECORDING   default data/synthnocs-val
# Environment: TRICONS (default target/release/tricons), SEEDS (default "0 1 2"),
#   MASKS (default "gt model"), ROTATION_FROM_KEYPOINTS (default bowl, as the shipped card),
#   ROTATION_KEYPOINT_BLEND (default camera=0.5,laptop=0.25,mug=0.5, as the shipped card; "none"
#   leaves the field out, the protocol before 2026-12-06),
#   CONSISTENCY_SCORE_SCALE (default 0.3, as the shipped card; "none" leaves the field out),
#   MIN_SCORE (default 0.6, as the shipped card; "none" leaves the field out; replay with
#   ground-truth masks reports every pose whatever it says),
#   EXPORT_ARGS (more arguments for the export, e.g. --no-check: the onnx reference evaluator's
#   GatherElements cannot run the relative-coordinate variants' graphs, numpy.choose's 64 limit).
set -euo pipefail
[ $# -ge 2 ] || { sed -n 2,20p "$0" >&2; exit 2; }
ckpt=$1 out=$2 rec=${3:-data/synthnocs-val}
tricons=${TRICONS:-target/release/tricons}
seeds=${SEEDS:-0 1 2}
masks=${MASKS:-gt model}
[ -f "$ckpt" ] || { echo "error: no checkpoint $ckpt" >&2; exit 1; }
[ -x "$tricons" ] || { echo "error: $tricons not built (cargo build --release)" >&2; exit 1; }
mkdir -p "$out"
consistency=
[ "${CONSISTENCY_SCORE_SCALE:-0.3}" = none ] || consistency="--consistency-score-scale ${CONSISTENCY_SCORE_SCALE:-0.3}"
min_score=
[ "${MIN_SCORE:-0.6}" = none ] || min_score="--min-score ${MIN_SCORE:-0.6}"
blend=${ROTATION_KEYPOINT_BLEND:-camera=0.5,laptop=0.25,mug=0.5}
[ "$blend" = none ] && blend=
root=$(pwd)
out=$(cd "$out" && pwd)
case $ckpt in /*) ;; *) ckpt=$root/$ckpt ;; esac
(cd tools && .venv/bin/python -m tricons_pose.export --checkpoint "$ckpt" --out "$out/tricons-pose.onnx" \
    --rotation-from-keypoints "${ROTATION_FROM_KEYPOINTS:-bowl}" --rotation-keypoint-blend "$blend" $consistency $min_score \
    ${EXPORT_ARGS:-} >"$out/export.log" 2>&1) \
    || { cat "$out/export.log" >&2; echo "error: export of $ckpt failed" >&2; exit 1; }
. tools/eval_common.sh
for m in $masks; do
    replay_seeds "$m" --model "$out/tricons-pose.card.json" --masks "$m"
done
{
    echo "# $ckpt on $rec (seeds: $seeds)"
    for m in $masks; do
        echo
        echo "## $m masks"
        echo
        seeds_summary "$m" "$m masks" IoU50,IoU75,5deg2cm,10deg5cm
    done
} >"$out/summary.md"
cat "$out/summary.md"
