"""The NOCS dataset layout (CAMERA25 / REAL275) in tools/: a reader for training and
prediction, and a writer that turns a tricons recording (SynthNOCS) into that layout so
that every path of issue 19 is tested without the real data.

The layout, as the NOCS authors distribute it and SPD / DualPoseNet / AG-Pose read it::

    ROOT/Real/{train,test}/scene_K/NNNN_{color,depth,mask,coord}.png, NNNN_meta.txt
    ROOT/CAMERA/{train,val}/SSSSS/NNNN_{color,depth,mask,coord}.png, NNNN_meta.txt  (ten frames a folder)
    ROOT/camera_full_depths/{train,val}/SSSSS/NNNN_composed.png  (CAMERA's depth with the real background)
    ROOT/obj_models/{train,val}/SYNSET/MODEL/bbox.txt  (CAMERA's box corners, NOCS units: NOCS's loader)
    ROOT/Real/train/scene_K/NNNN_label.pkl      (SPD's preprocessing: poses per image)
    ROOT/obj_models/{real_train,real_test,camera_train,camera_val}.pkl  (model points, NOCS space)
    ROOT/obj_models/{real_train,real_test}/MODEL.txt  (the model's box size, NOCS units: NOCS's loader)
    ROOT/gts/real_test/results_real_test_scene_K_NNNN.pkl     (ground truth for evaluation)
    ROOT/segmentation_results/real_test/results_test_scene_K_NNNN.pkl  (published Mask R-CNN)

File conventions (the NOCS repository's ``load_*`` functions): ``_mask.png`` 8-bit
instance ids, 255 = background; ``_coord.png`` 8-bit RGB, NOCS coordinate + 0.5 with z
stored flipped (the loader uses ``1 - z``); ``_depth.png`` 16-bit millimetres. CAMERA's
``_depth.png`` holds the rendered objects only; what SPD / AG-Pose train and test on is the
``_composed.png`` of ``camera_full_depths/`` (the objects over a real background), 8-bit
RGB with depth = G * 256 + R and 32001 = no depth; it is read from the scene folder or
that tree, and a CAMERA scene without it is an error. ``_meta.txt`` lines
``instance_id class_id model_name`` (Real) or ``instance_id class_id synset model_id``
(CAMERA); class ids 1..6 = bottle, bowl, camera, can, laptop, mug; 0 = distractor. The
group and split folders may be spelled ``CAMERA``/``Real`` (NOCS, SPD) or
``camera``/``real`` (DualPoseNet, AG-Pose). Poses: ``_label.pkl`` holds ``instance_ids``, ``class_ids``,
``bboxes`` (y1, x1, y2, x2), ``scales`` (the box diagonal, metres), ``rotations``,
``translations``, ``model_list``; the box extents in NOCS units come from the object
model's points (``2 max |p|`` per axis), so size = scale * extents. ``gt_RTs`` are 4x4
``[s R | t]`` with ``gt_scales`` the normalised extents.

:class:`NocsLayoutRecording` offers the same interface as :class:`~.recording.Recording`
(what :class:`~.data.InstanceDataset` and ``predict`` use), so ``train --data`` and
``predict --data`` take a scene directory or a split directory of scenes.
"""

from __future__ import annotations

import os
import pickle
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .recording import CLASSES, Annotations, FrameEntry, Instance, Intrinsics, Recording, RecordingError, read_png

MASK_BACKGROUND = 255
"""Background value of NOCS ``_mask.png`` files."""
REAL275 = Intrinsics(640, 480, 591.0125, 590.16775, 322.525, 244.11084)
CAMERA25 = Intrinsics(640, 480, 577.5, 577.5, 319.5, 239.5)
DEPTH_SCALE_M = 0.001
"""NOCS depth files are millimetres."""
SPLIT_DIRS = {"real_train": ("Real", "train"), "real_test": ("Real", "test"),
              "camera_train": ("CAMERA", "train"), "camera_val": ("CAMERA", "val")}
