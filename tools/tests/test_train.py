"""Training loop (tricons_pose.train): log, checkpoints, exact resume."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from tricons_pose import train as T
from tricons_pose.config import ModelConfig

CFG = ModelConfig.shipped().replace(n_points=256, crop_size=32, name="test")


class TinyModel(nn.Module):
    """Stand-in with the contract's forward_train(inputs, aug); uses rgb, choose, pts, aug and dropout."""

    def __init__(self, cfg):
        super().__init__()
        self.conv = nn.Conv2d(3, 4, 3, padding=1)
        self.point = nn.Linear(3 + 4, 16)
        self.drop = nn.Dropout(0.2)
        self.head = nn.Linear(16, 3 + 3 + 3)

    def forward_train(self, inputs, aug):
        B, N, _ = inputs["pts"].shape
        img = self.conv(inputs["rgb"]).flatten(2)  # (B, 4, S*S)
        f_im = torch.gather(img, 2, inputs["choose"].unsqueeze(1).expand(-1, 4, -1)).transpose(1, 2)
        c = inputs["pts"].mean(1, keepdim=True)
        P = inputs["pts"] - c
        P0 = aug["dS"][:, 0].unsqueeze(1) * (P @ aug["dR"][:, 0].transpose(1, 2)) + aug["dT"][:, 0].unsqueeze(1)
        f = self.drop(torch.relu(self.point(torch.cat([P0, f_im], -1)))).mean(1)
        o = self.head(f)
        return {"t": c.squeeze(1) + o[:, :3], "s": o[:, 3:6], "n": o[:, 6:]}


def tiny_loss(out, targets, cfg):
    pose = (out["t"] - targets["t"]).norm(dim=-1).mean() + (out["s"] - targets["s"]).norm(dim=-1).mean()
    nocs = (out["n"][:, None] - targets["nocs"]).abs().mean()
    return {"pose": pose, "nocs": nocs, "total": pose + 2 * nocs}


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """Shared preprocessed-instance cache: each frame is decoded once for all runs."""
    global _CACHE
    _CACHE = str(tmp_path_factory.mktemp("cache"))
    return _CACHE


_CACHE = None


@pytest.fixture(autouse=True)
def _use_cache(cache):
    yield


def _args(rec, out, *extra):
    return T.parse_args(["--data", str(rec), "--out", str(out), "--cache-dir", _CACHE, "--epochs", "3", "--batch-size", "2", "--seed", "4",
                         "--threads", "1", "--workers", "0", "--log-every", "1", "--lr", "1e-3", "--max-lr", "1e-2",
                         "--cycle-steps", "2", *extra])


def _run(args):
    return T.train(args, model_factory=TinyModel, loss_fn=tiny_loss, cfg=CFG)


def _log(path):
    return [json.loads(line) for line in (path / "log.jsonl").read_text().splitlines()]


def test_two_steps_write_log_and_checkpoint(recording, tmp_path):
    out = tmp_path / "run"
    summary = _run(_args(recording, out, "--max-steps", "2"))
    assert summary["step"] == 2
    log = _log(out)
    assert [r["step"] for r in log] == [1, 2]
    for r in log:
        assert {"epoch", "lr", "total", "pose", "nocs", "samples_per_s"} <= set(r)
    assert log[0]["lr"] == pytest.approx(1e-3) and log[1]["lr"] > log[0]["lr"]  # cyclic: rising
    ck = torch.load(out / "checkpoint.pt", weights_only=False)
    assert ck["step"] == 2 and ck["epoch"] == 0 and ck["step_in_epoch"] == 2
    assert {"model", "optimizer", "scheduler", "rng"} <= set(ck)
    assert not list(out.glob("*.tmp*"))
    info = json.loads((out / "config.json").read_text())
    assert info["model_config"]["name"] == "test" and info["n_samples"] >= 4


