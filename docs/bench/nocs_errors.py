"""Pose errors of one prediction against one ground-truth instance (JSON Lines dicts with R, t),
shared by the throwaway analysis scripts under docs/bench/: bottle, bowl and can by the angle of
their symmetry axes (y), every other class by the full rotation; translation in centimetres."""
import numpy as np

SYM = {"bottle", "bowl", "can"}


def rerr(a, b, cls):
    Ra, Rb = np.array(a["R"]), np.array(b["R"])
    if cls in SYM:
        ya, yb = Ra[:, 1], Rb[:, 1]
        return np.degrees(np.arccos(np.clip(ya @ yb / np.linalg.norm(ya) / np.linalg.norm(yb), -1, 1)))
    return np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1)))


def terr(a, b):
    return np.linalg.norm(np.array(a["t"]) - np.array(b["t"])) * 100
