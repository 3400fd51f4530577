#!/usr/bin/env bash
# All the tests, as CI runs them (README "All tests"; `.ci/run` calls exactly this):
#   1. `cargo test --locked`: every Rust test on this machine (x86_64);
#   2. `cross/check.sh --tests-only aarch64`: the in-process Rust suites again for
#      aarch64 under qemu-user (see cross/check.sh for what it leaves to the host);
#   3. `tools/pytest.sh`: the Python model side (tools/tests).
# The three are the same commands as run one after the other; this script only overlaps
# them where one alone leaves a core idle: the Python environment is installed (network)
# while Rust builds; the host and the aarch64 builds run side by side (each spends long
# stretches on one crate at a time: tract's, then this one's), the aarch64 one in its own
# target directory (target/cross) so that neither waits for the other's lock; the tests
# run once both builds are done, the Python tests beside the aarch64 tests under qemu
# (which leave a core idle whenever one long test runs alone).
# A failure of any part fails the whole, with that part's output shown.
#
# Usage: ./test.sh        (TRICONS_SERIAL=1 runs the three strictly one after the other)
set -euo pipefail
cd "$(dirname "$0")"

if [ -n "${TRICONS_SERIAL:-}" ]; then
    cargo test --locked && cross/check.sh --tests-only aarch64 && tools/pytest.sh
    exit
fi

logs=$(mktemp -d)
pids=()
trap 'kill "${pids[@]}" 2>/dev/null; rm -rf "$logs"' EXIT
t0=$(date +%s)
stamp() { echo "== [$(( $(date +%s) - t0 )) s] $*"; }
# the aarch64 build and tests in their own target directory (see above)
cross_check() { CARGO_TARGET_DIR=target/cross cross/check.sh "$@"; }

# the venv (tools/pytest.sh installs it on first use; `--collect-only` makes it do only that)
stamp "installing tools/.venv in the background (log shown if it fails)"
tools/pytest.sh tests --collect-only -q >"$logs/venv.log" 2>&1 &
venv_pid=$!
pids+=("$venv_pid")

stamp "cross/check.sh --tests-only --build-only aarch64 in the background (log shown if it fails)"
cross_check --tests-only --build-only aarch64 >"$logs/cross-build.log" 2>&1 &
cross_pid=$!
pids+=("$cross_pid")

stamp "cargo test --locked --no-run (the host build, beside the aarch64 one)"
cargo test --locked --no-run
stamp "host build done"
if ! wait "$cross_pid"; then
    cat "$logs/cross-build.log" >&2
    stamp "the aarch64 build failed"
    exit 1
fi
tail -n 3 "$logs/cross-build.log"
stamp "aarch64 build done"

stamp "cargo test --locked"
cargo test --locked
stamp "host suite passed"

if ! wait "$venv_pid"; then
    cat "$logs/venv.log" >&2
    stamp "installing tools/.venv failed"
    exit 1
fi
stamp "tools/pytest.sh in the background (its output follows the aarch64 suite)"
tools/pytest.sh >"$logs/pytest.log" 2>&1 &
pytest_pid=$!
pids+=("$pytest_pid")

stamp "cross/check.sh --tests-only aarch64 (tests under qemu)"
qemu_rc=0
cross_check --tests-only aarch64 || qemu_rc=$?
stamp "aarch64 suite: exit $qemu_rc; waiting for pytest"
pytest_rc=0
wait "$pytest_pid" || pytest_rc=$?
cat "$logs/pytest.log"
stamp "pytest: exit $pytest_rc"
if [ "$qemu_rc" -ne 0 ] || [ "$pytest_rc" -ne 0 ]; then
    exit 1
fi
stamp "all tests passed"
