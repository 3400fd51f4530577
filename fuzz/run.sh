#!/usr/bin/env bash
# Fuzz every target (or the named ones) for SECONDS each with libFuzzer and
# AddressSanitizer, on the pinned stable toolchain (RUSTC_BOOTSTRAP=1 lets it
# take the nightly-only sanitizer flags; nothing else changes).
#
# Usage: fuzz/run.sh [--smoke] [SECONDS] [TARGET...]   (default: 60 s, every target)
#   --smoke   no sanitizer (a faster build; crashes and hangs still found) and
#             SECONDS defaults to 10: a quick check
#
# Corpora grow in fuzz/corpus/TARGET (seeded from fuzz/seeds/TARGET and the shipped
# files in fuzz/seeds.txt); crashes land in fuzz/artifacts/TARGET. Copy a crash
# into fuzz/regressions/TARGET/ once fixed: `cargo test --test fuzz_inputs_tests`
# replays it from then on. Needs cargo-fuzz (`cargo install cargo-fuzz --locked`).
set -euo pipefail
cd "$(dirname "$0")"

sanitizer=address
secs=""
targets=()
for arg in "$@"; do
    case "$arg" in
        --smoke) sanitizer=none ;;
        -h | --help) sed -n '2,13p' "$0"; exit 0 ;;
        *[!0-9]*) targets+=("$arg") ;;
        *) secs=$arg ;;
    esac
done
[ -n "$secs" ] || { [ "$sanitizer" = none ] && secs=10 || secs=60; }
if [ ${#targets[@]} -eq 0 ]; then
    for f in fuzz_targets/*.rs; do targets+=("$(basename "$f" .rs)"); done
fi
command -v cargo-fuzz >/dev/null || { echo "cargo-fuzz not found: cargo install cargo-fuzz --locked" >&2; exit 1; }

export RUSTC_BOOTSTRAP=1
start=$(date +%s)
# Release build with debug assertions (-a: integer overflow is a failure too).
cargo fuzz build -a --sanitizer "$sanitizer"
echo "== built in $(( $(date +%s) - start )) s (sanitizer: $sanitizer)"

failed=()
for t in "${targets[@]}"; do
    mkdir -p "corpus/$t"
    [ -d "seeds/$t" ] && cp -n seeds/"$t"/* "corpus/$t/" 2>/dev/null || true
    while read -r target path; do
        [ "$target" = "$t" ] && cp -n "../$path" "corpus/$t/" 2>/dev/null || true
    done < <(grep -v '^#' seeds.txt)
    echo "== $t: ${secs} s"
    log=$(mktemp)
    if ! cargo fuzz run -a --sanitizer "$sanitizer" "$t" "corpus/$t" -- \
        -max_total_time="$secs" -timeout=10 -rss_limit_mb=2048 -max_len=65536 -print_final_stats=1 2>"$log"; then
        failed+=("$t")
        tail -n 30 "$log" >&2
    fi
    grep -E "stat::number_of_executed_units|stat::peak_rss_mb" "$log" | tr '\n' ' ' || true
    echo
    rm -f "$log"
done
if [ ${#failed[@]} -gt 0 ]; then
    echo "fuzzing found failures in: ${failed[*]} (inputs in fuzz/artifacts/)" >&2
    exit 1
fi
echo "== every target ran ${secs} s without a failure"
