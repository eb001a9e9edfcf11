"""Model configurations (frozen dataclasses) and the registry of named configs.

A config fully determines a network; checkpoints store `config_to_dict(cfg)` beside the
weights and rebuild the model with `config_from_dict`.

Named configs
-------------
- ``paper``: InceptionNeXt-Small backbone with AIncep blocks (dense ACN, K = {3, 5, 7}), a
  two-layer FC neck (768 -> 1024 -> 1024) and a 4-output head, 224 x 224 input
  (DESIGN.md section 7: 49.9 M parameters, 8.85 GMACs).
- ``paper_k0``, ``paper_k3``, ``paper_k35``: the Table II ablation at paper size
  (K = {} is the plain 3x3 depthwise branch of InceptionNeXt).
- ``paper_dw``: the paper network with depthwise ACN kernels (8.38 GMACs).
- ``cpu``: the network that trains on the project's 2-core CPU machine in about two hours
  (see `CPU_RATIONALE`), plus its Table II ablation ``cpu_k0``, ``cpu_k3``, ``cpu_k35``.
- ``zoom_cpu``: the zoom-in stage that goes with ``cpu`` (`rhaml_jax.zoom`): 64 x 64
  crops around AMLNet's estimate, its range, bearing and heading corrections out.
- ``cpu_heat``: AMLNet with the dense head (`amlnet.heatmap`) on the luminance of a 256 x 320
  image (twice `cpu`'s resolution), three stages (1, 1, 2) of (32, 64, 128) with the paper's
  ACN, 0.38 M parameters, 0.22 GMACs: the first stage for images our renderer did not make
  (issue 18); ``zoom_cpu_luma``: `zoom_cpu` on luminance crops, its partner.
- ``cpu_heat_chroma``, ``cpu_heat_log``, ``zoom_cpu_log``: the same networks with the chroma
  contrast or the log luminance in place of one luminance copy (fields `chroma`, `log_luma`).
- ``frontnet``: the PULP-Frontnet baseline (0.32 M parameters, 0.066 GMACs at 224 x 224).
- ``tiny``, ``tiny_dw``, ``tiny_k0``, ``tiny_zoom``, ``tiny_heat``, ``micro``, ``tiny_frontnet``: test-size networks (XLA's CPU
  compiler needs ~0.1 s per fused kernel, so tests use the smallest networks that cover the code).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal, Union

from rhaml_jax.errors import RhamlError

__all__ = [
    "AMLNetConfig",
    "FrontNetConfig",
    "ModelConfig",
    "CONFIGS",
    "CPU_RATIONALE",
    "get_config",
    "config_names",
    "config_to_dict",
    "config_from_dict",
    "num_outputs",
]

AngleHead = Literal["psi", "cossin", "axis"]


@dataclass(frozen=True)
class AMLNetConfig:
    """AMLNet: stem 4x4/4 + BN; stages of AIncep blocks; BN + conv 2x2/2 between stages;
    global average pooling (or flatten, see `pool`); FC neck with GELU; linear head.

    acn_kernels: the set K of ACN kernel sizes; () means the plain 3x3 depthwise branch.
    acn_dense: ACN 1xk / kx1 kernels dense over the C/8 branch channels (paper size) or
      depthwise.
    angle_head: "psi" outputs (o, x, y, psi) as in the paper; "cossin" outputs
      (o, x, y, cos psi, sin psi) and decodes psi with atan2; "axis" adds (cos 2psi, sin 2psi),
      which survive a front/back look-alike robot (`loss` says why; documented options).
    task: "localize" (AMLNet: the whole image in, the pose out) or "zoom" (the zoom-in stage,
      `rhaml_jax.zoom`: a crop around a first estimate in, its correction out). The crop
      is `zoom_factor` times the robot's projected length `zoom_length_m` wide, centred on its
      point `zoom_centre_z_m` above the ground.
    pool: "gap" is the paper's global average pooling; "flatten" feeds the whole final
      feature grid to the neck, so the image position of the robot (its bearing) reaches the
      head directly instead of through zero-padding artefacts (a documented option).
    head: "global" is the paper's FC head on pooled features (one pose per image);
      "heatmap" is a dense head at stride 8 (`amlnet.heatmap`): a CenterNet-style map of where
      the robot's point `zoom_centre_z_m` above the ground projects, with a sub-cell offset,
      log range and heading per cell. The bearing then comes from the peak's image column
      (geometry) instead of a regression; it needs three or more stages (the last at stride 16
      is upsampled into the stride-8 head) and ignores pool and neck.
    luma: the network sees the image's luminance (replicated to three channels) instead of
      its colours, so no decision can rest on a hue (the held-out set paints the robot in
      hues training never gives a part).
    chroma: with luma, the third channel carries the local chroma contrast instead (`model.
      chroma_contrast`: the distance of each pixel's BT.601 (Cb, Cr) from their mean over a
      `chroma_window`-pixel box): still no hue, and a global tint of the light or a hue rotation of
      the whole image changes it little, but a robot whose colour differs from its surroundings
      stands out where its luminance does not. A luma checkpoint starts a chroma one exactly
      (`trainer.initial_weights` moves the third channel's stem weights onto the first).
    log_luma: with luma, the second channel carries the log luminance instead (`model.
      log_luminance`): a ratio of brightnesses, so black tyres on a dim floor differ as much as a
      red body on a grey one, and the robot's outline does not shrink where the light is low (the
      range read long on dark surroundings, issue 18). A luma checkpoint starts it exactly, as for
      chroma (the second channel's weights go onto the first).
    """

    name: str
    input_hw: tuple[int, int] = (224, 224)
    depths: tuple[int, ...] = (3, 3, 27, 3)
    dims: tuple[int, ...] = (96, 192, 384, 768)
    mlp_ratios: tuple[int, ...] = (4, 4, 4, 3)
    acn_kernels: tuple[int, ...] = (3, 5, 7)
    acn_dense: bool = True
    band_kernel: int = 11
    branch_ratio: int = 8
    neck: tuple[int, ...] = (1024, 1024)
    angle_head: AngleHead = "psi"
    pool: Literal["gap", "flatten"] = "gap"
    layer_scale_init: float = 1e-6
    drop_path: float = 0.0
    task: Literal["localize", "zoom"] = "localize"
    zoom_length_m: float = 0.455
    zoom_centre_z_m: float = 0.12
    zoom_factor: float = 2.0
    head: Literal["global", "heatmap"] = "global"
    luma: bool = False
    chroma: bool = False
    chroma_window: int = 15
    log_luma: bool = False
    kind: Literal["amlnet"] = "amlnet"

    def __post_init__(self):
        n = len(self.depths)
        if self.chroma and not self.luma:
            raise RhamlError(f"config {self.name}: chroma (the local chroma contrast channel) needs luma")
        if self.log_luma and not self.luma:
            raise RhamlError(f"config {self.name}: log_luma (the log luminance channel) needs luma")
        if self.chroma_window < 1 or self.chroma_window % 2 == 0:
            raise RhamlError(f"config {self.name}: chroma_window must be odd and positive, got {self.chroma_window}")
        if not (len(self.dims) == len(self.mlp_ratios) == n and n >= 1):
            raise RhamlError(f"config {self.name}: depths, dims and mlp_ratios need equal lengths")
        if any(k % 2 == 0 or k < 1 for k in self.acn_kernels):
            raise RhamlError(f"config {self.name}: acn_kernels must be odd, got {self.acn_kernels}")
        if len(set(self.acn_kernels)) != len(self.acn_kernels):
            raise RhamlError(f"config {self.name}: acn_kernels repeats a size: {self.acn_kernels}")
        if any(c // self.branch_ratio < 1 for c in self.dims):
            raise RhamlError(f"config {self.name}: dims {self.dims} too narrow for branch_ratio {self.branch_ratio}")
        stride = 4 * 2 ** (n - 1)
        h, w = self.input_hw
        if h % stride or w % stride:
            raise RhamlError(f"config {self.name}: input_hw {self.input_hw} must be divisible by {stride}")
        if self.angle_head not in ("psi", "cossin", "axis"):
            raise RhamlError(f"config {self.name}: angle_head must be 'psi', 'cossin' or 'axis', got {self.angle_head!r}")
        if self.task not in ("localize", "zoom"):
            raise RhamlError(f"config {self.name}: task must be 'localize' or 'zoom', got {self.task!r}")
        if self.task == "zoom" and (h != w or self.zoom_length_m <= 0 or self.zoom_factor <= 0):
            raise RhamlError(f"config {self.name}: a zoom network needs a square input and positive zoom_length_m, zoom_factor")
        if self.head not in ("global", "heatmap"):
            raise RhamlError(f"config {self.name}: head must be 'global' or 'heatmap', got {self.head!r}")
        if self.head == "heatmap" and (self.task != "localize" or n < 3 or self.angle_head != "cossin"):
            raise RhamlError(f"config {self.name}: a heatmap head needs task 'localize', at least three stages and "
                             "angle_head 'cossin'")
        if self.pool not in ("gap", "flatten"):
            raise RhamlError(f"config {self.name}: pool must be 'gap' or 'flatten', got {self.pool!r}")

    @property
    def final_grid(self) -> tuple[int, int]:
        stride = 4 * 2 ** (len(self.depths) - 1)
        return self.input_hw[0] // stride, self.input_hw[1] // stride


@dataclass(frozen=True)
class FrontNetConfig:
    """PULP-Frontnet: 5x5/2 conv + BN + ReLU + 2x2 max-pool, three blocks of two 3x3 convs
    (the first of each stride 2) with BN + ReLU, dropout, one FC layer on the flat features."""

    name: str
    input_hw: tuple[int, int] = (224, 224)
    stem_channels: int = 32
    channels: tuple[int, ...] = (32, 64, 128)
    dropout: float = 0.5
    angle_head: AngleHead = "psi"
    kind: Literal["frontnet"] = "frontnet"

    def __post_init__(self):
        stride = 4 * 2 ** len(self.channels)
        h, w = self.input_hw
        if h % stride or w % stride:
            raise RhamlError(f"config {self.name}: input_hw {self.input_hw} must be divisible by {stride}")


ModelConfig = Union[AMLNetConfig, FrontNetConfig]

CPU_RATIONALE = """\
`cpu` config: input 128 x 160 (H x W), the 480 x 640 camera image at 0.25 x 0.267 (close to
its 4:3 aspect; divisible by the network's stride 32, final grid 4 x 5); widths (32, 64, 128,
256) = 1/3 of the paper's; depths (2, 2, 6, 2); the paper's dense ACN with K = {3, 5, 7}, so
the Table II question can still be asked at this size (cpu_k0, cpu_k3, cpu_k35); neck
256 -> 256 -> 256; layer scale initialised at 0.1 instead of 1e-6 (a short run cannot afford
residual branches that start switched off).  3.4 M parameters, 0.140 GMACs (63x fewer than
`paper`); 4000 steps of 32 train in about two hours here.  Documented departures from the
paper's head, each for a reason measured in BENCHMARKS.md:
- pool="flatten": the final 4 x 5 x 256 grid reaches the neck whole (not averaged), so the
  robot's bearing, i.e. its image column, reaches the head directly;
- angle_head="cossin": (cos psi, sin psi) instead of psi (the paper's psi head had not left
  the mean predictor after 270 steps where this one had).
At this input size the robot is 5-40 pixels wide, and the whole-image network learns where
it is (bearing error ~2 deg, range error ~8 %) but not which way it faces: its heading outputs
stayed at the mean predictor (also with the "axis" head, which survives the Pioneer's
front/back look-alike ends, in a run stopped at step 950).  So `cpu` comes with a zoom-in
stage, `zoom_cpu` (`rhaml_jax.zoom`): a 1.3 M-parameter network of the same blocks on a
64 x 64 crop of the full-resolution image around the estimate, twice the robot's projected
length wide, which regresses the range, bearing and heading corrections."""


def _amlnet(name: str, **kw) -> AMLNetConfig:
    return AMLNetConfig(name=name, **kw)


_CPU = dict(
    input_hw=(128, 160),
    depths=(2, 2, 6, 2),
    dims=(32, 64, 128, 256),
    mlp_ratios=(4, 4, 4, 3),
    neck=(256, 256),
    pool="flatten",
    angle_head="cossin",
    layer_scale_init=0.1,
)
_TINY = dict(input_hw=(32, 32), depths=(1, 1, 1, 1), dims=(16, 16, 32, 32), mlp_ratios=(2, 2, 2, 2), neck=(16,), layer_scale_init=0.1)

CONFIGS: dict[str, ModelConfig] = {
    "paper": _amlnet("paper"),
    "paper_k0": _amlnet("paper_k0", acn_kernels=()),
    "paper_k3": _amlnet("paper_k3", acn_kernels=(3,)),
    "paper_k35": _amlnet("paper_k35", acn_kernels=(3, 5)),
    "paper_dw": _amlnet("paper_dw", acn_dense=False),
    "cpu": _amlnet("cpu", **_CPU),
    "cpu_k0": _amlnet("cpu_k0", acn_kernels=(), **_CPU),
    "cpu_k3": _amlnet("cpu_k3", acn_kernels=(3,), **_CPU),
    "cpu_k35": _amlnet("cpu_k35", acn_kernels=(3, 5), **_CPU),
    "cpu_psi": _amlnet("cpu_psi", **{**_CPU, "angle_head": "psi"}),
    "zoom_cpu": _amlnet("zoom_cpu", task="zoom", input_hw=(64, 64), depths=(1, 1, 3, 1), dims=(32, 64, 128, 256),
                        mlp_ratios=(4, 4, 4, 3), neck=(256,), pool="flatten", angle_head="axis", layer_scale_init=0.1),
    "zoom_cpu_luma": _amlnet("zoom_cpu_luma", task="zoom", input_hw=(64, 64), depths=(1, 1, 3, 1), dims=(32, 64, 128, 256),
                             mlp_ratios=(4, 4, 4, 3), neck=(256,), pool="flatten", angle_head="axis", layer_scale_init=0.1,
                             luma=True),
    "zoom_cpu_log": _amlnet("zoom_cpu_log", task="zoom", input_hw=(64, 64), depths=(1, 1, 3, 1), dims=(32, 64, 128, 256),
                            mlp_ratios=(4, 4, 4, 3), neck=(256,), pool="flatten", angle_head="axis", layer_scale_init=0.1,
                            luma=True, log_luma=True),
    "cpu_heat": _amlnet("cpu_heat", input_hw=(256, 320), depths=(1, 1, 2), dims=(32, 64, 128), mlp_ratios=(4, 4, 4),
                        angle_head="cossin", head="heatmap", luma=True, layer_scale_init=0.1),
    "cpu_heat_chroma": _amlnet("cpu_heat_chroma", input_hw=(256, 320), depths=(1, 1, 2), dims=(32, 64, 128),
                               mlp_ratios=(4, 4, 4), angle_head="cossin", head="heatmap", luma=True, chroma=True,
                               layer_scale_init=0.1),
    "cpu_heat_log": _amlnet("cpu_heat_log", input_hw=(256, 320), depths=(1, 1, 2), dims=(32, 64, 128),
                            mlp_ratios=(4, 4, 4), angle_head="cossin", head="heatmap", luma=True, log_luma=True,
                            layer_scale_init=0.1),
    "frontnet": FrontNetConfig("frontnet"),
    "tiny": _amlnet("tiny", **_TINY),
    "tiny_dw": _amlnet("tiny_dw", acn_dense=False, **_TINY),
    "tiny_k0": _amlnet("tiny_k0", acn_kernels=(), **_TINY),
    "micro": _amlnet("micro", input_hw=(16, 16), depths=(1, 1), dims=(16, 16), mlp_ratios=(2, 2), neck=(8,), layer_scale_init=0.1),
    "tiny_heat": _amlnet("tiny_heat", input_hw=(32, 48), depths=(1, 1, 1), dims=(16, 16, 32), mlp_ratios=(2, 2, 2),
                         angle_head="cossin", head="heatmap", luma=True, layer_scale_init=0.1),
    "tiny_zoom": _amlnet("tiny_zoom", task="zoom", angle_head="axis", pool="flatten", **_TINY),
    "tiny_frontnet": FrontNetConfig("tiny_frontnet", input_hw=(32, 32), stem_channels=8, channels=(8, 8, 16)),
}


def config_names() -> list[str]:
    return list(CONFIGS)


def get_config(name: str) -> ModelConfig:
    try:
        return CONFIGS[name]
    except KeyError:
        raise RhamlError(f"--config: unknown model config {name!r}; known: {', '.join(CONFIGS)}") from None


def num_outputs(cfg: ModelConfig) -> int:
    return {"psi": 4, "cossin": 5, "axis": 7}[cfg.angle_head]


def config_to_dict(cfg: ModelConfig) -> dict:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(cfg).items()}


def config_from_dict(d: dict) -> ModelConfig:
    kind = d.get("kind")
    cls = {"amlnet": AMLNetConfig, "frontnet": FrontNetConfig}.get(kind)
    if cls is None:
        raise RhamlError(f"model config: unknown kind {kind!r}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(d) - names
    if unknown:
        raise RhamlError(f"model config: unknown field(s) {sorted(unknown)}")
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})
