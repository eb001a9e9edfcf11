"""Parameter and MAC counts, taken from the model itself.

Parameters: the sizes of every `nnx.Param` (BatchNorm scale and bias included, running
statistics not), from an abstract (shape-only) build.
MACs: the multiply-accumulates of every convolution and matrix product in the jaxpr of the
reference forward pass at batch 1 (the convention of ptflops / fvcore: element-wise work such
as BN, GELU, softmax and the ACN weighting is not counted).  The reference implementation is
used because there every depthwise convolution is a `conv_general_dilated`.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jax.extend import core as jcore

from rhaml_jax.amlnet.config import ModelConfig
from rhaml_jax.amlnet.functional import build

__all__ = ["count_params", "count_macs", "jaxpr_macs"]


def count_params(cfg: ModelConfig, net=None) -> int:
    net = build(cfg, abstract=True) if net is None else net
    return int(sum(math.prod(x.shape) for x in jax.tree.leaves(net.params)))


def _eqn_macs(eqn) -> int:
    name = eqn.primitive.name
    if name == "conv_general_dilated":
        out = eqn.outvars[0].aval.shape
        rhs = eqn.invars[1].aval.shape
        dn = eqn.params["dimension_numbers"]
        rhs_spec = dn.rhs_spec  # (out feature dim, in feature dim, spatial...)
        k_spatial = math.prod(rhs[d] for d in rhs_spec[2:])
        return math.prod(out) * k_spatial * rhs[rhs_spec[1]]
    if name == "dot_general":
        (lc, _), _ = eqn.params["dimension_numbers"]
        lhs = eqn.invars[0].aval.shape
        return math.prod(eqn.outvars[0].aval.shape) * math.prod(lhs[d] for d in lc)
    return 0


def jaxpr_macs(jaxpr) -> int:
    total = 0
    for eqn in jaxpr.eqns:
        total += _eqn_macs(eqn)
        for v in eqn.params.values():
            for sub in v if isinstance(v, (list, tuple)) else (v,):
                if isinstance(sub, jcore.ClosedJaxpr):
                    total += jaxpr_macs(sub.jaxpr)
                elif isinstance(sub, jcore.Jaxpr):
                    total += jaxpr_macs(sub)
    return total


def count_macs(cfg: ModelConfig, impl: str = "reference", net=None) -> int:
    net = build(cfg, abstract=True) if net is None else net
    h, w = cfg.input_hw
    images = jax.ShapeDtypeStruct((1, h, w, 3), jnp.float32)
    jaxpr = jax.make_jaxpr(lambda p, s, x: net.apply(p, s, x, impl=impl))(net.params, net.batch_stats, images)
    return jaxpr_macs(jaxpr.jaxpr)
