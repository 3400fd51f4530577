"""TriCons-Pose network (PyTorch).

Pipeline (paper, Sec. "Proposed Method"; AG-Pose for what the paper keeps):

1. Multi-modal encoding: the cloud is centred on its centroid c; PointNet++ MSG on
   the points (custom ops), an image encoder on the crop, per-point image features
   gathered with ``choose``; fused = cat(point, image) -> (B, N, C).
2. SCKD: learnable queries (M, C) attend to the fused features (pre-LN
   cross-attention / self-attention / FFN blocks) -> instance-adaptive queries;
   cosine similarity with the fused features (eps) -> softmax(S / tau) over the
   points = heatmap H; kpt_3d = H @ P, kpt_feat = H @ fused.
3. PIGA, B blocks: local stage (triangle descriptors of each keypoint's K nearest
   points -> g_i, added to the neighbours' fused features before a single-head
   cross-attention keypoint -> neighbours, residual) and global stage (triangle
   descriptors among keypoints -> g_gl, F + G_gl -> LayerNorm -> multi-head
   self-attention, residual), then a pre-LN FFN (residual).
4. Heads: keypoint NOCS (MLP, 0.5 * tanh), pose feature
   cat(emb(kpt_3d - centroid), F, emb(kpt_nocs)) -> per-keypoint MLP -> mean-pool
   -> MLP_R (6D), MLP_t (residual to the centroid), MLP_s (softplus, metres).

:meth:`TriConsPose.forward` is the inference / export path (only custom ops and
standard torch ops, no data-dependent Python control flow).
:meth:`TriConsPose.forward_train` runs the two augmented views of the paper.
Design decisions are listed in tools/MODEL.md.
"""
from __future__ import annotations

import math
from typing import Dict, Optional, Tuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .config import ModelConfig
from .image_encoder import SmallCNN, build_image_encoder, gather_pixel_features
from .ops import group_points, triangle_descriptor
from .pointnet2 import PointNet2MSG
from .rotation import rotation_matrix_from_6d

#: metric inputs of the pairwise descriptors (offsets, distances) are multiplied
#: by this (metres -> decimetres) so that MLP inputs are O(1)
GEO_SCALE = 10.0


# ============================================================================ utils
def mlp(sizes, act_last: bool = False) -> nn.Sequential:
    """Linear layers with ReLU between them (and after the last if ``act_last``)."""
    layers = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2 or act_last:
            layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


