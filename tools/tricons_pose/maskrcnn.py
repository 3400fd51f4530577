"""The instance segmenter the runtime ships: a light torchvision Mask R-CNN.

``tricons`` segments objects with any torchvision Mask R-CNN exported by
``torch.onnx.export``. This module builds, trains, exports and evaluates the
one it ships (MobileNetV3-Large-FPN backbone, the six NOCS classes) and the
random-weight ResNet-50-FPN export the runtime is checked against.

Commands (run from tools/ with ``python -m tricons_pose.maskrcnn ...``):

* ``train``  -- train the light model on a SynthNOCS recording (CPU), with
  checkpoints and a progress log; resumable; ``--init`` starts from another
  checkpoint's weights, ``--freeze-bn`` keeps BatchNorm statistics fixed,
  ``--other-class`` adds a seventh class, "other", trained on SynthNOCS distractors
  (data from ``tricons synth --distractor-masks``; the card names it, the runtime lets it
  suppress the NOCS detections it covers and reports none of its own).
* ``import-onnx`` -- rebuild a checkpoint from a light ONNX export (BatchNorm
  folded into the convs by the export becomes identity BatchNorm), to fine-tune.
* ``export`` -- export a checkpoint the way a user would
  (``torch.onnx.export``, TorchScript exporter, opset 17) plus a model card.
* ``export-r50`` -- an unmodified ``maskrcnn_resnet50_fpn`` with random weights.
* ``evaluate`` -- bbox and mask AP50 / AP75 of an ONNX file on a recording
  (onnxruntime), COCO-style 101-point interpolation, mean over classes.
* ``fixture`` -- onnxruntime's outputs on one frame, as the JSON the Rust
  tests compare against.

Why MobileNetV3-Large-FPN: torchvision has no light Mask R-CNN, and this is
the backbone of its fastest detector (``fasterrcnn_mobilenet_v3_large_fpn``):
~5x fewer backbone FLOPs than ResNet-50-FPN, depthwise convolutions that run
well on ARM cores. No pretrained weights are reachable here, so it trains from
scratch with ordinary BatchNorm (torchvision's default FrozenBatchNorm only
makes sense with ImageNet statistics).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .recording import CLASSES, Recording

#: label 0 is background; label i (1..6) is CLASSES[i - 1].
NUM_LABELS = len(CLASSES) + 1
#: A model trained with ``--other-class`` has one more label: "other", the SynthNOCS
#: distractors (``{id}_distractors.png``), so that what is no NOCS object has a class of its
#: own to win instead of a NOCS one. The card names it "other" (no NOCS category): the runtime
#: lets such detections suppress the NOCS ones they cover, then drops them.
OTHER_LABEL = NUM_LABELS
OTHER_NAME = "other"
#: The shipped model works on images whose short side is resized to this.
LIGHT_MIN_SIZE = 320
LIGHT_MAX_SIZE = 432
#: Instances smaller than this (pixels) are not training targets.
MIN_TARGET_PIXELS = 16
OPSET = 17
#: Mask pixels whose onnxruntime probability lies within this of the 0.5 threshold are
#: "ambiguous" in fixtures: float noise may flip them (random weights put many there).
MASK_BAND = 1e-4
OUTPUT_NAMES = ["boxes", "labels", "scores", "masks"]


#: FPN and head width of the shipped model (torchvision's default is 256).
LIGHT_CHANNELS = 128
#: Hidden width of the box head's two FC layers (torchvision: 1024).
LIGHT_BOX_HIDDEN = 256


def build_light(
    min_size: int = LIGHT_MIN_SIZE, max_size: int = LIGHT_MAX_SIZE, score_thresh: float = 0.05, other_class: bool = False
):
    """Mask R-CNN with a MobileNetV3-Large-FPN backbone and the six NOCS classes (and
    :data:`OTHER_LABEL` with ``other_class``).

    torchvision's own classes throughout (``MaskRCNN``, ``BackboneWithFPN``,
    ``TwoMLPHead``, ``MaskRCNNHeads``); only the widths are smaller than
    torchvision's ResNet-50 defaults: 128-channel FPN and mask head, a 256-wide
    box head, MobileNetV3-Large with the reduced tail. ~4.5 M parameters
    (ResNet-50-FPN Mask R-CNN: 44 M).
    """
    from torchvision.models import mobilenet_v3_large
    from torchvision.models.detection import MaskRCNN
    from torchvision.models.detection.anchor_utils import AnchorGenerator
    from torchvision.models.detection.backbone_utils import BackboneWithFPN
    from torchvision.models.detection.faster_rcnn import FastRCNNPredictor, TwoMLPHead
    from torchvision.models.detection.mask_rcnn import MaskRCNNHeads, MaskRCNNPredictor
    from torchvision.ops.feature_pyramid_network import LastLevelMaxPool

    features = mobilenet_v3_large(weights=None, norm_layer=nn.BatchNorm2d, reduced_tail=True).features
    # The last block at strides 8, 16 and 32 (torchvision's mobilenet_backbone(fpn=True) returns two
    # stride-32 maps; objects here are 20-200 px at the working size, so finer levels matter).
    strides, last_at = 2, {}
    for i, block in enumerate(features):
        if getattr(block, "_is_cn", False):
            strides *= 2
        last_at[strides] = i
    taps = [last_at[8], last_at[16], last_at[32]]
    backbone = BackboneWithFPN(
        features,
        {str(t): str(k) for k, t in enumerate(taps)},
        [features[t].out_channels for t in taps],
        LIGHT_CHANNELS,
        extra_blocks=LastLevelMaxPool(),
    )
    # Four maps (strides 8, 16, 32, 64), two sizes and three aspect ratios per level.
    anchors = AnchorGenerator(((16, 32), (48, 64), (96, 128), (192, 256)), ((0.5, 1.0, 2.0),) * 4)
    c = LIGHT_CHANNELS
    labels = NUM_LABELS + 1 if other_class else NUM_LABELS
    return MaskRCNN(
        backbone,
        num_classes=None,
        rpn_anchor_generator=anchors,
        box_head=TwoMLPHead(c * 7 * 7, LIGHT_BOX_HIDDEN),
        box_predictor=FastRCNNPredictor(LIGHT_BOX_HIDDEN, labels),
        mask_head=MaskRCNNHeads(c, [c] * 4, 1),
        mask_predictor=MaskRCNNPredictor(c, c, labels),
        min_size=min_size,
        max_size=max_size,
        rpn_pre_nms_top_n_test=500,
        rpn_post_nms_top_n_test=300,
        box_score_thresh=score_thresh,
        box_detections_per_img=50,
        box_batch_size_per_image=128,
    )


def build_r50(seed: int = 0):
    """Unmodified torchvision ``maskrcnn_resnet50_fpn`` with random weights.

    ``box_score_thresh=0`` (a constructor argument) so random weights still
    yield detections (scores spread over ~0.43-0.69 with seed 0).
    """
    from torchvision.models.detection import maskrcnn_resnet50_fpn

    torch.manual_seed(seed)
    model = maskrcnn_resnet50_fpn(weights=None, weights_backbone=None, box_score_thresh=0.0)
    return model.eval()


# --------------------------------------------------------------------------- data


class SegData:
    """The annotated frames of one or more recordings as training targets, read from disk
    when asked for (a frame's PNGs decode in milliseconds, next to seconds per training step;
    ten thousand frames held decoded would take 9 GB)."""

    def __init__(self, roots: str | list[str], limit: int | None = None, other: bool = False):
        """``limit`` caps the frames taken from each recording. With ``other``, each frame's
        distractors (``{id}_distractors.png``, written by ``tricons synth --distractor-masks``)
        become targets of :data:`OTHER_LABEL`."""
        roots = [roots] if isinstance(roots, str) else list(roots)
        self.other = other
        self.frames = []  # (recording, annotations)
        for root in roots:
            rec = Recording(root)
            n = len(rec) if limit is None else min(limit, len(rec))
            for i in range(n):
                ann = rec.annotations(i)
                if ann is not None and ann.mask is not None:
                    self.frames.append((rec, i, ann))

    def __len__(self):
        return len(self.frames)

    def image(self, i: int) -> np.ndarray:
        """Frame ``i``'s colour image, HxWx3 uint8."""
        from PIL import Image

        rec, k, _ = self.frames[i]
        return np.asarray(Image.open(rec.root / rec.frames[k].color).convert("RGB"))

    def target(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Frame ``i``'s instances of at least MIN_TARGET_PIXELS pixels: boxes (N, 4) xyxy
        float32, labels (N,) int64 (class id + 1), masks (N, H, W) bool."""
        from PIL import Image

        rec, _, ann = self.frames[i]
        ids = np.asarray(Image.open(rec.root / ann.mask))
        masks, labels, boxes = [], [], []
        for inst in ann.instances:
            m = ids == inst.id
            if m.sum() < MIN_TARGET_PIXELS:
                continue
            ys, xs = np.nonzero(m)
            boxes.append([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1])
            masks.append(m)
            labels.append(inst.class_id + 1)
        if self.other:
            for m in distractor_masks(self.distractors_path(i)):
                if m.sum() < MIN_TARGET_PIXELS:
                    continue
                ys, xs = np.nonzero(m)
                boxes.append([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1])
                masks.append(m)
                labels.append(OTHER_LABEL)
        return (
            np.asarray(boxes, np.float32).reshape(-1, 4),
            np.asarray(labels, np.int64),
            np.asarray(masks, bool).reshape(-1, *ids.shape[:2]),
        )

    def distractors_path(self, i: int) -> Path:
        """Where frame ``i``'s distractor mask is (beside its colour image)."""
        rec, k, _ = self.frames[i]
        color = rec.frames[k].color
        return rec.root / (color.removesuffix("_color.png") + "_distractors.png")

    def item(self, i: int, flip: bool):
        img = torch.from_numpy(self.image(i).copy()).permute(2, 0, 1).float() / 255.0
        boxes, labels, masks = self.target(i)
        w = img.shape[2]
        masks = masks.astype(np.uint8)
        if flip:
            img = img.flip(-1)
            masks = masks[..., ::-1].copy()
            boxes[:, [0, 2]] = w - boxes[:, [2, 0]]
        return img, {"boxes": torch.from_numpy(boxes), "labels": torch.from_numpy(labels), "masks": torch.from_numpy(masks)}


def distractor_masks(path: Path) -> list[np.ndarray]:
    """The distractors of a ``{id}_distractors.png`` (u8: 0 none, k the k-th distractor), one
    boolean mask each, in id order; a missing file is an error that says how to make it."""
    from PIL import Image

    if not path.exists():
        raise FileNotFoundError(
            f"{path}: no distractor mask; --other-class needs training data written by "
            "`tricons synth --distractor-masks`"
        )
    ids = np.asarray(Image.open(path))
    return [ids == k for k in np.unique(ids) if k != 0]


def has_other_class(state: dict) -> bool:
    """Whether a ``build_light`` state_dict has the :data:`OTHER_LABEL` class."""
    return state["roi_heads.box_predictor.cls_score.weight"].shape[0] == NUM_LABELS + 1


def add_other_class(state: dict) -> dict:
    """A six-class ``build_light`` state_dict with :data:`OTHER_LABEL` added: its classifier
    row starts as the background's (what a distractor was until now), its box regression at
    zero and its mask logits as the mean of the six classes'."""
    out = dict(state)
    cls_w, cls_b = "roi_heads.box_predictor.cls_score.weight", "roi_heads.box_predictor.cls_score.bias"
    box_w, box_b = "roi_heads.box_predictor.bbox_pred.weight", "roi_heads.box_predictor.bbox_pred.bias"
    mask_w, mask_b = "roi_heads.mask_predictor.mask_fcn_logits.weight", "roi_heads.mask_predictor.mask_fcn_logits.bias"
    out[cls_w] = torch.cat([state[cls_w], state[cls_w][:1]])
    out[cls_b] = torch.cat([state[cls_b], state[cls_b][:1]])
    out[box_w] = torch.cat([state[box_w], torch.zeros_like(state[box_w][:4])])
    out[box_b] = torch.cat([state[box_b], torch.zeros_like(state[box_b][:4])])
    out[mask_w] = torch.cat([state[mask_w], state[mask_w][1:].mean(0, keepdim=True)])
    out[mask_b] = torch.cat([state[mask_b], state[mask_b][1:].mean(0, keepdim=True)])
    return out


# --------------------------------------------------------------------------- training


def train(args):
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    log = open(out / "train.log", "a", buffering=1)
    t0 = time.time()
    data = SegData(args.data, args.limit, other=args.other_class)
    print(f"{len(data)} frames indexed in {time.time() - t0:.0f} s", file=log)
    model = build_light(args.min_size, args.max_size, other_class=args.other_class)
    params = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(params, lr=args.lr, weight_decay=1e-4)
    step = 0
    ckpt = out / "last.pt"
    if ckpt.exists():
        state = torch.load(ckpt, map_location="cpu")
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["opt"])
        step = state["step"]
        print(f"resumed at step {step}", file=log)
    elif args.init:
        # Weights only: the optimiser and the learning-rate schedule start afresh.
        state = torch.load(args.init, map_location="cpu")
        weights = state["model"]
        if args.other_class and not has_other_class(weights):
            weights = add_other_class(weights)
            print("added the class 'other' to the initial weights", file=log)
        model.load_state_dict(weights)
        print(f"initialised from {args.init}", file=log)

    def lr_at(s):
        if s < args.warmup:
            return args.lr * (s + 1) / args.warmup
        frac = (s - args.warmup) / max(1, args.steps - args.warmup)
        return args.lr * (0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * min(frac, 1.0))))

    model.train()
    if args.freeze_bn:
        # BatchNorm normalises with its running statistics and does not update them (their
        # affine weight and bias still train: after import-onnx the bias is the conv's only one).
        for m in model.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.eval()
    elif args.init and not ckpt.exists():
        print("warning: --init without --freeze-bn: batch statistics replace the running ones", file=log)
    smooth = None
    while step < args.steps:
        idx = rng.integers(0, len(data), args.batch)
        flips = rng.random(args.batch) < 0.5
        imgs, tgts = zip(*(data.item(int(i), bool(f)) for i, f in zip(idx, flips)))
        for g in opt.param_groups:
            g["lr"] = lr_at(step)
        losses = model(list(imgs), list(tgts))
        loss = sum(losses.values())
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(params, 10.0)
        opt.step()
        step += 1
        vals = {k: float(v.detach()) for k, v in losses.items()}
        smooth = vals if smooth is None else {k: 0.95 * smooth[k] + 0.05 * vals[k] for k in vals}
        if step % 20 == 0 or step == 1 or step == args.steps:
            parts = " ".join(f"{k.replace('loss_', '')}={v:.3f}" for k, v in smooth.items())
            print(f"step {step}/{args.steps} lr={lr_at(step):.2e} {parts} {time.time() - t0:.0f}s", file=log)
        if step % args.ckpt_every == 0 or step == args.steps:
            tmp = out / "last.pt.tmp"
            torch.save({"model": model.state_dict(), "opt": opt.state_dict(), "step": step, "args": vars(args)}, tmp)
            os.replace(tmp, ckpt)
    print("done", file=log)


