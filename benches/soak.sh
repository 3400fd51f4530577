#!/usr/bin/env bash
# Soak benchmark of the pose service (not a test): `tricons serve` over the
# shipped demo recording in a loop for 10,000 frames, then the final health
# view (throughput, per-stage latency percentiles, dropped frames, memory).
#
# Usage: benches/soak.sh [gt|full] [frames]   (default: gt 10000)
#   gt    ground-truth masks, int8 pose model, --rate max (the pose service's
#         throughput; nothing may drop)
#   full  Mask R-CNN int8 + pose int8 on a live-rate source (30 fps): inference
#         is slower than the camera, so the capture queue drops (counted)
# Writes data/soak/<mode>.{stats.json,log,jsonl}; the log has a stats line
# (with resident memory) every 30 s.
set -euo pipefail
cd "$(dirname "$0")/.."
mode=${1:-gt}
frames=${2:-10000}
mkdir -p data/soak
rm -f "data/soak/$mode.jsonl"
cargo build --release --locked
common=(serve --recording tests/data/synthnocs-demo --loop 0 --frames "$frames" --no-listen
        --model models/tricons-pose.int8.json --out "data/soak/$mode.jsonl"
        --stats-out "data/soak/$mode.stats.json" --stats-interval 30)
case "$mode" in
    gt) extra=(--masks gt --rate max) ;;
    full) extra=(--masks model --segmenter models/maskrcnn-light.int8.json --rate recorded) ;;
    *) echo "mode: gt or full" >&2; exit 2 ;;
esac
/usr/bin/time -v target/release/tricons "${common[@]}" "${extra[@]}" 2> >(tee "data/soak/$mode.log" >&2)
echo "== data/soak/$mode.stats.json"
cat "data/soak/$mode.stats.json"
