"""The official-DINOv2 loader (tricons_pose.dinov2) against an independent ViT: timm's
``vit_small_patch14_dinov2`` (random, seeded weights written in the official key format).

No weights are downloaded: the "official" file is made here from timm's model. The
project's encoder (``ModelConfig.paper()``: 192 px crop -> 196 px, 14x14 patches, a
37x37 position grid as in ``dinov2_vits14_pretrain.pth``) must reproduce timm's patch
tokens on the same normalised image.
"""
from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F
from torch import nn

timm = pytest.importorskip("timm")

from tricons_pose.config import ModelConfig  # noqa: E402
from tricons_pose.data import IMAGENET_MEAN, IMAGENET_STD  # noqa: E402
from tricons_pose.dinov2 import load_official_dinov2  # noqa: E402
from tricons_pose.image_encoder import DinoV2Encoder, SmallCNN, build_image_encoder  # noqa: E402

torch.set_num_threads(1)

D, DEPTH, GRID = 384, 12, 37  # ViT-S/14 as published: 1 + 37*37 position tokens (518 px)
_BLOCK = {"norm1.weight": (D,), "norm1.bias": (D,), "attn.qkv.weight": (3 * D, D),
          "attn.qkv.bias": (3 * D,), "attn.proj.weight": (D, D), "attn.proj.bias": (D,),
          "ls1.gamma": (D,), "norm2.weight": (D,), "norm2.bias": (D,),
          "mlp.fc1.weight": (4 * D, D), "mlp.fc1.bias": (4 * D,), "mlp.fc2.weight": (D, 4 * D),
          "mlp.fc2.bias": (D,), "ls2.gamma": (D,)}
# the official dinov2_vits14_pretrain.pth layout (written out here, not taken from the loader)
OFFICIAL = {"cls_token": (1, 1, D), "pos_embed": (1, 1 + GRID * GRID, D), "mask_token": (1, D),
            "patch_embed.proj.weight": (D, 3, 14, 14), "patch_embed.proj.bias": (D,),
            **{f"blocks.{i}.{k}": s for i in range(DEPTH) for k, s in _BLOCK.items()},
            "norm.weight": (D,), "norm.bias": (D,)}


def _timm_vit(img_size: int) -> nn.Module:
    return timm.create_model("vit_small_patch14_dinov2", pretrained=False, img_size=img_size).eval()


def _official_from_timm(model: nn.Module, g: torch.Generator) -> dict:
    """timm's state_dict in the official format. timm's names are DINOv2's for the
    non-register ViT-S/14 (asserted); the only conversion is the ``mask_token`` that
    timm drops and the official file carries."""
    sd = {k: v.detach().clone() for k, v in model.state_dict().items()}
    assert set(sd) == set(OFFICIAL) - {"mask_token"}
    sd["mask_token"] = torch.randn(1, D, generator=g)
    return sd


@pytest.fixture(scope="module")
def official(tmp_path_factory):
    """(path, state_dict): a seeded random ViT-S/14 in the official format.

    timm initialises LayerScale at 1e-5 (the blocks would hardly matter) and norms
    at 1/0, so gammas, norm affines, biases and the class token are redrawn at
    trained-like magnitudes: every tensor then shapes the output."""
    torch.manual_seed(0)
    model = _timm_vit(518)
    g = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for n, p in model.named_parameters():
            if n.endswith("gamma"):
                p.uniform_(0.05, 1.0, generator=g)
            elif "norm" in n and n.endswith("weight"):
                p.copy_(1 + 0.2 * torch.randn(p.shape, generator=g))
            elif n.endswith("bias"):
                p.copy_(0.05 * torch.randn(p.shape, generator=g))
            elif n == "cls_token":
                p.copy_(0.5 * torch.randn(p.shape, generator=g))
    sd = _official_from_timm(model, g)
    assert {k: tuple(v.shape) for k, v in sd.items()} == OFFICIAL
    path = tmp_path_factory.mktemp("dinov2") / "dinov2_vits14_pretrain.pth"
    torch.save(sd, path)
    return path, sd


def _paper_encoder(seed: int = 5) -> DinoV2Encoder:
    torch.manual_seed(seed)
    enc = build_image_encoder(ModelConfig.paper())
    assert isinstance(enc, DinoV2Encoder) and enc.vit_input == 196 and enc.grid == 14
    return enc