# --------------------------------------------------------------------------- export


def export_onnx(model, path: Path, height: int = 480, width: int = 640, opset: int = OPSET, output_names=OUTPUT_NAMES):
    """``torch.onnx.export`` as torchvision's docs show it (TorchScript exporter).
    ``output_names=None`` leaves torch's numeric names (what a user gets without them)."""
    model.eval()
    x = torch.rand(3, height, width)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".onnx.tmp")
    torch.onnx.export(
        model,
        ([x],),
        str(tmp),
        opset_version=opset,
        input_names=["image"],
        output_names=output_names,
        dynamic_axes={"image": [1, 2]}
        | ({"boxes": [0], "labels": [0], "scores": [0], "masks": [0, 2, 3]} if output_names else {}),
        dynamo=False,
    )
    os.replace(tmp, path)


# card fields chosen for a shipped model by evaluation (docs/results.md), which a re-export
# over an existing card keeps: thresholds, duplicate suppression, the pose stage's masks
KEPT_CARD_FIELDS = ("score_threshold", "mask_threshold", "duplicate_mask_iou", "duplicate_mask_inside",
                    "pose_mask_erode_px", "pose_mask_max_radius_m")


def write_card(path: Path, onnx_name: str, extra: dict, other_class: bool = False):
    """Write the segmenter card of ``onnx_name`` (beside ``path``); when a card is already at
    ``path``, its :data:`KEPT_CARD_FIELDS` stay as they are. ``other_class``: the model's
    :data:`OTHER_LABEL` is named :data:`OTHER_NAME`."""
    import hashlib

    kept = {}
    if path.exists():
        old = json.loads(path.read_text())
        kept = {k: old[k] for k in KEPT_CARD_FIELDS if k in old}
    card = {
        "format": "tricons-segmenter-card",
        "version": 1,
        "model": onnx_name,
        "sha256": hashlib.sha256((path.parent / onnx_name).read_bytes()).hexdigest(),
        "architecture": extra.pop("architecture"),
        "input": {"name": "image", "layout": "CHW", "color": "rgb", "scale": 1.0 / 255.0},
        "outputs": {"boxes": "boxes", "labels": "labels", "scores": "scores", "masks": "masks"},
        "labels": {str(i + 1): c for i, c in enumerate(CLASSES)} | ({str(OTHER_LABEL): OTHER_NAME} if other_class else {}),
        "score_threshold": 0.5,
        "mask_threshold": 0.5,
        **extra,
        **kept,
    }
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(card, indent=2) + "\n")
    os.replace(tmp, path)


