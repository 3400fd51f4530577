#!/usr/bin/env bash
# All the tests, as CI runs them (README "All tests"; `.ci/run` calls exactly this):
#   1. `cargo test --locked`: every Rust test on this machine (x86_64);
#   2. `cross/check.sh --tests-only aarch64`: the in-process Rust suites again for
#      aarch64 under qemu-user (see cross/check.sh for what it leaves to the host);
#   3. `tools/pytest.sh`: the Python model side (tools/tests).
# The three are the same commands as run one after the other; this script only overlaps
# what does not compete for the two cores: the Python environment is installed (network)
# while Rust builds, and the Python tests run beside the aarch64 tests under qemu (which
# leave a core idle whenever one long test runs alone), once the aarch64 build is done.
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
trap 'rm -rf "$logs"' EXIT
t0=$(date +%s)
stamp() { echo "== [$(( $(date +%s) - t0 )) s] $*"; }

# the venv (tools/pytest.sh installs it on first use; `--collect-only` makes it do only that)
stamp "installing tools/.venv in the background (log shown if it fails)"
tools/pytest.sh tests --collect-only -q >"$logs/venv.log" 2>&1 &
venv_pid=$!

stamp "cargo test --locked"
cargo test --locked
stamp "host suite passed"

stamp "cross/check.sh --tests-only aarch64 --build-only"
cross/check.sh --tests-only --build-only aarch64

if ! wait "$venv_pid"; then
    cat "$logs/venv.log" >&2
    stamp "installing tools/.venv failed"
    exit 1
fi
stamp "tools/pytest.sh in the background (its output follows the aarch64 suite)"
tools/pytest.sh >"$logs/pytest.log" 2>&1 &
pytest_pid=$!

stamp "cross/check.sh --tests-only aarch64 (tests under qemu)"
qemu_rc=0
cross/check.sh --tests-only aarch64 || qemu_rc=$?
stamp "aarch64 suite: exit $qemu_rc; waiting for pytest"
pytest_rc=0
wait "$pytest_pid" || pytest_rc=$?
cat "$logs/pytest.log"
stamp "pytest: exit $pytest_rc"
if [ "$qemu_rc" -ne 0 ] || [ "$pytest_rc" -ne 0 ]; then
    exit 1
fi
stamp "all tests passed"
