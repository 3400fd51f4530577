#!/usr/bin/env bash
# Python-side tests (what CI runs after `cargo test`). Run from anywhere:
#   tools/pytest.sh [pytest args...]   (default: all of tools/tests; paths are relative to tools/)
# Creates tools/.venv (python3 -m venv) on first use and reinstalls
# tools/requirements.txt only when its hash changed. Set PYTHON to pick the
# interpreter that creates the venv (default python3), TRICONS_BIN to use a
# specific tricons binary for the test recordings.
set -euo pipefail
tools="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$tools/.venv"
req="$tools/requirements.txt"
stamp="$venv/.requirements.sha256"
if [ ! -x "$venv/bin/python" ]; then
    "${PYTHON:-python3}" -m venv "$venv"
fi
want="$(sha256sum "$req" | cut -d' ' -f1)"
have="$(cat "$stamp" 2>/dev/null || true)"
if [ "$want" != "$have" ]; then
    "$venv/bin/python" -m pip install -q --upgrade pip
    "$venv/bin/python" -m pip install -q -r "$req"
    echo "$want" > "$stamp"
fi
cd "$tools"
if [ $# -eq 0 ]; then set -- tests; fi
exec "$venv/bin/python" -m pytest -q "$@"
