#!/usr/bin/env bash
# Speed benchmarks of the runtime against onnxruntime, all in one run on the same inputs
# (docs/results.md, "Speed"). Needs a release build, tools/.venv and the standard-op pose
# export (tools/README.md, "Export"):
#   cd tools && python -m tricons_pose.export --checkpoint ../models/checkpoints/tricons-pose-v2/model-step12000.pt \
#       --standard-ops --out ../data/models/tricons-pose-standard.onnx
# Usage: benches/speed.sh [OUT_DIR] (default data/bench/speed); BEFORE=path/to/old/tricons adds
# the older binary's pose and segmenter numbers in the same run. RUNS (default 10).
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-data/bench/speed}"
runs="${RUNS:-10}"
mkdir -p "$out"
bin=target/release/tricons
py=tools/.venv/bin/python
standard=data/models/tricons-pose-standard.onnx
[ -x "$bin" ] || { echo "build first: cargo build --release" >&2; exit 1; }
[ -f "$standard" ] || { echo "missing $standard (see the header of this script)" >&2; exit 1; }
image=tests/data/synthnocs-demo/000000_color.png
log() { echo "== $*" >&2; }

if [ -n "${BEFORE:-}" ]; then
    log "before: pose float + int8"
    "$BEFORE" bench --runs "$runs" --int8 models/tricons-pose.int8.json --json "$out/before-pose.json" > "$out/before-pose.txt"
    log "before: segmenter float + int8"
    "$BEFORE" bench --segmenter models/maskrcnn-light.card.json --int8 models/maskrcnn-light.int8.json \
        --runs "$runs" --json "$out/before-segment.json" > "$out/before-segment.txt"
fi
log "tricons: pose float + int8, 1 and 2 threads"
"$bin" bench --runs "$runs" --int8 models/tricons-pose.int8.json --threads 1,2 --json "$out/pose.json" > "$out/pose.txt"
log "tricons: segmenter float + int8, 1 and 2 threads"
"$bin" bench --segmenter models/maskrcnn-light.card.json --int8 models/maskrcnn-light.int8.json --runs "$runs" \
    --threads 1,2 --json "$out/segment.json" > "$out/segment.txt"
log "tricons: pipeline float and int8, 1 and 2 threads"
"$bin" bench --pipeline --runs "$runs" --threads 1,2 --json "$out/pipeline-float.json" > "$out/pipeline-float.txt"
"$bin" bench --pipeline --runs "$runs" --threads 1,2 --model models/tricons-pose.int8.json \
    --segmenter models/maskrcnn-light.int8.json --json "$out/pipeline-int8.json" > "$out/pipeline-int8.txt"
cd tools
for t in 1 2; do
    log "onnxruntime: pose, $t thread(s)"
    .venv/bin/python -m tricons_pose.bench --checkpoint ../models/checkpoints/tricons-pose-v2/model-step12000.pt \
        --standard-onnx "../$standard" --runs "$runs" --threads "$t" --json "../$out/ort-pose-t$t.json" > /dev/null
    log "onnxruntime: segmenter, $t thread(s)"
    .venv/bin/python -m tricons_pose.maskrcnn bench --model ../models/maskrcnn-light.onnx --image "../$image" \
        --runs "$runs" --threads "$t" > "../$out/ort-segment-t$t.json"
done
log "onnxruntime: pipeline, as exported and with the score floor raised"
.venv/bin/python -m tricons_pose.bench_pipeline --pose "../$standard" --threads 1,2 --runs "$runs" \
    --json "../$out/ort-pipeline.json" > "../$out/ort-pipeline.txt"
.venv/bin/python -m tricons_pose.bench_pipeline --pose "../$standard" --threads 1,2 --runs "$runs" --score-floor 0.5 \
    --json "../$out/ort-pipeline-floor.json" > "../$out/ort-pipeline-floor.txt"
cd ..
log "tricons serve: 300 frames, int8 models, --rate max, 2 threads"
"$bin" serve --recording tests/data/synthnocs-demo --rate max --loop 0 --frames 300 --threads 2 \
    --model models/tricons-pose.int8.json --segmenter models/maskrcnn-light.int8.json --no-listen \
    --out "$out/serve.jsonl" --stats-interval 0 --stats-out "$out/serve-stats.json" 2> "$out/serve.log" > /dev/null
rm -f "$out/serve.jsonl"
tail -1 "$out/serve.log"
log "tricons serve: the same with one segment worker (the stage as before --segment-workers)"
"$bin" serve --recording tests/data/synthnocs-demo --rate max --loop 0 --frames 300 --threads 2 --segment-workers 1 \
    --model models/tricons-pose.int8.json --segmenter models/maskrcnn-light.int8.json --no-listen \
    --out "$out/serve-w1.jsonl" --stats-interval 0 --stats-out "$out/serve-w1-stats.json" 2> "$out/serve-w1.log" > /dev/null
rm -f "$out/serve-w1.jsonl"
tail -1 "$out/serve-w1.log"
cat "$out"/*.txt
