"""Tests of the TriCons-Pose network: config, rotation, descriptors, model paths."""
import math

import pytest
import torch

from tricons_pose.config import ModelConfig
from tricons_pose.image_encoder import (DinoV2Encoder, SmallCNN, bilinear_matrix, gather_pixel_features,
                                        resize_separable)
from tricons_pose.losses import compute_losses
from tricons_pose.model import (PairwiseEmbedding, TriangleEmbedding, TriConsPose,
                                global_triangle_phi, pairwise_descriptor, sample_augmentation)
from tricons_pose.ops import triangle_descriptor_torch
from tricons_pose.rotation import rotation_6d_from_matrix, rotation_matrix_from_6d


def _random_rotations(B, dtype=torch.float64, seed=0):
    q, _ = torch.linalg.qr(torch.randn(B, 3, 3, generator=torch.Generator().manual_seed(seed),
                                       dtype=dtype))
    return q * torch.det(q).sign()[:, None, None]


def _inputs(cfg, B, seed=1):
    g = torch.Generator().manual_seed(seed)
    N, cs = cfg.n_points, cfg.crop_size
    pts = torch.randn(B, N, 3, generator=g) * torch.tensor([0.06, 0.04, 0.05]) + torch.tensor([0.05, -0.02, 0.7])
    return {"rgb": torch.randn(B, 3, cs, cs, generator=g), "pts": pts,
            "choose": torch.randint(0, cs * cs, (B, N), generator=g)}


def _targets(cfg, inp):
    B = inp["pts"].shape[0]
    return {"R": _random_rotations(B, torch.float32), "t": inp["pts"].mean(1) + 0.01,
            "s": torch.full((B, 3), 0.15), "nocs": torch.rand(B, cfg.n_points, 3) - 0.5}


def _check_pose(out, B, M):
    R, s = out["R"], out["s"]
    assert R.shape == (B, 3, 3) and out["t"].shape == (B, 3) and s.shape == (B, 3)
    assert out["kpt_3d"].shape == (B, M, 3) and out["kpt_nocs"].shape == (B, M, 3)
    eye = torch.eye(3).expand(B, 3, 3)
    assert torch.allclose(R.transpose(1, 2) @ R, eye, atol=1e-5)
    assert torch.allclose(torch.det(R), torch.ones(B), atol=1e-5)
    assert (s > 0).all()
    assert (out["kpt_nocs"].abs() <= 0.5).all()
    for v in out.values():
        assert torch.isfinite(v).all()


# ------------------------------------------------------------------------ config
def test_config_json_roundtrip_and_constructors():
    for cfg in [ModelConfig.paper(), ModelConfig.shipped(), ModelConfig.paper().baseline(),
                ModelConfig.shipped().with_descriptor("ppf")]:
        back = ModelConfig.from_json(cfg.to_json())
        assert back == cfg
        assert ModelConfig.from_dict(cfg.to_dict()) == cfg
    p = ModelConfig.paper()
    assert (p.n_points, p.n_keypoints, p.channels, p.blocks, p.k_local, p.k_global,
            p.crop_size, p.tau, p.image_encoder) == (1024, 96, 256, 6, 16, 3, 192, 0.1, "dinov2")
    assert (p.w_pose, p.w_nocs, p.w_cd, p.w_div, p.w_rec, p.w_cvc) == (0.3, 2.0, 2.0, 10.0, 15.0, 0.1)
    b = p.baseline()
    assert not b.use_sckd_loss and not b.use_piga
    w = p.without_piga()
    assert w.use_sckd_loss and not w.use_piga
    s = p.without_sckd()
    assert not s.use_sckd_loss and s.use_piga and s.descriptor == "triangle"


def test_config_rejects_inconsistent_values():
    with pytest.raises(ValueError):
        ModelConfig.shipped().replace(channels=100)
    with pytest.raises(ValueError):
        ModelConfig.shipped().replace(descriptor="sift")
    with pytest.raises(ValueError):
        ModelConfig.from_dict({**ModelConfig.shipped().to_dict(), "bogus": 1})


