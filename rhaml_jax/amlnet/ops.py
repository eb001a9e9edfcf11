"""Pure convolution kernels of AMLNet, NHWC, in two implementations.

"fast": what runs on XLA's CPU backend at matmul-like speed.  XLA's own depthwise (grouped)
convolution runs at 0.1-0.2 GMAC/s there, several hundred times below a matmul, so
- depthwise convolutions are sums of shifted slices times per-channel weights (XLA fuses
  the whole sum into one loop);
- 1x1 convolutions and the patchify convolutions (stem 4x4/4, downsampling 2x2/2) are
  reshapes + matrix products;
- dense 1xk / kx1 convolutions are im2col matrix products (`im2col_1d`; XLA's own
  convolution was as fast forward, but its weight gradient at 12-24 channels was not), not
  the "taps first" alternative `dense_1d`, kept for the benchmark: one matmul of the input
  with every tap's matrix side by side, then shifted sums; see acn.py.
"reference": the same operations as plain `lax.conv_general_dilated` calls; used by the tests
and by MAC counting (every multiply-accumulate is then a convolution or a matrix product).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
from jax import lax

DN = ("NHWC", "HWIO", "NHWC")


def _pad_axis(x, axis: int, p: int):
    pads = [(0, 0)] * x.ndim
    pads[axis] = (p, p)
    return jnp.pad(x, pads)


def _window(xp, axis: int, start: int, size: int):
    return lax.slice_in_dim(xp, start, start + size, axis=axis)


# ----------------------------------------------------------------------------- depthwise
def _shifted_sum(x, w, axis: int):
    """sum_j window_j(pad(x)) * w[j]: the depthwise 'same' convolution (odd k = w.shape[0])."""
    k, n = w.shape[0], x.shape[axis]
    xp = _pad_axis(x, axis, k // 2)
    out = _window(xp, axis, 0, n) * w[0]
    for j in range(1, k):
        out = out + _window(xp, axis, j, n) * w[j]
    return out


@functools.partial(jax.custom_vjp, nondiff_argnums=(2,))
def _depthwise_1d(x, w, axis: int):
    return _shifted_sum(x, w, axis)


def _depthwise_1d_fwd(x, w, axis):
    return _shifted_sum(x, w, axis), (x, w)


def _depthwise_1d_bwd(axis, res, dy):
    # Written out because XLA's reverse mode of the k shifted slices (pads and adds of
    # slice transposes) measured 27x the forward at the paper's stage-1 shape
    # (experiments/profile_block_grad.py): dx is the same convolution of dy with the kernel
    # flipped, dw[j] the per-channel sum of window_j(pad(x)) * dy.
    x, w = res
    k, n = w.shape[0], x.shape[axis]
    xp = _pad_axis(x, axis, k // 2)
    red = tuple(range(x.ndim - 1))
    dw = jnp.stack([jnp.sum(_window(xp, axis, j, n) * dy, axis=red) for j in range(k)])
    return _shifted_sum(dy, w[::-1], axis), dw.astype(w.dtype)


_depthwise_1d.defvjp(_depthwise_1d_fwd, _depthwise_1d_bwd)


def depthwise_1d(x, w, b=None, axis: int = 2):
    """Depthwise 'same' convolution along `axis` (1 = H, 2 = W); w: (k, C) with k odd, b: (C,)."""
    out = _depthwise_1d(x, w, axis)
    return out if b is None else out + b


def depthwise_2d(x, w, b=None):
    """Depthwise 'same' kxk convolution; w: (kh, kw, C)."""
    kh, kw = w.shape[:2]
    h, wd = x.shape[1:3]
    xp = jnp.pad(x, ((0, 0), (kh // 2, kh // 2), (kw // 2, kw // 2), (0, 0)))
    out = None
    for i in range(kh):
        for j in range(kw):
            t = xp[:, i : i + h, j : j + wd, :] * w[i, j]
            out = t if out is None else out + t
    return out if b is None else out + b


def depthwise_1d_ref(x, w, b=None, axis: int = 2):
    k, c = w.shape
    kern = w.reshape((1, k, 1, c) if axis == 2 else (k, 1, 1, c))
    out = lax.conv_general_dilated(x, kern, (1, 1), "SAME", dimension_numbers=DN, feature_group_count=c)
    return out if b is None else out + b


def depthwise_2d_ref(x, w, b=None):
    kh, kw, c = w.shape
    out = lax.conv_general_dilated(x, w.reshape(kh, kw, 1, c), (1, 1), "SAME", dimension_numbers=DN, feature_group_count=c)
    return out if b is None else out + b


# ----------------------------------------------------------------------------- dense
def pointwise(x, w, b=None):
    """1x1 convolution as a matrix product; w: (C_in, C_out)."""
    # As a 2-D product: with a 4-D einsum, XLA gave the weight gradient's operand a
    # transposed layout and fused GELU's derivative into that transposing copy (a profiler
    # trace showed it); 2-D, the paper's stage-1 block forward + backward went from 448 to
    # 369 ms (experiments/profile_block_grad.py).
    out = (x.reshape(-1, x.shape[-1]) @ w).reshape(*x.shape[:-1], w.shape[-1])
    return out if b is None else out + b


def pointwise_ref(x, w, b=None):
    out = lax.conv_general_dilated(x, w[None, None], (1, 1), "VALID", dimension_numbers=DN)
    return out if b is None else out + b


def gelu_ref(h):
    """Exact GELU as jax writes it (through erfc); `gelu` is the fast form."""
    return jax.nn.gelu(h, approximate=False)


def mlp_ref(x, w1, b1, w2, b2):
    """InceptionNeXt's MLP: 1x1 conv, exact (erf) GELU, 1x1 conv, as lax convolutions."""
    return pointwise_ref(gelu_ref(pointwise_ref(x, w1, b1)), w2, b2)


