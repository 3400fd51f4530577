"""Markdown tables from ``tricons eval --json`` reports (for docs/results.md)::

    python -m tricons_pose.report --row "AG-Pose (baseline)=../data/eval/baseline.published.json" \\
        --row "Full=../data/eval/shipped.published.json" --metrics 5deg2cm,5deg5cm,10deg2cm,10deg5cm
    python -m tricons_pose.report --per-class ../data/eval/shipped.published.json
    python -m tricons_pose.report --per-class s0.eval.json --metrics 5deg2cm,median_rotation_deg

A row or ``--per-class`` given several reports (comma-separated: the same model under
several sampling seeds) shows each cell as the mean and, in brackets, the lowest and
highest of them::

    python -m tricons_pose.report --row "shipped=s0.eval.json,s1.eval.json,s2.eval.json" --metrics IoU50,10deg5cm
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

ALL_METRICS = ("IoU25", "IoU50", "IoU75", "5deg2cm", "5deg5cm", "10deg2cm", "10deg5cm")
HEADER = {"IoU25": "IoU25", "IoU50": "IoU50", "IoU75": "IoU75", "5deg2cm": "5°2cm", "5deg5cm": "5°5cm",
          "10deg2cm": "10°2cm", "10deg5cm": "10°5cm",
          "median_rotation_deg": "median rot. (°)", "median_translation_cm": "median transl. (cm)"}
# per-class fields of a report (not APs) that ``--per-class`` can show; they have no mean row
CLASS_FIELDS = ("median_rotation_deg", "median_translation_cm")


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.1f}"


def _cell(values: list) -> tuple[float | None, str]:
    """(mean, text) of one metric over one or more reports: "m" or "m (lo-hi)"."""
    vals = [v for v in values if v is not None]
    if not vals:
        return None, "-"
    m = sum(vals) / len(vals)
    if len(values) == 1:
        return m, _fmt(m)
    return m, f"{m:.1f} ({min(vals):.1f}-{max(vals):.1f})"


def _reports(r) -> list[dict]:
    return r if isinstance(r, list) else [r]


def table(rows: list[tuple[str, dict | list[dict]]], metrics, first: str = "Method", bold_best: bool = False) -> str:
    """One row per (name, report or reports) with the mean AP of each metric
    (several reports: their mean, lowest and highest)."""
    cells = {name: [_cell([rep["mean"].get(m) for rep in _reports(r)]) for m in metrics] for name, r in rows}
    best = [max((cells[name][j][0] or -1) for name, _ in rows) for j in range(len(metrics))]
    lines = [f"| {first} | " + " | ".join(HEADER.get(m, m) for m in metrics) + " |",
             "| --- |" + " --- |" * len(metrics)]
    for name, _ in rows:
        out = []
        for j, (v, s) in enumerate(cells[name]):
            out.append(f"**{s}**" if bold_best and v is not None and v == best[j] and len(rows) > 1 else s)
        lines.append(f"| {name} | " + " | ".join(out) + " |")
    return "\n".join(lines)


def per_class(report: dict | list[dict], metrics) -> str:
    """One row per class, then the mean (several reports of one model: mean, lowest, highest)."""
    reps = _reports(report)
    lines = ["| class | " + " | ".join(HEADER.get(m, m) for m in metrics) + " |", "| --- |" + " --- |" * len(metrics)]
    for k, c in enumerate(reps[0]["classes"]):
        vals = [_cell([rep["classes"][k].get(m) if m in CLASS_FIELDS else rep["classes"][k]["ap"].get(m)
                       for rep in reps])[1] for m in metrics]
        lines.append(f"| {c['class']} | " + " | ".join(vals) + " |")
    lines.append("| mean | " + " | ".join("-" if m in CLASS_FIELDS else _cell([rep["mean"].get(m) for rep in reps])[1]
                                         for m in metrics) + " |")
    return "\n".join(lines)


def _load(paths: str) -> dict | list[dict]:
    reps = [json.loads(Path(x).read_text()) for x in paths.split(",") if x]
    return reps[0] if len(reps) == 1 else reps


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
        print(per_class(_load(a.per_class), metrics))
    if a.row:
        rows = []
        for item in a.row:
            name, _, path = item.rpartition("=")
            rows.append((name, _load(path)))
        print(table(rows, metrics, a.first, a.bold_best))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
