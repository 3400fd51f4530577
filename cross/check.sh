#!/usr/bin/env bash
# Verifies the ARM builds on a machine without Docker: Debian's cross linkers
# and qemu-user run the release build and the full Rust test suite for
# aarch64-unknown-linux-gnu and armv7-unknown-linux-gnueabihf.
#
# Usage: cross/check.sh [--tests-only] [--all-tests] [--build-only] [aarch64] [armv7]   (default: both targets)
#   --tests-only   skip the release build and the cold-start run
#   --build-only   build the test binaries, run nothing (./test.sh builds first, then runs
#                  the qemu suite beside the Python tests)
#   --all-tests    also run the suites that drive the binary as a separate process
#                  (cli_tests, service_tests: signals, files, sockets, the process's
#                  exit status; the same on every ISA, and under qemu they take most of
#                  the run), the doc examples and the slow control-logic tests listed in
#                  ISA_INDEPENDENT below. Without it, every other test runs: the library's unit
#                  tests, the kernels, int8, the pose and Mask R-CNN graphs against their
#                  golden fixtures, metrics, recordings, capture decoders, synth, built
#                  without the `ros2` feature (its serialisation tests run on the host).
#
# Installs what is missing (apt packages as root, rustup targets for the
# toolchain pinned in rust-toolchain.toml). Prints binary sizes and an
# indicative cold-start time under qemu.
set -euo pipefail
cd "$(dirname "$0")/.."

tests_only=""
all_tests=""
no_run=()
wanted=()
for arg in "$@"; do
    case "$arg" in
        --tests-only) tests_only=1 ;;
        --all-tests) all_tests=1 ;;
        --build-only) no_run=(--no-run) ;;
        -h | --help) sed -n '2,22p' "$0"; exit 0 ;;
        *) wanted+=("$arg") ;;
    esac
