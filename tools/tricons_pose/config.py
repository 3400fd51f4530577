"""Model configuration for TriCons-Pose: paper sizes, shipped (CPU) sizes, ablations.

Every architectural number the network reads lives in :class:`ModelConfig`, so a
configuration serialised with :meth:`ModelConfig.to_dict` (plain JSON types) is
enough to rebuild the network for a model card or a checkpoint.
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from typing import Any, Dict, Tuple

IMAGE_ENCODERS = ("cnn", "dinov2")
DESCRIPTORS = ("triangle", "relative", "ppf", "dist_angle")


def _tuplify(x: Any) -> Any:
    """Recursively turn lists (from JSON) back into tuples."""
    if isinstance(x, (list, tuple)):
        return tuple(_tuplify(v) for v in x)
    return x


@dataclass(frozen=True)
class ModelConfig:
    """All hyper-parameters of :class:`tricons_pose.model.TriConsPose` and its losses.

    Field names of the interface contract (tools/CONTRACT.md): ``n_points`` (N),
    ``n_keypoints`` (M), ``channels`` (C = ``point_channels`` + ``image_channels``),
    ``blocks`` (B, PIGA blocks), ``k_local`` (K), ``k_global`` (K_gl), ``crop_size``,
    ``tau``, ``image_encoder`` ("cnn" | "dinov2"), ``descriptor``
    ("triangle" | "relative" | "ppf" | "dist_angle"), ``use_sckd_loss`` (L_cvc and the
    second augmented view), ``use_piga`` (False: AG-Pose's relative-coordinate
    aggregation instead of PIGA), and the loss weights ``w_*``.

    The remaining fields size the sub-networks (PointNet++ levels, SCKD attention,
    heads, image encoders) and the loss constants. Use :meth:`paper` or
    :meth:`shipped` rather than the defaults directly; the defaults equal ``paper()``.
    """

    # --- contract fields -------------------------------------------------------
    n_points: int = 1024
    n_keypoints: int = 96
    channels: int = 256
    point_channels: int = 128
    image_channels: int = 128
    blocks: int = 6
    k_local: int = 16
    k_global: int = 3
    crop_size: int = 192
    tau: float = 0.1
    image_encoder: str = "dinov2"
    descriptor: str = "triangle"
    use_sckd_loss: bool = True
    use_piga: bool = True
    # loss weights (paper, Implementation Details; delta = AG-Pose's reconstruction
    # offset regulariser, kept because the paper keeps AG-Pose's losses)
    w_pose: float = 0.3
    w_nocs: float = 2.0
    w_cd: float = 2.0
    w_div: float = 10.0
    w_rec: float = 15.0
    w_cvc: float = 0.1
    w_delta: float = 1.0

    # --- PointNet++ MSG (AG-Pose PointNet2MSG) ---------------------------------
    pn2_npoints: Tuple[int, ...] = (512, 256, 128, 64)
    pn2_radii: Tuple[Tuple[float, ...], ...] = (
        (0.01, 0.02), (0.02, 0.04), (0.04, 0.08), (0.08, 0.16))
    pn2_nsamples: Tuple[int, ...] = (16, 32)
    # per level: shared-MLP widths of each scale (output of the level = n_scales * last)
    pn2_mlps: Tuple[Tuple[int, ...], ...] = (
        (16, 16, 32), (32, 32, 64), (64, 64, 128), (128, 128, 256))
    # feature propagation, listed from the finest level (output, last width must be
    # point_channels) to the coarsest
    pn2_fp_mlps: Tuple[Tuple[int, ...], ...] = (
        (128, 128), (256, 256), (256, 256), (512, 512))

    # --- image encoders --------------------------------------------------------
    cnn_widths: Tuple[int, ...] = (32, 64, 128)
    vit_patch: int = 14
    vit_dim: int = 384
    vit_depth: int = 12
    vit_heads: int = 6
    vit_mlp_ratio: float = 4.0
    vit_pos_grid: int = 37  # official ViT-S/14 pos_embed: 1 + 37*37 tokens

    # --- SCKD ------------------------------------------------------------------
    sckd_layers: int = 4  # AG-Pose detector: 4 attention blocks
    heads: int = 4        # attention heads (SCKD blocks, PIGA global stage)
    ffn_dim: int = 256
    heatmap_eps: float = 1e-7

    # --- PIGA ------------------------------------------------------------------
    descriptor_hidden: int = 64
    piga_ffn: bool = True
    detach_kpt_geometry: bool = True  # PIGA sees kpt_3d.detach() (AG-Pose)

    # --- heads -----------------------------------------------------------------
    nocs_hidden: int = 256
    # one NOCS output per category, selected by the instance's class id (AG-Pose's
    # per-category NOCS head, without its bins); adds a ``class_id`` (B,) int64 input
    nocs_per_class: bool = False
    n_classes: int = 6
    pose_hidden: int = 256
    pts_per_kpt: int = 10
    size_init: float = 0.2  # metres; softplus bias so s starts near this value

    # --- loss constants --------------------------------------------------------
    nocs_beta: float = 0.1
    div_threshold: float = 0.01
    cvc_eps: float = 1e-6
    cvc_beta: float = 1.0

    name: str = "paper"
    notes: str = ""

    def __post_init__(self) -> None:
        for k in ("pn2_npoints", "pn2_radii", "pn2_nsamples", "pn2_mlps",
                  "pn2_fp_mlps", "cnn_widths"):
            object.__setattr__(self, k, _tuplify(getattr(self, k)))
        self.validate()

    # ------------------------------------------------------------------ checks
    def validate(self) -> None:
        """Raise ``ValueError`` on inconsistent settings."""
        if self.channels != self.point_channels + self.image_channels:
            raise ValueError("channels must equal point_channels + image_channels")
        if self.image_encoder not in IMAGE_ENCODERS:
            raise ValueError(f"image_encoder must be one of {IMAGE_ENCODERS}")
        if self.descriptor not in DESCRIPTORS:
            raise ValueError(f"descriptor must be one of {DESCRIPTORS}")
        L = len(self.pn2_npoints)
        if not (len(self.pn2_radii) == len(self.pn2_mlps) == len(self.pn2_fp_mlps) == L):
            raise ValueError("pn2_npoints/radii/mlps/fp_mlps must have one entry per level")
        if any(len(r) != len(self.pn2_nsamples) for r in self.pn2_radii):
            raise ValueError("each level needs one radius per pn2_nsamples entry")
        if self.pn2_fp_mlps[0][-1] != self.point_channels:
            raise ValueError("pn2_fp_mlps[0][-1] must equal point_channels")
        if self.pn2_npoints[0] > self.n_points:
            raise ValueError("first PointNet++ level samples more points than N")
        if self.k_local > self.n_points or self.k_local < 2:
            raise ValueError("need 2 <= k_local <= n_points")
        if self.k_global + 1 > self.n_keypoints or self.k_global < 2:
            raise ValueError("need 2 <= k_global < n_keypoints")
        if self.channels % self.heads:
            raise ValueError("channels must be divisible by heads")
        if self.image_encoder == "dinov2" and self.vit_dim % self.vit_heads:
            raise ValueError("vit_dim must be divisible by vit_heads")

    # ------------------------------------------------------------- serialise
    def to_dict(self) -> Dict[str, Any]:
        """Plain-JSON dict (tuples become lists)."""
        return json.loads(json.dumps(dataclasses.asdict(self)))

    @classmethod
    def from_dict(cls, d: Dict[str, Any]) -> "ModelConfig":
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError``."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown ModelConfig keys: {sorted(unknown)}")
        return cls(**{k: _tuplify(v) for k, v in d.items()})

    def to_json(self) -> str:
        """JSON text of :meth:`to_dict` (sorted keys)."""
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> "ModelConfig":
        """Inverse of :meth:`to_json`."""
        return cls.from_dict(json.loads(text))

    def replace(self, **kw: Any) -> "ModelConfig":
        """Copy with some fields changed (validated)."""
        return dataclasses.replace(self, **kw)

    # ---------------------------------------------------------- constructors
    @classmethod
    def paper(cls) -> "ModelConfig":
        """The paper's settings (Implementation Details + AG-Pose defaults it keeps).

        N=1024, M=96, C=256 (128 point + 128 image), B=6, K=16, K_gl=3, crop 192,
        tau 0.1, frozen DINOv2 ViT-S/14-shaped image encoder, PointNet++ MSG with
        AG-Pose's four levels, 4 SCKD attention blocks.

        31.9 M parameters, of which 22.06 M are the ViT (frozen once weights are
        loaded), so 9.9 M trainable. Measured on the project's shared 2-core CPU box
        (torch 2.15, float32, 2 threads): forward_train + losses + backward + Adam
        step for a batch of 16 (both views) 13-17 s; inference forward for a batch
        of 16: 2.8 s. Meant for a GPU.
        """
        return cls(name="paper")

    @classmethod
    def shipped(cls) -> "ModelConfig":
        """Sizes that train on 2 CPU cores in about two hours on a few thousand
        SynthNOCS instances.

        N=512, M=32, C=128 (64 point + 64 image), B=2, K=8, K_gl=3, crop 96, a small
        encoder-decoder CNN (118 k parameters) for the image, PointNet++ MSG with
        three levels (256/64/16 centres, radii doubled from the paper's first three
        levels to suit the sparser cloud, nsample 8/16), 2 SCKD attention blocks.
        1.49 M parameters, all trainable.

        Measured on the project's shared 2-core CPU box (torch 2.15, float32,
        2 threads, light load): forward_train + losses + backward + Adam step for a
        batch of 16 with both augmented views 0.58-0.68 s (0.93 s of CPU time on
        one thread); inference forward for a batch of 16: 0.15 s. At ~0.65 s a step,
        2 hours are ~11 k steps = ~177 k samples, i.e. ~60 epochs of 3000 instances
        (data loading not included).
        """
        return cls(
            name="shipped",
            n_points=512,
            n_keypoints=32,
            channels=128,
            point_channels=64,
            image_channels=64,
            blocks=2,
            k_local=8,
            k_global=3,
            crop_size=96,
            image_encoder="cnn",
            pn2_npoints=(256, 64, 16),
            pn2_radii=((0.02, 0.04), (0.04, 0.08), (0.08, 0.16)),
            pn2_nsamples=(8, 16),
            pn2_mlps=((16, 16, 32), (32, 32, 64), (64, 64, 128)),
            pn2_fp_mlps=((64, 64), (128, 128), (128, 128)),
            cnn_widths=(16, 32, 64),
            sckd_layers=2,
            heads=4,
            ffn_dim=128,
            descriptor_hidden=32,
            nocs_hidden=128,
            pose_hidden=128,
            pts_per_kpt=8,
        )

    # --------------------------------------------------------------- ablations
    def baseline(self) -> "ModelConfig":
        """AG-Pose: no L_cvc (single augmented view), no triangle descriptors
        (AG-Pose's relative-coordinate aggregation instead of PIGA)."""
        return self.replace(name=self.name + "-baseline", use_sckd_loss=False,
                            use_piga=False, descriptor="relative")

    def without_sckd(self) -> "ModelConfig":
        """Paper's "w/o SCKD": PIGA kept, cross-view consistency loss removed."""
        return self.replace(name=self.name + "-wo-sckd", use_sckd_loss=False)

    def without_piga(self) -> "ModelConfig":
        """Paper's "w/o PIGA": L_cvc kept, triangle-based geometric bias replaced by
        AG-Pose's relative-coordinate aggregation."""
        return self.replace(name=self.name + "-wo-piga", use_piga=False,
                            descriptor="relative")

    def with_descriptor(self, descriptor: str) -> "ModelConfig":
        """Descriptor ablation inside PIGA: "triangle" | "relative" | "ppf" | "dist_angle"."""
        return self.replace(name=f"{self.name}-{descriptor}", descriptor=descriptor,
                            use_piga=True)

    # convenience for callers that want the ablation straight from the paper sizes
    @classmethod
    def ablation(cls, which: str, base: "ModelConfig | None" = None) -> "ModelConfig":
        """``which`` in {"full", "baseline", "wo_sckd", "wo_piga", "relative", "ppf",
        "dist_angle", "triangle"}; ``base`` defaults to :meth:`paper`."""
        base = base or cls.paper()
        if which == "full":
            return base
        if which == "baseline":
            return base.baseline()
        if which == "wo_sckd":
            return base.without_sckd()
        if which == "wo_piga":
            return base.without_piga()
        if which in DESCRIPTORS:
            return base.with_descriptor(which)
        raise ValueError(f"unknown ablation {which!r}")
