#!/usr/bin/env bash
# A Mask R-CNN checkpoint evaluated as the runtime serves it (docs/results.md, the segmenter
# sections): export over a copy of the shipped segmenter card (its threshold, duplicate
# suppression and pose-stage mask fields kept), then on one recording
#   - `tricons segment --json`: box and mask AP at the card's threshold and detections per object;
#   - where each detection falls (right class / wrong class / partial / no object), by
#     docs/bench/duplicates-2026-12-02/breakdown.py;
#   - `tricons replay --masks model` with the shipped pose model at three point-sampling seeds, one
#     thread; then the mean (lowest-highest) over the seeds, overall and per class.
#
# Usage: tools/eval_segmenter.sh CHECKPOINT OUT_DIR [RECORDING]   (from the repository root)
#   CHECKPOINT  last.pt or model-step*.pt of `python -m tricons_pose.maskrcnn train`
#   OUT_DIR     gets maskrcnn.onnx + card, seg.{json,txt}, breakdown.txt,
#               model-seed<S>.{jsonl,eval.json,txt}, summary.md
#   RECORDING   default data/synthnocs-val
# Environment: TRICONS (default target/release/tricons), SEEDS (default "0 1 2"),
#   CARD (the card whose fields are kept, default models/maskrcnn-light.card.json),
#   POSE (the pose card, default models/tricons-pose.card.json).
set -euo pipefail
[ $# -ge 2 ] || { sed -n 2,18p "$0" >&2; exit 2; }
ckpt=$1 out=$2 rec=${3:-data/synthnocs-val}
tricons=${TRICONS:-target/release/tricons}
seeds=${SEEDS:-0 1 2}
card=${CARD:-models/maskrcnn-light.card.json}
pose=${POSE:-models/tricons-pose.card.json}
[ -f "$ckpt" ] || { echo "error: no checkpoint $ckpt" >&2; exit 1; }
[ -f "$card" ] || { echo "error: no segmenter card $card" >&2; exit 1; }
[ -x "$tricons" ] || { echo "error: $tricons not built (cargo build --release)" >&2; exit 1; }
mkdir -p "$out"
root=$(pwd)
out=$(cd "$out" && pwd)
case $ckpt in /*) ;; *) ckpt=$root/$ckpt ;; esac
# the export keeps the chosen fields of a card already beside it (maskrcnn.write_card)
cp "$card" "$out/maskrcnn.card.json"
(cd tools && .venv/bin/python -m tricons_pose.maskrcnn export --checkpoint "$ckpt" --out "$out/maskrcnn.onnx" \
    >"$out/export.log" 2>&1) \
    || { cat "$out/export.log" >&2; echo "error: export of $ckpt failed" >&2; exit 1; }
"$tricons" segment --recording "$rec" --model "$out/maskrcnn.card.json" --out "$out/segment" \
    --json "$out/seg.json" >"$out/seg.txt" 2>&1 \
    || { cat "$out/seg.txt" >&2; echo "error: segment failed" >&2; exit 1; }
tools/.venv/bin/python docs/bench/duplicates-2026-12-02/breakdown.py "$rec" "$out/segment/segments.jsonl" \
    >"$out/breakdown.txt"
rm -rf "$out/segment"
. tools/eval_common.sh
replay_seeds model --model "$pose" --masks model --segmenter "$out/maskrcnn.card.json"
{
    echo "# $ckpt on $rec (pose model $pose; seeds: $seeds)"
    echo
    echo '```'
    grep -E "AP|per object|detections" "$out/seg.txt" || true
    cat "$out/breakdown.txt"
    echo '```'
    echo
    seeds_summary model pipeline IoU25,IoU50,IoU75,5deg2cm,5deg5cm,10deg2cm,10deg5cm
} >"$out/summary.md"
cat "$out/summary.md"
