"""Recording reader and training-data pipeline (tricons_pose.recording, tricons_pose.data)."""

from __future__ import annotations

import json
import shutil
import struct
import zlib

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch.utils.data import DataLoader

from tricons_pose import data as D
from tricons_pose.recording import CLASSES, Instance, Intrinsics, Recording, RecordingError, decode_png, read_png

# ------------------------------------------------------------------------ PNG


def _paeth(a, b, c):
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    return a if pa <= pb and pa <= pc else (b if pb <= pc else c)


def encode_png(arr: np.ndarray, filters) -> bytes:
    """Straightforward reference encoder: filter type per row from ``filters``."""
    h, w = arr.shape[:2]
    ch = 1 if arr.ndim == 2 else arr.shape[2]
    depth = 16 if arr.dtype == np.uint16 else 8
    ctype = {1: 0, 2: 4, 3: 2, 4: 6}[ch]
    raw = arr.astype(">u2").tobytes() if depth == 16 else arr.tobytes()
    stride = w * ch * depth // 8
    bpp = ch * depth // 8
    rows = [raw[r * stride : (r + 1) * stride] for r in range(h)]
    out = bytearray()
    prev = bytes(stride)
    for r, row in enumerate(rows):
        f = filters[r % len(filters)]
        line = bytearray([f])
        for i in range(stride):
            a = row[i - bpp] if i >= bpp else 0
            b = prev[i]
            c = prev[i - bpp] if i >= bpp else 0
            pred = [0, a, b, (a + b) // 2, _paeth(a, b, c)][f]
            line.append((row[i] - pred) & 0xFF)
        out += line
        prev = row

    def chunk(t, body):
        return struct.pack(">I", len(body)) + t + body + struct.pack(">I", zlib.crc32(t + body) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", w, h, depth, ctype, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(bytes(out))) + chunk(b"IEND", b"")


@pytest.mark.parametrize("shape,dtype", [((7, 9), np.uint8), ((6, 5, 3), np.uint8), ((5, 8), np.uint16),
                                         ((9, 4, 3), np.uint16), ((4, 6, 4), np.uint8), ((3, 5, 2), np.uint16)])
@pytest.mark.parametrize("filters", [[0], [1], [2], [3], [4], [4, 3, 0, 2, 1, 4, 4, 3]])
@pytest.mark.parametrize("pillow", [True, False], ids=["pillow-where-exact", "numpy-only"])
def test_png_decoder_exact_all_filters(shape, dtype, filters, pillow, monkeypatch):
    import tricons_pose.recording as recording

    if not pillow:  # the numpy unfiltering for every format, as without Pillow
        monkeypatch.setattr(recording, "_decode_with_pillow", lambda *a: None)
    rng = np.random.default_rng(0)
    arr = rng.integers(0, np.iinfo(dtype).max + 1, size=shape, dtype=np.int64).astype(dtype)
    img = decode_png(encode_png(arr, filters))
    assert img.array.dtype == dtype and img.array.shape == shape
    np.testing.assert_array_equal(img.array, arr)


def test_png_errors_name_the_file(tmp_path):
    p = tmp_path / "x.png"
    p.write_bytes(b"not a png")
    with pytest.raises(RecordingError, match="x.png.*signature"):
        read_png(p)
    good = bytearray(encode_png(np.zeros((2, 2), np.uint8), [0]))
    good[-5] ^= 1  # IEND CRC
    p.write_bytes(bytes(good))
    with pytest.raises(RecordingError, match="x.png.*CRC"):
        read_png(p)
    with pytest.raises(RecordingError, match="missing.png"):
        read_png(tmp_path / "missing.png")


# ------------------------------------------------------------------ recording


def test_reader_shapes_and_types(recording):
    rec = Recording(recording)
    assert len(rec) == 3 and rec.size == (640, 480)
    assert rec.intrinsics.fx == pytest.approx(591.0125)
    c, d, ann = rec.color(0), rec.depth_m(0), rec.annotations(0)
    m, n = rec.mask(0, ann), rec.nocs_raw(0, ann)
    assert c.shape == (480, 640, 3) and c.dtype == np.uint8
    assert d.shape == (480, 640) and d.dtype == np.float32 and 0.2 <= d[d > 0].min() and d.max() <= 3.0
    assert m.shape == (480, 640) and set(np.unique(m)) == {0} | {i.id for i in ann.instances}
    assert n.shape == (480, 640, 3) and n.dtype == np.uint16
    # 16-bit exactness: an 8-bit truncation would give multiples of 257 only
    assert np.any(n[m > 0] % 257 != 0)
    assert np.all(n[m == 0] == 0)
    for inst in ann.instances:
        assert inst.cls in CLASSES and inst.class_id == CLASSES.index(inst.cls)
        np.testing.assert_allclose(inst.R @ inst.R.T, np.eye(3), atol=1e-6)


@pytest.mark.parametrize("which", ["recording", "recording_clean"])
def test_nocs_map_matches_depth_and_pose(which, request):
    """Back-project masked depth, map into the object frame, / |s| + 0.5 == NOCS map (median < 0.02)."""
    rec = Recording(request.getfixturevalue(which))
    k = rec.intrinsics
    checked = 0
    for fi in range(len(rec)):
        ann = rec.annotations(fi)
        depth, mask, nocs = rec.depth_m(fi).astype(np.float64), rec.mask(fi, ann), rec.nocs(fi, ann)
        for inst in ann.instances:
            v, u = np.nonzero((mask == inst.id) & (depth > 0))
            z = depth[v, u]
            p = np.stack([(u - k.cx) * z / k.fx, (v - k.cy) * z / k.fy, z], 1)
            obj = (p - inst.t) @ inst.R / np.linalg.norm(inst.s) + 0.5
            err = np.abs(obj - nocs[v, u]).max(axis=1)
            assert np.median(err) < 0.02, (fi, inst.id, np.median(err))
            checked += 1
    assert checked >= 2


def test_reader_errors_name_the_file(recording, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(recording, bad)
    man = json.loads((bad / "manifest.json").read_text())
    man["version"] = 2
    (bad / "manifest.json").write_text(json.dumps(man))
    with pytest.raises(RecordingError, match=r"manifest.json.*version"):
        Recording(bad)
    man["version"] = 1
    (bad / "manifest.json").write_text(json.dumps(man))
    rec = Recording(bad)
    # an 8-bit image where 16-bit depth is expected
    shutil.copy(bad / "000000_mask.png", bad / "000000_depth.png")
    with pytest.raises(RecordingError, match=r"000000_depth.png.*16-bit gray"):
        rec.depth_raw(0)
    gt = json.loads((bad / "000001_gt.json").read_text())
    gt["instances"][0]["class"] = "teapot"
    (bad / "000001_gt.json").write_text(json.dumps(gt))
    with pytest.raises(RecordingError, match=r"000001_gt.json.*teapot"):
        rec.annotations(1)
    (bad / "000002_coord.png").unlink()
    with pytest.raises(RecordingError, match="000002_coord.png"):
        rec.nocs(2)
    with pytest.raises(RecordingError, match="not found"):
        Recording(tmp_path / "nothing")


# ---------------------------------------------------------------- preprocessing


@pytest.mark.parametrize("h,w,side", [(10, 30, 40), (39, 1, 40), (40, 10, 80), (79, 79, 80), (80, 5, 120),
                                      (399, 2, 400), (400, 100, 440), (439, 10, 440), (470, 600, 440)])
def test_crop_side_formula(h, w, side):
    assert D.crop_side(h, w) == side


def test_crop_window_hand_cases():
    assert D.crop_window((100, 150, 200, 260), 480, 640) == (85, 165, 190, 270)  # side 80, centre (125, 230)
    assert D.crop_window((0, 10, 0, 10), 480, 640) == (0, 40, 0, 40)  # shifted down/right
    assert D.crop_window((470, 480, 630, 640), 480, 640) == (440, 480, 600, 640)  # shifted up/left
    assert D.crop_window((0, 480, 0, 640), 480, 640) == (20, 460, 100, 540)  # capped at 440, centred
    assert D.mask_bbox(np.pad(np.ones((3, 4), bool), ((5, 2), (7, 1)))) == (5, 8, 7, 11)


def test_remap_choose_and_resize():
    side, S = 200, 192
    ch = np.array([25 * side + 199, 0, side * side - 1])
    np.testing.assert_array_equal(D.remap_choose(ch, side, S), [24 * S + 191, 0, S * S - 1])
    img = np.random.default_rng(1).integers(0, 256, (200, 200, 3)).astype(np.uint8)
    ours = D.resize_bilinear(img, 96)
    ref = F.interpolate(torch.from_numpy(img).permute(2, 0, 1)[None].double(), size=(96, 96), mode="bilinear",
                        align_corners=False)[0].permute(1, 2, 0).numpy()
    np.testing.assert_allclose(ours, ref, atol=1e-9)
    up = D.resize_bilinear(img[:50, :50], 96)  # upscaling too
    ref = F.interpolate(torch.from_numpy(img[:50, :50]).permute(2, 0, 1)[None].double(), size=(96, 96),
                        mode="bilinear", align_corners=False)[0].permute(1, 2, 0).numpy()
    np.testing.assert_allclose(up, ref, atol=1e-9)


def _fake_prepared(n_valid: int) -> D.PreparedInstance:
    side = 40
    rng = np.random.default_rng(3)
    choose = np.sort(rng.choice(side * side, n_valid, replace=False)).astype(np.int64)
    inst = Instance(1, "mug", 5, np.eye(3), np.array([0.0, 0.0, 0.5]), np.array([0.1, 0.1, 0.1]), True)
    return D.PreparedInstance((100, 140, 200, 240), np.zeros((side, side, 3), np.uint8), choose,
                              np.full(n_valid, 500, np.uint16), np.full((n_valid, 3), 32768, np.uint16), inst, 0.001,
                              Intrinsics(640, 480, 600.0, 600.0, 320.0, 240.0))


def test_sampling_with_replacement_only_when_short():
    short = D.make_sample(_fake_prepared(20), 64, 32, np.random.default_rng(0))
    assert short["pts"].shape == (64, 3) and len(torch.unique(short["choose"])) <= 20
    idx = D.sample_indices(20, 64, np.random.default_rng(0))
    assert idx.shape == (64,) and idx.max() < 20 and len(set(idx.tolist())) < 64  # repeats
    enough = D.sample_indices(100, 64, np.random.default_rng(0))
    assert len(set(enough.tolist())) == 64


def test_dataset_samples(recording):
    ds = D.InstanceDataset([recording], n_points=256, crop_size=64, seed=3)
    rec = ds.recordings[0]
    assert len(ds) == sum(len(rec.annotations(i).instances) for i in range(len(rec)))
    k = rec.intrinsics
    frames = {fi: (rec.mask(fi), rec.depth_m(fi), rec.nocs(fi), rec.color(fi)) for fi in range(len(rec))}
    for i in range(len(ds)):
        s = ds[i]
        assert s["rgb"].shape == (3, 64, 64) and s["rgb"].dtype == torch.float32
        assert s["pts"].shape == (256, 3) and s["nocs"].shape == (256, 3) and s["choose"].dtype == torch.int64
        assert s["R"].shape == (3, 3) and s["t"].shape == (3,) and s["s"].shape == (3,)
        assert 0 <= int(s["choose"].min()) and int(s["choose"].max()) < 64 * 64
        assert "aug_R" not in s
        j = int(s["index"])
        p = ds.prepared(j)
        ref = ds._anns[(ds.index[j].rec, ds.index[j].frame)][ds.index[j].pos]
        assert int(s["class_id"]) == ref.class_id
        # the same draws again: choose points into the mask, pts back-project from the depth there
        idx = D.sample_indices(p.n_valid, 256, np.random.default_rng((3, 0, i)))
        ch = p.choose_all[idx]
        rmin, rmax, cmin, _ = p.window
        v, u = ch // p.side + rmin, ch % p.side + cmin
        fi = ds.index[j].frame
        mask, depth, nocs, color = frames[fi]
        assert np.all(mask[v, u] == ref.id)
        assert np.all(depth[v, u] > 0)
        pts = s["pts"].double().numpy()
        np.testing.assert_allclose(pts[:, 2], depth[v, u], rtol=1e-6)
        np.testing.assert_allclose(pts[:, 0] / pts[:, 2] * k.fx + k.cx, u, atol=1e-3)
        np.testing.assert_allclose(pts[:, 1] / pts[:, 2] * k.fy + k.cy, v, atol=1e-3)
        np.testing.assert_array_equal(s["choose"].numpy(), D.remap_choose(ch, p.side, 64))
        np.testing.assert_allclose(s["nocs"].numpy() + 0.5, nocs[v, u], atol=1e-6)
        # the rgb is the normalised resized crop
        crop = color[rmin:rmax, cmin:p.window[3]]
        np.testing.assert_allclose(s["rgb"].numpy(), D.normalise_rgb(D.resize_bilinear(crop, 64)), atol=1e-6)


def test_dataset_deterministic(recording):
    mk = lambda seed: D.InstanceDataset([recording], n_points=128, crop_size=32, seed=seed, augment=D.AugmentConfig())
    a, b, c = mk(7), mk(7), mk(8)
    sa, sb, sc = a[1], b[1], c[1]
    for key in sa:
        assert torch.equal(sa[key], sb[key]), key
    assert not torch.equal(sa["pts"], sc["pts"])
    a.set_epoch(1)
    assert not torch.equal(a[1]["aug_pts"], sa["aug_pts"])
    a.set_epoch(0)
    assert torch.equal(a[1]["aug_pts"], sa["aug_pts"])


def test_small_instances_are_replaced_by_the_next(recording):
    ds = D.InstanceDataset([recording], n_points=64, crop_size=32)
    ds.prepared(0)
    key = (ds.index[0].rec, ds.index[0].frame)
    ds._mem[key][ds.index[0].pos] = _fake_prepared(16)  # not more than 16 valid pixels
    assert int(ds[0]["index"]) == 1 and 0 in ds.skipped


@pytest.mark.parametrize("axes", ["camera", "object"])
def test_augmentation_round_trip_and_view_targets(recording, axes):
    aug = D.AugmentConfig(scale_axes=axes, isotropic_views=(0,) if axes == "camera" else ())
    ds = D.InstanceDataset([recording], n_points=256, crop_size=32, seed=1, augment=aug)
    for i in range(len(ds)):
        s = ds[i]
        x = s["pts"].double()
        for v in range(2):
            dR, dS, dT = s["aug_R"][v].double(), s["aug_S"][v].double(), s["aug_T"][v].double()
            y = s["aug_pts"][v].double()
            back = (dR.T @ torch.linalg.solve(dS, (y - dT).T)).T  # x = dR^-1 dS^-1 (y - dT)
            assert (back - x).abs().max() < 1e-6
            np.testing.assert_allclose(dR.T @ dR, np.eye(3), atol=1e-6)
            e = s["aug_scale"][v].double()
            assert torch.all((e >= 0.8) & (e <= 1.2))
            ang = torch.arccos(((torch.trace(dR) - 1) / 2).clamp(-1, 1))
            assert 0 < float(ang) <= np.deg2rad(20 * 3 ** 0.5)
            if axes == "camera":
                np.testing.assert_allclose(dS.numpy(), torch.diag(e).numpy(), atol=1e-7)
                # the model's centred convention (forward_train) gives the same points
                c = x.mean(0)
                model_view = e * ((x - c) @ dR.T) + s["aug_dt"][v].double()
                assert (model_view + c - y).abs().max() < 1e-6
                if v == 0:
                    assert float(e.max() - e.min()) == 0.0
                assert "aug_gt_R" not in s
                continue
            # the view's targets are exact: A (R p + t) + dT == R_v (e * p) + t_v
            p = torch.randn(5, 3, dtype=torch.float64) * 0.05
            lhs = ((s["R"].double() @ p.T).T + s["t"].double()) @ (dS @ dR).T + dT
            rhs = (s["aug_gt_R"][v].double() @ (e * p).T).T + s["aug_gt_t"][v].double()
            assert (lhs - rhs).abs().max() < 1e-5
            np.testing.assert_allclose(s["aug_gt_s"][v].numpy(), (s["s"].double() * e).numpy(), rtol=1e-6)
            # view NOCS consistent with view points and view pose, as for the original
            obj = (y - s["aug_gt_t"][v].double()) @ s["aug_gt_R"][v].double() / s["aug_gt_s"][v].double().norm()
            assert (obj - s["aug_nocs"][v].double()).abs().max(dim=1).values.median() < 0.02
        assert not torch.equal(s["aug_R"][0], s["aug_R"][1])


def test_dataloader_collate_and_split(recording, tmp_path):
    ds = D.InstanceDataset([recording], n_points=64, crop_size=32, augment=D.AugmentConfig(), cache_dir=tmp_path / "c")
    batch = next(iter(DataLoader(ds, batch_size=3, shuffle=False)))
    inputs, aug, targets = D.split_batch(batch)
    assert inputs["rgb"].shape == (3, 3, 32, 32) and inputs["pts"].shape == (3, 64, 3)
    assert aug["pts"].shape == (3, 2, 64, 3) and aug["R"].shape == (3, 2, 3, 3) and aug["S"].shape == (3, 2, 3, 3)
    assert aug["dR"].shape == (3, 2, 3, 3) and aug["dS"].shape == (3, 2, 3) and aug["dT"].shape == (3, 2, 3)
    assert targets["class_id"].shape == (3,)
    assert list((tmp_path / "c").glob("*.npz"))
    # a fresh dataset reads the disk cache and gives identical samples
    ds2 = D.InstanceDataset([recording], n_points=64, crop_size=32, augment=D.AugmentConfig(), cache_dir=tmp_path / "c")
    ds2._load_frame = None  # would fail if called: prepared() must come from the cache
    ds2.__dict__.pop("_load_frame")
    for key, v in ds[2].items():
        assert torch.equal(v, ds2[2][key]), key


# ------------------------------------------------------------ mask perturbation


def test_perturb_mask_exact_cases():
    m = np.zeros((7, 7), bool)
    m[3, 3] = True
    grown = D.perturb_mask(m, 1, 0, 0)
    assert grown.sum() == 9 and grown[2:5, 2:5].all()
    assert np.array_equal(D.perturb_mask(grown, -1, 0, 0), m)  # a 3x3 square eroded by 1: its centre
    assert np.array_equal(D.perturb_mask(m, 0, 0, 0), m)
    moved = D.perturb_mask(m, 0, 2, -1)
    assert moved.sum() == 1 and moved[5, 2]
    assert not D.perturb_mask(m, 0, 4, 0).any()  # shifted off the window
    # erosion treats the outside as mask: a mask filling the window's left column stays
    edge = np.zeros((5, 5), bool)
    edge[:, :2] = True
    assert np.array_equal(D.perturb_mask(edge, -1, 0, 0)[:, 0], np.ones(5, bool))
    assert not D.perturb_mask(edge, -1, 0, 0)[:, 1].any()
    # dilation by 2 of a pixel near the corner is clipped by the window
    c = np.zeros((5, 5), bool)
    c[0, 0] = True
    assert D.perturb_mask(c, 2, 0, 0).sum() == 9


def test_perturbation_config_is_checked():
    with pytest.raises(ValueError, match="mask_perturb"):
        D.AugmentConfig(mask_perturb=1.5)
    with pytest.raises(ValueError, match="mask_dilate_px"):
        D.AugmentConfig(mask_dilate_px=-1)
    # the mask and depth of the crop window are needed
    with pytest.raises(ValueError, match="keep_crop"):
        D.perturbed_pixels(_fake_prepared(50), np.random.default_rng(0), D.AugmentConfig(mask_perturb=0.5))


def test_perturbed_samples_lie_in_the_perturbed_mask_with_map_or_pose_nocs(recording):
    aug = D.AugmentConfig(mask_perturb=1.0, mask_dilate_px=3, mask_erode_px=2, mask_shift_px=2)
    ds = D.InstanceDataset([recording], n_points=256, crop_size=64, seed=5, augment=aug)
    rec = ds.recordings[0]
    k = rec.intrinsics
    n_off = 0
    for i in range(len(ds)):
        s = ds[i]
        j = int(s["index"])
        p = ds.prepared(j)
        ref = ds._anns[(ds.index[j].rec, ds.index[j].frame)][ds.index[j].pos]
        fi = ds.index[j].frame
        mask, depth, nocs_map = rec.mask(fi), rec.depth_m(fi), rec.nocs(fi)
        rmin, rmax, cmin, cmax = p.window
        assert np.array_equal(p.mask_crop, mask[rmin:rmax, cmin:cmax] == ref.id)
        # the same draws again: the perturbed mask, then the points sampled from it
        rng = np.random.default_rng((5, 0, i))
        u = rng.random()
        radius = int(rng.integers(-2, 4))
        dy, dx = (int(v) for v in rng.integers(-2, 3, 2))
        assert u < 1.0
        pm = D.perturb_mask(p.mask_crop, radius, dy, dx) & (p.depth_crop > 0)
        if pm.sum() <= D.MIN_VALID_PIXELS:
            continue
        choose_all = np.flatnonzero(pm)
        idx = D.sample_indices(choose_all.size, 256, rng)
        ch = choose_all[idx]
        np.testing.assert_array_equal(s["choose"].numpy(), D.remap_choose(ch, p.side, 64))
        v, u_ = ch // p.side + rmin, ch % p.side + cmin
        pts = s["pts"].double().numpy()
        np.testing.assert_allclose(pts[:, 2], depth[v, u_], rtol=1e-6)
        np.testing.assert_allclose(pts[:, 0] / pts[:, 2] * k.fx + k.cx, u_, atol=1e-3)
        on = mask[v, u_] == ref.id
        n_off += int((~on).sum())
        got = s["nocs"].double().numpy()
        # on the instance: the NOCS map; off it: the pose's coordinates R^T (p - t) / |s|
        np.testing.assert_allclose(got[on] + 0.5, nocs_map[v[on], u_[on]], atol=1e-6)
        pose = (pts - ref.t) @ ref.R / np.linalg.norm(ref.s)
        np.testing.assert_allclose(got[~on], pose[~on], atol=1e-5)
    assert n_off > 0  # some dilated or shifted mask reached off the instance


def test_crop_arrays_are_cached_beside_the_instances(recording, tmp_path):
    cache = tmp_path / "c"
    plain = D.InstanceDataset([recording], n_points=64, crop_size=32, cache_dir=cache)
    for i in range(len(plain)):
        plain.prepared(i)
    assert list(cache.glob("*.npz")) and not list(cache.glob("*.crop.npz"))
    aug = D.AugmentConfig(mask_perturb=0.7)
    # the instance cache exists: the crops are added from the depth and mask images
    a = D.InstanceDataset([recording], n_points=64, crop_size=32, seed=2, augment=aug, cache_dir=cache)
    b = D.InstanceDataset([recording], n_points=64, crop_size=32, seed=2, augment=aug)  # no disk cache
    sa = [a[i] for i in range(len(a))]
    assert len(list(cache.glob("*.crop.npz"))) == len(list(cache.glob("*.npz"))) // 2
    for x, y in zip(sa, (b[i] for i in range(len(b)))):
        for key in x:
            assert torch.equal(x[key], y[key]), key
    # and read back from the crop files
    c = D.InstanceDataset([recording], n_points=64, crop_size=32, seed=2, augment=aug, cache_dir=cache)
    c.recordings[0].depth_raw = None  # would fail if the frames were decoded again
    for x, i in zip(sa, range(len(c))):
        for key, val in c[i].items():
            assert torch.equal(val, x[key]), key
