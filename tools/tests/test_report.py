"""Markdown tables of tricons eval reports (tricons_pose.report)."""

from __future__ import annotations

import json

from tricons_pose import report as R


def _rep(v50: float, bottle: float) -> dict:
    return {"mean": {"IoU50": v50, "10deg5cm": None},
            "classes": [{"class": "bottle", "ap": {"IoU50": bottle, "10deg5cm": None}}]}


def test_one_report_per_row_and_best_in_bold():
    t = R.table([("a", _rep(70.04, 1.0)), ("b", _rep(71.0, 2.0))], ["IoU50", "10deg5cm"], bold_best=True)
    assert t.splitlines()[0] == "| Method | IoU50 | 10°5cm |"
    assert t.splitlines()[2] == "| a | 70.0 | - |" and t.splitlines()[3] == "| b | **71.0** | - |"


def test_several_reports_give_mean_and_range(tmp_path):
    paths = []
    for k, (v, b) in enumerate([(70.0, 10.0), (73.0, 40.0), (71.5, 25.0)]):
        paths.append(tmp_path / f"s{k}.json")
        paths[-1].write_text(json.dumps(_rep(v, b)))
    reps = R._load(",".join(map(str, paths)))
    assert len(reps) == 3
    assert R.table([("seeds", reps)], ["IoU50"]).splitlines()[2] == "| seeds | 71.5 (70.0-73.0) |"
    pc = R.per_class(reps, ["IoU50", "10deg5cm"]).splitlines()
    assert pc[2] == "| bottle | 25.0 (10.0-40.0) | - |" and pc[3] == "| mean | 71.5 (70.0-73.0) | - |"
    # one path: the report itself, cells without a range
    assert R._load(str(paths[0]))["mean"]["IoU50"] == 70.0


def test_per_class_median_errors_come_from_the_class_fields():
    reps = [{"mean": {"IoU50": 70.0},
             "classes": [{"class": "camera", "ap": {"IoU50": 60.0}, "median_rotation_deg": d,
                          "median_translation_cm": None}]} for d in (6.0, 8.0)]
    pc = R.per_class(reps, ["IoU50", "median_rotation_deg", "median_translation_cm"]).splitlines()
    assert pc[0] == "| class | IoU50 | median rot. (°) | median transl. (cm) |"
    assert pc[2] == "| camera | 60.0 (60.0-60.0) | 7.0 (6.0-8.0) | - |"
    assert pc[3] == "| mean | 70.0 (70.0-70.0) | - | - |"
