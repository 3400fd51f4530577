"""Weight averaging of checkpoints (tricons_pose.average)."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from tricons_pose import average as A
from tricons_pose.config import ModelConfig

CFG = ModelConfig.shipped().replace(n_points=256, crop_size=32, name="test")


def test_average_states_is_the_weighted_mean_and_keeps_integer_buffers():
    a = {"w": torch.tensor([1.0, 2.0]), "n": torch.tensor(7)}
    b = {"w": torch.tensor([3.0, 6.0]), "n": torch.tensor(9)}
    assert torch.equal(A.average_states([a, b])["w"], torch.tensor([2.0, 4.0]))
    assert torch.equal(A.average_states([a, b], [3, 1])["w"], torch.tensor([1.5, 3.0]))
    out = A.average_states([a, b])
    assert out["n"].item() == 7 and out["n"].dtype == a["n"].dtype
    assert A.average_states([a])["w"].data_ptr() != a["w"].data_ptr()  # a copy, not an alias


@pytest.mark.parametrize("other, message", [({"v": torch.zeros(2)}, "other keys"),
                                            ({"w": torch.zeros(3)}, "shape")])
def test_average_states_rejects_other_models(other, message):
    with pytest.raises(ValueError, match=message):
        A.average_states([{"w": torch.zeros(2)}, other])


def test_average_states_rejects_bad_weights():
    s = {"w": torch.zeros(2)}
    for w in ([1.0], [0.0, 0.0], [-1.0, 2.0]):
        with pytest.raises(ValueError, match="weights"):
            A.average_states([s, s], w)


class BnModel(nn.Module):
    def __init__(self):
        super().__init__()
        self.bn = nn.BatchNorm1d(3, momentum=0.1)

    def forward_train(self, inputs, aug):
        return self.bn(inputs["pts"].reshape(-1, 3))


def _batch(x):
    z = torch.zeros(1)
    return {"rgb": z, "pts": x, "choose": z, "class_id": z, "R": z, "t": z, "s": z, "nocs": z,
            "handle_visible": z, "sym": z}


def test_recompute_batchnorm_sets_the_plain_mean_of_the_batches_statistics():
    torch.manual_seed(0)
    xs = [torch.randn(2, 5, 3) * (i + 1) + i for i in range(4)]
    m = BnModel().eval()
    m.bn.running_mean.fill_(100.0)
    used = A.recompute_batchnorm(m, [_batch(x) for x in xs], batches=3)
    assert used == 3 and not m.training and m.bn.momentum == 0.1
    flat = [x.reshape(-1, 3) for x in xs[:3]]
    mean = torch.stack([f.mean(0) for f in flat]).mean(0)
    var = torch.stack([f.var(0, unbiased=True) for f in flat]).mean(0)
    assert torch.allclose(m.bn.running_mean, mean, atol=1e-6)
    assert torch.allclose(m.bn.running_var, var, atol=1e-5)
    assert int(m.bn.num_batches_tracked) == 3


def test_cli_averages_real_checkpoints_and_recomputes_the_statistics(recording, tmp_path):
    pytest.importorskip("tricons_pose.model")
    from tricons_pose.train import default_model_factory

    paths, states = [], []
    for seed in (1, 2):
        torch.manual_seed(seed)
        sd = default_model_factory(CFG).state_dict()
        states.append(sd)
        paths.append(tmp_path / f"m{seed}.pt")
        torch.save({"config": CFG.to_dict(), "model": sd, "step": 10 * seed}, paths[-1])
    out = tmp_path / "avg.pt"
    assert A.main(["--checkpoints", *map(str, paths), "--out", str(out), "--bn-data", str(recording),
                   "--bn-batches", "2", "--batch-size", "2", "--cache-dir", str(tmp_path / "cache")]) == 0
    ck = torch.load(out, weights_only=False)
    assert ck["config"] == CFG.to_dict() and ck["step"] == 20 and "2 batches" in ck["batchnorm"]
    bn_buffers = {k for k in ck["model"] if k.endswith(("running_mean", "running_var", "num_batches_tracked"))}
    assert bn_buffers, "the shipped configuration's CNN has BatchNorm"
    for k, v in ck["model"].items():
        if k in bn_buffers:
            continue
        assert torch.allclose(v, (states[0][k] + states[1][k]) / 2, atol=1e-7), k
    means = [k for k in bn_buffers if k.endswith("running_mean")]
    assert all(not torch.allclose(ck["model"][k], torch.zeros_like(ck["model"][k])) for k in means)
    assert all(int(ck["model"][k]) == 2 for k in bn_buffers if k.endswith("num_batches_tracked"))
    default_model_factory(CFG).load_state_dict(ck["model"])  # loadable as is


def test_cli_rejects_checkpoints_of_other_configurations(tmp_path):
    pytest.importorskip("tricons_pose.model")
    from tricons_pose.train import default_model_factory

    a, b = tmp_path / "a.pt", tmp_path / "b.pt"
    torch.save({"config": CFG.to_dict(), "model": default_model_factory(CFG).state_dict()}, a)
    other = CFG.replace(n_keypoints=CFG.n_keypoints // 2)
    torch.save({"config": other.to_dict(), "model": default_model_factory(other).state_dict()}, b)
    with pytest.raises(SystemExit, match="another model configuration"):
        A.main(["--checkpoints", str(a), str(b), "--out", str(tmp_path / "o.pt")])