@pytest.mark.parametrize("stop_at,workers", [(2, "0"), (4, "1")])
def test_resume_continues_exactly(recording, tmp_path, stop_at, workers):
    """Interrupted at step k, resumed: the next steps' losses equal an uninterrupted run's."""
    steps_per_epoch = None
    full = tmp_path / "full"
    _run(_args(recording, full, "--max-steps", str(stop_at + 2), "--workers", workers))
    steps_per_epoch = json.loads((full / "config.json").read_text())["steps_per_epoch"]
    part = tmp_path / "part"
    _run(_args(recording, part, "--max-steps", str(stop_at), "--workers", workers))
    _run(_args(recording, part, "--max-steps", str(stop_at + 2), "--workers", workers, "--resume"))
    a, b = _log(full), _log(part)
    config = json.loads((part / "config.json").read_text())
    assert config["args"]["max_steps"] == stop_at and not config["args"]["resume"], "the first run's arguments stay"
    assert [(r["args"]["max_steps"], r["step"]) for r in config["resumed_with"]] == [(stop_at + 2, stop_at)]
    assert [r["step"] for r in b] == list(range(1, stop_at + 3))
    for ra, rb in zip(a, b):
        assert (ra["step"], ra["epoch"], ra["lr"]) == (rb["step"], rb["epoch"], rb["lr"])
        assert ra["total"] == rb["total"], (ra["step"], ra["total"], rb["total"])
    assert steps_per_epoch >= 2  # the runs cross an epoch boundary for stop_at=4 with 8 instances


def test_full_epochs_write_final_model(recording, tmp_path):
    out = tmp_path / "run"
    args = _args(recording, out, "--ckpt-every", "3")
    args.epochs = 1
    summary = _run(args)
    final = torch.load(out / "model.pt", weights_only=False)
    assert final["config"]["name"] == "test" and final["step"] == summary["step"]
    ck = torch.load(out / "checkpoint.pt", weights_only=False)
    assert ck["epoch"] == 1 and ck["step_in_epoch"] == 0


def test_resume_rejects_other_config(recording, tmp_path):
    out = tmp_path / "run"
    _run(_args(recording, out, "--max-steps", "1"))
    with pytest.raises(SystemExit, match="different model configuration"):
        T.train(_args(recording, out, "--resume"), model_factory=TinyModel, loss_fn=tiny_loss,
                cfg=CFG.replace(name="other"))


def test_config_names():
    assert T.build_config("shipped").name == "shipped"
    assert not T.build_config("baseline").use_sckd_loss
    assert not T.build_config("without_piga").use_piga
    with pytest.raises(SystemExit):
        T.build_config("nope")


def test_real_model_one_step(recording, tmp_path):
    """The real TriConsPose + compute_losses through the loop (tiny sizes)."""
    pytest.importorskip("tricons_pose.model")
    pytest.importorskip("tricons_pose.losses")
    out = tmp_path / "real"
    args = _args(recording, out, "--max-steps", "1")
    summary = T.train(args, cfg=CFG)
    assert summary["step"] == 1 and torch.isfinite(torch.tensor(summary["last"]["total"]))
    assert {"pose", "nocs", "cd", "cvc"} <= set(summary["last"])


def test_init_from_starts_at_the_given_weights_with_a_fresh_schedule(recording, tmp_path):
    """--init-from loads the source checkpoint's weights exactly and restarts the schedule."""
    src = tmp_path / "src"
    _run(_args(recording, src, "--max-steps", "3"))
    ck = torch.load(src / "checkpoint.pt", weights_only=False)
    out = tmp_path / "tuned"
    seen = {}

    def factory(cfg):
        m = TinyModel(cfg)
        orig = m.load_state_dict

        def load(state, *a, **k):
            seen["loaded"] = {n: v.clone() for n, v in state.items()}
            return orig(state, *a, **k)

        m.load_state_dict = load
        return m

    T.train(_args(recording, out, "--max-steps", "1", "--init-from", str(src / "checkpoint.pt"),
                  "--keep-cycle-ends"), model_factory=factory, loss_fn=tiny_loss, cfg=CFG)
    assert seen["loaded"].keys() == ck["model"].keys()
    assert all(torch.equal(seen["loaded"][n], ck["model"][n]) for n in ck["model"])
    log = _log(out)
    assert [r["step"] for r in log] == [1] and log[0]["lr"] == pytest.approx(1e-3)  # schedule restarted
    with pytest.raises(SystemExit, match="different model configuration"):
        T.train(_args(recording, tmp_path / "other", "--max-steps", "1", "--init-from", str(src / "checkpoint.pt")),
                model_factory=TinyModel, loss_fn=tiny_loss, cfg=CFG.replace(name="other"))


