"""Official DINOv2 ViT-S/14 weights (``dinov2_vits14_pretrain.pth``) into the project's
frozen :class:`~tricons_pose.image_encoder.DinoV2Encoder`.

The official file is a plain ``state_dict`` of the backbone::

    cls_token (1, 1, D)   pos_embed (1, 1 + 37*37, D)   mask_token (1, D)
    patch_embed.proj.{weight (D, 3, 14, 14), bias (D,)}
    blocks.<i>.norm1.{weight,bias}  blocks.<i>.attn.qkv.{weight (3D, D), bias}
    blocks.<i>.attn.proj.{weight,bias}  blocks.<i>.ls1.gamma (D,)
    blocks.<i>.norm2.{weight,bias}  blocks.<i>.mlp.fc1.{weight (4D, D), bias}
    blocks.<i>.mlp.fc2.{weight (D, 4D), bias}  blocks.<i>.ls2.gamma (D,)
    norm.{weight,bias}

with D = 384 and i = 0..11 for ViT-S/14 (175 tensors; the ``*_reg4`` variants add
``register_tokens``, which this encoder has no place for). :func:`load_official_dinov2`
maps each key onto the encoder's ViT (``encoder.vit``, whose parameters carry the same
names), checks every key and shape against the encoder's configuration, resamples the
position grid when the file's differs from the encoder's ``pos_grid`` (DINOv2's own
formula: bicubic on the 2-D grid with scale ``(P + 0.1) / M``, class position kept),
copies the weights and freezes the ViT (``requires_grad`` off, eval mode). Nothing is
downloaded; nothing is changed when a check fails.

``mask_token`` is used only by DINOv2's masked-image training: it is optional here,
copied when present (so ``encoder.vit.state_dict()`` equals the file) and never used.

At run time the encoder resamples its ``pos_grid`` x ``pos_grid`` grid (37 for the
official file and the ``paper`` configuration) to the crop's patch grid (192 px crop
-> 196 px -> 14 x 14) with the same DINOv2 formula, precomputed as matrices
(:meth:`DinoV2ViT.pos_interp_matrix`).
"""
from __future__ import annotations

import math
import os
from typing import Dict, List, Mapping, Tuple, Union

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .image_encoder import DinoV2Encoder

OFFICIAL_FILE = "dinov2_vits14_pretrain.pth"

# per-block tensors of the official checkpoint, in file order
_BLOCK_KEYS = ("norm1.weight", "norm1.bias", "attn.qkv.weight", "attn.qkv.bias",
               "attn.proj.weight", "attn.proj.bias", "ls1.gamma", "norm2.weight", "norm2.bias",
               "mlp.fc1.weight", "mlp.fc1.bias", "mlp.fc2.weight", "mlp.fc2.bias", "ls2.gamma")
_OPTIONAL = ("mask_token",)
_POS = "pos_embed"


def _encoder_of(obj: nn.Module) -> DinoV2Encoder:
    """The :class:`DinoV2Encoder` itself, or a model's ``image_encoder`` attribute."""
    enc = obj if isinstance(obj, DinoV2Encoder) else getattr(obj, "image_encoder", None)
    if not isinstance(enc, DinoV2Encoder):
        kind = type(enc if enc is not None else obj).__name__
        raise ValueError(f"DINOv2 weights need the 'dinov2' image encoder (ModelConfig.image_encoder), "
                         f"this model has {kind}")
    return enc


