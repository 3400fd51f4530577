# Shared by tools/eval_runtime.sh and tools/eval_segmenter.sh (sourced, not run): `tricons
# replay` at several point-sampling seeds and the markdown summary of the runs.
# Needs: $tricons (the binary), $rec (the recording), $out (absolute output dir), $seeds.

# replay_seeds NAME REPLAY_ARGS...: one `tricons replay` per seed, one thread, into
# $out/NAME-seed<S>.{jsonl,eval.json,txt}; exits on the first failure with its log shown.
replay_seeds() {
    local name=$1 s
    shift
    for s in $seeds; do
        "$tricons" replay --recording "$rec" "$@" --seed "$s" --threads 1 --out "$out/$name-seed$s.jsonl" \
            >"$out/$name-seed$s.txt" 2>&1 \
            || { cat "$out/$name-seed$s.txt" >&2; echo "error: replay ($name, seed $s) failed" >&2; exit 1; }
    done
}

# seeds_summary NAME ROW METRICS: the mean (lowest-highest) over the seeds as one table row
# named ROW with METRICS, then the per-class table.
seeds_summary() {
    local name=$1 row=$2 metrics=$3 files
    files=$(for s in $seeds; do printf '%s,' "$out/$name-seed$s.eval.json"; done)
    (cd tools && .venv/bin/python -m tricons_pose.report --row "$row=$files" --metrics "$metrics")
    echo
    (cd tools && .venv/bin/python -m tricons_pose.report --per-class "$files" \
        --metrics IoU50,IoU75,5deg2cm,10deg5cm,median_rotation_deg)
}
