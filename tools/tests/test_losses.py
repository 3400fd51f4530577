"""Tests of tricons_pose.losses (L_cvc and AG-Pose's terms)."""
import math

import pytest
import torch

from tricons_pose.config import ModelConfig
from tricons_pose.losses import (_dist, chamfer, compute_losses, cvc_loss, diversity_loss,
                                 keypoint_surface_loss, nocs_target_from_heatmap,
                                 nocs_target_from_pose, normalised_distance_matrix,
                                 pose_loss, smooth_l1_dis)
from tricons_pose.model import apply_view_transform, invert_view_transform, sample_augmentation


def _kpts(B=3, M=16, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(B, M, 3, generator=g, dtype=dtype) * 0.08


def _identity_aug(B, dtype=torch.float64):
    return (torch.eye(3, dtype=dtype).expand(B, 2, 3, 3), torch.zeros(B, 2, 3, dtype=dtype),
            torch.ones(B, 2, 3, dtype=dtype))


def test_cvc_zero_for_identical_views():
    k = _kpts()
    views = torch.stack([k, k], dim=1)
    dR, dT, dS = _identity_aug(k.shape[0])
    assert cvc_loss(views, dR, dT, dS).item() == 0.0


def test_cvc_zero_for_two_rigid_scale_augmentations_mapped_back():
    k = _kpts(B=4)
    aug = sample_augmentation(4, anisotropic_views=(0, 1), dtype=torch.float64,
                              generator=torch.Generator().manual_seed(3))
    views = torch.stack([apply_view_transform(k, aug["dR"][:, v], aug["dT"][:, v], aug["dS"][:, v])
                         for v in range(2)], dim=1)
    # the views really differ in the augmented frames
    assert (views[:, 0] - views[:, 1]).abs().max() > 1e-3
    loss = cvc_loss(views, aug["dR"], aug["dT"], aug["dS"])
    assert loss.item() < 1e-20


def test_normalised_distance_matrix_is_scale_invariant():
    # a global isotropic scale of one view's mapped-back keypoints leaves D-bar unchanged
    k = _kpts()
    assert torch.allclose(normalised_distance_matrix(k), normalised_distance_matrix(2.5 * k),
                          atol=1e-6)


def test_cvc_grows_monotonically_with_perturbation():
    k = _kpts(B=2, M=24, seed=1)
    noise = torch.randn(k.shape, generator=torch.Generator().manual_seed(5), dtype=k.dtype)
    dR, dT, dS = _identity_aug(2)
    losses = []
    for a in [0.0, 0.002, 0.005, 0.01, 0.02, 0.05]:
        views = torch.stack([k, k + a * noise], dim=1)
        losses.append(cvc_loss(views, dR, dT, dS).item())
    assert losses[0] == 0.0
    assert all(b > a for a, b in zip(losses, losses[1:])), losses


def test_cvc_gradient_finite_at_zero_distance_diagonal():
    k = _kpts(dtype=torch.float32).requires_grad_(True)
    k2 = k.detach() + 0.01
    dR, dT, dS = _identity_aug(k.shape[0], torch.float32)
    loss = cvc_loss(torch.stack([k, k2 * 1.0], 1), dR, dT, dS)
    loss.backward()
    assert torch.isfinite(k.grad).all()
    k.grad = None
    cvc_loss(torch.stack([k, k], 1), dR, dT, dS).backward()
    assert torch.isfinite(k.grad).all()


def test_view_transform_inverse_roundtrip():
    x = _kpts()
    aug = sample_augmentation(3, anisotropic_views=(0, 1), dtype=torch.float64)
    for v in range(2):
        y = apply_view_transform(x, aug["dR"][:, v], aug["dT"][:, v], aug["dS"][:, v])
        back = invert_view_transform(y, aug["dR"][:, v], aug["dT"][:, v], aug["dS"][:, v])
        assert torch.allclose(back, x, atol=1e-12)


def test_diversity_penalises_only_close_pairs():
    far = torch.tensor([[[0.0, 0, 0], [0.05, 0, 0], [0, 0.05, 0]]])
    assert diversity_loss(far, 0.01).item() == 0.0
    close = torch.tensor([[[0.0, 0, 0], [0.005, 0, 0], [0, 0.05, 0]]])
    # one unordered pair at half the threshold: 2 ordered pairs * 0.5 / (3*2)
    assert diversity_loss(close, 0.01).item() == pytest.approx(1.0 / 6.0, rel=1e-5)


def test_pose_loss_zero_at_ground_truth_and_positive_elsewhere():
    R = torch.eye(3).expand(2, 3, 3)
    t = torch.zeros(2, 3)
    s = torch.ones(2, 3)
    assert pose_loss(R, t, s, R, t, s).item() == 0.0
    assert pose_loss(R, t + 0.1, s, R, t, s).item() == pytest.approx(0.1 * math.sqrt(3), rel=1e-5)


def test_chamfer_and_surface_loss():
    a = _kpts(dtype=torch.float32)
    assert chamfer(a, a).item() < 1e-5
    assert keypoint_surface_loss(a, a).item() < 1e-5
    assert chamfer(a, a + 0.01).item() > 0.0


def test_pairwise_distance_matches_broadcast_differences_and_their_gradient():
    """_dist (torch.cdist, difference mode) against the (B, n, m, 3) broadcast it
    replaced, in value and in the gradient of a Chamfer-like loss, float32."""
    g = torch.Generator().manual_seed(3)
    a0 = torch.randn(2, 40, 3, generator=g) * 0.1
    b0 = torch.cat([a0[:, :5], torch.randn(2, 20, 3, generator=g) * 0.1], dim=1)  # exact zeros too
    grads = []
    for f in (_dist, lambda a, b: ((a.unsqueeze(2) - b.unsqueeze(1)) ** 2).sum(-1).clamp(min=1e-12).sqrt()):
        a, b = a0.clone().requires_grad_(), b0.clone().requires_grad_()
        d = f(a, b)
        (d.amin(2).mean() + d.amin(1).mean() + 0.01 * d.mean()).backward()
        grads.append((d.detach(), a.grad, b.grad))
    for x, y in zip(grads[0], grads[1]):
        assert torch.isfinite(x).all()
        assert torch.allclose(x, y, atol=1e-6, rtol=1e-5)
    assert (grads[0][0][:, :5, :5].diagonal(dim1=1, dim2=2) == 0).all()


def test_nocs_targets_agree_for_exact_points():
    # points generated from a pose: heatmap-weighted NOCS == pose-derived NOCS
    g = torch.Generator().manual_seed(0)
    B, N, M = 2, 50, 7
    nocs = torch.rand(B, N, 3, generator=g) - 0.5
    s = torch.tensor([[0.1, 0.2, 0.15], [0.3, 0.1, 0.1]])
    q, _ = torch.linalg.qr(torch.randn(B, 3, 3, generator=g))
    R = q * torch.det(q).sign()[:, None, None]
    t = torch.randn(B, 3, generator=g)
    pts = (nocs * s.norm(dim=-1)[:, None, None]) @ R.transpose(1, 2) + t[:, None]
    H = torch.softmax(torch.randn(B, M, N, generator=g), dim=-1)
    kpt = H @ pts
    assert torch.allclose(nocs_target_from_heatmap(H, nocs), nocs_target_from_pose(kpt, R, t, s),
                          atol=1e-5)


def test_smooth_l1_dis_matches_definition():
    a = torch.tensor([[[0.0, 0.05, 0.3]]])
    b = torch.zeros_like(a)
    expected = (0.05 ** 2 / (2 * 0.1)) + (0.3 - 0.05)
    assert smooth_l1_dis(a, b, 0.1).item() == pytest.approx(expected, rel=1e-5)


def test_compute_losses_total_is_weighted_sum():
    cfg = ModelConfig.shipped()
    B, M, N = 2, 5, 20
    g = torch.Generator().manual_seed(0)
    pts = torch.randn(B, N, 3, generator=g) * 0.05
    aug = sample_augmentation(B, generator=g)
    out = {"R": torch.eye(3).expand(B, 3, 3), "t": torch.zeros(B, 3), "s": torch.ones(B, 3) * 0.2,
           "kpt_3d": pts[:, :M], "recon": pts, "recon_delta": torch.zeros(B, 10, 3),
           "kpt_nocs": torch.zeros(B, M, 3), "heatmap": torch.softmax(torch.randn(B, M, N, generator=g), -1),
           "kpt_views": torch.randn(B, 2, M, 3, generator=g) * 0.05,
           "dR": aug["dR"], "dT": aug["dT"], "dS": aug["dS"], "pts": pts}
    tg = {"R": torch.eye(3).expand(B, 3, 3), "t": torch.ones(B, 3) * 0.01,
          "s": torch.ones(B, 3) * 0.25, "nocs": torch.rand(B, N, 3, generator=g) - 0.5}
    L = compute_losses(out, tg, cfg)
    ws = {"pose": cfg.w_pose, "nocs": cfg.w_nocs, "cd": cfg.w_cd, "div": cfg.w_div,
          "rec": cfg.w_rec, "delta": cfg.w_delta, "cvc": cfg.w_cvc}
    total = sum(ws[k] * L[k] for k in ws)
    assert torch.allclose(L["total"], total)
    assert L["cvc"].item() > 0
    L2 = compute_losses(out, tg, cfg.without_sckd())
    assert L2["cvc"].item() == 0.0


def _rot_y(phi):
    c, s = math.cos(phi), math.sin(phi)
    return torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], dtype=torch.float64)