def official_shapes(encoder: nn.Module) -> Dict[str, Tuple[int, ...]]:
    """Official key -> shape the file must hold for this encoder's configuration.

    Built from the encoder's sizes (dim, depth, heads' qkv, MLP width, patch,
    position grid), independently of its ``state_dict``, so a structural change of
    the project's ViT shows up as a mismatch in :func:`project_key_map`.
    ``pos_embed``'s grid may differ in the file (it is resampled); listed here at the
    encoder's grid.
    """
    vit = _encoder_of(encoder).vit
    D = vit.cls_token.shape[-1]
    P = vit.pos_grid
    patch = vit.patch
    hidden = vit.blocks[0].mlp.fc1.out_features if len(vit.blocks) else 4 * D
    shapes: Dict[str, Tuple[int, ...]] = {
        "cls_token": (1, 1, D),
        _POS: (1, 1 + P * P, D),
        "mask_token": (1, D),
        "patch_embed.proj.weight": (D, 3, patch, patch),
        "patch_embed.proj.bias": (D,),
    }
    per_block = {
        "norm1.weight": (D,), "norm1.bias": (D,),
        "attn.qkv.weight": (3 * D, D), "attn.qkv.bias": (3 * D,),
        "attn.proj.weight": (D, D), "attn.proj.bias": (D,),
        "ls1.gamma": (D,),
        "norm2.weight": (D,), "norm2.bias": (D,),
        "mlp.fc1.weight": (hidden, D), "mlp.fc1.bias": (hidden,),
        "mlp.fc2.weight": (D, hidden), "mlp.fc2.bias": (D,),
        "ls2.gamma": (D,),
    }
    for i in range(len(vit.blocks)):
        for k in _BLOCK_KEYS:
            shapes[f"blocks.{i}.{k}"] = per_block[k]
    shapes["norm.weight"] = (D,)
    shapes["norm.bias"] = (D,)
    return shapes


def project_key_map(encoder: nn.Module) -> Dict[str, str]:
    """Official key -> name of the tensor in ``encoder.vit.state_dict()``.

    The project's ViT was written with DINOv2's names, so the map is the identity;
    it is still checked, name by name and shape by shape, against the ViT's actual
    parameters, so that a structural change (no LayerScale, another MLP, ...) is an
    error here rather than a silently wrong load.
    """
    enc = _encoder_of(encoder)
    want = official_shapes(enc)
    own = {k: tuple(v.shape) for k, v in enc.vit.state_dict().items()}
    problems = [f"{k}: the project ViT has no such tensor" for k in want if k not in own]
    problems += [f"{k}: the project ViT has it, DINOv2 ViT-S/14 does not" for k in own if k not in want]
    problems += [f"{k}: project shape {own[k]} vs DINOv2 {want[k]}" for k in want
                 if k in own and own[k] != want[k]]
    if problems:
        raise ValueError("the project's ViT is not DINOv2-shaped:\n  " + "\n  ".join(problems))
    return {k: k for k in want}


def resample_pos_embed(pos_embed: Tensor, grid: int) -> Tensor:
    """(1, 1 + M*M, D) -> (1, 1 + grid*grid, D) as DINOv2 resizes its position grid:
    ``F.interpolate(mode="bicubic", scale_factor=(grid + 0.1) / M, align_corners=False)``
    on the (D, M, M) grid in float32, the class position kept as it is."""
    n = pos_embed.shape[1] - 1
    M = math.isqrt(n)
    D = pos_embed.shape[-1]
    if M == grid:
        return pos_embed
    g = pos_embed[:, 1:].float().reshape(1, M, M, D).permute(0, 3, 1, 2)
    s = (grid + 0.1) / M
    g = F.interpolate(g, scale_factor=(s, s), mode="bicubic", align_corners=False)
    if tuple(g.shape[-2:]) != (grid, grid):  # cannot happen for grid >= 1; guard the formula
        raise AssertionError(f"bicubic resampling gave {tuple(g.shape[-2:])}, wanted {grid}x{grid}")
    g = g.permute(0, 2, 3, 1).reshape(1, grid * grid, D).to(pos_embed.dtype)
    return torch.cat([pos_embed[:, :1], g], dim=1)


def _read(path: Union[str, os.PathLike]) -> Mapping[str, Tensor]:
    if not os.path.isfile(path):
        raise FileNotFoundError(f"DINOv2 checkpoint {os.fspath(path)!r} does not exist")
    sd = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(sd, Mapping) or not all(isinstance(k, str) and isinstance(v, Tensor)
                                             for k, v in sd.items()):
        raise ValueError(f"{os.fspath(path)}: not a plain state_dict (name -> tensor) like {OFFICIAL_FILE}")
    return sd


