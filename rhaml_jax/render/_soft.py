"""Soft silhouette: probabilistic union of per-face soft coverages (after SoftRas).

For a pixel centre p and face f, s_f(p) is the signed distance (px) from p to the face's
projected (near-clipped) polygon, positive inside. The face covers p with probability
sigmoid(k s_f) for sharpness k (1/px), and the faces together cover it with

    A(p) = 1 - prod_f (1 - sigmoid(k s_f)) = 1 - exp(sum_f tau(x_f) log_sigmoid(x_f)),  x_f = -k s_f,

which tends to the hard silhouette (the union of the faces) as k -> infinity. The taper tau
fades a face out smoothly between `cutoff - RAMP` and `cutoff` (units of 1/k px) outside it,
so each face only touches the pixels of its box grown by cutoff / k (the pairs of `_tiles`)
and the image stays a continuous, differentiable function of the pose. Summing logs makes the
union a scatter-add, whose transpose is a gather.

Gradients: `coverage` has a custom VJP in which only the nearest edge of each face carries the
gradient of its distance (d dist / d endpoint = (1 - t) or t times the unit offset, t the
closest point's parameter on that segment), recomputed chunk by chunk in the backward pass;
`coverage_autodiff` is the same forward over a fixed number of chunks, differentiated by XLA
(the reference for tests and benchmarks).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from rhaml_jax.render._edges import distance_vjp, signed_distance
from rhaml_jax.render._tiles import Layout, chunk_pairs, fold_chunks

RAMP = 3.0  # width of the taper, in units of 1/k px


def _taper(x, cutoff):
    """(tau, dtau/dx): 1 for x <= cutoff - RAMP, smoothstep down to 0 at x = cutoff."""
    a = jnp.clip((cutoff - x) / RAMP, 0.0, 1.0)
    return a * a * (3 - 2 * a), -6 * a * (1 - a) / RAMP


def _values(q, orient, u, v, used, k, cutoff):
    """(C, N) log of 'not covered' per (pair, pixel), signed distances and VJP data."""
    sd, aux = signed_distance(q, orient, u, v)
    x = -k * sd
    tau, _ = _taper(x, cutoff)
    return jnp.where(used, tau * jax.nn.log_sigmoid(x), 0.0), sd, aux


def _computed(x):
    """Computes x (a scatter's indices or updates) before the scatter consumes it. Guard against
    XLA's CPU scatter fusion, which otherwise evaluates the whole producer element by element
    inside the scatter's serial loop (measured 40x slower for the backward pass)."""
    return jax.lax.optimization_barrier(x)


def _chunk_inputs(sf_poly, orient, lay, first, size, width, height, block):
    pr = chunk_pairs(lay, first, size, width, height, block)
    dt = sf_poly.dtype
    out = pr, sf_poly[pr.face], orient[pr.face], pr.px.astype(dt), pr.py.astype(dt)
    # Materialise the chunk's inputs: without the barrier XLA fuses these gathers into every
    # consumer and recomputes them there (measured 50x slower backward on CPU).
    return jax.lax.optimization_barrier(out)


def _accumulate(poly, k, orient, lay, width, height, block, size, cutoff):
    npix = width * height

    def body(first, s):
        pr, q, o, u, v = _chunk_inputs(poly, orient, lay, first, size, width, height, block)
        val, _, _ = _values(q, o, u, v, pr.used, k, cutoff)
        return s.at[pr.index].add(_computed(val), mode="drop")

    return fold_chunks(lay, size, body, jnp.zeros((npix,), poly.dtype))


@functools.partial(jax.custom_vjp, nondiff_argnums=(4, 5, 6, 7, 8))
def coverage(poly, k, orient, lay: Layout, width: int, height: int, block: int, size: int, cutoff: float):
    """poly (F, 4, 2), k () sharpness, orient (F,), Layout -> (H * W,) coverage in [0, 1]."""
    return -jnp.expm1(_accumulate(poly, k, orient, lay, width, height, block, size, cutoff))


def _fwd(poly, k, orient, lay, width, height, block, size, cutoff):
    s = _accumulate(poly, k, orient, lay, width, height, block, size, cutoff)
    return -jnp.expm1(s), (poly, k, orient, lay, s)


def _bwd(width, height, block, size, cutoff, res, g):
    poly, k, orient, lay, s = res
    npix = width * height
    gs_pix = -g * jnp.exp(s)  # dA/ds = -exp(s)

    def body(first, carry):
        gpoly, gk = carry
        pr, q, o, u, v = _chunk_inputs(poly, orient, lay, first, size, width, height, block)
        gs = jnp.where(pr.used, gs_pix[jnp.minimum(pr.index, npix - 1)], 0.0)  # gather: scatter's transpose
        sd, near = signed_distance(q, o, u, v)
        x = -k * sd
        tau, dtau = _taper(x, cutoff)
        dval_dx = gs * (tau * jax.nn.sigmoid(-x) + dtau * jax.nn.log_sigmoid(x))
        gk = gk + jnp.sum(dval_dx * -sd)
        gq = distance_vjp(q, near, dval_dx * -k)  # (C, 4, 2)
        flat = (pr.face[:, None] * 8 + jnp.arange(8, dtype=jnp.int32)).reshape(-1)
        flat, val = _computed((flat, gq.reshape(-1)))
        return gpoly.at[flat].add(val), gk

    gpoly, gk = fold_chunks(lay, size, body, (jnp.zeros((poly.size,), poly.dtype), jnp.zeros_like(k)))
    return gpoly.reshape(poly.shape), gk, None, None


coverage.defvjp(_fwd, _bwd)


def coverage_autodiff(poly, k, orient, lay: Layout, width: int, height: int, block: int, size: int,
                      cutoff: float, capacity: int):
    """Same values (pairs beyond `capacity` dropped), differentiated by XLA's reverse mode."""
    npix = width * height
    n_chunks = -(-capacity // size)

    def body(s, first):
        pr, q, o, u, v = _chunk_inputs(poly, orient, lay, first, size, width, height, block)
        val, _, _ = _values(q, o, u, v, pr.used, k, cutoff)
        return s.at[pr.index].add(_computed(val), mode="drop"), None

    firsts = jnp.arange(n_chunks, dtype=jnp.int32) * size
    s, _ = jax.lax.scan(body, jnp.zeros((npix,), poly.dtype), firsts)
    return -jnp.expm1(s)