def _crop(batch: int, size: int) -> torch.Tensor:
    """A seeded RGB crop in [0, 1], ImageNet-normalised as tricons_pose.data does."""
    g = torch.Generator().manual_seed(2)
    rgb = torch.rand(batch, size, size, 3, generator=g)
    x = (rgb - torch.tensor(IMAGENET_MEAN)) / torch.tensor(IMAGENET_STD)
    return x.permute(0, 3, 1, 2).contiguous()


def _dinov2_pos(pos_embed: torch.Tensor, g: int) -> torch.Tensor:
    """DINOv2's run-time resampling of the position grid (interpolate_pos_encoding):
    bicubic with scale factor (g + 0.1) / M, class position kept."""
    M = math.isqrt(pos_embed.shape[1] - 1)
    grid = pos_embed[:, 1:].reshape(1, M, M, -1).permute(0, 3, 1, 2)
    s = (g + 0.1) / M
    grid = F.interpolate(grid, scale_factor=(s, s), mode="bicubic", align_corners=False)
    return torch.cat([pos_embed[:, :1], grid.permute(0, 2, 3, 1).reshape(1, g * g, -1)], dim=1)


def test_patch_tokens_equal_timm(official):
    path, sd = official
    enc = _paper_encoder()
    info = load_official_dinov2(enc, path)
    assert info["tensors"] == len(OFFICIAL) and info["pos_grid"] == (GRID, GRID) and info["mask_token"]
    own = enc.vit.state_dict()
    assert all(torch.equal(own[k], sd[k]) for k in OFFICIAL)

    # timm at the ViT's input size, its 14x14 position table resampled by DINOv2's
    # formula from the file's 37x37 one (the project does this with precomputed matrices)
    ref = _timm_vit(196)
    ref_sd = {k: v for k, v in sd.items() if k != "mask_token"}
    ref_sd["pos_embed"] = _dinov2_pos(sd["pos_embed"], 14)
    ref.load_state_dict(ref_sd, strict=True)

    x = _crop(2, 192)  # the paper crop; the encoder resizes it to 196 (bilinear, half-pixel)
    seen = {}
    enc.vit.register_forward_hook(lambda m, i, o: seen.__setitem__("tokens", o))
    ref.blocks[-1].register_forward_hook(lambda m, i, o: seen.__setitem__("prenorm", o))
    with torch.no_grad():
        out = enc(x)
        # reference resize in float64 (float32 interpolate rounds its source coordinates)
        x196 = F.interpolate(x.double(), size=(196, 196), mode="bilinear", align_corners=False).float()
        feats = ref.forward_features(x196)  # (B, 1 + 196, D), after the final norm
    assert out.shape == (2, 128, 192, 192)
    tokens = seen["tokens"]                           # project: patch tokens before the norm
    prenorm = seen["prenorm"][:, ref.num_prefix_tokens:]
    assert tokens.shape == prenorm.shape == (2, 196, D)
    # float32 throughout; the two differ only in summation order (fused attention vs
    # explicit softmax, einsum vs interpolate), rounding error ~ depth * sqrt(K) * 6e-8
    # ~ 3e-5 relative at worst (K <= 1536): 1e-4 of the feature scale is above that
    # and far below any mapping error (the negative control below is ~3e-2 relative)
    tol = 1e-4 * prenorm.abs().max().item()
    err = (tokens - prenorm).abs().max().item()
    assert err < tol, (err, tol)
    with torch.no_grad():
        normed = enc.vit.norm(tokens)
    feats = feats[:, ref.num_prefix_tokens:]
    assert (normed - feats).abs().max().item() < 1e-4 * feats.abs().max().item()

    # negative control: timm's own position resampling (size-based, antialiased) is a
    # different table; the comparison must see it
    ref_sd["pos_embed"] = timm.layers.resample_abs_pos_embed(sd["pos_embed"], (14, 14), num_prefix_tokens=1)
    ref.load_state_dict(ref_sd, strict=True)
    with torch.no_grad():
        ref.forward_features(x196)
    assert (tokens - seen["prenorm"][:, 1:]).abs().max().item() > 30 * tol


def _save(tmp_path, sd, name="dinov2_vits14_pretrain.pth"):
    p = tmp_path / name
    torch.save(sd, p)
    return p