class MultiHeadAttention(nn.Module):
    """Plain multi-head attention (explicit matmuls; exports with a symbolic batch)."""

    def __init__(self, dim: int, heads: int):
        super().__init__()
        self.heads = heads
        self.q = nn.Linear(dim, dim)
        self.k = nn.Linear(dim, dim)
        self.v = nn.Linear(dim, dim)
        self.o = nn.Linear(dim, dim)

    def forward(self, x: Tensor, kv: Tensor) -> Tensor:
        """x (B, Lq, D) attends to kv (B, Lk, D) -> (B, Lq, D)."""
        B, Lq, D = x.shape
        h = self.heads
        q = self.q(x).reshape(B, Lq, h, D // h).transpose(1, 2)
        k = self.k(kv).reshape(B, -1, h, D // h).transpose(1, 2)
        v = self.v(kv).reshape(B, -1, h, D // h).transpose(1, 2)
        a = torch.softmax((q @ k.transpose(-2, -1)) * (D // h) ** -0.5, dim=-1)
        return self.o((a @ v).transpose(1, 2).reshape(B, Lq, D))


def _eps_norm(u: Tensor, eps2: float = 1e-12) -> Tensor:
    return torch.sqrt((u * u).sum(-1) + eps2)


def _angle(u: Tensor, v: Tensor) -> Tensor:
    """Angle between vectors (last dim 3), finite for zero vectors."""
    c = (u * v).sum(-1) / (_eps_norm(u) * _eps_norm(v))
    return torch.acos(c.clamp(-1.0 + 1e-6, 1.0 - 1e-6))


def _gather_xyz(points: Tensor, idx: Tensor) -> Tensor:
    """points (B, N, 3), idx (B, M, K) -> (B, M, K, 3) (plain torch, ablation paths)."""
    B, M, K = idx.shape
    flat = idx.reshape(B, M * K, 1).expand(-1, -1, 3)
    return torch.gather(points, 1, flat).reshape(B, M, K, 3)


def _knn(query: Tensor, points: Tensor, k: int) -> Tensor:
    """k nearest points (ascending) with torch.topk; used by the non-triangle ablations."""
    d2 = ((query.unsqueeze(2) - points.unsqueeze(1)) ** 2).sum(-1)
    return torch.topk(d2, k, dim=-1, largest=False, sorted=True).indices


# ===================================================================== augmentation
def _axis_rotations(angles: Tensor) -> Tensor:
    """(..., 3) angles (rad) about x, y, z -> Rx @ Ry @ Rz (..., 3, 3)."""
    cx, cy, cz = torch.cos(angles).unbind(-1)
    sx, sy, sz = torch.sin(angles).unbind(-1)
    o, z = torch.ones_like(cx), torch.zeros_like(cx)
    Rx = torch.stack([o, z, z, z, cx, -sx, z, sx, cx], -1).reshape(*cx.shape, 3, 3)
    Ry = torch.stack([cy, z, sy, z, o, z, -sy, z, cy], -1).reshape(*cx.shape, 3, 3)
    Rz = torch.stack([cz, -sz, z, sz, cz, z, z, z, o], -1).reshape(*cx.shape, 3, 3)
    return Rx @ Ry @ Rz


def sample_augmentation(batch: int, views: int = 2, max_angle_deg: float = 20.0,
                        max_translation: float = 0.02, scale: Tuple[float, float] = (0.8, 1.2),
                        anisotropic_views: Tuple[int, ...] = (1,),
                        generator: Optional[torch.Generator] = None,
                        dtype: torch.dtype = torch.float32) -> Dict[str, Tensor]:
    """Random view transforms P^v = dS_v * (dR_v P) + dT_v (paper Eq. 1).

    Angles U(-a, a) per axis (dR = Rx Ry Rz, AG-Pose), dT ~ U(-0.02, 0.02) m,
    dS ~ U(0.8, 1.2): one factor for all axes, except views listed in
    ``anisotropic_views`` (0-based) which get one factor per axis. View 0 drives
    the pose supervision, so it stays isotropic (see tools/MODEL.md).

    Returns {"dR": (B, V, 3, 3), "dT": (B, V, 3), "dS": (B, V, 3)}.
    """
    g = generator
    ang = (torch.rand(batch, views, 3, generator=g, dtype=dtype) * 2 - 1) * math.radians(max_angle_deg)
    dR = _axis_rotations(ang)
    dT = (torch.rand(batch, views, 3, generator=g, dtype=dtype) * 2 - 1) * max_translation
    lo, hi = scale
    s_iso = lo + (hi - lo) * torch.rand(batch, views, 1, generator=g, dtype=dtype)
    s_ani = lo + (hi - lo) * torch.rand(batch, views, 3, generator=g, dtype=dtype)
    mask = torch.zeros(1, views, 1, dtype=torch.bool)
    for v in anisotropic_views:
        if v < views:
            mask[0, v, 0] = True
    dS = torch.where(mask, s_ani, s_iso.expand(-1, -1, 3))
    return {"dR": dR, "dT": dT, "dS": dS}


def apply_view_transform(x: Tensor, dR: Tensor, dT: Tensor, dS: Tensor) -> Tensor:
    """y = dS * (dR x) + dT for rows x (B, L, 3); dR (B, 3, 3), dT (B, 3), dS (B, 3)."""
    return (x @ dR.transpose(1, 2)) * dS.unsqueeze(1) + dT.unsqueeze(1)


def invert_view_transform(y: Tensor, dR: Tensor, dT: Tensor, dS: Tensor) -> Tensor:
    """x = dR^-1 dS^-1 (y - dT) (paper's inverse map) for rows y (B, L, 3)."""
    return ((y - dT.unsqueeze(1)) / dS.unsqueeze(1)) @ dR


# ============================================================================ SCKD
class _SCKDBlock(nn.Module):
    def __init__(self, C: int, heads: int, ffn: int):
        super().__init__()
        self.n1, self.n2, self.n3 = nn.LayerNorm(C), nn.LayerNorm(C), nn.LayerNorm(C)
        self.cross = MultiHeadAttention(C, heads)
        self.self_attn = MultiHeadAttention(C, heads)
        self.ffn = mlp([C, ffn, C])

    def forward(self, q: Tensor, feats: Tensor) -> Tensor:
        q = q + self.cross(self.n1(q), feats)
        x = self.n2(q)
        q = q + self.self_attn(x, x)
        return q + self.ffn(self.n3(q))


class SCKD(nn.Module):
    """Instance-adaptive keypoint detector of SCKD.

    Learnable queries Q (M, C) -> ``sckd_layers`` pre-LN blocks (cross-attention to
    the fused features, self-attention among queries, FFN) -> Q_ins; cosine
    similarity S_ij = <Q_i, F_j> / (|Q_i| |F_j| + eps); H = softmax(S / tau) over
    the N points.
    """

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        C = cfg.channels
        self.tau = cfg.tau
        self.eps = cfg.heatmap_eps
        self.queries = nn.Parameter(torch.empty(cfg.n_keypoints, C))
        nn.init.xavier_normal_(self.queries)
        self.blocks = nn.ModuleList([_SCKDBlock(C, cfg.heads, cfg.ffn_dim)
                                     for _ in range(cfg.sckd_layers)])

    def forward(self, fused: Tensor) -> Tensor:
        """fused (B, N, C) -> heatmap H (B, M, N) (rows sum to 1)."""
        q = self.queries.unsqueeze(0).expand(fused.shape[0], -1, -1)
        for blk in self.blocks:
            q = blk(q, fused)
        num = q @ fused.transpose(1, 2)                                   # (B, M, N)
        den = _eps_norm(q, 0.0).unsqueeze(2) * _eps_norm(fused, 0.0).unsqueeze(1) + self.eps
        return torch.softmax((num / den) / self.tau, dim=2)


# ==================================================================== geometry (PIGA)
def global_triangle_phi(kpt: Tensor, k_global: int) -> Tensor:
    """Triangle descriptors among keypoints for the global stage, self excluded.

    Calls ``triangle_descriptor(kpt, kpt, k_global + 1)``: the first neighbour is
    the keypoint itself (or a coincident keypoint; same geometry) at distance 0.
    The k_global triangles (p_i, q_0, q_b) that contain it are degenerate and come
    first in row-major pair order, so they are dropped; the remaining
    k_global(k_global-1)/2 area weights are renormalised to sum to 1 (the weight of
    a triangle is phi.sum() / pi because its three angles sum to pi), which equals
    the softmax over the proper triangles only.

    Returns (B, M, k_global(k_global-1)/2, 3).
    """
    phi, _ = triangle_descriptor(kpt, kpt, k_global + 1)
    kept = phi[:, :, k_global:]
    w = kept.sum(-1, keepdim=True) / math.pi
    return kept / w.sum(-2, keepdim=True)


class TriangleEmbedding(nn.Module):
    """g_i = mean over triangles of MLP(phi_i,ab) (paper Eq. for g_i), (B, M, C).

    The MLP sees ``phi * N_t`` (= area weight relative to the uniform weight, times
    the angles): a constant rescale so the inputs are O(1) radians instead of
    O(1/N_t); it does not change invariance.
    """

    def __init__(self, C: int, hidden: int):
        super().__init__()
        self.mlp = mlp([3, hidden, C])

    def forward(self, phi: Tensor) -> Tensor:
        """phi (B, M, T, 3) -> g (B, M, C)."""
        return self.mlp(phi * phi.shape[2]).mean(dim=2)

    def embed_local(self, query: Tensor, points: Tensor, k: int) -> Tensor:
        """g_i from the k nearest ``points`` of each query (module-level helper)."""
        phi, _ = triangle_descriptor(query, points, k)
        return self(phi)


def pairwise_descriptor(kind: str, p: Tensor, q: Tensor) -> Tensor:
    """Pairwise geometry between centres p (B, M, 3) and neighbours q (B, M, K, 3).

    * "relative": (q_j - p_i) * GEO_SCALE -> (B, M, K, 3) (pose-variant).
    * "ppf": point-pair feature (|d|, angle(n_i, d), angle(n_j, d), angle(n_i, n_j))
      with d = q_j - p_i and "normals" approximated by the direction from the
      neighbourhood centroid c_i = mean_j q_j: n_i = p_i - c_i, n_j = q_j - c_i
      -> (B, M, K, 4) (rigid-invariant).
    * "dist_angle": |d| -> (B, M, K, 1) and angles between d_j and d_x for every
      neighbour x -> (B, M, K, K, 1), concatenated as (B, M, K, 1 + K)
      (GeoTransformer-style distance + angle, rigid-invariant).
    """
    d = q - p.unsqueeze(2)
    if kind == "relative":
        return d * GEO_SCALE
    dist = _eps_norm(d).unsqueeze(-1) * GEO_SCALE
    if kind == "ppf":
        c = q.mean(dim=2, keepdim=True)
        n_i = (p.unsqueeze(2) - c).expand_as(d)
        n_j = q - c
        return torch.cat([dist, _angle(n_i, d).unsqueeze(-1), _angle(n_j, d).unsqueeze(-1),
                          _angle(n_i, n_j).unsqueeze(-1)], dim=-1)
    if kind == "dist_angle":
        ang = _angle(d.unsqueeze(3), d.unsqueeze(2))       # (B, M, K, K)
        return torch.cat([dist, ang], dim=-1)
    raise ValueError(kind)


class PairwiseEmbedding(nn.Module):
    """Embedding of :func:`pairwise_descriptor` features, one C-vector per pair.

    "dist_angle": MLP_d(distance) + max over x of MLP_a(angle(d_j, d_x)).
    """

    def __init__(self, kind: str, C: int, hidden: int):
        super().__init__()
        self.kind = kind
        if kind == "dist_angle":
            self.mlp_d = mlp([1, hidden, C])
            self.mlp_a = mlp([1, hidden, C])
        else:
            self.mlp = mlp([3 if kind == "relative" else 4, hidden, C])

    def forward(self, desc: Tensor) -> Tensor:
        """(B, M, K, D) -> (B, M, K, C)."""
        if self.kind == "dist_angle":
            return self.mlp_d(desc[..., :1]) + self.mlp_a(desc[..., 1:].unsqueeze(-1)).amax(dim=-2)
        return self.mlp(desc)


# ====================================================================== PIGA blocks
class PIGABlock(nn.Module):
    """One PIGA block (local cross-attention + global self-attention + FFN).

    Geometric bias by mode: "triangle" (paper), "relative" / "ppf" / "dist_angle"
    (descriptor ablation: pairwise descriptors on the same K / K_gl neighbourhoods,
    one bias per neighbour locally, mean over the K_gl keypoint neighbours globally),
    "agpose" (use_piga=False: AG-Pose's relative-coordinate aggregation, per-neighbour
    relative offsets locally, absolute position + mean relative offset to all
    keypoints globally).
    """

    def __init__(self, cfg: ModelConfig, mode: str):
        super().__init__()
        C, h = cfg.channels, cfg.descriptor_hidden
        self.mode = mode
        self.scale = C ** -0.5
        if mode == "triangle":
            self.geo_local = TriangleEmbedding(C, h)
            self.geo_global = TriangleEmbedding(C, h)
        elif mode == "agpose":
            self.geo_local = PairwiseEmbedding("relative", C, h)
            self.geo_abs = mlp([3, h, C])
            self.geo_rel = mlp([3, h, C])
        else:
            self.geo_local = PairwiseEmbedding(mode, C, h)
            self.geo_global = PairwiseEmbedding(mode, C, h)
        self.ln_q = nn.LayerNorm(C)
        self.ln_kv = nn.LayerNorm(C)
        self.wq = nn.Linear(C, C)
        self.wk = nn.Linear(C, C)
        self.wv = nn.Linear(C, C)
        self.ln_g = nn.LayerNorm(C)
        self.attn = MultiHeadAttention(C, cfg.heads)
        self.use_ffn = cfg.piga_ffn
        if self.use_ffn:
            self.ln_f = nn.LayerNorm(C)
            self.ffn = mlp([C, cfg.ffn_dim, C])

    def geometry(self, geo: Dict[str, Tensor]) -> Tuple[Tensor, Tensor]:
        """Raw descriptors -> (local bias (B, M, K or 1, C), global embedding (B, M, C))."""
        if self.mode == "triangle":
            return self.geo_local(geo["local"]).unsqueeze(2), self.geo_global(geo["global"])
        if self.mode == "agpose":
            g = self.geo_abs(geo["abs"]) + self.geo_rel(geo["global"]).mean(dim=2)
            return self.geo_local(geo["local"]), g
        return self.geo_local(geo["local"]), self.geo_global(geo["global"]).mean(dim=2)

    def forward(self, f: Tensor, nbr: Tensor, geo: Dict[str, Tensor]) -> Tensor:
        """f (B, M, C) keypoint features, nbr (B, M, K, C) neighbour fused features."""
        bias, g_gl = self.geometry(geo)
        kv = self.ln_kv(nbr + bias)                                   # F_hat_ij = F_ij + g_i
        q = self.wq(self.ln_q(f))                                     # (B, M, C)
        k = self.wk(kv)                                               # (B, M, K, C)
        v = self.wv(kv)
        a = torch.softmax((k @ q.unsqueeze(-1)).squeeze(-1) * self.scale, dim=-1)  # over K
        f = f + (a.unsqueeze(-1) * v).sum(dim=2)                      # local, residual
        x = self.ln_g(f + g_gl)                                       # LN(F_l + G_gl)
        f = f + self.attn(x, x)                                       # global, residual
        if self.use_ffn:
            f = f + self.ffn(self.ln_f(f))
        return f


# ============================================================================ heads
class PoseHead(nn.Module):
    """Pose & size regression from cat(emb(kpt_3d - centroid), F, emb(kpt_nocs)).

    Per-keypoint MLP -> concat with its mean over keypoints -> per-keypoint MLP ->
    mean-pool -> MLP_R (6D, :func:`rotation_matrix_from_6d`), MLP_t (translation
    residual to the centroid), MLP_s (softplus, metres; bias initialised so that
    s starts at ``size_init``).
    """

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        C, H = cfg.channels, cfg.pose_hidden
        self.emb_pts = mlp([3, 32, 64], act_last=True)
        self.emb_nocs = mlp([3, 32, 64], act_last=True)
        self.mlp1 = mlp([C + 128, 2 * H, H], act_last=True)
        self.mlp2 = mlp([2 * H, 2 * H, 2 * H], act_last=True)
        self.head_r = mlp([2 * H, H, 6])
        self.head_t = mlp([2 * H, H, 3])
        self.head_s = mlp([2 * H, H, 3])
        nn.init.constant_(self.head_s[-1].bias, math.log(math.expm1(cfg.size_init)))

    def forward(self, kpt_rel: Tensor, f: Tensor, kpt_nocs: Tensor):
        """kpt_rel (B, M, 3) keypoints minus the cloud centroid, f (B, M, C),
        kpt_nocs (B, M, 3) -> R (B, 3, 3), t_residual (B, 3), s (B, 3)."""
        x = torch.cat([self.emb_pts(kpt_rel * GEO_SCALE), f, self.emb_nocs(kpt_nocs)], dim=-1)
        x = self.mlp1(x)
        # mlp2's first layer on cat([x, mean(x) expanded]), written as the sum of its two
        # halves: same parameters and result, but no Expand + Concat in the exported graph
        # (tract 0.23's declutter mis-splits that concat-einsum; docs/results.md)
        first, h = self.mlp2[0], x.shape[-1]
        x = F.linear(x, first.weight[:, :h], first.bias) + F.linear(x.mean(dim=1, keepdim=True), first.weight[:, h:])
        x = self.mlp2[1:](x).mean(dim=1)
        R = rotation_matrix_from_6d(self.head_r(x))
        return R, self.head_t(x), F.softplus(self.head_s(x))


class Reconstructor(nn.Module):
    """Each keypoint predicts ``pts_per_kpt`` points (offsets from the keypoint) for
    L_rec (AG-Pose): global = mean(pos_enc(kpt) + mlp(F)); decoder(cat(global, mlp(F)))."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        C, H = cfg.channels, cfg.pose_hidden
        self.k = cfg.pts_per_kpt
        self.pos = mlp([3, 64, C])
        self.feat = mlp([C, C, C])
        self.dec = mlp([2 * C, 2 * H, 2 * H, 3 * self.k])

    def forward(self, kpt: Tensor, f: Tensor) -> Tuple[Tensor, Tensor]:
        """kpt (B, M, 3), f (B, M, C) -> points (B, M*k, 3), offsets (B, M*k, 3)."""
        B, M, _ = kpt.shape
        ff = self.feat(f)
        glob = (self.pos(kpt * GEO_SCALE) + ff).mean(dim=1, keepdim=True).expand_as(ff)
        delta = self.dec(torch.cat([glob, ff], dim=-1)).reshape(B, M * self.k, 3) / GEO_SCALE
        return kpt.repeat_interleave(self.k, dim=1) + delta, delta


# ============================================================================ model
class TriConsPose(nn.Module):
    """TriCons-Pose (see module docstring). Build with a :class:`ModelConfig`.

    ``forward(inputs)`` -> {"R" (B,3,3), "t" (B,3), "s" (B,3), "kpt_3d" (B,M,3) camera
    frame, "kpt_nocs" (B,M,3)} for inputs {"rgb" (B,3,crop,crop), "pts" (B,N,3)
    camera frame metres, "choose" (B,N) int64}.
    """

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        cfg.validate()
        self.cfg = cfg
        self.image_encoder = build_image_encoder(cfg)
        self.point_encoder = PointNet2MSG.from_config(cfg)
        self.sckd = SCKD(cfg)
        self.mode = cfg.descriptor if cfg.use_piga else "agpose"
        self.piga = nn.ModuleList([PIGABlock(cfg, self.mode) for _ in range(cfg.blocks)])
        C = cfg.channels
        n_out = 3 * cfg.n_classes if cfg.nocs_per_class else 3
        self.nocs_head = mlp([C, cfg.nocs_hidden, cfg.nocs_hidden, n_out])
        self.pose_head = PoseHead(cfg)
        self.reconstructor = Reconstructor(cfg)

    # ------------------------------------------------------------------ pieces
    def encode_image(self, rgb: Tensor, choose: Tensor) -> Tensor:
        """(B, 3, crop, crop), (B, N) -> per-point image features (B, N, C_im).

        In training the CNN's last 1x1 conv runs on the chosen pixels only
        (:meth:`SmallCNN.forward_gathered`, same values); evaluation and export run it on
        the whole map, the graph the runtime expects."""
        enc = self.image_encoder
        if self.training and isinstance(enc, SmallCNN):
            return enc.forward_gathered(rgb, choose).transpose(1, 2)
        return gather_pixel_features(enc(rgb), choose).transpose(1, 2)

    def detect(self, P: Tensor, f_im: Tensor) -> Tuple[Tensor, Tensor, Tensor, Tensor]:
        """Centred/augmented points P (B, N, 3) + image feats (B, N, C_im) ->
        fused (B, N, C), heatmap (B, M, N), kpt_3d (B, M, 3), kpt_feat (B, M, C)."""
        f_p = self.point_encoder(P).transpose(1, 2)                   # (B, N, C_p)
        fused = torch.cat([f_p, f_im], dim=-1)
        H = self.sckd(fused)
        return fused, H, H @ P, H @ fused

    def _geometry(self, kpt: Tensor, P: Tensor) -> Tuple[Dict[str, Tensor], Tensor]:
        """Raw descriptors for the PIGA blocks + local neighbour indices (B, M, K)."""
        cfg = self.cfg
        if self.mode == "triangle":
            phi, idx = triangle_descriptor(kpt, P, cfg.k_local)
            return {"local": phi, "global": global_triangle_phi(kpt, cfg.k_global)}, idx
        idx = _knn(kpt, P, cfg.k_local)
        q = _gather_xyz(P, idx)
        if self.mode == "agpose":
            rel_all = (kpt.unsqueeze(1) - kpt.unsqueeze(2)) * GEO_SCALE   # p_j - p_i
            return {"local": pairwise_descriptor("relative", kpt, q),
                    "abs": kpt * GEO_SCALE, "global": rel_all}, idx
        idx_gl = _knn(kpt, kpt, cfg.k_global + 1)[:, :, 1:]
        q_gl = _gather_xyz(kpt, idx_gl)
        return {"local": pairwise_descriptor(self.mode, kpt, q),
                "global": pairwise_descriptor(self.mode, kpt, q_gl)}, idx

    def aggregate(self, kpt: Tensor, kpt_feat: Tensor, P: Tensor, fused: Tensor) -> Tensor:
        """PIGA: keypoints (B, M, 3), features (B, M, C), points, fused -> F (B, M, C)."""
        geo_kpt = kpt.detach() if self.cfg.detach_kpt_geometry else kpt
        geo, idx = self._geometry(geo_kpt, P)
        nbr = group_points(fused.transpose(1, 2).contiguous(), idx).permute(0, 2, 3, 1)
        f = kpt_feat
        for blk in self.piga:
            f = blk(f, nbr, geo)
        return f

    def nocs(self, f: Tensor, class_id: Tensor | None) -> Tensor:
        """Keypoint features (B, M, C) -> NOCS (B, M, 3); with ``nocs_per_class`` the
        row of each instance's class (``class_id`` (B,) int64, 0-based), selected by a
        one-hot product so that the export is plain Equal / Cast / Mul / ReduceSum."""
        raw = self.nocs_head(f)
        if self.cfg.nocs_per_class:
            if class_id is None:
                raise ValueError("nocs_per_class: the inputs need 'class_id' (B,) int64")
            B, M, _ = raw.shape
            k = torch.arange(self.cfg.n_classes, device=raw.device)
            onehot = (class_id.reshape(B, 1) == k.reshape(1, -1)).to(raw.dtype)      # (B, K)
            raw = (raw.reshape(B, M, self.cfg.n_classes, 3) * onehot.reshape(B, 1, -1, 1)).sum(dim=2)
        return 0.5 * torch.tanh(raw)

    def heads(self, kpt: Tensor, f: Tensor, centroid: Tensor, class_id: Tensor | None = None):
        """-> kpt_nocs (B, M, 3), R, t (absolute in the frame of ``kpt``), s."""
        kpt_nocs = self.nocs(f, class_id)
        R, t_res, s = self.pose_head(kpt - centroid, f, kpt_nocs.detach())
        return kpt_nocs, R, centroid.squeeze(1) + t_res, s

    # ----------------------------------------------------------------- forward
    def forward(self, inputs: Dict[str, Tensor]) -> Dict[str, Tensor]:
        """Inference / export path. See class docstring for inputs and outputs."""
        pts = inputs["pts"]
        c = pts.mean(dim=1, keepdim=True)
        P = pts - c
        f_im = self.encode_image(inputs["rgb"], inputs["choose"])
        fused, H, kpt, kpt_feat = self.detect(P, f_im)
        f = self.aggregate(kpt, kpt_feat, P, fused)
        kpt_nocs, R, t, s = self.heads(kpt, f, torch.zeros_like(c), inputs.get("class_id"))
        return {"R": R, "t": t + c.squeeze(1), "s": s, "kpt_3d": kpt + c, "kpt_nocs": kpt_nocs}

    def forward_train(self, inputs: Dict[str, Tensor], aug: Dict[str, Tensor]) -> Dict[str, Tensor]:
        """Training path with the paper's two augmented views.

        ``aug``: {"dR": (B, V, 3, 3), "dT": (B, V, 3), "dS": (B, V, 3)} with V >= 1
        (V >= 2 when ``use_sckd_loss``), e.g. from :func:`sample_augmentation`. The
        centred cloud P = pts - centroid is transformed per view,
        P^v = dS_v * (dR_v P) + dT_v; both views go through the shared PointNet++
        and SCKD (image features computed once and shared). PIGA and the heads run on
        view 0 (the paper's P_kp^1, F_kp^1), whose predictions are mapped back to the
        camera frame: keypoints / reconstructed points / t by the exact inverse map
        (+ centroid), R = dR_0^T R^0, s = s^0 / geometric-mean(dS_0) (exact for an
        isotropic dS_0).

        Returns {"R", "t", "s", "kpt_3d", "recon", "recon_delta" (camera frame),
        "R_view", "t_view", "s_view" (view 0's own prediction, translation in camera
        coordinates of the augmented scene: centred view frame + centroid; for
        supervision with exact per-view targets, e.g. scaling along object axes),
        "kpt_nocs", "heatmap" (B, M, N) of view 0, "kpt_views" (B, V', M, 3) in the
        view frames (V' = 2 with use_sckd_loss, else 1), "dR", "dT", "dS" of those
        views, "pts" (the input cloud)}.
        """
        pts = inputs["pts"]
        B = pts.shape[0]
        V = 2 if self.cfg.use_sckd_loss else 1
        dR, dT, dS = (aug[k][:, :V].to(pts) for k in ("dR", "dT", "dS"))
        if dR.shape[1] < V:
            raise ValueError("use_sckd_loss needs two augmented views in aug")
        dS = dS.expand(-1, -1, 3) if dS.shape[-1] == 1 else dS
        c = pts.mean(dim=1, keepdim=True)
        P = pts - c
        Pv = torch.cat([apply_view_transform(P, dR[:, v], dT[:, v], dS[:, v]) for v in range(V)], 0)
        f_im = self.encode_image(inputs["rgb"], inputs["choose"])
        fused, H, kpt, kpt_feat = self.detect(Pv, f_im.repeat(V, 1, 1))
        kpt_views = torch.stack(kpt.split(B, dim=0), dim=1)           # (B, V, M, 3)
        P0, fused0, H0, kpt0, kf0 = Pv[:B], fused[:B], H[:B], kpt[:B], kpt_feat[:B]
        f = self.aggregate(kpt0, kf0, P0, fused0)
        kpt_nocs, R0, t0, s0 = self.heads(kpt0, f, P0.mean(dim=1, keepdim=True), inputs.get("class_id"))
        recon0, delta0 = self.reconstructor(kpt0, f)
        R_0, T_0, S_0 = dR[:, 0], dT[:, 0], dS[:, 0]
        back = lambda y: invert_view_transform(y, R_0, T_0, S_0) + c  # noqa: E731
        s_iso = S_0.prod(dim=-1, keepdim=True) ** (1.0 / 3.0)
        return {
            "R": R_0.transpose(1, 2) @ R0,
            "t": back(t0.unsqueeze(1)).squeeze(1),
            "s": s0 / s_iso,
            "R_view": R0, "t_view": t0 + c.squeeze(1), "s_view": s0,
            "kpt_3d": back(kpt0),
            "recon": back(recon0),
            "recon_delta": delta0,
            "kpt_nocs": kpt_nocs,
            "heatmap": H0,
            "kpt_views": kpt_views,
            "dR": dR, "dT": dT, "dS": dS,
            "pts": pts,
        }

    # ------------------------------------------------------------------ utils
    def num_parameters(self, trainable_only: bool = False) -> int:
        """Parameter count (all, or only those with requires_grad)."""
        return sum(p.numel() for p in self.parameters() if p.requires_grad or not trainable_only)
