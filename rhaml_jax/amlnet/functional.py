"""Builds a model, splits it once with `nnx.split`, and exposes it as plain functions of
(params, batch_stats, inputs) for `jax.jit`.

    net = build(cfg, key)                  # Net(cfg, graphdef, params, batch_stats)
    out = net.apply(params, batch_stats, images)                   # inference (running stats)
    out, new_stats = net.train_apply(params, batch_stats, images, key)   # batch statistics

`impl="reference"` swaps every fast kernel for plain lax convolutions (tests, MAC counting).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import jax
import numpy as np
from flax import nnx

from rhaml_jax.amlnet.config import AMLNetConfig, FrontNetConfig, ModelConfig
from rhaml_jax.amlnet.frontnet import FrontNet
from rhaml_jax.amlnet.init import HostInit
from rhaml_jax.amlnet.model import AMLNet
from rhaml_jax.errors import RhamlError

__all__ = ["Net", "build", "make_module", "check_images"]


def make_module(cfg: ModelConfig, key) -> nnx.Module:
    """The NNX module of `cfg`, initialised from `key` (None: zeros, for shape-only builds)."""
    init = HostInit(key)
    if isinstance(cfg, AMLNetConfig):
        return AMLNet(cfg, init=init)
    if isinstance(cfg, FrontNetConfig):
        return FrontNet(cfg, init=init)
    raise RhamlError(f"model config: unsupported type {type(cfg).__name__}")


@dataclass(frozen=True)
class Net:
    cfg: ModelConfig
    graphdef: Any
    params: Any
    batch_stats: Any

    def apply(self, params, batch_stats, images, impl: str = "fast"):
        model = nnx.merge(self.graphdef, params, batch_stats, copy=True)
        return model(images, train=False, impl=impl)

    def train_apply(self, params, batch_stats, images, key=None, impl: str = "fast"):
        model = nnx.merge(self.graphdef, params, batch_stats, copy=True)
        out = model(images, train=True, key=key, impl=impl)
        return out, nnx.state(model, nnx.BatchStat)


def build(cfg: ModelConfig, key=None, abstract: bool = False) -> Net:
    """Initialises `cfg` with PRNG `key` (default key 0); `abstract` gives shapes only."""
    key = jax.random.key(0) if key is None else key
    model = nnx.eval_shape(lambda: make_module(cfg, None)) if abstract else make_module(cfg, key)
    graphdef, params, batch_stats = nnx.split(model, nnx.Param, nnx.BatchStat)
    return Net(cfg, graphdef, params, batch_stats)


def check_images(cfg: ModelConfig, images, name: str = "images") -> None:
    """Raises RhamlError unless `images` is (B, H, W, 3) float32 at the config's input size."""
    shape = tuple(np.shape(images))
    h, w = cfg.input_hw
    dtype = getattr(images, "dtype", None)
    if len(shape) != 4:
        raise RhamlError(f"{name}: expected (B, {h}, {w}, 3) images, got shape {shape}")
    if shape[3] != 3:
        raise RhamlError(f"{name}: expected 3 (RGB) channels last, got shape {shape}")
    if shape[1:3] != (h, w):
        raise RhamlError(f"{name}: config {cfg.name} takes {h} x {w} images, got {shape[1]} x {shape[2]} (shape {shape})")
    if dtype is None or np.dtype(dtype) != np.float32:
        raise RhamlError(f"{name}: expected float32 in [0, 1], got dtype {dtype}")