# ---------------------------------------------------------------------- rotation
def test_rotation_6d_roundtrip():
    R = _random_rotations(64)
    d6 = rotation_6d_from_matrix(R)
    assert d6.shape == (64, 6)
    assert torch.allclose(rotation_matrix_from_6d(d6), R, atol=1e-12)


def test_rotation_from_arbitrary_6d_is_proper_and_follows_convention():
    d6 = torch.randn(32, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    R = rotation_matrix_from_6d(d6)
    assert torch.allclose(R.transpose(1, 2) @ R, torch.eye(3, dtype=torch.float64).expand(32, 3, 3), atol=1e-12)
    assert torch.allclose(torch.det(R), torch.ones(32, dtype=torch.float64), atol=1e-12)
    # y column = normalised second vector; z perpendicular to the first vector
    y = d6[:, 3:] / d6[:, 3:].norm(dim=1, keepdim=True)
    assert torch.allclose(R[:, :, 1], y, atol=1e-12)
    assert torch.allclose((R[:, :, 2] * d6[:, :3]).sum(1), torch.zeros(32, dtype=torch.float64), atol=1e-12)


# ------------------------------------------------------------------- descriptors
def test_triangle_embedding_invariant_to_rigid_motion():
    torch.manual_seed(0)
    emb = TriangleEmbedding(32, 16).double()
    g = torch.Generator().manual_seed(4)
    pts = torch.randn(2, 200, 3, generator=g, dtype=torch.float64) * 0.05
    kpt = torch.randn(2, 12, 3, generator=g, dtype=torch.float64) * 0.05
    R = _random_rotations(2, seed=7)
    T = torch.tensor([[0.3, -0.2, 0.9], [-0.1, 0.05, 0.6]], dtype=torch.float64)
    move = lambda x: x @ R.transpose(1, 2) + T[:, None]  # noqa: E731
    g1 = emb.embed_local(kpt, pts, 8)
    g2 = emb.embed_local(move(kpt), move(pts), 8)
    assert g1.shape == (2, 12, 32)
    assert torch.allclose(g1, g2, atol=1e-5)
    # and the global (keypoint-keypoint) embedding too
    h1 = emb(global_triangle_phi(kpt, 3))
    h2 = emb(global_triangle_phi(move(kpt), 3))
    assert torch.allclose(h1, h2, atol=1e-5)


def test_global_triangle_phi_drops_self_and_renormalises():
    g = torch.Generator().manual_seed(5)
    kpt = torch.randn(2, 10, 3, generator=g, dtype=torch.float64) * 0.05
    K = 3
    d2 = ((kpt[:, :, None] - kpt[:, None]) ** 2).sum(-1)
    idx = d2.argsort(dim=-1)[:, :, 1:K + 1]               # K nearest, self excluded
    expected = triangle_descriptor_torch(kpt, kpt, idx)    # softmax over the 3 proper triangles
    got = global_triangle_phi(kpt, K)
    assert got.shape == (2, 10, 3, 3)
    assert torch.allclose(got, expected, atol=1e-12)


@pytest.mark.parametrize("kind", ["ppf", "dist_angle"])
def test_pairwise_invariant_descriptors_are_rigid_invariant(kind):
    g = torch.Generator().manual_seed(6)
    p = torch.randn(2, 5, 3, generator=g, dtype=torch.float64) * 0.05
    q = torch.randn(2, 5, 6, 3, generator=g, dtype=torch.float64) * 0.05
    R = _random_rotations(2, seed=8)
    T = torch.randn(2, 3, generator=g, dtype=torch.float64)
    d1 = pairwise_descriptor(kind, p, q)
    d2 = pairwise_descriptor(kind, p @ R.transpose(1, 2) + T[:, None],
                             torch.einsum("bmkj,bij->bmki", q, R) + T[:, None, None])
    assert torch.allclose(d1, d2, atol=1e-6)
    torch.manual_seed(0)
    e = PairwiseEmbedding(kind, 16, 8).double()
    assert e(d1).shape == (2, 5, 6, 16)


# ----------------------------------------------------------------- image encoders
def test_gather_pixel_features_row_major():
    fm = torch.arange(2 * 3 * 4 * 5, dtype=torch.float32).reshape(2, 3, 4, 5)
    choose = torch.tensor([[0, 7, 19], [5, 6, 1]])
    out = gather_pixel_features(fm, choose)
    assert out.shape == (2, 3, 3)
    assert out[0, 1, 1] == fm[0, 1, 1, 2] and out[1, 2, 0] == fm[1, 2, 1, 0]


def test_small_cnn_keeps_resolution():
    net = SmallCNN(24, (8, 16, 32))
    assert net(torch.randn(2, 3, 32, 32)).shape == (2, 24, 32, 32)


def test_small_cnn_gathered_head_equals_gathering_the_whole_map():
    """Training's gather-then-1x1-conv against the exported conv-then-gather: the same
    features and the same gradients for every parameter (train mode, batch statistics)."""
    torch.manual_seed(4)
    net = SmallCNN(24, (8, 16, 32)).train()
    x = torch.randn(3, 3, 32, 32)
    choose = torch.randint(0, 32 * 32, (3, 50))
    choose[:, 1] = choose[:, 0]  # a pixel chosen twice
    outs, grads = [], []
    for f in (lambda: net.forward_gathered(x, choose), lambda: gather_pixel_features(net(x), choose)):
        net.zero_grad()
        y = f()
        (y * torch.linspace(-1, 1, y.numel()).reshape(y.shape)).sum().backward()
        outs.append(y.detach())
        grads.append([p.grad.clone() for p in net.parameters()])
    assert outs[0].shape == (3, 24, 50)
    assert torch.allclose(outs[0], outs[1], atol=1e-5, rtol=1e-5)
    for g0, g1 in zip(*grads):
        assert torch.allclose(g0, g1, atol=1e-4, rtol=1e-4)


def test_dinov2_weights_load_by_official_names_and_freeze(tmp_path):
    kw = dict(patch=14, dim=48, depth=2, heads=2, mlp_ratio=2.0, pos_grid=5)
    torch.manual_seed(0)
    src = DinoV2Encoder(8, 56, **kw)
    torch.manual_seed(1)
    dst = DinoV2Encoder(8, 56, **kw)
    sd = {k: v.clone() for k, v in src.vit.state_dict().items()}
    for k in ["cls_token", "pos_embed", "mask_token", "patch_embed.proj.weight",
              "blocks.0.norm1.weight", "blocks.0.attn.qkv.weight", "blocks.0.attn.proj.bias",
              "blocks.0.ls1.gamma", "blocks.1.mlp.fc1.weight", "blocks.1.mlp.fc2.bias",
              "blocks.1.ls2.gamma", "norm.weight"]:
        assert k in sd, k
    path = tmp_path / "dinov2.pth"
    torch.save({"module." + k: v for k, v in sd.items()}, path)
    dst.load_dinov2_weights(str(path))
    x = torch.randn(1, 3, 56, 56)
    assert torch.allclose(dst.vit(x), src.vit(x))
    assert dst.frozen and not any(p.requires_grad for p in dst.vit.parameters())
    assert all(p.requires_grad for p in dst.proj.parameters())
    bad = dict(sd)
    bad["blocks.0.attn.qkv.weight"] = torch.zeros(10, 48)
    with pytest.raises(ValueError, match="shape"):
        DinoV2Encoder(8, 56, **kw).load_dinov2_weights(bad)
    missing = {k: v for k, v in sd.items() if k != "pos_embed"}
    with pytest.raises(ValueError, match="missing"):
        DinoV2Encoder(8, 56, **kw).load_dinov2_weights(missing)


def test_dinov2_default_shapes_match_vit_s14():
    enc = DinoV2Encoder(128, 192)
    sd = enc.vit.state_dict()
    assert sd["pos_embed"].shape == (1, 1370, 384)
    assert sd["patch_embed.proj.weight"].shape == (384, 3, 14, 14)
    assert sd["blocks.11.attn.qkv.weight"].shape == (1152, 384)
    assert sd["blocks.11.mlp.fc1.weight"].shape == (1536, 384)
    assert enc.vit_input == 196 and enc.grid == 14
    n = sum(v.numel() for v in sd.values())
    assert 21_000_000 < n < 23_000_000  # ViT-S/14: ~22.1 M


@pytest.mark.parametrize("h_in,w_in,h_out,w_out", [(192, 192, 196, 196), (14, 14, 192, 192), (7, 9, 5, 20), (8, 8, 8, 8)])
def test_separable_bilinear_equals_interpolate(h_in, w_in, h_out, w_out):
    import torch.nn.functional as F

    x = torch.randn(2, 3, h_in, w_in, dtype=torch.float64)
    want = F.interpolate(x, size=(h_out, w_out), mode="bilinear", align_corners=False)
    got = resize_separable(x, bilinear_matrix(h_in, h_out).double(), bilinear_matrix(w_in, w_out).double())
    assert got.shape == want.shape
    assert torch.allclose(got, want, atol=1e-6)  # matrices are float32: ~1e-7 relative
    # rows are convex combinations of at most two inputs
    a = bilinear_matrix(h_in, h_out)
    assert torch.allclose(a.sum(1), torch.ones(h_out)) and int((a != 0).sum(1).max()) <= 2


def test_dinov2_encoder_resizes_as_interpolate_and_keeps_its_state_dict_keys():
    import torch.nn.functional as F

    torch.manual_seed(0)
    enc = DinoV2Encoder(8, 28, patch=14, dim=16, depth=1, heads=2, mlp_ratio=2.0, pos_grid=3)
    assert not any(k.startswith(("to_vit", "to_crop")) for k in enc.state_dict())
    enc.eval()
    x = torch.randn(2, 3, 28, 28)
    fm = enc.proj(enc.vit(x).transpose(1, 2).reshape(2, 16, 2, 2))
    want = F.interpolate(fm, size=(28, 28), mode="bilinear", align_corners=False)
    assert torch.allclose(enc(x), want, atol=1e-5)
    enc30 = DinoV2Encoder(8, 30, patch=14, dim=16, depth=1, heads=2, mlp_ratio=2.0, pos_grid=3).eval()
    x30 = torch.randn(1, 3, 30, 30)
    assert enc30.vit_input == 28 and enc30(x30).shape == (1, 8, 30, 30)
    with pytest.raises(ValueError, match="crop"):
        enc30(torch.randn(1, 3, 32, 32))


# -------------------------------------------------------------------------- model
def test_forward_shipped_shapes_and_pose_validity():
    cfg = ModelConfig.shipped()
    torch.manual_seed(0)
    m = TriConsPose(cfg).eval()
    with torch.no_grad():
        out = m(_inputs(cfg, 2))
    _check_pose(out, 2, cfg.n_keypoints)


def test_forward_paper_config_batch_one():
    cfg = ModelConfig.paper()
    torch.manual_seed(0)
    m = TriConsPose(cfg).eval()
    with torch.no_grad():
        out = m(_inputs(cfg, 1))
    _check_pose(out, 1, 96)


def test_forward_is_deterministic_for_a_fixed_seed():
    cfg = ModelConfig.shipped()
    inp = _inputs(cfg, 2)
    outs = []
    for _ in range(2):
        torch.manual_seed(123)
        m = TriConsPose(cfg).eval()
        with torch.no_grad():
            outs.append(m(inp))
    for k in outs[0]:
        assert torch.equal(outs[0][k], outs[1][k]), k


def test_forward_train_identity_augmentation_matches_forward():
    cfg = ModelConfig.shipped()
    torch.manual_seed(0)
    m = TriConsPose(cfg).eval()
    inp = _inputs(cfg, 2)
    ident = {"dR": torch.eye(3).expand(2, 2, 3, 3), "dT": torch.zeros(2, 2, 3),
             "dS": torch.ones(2, 2, 3)}
    with torch.no_grad():
        a = m(inp)
        b = m.forward_train(inp, ident)
    for k in ["R", "t", "s", "kpt_3d", "kpt_nocs"]:
        assert torch.allclose(a[k], b[k], atol=1e-5), k
    assert torch.allclose(b["kpt_views"][:, 0], b["kpt_views"][:, 1], atol=1e-6)


def test_forward_train_maps_pose_back_to_camera_frame():
    # an isotropic view transform of the input is undone exactly by forward_train
    cfg = ModelConfig.shipped()
    torch.manual_seed(0)
    m = TriConsPose(cfg).eval()
    inp = _inputs(cfg, 2)
    aug = sample_augmentation(2, anisotropic_views=(), generator=torch.Generator().manual_seed(9))
    c = inp["pts"].mean(1, keepdim=True)
    dR, dT, dS = aug["dR"][:, 0], aug["dT"][:, 0], aug["dS"][:, 0]
    moved = dict(inp, pts=((inp["pts"] - c) @ dR.transpose(1, 2)) * dS[:, None] + dT[:, None] + c)
    with torch.no_grad():
        direct = m(moved)
        tr = m.forward_train(inp, aug)
    assert torch.allclose(dR.transpose(1, 2) @ direct["R"], tr["R"], atol=1e-4)
    back_t = (((direct["t"] - c[:, 0] - dT) / dS) [:, None] @ dR)[:, 0] + c[:, 0]
    assert torch.allclose(back_t, tr["t"], atol=1e-5)
    assert torch.allclose(direct["s"] / dS, tr["s"], atol=1e-5)


def _train_step(cfg, B=2):
    torch.manual_seed(0)
    m = TriConsPose(cfg).train()
    inp = _inputs(cfg, B)
    aug = sample_augmentation(B, generator=torch.Generator().manual_seed(2))
    out = m.forward_train(inp, aug)
    L = compute_losses(out, _targets(cfg, inp), cfg)
    L["total"].backward()
    return m, out, L


def test_forward_train_loss_backward_gives_finite_gradients_everywhere():
    cfg = ModelConfig.shipped()
    m, out, L = _train_step(cfg)
    assert out["kpt_views"].shape == (2, 2, cfg.n_keypoints, 3)
    for k, v in L.items():
        assert torch.isfinite(v), k
    assert L["cvc"].item() > 0
    missing, zero = [], []
    for name, p in m.named_parameters():
        if not p.requires_grad:
            continue
        if p.grad is None:
            missing.append(name)
            continue
        assert torch.isfinite(p.grad).all(), name
        if p.grad.abs().max() == 0:
            zero.append(name)
    assert not missing, missing
    assert not zero, zero


@pytest.mark.parametrize("which", ["baseline", "wo_sckd", "wo_piga", "relative", "ppf", "dist_angle"])
def test_ablation_configs_build_and_train(which):
    base = ModelConfig.shipped().replace(n_points=256, pn2_npoints=(128, 32, 8))
    cfg = ModelConfig.ablation(which, base)
    m, out, L = _train_step(cfg)
    assert torch.isfinite(L["total"])
    assert (L["cvc"].item() == 0.0) == (not cfg.use_sckd_loss)
    assert out["kpt_views"].shape[1] == (2 if cfg.use_sckd_loss else 1)
    for name, p in m.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
    with torch.no_grad():
        _check_pose(m.eval()(_inputs(cfg, 2)), 2, cfg.n_keypoints)


def test_view_frame_pose_supervision():
    cfg = ModelConfig.shipped().replace(n_points=256, pn2_npoints=(128, 32, 8))
    m, out, _ = _train_step(cfg)
    inp = _inputs(cfg, 2)
    tg = {"R": out["R_view"].detach(), "t": out["t_view"].detach(), "s": out["s_view"].detach(),
          "nocs": _targets(cfg, inp)["nocs"]}
    L = compute_losses(out, tg, cfg, pose_frame="view")
    assert L["pose"].item() < 1e-5
    with pytest.raises(ValueError):
        compute_losses(out, {k: v for k, v in tg.items() if k != "nocs"}, cfg, pose_frame="view")


def test_forward_exports_to_onnx_with_symbolic_batch(tmp_path):
    """Export at B=2 (TorchScript exporter + ai.tricons symbolics), run at B=3 with the
    ONNX reference evaluator and the ops' numpy references: same outputs."""
    onnx = pytest.importorskip("onnx")
    from onnx.reference import ReferenceEvaluator
    from tricons_pose import onnx_export_ops as oe

    cfg = ModelConfig.shipped().replace(n_points=128, pn2_npoints=(64, 16, 4), crop_size=32,
                                        n_keypoints=12)
    torch.manual_seed(0)
    m = TriConsPose(cfg).eval()
    names = ["R", "t", "s", "kpt_3d", "kpt_nocs"]

    class Wrap(torch.nn.Module):
        def __init__(self, net):
            super().__init__()
            self.net = net

        def forward(self, rgb, pts, choose):
            o = self.net({"rgb": rgb, "pts": pts, "choose": choose})
            return tuple(o[k] for k in names)

    w = Wrap(m).eval()
    oe.register_symbolics()
    x2 = _inputs(cfg, 2)
    path = str(tmp_path / "m.onnx")
    torch.onnx.export(w, (x2["rgb"], x2["pts"], x2["choose"]), path, dynamo=False,
                      opset_version=17, custom_opsets=oe.CUSTOM_OPSETS,
                      input_names=["rgb", "pts", "choose"], output_names=names,
                      dynamic_axes={k: {0: "B"} for k in ["rgb", "pts", "choose"] + names})
    model = onnx.load(path)
    domains = {n.op_type for n in model.graph.node if n.domain == "ai.tricons"}
    assert domains == {"FurthestPointSample", "GatherPoints", "BallQuery", "GroupPoints",
                       "ThreeNN", "ThreeInterpolate", "TriangleDescriptor"}
    w.eval()
    x3 = _inputs(cfg, 3, seed=5)
    got = ReferenceEvaluator(model, new_ops=oe.reference_ops()).run(
        None, {k: x3[k].numpy() for k in ["rgb", "pts", "choose"]})
    with torch.no_grad():
        ref = w(x3["rgb"], x3["pts"], x3["choose"])
    for n, a, b in zip(names, got, ref):
        assert a.shape == tuple(b.shape), n
        assert abs(a - b.numpy()).max() < 1e-4, n


def test_dinov2_position_grid_resampling_matches_official_formula():
    import torch.nn.functional as F
    torch.manual_seed(0)
    vit = DinoV2Encoder(8, 192).vit
    P, D = 37, 384
    grid = vit.pos_embed[:, 1:].reshape(1, P, P, D).permute(0, 3, 1, 2)
    for g in (14, 9):
        ref = F.interpolate(grid, scale_factor=((g + 0.1) / P, (g + 0.1) / P), mode="bicubic",
                            align_corners=False).permute(0, 2, 3, 1).reshape(1, g * g, D)
        assert torch.allclose(vit._pos(g, g)[:, 1:], ref, atol=1e-5)
