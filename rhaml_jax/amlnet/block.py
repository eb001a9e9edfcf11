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
from rhaml_jax.amlnet.norm import BatchNorm

__all__ = ["Mixer", "AIncepBlock", "trunc_param"]


def trunc_param(key, shape, std=0.02):
    return nnx.Param(std * jax.random.truncated_normal(key, -2.0, 2.0, shape, jnp.float32))


class Mixer(nnx.Module):
    def __init__(self, c: int, kernels, dense: bool, band: int, branch_ratio: int, *, rngs: nnx.Rngs):
        g = c // branch_ratio
        self.split = (c - 3 * g, g, g, g)
        self.acn = ACN(g, kernels, dense, rngs=rngs)
        self.band_w = trunc_param(rngs.params(), (band, g))
        self.band_w_b = nnx.Param(jnp.zeros((g,)))
        self.band_h = trunc_param(rngs.params(), (band, g))
        self.band_h_b = nnx.Param(jnp.zeros((g,)))

    def __call__(self, x, impl: str = "fast"):
        i0, g = self.split[0], self.split[1]
        a, b, c, d = x[..., :i0], x[..., i0 : i0 + g], x[..., i0 + g : i0 + 2 * g], x[..., i0 + 2 * g :]
        dw = ops.depthwise_1d if impl == "fast" else ops.depthwise_1d_ref
        return jnp.concatenate(
            [a, self.acn(b, impl), dw(c, self.band_w[...], self.band_w_b[...], axis=2), dw(d, self.band_h[...], self.band_h_b[...], axis=1)],
            axis=-1,
        )


class AIncepBlock(nnx.Module):
    def __init__(self, c: int, ratio: int, cfg, *, rngs: nnx.Rngs):
        self.mixer = Mixer(c, cfg.acn_kernels, cfg.acn_dense, cfg.band_kernel, cfg.branch_ratio, rngs=rngs)
        self.norm = BatchNorm(c)
        self.fc1 = trunc_param(rngs.params(), (c, ratio * c))
        self.fc1_b = nnx.Param(jnp.zeros((ratio * c,)))
        self.fc2 = trunc_param(rngs.params(), (ratio * c, c))
        self.fc2_b = nnx.Param(jnp.zeros((c,)))
        self.gamma = nnx.Param(jnp.full((c,), cfg.layer_scale_init, jnp.float32))
        self.drop_path = float(cfg.drop_path)

    def __call__(self, x, train: bool, key=None, impl: str = "fast"):
        pw = ops.pointwise if impl == "fast" else ops.pointwise_ref
        y = self.norm(self.mixer(x, impl), train)
        y = pw(jax.nn.gelu(pw(y, self.fc1[...], self.fc1_b[...]), approximate=False), self.fc2[...], self.fc2_b[...])
        y = y * self.gamma[...]
        if train and self.drop_path > 0.0 and key is not None:
            keep = 1.0 - self.drop_path
            mask = jax.random.bernoulli(key, keep, (x.shape[0], 1, 1, 1)).astype(x.dtype) / keep
            y = y * mask
        return x + y