def export_cmd(args):
    state = torch.load(args.checkpoint, map_location="cpu")
    other = has_other_class(state["model"])
    model = build_light(args.min_size, args.max_size, other_class=other)
    model.load_state_dict(state["model"])
    out = Path(args.out)
    export_onnx(model, out)
    card = out.with_name(out.name.removesuffix(".onnx") + ".card.json")
    write_card(
        card,
        out.name,
        {
            "architecture": f"torchvision MaskRCNN, MobileNetV3-Large-FPN, min_size {args.min_size}",
            "training": {"data": args.train_data, "steps": state["step"], "args": state.get("args", {})},
        },
        other_class=other,
    )
    print(f"wrote {out} and {card}")


def export_r50_cmd(args):
    model = build_r50(args.seed)
    out = Path(args.out)
    export_onnx(model, out, opset=args.opset)
    print(f"wrote {out}")


# --------------------------------------------------------------------------- import from ONNX


def _scope_path(node_name: str) -> str | None:
    """The module path a TorchScript-exported node name encodes, or None if it encodes none:
    ``/backbone/body/body.1/block/block.0/block.0.0/Conv`` -> ``backbone.body.1.block.0.0``.
    A container's child scope is the container's scope plus ``.child``; a module called again
    gets ``_2``, ``_3``... (``/rpn/head/cls_logits_2/Conv``)."""
    parts = node_name.split("/")
    if len(parts) < 3 or parts[0] != "":
        return None
    path, prev = [], None
    for part in parts[1:-1]:
        part = re.sub(r"_\d+$", "", part)
        path.append(part[len(prev) + 1 :] if prev and part.startswith(prev + ".") else part)
        prev = part
    return ".".join(path)


