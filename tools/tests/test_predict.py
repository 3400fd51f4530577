"""predict.py: a checkpoint's predictions in the tricons format, scored by `tricons eval`."""

import json
import subprocess

import numpy as np
import pytest
import torch

from tricons_pose.config import ModelConfig
from tricons_pose.predict import CLASSES
from tricons_pose.model import TriConsPose
from tricons_pose.predict import load_model, predict_recording, write_jsonl
from tricons_pose.recording import Recording


def tiny_config() -> ModelConfig:
    return ModelConfig.shipped().replace(n_points=256, n_keypoints=8, crop_size=32)


def test_predictions_cover_every_frame_and_evaluate(tmp_path, recording, tricons_bin):
    torch.manual_seed(0)
    cfg = tiny_config()
    ckpt = tmp_path / "model.pt"
    torch.save({"config": cfg.to_dict(), "model": TriConsPose(cfg).state_dict()}, ckpt)
    model, loaded = load_model(ckpt)
    assert loaded == cfg and not model.training

    frames = predict_recording(model, loaded, recording, batch_size=4)
    rec = Recording(recording)
    assert [f["frame"] for f in frames] == [fr.id for fr in rec.frames]
    n_gt = sum(len(rec.annotations(i).instances) for i in range(len(rec)))
    n_pred = sum(len(f["instances"]) for f in frames)
    assert 0 < n_pred <= n_gt
    for f in frames:
        for inst in f["instances"]:
            r = np.array(inst["R"])
            assert np.allclose(r.T @ r, np.eye(3), atol=1e-4) and np.linalg.det(r) > 0
            assert all(v > 0 for v in inst["s"])
    # deterministic for the same settings; another batch size changes only float rounding
    assert predict_recording(model, loaded, recording, batch_size=4) == frames
    other = predict_recording(model, loaded, recording, batch_size=3)
    for fa, fb in zip(frames, other):
        assert len(fa["instances"]) == len(fb["instances"])
        for a, b in zip(fa["instances"], fb["instances"]):
            assert a["class"] == b["class"]
            for key in ("R", "t", "s"):
                assert np.allclose(a[key], b[key], atol=1e-4), key

    pred = tmp_path / "pred.jsonl"
    write_jsonl(pred, frames)
    report = tmp_path / "report.json"
    res = subprocess.run(
        [str(tricons_bin), "eval", "--gt", str(recording), "--pred", str(pred), "--json", str(report)],
        capture_output=True,
        text=True,
    )
    assert res.returncode == 0, res.stderr
    means = json.loads(report.read_text())["mean"]
    assert set(means) >= {"IoU25", "IoU50", "IoU75", "5deg2cm", "5deg5cm", "10deg2cm", "10deg5cm"}


def test_tricons_rng_reproduces_the_committed_sequences():
    """The Python port of the runtime RNG still produces tests/fixtures/rng/sequences.json
    (which cargo test checks against the Rust RNG)."""
    import json
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    sys.path.insert(0, str(root / "tools" / "golden"))
    from make_rng_fixtures import build

    committed = json.loads((root / "tests" / "fixtures" / "rng" / "sequences.json").read_text())
    assert build() == committed


def test_tricons_sampler_draws_without_replacement_when_possible():
    from tricons_pose.data import sample_indices
    from tricons_pose.tricons_rng import instance_rng

    idx = sample_indices(300, 64, instance_rng(0, 3, 1))
    assert len(set(idx.tolist())) == 64 and idx.max() < 300
    again = sample_indices(300, 64, instance_rng(0, 3, 1))
    assert (idx == again).all()
    assert not (idx == sample_indices(300, 64, instance_rng(0, 3, 2))).all()


def test_keypoint_rotation_recovers_a_similarity_transform():
    """Exact case: keypoints that are a rotated, scaled, shifted copy of their NOCS
    coordinates give back that rotation (a proper one, never a reflection)."""
    from tricons_pose.predict import keypoint_rotation
    from tricons_pose.rotation import rotation_matrix_from_6d

    g = torch.Generator().manual_seed(5)
    R = rotation_matrix_from_6d(torch.randn(4, 6, generator=g, dtype=torch.float64))
    nocs = torch.rand(4, 32, 3, generator=g, dtype=torch.float64) - 0.5
    scale = torch.tensor([0.1, 0.3, 1.0, 2.0], dtype=torch.float64).view(4, 1, 1)
    t = torch.randn(4, 1, 3, generator=g, dtype=torch.float64)
    pts = scale * nocs @ R.transpose(1, 2) + t
    got = keypoint_rotation(nocs, pts)
    assert torch.allclose(got, R, atol=1e-9)
    assert torch.allclose(torch.linalg.det(got), torch.ones(4, dtype=torch.float64))
    # a mirrored point set still yields a rotation (det +1), not the reflection
    mirrored = pts * torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64)
    assert torch.allclose(torch.linalg.det(keypoint_rotation(nocs, mirrored)), torch.ones(4, dtype=torch.float64))


def test_rotation_from_keypoints_replaces_only_the_listed_classes(recording):
    """The listed classes get the keypoint fit's rotation, every other field and class
    stays the head's; an unknown class name is refused."""
    from tricons_pose.predict import parse_classes

    torch.manual_seed(0)
    cfg = tiny_config()
    model = TriConsPose(cfg).eval()
    head = predict_recording(model, cfg, recording, batch_size=4)
    classes = {i["class"] for f in head for i in f["instances"]}
    chosen = sorted(classes)[:1]
    mixed = predict_recording(model, cfg, recording, batch_size=4, rotation_from_keypoints=chosen)
    every = predict_recording(model, cfg, recording, batch_size=4, rotation_from_keypoints=parse_classes("all"))
    changed = 0
    for fh, fm, fe in zip(head, mixed, every):
        for h, m, e in zip(fh["instances"], fm["instances"], fe["instances"]):
            assert m["t"] == h["t"] and m["s"] == h["s"] and e["t"] == h["t"]
            if h["class"] in chosen:
                assert m["R"] == e["R"]
                changed += m["R"] != h["R"]
            else:
                assert m["R"] == h["R"]
    assert changed > 0
    assert parse_classes("bottle, mug") == ("bottle", "mug") and parse_classes("") == ()
    with pytest.raises(ValueError, match="unknown classes"):
        predict_recording(model, cfg, recording, rotation_from_keypoints=("cup",))