def test_keep_cycle_ends_saves_the_low_rate_weights(recording, tmp_path):
    out = tmp_path / "run"
    _run(_args(recording, out, "--max-steps", "4", "--keep-cycle-ends"))  # cycle = 2 x 2 steps
    kept = torch.load(out / "model-step4.pt", weights_only=False)
    assert kept["step"] == 4 and kept["config"]["name"] == "test"


@pytest.mark.parametrize("mode", ["triangular2", "triangular"])
def test_lr_mode_sets_the_height_of_later_cycles(recording, tmp_path, mode):
    """Half-cycle 2 steps from 1e-3 to 1e-2: the second cycle's peak (step 7) is half the
    first's (step 3) rise with triangular2 and the same with triangular; a resume keeps it."""
    out = tmp_path / mode
    _run(_args(recording, out, "--max-steps", "5", "--lr-mode", mode))
    _run(_args(recording, out, "--max-steps", "8", "--lr-mode", mode, "--resume"))
    lr = {r["step"]: r["lr"] for r in _log(out)}
    assert lr[3] == pytest.approx(1e-2)
    assert lr[7] == pytest.approx(1e-2 if mode == "triangular" else 1e-3 + 0.5 * (1e-2 - 1e-3))


def test_anneal_decays_from_lr_to_zero_over_max_steps(recording, tmp_path):
    """--lr-mode anneal: step k runs at lr (1 + cos(pi (k - 1) / max_steps)) / 2, falling every
    step; without --max-steps it refuses to start."""
    out = tmp_path / "anneal"
    _run(_args(recording, out, "--max-steps", "8", "--lr-mode", "anneal"))
    lr = {r["step"]: r["lr"] for r in _log(out)}
    assert sorted(lr) == list(range(1, 9))
    for k, v in lr.items():
        assert v == pytest.approx(1e-3 * 0.5 * (1 + math.cos(math.pi * (k - 1) / 8)))
    assert all(lr[k] > lr[k + 1] for k in range(1, 8))
    with pytest.raises(SystemExit, match="max-steps"):
        _run(_args(recording, tmp_path / "no-max", "--lr-mode", "anneal"))


def test_mixed_batches_take_each_sets_share_in_its_own_order():
    """--real: every batch has per_a instances of set A then per_b of set B; each set is walked
    in its own seeded permutation with wrap-around; a resume start skips exactly that many."""
    s = T.MixedEpochSampler(n_a=5, n_b=3, per_a=3, per_b=1, steps=4, seed=7, epoch=2)
    order = s.order()
    assert order.shape == (16,)
    batches = order.reshape(4, 4)
    assert (batches[:, :3] < 5).all() and (batches[:, 3] >= 5).all()
    # 12 draws from A: the permutation of 5 walked twice and then 2 more
    a = batches[:, :3].reshape(-1)
    assert sorted(a[:5]) == list(range(5)) and sorted(a[5:10]) == list(range(5)) and list(a[10:]) == list(a[:2])
    assert sorted(batches[:3, 3]) == [5, 6, 7] and batches[3, 3] == batches[0, 3]
    again = T.MixedEpochSampler(5, 3, 3, 1, 4, seed=7, epoch=2, start=8)
    assert [i for _, i in again] == list(order[8:]) and len(again) == 8
    assert list(T.MixedEpochSampler(5, 3, 3, 1, 4, seed=7, epoch=3).order()) != list(order)
    with pytest.raises(ValueError):
        T.MixedEpochSampler(5, 0, 3, 1, 4, seed=7)


