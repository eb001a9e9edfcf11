"""The AIncep block: InceptionNeXt's block with ACN in place of the 3x3 branch.

token mixer (channels split into identity | ACN | 1 x band depthwise | band x 1 depthwise,
the three convolved branches C/8 wide each) -> BN -> MLP (1x1 conv, GELU, 1x1 conv) ->
layer scale -> drop path -> + input.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import nnx

from rhaml_jax.amlnet import ops
from rhaml_jax.amlnet.acn import ACN
from rhaml_jax.amlnet.init import HostInit
from rhaml_jax.amlnet.norm import BatchNorm

__all__ = ["Mixer", "AIncepBlock"]


class Mixer(nnx.Module):
    def __init__(self, c: int, kernels, dense: bool, band: int, branch_ratio: int, *, init: HostInit):
        g = c // branch_ratio
        self.split = (c - 3 * g, g, g, g)
        self.acn = ACN(g, kernels, dense, init=init)
        self.band_w = init.trunc_normal((band, g))
        self.band_w_b = init.zeros((g,))
        self.band_h = init.trunc_normal((band, g))
        self.band_h_b = init.zeros((g,))

    def __call__(self, x, impl: str = "fast"):
        i0, g = self.split[0], self.split[1]
        a, b, c, d = x[..., :i0], x[..., i0 : i0 + g], x[..., i0 + g : i0 + 2 * g], x[..., i0 + 2 * g :]
        dw = ops.depthwise_1d if impl == "fast" else ops.depthwise_1d_ref
        return jnp.concatenate(
            [a, self.acn(b, impl), dw(c, self.band_w[...], self.band_w_b[...], axis=2), dw(d, self.band_h[...], self.band_h_b[...], axis=1)],
            axis=-1,
        )


class AIncepBlock(nnx.Module):
    def __init__(self, c: int, ratio: int, cfg, *, init: HostInit):
        self.mixer = Mixer(c, cfg.acn_kernels, cfg.acn_dense, cfg.band_kernel, cfg.branch_ratio, init=init)
        self.norm = BatchNorm(c)
        self.fc1 = init.trunc_normal((c, ratio * c))
        self.fc1_b = init.zeros((ratio * c,))
        self.fc2 = init.trunc_normal((ratio * c, c))
        self.fc2_b = init.zeros((c,))
        self.gamma = init.full((c,), cfg.layer_scale_init)
        self.drop_path = float(cfg.drop_path)

    def __call__(self, x, train: bool, key=None, impl: str = "fast"):
        mlp = ops.mlp if impl == "fast" else ops.mlp_ref
        y = self.norm(self.mixer(x, impl), train)
        y = mlp(y, self.fc1[...], self.fc1_b[...], self.fc2[...], self.fc2_b[...])
        y = y * self.gamma[...]
        if train and self.drop_path > 0.0 and key is not None:
            keep = 1.0 - self.drop_path
            mask = jax.random.bernoulli(key, keep, (x.shape[0], 1, 1, 1)).astype(x.dtype) / keep
            y = y * mask
        return x + y