def _conv_calls(model: nn.Module) -> tuple[list[str], dict[str, str]]:
    """The names of ``model``'s Conv2d modules in the order an eval-mode forward calls them
    (a shared module, like the RPN head's, once per call), and for each conv whose output
    goes straight into a BatchNorm2d, that BatchNorm2d's name."""
    names = {m: n for n, m in model.named_modules()}
    calls: list[str] = []
    outputs: dict[int, tuple[torch.Tensor, str]] = {}  # keeps the tensors alive: ids stay unique
    bn_of: dict[str, str] = {}

    def on_conv(mod, inputs, out):
        calls.append(names[mod])
        outputs[id(out)] = (out, names[mod])

    def on_bn(mod, inputs):
        hit = outputs.get(id(inputs[0]))
        if hit is not None and hit[0] is inputs[0]:
            bn_of[hit[1]] = names[mod]

    hooks = [m.register_forward_hook(on_conv) for m in names if isinstance(m, nn.Conv2d)]
    hooks += [m.register_forward_pre_hook(on_bn) for m in names if isinstance(m, nn.BatchNorm2d)]
    was_training = model.training
    try:
        model.eval()
        with torch.no_grad():
            model([torch.zeros(3, 64, 64)])  # the mask head runs even on zero detections
    finally:
        for h in hooks:
            h.remove()
        model.train(was_training)
    return calls, bn_of


