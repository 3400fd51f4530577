"""Shared fixtures: tiny SynthNOCS recordings written by the project's own Rust CLI.

The ``tricons`` binary is found via ``$TRICONS_BIN``, else
``<repo>/target/release/tricons``, else ``<repo>/target/debug/tricons`` (also
under ``$CARGO_TARGET_DIR``), else built with ``cargo build`` in the repo root.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

TOOLS = Path(__file__).resolve().parents[1]
REPO = TOOLS.parent
if str(TOOLS) not in sys.path:
    sys.path.insert(0, str(TOOLS))


def _candidates():
    env = os.environ.get("TRICONS_BIN")
    if env:
        yield Path(env)
    roots = [REPO / "target"]
    if os.environ.get("CARGO_TARGET_DIR"):
        roots.insert(0, Path(os.environ["CARGO_TARGET_DIR"]))
    for root in roots:
        for profile in ("release", "debug"):
            yield root / profile / "tricons"


def find_tricons() -> Path:
    """Path of a tricons binary, building one with cargo if none exists."""
    env = os.environ.get("TRICONS_BIN")
    if env and not Path(env).is_file():
        raise RuntimeError(f"TRICONS_BIN={env} does not exist")
    for p in _candidates():
        if p.is_file() and os.access(p, os.X_OK):
            return p
    cargo = shutil.which("cargo")
    if cargo is None:
        pytest.skip("no tricons binary and no cargo to build one (set TRICONS_BIN)")
    subprocess.run([cargo, "build", "--quiet", "--bin", "tricons"], cwd=REPO, check=True)
    for p in _candidates():
        if p.is_file():
            return p
    raise RuntimeError("cargo build finished but no tricons binary was found")


def synth(out: Path, frames: int, seed: int, *extra: str) -> Path:
    """Run ``tricons synth`` into ``out`` and return it."""
    subprocess.run(
        [str(find_tricons()), "synth", "--out", str(out), "--frames", str(frames), "--seed", str(seed), *extra],
        check=True,
        capture_output=True,
    )
    return out


@pytest.fixture(scope="session")
def tricons_bin() -> Path:
    return find_tricons()


@pytest.fixture(scope="session")
def recording(tmp_path_factory) -> Path:
    """3 frames, seed 5, default sensor noise (depth holes)."""
    return synth(tmp_path_factory.mktemp("rec") / "sn", 3, 5)


@pytest.fixture(scope="session")
def recording_clean(tmp_path_factory) -> Path:
    """2 frames, seed 11, no depth noise."""
    return synth(tmp_path_factory.mktemp("rec_clean") / "sn", 2, 11, "--no-depth-noise")
