"""Image encoders: dense feature maps of the RGB crop, sampled at the object points.

* :class:`SmallCNN`: a from-scratch encoder-decoder (stride-2 convolutions, then
  bilinear upsampling with skip connections back to crop resolution). Used by the
  shipped model, which trains on CPU without pretrained weights.
* :class:`DinoV2Encoder`: a ViT-S/14 shaped like DINOv2 (patch 14, dim 384, 12 blocks,
  6 heads, LayerScale), randomly initialised; :meth:`DinoV2Encoder.load_dinov2_weights`
  loads a user-supplied official ``dinov2_vits14`` state dict and freezes the ViT.
  Patch tokens (before the final norm, as AG-Pose) -> 1x1 conv to ``C_im`` ->
  bilinear upsampling to the crop.

Both return (B, C_im, crop, crop); :func:`gather_pixel_features` picks the per-point
features with ``choose`` (B, N), indices into the crop's row-major pixels.
"""
from __future__ import annotations

from typing import Dict, Mapping, Optional, Sequence, Union

import torch
import torch.nn.functional as F
from torch import Tensor, nn


def gather_pixel_features(feat: Tensor, choose: Tensor) -> Tensor:
    """(B, C, H, W) feature map, (B, N) int64 row-major pixel indices -> (B, C, N).

    Written as one flat row gather (ONNX ``Gather`` on a (B*H*W, C) table with
    offsets b*H*W) rather than ``GatherElements``, which some runtimes and the ONNX
    reference evaluator handle poorly for large axes.
    """
    B, C = feat.shape[0], feat.shape[1]
    hw = feat.shape[2] * feat.shape[3]
    table = feat.reshape(B, C, hw).transpose(1, 2).reshape(-1, C)        # (B*HW, C)
    offs = torch.arange(B, device=choose.device, dtype=choose.dtype).unsqueeze(1) * hw
    rows = table[(choose + offs).reshape(-1)]                            # (B*N, C)
    return rows.reshape(B, -1, C).transpose(1, 2)


# ----------------------------------------------------------------------------- CNN
def _conv_bn(c_in: int, c_out: int, stride: int = 1, k: int = 3) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, k, stride=stride, padding=k // 2, bias=False),
                         nn.BatchNorm2d(c_out), nn.ReLU(inplace=True))


