"""Line probes (paper Eq. 7-11): response to a surface mode and directional selectivity."""

from __future__ import annotations

import jax.numpy as jnp

from .r_curve import log_g
from .window import gaussian_projection, hertz_line_response

__all__ = ["line_response", "selectivity"]


def line_response(kx, ky, depth, a, window: str = "gaussian"):
    """Response H(kx, ky; d, a) of an x-probe (the line x = 0) to a surface mode, metres.

    A texture mode exp(i (kx x + ky y)) under the contact window of radius ``a``
    (m) gives the probe at ``depth`` (m) the output H times the mode amplitude.
    For the Gaussian window H = G(kx; d, a) * a sqrt(2 pi / 3) exp(-a^2 ky^2 / 6)
    (separable); for Hertz it is the quadrature of ``window.hertz_line_response``.
    A y-probe's response is ``line_response(ky, kx, ...)``. kx, ky in rad/m.
    """
    if window == "gaussian":
        return jnp.exp(log_g(kx, depth, a)) * gaussian_projection(ky, a)
    if window == "hertz":
        return hertz_line_response(kx, ky, depth, a)
    raise ValueError(f"unknown window {window!r}; expected 'gaussian' or 'hertz'")


def selectivity(theta, k, depth, a, window: str = "gaussian"):
    """Directional selectivity s(theta) = |H(k cos theta, k sin theta)| / |H(k, 0)| (paper Fig. 4).

    Response of an x-probe to a 1-D grating of wavenumber ``k`` (rad/m) whose
    wavevector makes angle ``theta`` (rad) with the x axis (the probe's
    normal), relative to theta = 0. depth, a in metres.
    """
    h = line_response(k * jnp.cos(theta), k * jnp.sin(theta), depth, a, window)
    h0 = line_response(k, jnp.zeros_like(k), depth, a, window)
    return jnp.abs(h) / jnp.abs(h0)
