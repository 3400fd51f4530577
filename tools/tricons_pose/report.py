"""Markdown tables from ``tricons eval --json`` reports (for docs/results.md)::

    python -m tricons_pose.report --row "AG-Pose (baseline)=../data/eval/baseline.published.json" \\
        --row "Full=../data/eval/shipped.published.json" --metrics 5deg2cm,5deg5cm,10deg2cm,10deg5cm
    python -m tricons_pose.report --per-class ../data/eval/shipped.published.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

ALL_METRICS = ("IoU25", "IoU50", "IoU75", "5deg2cm", "5deg5cm", "10deg2cm", "10deg5cm")
HEADER = {"IoU25": "IoU25", "IoU50": "IoU50", "IoU75": "IoU75", "5deg2cm": "5°2cm", "5deg5cm": "5°5cm",
          "10deg2cm": "10°2cm", "10deg5cm": "10°5cm"}


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.1f}"


def table(rows: list[tuple[str, dict]], metrics, first: str = "Method", bold_best: bool = False) -> str:
    """One row per (name, report) with the mean AP of each metric."""
    best = {m: max((r["mean"].get(m) or -1) for _, r in rows) for m in metrics}
    lines = [f"| {first} | " + " | ".join(HEADER.get(m, m) for m in metrics) + " |",
             "| --- |" + " --- |" * len(metrics)]
    for name, r in rows:
        cells = []
        for m in metrics:
            v = r["mean"].get(m)
            s = _fmt(v)
            cells.append(f"**{s}**" if bold_best and v is not None and v == best[m] and len(rows) > 1 else s)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def per_class(report: dict, metrics) -> str:
    """One row per class, then the mean."""
    lines = ["| class | " + " | ".join(HEADER.get(m, m) for m in metrics) + " |", "| --- |" + " --- |" * len(metrics)]
    for c in report["classes"]:
        lines.append(f"| {c['class']} | " + " | ".join(_fmt(c['ap'].get(m)) for m in metrics) + " |")
    lines.append("| mean | " + " | ".join(_fmt(report["mean"].get(m)) for m in metrics) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--row", action="append", default=[], metavar="NAME=REPORT.json")
    p.add_argument("--per-class", metavar="REPORT.json")
    p.add_argument("--metrics", default=",".join(ALL_METRICS))
    p.add_argument("--first", default="Method", help="header of the first column")
    p.add_argument("--bold-best", action="store_true")
    a = p.parse_args(argv)
    metrics = [m for m in a.metrics.split(",") if m]
    if a.per_class:
        print(per_class(json.loads(Path(a.per_class).read_text()), metrics))
    if a.row:
        rows = []
        for item in a.row:
            name, _, path = item.rpartition("=")
            rows.append((name, json.loads(Path(path).read_text())))
        print(table(rows, metrics, a.first, a.bold_best))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