done
[ ${#wanted[@]} -gt 0 ] || wanted=(aarch64 armv7)

# Slow tests of ISA-independent control logic, and the Mask R-CNN's golden test on
# more than one frame, left out of the default qemu run (names as libtest filters;
# --all-tests runs them; they all run on the host).
ISA_INDEPENDENT=(
    shipped_segmenter_matches_onnxruntime_on_more_frames
    batch_norm_folding_matches_the_unfolded_graph
    card_and_graph_mismatches_are_clear_errors
    nan_depth_from_a_float_source_is_no_measurement
    unusable_masks_are_reported_not_estimated
    worker_threads_give_the_same_bits_as_one_thread
    quantize_is_deterministic_and_validate_reports_and_gates
    quantize_refuses_unusable_calibration_and_models_without_int8_nodes
    the_most_sensitive_nodes_go_float_and_the_rest_still_loads
    frames_without_objects_run_and_follow_threshold_and_size
    raised_score_floor_keeps_exactly_the_detections_above_the_threshold
    rendered_ground_truth_is_self_consistent
    masks_and_annotations_agree_and_handles_can_hide
    # Each loads and plans the whole shipped pose graph under qemu (~200 s apiece on one
    # core, 366 s for the determinism test, which estimates a frame twice; timed in
    # docs/results.md, "Test suite", stops 28 and 29). They check graph rewrites, control
    # logic and the f64 keypoint fit: on this ISA
    # every kernel a rewrite brings in is checked against tract's own op and its reference
    # in ops_kernel_tests, and the fully rewritten graph against PyTorch's outputs in
    # fixture_inputs_through_the_estimator_match_pytorch, both of which still run here.
    a_whole_demo_frame_is_estimated_deterministically
    kernel_rewrite_gives_the_unrewritten_graph_bit_for_bit
    layer_norm_rewrite_matches_the_unrewritten_graph
    softmax_rewrite_matches_the_unrewritten_graph
    early_pixel_gather_matches_the_unrewritten_graph
    moving_means_before_products_matches_the_graph_as_exported
    rotation_from_keypoints_follows_the_card_and_matches_pytorch
    # four Mask R-CNN runs for a thread-sharing property (shipped_segmenter_matches_onnxruntime
    # checks the segmenter's numerics here)
    a_shared_segmenter_gives_the_same_detections_on_two_threads
    # two Mask R-CNN runs to check which masks reach the pose stage (control logic; the
    # erosion and depth-outlier kernels are the library's unit tests, which run here)
    the_pose_stage_gets_the_cards_eroded_masks_without_depth_outliers
)

declare -A TRIPLE=([aarch64]=aarch64-unknown-linux-gnu [armv7]=armv7-unknown-linux-gnueabihf)
declare -A GCC=([aarch64]=aarch64-linux-gnu-gcc [armv7]=arm-linux-gnueabihf-gcc)
declare -A QEMU=([aarch64]=qemu-aarch64-static [armv7]=qemu-arm-static)
declare -A SYSROOT=([aarch64]=/usr/aarch64-linux-gnu [armv7]=/usr/arm-linux-gnueabihf)
declare -A APT=([aarch64]="gcc-aarch64-linux-gnu libc6-dev-arm64-cross" [armv7]="gcc-arm-linux-gnueabihf libc6-dev-armhf-cross")

missing=()
for arch in "${wanted[@]}"; do
    [ -n "${TRIPLE[$arch]:-}" ] || { echo "unknown target '$arch' (aarch64 or armv7)" >&2; exit 2; }
    command -v "${GCC[$arch]}" >/dev/null || missing+=(${APT[$arch]})
    command -v "${QEMU[$arch]}" >/dev/null || missing+=(qemu-user-static)
done
if [ ${#missing[@]} -gt 0 ]; then
    echo "== installing ${missing[*]}"
    sudo_cmd=()
    [ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
    "${sudo_cmd[@]}" apt-get update -qq
    DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

installed=$(rustup target list --installed)
for arch in "${wanted[@]}"; do
    grep -qx "${TRIPLE[$arch]}" <<<"$installed" || rustup target add "${TRIPLE[$arch]}"
done

for arch in "${wanted[@]}"; do
    triple=${TRIPLE[$arch]}
    env_triple=$(tr 'a-z-' 'A-Z_' <<<"$triple")
    runner="${QEMU[$arch]} -L ${SYSROOT[$arch]}"
    export "CARGO_TARGET_${env_triple}_LINKER=${GCC[$arch]}"
    export "CARGO_TARGET_${env_triple}_RUNNER=$runner"
    # The CLI tests spawn the tricons binary; without binfmt it needs qemu too.
    export TRICONS_TEST_RUNNER="$runner"

    if [ -z "$tests_only" ]; then
        echo "== $triple: release build"
        cargo build --release --locked --target "$triple" --bin tricons
        bin=target/$triple/release/tricons
        size=$(stat -c %s "$bin")
        echo "$triple: binary $bin is $((size / 1024)) KiB"
        tmp=$(mktemp -d)
        start=$(date +%s%N)
        $runner "$bin" synth --out "$tmp/rec" --frames 1 --seed 1 >/dev/null 2>&1
        $runner "$bin" inspect "$tmp/rec" --predictions >"$tmp/gt.jsonl"
        $runner "$bin" eval --gt "$tmp/rec" --pred "$tmp/gt.jsonl" --json "$tmp/r.json" >/dev/null
        end=$(date +%s%N)
        echo "$triple: cold start under qemu (synth 1 frame + inspect + eval): $(((end - start) / 1000000)) ms (qemu timing is indicative only)"
        rm -rf "$tmp"
    fi

    if [ -n "$all_tests" ]; then
        echo "== $triple: test suite under ${QEMU[$arch]}"
        cargo test --locked --target "$triple" "${no_run[@]}"
    else
        suites=()
        for f in tests/*.rs; do
            name=$(basename "$f" .rs)
            case "$name" in cli_tests | service_tests | bad_input_tests) ;; *) suites+=(--test "$name") ;; esac
        done
        # ISA_INDEPENDENT: control logic whose numerics the golden-fixture tests already
        # cover on this ISA (each 1-8 s on the host, 30-80x that under qemu; timings in
        # docs/results.md). They run on the host in CI.
        # Without the `ros2` feature: its code is byte-level serialisation (CDR is little-endian
        # on every supported target) tested on the host, and RustDDS, ros2-client, mcap and
        # the zstd/lz4 C libraries are a large part of what a fresh aarch64 build compiles.
        # --all-tests builds the default features.
        features=(--no-default-features --features v4l)
        skips=()
        for t in "${ISA_INDEPENDENT[@]}"; do skips+=(--skip "$t"); done
        echo "== $triple: test suite under ${QEMU[$arch]} (library and $((${#suites[@]} / 2)) integration suites less the ${#ISA_INDEPENDENT[@]} tests of ISA_INDEPENDENT; --all-tests runs everything)"
        if [ ${#no_run[@]} -gt 0 ]; then
            cargo test --locked --target "$triple" "${features[@]}" --lib "${suites[@]}" --no-run
        else
            cargo test --locked --target "$triple" "${features[@]}" --lib "${suites[@]}" -- "${skips[@]}"
        fi
    fi
done