def test_mixed_training_resumes_exactly(recording, tmp_path):
    """--data A --real B (here the same frames twice): batches mix, and an interrupted run
    resumed gives the uninterrupted run's losses."""
    mix = ("--real", str(recording), "--real-per-batch", "1", "--steps-per-epoch", "3")
    full, part = tmp_path / "full", tmp_path / "part"
    _run(_args(recording, full, "--max-steps", "5", *mix))
    _run(_args(recording, part, "--max-steps", "2", *mix))
    _run(_args(recording, part, "--max-steps", "5", "--resume", *mix))
    a, b = _log(full), _log(part)
    assert [r["step"] for r in a] == [1, 2, 3, 4, 5] and [r["epoch"] for r in a] == [0, 0, 0, 1, 1]
    for ra, rb in zip(a, b):
        assert (ra["step"], ra["lr"], ra["total"]) == (rb["step"], rb["lr"], rb["total"])
    info = json.loads((full / "config.json").read_text())
    assert info["steps_per_epoch"] == 3 and info["n_samples"] % 2 == 0
    with pytest.raises(SystemExit):
        _args(recording, full, "--real-per-batch", "1")  # without --real


def test_init_from_grows_a_class_agnostic_nocs_head_into_one_per_class():
    """A class-agnostic checkpoint starts a ``nocs_per_class`` model with the same outputs for
    every class; only that field (and the name) may differ."""
    from tricons_pose.model import TriConsPose

    small = CFG.replace(name="agnostic")
    torch.manual_seed(0)
    old = TriConsPose(small).eval()
    init = {"config": small.to_dict(), "model": old.state_dict()}
    grown_cfg = small.replace(nocs_per_class=True, name="per-class")
    new = TriConsPose(grown_cfg).eval()
    new.load_state_dict(T.init_weights(init, grown_cfg, "ck.pt"))
    B = 6
    x = {"rgb": torch.randn(B, 3, 32, 32), "pts": torch.randn(B, 256, 3) * 0.05 + torch.tensor([0.0, 0.0, 0.6]),
         "choose": torch.randint(0, 32 * 32, (B, 256)), "class_id": torch.arange(B)}
    with torch.no_grad():
        a, b = old(x), new(x)
    for k in ("R", "t", "s", "kpt_nocs"):
        assert torch.allclose(a[k], b[k], atol=1e-6), k
    # after the heads diverge, each instance reads its own class's row
    with torch.no_grad():
        new.nocs_head[-1].bias.view(6, 3)[2] += 0.3
        c = new(x)
    changed = (c["kpt_nocs"] - b["kpt_nocs"]).abs().amax(dim=(1, 2)) > 1e-4
    assert changed.tolist() == [False, False, True, False, False, False]
    with pytest.raises(ValueError, match="class_id"):
        new({k: v for k, v in x.items() if k != "class_id"})
    with pytest.raises(SystemExit, match="more than nocs_per_class"):
        T.init_weights(init, grown_cfg.replace(blocks=1), "ck.pt")


def test_init_from_accepts_another_crop_size_for_a_cnn_model_only():
    """A CNN model's weights do not depend on the crop size: a checkpoint starts a model of
    another crop with every tensor equal; any other difference is still refused."""
    from tricons_pose.model import TriConsPose

    small = CFG.replace(name="crop-a")
    torch.manual_seed(0)
    init = {"config": small.to_dict(), "model": TriConsPose(small).state_dict()}
    bigger = small.replace(crop_size=small.crop_size * 2, name="crop-b")
    new = TriConsPose(bigger)
    new.load_state_dict(T.init_weights(init, bigger, "ck.pt"))
    for k, v in new.state_dict().items():
        assert torch.equal(v, init["model"][k]), k
    with pytest.raises(SystemExit, match="different model configuration"):
        T.init_weights(init, bigger.replace(blocks=1), "ck.pt")