def state_from_onnx(path: str, model: nn.Module | None = None) -> dict[str, torch.Tensor]:
    """Rebuild a ``build_light()`` state_dict from an eval-mode ``export_onnx`` file.

    The TorchScript exporter keeps the state_dict names of what it does not touch (FPN,
    heads, Linear layers, convs without BatchNorm) and folds each eval-mode BatchNorm into
    the conv before it, under unnamed initializers (``onnx::Conv_2847``). Named
    initializers are loaded by name; the Conv nodes are matched one to one, in graph order,
    to the Conv2d calls of an eval-mode forward (a shared module once per call, always with
    the same initializers), each match checked on weight shape, groups, strides, pads and
    dilations, on the initializer name where it has one and on the module path the node
    name encodes. A folded conv gets the folded weight, and its BatchNorm becomes the
    identity plus the folded bias (weight 1, running mean 0, running variance 1 - eps),
    so the model in eval mode computes what the ONNX graph does. The original BatchNorm
    statistics are gone: train the result with BatchNorm in eval mode (``--freeze-bn``).
    """
    import onnx
    from onnx import numpy_helper

    model = build_light() if model is None else model
    graph = onnx.load(path).graph
    if any(n.op_type == "BatchNormalization" for n in graph.node):
        raise ValueError(f"{path} has BatchNormalization nodes: only eval-mode, constant-folded exports are supported")
    inits = {t.name: torch.from_numpy(numpy_helper.to_array(t).copy()) for t in graph.initializer}
    sd = model.state_dict()
    state: dict[str, torch.Tensor] = {}
    for name, value in inits.items():
        if name in sd:
            if value.shape != sd[name].shape:
                raise ValueError(f"{name}: {tuple(value.shape)} in {path}, {tuple(sd[name].shape)} in the model")
            state[name] = value.to(sd[name].dtype)

    calls, bn_of = _conv_calls(model)
    nodes = [n for n in graph.node if n.op_type == "Conv"]
    if len(nodes) != len(calls):
        raise ValueError(f"{len(nodes)} Conv nodes in {path}, {len(calls)} Conv2d calls in the model")
    modules = dict(model.named_modules())
    n_convs = sum(isinstance(m, nn.Conv2d) for m in modules.values())
    used: dict[str, tuple[str, ...]] = {}
    for node, name in zip(nodes, calls):
        conv = modules[name]
        where = f"Conv node {node.name!r} -> {name}"
        scope = _scope_path(node.name)
        if scope in modules and isinstance(modules[scope], nn.Conv2d) and scope != name:
            raise ValueError(f"{where}: the node name says {scope}")
        inputs = tuple(i for i in node.input[1:] if i)
        if name in used:
            if used[name] != inputs:
                raise ValueError(f"{where}: {name} is called again with other initializers {inputs} != {used[name]}")
            continue
        used[name] = inputs
        attrs = {a.name: onnx.helper.get_attribute_value(a) for a in node.attribute}
        w = inits[inputs[0]]
        b = inits[inputs[1]] if len(inputs) > 1 else None
        ph, pw = conv.padding
        got = (tuple(w.shape), attrs.get("group", 1), list(attrs.get("strides", [1, 1])),
               list(attrs.get("pads", [0, 0, 0, 0])), list(attrs.get("dilations", [1, 1])))
        want = (tuple(conv.weight.shape), conv.groups, list(conv.stride), [ph, pw, ph, pw], list(conv.dilation))
        if got != want:
            raise ValueError(f"{where}: (shape, group, strides, pads, dilations) {got} in the graph, {want} in the model")
        if inputs[0] in sd and inputs[0] != f"{name}.weight":
            raise ValueError(f"{where}: its weight is named {inputs[0]}")
        bias = b if b is not None else torch.zeros(w.shape[0])
        state[f"{name}.weight"] = w
        bn = bn_of.get(name)
        if bn is None:
            if conv.bias is not None:
                state[f"{name}.bias"] = bias
            elif b is not None and bool(b.any()):
                raise ValueError(f"{where}: a bias in the graph, none in the model")
            continue
        if conv.bias is not None:
            state[f"{name}.bias"] = torch.zeros_like(bias)
        eps = modules[bn].eps
        state[f"{bn}.weight"] = torch.ones_like(bias)
        state[f"{bn}.bias"] = bias
        state[f"{bn}.running_mean"] = torch.zeros_like(bias)
        state[f"{bn}.running_var"] = torch.full_like(bias, 1.0 - eps)
        state[f"{bn}.num_batches_tracked"] = torch.zeros((), dtype=torch.long)
    if len(used) != n_convs:
        raise ValueError(f"{len(used)} of the model's {n_convs} Conv2d modules matched")
    missing = [k for k in sd if k not in state]
    if missing:
        raise ValueError(f"{len(missing)} state_dict entries not in {path}: {missing[:5]}...")
    return {k: state[k].to(sd[k].dtype) for k in sd}