"""Split name -> directories under the dataset root (the obj_models / gts file names)."""
SYMMETRIC = ("bottle", "bowl", "can")
COMPOSED_NO_DEPTH = 32001
"""The value of a ``_composed.png`` pixel without depth (SPD / AG-Pose map it to 0)."""
SYNSETS = {"bottle": "02876657", "bowl": "02880940", "camera": "02942699", "can": "02946921",
           "laptop": "03642806", "mug": "03797390"}
"""ShapeNet synset of each class: CAMERA's meta lines and object-model folders name it."""
FRAMES_PER_CAMERA_FOLDER = 10


def class_id(name: str) -> int:
    """NOCS class id (1-based) of a class name."""
    return CLASSES.index(name) + 1


def _save_png(path: Path, array: np.ndarray) -> None:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.tmp{os.getpid()}")
    Image.fromarray(array).save(tmp, format="PNG")  # uint16 (H, W) -> 16-bit grayscale
    os.replace(tmp, path)


def _save_pickle(path: Path, obj) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.tmp{os.getpid()}")
    with open(tmp, "wb") as f:
        pickle.dump(obj, f, protocol=2)  # the published files were written by Python 2's cPickle
    os.replace(tmp, path)


def _bbox(mask: np.ndarray) -> np.ndarray:
    """(y1, x1, y2, x2) of a boolean mask, NOCS convention (exclusive end), int32."""
    ys, xs = np.nonzero(mask)
    return np.array([ys.min(), xs.min(), ys.max() + 1, xs.max() + 1], dtype=np.int32)


