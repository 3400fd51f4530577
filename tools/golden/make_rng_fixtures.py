"""Write tests/fixtures/rng/sequences.json: the runtime RNG's sequences, from the Python port.

``cargo test`` checks that ``tricons::synth::rng`` and ``pose::sample_indices`` produce
these numbers and pytest checks that ``tricons_pose.tricons_rng`` still does, so the
port that lets PyTorch sample the points ``tricons replay`` samples cannot drift::

    python tools/golden/make_rng_fixtures.py --out tests/fixtures/rng/sequences.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tricons_pose.tricons_rng import TriconsRng, instance_rng, mix_seed  # noqa: E402

SEEDS = (0, 1, 7, 2**63 + 12345, 2**64 - 1)
MIX_WORDS = ([], [0], [1, 2], [2, 1], [0, 5, 3], [2**64 - 1, 42])
SAMPLE_CASES = ((10, 10), (100, 7), (5, 12), (1, 3), (20000, 16))
INSTANCE_CASES = ((0, 0, 0), (0, 3, 2), (9, 123, 7))


def build() -> dict:
    """The fixture content (integers as decimal strings: u64 does not fit JSON doubles)."""
    return {
        "mix_seed": [{"words": [str(w) for w in ws], "seed": str(mix_seed(ws))} for ws in MIX_WORDS],
        "next_u64": [{"seed": str(s), "values": [str(v) for v in _take(TriconsRng(s), 6)]} for s in SEEDS],
        "below": [{"seed": str(s), "n": n, "values": _below(TriconsRng(s), n, 5)}
                  for s in (3, 11) for n in (1, 2, 1000, 2**40)],
        "sample_indices": [{"seed": str(s), "n_valid": nv, "n": n,
                            "indices": TriconsRng(s).sample_indices(nv, n).tolist()}
                           for s in (0, 99) for nv, n in SAMPLE_CASES],
        "instance_rng": [{"seed": s, "frame": f, "instance": i,
                          "indices": instance_rng(s, f, i).sample_indices(50, 8).tolist()}
                         for s, f, i in INSTANCE_CASES],
    }


def _below(rng: TriconsRng, n: int, count: int) -> list[int]:
    return [rng.below(n) for _ in range(count)]


def _take(rng: TriconsRng, n: int) -> list[int]:
    return [rng.next_u64() for _ in range(n)]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_name(args.out.name + f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(build(), indent=1) + "\n")
    os.replace(tmp, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
