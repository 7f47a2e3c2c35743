"""The 4 x 4 spectral matrix of the probes as line integrals over the k-plane, with a cheap exact Jacobian.

A texture of power spectrum Phi(k) = Phi(|k|) A(theta) slides at (vx, vy); the
mode k rings at omega = k . v. The angular factor of a directional texture is

    log A(theta) = p cos 2 theta + q sin 2 theta + p4 cos 4 theta + q4 sin 4 theta,

the log-Fourier series of an axial lobe to its fourth harmonic: positive for
every coefficient, smooth, 1 at zero. The fourth harmonic sets the lobe's
slope at the two axes independently (2 q + 4 q4 at theta = 0, -2 q + 4 q4 at
90 deg), which each pair's line reads across its probe and which biases the
minor speed where it is wrong: a brushed surface's lobe (geometric anisotropy,
log A = sum_n 3 rho^n cos 2n theta / n where k l >> 1, rho = (aspect - 1) / (aspect + 1)) has
a fourth harmonic a quarter of its second at aspect 3 (``docs/model.md``).

Channel x(d) weighs Phi by G(kx; d, a) L(ky), channel
y(d) by G(ky; d, a) L(kx), with G the normalised window-depth response
(``r_curve.log_g``) and L(q) = exp(-a^2 q^2 / 6) the Gaussian window's
spectrum across the probe. Every entry of the spectral matrix of
(x1, x2, y1, y2) is a line integral over k . v = omega,

    S_ij(omega) = Int Phi(|k|) c_i(k) c_j(k) du / |v_u|,

evaluated here on ONE set of Gauss-Legendre nodes per omega, shared by the ten
entries: the discrete sums then keep the matrix's Gram structure, so that the
conditioned spectra of the cross-pair chain (small differences of these
entries where the pairs are coherent) are as accurate as the rule itself.
The line is parametrised by ky when |vx| >= |vy| and by kx otherwise, over
the union of both pairs' ranges (where their factors are above exp(-25) of
their reach), in six panels split at the kinks of G (kx = 0, ky = 0) and where
either pair's window factor ends.

``log_matrix`` carries its own JVP: the node positions and channel factors
depend on (vx, vy, a) only, so three forward tangents go through them (one
``jax.jvp`` each: a ``jax.linearize`` mapped over them ran 2x slower inside the
Jacobian, a vmapped ``jax.jvp`` 1.6-2x; under the Hertz window all three take
their tangents from one table lookup, ``hertz.hertz_lookup``); the texture
knots enter through the spline's basis at the nodes, a fixed linear map, and A's coefficients through its
closed-form derivatives. A
Jacobian over all parameters then costs about four evaluations instead of one
per parameter.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from .._numerics import any_in_batch, tiny
from .._quadrature import gauss_legendre
from .r_curve import log_g
from . import hertz as hertz_mod
from .spline import log_phi_at

__all__ = ["ENTRIES", "N_NODES", "log_matrix", "log_angular", "hertz_kappa"]

#: (channel, channel) of each entry of ``log_matrix``; channels (x1, x2, y1, y2)
ENTRIES = ((0, 0), (0, 1), (1, 1), (2, 2), (2, 3), (3, 3), (0, 2), (0, 3), (1, 2), (1, 3))
#: Gauss-Legendre nodes per panel (six panels per line); a program with the Hertz window has more (its response
#: oscillates across the probe): with 16, the entries are within 1e-3 of a 96-node rule relative to their power
#: above a floor 50 dB below each pair's peak (with 12, 3e-2: ``tests/test_joint.py``)
N_NODES = 12
N_NODES_HERTZ = 16
#: the Hertz window's line response is followed to |k| a = HERTZ_REACH across the probe
HERTZ_REACH = 24.0
_LOG_EDGE = 25.0        # a factor's reach: where it has fallen exp(-25) below its peak


def _nodes(p, omega, d1, d2, window=None, hertz_coef=None, lookup=None):
    """Nodes of the line k . v = omega for (vx, vy, a) = p at omega (F,) >= 0, rad/s.

    window: the contact window, 0 Gaussian or 1 Hertz (a traced scalar); hertz_coef: the Hertz
    table's coefficients (``hertz.hertz_table().coef``), or None for a Gaussian-only program;
    lookup: the Hertz table's values and partials at these nodes (``_hertz_lookup``; None: looked up here).

    Returns log|k| (F, N), the log quadrature weights including 1 / |v_u| (F, N; -2e4 where a
    panel is empty), the four channels' factors as a log envelope and a signed mantissa
    (factor = mantissa exp(envelope); (4, F, N) each; the Gaussian window's mantissa is 1), and
    cos 2 theta, sin 2 theta of the nodes' direction (F, N) each.
    """
    a = p[2]
    only_hertz, only_gauss = _which(window, hertz_coef)
    log_k, log_w, kx, ky, cos2, sin2 = _line(p, omega, d1, window, hertz_coef)
    lx, ly = -jnp.square(a * kx) / 6.0, -jnp.square(a * ky) / 6.0
    # one log_g over the four channels (written four times it compiles four times)
    k_s = jnp.stack([kx, kx, ky, ky])
    depth = jnp.stack([d1, d2, d1, d2])[:, None, None]
    if not only_hertz:
        g_env = log_g(k_s, depth, a) + jnp.stack([ly, ly, lx, lx])
        if only_gauss:
            return log_k, log_w, g_env, jnp.ones_like(g_env), cos2, sin2
    h_env, h_mant = hertz_mod.hertz_factors(*_hertz_args(kx, ky, d1, d2, a, hertz_coef), lookup=lookup)
    h_env, h_mant = h_env.astype(kx.dtype), h_mant.astype(kx.dtype)
    if only_hertz:
        return log_k, log_w, h_env, h_mant, cos2, sin2
    use = window == 1
    return log_k, log_w, jnp.where(use, h_env, g_env), jnp.where(use, h_mant, 1.0), cos2, sin2


def hertz_kappa(p, omega, d1):
    """The largest |kx| a, |ky| a of the line's nodes for (vx, vy, a) = p at omega (F,) under the Hertz window: the
    corner of the table its lookups read (``hertz.corner``)."""
    kx, ky = _line(p, omega, d1, 1, jnp.zeros((1, 1)))[2:4]          # (``_line`` asks only whether there is a table)
    return jnp.max(jnp.maximum(jnp.abs(kx), jnp.abs(ky))) * p[2]


def _which(window, hertz_coef):
    """(only the Hertz window, only the Gaussian window): a window given as a Python number is a static choice,
    and only that window's factors are computed."""
    hertz = hertz_coef is not None
    static = window is None or isinstance(window, (int, float))
    return hertz and static and window == 1, not hertz or (static and window != 1)


def _hertz_args(kx, ky, d1, d2, a, hertz_coef):
    """The four channels' arguments of ``hertz.hertz_factors`` / ``hertz.hertz_lookup`` at nodes (kx, ky)."""
    table = hertz_mod.table_of(hertz_coef)
    return (jnp.stack([kx, kx, ky, ky]), jnp.stack([ky, ky, kx, kx]), jnp.stack([d1, d2]), a, table,
            (0, 1, 0, 1))


def _hertz_lookup(p, omega, d1, d2, window, hertz_coef):
    """The Hertz table's values and partials at the nodes of ``_nodes`` (one lookup, constants for tangents)."""
    kx, ky = _line(p, omega, d1, window, hertz_coef)[2:4]
    return hertz_mod.hertz_lookup(*_hertz_args(kx, ky, d1, d2, p[2], hertz_coef))


def _line(p, omega, d1, window, hertz_coef):
    """The line's nodes (``_nodes``): log|k|, log weights, kx, ky, cos 2 theta, sin 2 theta, (F, N) each."""
    vx, vy, a = p[0], p[1], p[2]
    hertz = hertz_coef is not None
    only_hertz, only_gauss = _which(window, hertz_coef)
    k_g = _LOG_EDGE / (2.0 * d1)
    # the window's reach across a probe: the Gaussian's exp(-25); the Hertz disk's spectrum falls only as
    # (k a)^-2 in amplitude, and its line response is followed to HERTZ_REACH / a
    k_gauss, k_hertz = (3.0 * _LOG_EDGE) ** 0.5 / a, HERTZ_REACH / a
    k_l = k_hertz if only_hertz else (k_gauss if only_gauss else jnp.where(window == 1, k_hertz, k_gauss))
    by_ky = vx >= vy
    v_u = jnp.where(by_ky, vx, vy)
    v_o = jnp.where(by_ky, vy, vx)
    has_o = v_o > 0
    safe = jnp.where(has_o, v_o, 1.0)

    def reach(limit):       # u with |(omega - u v_o) / v_u| <= limit (every u when v_o = 0)
        return (jnp.where(has_o, (omega - limit * v_u) / safe, -jnp.inf),
                jnp.where(has_o, (omega + limit * v_u) / safe, jnp.inf))

    lo_a, hi_a = reach(k_g)                 # the pair sensitive to the solved component
    lo_a, hi_a = jnp.maximum(lo_a, -k_l), jnp.minimum(hi_a, k_l)
    lo_b, hi_b = reach(k_l)                 # the pair sensitive to u
    lo_b, hi_b = jnp.maximum(lo_b, -k_g), jnp.minimum(hi_b, k_g)
    lo, hi = jnp.minimum(lo_a, lo_b), jnp.maximum(hi_a, hi_b)
    hi = jnp.maximum(hi, lo)
    inner = [jnp.zeros_like(omega), jnp.where(has_o, omega / safe, jnp.inf), jnp.full_like(omega, -k_l),
             jnp.full_like(omega, k_l), jnp.where(has_o, (omega - k_l * v_u) / safe, -jnp.inf)]
    cuts = jnp.sort(jnp.stack([lo] + [jnp.clip(c, lo, hi) for c in inner] + [hi]), axis=0)     # (7, F)
    x, w = (jnp.asarray(t, omega.dtype) for t in gauss_legendre(N_NODES_HERTZ if hertz else N_NODES))
    half = 0.5 * (cuts[1:] - cuts[:-1])                                                      # (6, F)
    mid = 0.5 * (cuts[1:] + cuts[:-1])
    u = jnp.moveaxis(mid[..., None] + half[..., None] * x, 0, 1).reshape(omega.shape[0], -1)    # (F, N)
    wt = jnp.moveaxis(half[..., None] * w, 0, 1).reshape(omega.shape[0], -1)
    solved = (omega[:, None] - u * v_o) / v_u
    kx = jnp.where(by_ky, solved, u)
    ky = jnp.where(by_ky, u, solved)
    log_w = jnp.where(wt <= 0, -2e4, jnp.log(jnp.clip(wt, tiny(wt), None)) - jnp.log(v_u))
    k2 = jnp.square(kx) + jnp.square(ky)
    log_k = 0.5 * jnp.log(k2 + tiny(kx))
    # the direction of |k| < 1 rad/m (wavelengths of metres) is irrelevant: the floor keeps its tangents finite
    k2_floor = jnp.maximum(k2, 1.0)
    cos2, sin2 = (jnp.square(kx) - jnp.square(ky)) / k2_floor, 2.0 * kx * ky / k2_floor
    return log_k, log_w, kx, ky, cos2, sin2


def log_angular(cos2, sin2, aniso):
    """log A(theta) of the module at directions given by cos 2 theta, sin 2 theta; aniso = (p, q, p4, q4).

    Returns log A, its derivatives with respect to cos 2 theta and sin 2 theta (same shape), and with
    respect to the four coefficients (4, ...)."""
    p, q, p4, q4 = aniso[0], aniso[1], aniso[2], aniso[3]
    cos4, sin4 = cos2 * cos2 - sin2 * sin2, 2.0 * sin2 * cos2
    log_a = p * cos2 + q * sin2 + p4 * cos4 + q4 * sin4
    d_c = p + 2.0 * (p4 * cos2 + q4 * sin2)
    d_s = q + 2.0 * (q4 * cos2 - p4 * sin2)
    return log_a, d_c, d_s, jnp.stack([cos2, sin2, cos4, sin4])


def _entries(base, env, mant):
    """(10, F, N) log envelopes and signed mantissas of the entries' integrands at the nodes."""
    return (jnp.stack([base + env[i] + env[j] for i, j in ENTRIES]),
            jnp.stack([mant[i] * mant[j] for i, j in ENTRIES]))


def _signed_sum(terms, mant):
    """sum over the last axis of mant e^terms as (log of its magnitude scale ``top``, relative weights
    e^(terms - top), the sum relative to e^top)."""
    top = jnp.max(terms, axis=-1)
    weight = jnp.exp(terms - top[..., None])
    return top, weight, jnp.sum(weight * mant, axis=-1)


def _log_abs(top, total):
    """log|sum| and its sign (+1 where the sum vanishes), floored at -1e4."""
    out = top + jnp.log(jnp.maximum(jnp.abs(total), tiny(total)))
    return jnp.maximum(out, -1e4), jnp.where(total < 0, -1.0, 1.0).astype(total.dtype)


def log_matrix(p, log_phi, aniso, omega, depths, log_k_knots, window=None, hertz_coef=None, p_tangents=True):
    """log|S| and sign of the ten entries (``ENTRIES``) of the spectral matrix at omega (F,) >= 0 rad/s:
    (10, F) each.

    p: (vx, vy, a) in m/s, m/s, m (positive). log_phi: (n,) log texture spectrum at the knots
    ``log_k_knots`` (log rad/m). aniso: (4,) the angular factor's (p, q, p4, q4) (zeros: isotropic).
    depths: (2,) d1, d2 in m. window: 0 Gaussian, 1 Hertz (traced; None: Gaussian); hertz_coef: the
    Hertz table's coefficients (None: a Gaussian-only program). No gains, levels or noise.
    p_tangents: (traced bool) whether the tangents in p are wanted; False gives them as 0, for a caller
    that will not use them (a solver's evaluation of a start it only compares by cost). Under the Hertz
    disk that skips the table's partials and the nodes' tangents, the most of its Jacobian.
    """
    # a window given as a Python number stays static inside the custom_jvp (its arguments are traced): only that
    # window's factors are then computed, in the values as in the tangents
    static = None if not (window is None or isinstance(window, (int, float))) else (1 if window == 1 else 0)
    return _log_matrix(static, p, log_phi, aniso, omega, depths, log_k_knots, window, hertz_coef, p_tangents)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _log_matrix(static, p, log_phi, aniso, omega, depths, log_k_knots, window, hertz_coef, p_tangents):
    window = window if static is None else static
    if _which(window, hertz_coef)[0] and jnp.result_type(p, omega) == jnp.float64:
        return _hertz_values(p, log_phi, aniso, omega, depths, log_k_knots, hertz_coef)
    log_k, log_w, env, mant, cos2, sin2 = _nodes(p, omega, depths[0], depths[1], window, hertz_coef)
    base = log_phi_at(log_k, log_k_knots, log_phi) + log_angular(cos2, sin2, aniso)[0] + log_w
    top, _, total = _signed_sum(*_entries(base, env, mant))
    return _log_abs(top, total)


def _hertz_values(p, log_phi, aniso, omega, depths, log_k_knots, hertz_coef):
    """``log_matrix``'s values under the Hertz window alone, in float64 (``_raw_nodes``)."""
    log_k, log_w, hn, cos2, sin2 = _raw_nodes(p, omega, depths[0], depths[1], hertz_coef)
    base = log_phi_at(log_k, log_k_knots, log_phi) + log_angular(cos2, sin2, aniso)[0] + log_w
    return _log_abs(*_raw_sum(base, hn)[::2])


def _raw_nodes(p, omega, d1, d2, hertz_coef, lookup=None):
    """``_nodes`` under the Hertz window alone, in float64, with the channels' factors the table's Hn as they are:
    (log_k, log_w, hn (4, F, N), cos2, sin2). An entry is then e^top sum_n e^(base_n - top) Hn_i Hn_j, one
    exponential a node for the ten entries, and no envelope (which keeps the factors' logs finite through the zeros
    of Hn, and float32 above its underflow): the line's nodes keep |k_s| d below 74, so Hn stays above about e^-74
    and products of two far above float64's underflow. lookup: the table's values and partials at these nodes
    (their tangents; None: the values alone, one gather a node for both depths)."""
    log_k, log_w, kx, ky, cos2, sin2 = _line(p, omega, d1, 1, hertz_coef)
    if lookup is None:
        h = hertz_mod.hertz_hn_depths(jnp.stack([kx, ky]), jnp.stack([ky, kx]), jnp.stack([d1, d2]), p[2],
                                      hertz_mod.table_of(hertz_coef))                 # (depth, pair, F, N)
        hn = jnp.stack([h[0, 0], h[1, 0], h[0, 1], h[1, 1]])
    else:
        hn = hertz_mod.hertz_hn(*_hertz_args(kx, ky, d1, d2, p[2], hertz_coef), lookup=lookup)
    return log_k, log_w, hn, cos2, sin2


def _raw_sum(base, hn):
    """The ten entries from ``_raw_nodes``' factors: (top (10, F), weights e^(base - top) (F, N), sums (10, F))."""
    top = jnp.max(base, axis=-1)
    weight = jnp.exp(base - top[:, None])
    total = jnp.stack([jnp.sum(weight * hn[i] * hn[j], axis=-1) for i, j in ENTRIES])
    return jnp.broadcast_to(top, total.shape), weight, total


@_log_matrix.defjvp
def _log_matrix_jvp(static, primals, tangents):
    p, log_phi, aniso, omega, depths, log_k_knots, window, hertz_coef, p_tangents = primals
    window = window if static is None else static
    p_dot, phi_dot, aniso_dot = tangents[0], tangents[1], tangents[2]
    d1, d2 = depths[0], depths[1]
    only_hertz, only_gauss = _which(window, hertz_coef)
    raw = only_hertz and jnp.result_type(p, omega) == jnp.float64

    def nodes_at(q, lookup=None):
        if raw:
            return _raw_nodes(q, omega, d1, d2, hertz_coef, lookup)
        return _nodes(q, omega, d1, d2, window, hertz_coef, lookup)

    def with_tangents():
        # the nodes and their three tangents, one jvp each
        # the Hertz table looked up once, its partials giving every tangent: a lookup per jvp is not merged by XLA
        # inside the solver's loop (17 ms a Jacobian there against 12, benchmarks/hertz_lookup.py's record)
        lookup = None if only_gauss else _hertz_lookup(p, omega, d1, d2, window, hertz_coef)
        fn = lambda q: nodes_at(q, lookup)                                            # noqa: E731
        node_t = [jax.jvp(fn, (p,), (jnp.zeros_like(p).at[i].set(1.0),)) for i in range(3)]
        return node_t[0][0], tuple(jnp.stack(t) for t in zip(*(tan for _, tan in node_t)))

    def without():
        # the values as with_tangents has them, to the last bit (a solver compares the two paths' costs)
        nodes = nodes_at(p, _hertz_lookup(p, omega, d1, d2, window, hertz_coef) if raw else None)
        return nodes, tuple(jnp.zeros((3,) + x.shape, x.dtype) for x in nodes)

    if only_gauss or p_tangents is True:    # the Gaussian window's node tangents cost little beside the rest
        nodes, node_dots = with_tangents()
    else:
        nodes, node_dots = jax.lax.cond(any_in_batch(p_tangents), with_tangents, without)
    if raw:
        (log_k, log_w, mant, cos2, sin2), (d_log_k, d_log_w, d_mant, d_cos2, d_sin2) = nodes, node_dots
    else:
        log_k, log_w, env, mant, cos2, sin2 = nodes
        d_log_k, d_log_w, d_env, d_mant, d_cos2, d_sin2 = node_dots
    # the spline's value and slope in log k at the nodes, and its basis (linear in the knot values)
    spline = lambda lk: log_phi_at(lk, log_k_knots, log_phi, "scan")              # noqa: E731
    phi, dphi = jax.jvp(spline, (log_k,), (jnp.ones_like(log_k),))
    basis = jax.jacfwd(lambda y: log_phi_at(log_k, log_k_knots, y, "scan"))(log_phi)     # (F, N, n)
    log_ang, da_c, da_s, da_coef = log_angular(cos2, sin2, aniso)
    base = phi + log_ang + log_w
    if raw:         # one weight a node for the ten entries; the factors' products carry their signs and sizes
        m = jnp.stack([mant[i] * mant[j] for i, j in ENTRIES])                    # (10, F, N)
        top, weight, total = _raw_sum(base, mant)
    else:
        terms, m = _entries(base, env, mant)                                      # (10, F, N)
        top, weight, total = _signed_sum(terms, m)
    out, out_sign = _log_abs(top, total)
    floor = out > -1e4
    # S = e^top sum w m: d log|S| = sum w (m dT + dm) / sum w m, finite where a factor changes sign
    inv = 1.0 / jnp.where(jnp.abs(total) > 0, total, 1.0)
    wm = weight * m * inv[..., None]                                              # (10, F, N)
    d_base = dphi * d_log_k + d_log_w + da_c * d_cos2 + da_s * d_sin2            # (3, F, N)
    if raw:
        d_terms = d_base[:, None]                                                 # (3, 1, F, N)
    else:
        d_terms = jnp.stack([d_base + d_env[:, i] + d_env[:, j] for i, j in ENTRIES], axis=1)   # (3, 10, F, N)
    d_m = jnp.stack([d_mant[:, i] * mant[j] + mant[i] * d_mant[:, j] for i, j in ENTRIES], axis=1)
    jac_p = jnp.moveaxis(jnp.sum(wm * d_terms + weight * inv[..., None] * d_m, axis=-1), 0, -1)   # (10, F, 3)
    jac_phi = jnp.einsum("efn,fnj->efj", wm, basis)                               # (10, F, n)
    jac_ang = jnp.einsum("efn,cfn->efc", wm, da_coef)                             # (10, F, 4)
    out_dot = (jnp.einsum("efi,i->ef", jac_p, p_dot) + jnp.einsum("efj,j->ef", jac_phi, phi_dot)
               + jnp.einsum("efi,i->ef", jac_ang, aniso_dot))
    return (out, out_sign), (jnp.where(floor, out_dot, 0.0), jnp.zeros_like(out_sign))
