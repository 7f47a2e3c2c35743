"""Contact windows: the paper's Gaussian (Eq. 24-25) and the Hertz disk (Eq. 12).

A window w(x, y; a) multiplies the texture under a contact of radius ``a``
(metres); w(0, 0) = 1. The *projection* of a window along y is what an
x-probe integrates; the *line response* H(kx, ky; d, a) of an x-probe at
depth d to a surface mode exp(i (kx x + ky y)) is

    H = Int K_d(x) exp(i kx x) Int w(x, y) exp(i ky y) dy dx     (metres)

with K_d the Poisson kernel of ``decay``. For the Gaussian it separates as
G(kx; d, a) * L(ky; a) (see ``r_curve.log_g``); for Hertz it is computed by
quadrature here.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._quadrature import composite_legendre, gauss_chebyshev_u

__all__ = [
    "WINDOWS",
    "gaussian_window",
    "hertz_window",
    "gaussian_window_spectrum",
    "gaussian_projection",
    "hertz_projection",
    "hertz_line_response",
]

WINDOWS = ("gaussian", "hertz")


def gaussian_window(x, y, a):
    """Paper Eq. 24: w = exp(-3 (x^2 + y^2) / (2 a^2)); x, y, a in metres."""
    return jnp.exp(-1.5 * (jnp.square(x) + jnp.square(y)) / jnp.square(a))


def hertz_window(x, y, a):
    """Paper Eq. 12: w = sqrt(1 - r^2 / a^2) on the contact disk, 0 outside; metres."""
    return jnp.sqrt(jnp.clip(1.0 - (jnp.square(x) + jnp.square(y)) / jnp.square(a), 0.0, None))


def gaussian_window_spectrum(k, a):
    """Paper Eq. 25 normalised to 1 at k = 0: W_x(k) = exp(-a^2 k^2 / 6); k in rad/m, a in m."""
    return jnp.exp(-jnp.square(a * k) / 6.0)


def gaussian_projection(ky, a):
    """Int exp(-3 y^2 / (2 a^2)) exp(i ky y) dy = a sqrt(2 pi / 3) W(ky), metres."""
    return a * float(np.sqrt(2.0 * np.pi / 3.0)) * gaussian_window_spectrum(ky, a)


def hertz_projection(x, ky, a, n: int = 64):
    """Int sqrt(1 - (x^2 + y^2)/a^2) exp(i ky y) dy = pi b J1(ky b) / (a ky), b^2 = a^2 - x^2.

    Evaluated with an ``n``-point Gauss-Chebyshev (second kind) rule, exact at
    ky = 0 (pi b^2 / 2a) and accurate while |ky| b is below about n / 2.
    Zero for |x| >= a. x, a in metres, ky in rad/m; result in metres.
    """
    u, w = gauss_chebyshev_u(n)
    dtype = jnp.result_type(x, ky, a, float)
    u, w = u.astype(dtype), w.astype(dtype)
    b2 = jnp.clip(jnp.square(a) - jnp.square(x), 0.0, None)
    b = jnp.sqrt(b2)
    arg = (jnp.asarray(ky) * b)[..., None] * u
    return b2 / a * jnp.sum(w * jnp.cos(arg), axis=-1)


def hertz_line_response(kx, ky, depth, a, *, n: int = 24, panels: int = 16, n_y: int = 64):
    """Line response H(kx, ky; d, a) of an x-probe under the Hertz window, metres.

    H = 2 Int_0^a K_d(x) cos(kx x) P(x, ky) dx with P the ``hertz_projection``;
    the substitution x = d tan(theta) absorbs the Poisson kernel's peak, and
    ``panels`` x ``n`` Gauss-Legendre nodes cover theta in [0, atan(a/d)]
    (accurate to about 1e-12 relative while |kx| a < 100). Real and even in
    kx and ky; it changes sign at large |kx| a (the disk's edge).
    """
    kx, ky, depth, a = jnp.broadcast_arrays(*(jnp.asarray(v) for v in (kx, ky, depth, a)))
    theta, wt = composite_legendre(jnp.zeros_like(a), jnp.arctan(a / depth), n, panels)
    x = depth[..., None] * jnp.tan(theta)
    proj = hertz_projection(x, ky[..., None], a[..., None], n=n_y)
    return (2.0 / jnp.pi) * jnp.sum(wt * jnp.cos(kx[..., None] * x) * proj, axis=-1)