def torch_record(model: nn.Module, image: str) -> dict:
    """An eval-mode PyTorch model's detections on one PNG, in the record format
    ``compare_detections`` takes (boxes, labels, scores, 0.5-thresholded masks)."""
    from PIL import Image

    img = np.asarray(Image.open(image).convert("RGB"))
    x = torch.from_numpy(img.copy()).permute(2, 0, 1).float() / 255.0
    model.eval()
    with torch.no_grad():
        det = model([x])[0]
    return {
        "instances": [
            {"box": [float(v) for v in box], "label": int(label), "score": float(score), "mask_rle": rle(m[0].numpy() >= 0.5)}
            for box, label, score, m in zip(det["boxes"], det["labels"], det["scores"], det["masks"])
        ]
    }


def onnx_has_other_class(path: str) -> bool:
    """Whether a light export has the :data:`OTHER_LABEL` class (from its classifier's shape)."""
    import onnx

    for t in onnx.load(path).graph.initializer:
        if t.name == "roi_heads.box_predictor.cls_score.weight":
            return t.dims[0] == NUM_LABELS + 1
    raise ValueError(f"{path}: no roi_heads.box_predictor.cls_score.weight: not a light Mask R-CNN export")


def import_onnx_cmd(args):
    import hashlib

    torch.set_num_threads(args.threads)
    model = build_light(args.min_size, args.max_size, other_class=onnx_has_other_class(args.onnx))
    state = state_from_onnx(args.onnx, model)
    model.load_state_dict(state)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    source = {"import_onnx": str(args.onnx), "sha256": hashlib.sha256(Path(args.onnx).read_bytes()).hexdigest()}
    tmp = out.with_suffix(".pt.tmp")
    torch.save({"model": state, "step": 0, "args": source}, tmp)
    os.replace(tmp, out)
    print(f"wrote {out}: {len(state)} state_dict entries from {args.onnx}")
    if args.check:
        cmp = compare_detections(ort_fixture(args.onnx, args.check), torch_record(model, args.check))
        print(json.dumps({"check": args.check} | cmp))


# --------------------------------------------------------------------------- evaluation


def run_ort(path: str, img: np.ndarray, threads: int = 1):
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    sess = ort.InferenceSession(path, so, providers=["CPUExecutionProvider"])
    x = (img.astype(np.float32) / 255.0).transpose(2, 0, 1).copy()
    return sess, x


def _ap(tp: np.ndarray, scores: np.ndarray, n_gt: int) -> float:
    """COCO-style AP: precision envelope sampled at 101 recall points."""
    if n_gt == 0:
        return float("nan")
    if len(scores) == 0:
        return 0.0
    order = np.argsort(-scores, kind="stable")
    tp = tp[order].astype(np.float64)
    ctp, cfp = np.cumsum(tp), np.cumsum(1 - tp)
    recall = ctp / n_gt
    precision = ctp / np.maximum(ctp + cfp, 1e-12)
    precision = np.maximum.accumulate(precision[::-1])[::-1]
    ap = 0.0
    for r in np.linspace(0, 1, 101):
        i = np.searchsorted(recall, r, side="left")
        ap += precision[i] if i < len(precision) else 0.0
    return ap / 101


def _iou_boxes(a, b):
    x0 = np.maximum(a[:, None, 0], b[None, :, 0])
    y0 = np.maximum(a[:, None, 1], b[None, :, 1])
    x1 = np.minimum(a[:, None, 2], b[None, :, 2])
    y1 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    aa = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    bb = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    return inter / np.maximum(aa[:, None] + bb[None, :] - inter, 1e-12)


def _iou_masks(a, b):
    a = a.reshape(len(a), -1).astype(np.float32)
    b = b.reshape(len(b), -1).astype(np.float32)
    inter = a @ b.T
    return inter / np.maximum(a.sum(1)[:, None] + b.sum(1)[None, :] - inter, 1e-12)


def average_precision(frames, thresholds=(0.5, 0.75)):
    """frames: list of (pred_boxes, pred_labels, pred_scores, pred_masks, gt_boxes, gt_labels, gt_masks).

    Greedy matching in score order per class (COCO), no crowd regions. Returns
    {"bbox": {0.5: ap, ...}, "mask": {...}} as means over the classes with
    ground truth.
    """
    out = {}
    for kind in ("bbox", "mask"):
        out[kind] = {}
        for thr in thresholds:
            aps = []
            for c in range(1, NUM_LABELS):
                tps, scs, n_gt = [], [], 0
                for pb, pl, ps, pm, gb, gl, gm in frames:
                    p = pl == c
                    g = gl == c
                    n_gt += int(g.sum())
                    if not p.any():
                        continue
                    order = np.argsort(-ps[p], kind="stable")
                    if g.any():
                        iou = _iou_boxes(pb[p], gb[g]) if kind == "bbox" else _iou_masks(pm[p], gm[g])
                        iou = iou[order]
                    matched = np.zeros(int(g.sum()), bool)
                    for k in range(len(order)):
                        hit = False
                        if g.any():
                            cand = np.where(~matched, iou[k], -1.0)
                            j = int(np.argmax(cand))
                            if cand[j] >= thr:
                                matched[j] = True
                                hit = True
                        tps.append(hit)
                    scs.extend(ps[p][order].tolist())
                ap = _ap(np.asarray(tps, bool), np.asarray(scs, np.float64), n_gt)
                if not math.isnan(ap):
                    aps.append(ap)
            out[kind][thr] = float(np.mean(aps)) if aps else float("nan")
    return out