@pytest.mark.parametrize("case,key", [
    ("missing", "blocks.7.mlp.fc2.bias"),
    ("missing", "pos_embed"),
    ("shape", "blocks.0.attn.qkv.weight"),
    ("shape", "pos_embed"),
    ("unexpected", "blocks.12.norm1.weight"),
    ("unexpected", "register_tokens"),
])
def test_bad_checkpoint_names_key_and_file_and_loads_nothing(official, tmp_path, case, key):
    _, sd = official
    bad = dict(sd)
    if case == "missing":
        del bad[key]
    elif case == "shape":
        v = bad[key]
        bad[key] = torch.zeros(v.shape[0], v.shape[1] + 1, *v.shape[2:])  # 1370 + 1 is no square grid
    else:
        bad[key] = torch.zeros(1, 4, D)
    path = _save(tmp_path, bad)
    enc = _paper_encoder()
    before = {k: v.clone() for k, v in enc.vit.state_dict().items()}
    with pytest.raises(ValueError, match=case) as e:
        load_official_dinov2(enc, path)
    assert repr(key) in str(e.value) and str(path) in str(e.value)
    assert all(torch.equal(v, before[k]) for k, v in enc.vit.state_dict().items())
    assert all(p.requires_grad for p in enc.vit.parameters()) and not enc.frozen


def test_not_a_state_dict_and_no_file(tmp_path):
    path = _save(tmp_path, [torch.zeros(1)], "list.pth")
    with pytest.raises(ValueError, match="state_dict") as e:
        load_official_dinov2(_paper_encoder(), path)
    assert str(path) in str(e.value)
    with pytest.raises(FileNotFoundError):
        load_official_dinov2(_paper_encoder(), tmp_path / "absent.pth")
    with pytest.raises(ValueError, match="dinov2"):
        load_official_dinov2(SmallCNN(8), tmp_path / "absent.pth")


def test_frozen_after_loading_and_a_train_step_leaves_it(official):
    path, _ = official

    class Holder(nn.Module):  # a model exposing the encoder as image_encoder, as TriConsPose
        def __init__(self):
            super().__init__()
            self.image_encoder = _paper_encoder()

    model = Holder()
    load_official_dinov2(model, path)
    enc = model.image_encoder
    assert enc.frozen and not enc.vit.training
    assert not any(p.requires_grad for p in enc.vit.parameters())
    assert all(p.requires_grad for p in enc.proj.parameters())
    vit0 = {k: v.clone() for k, v in enc.vit.state_dict().items()}
    proj0 = enc.proj.weight.detach().clone()
    # train.py's optimiser (trainable parameters only) and one given everything
    opt = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=1e-2)
    opt_all = torch.optim.AdamW(model.parameters(), lr=1e-2, weight_decay=0.1)
    model.train()  # the ViT has no dropout / batch norm: training mode changes nothing
    x = _crop(1, 192)
    y = enc(x)
    y.square().mean().backward()
    assert all(p.grad is None for p in enc.vit.parameters())
    opt.step()
    opt_all.step()
    assert all(torch.equal(v, vit0[k]) for k, v in enc.vit.state_dict().items())
    assert not torch.equal(enc.proj.weight, proj0)
    with torch.no_grad():
        a = enc.vit(F.interpolate(x, size=(196, 196), mode="bilinear", align_corners=False))
        enc.vit.eval()
        b = enc.vit(F.interpolate(x, size=(196, 196), mode="bilinear", align_corners=False))
    assert torch.equal(a, b)


def test_other_position_grid_is_resampled_as_dinov2(official, tmp_path):
    _, sd = official
    g = torch.Generator().manual_seed(3)
    other = dict(sd)
    other["pos_embed"] = torch.randn(1, 1 + 20 * 20, D, generator=g)  # a 280 px checkpoint
    del other["mask_token"]  # optional: DINOv2 uses it only in masked training
    enc = _paper_encoder()
    mask0 = enc.vit.mask_token.detach().clone()
    info = load_official_dinov2(enc, _save(tmp_path, other))
    assert info["pos_grid"] == (20, GRID) and not info["mask_token"]
    want = _dinov2_pos(other["pos_embed"], GRID)
    assert enc.vit.pos_embed.shape == (1, 1 + GRID * GRID, D)
    assert torch.equal(enc.vit.pos_embed[:, :1], other["pos_embed"][:, :1])
    assert torch.allclose(enc.vit.pos_embed, want, atol=1e-6)
    assert torch.equal(enc.vit.mask_token, mask0)