def test_rotation_keypoint_blend_lies_between_the_head_and_the_fit(recording):
    """A blended class reports the weighted chordal mean of the head's rotation and the keypoint
    fit's: on the geodesic between them, atan2(w sin a, 1 - w + w cos a) from the head for two
    rotations a apart; other classes and fields unchanged; bad blends refused."""
    import math

    from tricons_pose.predict import blend_rotations, check_blend, parse_blend

    torch.manual_seed(0)
    cfg = tiny_config()
    model = TriConsPose(cfg).eval()
    head = predict_recording(model, cfg, recording, batch_size=4)
    every = predict_recording(model, cfg, recording, batch_size=4, rotation_from_keypoints=CLASSES)
    classes = sorted({i["class"] for f in head for i in f["instances"]})
    w = 0.3
    blended = predict_recording(model, cfg, recording, batch_size=4,
                                rotation_keypoint_blend={classes[0]: w})

    def angle(a, b):
        r = torch.tensor(a, dtype=torch.float64).T @ torch.tensor(b, dtype=torch.float64)
        return math.acos(max(-1.0, min(1.0, (float(torch.trace(r)) - 1) / 2)))

    checked = 0
    for fh, fe, fb in zip(head, every, blended):
        for h, e, b in zip(fh["instances"], fe["instances"], fb["instances"]):
            assert b["t"] == h["t"] and b["s"] == h["s"]
            if h["class"] != classes[0]:
                assert b["R"] == h["R"]
                continue
            a = angle(h["R"], e["R"])
            if a < 1e-3:
                continue
            assert abs(angle(h["R"], b["R"]) + angle(b["R"], e["R"]) - a) < 1e-5
            assert abs(angle(h["R"], b["R"]) - math.atan2(w * math.sin(a), 1 - w + w * math.cos(a))) < 1e-5
            checked += 1
    assert checked > 0
    # the helper itself: a proper rotation, the midpoint of rotations about one axis
    Rz = lambda t: torch.tensor([[math.cos(t), -math.sin(t), 0], [math.sin(t), math.cos(t), 0], [0, 0, 1.0]],
                                dtype=torch.float64)
    assert torch.allclose(blend_rotations(Rz(0.0), Rz(0.8), 0.5), Rz(0.4), atol=1e-12)
    assert parse_blend("camera=0.5, mug=0.25") == {"camera": 0.5, "mug": 0.25} and parse_blend("") == {}
    for bad, words in ((lambda: parse_blend("camera"), "CLASS=WEIGHT"),
                       (lambda: check_blend({"cup": 0.5}), "unknown class"),
                       (lambda: check_blend({"mug": 1.0}), "strictly between"),
                       (lambda: check_blend({"mug": 0.5}, ("mug",)), "also in rotation_from_keypoints")):
        with pytest.raises(ValueError, match=words):
            bad()


def test_keypoint_residual_exact_cases():
    """Keypoints on the head's pose give 0; every keypoint moved by a 3-4-0 cm vector
    gives 5 cm over the diagonal; a larger disagreement gives a larger residual."""
    from tricons_pose.predict import keypoint_residual

    torch.manual_seed(1)
    R = torch.linalg.qr(torch.randn(2, 3, 3, dtype=torch.float64))[0]
    R = R * torch.linalg.det(R)[:, None, None]  # proper rotations
    t = torch.tensor([[0.1, -0.2, 0.9], [0.0, 0.0, 1.0]], dtype=torch.float64)
    s = torch.tensor([[0.08, 0.2, 0.08], [0.3, 0.4, 0.0]], dtype=torch.float64)
    nocs = torch.rand(2, 16, 3, dtype=torch.float64) - 0.5
    d = s.norm(dim=-1)
    on_pose = d[:, None, None] * (nocs @ R.transpose(1, 2)) + t[:, None, :]
    assert torch.allclose(keypoint_residual(R, t, s, nocs, on_pose), torch.zeros(2, dtype=torch.float64), atol=1e-12)
    moved = on_pose + torch.tensor([0.03, 0.04, 0.0], dtype=torch.float64)
    got = keypoint_residual(R, t, s, nocs, moved)
    assert torch.allclose(got, 0.05 / d)
    assert (keypoint_residual(R, t, s, nocs, on_pose + 2 * (moved - on_pose)) > got).all()


def test_consistency_scores_leave_the_poses_alone(recording):
    """With a consistency scale the scores are exp(-r / scale) in (0, 1]; every pose is
    the one reported without it."""
    torch.manual_seed(0)
    cfg = tiny_config()
    model = TriConsPose(cfg).eval()
    plain = predict_recording(model, cfg, recording, batch_size=4)
    scored = predict_recording(model, cfg, recording, batch_size=4, consistency_score_scale=0.3)
    n = 0
    for fp, fs in zip(plain, scored):
        for p, q in zip(fp["instances"], fs["instances"]):
            assert p["score"] == 1.0 and 0.0 < q["score"] < 1.0
            assert (p["R"], p["t"], p["s"]) == (q["R"], q["t"], q["s"])
            n += 1
    assert n > 0
