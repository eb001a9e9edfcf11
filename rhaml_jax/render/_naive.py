"""All-pairs soft silhouette: every pixel against every face, no binning, XLA autodiff.

Only a baseline for the benchmarks and a check that binning loses nothing: its cost is
H * W * F whatever the view.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from rhaml_jax.render._geometry import ScreenFaces
from rhaml_jax.render._soft import _values


def naive_coverage(sf: ScreenFaces, k, width: int, height: int, chunk: int, cutoff: float) -> jnp.ndarray:
    """ScreenFaces of F faces -> (height, width) coverage, faces taken `chunk` at a time."""
    nf = sf.poly.shape[0]
    pad = -nf % chunk
    poly = jnp.pad(sf.poly, ((0, pad), (0, 0), (0, 0)))
    orient = jnp.pad(sf.orient, (0, pad))
    valid = jnp.pad(sf.valid, (0, pad))
    dt = poly.dtype
    yy, xx = jnp.meshgrid(jnp.arange(height, dtype=dt), jnp.arange(width, dtype=dt), indexing="ij")
    u = jnp.broadcast_to(xx.reshape(1, -1), (chunk, width * height))
    v = jnp.broadcast_to(yy.reshape(1, -1), (chunk, width * height))

    def body(s, xs):
        q, o, ok = xs
        val, _, _ = _values(q, o, u, v, jnp.broadcast_to(ok[:, None], u.shape), k, cutoff)
        return s + jnp.sum(val, 0), None

    xs = (poly.reshape(-1, chunk, 4, 2), orient.reshape(-1, chunk), valid.reshape(-1, chunk))
    s, _ = jax.lax.scan(body, jnp.zeros((width * height,), dt), xs)
    return (-jnp.expm1(s)).reshape(height, width)
