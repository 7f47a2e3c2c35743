"""The R curve: ratio of deep to shallow probe amplitude spectra (paper Eq. 23).

With slip speed v along a probe's sensitive axis, a temporal frequency omega
maps to the spatial frequency alpha = omega / |v| (rad/m) and

    R(alpha; a) = G(alpha; d2, a) / G(alpha; d1, a),
    G(alpha; d, a) = Int W(k - alpha; a) exp(-|k| d) dk / Int W(k; a) dk.

G is normalised so that G -> exp(-|alpha| d) as a -> infinity (Eq. 5) and
R -> d1 / d2 as a -> 0. Everything here returns logarithms: R spans
hundreds of decades over the band (exp(-alpha (d2 - d1))).

- ``log_g`` / ``log_r_exact``: closed form for the Gaussian window (Eq. 24-25),
  evaluated with erfcx and logaddexp, finite for alpha up to 1e8 rad/m and
  a from 1 um to 1 m in float32 and float64.
- ``log_r_rough``: the paper's Eq. 26 (large-alpha asymptote), corrected as in docs/model.md.
- ``log_g_quadrature``: Gauss-Legendre reference, used only to check the two.
- ``log_r_hertz``: the Hertz window (Eq. 12) for a 1-D texture along the slip.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import erfc, erfcx, logsumexp

from .._quadrature import composite_legendre
from .window import hertz_line_response

__all__ = [
    "log_g",
    "log_r_exact",
    "log_r_rough",
    "log_g_quadrature",
    "log_r_quadrature",
    "log_r_hertz",
]

# python floats: weakly typed, so float32 inputs stay float32
_SQRT_3_2 = float(np.sqrt(1.5))
_SQRT_6 = float(np.sqrt(6.0))
_SQRT_PI = float(np.sqrt(np.pi))


def _erfcx(z):
    """erfcx(z) = exp(z^2) erfc(z) for z >= 0.

    jax.scipy.special.erfcx (jax 0.10) returns 0 on a narrow band of z
    (about 26.54-26.64 in float64, 9.19-9.42 in float32), so above a
    dtype-dependent threshold we use the asymptotic series, which there is
    accurate to machine precision with 8 terms.
    """
    z = jnp.asarray(z)
    threshold = 20.0 if z.dtype == jnp.float64 else 8.0
    big = z >= threshold
    zb = jnp.where(big, z, threshold)
    y = 0.5 / jnp.square(zb)
    s = jnp.ones_like(zb)
    for n in range(15, 0, -2):              # 1 - y (1 - 3 y (1 - 5 y (...)))
        s = 1.0 - n * y * s
    return jnp.where(big, s / (zb * _SQRT_PI), erfcx(jnp.where(big, 0.0, z)))


def _g_parts(alpha, depth, a):
    """Pieces of log G = -(alpha a)^2 / 6 + q + log A (Gaussian window).

    With z = sqrt(3/2) d / a - alpha a / sqrt(6) and z' = sqrt(3/2) d / a + alpha a / sqrt(6):
      z >= 0:  q = 0,   A = (erfcx(z) + erfcx(z')) / 2
      z <  0:  q = z^2, A = (erfc(z) + exp(-z^2) erfcx(z')) / 2
    Every piece stays finite; the large common factor -(alpha a)^2 / 6 is left
    out so that it cancels exactly in a ratio. Returns (z, q, log A).
    """
    alpha = jnp.abs(alpha)
    u = alpha * a / _SQRT_6
    c = _SQRT_3_2 * depth / a
    z = c - u
    zp = c + u
    neg = z < 0
    z_pos = jnp.where(neg, 0.0, z)      # safe branches: no inf/NaN in the unused side or its gradient
    z_neg = jnp.where(neg, z, 0.0)
    log_a_pos = jnp.log(0.5 * (_erfcx(z_pos) + _erfcx(zp)))
    log_a_neg = jnp.log(0.5 * (erfc(z_neg) + jnp.exp(-jnp.square(z_neg)) * _erfcx(zp)))
    q = jnp.where(neg, jnp.square(z_neg), 0.0)
    return z, q, jnp.where(neg, log_a_neg, log_a_pos)


@jax.custom_jvp
def log_g(alpha, depth, a):
    """log G(alpha; d, a) for the Gaussian window, normalised (G -> exp(-|alpha| d) as a -> inf).

    alpha: spatial frequency, rad/m. depth: probe depth d, m. a: contact radius, m.
    With u = |alpha| a / sqrt(6), c = sqrt(3/2) d / a, z = c - u, z' = c + u:
    z >= 0: log G = -u^2 + log((erfcx(z) + erfcx(z')) / 2);
    z <  0: log G = c^2 - 2 c u + log1p(exp(-z^2) (erfcx(z') - erfcx(-z)) / 2)
    (erfc(z) = 2 - exp(-z^2) erfcx(-z)): two erfcx evaluations serve both branches, and
    c^2 - 2 c u = 3 d^2 / (2 a^2) - |alpha| d keeps the two large terms from cancelling.

    Its derivatives are closed-form in the same two erfcx values (d erfcx(z) / dz = 2 z erfcx(z) -
    2 / sqrt(pi)), so a tangent costs a few products: differentiated through the formula, each tangent
    would evaluate the erfcx series again, and the joint model's three node tangents would be the
    largest part of its Jacobian.
    """
    return _log_g_parts(alpha, depth, a)[0]


def _log_g_parts(alpha, depth, a):
    """log G (``log_g``) and its partials in u = |alpha| a / sqrt(6) and c = sqrt(3/2) d / a."""
    alpha = jnp.abs(alpha)
    u = alpha * a / _SQRT_6
    c = _SQRT_3_2 * depth / a
    z = c - u
    zp = c + u
    t = _erfcx(jnp.abs(z))
    tp = _erfcx(zp)
    neg = z < 0
    s = 2.0 / _SQRT_PI
    # z >= 0 (t = erfcx(z))
    t_pos = jnp.where(neg, 1.0, t)
    dt, dtp = 2.0 * z * t_pos - s, 2.0 * zp * tp - s
    inv = 1.0 / (t_pos + tp)
    pos = (-jnp.square(u) + jnp.log(0.5 * (t_pos + tp)), -2.0 * u + (dtp - dt) * inv, (dt + dtp) * inv)
    # z < 0 (t = erfcx(-z)): q = exp(-z^2) (tp - t) / 2
    e = jnp.exp(-jnp.square(jnp.where(neg, z, 0.0)))
    q = 0.5 * e * (tp - t)
    inv_q = 1.0 / (1.0 + q)
    negs = (c * c - 2.0 * c * u + jnp.log1p(q), -2.0 * c + e * tp * (z + zp) * inv_q,
            2.0 * (c - u) + e * (tp * (zp - z) - s) * inv_q)
    return tuple(jnp.where(neg, n_, p_) for n_, p_ in zip(negs, pos))


@log_g.defjvp
def _log_g_jvp(primals, tangents):
    alpha, depth, a = primals
    d_alpha, d_depth, d_a = tangents
    value, g_u, g_c = _log_g_parts(alpha, depth, a)
    du = (jnp.where(alpha < 0, -a, a) * d_alpha + jnp.abs(alpha) * d_a) / _SQRT_6
    dc = _SQRT_3_2 * (d_depth - depth * d_a / a) / a
    return value, jnp.broadcast_to(g_u * du + g_c * dc, jnp.shape(value)).astype(value.dtype)


def log_r_exact(alpha, d1, d2, a):
    """log R(alpha; a) = log G(alpha; d2, a) - log G(alpha; d1, a), the exact R curve (Eq. 23).

    Gaussian window of contact radius ``a`` (m); ``alpha`` in rad/m; depths in m.
    """
    z1, q1, log_a1 = _g_parts(alpha, d1, a)
    z2, q2, log_a2 = _g_parts(alpha, d2, a)
    # q2 - q1 without cancellation when both are z^2 (z2 - z1 = sqrt(3/2) (d2 - d1) / a exactly)
    both = (z1 < 0) & (z2 < 0)
    dq = jnp.where(both, _SQRT_3_2 * (d2 - d1) / a * (z1 + z2), q2 - q1)
    return dq + log_a2 - log_a1


def log_r_rough(alpha, d1, d2, a):
    """Paper Eq. 26 (corrected): log R ~ -|alpha| (d2 - d1) + 3 (d2^2 - d1^2) / (2 a^2).

    The large-alpha asymptote of ``log_r_exact``; good for |alpha| >> 3 d2 / a^2.
    """
    return -jnp.abs(alpha) * (d2 - d1) + 1.5 * (jnp.square(d2) - jnp.square(d1)) / jnp.square(a)


def _half_line_log_integral(c, depth, a, n, panels, span):
    """log Int_0^inf exp(-(k - c)^2 a^2 / 6 - k d) dk by Gauss-Legendre in log space.

    The integration interval is where the (concave quadratic) log-integrand is
    within ``span`` of its maximum; only its ends use the quadratic's vertex.
    """
    beta = jnp.square(a) / 6.0
    mu = c - depth / (2.0 * beta)               # vertex of the log-integrand
    half = jnp.sqrt(span / beta)
    lo = jnp.maximum(mu - half, 0.0)
    # right end: vertex + half if the vertex is inside, else the drop from k = 0 reaches `span`
    m = jnp.abs(mu)
    hi = jnp.where(mu > 0, mu + half, (span / beta) / (m + jnp.sqrt(jnp.square(m) + span / beta)))
    k, w = composite_legendre(lo, hi, n, panels)
    dk = (lo - c)[..., None] + (k - lo[..., None])       # k - c without cancellation
    log_f = -beta[..., None] * jnp.square(dk) - k * depth[..., None]
    return logsumexp(log_f + jnp.log(w), axis=-1)


def log_g_quadrature(alpha, depth, a, *, n: int = 48, panels: int = 4, span: float = 60.0):
    """Reference log G for the Gaussian window by numerical quadrature (checks only).

    Integrates exp(-a^2 (k - alpha)^2 / 6 - |k| d) over k < 0 and k > 0
    separately with composite Gauss-Legendre rules; normalised as ``log_g``.
    """
    alpha, depth, a = jnp.broadcast_arrays(*(jnp.asarray(v) for v in (alpha, depth, a)))
    alpha = jnp.abs(alpha)
    right = _half_line_log_integral(alpha, depth, a, n, panels, span)
    left = _half_line_log_integral(-alpha, depth, a, n, panels, span)
    log_norm = 0.5 * np.log(6.0 * np.pi) - jnp.log(a)   # Int exp(-a^2 k^2 / 6) dk = sqrt(6 pi) / a
    return jnp.logaddexp(right, left) - log_norm


def log_r_quadrature(alpha, d1, d2, a, **kw):
    """Reference log R for the Gaussian window by quadrature (checks only)."""
    return log_g_quadrature(alpha, d2, a, **kw) - log_g_quadrature(alpha, d1, a, **kw)


def log_r_hertz(alpha, d1, d2, a, **kw):
    """log |R| for the Hertz window (Eq. 12) and a texture varying along the slip only.

    R = H(alpha, 0; d2, a) / H(alpha, 0; d1, a) with H the ``hertz_line_response``.
    The disk's edge makes R flatten at large alpha a where the Gaussian model
    keeps falling, and H changes sign there: expect isolated -inf/+inf spikes
    of log |R| at its zeros beyond alpha a ~ 10.
    """
    h2 = hertz_line_response(alpha, 0.0, d2, a, **kw)
    h1 = hertz_line_response(alpha, 0.0, d1, a, **kw)
    return jnp.log(jnp.abs(h2)) - jnp.log(jnp.abs(h1))
