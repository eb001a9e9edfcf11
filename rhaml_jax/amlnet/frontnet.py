"""PULP-Frontnet baseline (DESIGN.md section 7): 5x5/2 conv + BN + ReLU + 2x2 max-pool, three
blocks of two 3x3 convs (the first of each stride 2), each conv + BN + ReLU, dropout, one FC.
Convolutions carry no bias (BN follows).  Same input and output conventions as AMLNet."""

from __future__ import annotations

import jax
from flax import nnx

from rhaml_jax.amlnet import ops
from rhaml_jax.amlnet.init import HostInit
from rhaml_jax.amlnet.config import FrontNetConfig, num_outputs
from rhaml_jax.amlnet.model import normalize_images, scale_head
from rhaml_jax.amlnet.norm import BatchNorm

__all__ = ["FrontNet"]


class FrontNet(nnx.Module):
    def __init__(self, cfg: FrontNetConfig, *, init: HostInit):
        self.cfg = cfg
        self.stem = init.he_normal((5, 5, 3, cfg.stem_channels))
        self.stem_norm = BatchNorm(cfg.stem_channels)
        convs, norms, strides = [], [], []
        prev = cfg.stem_channels
        for c in cfg.channels:
            for s in (2, 1):
                convs.append(init.he_normal((3, 3, prev, c)))
                norms.append(BatchNorm(c))
                strides.append(s)
                prev = c
        self.convs, self.norms, self.strides = nnx.List(convs), nnx.List(norms), tuple(strides)
        h, w = cfg.input_hw
        flat = prev * (h // 2 ** (2 + len(cfg.channels))) * (w // 2 ** (2 + len(cfg.channels)))
        self.fc = init.trunc_normal((flat, num_outputs(cfg)))
        self.fc_b = init.zeros((num_outputs(cfg),))

    def __call__(self, images, train: bool = False, key=None, impl: str = "fast"):
        x = ops.conv_ref(normalize_images(images), self.stem[...], stride=2)
        x = jax.nn.relu(self.stem_norm(x, train))
        b, h, w, c = x.shape
        x = x.reshape(b, h // 2, 2, w // 2, 2, c).max(axis=(2, 4))
        for conv, norm, s in zip(self.convs, self.norms, self.strides):
            x = jax.nn.relu(norm(ops.conv_ref(x, conv[...], stride=s), train))
        x = x.reshape(x.shape[0], -1)
        if train and self.cfg.dropout > 0 and key is not None:
            keep = 1.0 - self.cfg.dropout
            x = x * jax.random.bernoulli(key, keep, x.shape).astype(x.dtype) / keep
        return scale_head(x @ self.fc[...] + self.fc_b[...])