class SmallCNN(nn.Module):
    """From-scratch encoder-decoder CNN: (B, 3, H, W) -> (B, out_channels, H, W).

    Encoder: for each width w, a stride-2 3x3 conv then a 3x3 conv (BN, ReLU), so
    the resolution halves per stage. Decoder: bilinear x2 upsampling, concatenation
    with the encoder map of that resolution (the input-resolution stem for the last
    step), 3x3 conv (1x1 at full resolution, for CPU cost); a final 1x1 conv gives
    ``out_channels`` at full resolution.
    H and W must be divisible by ``2 ** len(widths)``.
    """

    def __init__(self, out_channels: int, widths: Sequence[int] = (32, 64, 128)):
        super().__init__()
        widths = list(widths)
        stem = max(widths[0] // 2, 8)
        self.stem = _conv_bn(3, stem)
        self.down = nn.ModuleList()
        c = stem
        for w in widths:
            self.down.append(nn.Sequential(_conv_bn(c, w, stride=2), _conv_bn(w, w)))
            c = w
        skips = [stem] + widths[:-1]
        self.up = nn.ModuleList()
        for i, s in enumerate(reversed(skips)):
            # 3x3 at reduced resolutions, 1x1 at full resolution (cost)
            k = 1 if i == len(skips) - 1 else 3
            self.up.append(_conv_bn(c + s, max(s, out_channels // 2), k=k))
            c = max(s, out_channels // 2)
        self.head = nn.Conv2d(c, out_channels, 1)

    def features(self, x: Tensor) -> Tensor:
        """(B, 3, H, W) -> the decoder's full-resolution map before the final 1x1 conv."""
        feats = [self.stem(x)]
        for d in self.down:
            feats.append(d(feats[-1]))
        y = feats[-1]
        for i, up in enumerate(self.up):
            skip = feats[-2 - i]
            y = _upsample_to(y, skip.shape[-2:])
            y = up(torch.cat([y, skip], dim=1))
        return y

    def forward(self, x: Tensor) -> Tensor:
        """(B, 3, H, W) -> (B, out_channels, H, W)."""
        return self.head(self.features(x))

    def forward_gathered(self, x: Tensor, choose: Tensor) -> Tensor:
        """``gather_pixel_features(self(x), choose)``, (B, out_channels, N), with the final
        1x1 conv applied to the N chosen pixels only: a 1x1 conv acts on each pixel alone,
        so gathering first gives the same values (float rounding aside) for N / (H W) of
        its cost, forward and backward (training: 512 of 9216 pixels; the conv's backward
        was a sixth of a step). Export keeps :meth:`forward` (the runtime gathers early
        itself)."""
        y = self.features(x)
        B, C = y.shape[0], y.shape[1]
        idx = choose.unsqueeze(1).expand(B, C, choose.shape[1])
        rows = y.reshape(B, C, -1).gather(2, idx)                            # (B, C, N)
        return F.conv1d(rows, self.head.weight.flatten(1).unsqueeze(-1), self.head.bias)


def _upsample_to(y: Tensor, size) -> Tensor:
    """Bilinear (half-pixel) resize of ``y`` to ``size``.

    An exact integer ratio is expressed as a scale factor: the same result, and the
    exported Resize then takes constant scales instead of sizes computed from the
    input's (symbolic-batch) shape, which tract 0.23 cannot evaluate at run time.
    """
    h, w = int(size[0]), int(size[1])
    yh, yw = int(y.shape[-2]), int(y.shape[-1])
    if h % yh == 0 and w % yw == 0 and h // yh == w // yw:
        return F.interpolate(y, scale_factor=float(h // yh), mode="bilinear", align_corners=False)
    return F.interpolate(y, size=(h, w), mode="bilinear", align_corners=False)


def bilinear_matrix(n_in: int, n_out: int) -> Tensor:
    """(n_out, n_in) float32 matrix A with ``A @ v`` == 1-D bilinear (half-pixel,
    ``align_corners=False``, no antialias) resampling of v from n_in to n_out samples.

    Bilinear resizing is separable, so ``A_h @ x @ A_w^T`` equals
    ``F.interpolate(x, size=..., mode="bilinear", align_corners=False)``; computed by
    resampling the basis vectors, in float64.
    """
    basis = torch.eye(n_in, dtype=torch.float64).reshape(n_in, 1, 1, n_in)
    out = F.interpolate(basis, size=(1, n_out), mode="bilinear", align_corners=False)
    return out[:, 0, 0, :].transpose(0, 1).to(torch.float32).contiguous()


def resize_separable(x: Tensor, a_h: Tensor, a_w: Tensor) -> Tensor:
    """(B, C, H, W) -> (B, C, H', W') as ``a_h @ x @ a_w^T`` (:func:`bilinear_matrix`).

    Exports as two MatMuls with constant matrices: no Resize whose sizes come from
    the input's symbolic-batch shape (which tract 0.23 cannot evaluate at run time).
    """
    return torch.matmul(torch.matmul(a_h.to(x), x), a_w.to(x).transpose(0, 1))


# ------------------------------------------------------------------------- DINOv2
class _PatchEmbed(nn.Module):
    def __init__(self, patch: int, dim: int):
        super().__init__()
        self.proj = nn.Conv2d(3, dim, patch, stride=patch)

    def forward(self, x: Tensor) -> Tensor:
        return self.proj(x).flatten(2).transpose(1, 2)  # (B, HW, dim)


class _Attention(nn.Module):
    def __init__(self, dim: int, heads: int):
        super().__init__()
        self.heads = heads
        self.qkv = nn.Linear(dim, 3 * dim)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: Tensor) -> Tensor:
        B, T, D = x.shape
        h = self.heads
        qkv = self.qkv(x).reshape(B, T, 3, h, D // h).permute(2, 0, 3, 1, 4)
        q, k, v = qkv[0], qkv[1], qkv[2]
        a = torch.softmax((q @ k.transpose(-2, -1)) * (D // h) ** -0.5, dim=-1)
        return self.proj((a @ v).transpose(1, 2).reshape(B, T, D))


class _LayerScale(nn.Module):
    def __init__(self, dim: int, init: float = 1e-5):
        super().__init__()
        self.gamma = nn.Parameter(torch.full((dim,), init))

    def forward(self, x: Tensor) -> Tensor:
        return x * self.gamma


class _Mlp(nn.Module):
    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, x: Tensor) -> Tensor:
        return self.fc2(F.gelu(self.fc1(x)))


class _Block(nn.Module):
    def __init__(self, dim: int, heads: int, mlp_ratio: float):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=1e-6)
        self.attn = _Attention(dim, heads)
        self.ls1 = _LayerScale(dim)
        self.norm2 = nn.LayerNorm(dim, eps=1e-6)
        self.mlp = _Mlp(dim, int(dim * mlp_ratio))
        self.ls2 = _LayerScale(dim)

    def forward(self, x: Tensor) -> Tensor:
        x = x + self.ls1(self.attn(self.norm1(x)))
        return x + self.ls2(self.mlp(self.norm2(x)))


class DinoV2ViT(nn.Module):
    """ViT with DINOv2's parameter names (``cls_token``, ``pos_embed``, ``mask_token``,
    ``patch_embed.proj``, ``blocks.i.{norm1,attn.qkv,attn.proj,ls1.gamma,norm2,
    mlp.fc1,mlp.fc2,ls2.gamma}``, ``norm``), so an official checkpoint loads by name.

    :meth:`forward` returns the patch tokens before the final norm ("x_prenorm"
    without the class token), (B, gh*gw, dim).
    """

    def __init__(self, patch: int = 14, dim: int = 384, depth: int = 12, heads: int = 6,
                 mlp_ratio: float = 4.0, pos_grid: int = 37, grid: Optional[int] = None):
        super().__init__()
        self.patch = patch
        self.pos_grid = pos_grid
        # position-grid resampling matrix for the expected token grid, precomputed
        # (non-persistent buffer) so that forward/export only needs MatMuls
        self.grid = grid
        if grid is not None:
            self.register_buffer("pos_interp", self.pos_interp_matrix(grid), persistent=False)
        self.patch_embed = _PatchEmbed(patch, dim)
        self.cls_token = nn.Parameter(torch.zeros(1, 1, dim))
        self.pos_embed = nn.Parameter(torch.zeros(1, 1 + pos_grid * pos_grid, dim))
        self.mask_token = nn.Parameter(torch.zeros(1, dim))  # unused; official key
        self.blocks = nn.ModuleList([_Block(dim, heads, mlp_ratio) for _ in range(depth)])
        self.norm = nn.LayerNorm(dim, eps=1e-6)  # unused for x_prenorm; official key
        nn.init.trunc_normal_(self.pos_embed, std=0.02)
        nn.init.normal_(self.cls_token, std=1e-6)
        for m in self.modules():
            if isinstance(m, nn.Linear):
                nn.init.trunc_normal_(m.weight, std=0.02)
                nn.init.zeros_(m.bias)

    def pos_interp_matrix(self, g: int) -> Tensor:
        """(g, pos_grid) matrix A with A @ v == DINOv2's 1-D bicubic resampling of v.

        DINOv2 resizes the position grid with ``F.interpolate(mode="bicubic",
        scale_factor=(g + 0.1) / pos_grid)``, which is separable; A is that map
        applied to the basis vectors, so ``A_h @ grid @ A_w^T`` reproduces it with
        plain MatMuls (the TorchScript ONNX exporter cannot export bicubic with
        scale factors).
        """
        P = self.pos_grid
        basis = torch.eye(P, dtype=torch.float64).reshape(P, 1, P, 1).expand(P, 1, P, P)
        sf = (g + 0.1) / P
        out = F.interpolate(basis, scale_factor=(sf, sf), mode="bicubic", align_corners=False)
        return out[:, 0, :, 0].transpose(0, 1).to(torch.float32)         # (g, P)

    def _pos(self, gh: int, gw: int) -> Tensor:
        D = self.pos_embed.shape[-1]
        cls_pos = self.pos_embed[:, :1]
        grid = self.pos_embed[0, 1:].reshape(self.pos_grid, self.pos_grid, D)
        if (gh, gw) != (self.pos_grid, self.pos_grid):
            if self.grid is not None and gh == self.grid:
                Ah = self.pos_interp.to(grid)
            else:
                Ah = self.pos_interp_matrix(gh).to(grid)
            if self.grid is not None and gw == self.grid:
                Aw = self.pos_interp.to(grid)
            else:
                Aw = self.pos_interp_matrix(gw).to(grid)
            grid = torch.einsum("hi,ijd,wj->hwd", Ah, grid, Aw)
        return torch.cat([cls_pos, grid.reshape(1, gh * gw, D)], dim=1)

    def forward(self, x: Tensor) -> Tensor:
        """(B, 3, H, W), H and W multiples of the patch -> (B, gh*gw, dim)."""
        gh, gw = x.shape[-2] // self.patch, x.shape[-1] // self.patch
        t = self.patch_embed(x)
        t = torch.cat([self.cls_token.expand(t.shape[0], -1, -1), t], dim=1) + self._pos(gh, gw)
        for blk in self.blocks:
            t = blk(t)
        return t[:, 1:]


class DinoV2Encoder(nn.Module):
    """DINOv2 ViT-S/14-shaped image encoder: (B, 3, crop, crop) -> (B, C_im, crop, crop).

    The crop is resized (bilinear) to the nearest multiple of the patch size
    (192 -> 196, i.e. 14x14 patches) when it is not one already; the patch tokens
    go through a 1x1 conv to ``out_channels`` and are upsampled bilinearly to the
    crop. (1x1 conv and bilinear upsampling commute, so this equals AG-Pose's
    upsample-then-project at a fraction of the cost.)

    The ViT starts randomly initialised and trainable; :meth:`load_dinov2_weights`
    loads official weights and freezes it (``requires_grad=False``).
    """

    def __init__(self, out_channels: int, crop_size: int, patch: int = 14, dim: int = 384,
                 depth: int = 12, heads: int = 6, mlp_ratio: float = 4.0, pos_grid: int = 37):
        super().__init__()
        self.crop_size = crop_size
        g = max(1, int(round(crop_size / patch)))
        self.vit_input = g * patch
        self.grid = g
        self.vit = DinoV2ViT(patch, dim, depth, heads, mlp_ratio, pos_grid, grid=g)
        self.proj = nn.Conv2d(dim, out_channels, 1)
        self.frozen = False
        # the two bilinear resizes as constant separable matrices (non-persistent:
        # checkpoints are unchanged); crop -> ViT input and token grid -> crop
        self.register_buffer("to_vit", bilinear_matrix(crop_size, self.vit_input), persistent=False)
        self.register_buffer("to_crop", bilinear_matrix(g, crop_size), persistent=False)

    def forward(self, x: Tensor) -> Tensor:
        """(B, 3, crop, crop) ImageNet-normalised -> (B, out_channels, crop, crop)."""
        if self.vit_input != x.shape[-1] or self.vit_input != x.shape[-2]:
            if x.shape[-1] != self.crop_size or x.shape[-2] != self.crop_size:
                raise ValueError(f"expected a {self.crop_size}x{self.crop_size} crop, got {tuple(x.shape[-2:])}")
            x = resize_separable(x, self.to_vit, self.to_vit)
        tok = self.vit(x)                                   # (B, g*g, dim)
        B, D = tok.shape[0], tok.shape[-1]
        fm = tok.transpose(1, 2).reshape(B, D, self.grid, self.grid)
        fm = self.proj(fm)
        return resize_separable(fm, self.to_crop, self.to_crop)

    def freeze(self) -> None:
        """Freeze the ViT (the 1x1 projection stays trainable)."""
        for p in self.vit.parameters():
            p.requires_grad_(False)
        self.frozen = True

    def load_dinov2_weights(self, source: Union[str, Mapping[str, Tensor]],
                            freeze: bool = True) -> None:
        """Load an official DINOv2 ViT-S/14 state dict (path to a ``torch.save`` file
        or a mapping) into the ViT, then freeze it.

        Keys are the official ones (``patch_embed.proj.weight``, ``blocks.0.attn.qkv.weight``,
        ...); a ``"model"``/``"state_dict"`` wrapper and a ``"module."``/``"backbone."``
        prefix are accepted. Raises ``ValueError`` listing missing keys, unexpected
        keys and shape mismatches (nothing is loaded then).
        """
        sd = source
        if isinstance(source, str):
            sd = torch.load(source, map_location="cpu", weights_only=True)
        for wrap in ("model", "state_dict", "teacher"):
            if isinstance(sd, Mapping) and wrap in sd and isinstance(sd[wrap], Mapping):
                sd = sd[wrap]
        clean: Dict[str, Tensor] = {}
        for k, v in sd.items():
            for pre in ("module.", "backbone."):
                if k.startswith(pre):
                    k = k[len(pre):]
            clean[k] = v
        own = self.vit.state_dict()
        missing = sorted(set(own) - set(clean))
        unexpected = sorted(set(clean) - set(own))
        bad = sorted(f"{k}: checkpoint {tuple(clean[k].shape)} vs model {tuple(own[k].shape)}"
                     for k in set(own) & set(clean) if tuple(clean[k].shape) != tuple(own[k].shape))
        if missing or unexpected or bad:
            msg = ["DINOv2 weights do not match a ViT-S/14 (dim %d, %d blocks):"
                   % (own["cls_token"].shape[-1], len(self.vit.blocks))]
            if missing:
                msg.append(f"  missing keys ({len(missing)}): {missing[:8]}")
            if unexpected:
                msg.append(f"  unexpected keys ({len(unexpected)}): {unexpected[:8]}")
            if bad:
                msg.append(f"  shape mismatches ({len(bad)}): {bad[:8]}")
            raise ValueError("\n".join(msg))
        self.vit.load_state_dict(clean, strict=True)
        if freeze:
            self.freeze()


def build_image_encoder(cfg) -> nn.Module:
    """Image encoder for a :class:`tricons_pose.config.ModelConfig`."""
    if cfg.image_encoder == "cnn":
        if cfg.crop_size % (2 ** len(cfg.cnn_widths)):
            raise ValueError("crop_size must be divisible by 2**len(cnn_widths)")
        return SmallCNN(cfg.image_channels, cfg.cnn_widths)
    return DinoV2Encoder(cfg.image_channels, cfg.crop_size, cfg.vit_patch, cfg.vit_dim,
                         cfg.vit_depth, cfg.vit_heads, cfg.vit_mlp_ratio, cfg.vit_pos_grid)