def test_mask_perturbation_is_an_option_of_the_run(recording, tmp_path):
    with pytest.raises(SystemExit):
        _args(recording, tmp_path / "x", "--mask-perturb", "1.5")
    out = tmp_path / "run"
    assert _run(_args(recording, out, "--max-steps", "1", "--mask-perturb", "0.5"))["step"] == 1
    assert json.loads((out / "config.json").read_text())["args"]["mask_perturb"] == 0.5


def test_disk_frame_cache_trains_on_the_same_samples_and_keeps_no_frames_in_memory(recording, tmp_path):
    with pytest.raises(SystemExit):  # disk reads --cache-dir's files
        T.parse_args(["--data", str(recording), "--out", str(tmp_path / "x"), "--frame-cache", "disk"])
    mem, disk = tmp_path / "mem", tmp_path / "disk"
    _run(_args(recording, mem, "--max-steps", "4", "--mask-perturb", "0.5"))
    _run(_args(recording, disk, "--max-steps", "4", "--mask-perturb", "0.5", "--frame-cache", "disk"))
    assert [r["total"] for r in _log(mem)] == [r["total"] for r in _log(disk)]
    args = _args(recording, tmp_path / "y", "--frame-cache", "disk")
    ds = T.training_dataset([recording], CFG, 4, args.cache_dir, mask_perturb=0.5, memory_cache=False)
    for i in range(len(ds)):
        ds[i]
    assert ds._mem == {} and len(list(Path(args.cache_dir).glob("*.npz"))) > 0


def test_compiled_training_follows_the_eager_run(recording, tmp_path):
    """--compile runs the same steps through inductor kernels: the losses agree to rounding and
    the checkpoint holds the model's own parameter names (no compiled-wrapper prefix). Without
    dropout: compiled dropout draws its masks from another generator (TriConsPose has none)."""

    def no_dropout(cfg):
        m = TinyModel(cfg)
        m.drop = nn.Identity()
        return m

    eager, compiled = tmp_path / "eager", tmp_path / "compiled"
    T.train(_args(recording, eager, "--max-steps", "3"), model_factory=no_dropout, loss_fn=tiny_loss, cfg=CFG)
    T.train(_args(recording, compiled, "--max-steps", "3", "--compile"), model_factory=no_dropout, loss_fn=tiny_loss,
            cfg=CFG)
    np.testing.assert_allclose([r["total"] for r in _log(compiled)], [r["total"] for r in _log(eager)],
                               rtol=1e-4)
    a = torch.load(eager / T.CKPT_FILE, weights_only=False)["model"]
    b = torch.load(compiled / T.CKPT_FILE, weights_only=False)["model"]
    assert a.keys() == b.keys()
    for k in a:
        torch.testing.assert_close(b[k], a[k], rtol=1e-4, atol=1e-6)
    # batches of 3 from 8 instances: 3, 3, then 2; the short one runs eager, nothing recompiles
    from torch._dynamo.utils import counters

    torch._dynamo.reset()
    counters.clear()
    short = T.train(_args(recording, tmp_path / "short", "--max-steps", "3", "--batch-size", "3", "--compile"),
                    model_factory=no_dropout, loss_fn=tiny_loss, cfg=CFG)
    assert short["step"] == 3 and counters["stats"]["unique_graphs"] == 1


def test_bf16_autocast_trains_float32_weights_close_to_float32(recording, tmp_path):
    """--autocast bf16: the forward pass in bfloat16 where autocast puts it, the weights and
    the losses in float32; the first step's loss (same weights, same batch) within bfloat16's
    rounding of the float32 one."""
    ref, bf16 = tmp_path / "fp32", tmp_path / "bf16"
    _run(_args(recording, ref, "--max-steps", "2"))
    _run(_args(recording, bf16, "--max-steps", "2", "--autocast", "bf16"))
    first = [_log(d)[0]["total"] for d in (ref, bf16)]
    assert first[1] != first[0] and abs(first[1] - first[0]) < 2e-2 * abs(first[0])
    state = torch.load(bf16 / T.CKPT_FILE, weights_only=False)["model"]
    assert all(v.dtype == torch.float32 for v in state.values() if v.is_floating_point())