def mlp(x, w1, b1, w2, b2):
    """`mlp_ref` as two matrix products around `gelu`."""
    return pointwise(gelu(pointwise(x, w1, b1)), w2, b2)


_SQRT_HALF = 0.5**0.5
_INV_SQRT_2PI = (2.0 * math.pi) ** -0.5


def _normal_cdf(h):
    return 0.5 + 0.5 * lax.erf(h * _SQRT_HALF)


@jax.custom_jvp
def gelu(h):
    """Exact GELU, h Phi(h), equal to jax.nn.gelu(h, approximate=False) within float32 rounding.

    jax.nn.gelu's exact form goes through erfc, which XLA's CPU backend lowers to two
    exponential-and-select passes, and its derivative through them again; this one is one
    erf pass forward and one erf + exp pass backward (Phi + h phi)."""
    return h * _normal_cdf(h)


@gelu.defjvp
def _gelu_jvp(primals, tangents):
    (h,), (t,) = primals, tangents
    cdf = _normal_cdf(h)
    return h * cdf, t * (cdf + h * jnp.exp(-0.5 * h * h) * _INV_SQRT_2PI)


def patchify(x, w, b=None):
    """Non-overlapping sxs convolution with stride s (stem, downsampling); w: (s, s, C_in, C_out)."""
    s = w.shape[0]
    bsz, h, wd, c = x.shape
    p = x.reshape(bsz, h // s, s, wd // s, s, c).transpose(0, 1, 3, 2, 4, 5).reshape(bsz, h // s, wd // s, s * s * c)
    out = jnp.einsum("bhwk,kd->bhwd", p, w.reshape(s * s * c, -1))
    return out if b is None else out + b


def patchify_ref(x, w, b=None):
    s = w.shape[0]
    out = lax.conv_general_dilated(x, w, (s, s), "VALID", dimension_numbers=DN)
    return out if b is None else out + b


def conv_ref(x, w, b=None, stride: int = 1):
    """Dense 'same'-padded kxk convolution (FrontNet); w: (kh, kw, C_in, C_out)."""
    kh, kw = w.shape[:2]
    pad = ((kh // 2, kh // 2), (kw // 2, kw // 2))
    out = lax.conv_general_dilated(x, w, (stride, stride), pad, dimension_numbers=DN)
    return out if b is None else out + b


def dense_1d_ref(x, w, b=None, axis: int = 2):
    """Dense 'same' 1xk (axis=2) or kx1 (axis=1) convolution; w: (k, C_in, C_out)."""
    kern = w[None] if axis == 2 else w[:, None]
    out = lax.conv_general_dilated(x, kern, (1, 1), "SAME", dimension_numbers=DN)
    return out if b is None else out + b


def im2col_1d(x, k: int, axis: int):
    """(B, H, W, C) -> (B, H, W, k C): the k 'same'-padded windows along `axis` side by side,
    window j in channels [j C, (j + 1) C); times a (k C, C_out) matrix it is a 1xk / kx1
    convolution."""
    n = x.shape[axis]
    xp = _pad_axis(x, axis, k // 2)
    return jnp.concatenate([_window(xp, axis, j, n) for j in range(k)], axis=-1)


def dense_1d(x, w, b=None, axis: int = 2):
    """Dense 'same' 1xk / kx1 convolution, taps first (see module docstring)."""
    k, cin, cout = w.shape
    z = jnp.einsum("bhwc,cd->bhwd", x, w.transpose(1, 0, 2).reshape(cin, k * cout))
    return shifted_tap_sum(z, k, cout, axis) if b is None else shifted_tap_sum(z, k, cout, axis) + b


def shifted_tap_sum(z, k: int, cout: int, axis: int, offset: int = 0):
    """sum_j z[..., (offset + j) * cout : (offset + j + 1) * cout] shifted by j - k//2 along
    `axis` with zeros outside: the second half of a taps-first 1xk / kx1 convolution."""
    p = k // 2
    n = z.shape[axis]
    zp = _pad_axis(z, axis, p)
    out = None
    for j in range(k):
        c0 = (offset + j) * cout
        t = lax.slice_in_dim(lax.slice_in_dim(zp, c0, c0 + cout, axis=3), j, j + n, axis=axis)
        out = t if out is None else out + t
    return out
