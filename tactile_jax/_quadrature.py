"""Fixed-order Gauss rules as static numpy tables (usable inside jit/vmap/grad)."""

from __future__ import annotations

from functools import lru_cache

import jax.numpy as jnp
import numpy as np


@lru_cache(maxsize=None)
def gauss_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights of the n-point Gauss-Legendre rule on [-1, 1]."""
    return np.polynomial.legendre.leggauss(n)


@lru_cache(maxsize=None)
def gauss_chebyshev_u(n: int) -> tuple[np.ndarray, np.ndarray]:
    """n-point rule for Int_{-1}^{1} sqrt(1 - u^2) f(u) du (Chebyshev, second kind)."""
    i = np.arange(1, n + 1)
    theta = i * np.pi / (n + 1)
    return np.cos(theta), np.pi / (n + 1) * np.sin(theta) ** 2


def composite_legendre(lo, hi, n: int, panels: int):
    """Nodes and weights of ``panels`` equal Gauss-Legendre panels on [lo, hi].

    ``lo`` and ``hi`` may be traced arrays of any (broadcastable) shape; the
    rule's axis is appended last, shape (..., panels * n).
    """
    x, w = gauss_legendre(n)
    edges = np.linspace(0.0, 1.0, panels + 1)
    t = (edges[:-1, None] + 0.5 * (x[None, :] + 1.0) / panels).ravel()   # in [0, 1]
    wt = np.tile(w, panels) / (2.0 * panels)
    lo = jnp.asarray(lo)[..., None]
    span = jnp.asarray(hi)[..., None] - lo
    dtype = jnp.result_type(lo, span, float)
    return lo + span * t.astype(dtype), span * wt.astype(dtype)