def test_canonical_symmetric_rotation_removes_rotation_about_y():
    from tricons_pose.losses import canonical_symmetric_rotation
    q, _ = torch.linalg.qr(torch.randn(4, 3, 3, generator=torch.Generator().manual_seed(1),
                                       dtype=torch.float64))
    R = q * torch.det(q).sign()[:, None, None]
    Rc = canonical_symmetric_rotation(R)
    for phi in (0.3, 1.7, -2.9):
        assert torch.allclose(canonical_symmetric_rotation(R @ _rot_y(phi)), Rc, atol=1e-10)
    assert torch.allclose(Rc[:, :, 1], R[:, :, 1], atol=1e-12)           # y axis kept
    assert torch.allclose(Rc.transpose(1, 2) @ Rc, torch.eye(3, dtype=torch.float64).expand(4, 3, 3),
                          atol=1e-10)


def test_closest_symmetric_rotation():
    from tricons_pose.losses import closest_symmetric_rotation
    q, _ = torch.linalg.qr(torch.randn(3, 3, 3, generator=torch.Generator().manual_seed(2),
                                       dtype=torch.float64))
    R = q * torch.det(q).sign()[:, None, None]
    # a prediction equivalent to the GT up to a turn about y is matched exactly
    pred = R @ _rot_y(1.1)
    assert torch.allclose(closest_symmetric_rotation(R, pred), pred, atol=1e-10)
    # a level view with y_obj = -y_cam (the degenerate case of the fixed canonical form)
    level = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))[None]
    pred = level @ _rot_y(-2.0)
    assert torch.allclose(closest_symmetric_rotation(level, pred), pred, atol=1e-10)


