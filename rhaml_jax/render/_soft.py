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

from rhaml_jax.render._edges import edge_terms, signed_distance, sum_rows, vertex_sums
from rhaml_jax.render._tiles import Layout, block_pixels, block_rows, chunk_blocks, fold_chunks, padded_size

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
    """The chunk's blocks, their faces' polygons and orientations, pixel centres u, v and used."""
    b = chunk_blocks(lay, first, size, block)
    # Materialise the per-pair inputs: without the barrier XLA fuses these gathers into every
    # per-pixel consumer and recomputes them there, pixel by pixel (measured 2x slower forward
    # and 50x slower backward on CPU).
    b, q, o = jax.lax.optimization_barrier((b, sf_poly[b.face], orient[b.face]))
    u, v, used = block_pixels(b, block, sf_poly.dtype)
    return b, q, o, u, v, used


_ROWS = jax.lax.ScatterDimensionNumbers(update_window_dims=(1,), inserted_window_dims=(),
                                        scatter_dims_to_operand_dims=(0,))


def _add_rows(s, b, val, width, height, block, pad):
    """s (padded image, flat) += val (C, B * B), one B-pixel window per block row: a scatter with
    B times fewer indices than pixel by pixel. Unused pixels carry 0."""
    start = block_rows(b, width, height, block, pad).reshape(-1, 1)
    return jax.lax.scatter_add(s, start, _computed(val).reshape(-1, block), _ROWS, mode="drop")


def _image(s, width, height, pad):
    wp, hp = padded_size(width, height, pad)
    return s.reshape(hp, wp)[:height, :width].reshape(-1)


def _padded(img, width, height, pad):
    wp, hp = padded_size(width, height, pad)
    return jnp.pad(img.reshape(height, width), ((0, hp - height), (0, wp - width))).reshape(-1)


def _accumulate(poly, k, orient, lay, width, height, block, size, cutoff, pad):
    """Sum of the faces' log 'not covered' per pixel of the image padded for blocks of pad px (flat)."""
    wp, hp = padded_size(width, height, pad)

    def body(first, s):
        b, q, o, u, v, used = _chunk_inputs(poly, orient, lay, first, size, width, height, block)
        val, _, _ = _values(q, o, u, v, used, k, cutoff)
        return _add_rows(s, b, val, width, height, block, pad)

    return fold_chunks(lay, size, body, jnp.zeros((wp * hp,), poly.dtype))


@functools.partial(jax.custom_vjp, nondiff_argnums=(4, 5, 6, 7, 8))
def coverage(poly, k, orient, lays, width: int, height: int, blocks, sizes, cutoff: float):
    """poly (F, 4, 2), k () sharpness, orient (F,) -> (H * W,) coverage in [0, 1].

    lays: (forward, backward) Layouts of the same faces and margin in blocks of blocks =
    (forward, backward) px, visited sizes = (forward, backward) pairs per chunk. The passes
    may use different blocks (measured here: 8 px blocks fastest forward, 4 px backward).
    """
    pad = max(blocks)
    return _image(-jnp.expm1(_accumulate(poly, k, orient, lays[0], width, height, blocks[0], sizes[0], cutoff, pad)),
                  width, height, pad)


def _fwd(poly, k, orient, lays, width, height, blocks, sizes, cutoff):
    pad = max(blocks)
    s = _accumulate(poly, k, orient, lays[0], width, height, blocks[0], sizes[0], cutoff, pad)
    return _image(-jnp.expm1(s), width, height, pad), (poly, k, orient, lays[1], s)


def _bwd(width, height, blocks, sizes, cutoff, res, g):
    poly, k, orient, lay, s = res
    pad, block, size = max(blocks), blocks[1], sizes[1]
    gs_pix = -_padded(g, width, height, pad) * jnp.exp(s)  # dA/ds = -exp(s)
    wp, hp = padded_size(width, height, pad)
    nf = poly.shape[0]

    def body(first, carry):
        gpoly, gk = carry
        b, q, o, u, v, used = _chunk_inputs(poly, orient, lay, first, size, width, height, block)
        idx = jnp.minimum(v.astype(jnp.int32) * wp + u.astype(jnp.int32), wp * hp - 1)
        gs = jnp.where(used, gs_pix[idx], 0.0)  # gather: the scatter's transpose
        sd, near = signed_distance(q, o, u, v)
        x = -k * sd
        tau, dtau = _taper(x, cutoff)
        dval_dx = gs * (tau * jax.nn.sigmoid(-x) + dtau * jax.nn.log_sigmoid(x))
        # The per-(pair, pixel) terms are computed once and stored before the sums below
        # consume them (XLA would otherwise recompute the distance code in each of them).
        gx, gy, gkk, t, j = _computed(edge_terms(near, dval_dx * -k) + (dval_dx * -sd, near.t, near.j))
        gk = gk + sum_rows(gkk)  # (C,), summed after the loop
        gq = vertex_sums((gx, gy), t, j)  # (C, 8)
        return gpoly.at[b.face].add(_computed(gq)), gk

    init = (jnp.zeros((nf, 8), poly.dtype), jnp.zeros((size,), k.dtype))
    gpoly, gk = fold_chunks(lay, size, body, init)
    return gpoly.reshape(poly.shape), jnp.sum(gk), None, None


coverage.defvjp(_fwd, _bwd)


def coverage_autodiff(poly, k, orient, lay: Layout, width: int, height: int, block: int, size: int,
                      cutoff: float, capacity: int):
    """Same values (pairs beyond `capacity` dropped), differentiated by XLA's reverse mode."""
    wp, hp = padded_size(width, height, block)
    n_chunks = -(-capacity // size)

    def body(s, first):
        b, q, o, u, v, used = _chunk_inputs(poly, orient, lay, first, size, width, height, block)
        val, _, _ = _values(q, o, u, v, used, k, cutoff)
        return _add_rows(s, b, val, width, height, block, block), None

    firsts = jnp.arange(n_chunks, dtype=jnp.int32) * size
    s, _ = jax.lax.scan(body, jnp.zeros((wp * hp,), poly.dtype), firsts)
    return _image(-jnp.expm1(s), width, height, block)