def check_official_state_dict(encoder: nn.Module, sd: Mapping[str, Tensor],
                              source: str = "<state_dict>") -> Dict[str, Tensor]:
    """Validate an official-format state dict for ``encoder`` and return the tensors to
    load, keyed by the ViT's names (position grid resampled, float dtype of the ViT).

    Raises ``ValueError`` naming ``source`` and every offending key: missing,
    unexpected (``register_tokens`` gets a hint), wrong shape, non-floating dtype.
    """
    enc = _encoder_of(encoder)
    key_map = project_key_map(enc)
    want = official_shapes(enc)
    P = enc.vit.pos_grid
    problems: List[str] = []
    for k in want:
        if k not in sd and k not in _OPTIONAL:
            problems.append(f"missing key {k!r} (shape {want[k]})")
    for k in sd:
        if k not in want:
            hint = " (a *_reg4 checkpoint: register tokens are not supported)" if k == "register_tokens" else ""
            problems.append(f"unexpected key {k!r} {tuple(sd[k].shape)}{hint}")
    for k, v in sd.items():
        if k not in want:
            continue
        if not v.is_floating_point():
            problems.append(f"key {k!r}: dtype {v.dtype}, expected floating point")
            continue
        shape = tuple(v.shape)
        if k == _POS:
            n = shape[1] - 1 if len(shape) == 3 and shape[1] >= 2 else -1
            M = math.isqrt(n) if n > 0 else -1
            if len(shape) != 3 or shape[0] != 1 or shape[2] != want[k][2] or M * M != n:
                problems.append(f"key {k!r}: shape {shape}, expected (1, 1 + M*M, {want[k][2]}) "
                                f"(M = {P} for this encoder)")
        elif shape != want[k]:
            problems.append(f"key {k!r}: shape {shape}, expected {want[k]}")
    if problems:
        raise ValueError(f"{source}: not a DINOv2 ViT-S/14 state_dict for this encoder "
                         f"(dim {want['cls_token'][-1]}, {len(enc.vit.blocks)} blocks):\n  "
                         + "\n  ".join(problems))
    own = enc.vit.state_dict()
    out: Dict[str, Tensor] = {}
    for k, name in key_map.items():
        if k in sd:
            v = sd[k]
            if k == _POS:
                v = resample_pos_embed(v, P)
            out[name] = v.to(own[name].dtype)
        else:  # optional tensor absent from the file: keep the encoder's own
            out[name] = own[name]
    return out


def freeze_vit(encoder: nn.Module) -> None:
    """Freeze the ViT of ``encoder`` (``requires_grad`` off, eval mode). The 1x1 projection
    after it stays trainable. The ViT has no dropout, drop-path or batch norm, so a later
    ``model.train()`` (which puts it back in training mode) does not change its output."""
    enc = _encoder_of(encoder)
    enc.freeze()
    enc.vit.requires_grad_(False)
    enc.vit.eval()


def load_official_dinov2(encoder: nn.Module, path: Union[str, os.PathLike],
                         freeze: bool = True) -> Dict[str, object]:
    """Load the official ``dinov2_vits14_pretrain.pth`` at ``path`` (local file,
    ``torch.load(weights_only=True)`` on the CPU) into ``encoder`` (a
    :class:`DinoV2Encoder` or a model with an ``image_encoder`` one), then freeze its ViT.

    Returns a summary: {"path", "tensors" (copied), "pos_grid" (file, encoder),
    "mask_token" (whether present)}. Raises ``ValueError`` naming the file and the
    key on any mismatch, before anything is copied.
    """
    enc = _encoder_of(encoder)
    src = os.fspath(path)
    sd = _read(src)
    tensors = check_official_state_dict(enc, sd, src)
    enc.vit.load_state_dict(tensors, strict=True)
    if freeze:
        freeze_vit(enc)
    file_grid = math.isqrt(sd[_POS].shape[1] - 1)
    return {"path": src, "tensors": len([k for k in sd]), "pos_grid": (file_grid, enc.vit.pos_grid),
            "mask_token": "mask_token" in sd}