def test_symmetric_instances_ignore_rotation_about_y():
    cfg = ModelConfig.shipped()
    B, M, N = 2, 4, 30
    g = torch.Generator().manual_seed(0)
    pts = torch.randn(B, N, 3, generator=g) * 0.05
    aug = sample_augmentation(B, generator=g)
    R_gt = (torch.eye(3) @ _rot_y(0.8).float()).expand(B, 3, 3)   # GT turned about y
    # prediction: the GT turned back about y (symmetry-equivalent)
    out = {"R": torch.eye(3).expand(B, 3, 3), "t": torch.zeros(B, 3), "s": torch.ones(B, 3) * 0.2,
           "kpt_3d": pts[:, :M], "recon": pts, "recon_delta": torch.zeros(B, 8, 3),
           "kpt_nocs": torch.zeros(B, M, 3), "heatmap": torch.softmax(torch.randn(B, M, N, generator=g), -1),
           "kpt_views": torch.randn(B, 2, M, 3, generator=g) * 0.05,
           "dR": aug["dR"], "dT": aug["dT"], "dS": aug["dS"], "pts": pts}
    tg = {"R": R_gt, "t": torch.zeros(B, 3), "s": torch.ones(B, 3) * 0.2,
          "nocs": torch.rand(B, N, 3, generator=g) - 0.5, "sym": torch.tensor([True, False])}
    L_sym = compute_losses(out, tg, cfg)
    L_all = compute_losses(out, dict(tg, sym=torch.tensor([True, True])), cfg)
    # symmetric: no rotation error; not symmetric: the 0.8 rad turn counts
    assert L_all["pose"].item() < 1e-5
    assert L_sym["pose"].item() > 0.1