def write_nocs_layout(recording: str | os.PathLike, root: str | os.PathLike, split: str = "real_test",
                      scene: str = "scene_1") -> Path:
    """Writes the frames of tricons recording ``recording`` as scene ``scene`` of ``split``
    under dataset root ``root``, with the pose pickles (``_label.pkl``, ``gts/``), the
    object models (``obj_models/``) and segmentation-result pickles made from the
    ground-truth masks (score 1), all written by Python's pickle. Frame ids, instance ids
    and classes are kept (so predictions on the two can be scored against either ground
    truth). Returns the scene directory.

    A CAMERA split is written as CAMERA25 is distributed instead: frame k is
    ``SSSSS/NNNN`` with ``SSSSS = k // 10`` and ``NNNN = k % 10`` (``scene`` is not used,
    the split directory is returned), ``_depth.png`` holds the objects' depth only and the
    whole depth goes to ``camera_full_depths/<split>/SSSSS/NNNN_composed.png``; meta lines
    name a synset and a model, whose ``obj_models/<split>/SYNSET/MODEL/bbox.txt`` the NOCS
    loader reads.

    The recording's intrinsics must be the split's (REAL275 or CAMERA25: a NOCS layout has
    no intrinsics file); depth is written in millimetres.
    """
    if split not in SPLIT_DIRS:
        raise ValueError(f"split {split!r}: one of {', '.join(SPLIT_DIRS)}")
    rec = Recording(recording)
    want = CAMERA25 if split.startswith("camera") else REAL275
    if rec.intrinsics != want:
        raise RecordingError(f"{rec.manifest_path}: intrinsics {rec.intrinsics} are not {split}'s {want}")
    root = Path(root)
    camera = split.startswith("camera")
    part = SPLIT_DIRS[split][1]
    models: dict[str, np.ndarray] = {}
    models_path = root / "obj_models" / f"{split}.pkl"
    if models_path.exists():
        with open(models_path, "rb") as f:
            models = pickle.load(f)
    for i in range(len(rec)):
        ann = rec.annotations(i)
        if ann is None or ann.mask is None or ann.nocs is None:
            raise RecordingError(f"{rec.root}: frame {rec.frames[i].id} has no mask or NOCS map")
        if camera:
            scene, nid = f"{i // FRAMES_PER_CAMERA_FOLDER:05d}", f"{i % FRAMES_PER_CAMERA_FOLDER:04d}"
        else:
            nid = rec.frames[i].id
        scene_dir = root.joinpath(*SPLIT_DIRS[split], scene)
        scene_dir.mkdir(parents=True, exist_ok=True)
        _save_png(scene_dir / f"{nid}_color.png", rec.color(i))
        depth_mm = np.rint(rec.depth_raw(i).astype(np.float64) * rec.depth_scale_m / DEPTH_SCALE_M)
        depth_mm = np.clip(depth_mm, 0, 65535).astype(np.uint16)
        label = rec.mask(i, ann)
        if camera:
            if (depth_mm == COMPOSED_NO_DEPTH).any():
                raise RecordingError(f"{rec.root}: frame {rec.frames[i].id} has a depth of {COMPOSED_NO_DEPTH} mm, "
                                     "which a composed depth file cannot hold")
            _save_png(scene_dir / f"{nid}_depth.png", np.where(label > 0, depth_mm, 0).astype(np.uint16))
            composed = np.stack([depth_mm & 0xFF, depth_mm >> 8, np.zeros_like(depth_mm)], axis=-1).astype(np.uint8)
            _save_png(root / "camera_full_depths" / part / scene / f"{nid}_composed.png", composed)
        else:
            _save_png(scene_dir / f"{nid}_depth.png", depth_mm)
        mask = np.where(label == 0, MASK_BACKGROUND, label).astype(np.uint8)
        _save_png(scene_dir / f"{nid}_mask.png", mask)
        nocs = rec.nocs(i, ann)  # [0, 1], the object's NOCS coordinate + 0.5
        coord = np.rint(nocs * 255.0)
        coord[..., 2] = 255.0 - coord[..., 2]  # stored flipped, as the dataset does
        coord[label == 0] = 0
        _save_png(scene_dir / f"{nid}_coord.png", coord.astype(np.uint8))
        lines, label_pkl, gts, seg = [], {k: [] for k in ("instance_ids", "class_ids", "bboxes", "scales", "rotations",
                                                            "translations", "model_list")}, [], []
        for inst in ann.instances:
            inst_mask = label == inst.id
            if not inst_mask.any():
                continue
            diag = float(np.linalg.norm(inst.s))
            extents = np.asarray(inst.s, dtype=np.float64) / diag
            model = f"synth_{inst.cls}_{rec.frames[i].id}_{inst.id}"
            # the model's points: its box corners in NOCS units (2 max |p| = the extents)
            corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
            models[model] = (0.5 * corners * extents).astype(np.float32)
            # what the NOCS repository's own loader reads for a model's box
            if camera:
                box = root / "obj_models" / part / SYNSETS[inst.cls] / model / "bbox.txt"
                text = "".join(" ".join(f"{v:.9g}" for v in corner) + "\n" for corner in (extents / 2, -extents / 2))
                lines.append(f"{inst.id} {class_id(inst.cls)} {SYNSETS[inst.cls]} {model}")
            else:
                box = root / "obj_models" / split / f"{model}.txt"
                text = " ".join(f"{v:.9g}" for v in extents) + "\n"
                lines.append(f"{inst.id} {class_id(inst.cls)} {model}")
            box.parent.mkdir(parents=True, exist_ok=True)
            box.write_text(text, encoding="utf-8")
            label_pkl["instance_ids"].append(inst.id)
            label_pkl["class_ids"].append(class_id(inst.cls))
            label_pkl["bboxes"].append(_bbox(inst_mask))
            label_pkl["scales"].append(diag)
            label_pkl["rotations"].append(np.asarray(inst.R, dtype=np.float32))
            label_pkl["translations"].append(np.asarray(inst.t, dtype=np.float32))
            label_pkl["model_list"].append(model)
            RT = np.eye(4)
            RT[:3, :3] = diag * np.asarray(inst.R)
            RT[:3, 3] = inst.t
            gts.append((class_id(inst.cls), _bbox(inst_mask), RT, extents,
                        1 if inst.cls != "mug" or inst.handle_visible else 0))
            seg.append((class_id(inst.cls), 1.0, inst_mask, _bbox(inst_mask)))
        (scene_dir / f"{nid}_meta.txt").write_text("".join(f"{ln}\n" for ln in lines), encoding="utf-8")
        n = len(label_pkl["instance_ids"])
        label_out = {
            "instance_ids": list(label_pkl["instance_ids"]),
            "class_ids": list(label_pkl["class_ids"]),
            "bboxes": np.array(label_pkl["bboxes"], dtype=np.int32).reshape(n, 4),
            "scales": np.array(label_pkl["scales"], dtype=np.float32),
            "rotations": np.array(label_pkl["rotations"], dtype=np.float32).reshape(n, 3, 3),
            "translations": np.array(label_pkl["translations"], dtype=np.float32).reshape(n, 3),
            "model_list": list(label_pkl["model_list"]),
        }
        _save_pickle(scene_dir / f"{nid}_label.pkl", label_out)
        prefix = f"{SPLIT_DIRS[split][0].lower()}/{SPLIT_DIRS[split][1]}"
        gt_split = part if camera else split  # gts/val/results_val_00000_0000.pkl, gts/real_test/results_real_test_...
        _save_pickle(root / "gts" / gt_split / f"results_{gt_split}_{scene}_{nid}.pkl", {
            "image_path": f"data/{prefix}/{scene}/{nid}",
            "gt_class_ids": np.array([g[0] for g in gts], dtype=np.int32),
            "gt_bboxes": np.array([g[1] for g in gts], dtype=np.int32).reshape(n, 4),
            "gt_RTs": np.array([g[2] for g in gts], dtype=np.float64).reshape(n, 4, 4),
            "gt_scales": np.array([g[3] for g in gts], dtype=np.float64).reshape(n, 3),
            "gt_handle_visibility": np.array([g[4] for g in gts], dtype=np.int32),
        })
        h, w = label.shape
        _save_pickle(root / "segmentation_results" / split / f"results_{split.split('_')[1]}_{scene}_{nid}.pkl", {
            "pred_class_ids": np.array([s[0] for s in seg], dtype=np.int32),
            "pred_scores": np.array([s[1] for s in seg], dtype=np.float32),
            "pred_masks": (np.stack([s[2] for s in seg], axis=-1) if seg else np.zeros((h, w, 0), dtype=bool)),
            "pred_bboxes": np.array([s[3] for s in seg], dtype=np.int32).reshape(len(seg), 4),
        })
    _save_pickle(models_path, models)
    return root.joinpath(*SPLIT_DIRS[split]) if camera else scene_dir