def evaluate_cmd(args):
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = args.threads
    sess = ort.InferenceSession(args.model, so, providers=["CPUExecutionProvider"])
    data = SegData(args.data, args.limit)
    frames = []
    t0 = time.time()
    for i in range(len(data)):
        img = data.image(i)
        x = (img.astype(np.float32) / 255.0).transpose(2, 0, 1).copy()
        b, lab, s, m = sess.run(None, {"image": x})
        gb, gl, gm = data.target(i)
        frames.append((b, lab, s, m[:, 0] >= 0.5, gb, gl, gm))
    ap = average_precision(frames)
    res = {
        "model": args.model,
        "data": args.data,
        "frames": len(frames),
        "seconds": round(time.time() - t0, 1),
        **{f"{k}_AP{int(t * 100)}": round(100 * v, 1) for k, d in ap.items() for t, v in d.items()},
    }
    print(json.dumps(res, indent=2))
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    if args.card:
        card_path = Path(args.card)
        card = json.loads(card_path.read_text())
        card.setdefault("metrics", {})[Path(args.data).name] = {k: v for k, v in res.items() if "_AP" in k} | {
            "frames": res["frames"],
            "evaluator": "python -m tricons_pose.maskrcnn evaluate (onnxruntime, COCO 101-point AP, mean over classes)",
        }
        tmp = card_path.with_suffix(".tmp")
        tmp.write_text(json.dumps(card, indent=2) + "\n")
        os.replace(tmp, card_path)


def rle(mask: np.ndarray) -> list[int]:
    """Run lengths of a flattened (row-major) binary mask, starting with a 0-run."""
    flat = mask.reshape(-1).astype(np.uint8)
    change = np.flatnonzero(np.diff(np.concatenate([[0], flat, [1 - flat[-1]]])))
    return np.diff(np.concatenate([[0], change])).tolist()


def ort_fixture(model: str, image: str, min_score: float = 0.0) -> dict:
    """onnxruntime's detections on one PNG: boxes, labels, scores, 0.5-thresholded masks
    and the ambiguous pixels (|p - 0.5| < MASK_BAND), masks as run lengths."""
    import onnxruntime as ort
    from PIL import Image

    img = np.asarray(Image.open(image).convert("RGB"))
    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    sess = ort.InferenceSession(model, so, providers=["CPUExecutionProvider"])
    x = (img.astype(np.float32) / 255.0).transpose(2, 0, 1).copy()
    b, lab, s, m = sess.run(None, {"image": x})
    keep = [k for k in range(len(s)) if s[k] >= min_score]
    return {
        "model": Path(model).name,
        "image": Path(image).name,
        "producer": f"onnxruntime {ort.__version__}",
        "height": int(img.shape[0]),
        "width": int(img.shape[1]),
        "instances": [
            {
                "box": [float(v) for v in b[k]],
                "label": int(lab[k]),
                "score": float(s[k]),
                "mask_rle": rle(m[k, 0] >= 0.5),
                "ambiguous_rle": rle(np.abs(m[k, 0] - 0.5) < MASK_BAND),
            }
            for k in keep
        ],
    }


def decode_rle(runs, n: int) -> np.ndarray:
    out = np.zeros(n, bool)
    pos = 0
    for k, r in enumerate(runs):
        if k % 2:
            out[pos : pos + r] = True
        pos += r
    return out


def compare_detections(fixture: dict, record: dict) -> dict:
    """Match tract's detections (a `tricons segment` record) to onnxruntime's one to one
    (same label, nearest box), and report the worst box / score difference, the worst
    mask IoU over non-ambiguous pixels and how many could not be matched."""
    n = fixture["height"] * fixture["width"]
    ours = list(record["instances"])
    worst = {"matched": 0, "unmatched": 0, "box_px": 0.0, "score": 0.0, "mask_iou": 1.0}
    for inst in fixture["instances"]:
        cands = [
            (max(abs(p - q) for p, q in zip(inst["box"], o["box"])), j)
            for j, o in enumerate(ours)
            if o["label"] == inst["label"]
        ]
        if not cands:
            worst["unmatched"] += 1
            continue
        d, j = min(cands)
        o = ours.pop(j)
        a = decode_rle(inst["mask_rle"], n)
        b = decode_rle(o["mask_rle"], n)
        sure = ~decode_rle(inst["ambiguous_rle"], n)
        union = (a | b)[sure].sum()
        iou = (a & b)[sure].sum() / union if union else 1.0
        worst["matched"] += 1
        worst["box_px"] = max(worst["box_px"], d)
        worst["score"] = max(worst["score"], abs(inst["score"] - o["score"]))
        worst["mask_iou"] = min(worst["mask_iou"], float(iou))
    worst["unmatched"] += len(ours)
    return worst


