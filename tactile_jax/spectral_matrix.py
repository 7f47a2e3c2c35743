"""The 4 x 4 cross-spectral matrix of both probe pairs, cross-pair terms included (DESIGN.md, 2-D slip).

Channel c (x1, x2, y1, y2) weighs a texture mode (kx, ky) by

    w_x(d) = G(kx; d, a) L(ky),    w_y(d) = G(ky; d, a) L(kx),    L(k) = exp(-a^2 k^2 / 6),

so every entry is a line integral over k . v = omega,

    E[S_cd(omega)] = Int Phi(|k|) w_c(k) w_d(k) ds / |v|,

the pair entries of ``joint_model`` and, in addition, the x-y ones: both pairs
hear the modes with |kx| and |ky| below about 1/a, and at slow slip those fill
the lowest bins (x1-y1 coherence up to 0.99 there on the simulator).

This module serves bounds (``crb.whittle_crb``), not fits: the integral is a
plain Riemann sum over arc length s on a uniform grid (``n_s`` points over
|s| < 25 / (2 d1) + 9 / a), which costs no care about kinks; with the default
``n_s`` it puts 100 points across the window's width sqrt(3) / a at a = 1 mm
(raise ``n_s`` in proportion for contacts above about 3 mm), and the pair
entries agree with ``joint_model``'s Gauss-Legendre ones to 2e-3 in log. The spectra are point
values at ``omega`` (no spectral window): the ideal estimator's.
"""

from __future__ import annotations

import jax.numpy as jnp

from .joint_model import N_FIXED_PARAMS, _log_phi
from .r_curve import log_g

__all__ = ["CHANNEL_ORDER", "spectral_matrix"]

#: channel order of the matrix: the recording's (x1, x2, y1, y2)
CHANNEL_ORDER = ("x1", "x2", "y1", "y2")


def spectral_matrix(theta, omega, depths, log_k_knots, log_noise, *, n_s: int = 6001):
    """Expected spectral matrix (F, 4, 4) at ``omega`` (F,) rad/s, real and symmetric (co-located probes).

    theta: ``joint_model`` parameters (log speeds m/s, log a m, log gains, log ay,
    log noise (unused), log Phi knots). depths: (d1, d2) m. log_k_knots: the
    texture knots, log rad/m. log_noise: (4,) log white-noise PSD of each
    channel, added on the diagonal, in the units of the model's spectra.
    """
    vx, vy, a = jnp.exp(theta[0]), jnp.exp(theta[1]), jnp.exp(theta[2])
    log_gx, log_gy, log_ay = theta[3], theta[4], theta[5]
    d1, d2 = depths[0], depths[1]
    speed = jnp.hypot(vx, vy)
    ux, uy = vx / speed, vy / speed
    s_max = 25.0 / (2.0 * d1) + 9.0 / a
    s = jnp.linspace(-s_max, s_max, n_s)
    ds = s[1] - s[0]
    kx = omega[:, None] / speed * ux - s[None] * uy
    ky = omega[:, None] / speed * uy + s[None] * ux
    half_phi = 0.5 * _log_phi(kx, ky, log_k_knots, theta[N_FIXED_PARAMS:])
    lx, ly = -jnp.square(a * kx) / 6.0, -jnp.square(a * ky) / 6.0
    log_w = jnp.stack([log_g(kx, d1, a) + ly,
                       log_g(kx, d2, a) + ly + log_gx,
                       log_g(ky, d1, a) + lx + 0.5 * log_ay,
                       log_g(ky, d2, a) + lx + 0.5 * log_ay + log_gy]) + half_phi[None]      # (4, F, S)
    w = jnp.exp(log_w)
    s_cd = jnp.einsum("cfs,dfs->fcd", w, w) * ds / speed
    return s_cd + jnp.eye(4)[None] * jnp.exp(jnp.asarray(log_noise))[None, :, None]