@dataclass(frozen=True)
class _Frame:
    id: str
    label: dict | None


def scene_dirs(path: str | os.PathLike) -> list[Path]:
    """``path`` itself when it holds ``*_color.png`` frames, else its sub-directories that
    do (a split directory such as ``Real/train``), sorted."""
    path = Path(path)
    if any(path.glob("*_color.png")):
        return [path]
    scenes = sorted(d for d in path.iterdir() if d.is_dir() and any(d.glob("*_color.png")))
    if not scenes:
        raise RecordingError(f"{path}: neither a NOCS scene (*_color.png) nor a directory of scenes")
    return scenes


def _split_of(scene: Path) -> tuple[Path, str] | None:
    """(dataset root, split name) of a scene directory ``ROOT/Real/train/scene_1``."""
    group, part = scene.parent.parent.name.lower(), scene.parent.name.lower()
    for name, (g, p) in SPLIT_DIRS.items():
        if (group, part) == (g.lower(), p.lower()):
            return scene.parent.parent.parent, name
    return None


def is_nocs_layout(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a NOCS scene or split directory (not a tricons recording)."""
    path = Path(path)
    if (path / "manifest.json").exists() or not path.is_dir():
        return False
    try:
        scene_dirs(path)
    except RecordingError:
        return False
    return True


class NocsLayoutRecording:
    """One NOCS scene directory read like a tricons :class:`~.recording.Recording`.

    Poses come from the frames' ``_label.pkl`` with sizes from the object models
    (``obj_models/<split>.pkl`` under the dataset root, found from the scene's path, or
    ``obj_models`` given); mug handle visibility from the split's ``gts/`` pickle when
    there is one (else visible). Frames without a label pickle are unannotated.
    ``intrinsics``: the split's (CAMERA25 for ``CAMERA/*``, REAL275 otherwise) unless given.
    """

    def __init__(self, scene: str | os.PathLike, intrinsics: Intrinsics | None = None,
                 obj_models: str | os.PathLike | None = None):
        self.root = Path(scene)
        self.manifest_path = self.root  # error messages name the scene
        split = _split_of(self.root)
        if intrinsics is None:
            intrinsics = CAMERA25 if split is not None and split[1].startswith("camera") else REAL275
        self.intrinsics = intrinsics
        self.depth_scale_m = DEPTH_SCALE_M
        self.source = f"NOCS layout {self.root}"
        ids = sorted(p.name[: -len("_color.png")] for p in self.root.glob("*_color.png"))
        if not ids:
            raise RecordingError(f"{self.root}: no *_color.png frames in this NOCS scene")
        self._split = split
        models_path = Path(obj_models) if obj_models is not None else (
            split[0] / "obj_models" / f"{split[1]}.pkl" if split is not None else None)
        self._models: dict | None = None
        if models_path is not None and models_path.exists():
            with open(models_path, "rb") as f:
                self._models = pickle.load(f)
        self.frames: list[FrameEntry] = []
        camera = split is not None and split[1].startswith("camera")
        full_depths = split[0] / "camera_full_depths" / self.root.parent.name / self.root.name if camera else None
        for k, fid in enumerate(ids):
            depth = self._depth_file(fid, full_depths, camera)
            label = f"{fid}_label.pkl" if (self.root / f"{fid}_label.pkl").exists() else None
            self.frames.append(FrameEntry(fid, k / 30.0, f"{fid}_color.png", depth, label))

    def _depth_file(self, fid: str, full_depths: Path | None, camera: bool) -> str:
        """The frame's depth file: CAMERA's composed depth (scene folder, then
        ``camera_full_depths/``), else ``_depth.png``. A CAMERA frame without a composed
        file names ``_composed.png`` (the error comes when its depth is read)."""
        composed = [self.root / f"{fid}_composed.png"]
        if full_depths is not None:
            composed.append(full_depths / f"{fid}_composed.png")
        for p in composed:
            if p.exists():
                return str(p)
        if camera or not (self.root / f"{fid}_depth.png").exists():
            return str(composed[-1])
        return f"{fid}_depth.png"

    def __len__(self) -> int:
        return len(self.frames)

    def __repr__(self) -> str:
        return f"NocsLayoutRecording({str(self.root)!r}, frames={len(self.frames)})"

    @property
    def size(self) -> tuple[int, int]:
        return (self.intrinsics.width, self.intrinsics.height)

    def _image(self, name: str, what: str):
        p = self.root / name
        if not p.exists() and name.endswith("_composed.png"):
            raise RecordingError(f"{p}: no such file: a CAMERA frame's depth is its _composed.png (camera_full_depths/ "
                                 "of SPD / AG-Pose; _depth.png holds the rendered objects only)")
        img = read_png(p)
        if (img.width, img.height) != self.size:
            raise RecordingError(f"{p}: {what} is {img.width}x{img.height}, the layout's frames {self.size}")
        return img.array, img

    def color(self, i: int) -> np.ndarray:
        arr, img = self._image(self.frames[i].color, "colour image")
        if img.color not in ("rgb", "rgba") or img.bit_depth != 8:
            raise RecordingError(f"{self.root / self.frames[i].color}: expected 8-bit RGB, found {img.color} {img.bit_depth}-bit")
        return np.ascontiguousarray(arr[..., :3])

    def depth_raw(self, i: int) -> np.ndarray:
        name = self.frames[i].depth
        arr, img = self._image(name, "depth image")
        if img.color == "gray" and img.bit_depth == 16:
            return arr
        if img.color == "rgb" and img.bit_depth == 8:  # CAMERA25 composed depth
            depth = arr[..., 1].astype(np.uint16) * 256 + arr[..., 0]
            return np.where(depth == COMPOSED_NO_DEPTH, 0, depth).astype(np.uint16)
        raise RecordingError(f"{self.root / name}: expected 16-bit depth (or 8-bit RGB composed), found "
                             f"{img.color} {img.bit_depth}-bit")

    def depth_m(self, i: int) -> np.ndarray:
        return (self.depth_raw(i).astype(np.float64) * self.depth_scale_m).astype(np.float32)

    def _handles(self, i: int, instance_ids) -> dict[int, bool]:
        """instance id -> handle visible, from the gts pickle of a real test frame (its
        entries in the label pickle's ``instance_ids`` order)."""
        if self._split is None:
            return {}
        root, split = self._split
        gt_split = SPLIT_DIRS[split][1] if split.startswith("camera") else split
        p = root / "gts" / gt_split / f"results_{gt_split}_{self.root.name}_{self.frames[i].id}.pkl"
        if not p.exists():
            return {}
        with open(p, "rb") as f:
            g = pickle.load(f)
        return {int(iid): bool(v) for iid, v in zip(instance_ids, g.get("gt_handle_visibility", []))}

    def _label(self, i: int) -> dict | None:
        name = self.frames[i].annotations
        if name is None:
            return None
        with open(self.root / name, "rb") as f:
            return pickle.load(f)

    def annotations(self, i: int) -> Annotations | None:
        lab = self._label(i)
        if lab is None:
            return None
        path = self.root / self.frames[i].annotations
        if self._models is None:
            raise RecordingError(f"{path}: sizes need the object models (obj_models/<split>.pkl under the dataset root)")
        handles = self._handles(i, lab["instance_ids"])
        instances = []
        for k, iid in enumerate(lab["instance_ids"]):
            cid = int(lab["class_ids"][k])
            if not 1 <= cid <= len(CLASSES):
                raise RecordingError(f"{path}: class_ids[{k}] = {cid}, expected 1..{len(CLASSES)}")
            model = lab["model_list"][k]
            if model not in self._models:
                raise RecordingError(f"{path}: model {model!r} is not in the object models")
            extents = 2.0 * np.abs(np.asarray(self._models[model], dtype=np.float64)).max(axis=0)
            scale = float(lab["scales"][k])
            instances.append(Instance(
                id=int(iid), cls=CLASSES[cid - 1], class_id=cid - 1,
                R=np.asarray(lab["rotations"][k], dtype=np.float64),
                t=np.asarray(lab["translations"][k], dtype=np.float64),
                s=scale * extents, handle_visible=handles.get(int(iid), True)))
        fid = self.frames[i].id
        return Annotations(instances, f"{fid}_mask.png", f"{fid}_coord.png")

    def mask(self, i: int, ann: Annotations | None = None) -> np.ndarray | None:
        ann = ann if ann is not None else self.annotations(i)
        if ann is None or ann.mask is None:
            return None
        arr, img = self._image(ann.mask, "instance mask")
        if img.bit_depth != 8 or img.color not in ("gray", "rgb"):
            raise RecordingError(f"{self.root / ann.mask}: expected an 8-bit mask, found {img.color} {img.bit_depth}-bit")
        ids = arr if arr.ndim == 2 else arr[..., 0]
        return np.where(ids == MASK_BACKGROUND, 0, ids).astype(np.uint8)

    def nocs_raw(self, i: int, ann: Annotations | None = None) -> np.ndarray | None:
        """The NOCS map as tricons stores it: (H, W, 3) uint16, 65535 = 1.0, z unflipped."""
        ann = ann if ann is not None else self.annotations(i)
        if ann is None or ann.nocs is None:
            return None
        arr, img = self._image(ann.nocs, "NOCS map")
        if img.color != "rgb" or img.bit_depth != 8:
            raise RecordingError(f"{self.root / ann.nocs}: expected 8-bit RGB, found {img.color} {img.bit_depth}-bit")
        out = arr.astype(np.uint16) * 257
        out[..., 2] = 65535 - out[..., 2]
        return out

    def nocs(self, i: int, ann: Annotations | None = None) -> np.ndarray | None:
        raw = self.nocs_raw(i, ann)
        return None if raw is None else (raw.astype(np.float32) / np.float32(65535.0))


def open_any(path) -> list:
    """Recordings for a ``--data`` argument: a tricons recording (or an opened one), a NOCS
    scene, or a NOCS split directory of scenes (one recording per scene)."""
    if isinstance(path, (Recording, NocsLayoutRecording)):
        return [path]
    if is_nocs_layout(path):
        return [NocsLayoutRecording(s) for s in scene_dirs(path)]
    return [Recording(path)]