def bench_cmd(args):
    """onnxruntime frame latency on one image, medians over --runs (1 thread by default)."""
    import onnxruntime as ort
    from PIL import Image

    img = np.asarray(Image.open(args.image).convert("RGB"))
    x = (img.astype(np.float32) / 255.0).transpose(2, 0, 1).copy()
    so = ort.SessionOptions()
    so.intra_op_num_threads = args.threads
    t0 = time.perf_counter()
    sess = ort.InferenceSession(args.model, so, providers=["CPUExecutionProvider"])
    load_s = time.perf_counter() - t0
    for _ in range(args.warmup):
        sess.run(None, {"image": x})
    times = []
    for _ in range(args.runs):
        t = time.perf_counter()
        n = len(sess.run(None, {"image": x})[2])
        times.append(1e3 * (time.perf_counter() - t))
    times.sort()
    res = {"runtime": f"onnxruntime {ort.__version__}", "model": args.model, "threads": args.threads,
           "size": list(img.shape[:2]), "detections": n, "load_s": round(load_s, 2),
           "median_ms": round(float(np.median(times)), 1), "p10_ms": round(times[len(times) // 10], 1),
           "p90_ms": round(times[(len(times) - 1) * 9 // 10], 1), "runs": args.runs}
    print(json.dumps(res))


def fixture_cmd(args):
    fx = ort_fixture(args.model, args.image, args.min_score)
    Path(args.out).write_text(json.dumps(fx) + "\n")
    print(f"{args.out}: {len(fx['instances'])} instances")


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m tricons_pose.maskrcnn", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("train", help="train the light Mask R-CNN (resumes from OUT/last.pt)")
    t.add_argument("--data", required=True, nargs="+", help="one or more recordings, drawn from uniformly by frame")
    t.add_argument("--out", required=True)
    t.add_argument("--steps", type=int, default=6000)
    t.add_argument("--batch", type=int, default=4)
    t.add_argument("--lr", type=float, default=1e-3)
    t.add_argument("--warmup", type=int, default=200)
    t.add_argument("--threads", type=int, default=2)
    t.add_argument("--limit", type=int)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--ckpt-every", type=int, default=100)
    t.add_argument("--min-size", type=int, default=LIGHT_MIN_SIZE)
    t.add_argument("--max-size", type=int, default=LIGHT_MAX_SIZE)
    t.add_argument("--init", help="start from this checkpoint's weights (e.g. import-onnx's) unless OUT/last.pt exists")
    t.add_argument("--freeze-bn", action="store_true",
                   help="keep BatchNorm in eval mode (running statistics fixed, affine parameters trained)")
    t.add_argument("--other-class", action="store_true",
                   help="train a seventh class, 'other', on the data's distractors (needs `tricons synth "
                   "--distractor-masks` data); a six-class --init gets it added")
    e = sub.add_parser("export", help="export a checkpoint to ONNX + model card")
    e.add_argument("--checkpoint", required=True)
    e.add_argument("--out", required=True)
    e.add_argument("--train-data", default="SynthNOCS-train")
    e.add_argument("--min-size", type=int, default=LIGHT_MIN_SIZE)
    e.add_argument("--max-size", type=int, default=LIGHT_MAX_SIZE)
    r = sub.add_parser("export-r50", help="random-weight maskrcnn_resnet50_fpn export")
    r.add_argument("--out", required=True)
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--opset", type=int, default=OPSET)
    v = sub.add_parser("evaluate", help="bbox / mask AP50, AP75 with onnxruntime")
    v.add_argument("--model", required=True)
    v.add_argument("--data", required=True)
    v.add_argument("--limit", type=int)
    v.add_argument("--threads", type=int, default=2)
    v.add_argument("--json")
    v.add_argument("--card", help="also record the APs in this segmenter card's metrics")
    f = sub.add_parser("fixture", help="onnxruntime outputs on one image as JSON")
    f.add_argument("--model", required=True)
    f.add_argument("--image", required=True)
    f.add_argument("--out", required=True)
    f.add_argument("--min-score", type=float, default=0.0)
    io = sub.add_parser("import-onnx", help="rebuild a PyTorch checkpoint (for --init) from a light ONNX export")
    io.add_argument("--onnx", required=True)
    io.add_argument("--out", required=True)
    io.add_argument("--check", metavar="PNG", help="also compare its detections on this image with onnxruntime's")
    io.add_argument("--threads", type=int, default=1)
    io.add_argument("--min-size", type=int, default=LIGHT_MIN_SIZE)
    io.add_argument("--max-size", type=int, default=LIGHT_MAX_SIZE)
    bn = sub.add_parser("bench", help="onnxruntime frame latency")
    bn.add_argument("--model", required=True)
    bn.add_argument("--image", required=True)
    bn.add_argument("--runs", type=int, default=10)
    bn.add_argument("--warmup", type=int, default=2)
    bn.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    {
        "bench": bench_cmd,
        "train": train,
        "export": export_cmd,
        "export-r50": export_r50_cmd,
        "import-onnx": import_onnx_cmd,
        "evaluate": evaluate_cmd,
        "fixture": fixture_cmd,
    }[args.cmd](args)


if __name__ == "__main__":
    sys.exit(main())
