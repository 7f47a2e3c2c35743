"""The joint model of both probe pairs under 2-D slip through a Gaussian window (DESIGN.md).

A texture of isotropic power spectrum Phi(|k|) slides at (vx, vy); a mode k
rings at omega = k . v. The expected auto- and cross-spectra of a pair are
line integrals over the line k . v = omega in the k-plane,

    E[S_ab(omega)] = Int Phi(|k|) G(k_s; d_a, a) G(k_s; d_b, a) L(k_p; a)^2 dk / |v_u|,

with k_s the pair's sensitive axis, k_p the other one, G the normalised
window-depth response of ``r_curve.log_g`` and L^2 = exp(-a^2 k_p^2 / 3)
the window's spectrum across the probe. The line is parametrised by ky when
|vx| >= |vy| and by kx otherwise (u, with the other component solved from the
line; |v_u| is the speed along the other axis), on Gauss-Legendre nodes over
the interval where the integrand is above exp(-25) of its reach, split at the
kink of |k_s|. Everything is in log space.

The measured quantities are modelled as the estimator sees them: each bin's
expectation is the spectral-window average (``CrossSpectra.kernel``) of the
densities on a half-bin grid, so the resolution bias of steep spectra is
part of the model, not of the error.

Parameters (a flat vector, ``PARAMS`` order): log|vx|, log|vy| (m/s),
log a (m), log gx, log gy (deep/shallow gain ratios of the pairs), log ay
(gain of the y pair's shallow probe relative to x1), log noise (shallow
white noise floor, units^2/Hz) and log Phi at ``n_knots`` log-spaced
wavenumbers (rad/m). Between the knots log Phi is a cubic spline in log k
(``log_phi_at``), constant beyond the end knots.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.scipy.special import logsumexp

from ._numerics import tiny
from ._quadrature import gauss_legendre
from .cross_pair import regression
from .r_curve import log_g

__all__ = ["PARAMS", "N_FIXED_PARAMS", "ModelData", "banded_kernel", "param_names", "log_phi_at", "log_spectra",
           "residuals", "n_prior_residuals", "ratio_slope", "log_conditioned", "chain_model"]

#: names of the leading parameters; ``log_phi_j`` follow for the texture knots
PARAMS = ("log_vx", "log_vy", "log_a", "log_gx", "log_gy", "log_ay", "log_noise")
N_FIXED_PARAMS = len(PARAMS)

_LOG_EDGE = 25.0        # integrand reach: exp(-25) of its peak factor
_N_NODES = 24           # Gauss-Legendre nodes per side of the kink


def param_names(n_knots: int) -> tuple[str, ...]:
    return PARAMS + tuple(f"log_phi_{j}" for j in range(n_knots))


class ModelData(NamedTuple):
    """Everything the residuals need besides the parameters (a pytree of arrays).

    omega: (L,) bin frequencies of the fitted window of bins, rad/s.
    log_s11: (2, L) measured log shallow PSDs of the x and y pairs.
    log_h: (2, L) measured log|S12| / S11 (log AMPLITUDE ratio) of the pairs.
    h_err: (2, L) one-sigma errors of log_h.
    mask_s11, mask_h: (2, L) bins used for each kind of residual.
    s11_weight: scalar, 1 / sd of log PSD residuals (sqrt(K / bin_factor)).
    grid_omega: (F,) half-bin grid (rad/s) on which densities are evaluated.
    kernel: (L, F) spectral-window weights from the grid to each bin.
    log_k_knots: (n_knots,) log wavenumbers of the texture knots.
    depths: (2,) d1, d2 in metres.
    prior_center, prior_inv_sd: (P,) weak Gaussian priors on the internal
        parameters (inverse sd 0: none); they keep directions the data do not
        see (a speed component near 0, a huge contact) finite.
    smooth_inv_sd: inverse sd of the second differences of log Phi between
        knots (a smoothness prior where the data do not reach).
    log_white_grid, log_white_bin: (2, F), (2, L) log |A|^2 of each pair's
        prewhitening filter on the grid and at the bins (zeros without one):
        the estimator averaged S |A|^2 over its window and divided by |A|^2.
    kernel_index, kernel_log_w: optional (L, J) banded form of ``kernel`` (``banded_kernel``):
        the grid points of each bin's spectral window and their log weights. When given, the
        window average gathers J points per bin instead of summing over all F: the model's
        cost no longer grows as L x F (measured: see ``fit``).
    edge_index, centroid_shift: optional (2, L) grid indices of each bin's edges (omega -+ half a
        bin) and (2, L) each pair's realised shallow-power centroid in the bin's window less the one
        the window's weights expect (``pair_fit.centroid_shift``, bins). When given, the model adds
        the first-order realised window term R'_m shift_m to the ratio (``pair_fit``'s, with R the
        ratio of the model's densities, S12 / S11, on the grid).
    log_c22, mask_c22, c22_weight, c22_offset, log_noise_c22: optional; (2, L) measured log
        conditioned deep PSD S22.1 = S22 - |S12|^2 / S11 of each pair (Bendat & Piersol: the deep
        power the shallow probe does not explain), the bins used, 1 / sd of its log (sqrt(K - 1)),
        the mean log of its estimate less that of S11's, which the fitted level absorbs (psi(K - 1) - psi(K)), and
        (2, 2) log white-noise PSDs [shallow, deep] of each pair. When given, the residuals
        include S22.1: under 2-D slip the modes on the line k . v = omega decay at different
        |k|, so the pair is not fully coherent, by an amount set by vx, vy and a
        (``log_conditioned``).
    xy_beta1, xy_beta2, xy_w1, xy_w2, log_xy_c, mask_xy, xy_c_weight, xy_c_offset: optional; the
        measured chain of ``cross_pair`` at the bins: (L, 2) and (L, 3) complex regression coefficients
        of y1 on (x1, x2) and of y2 on (x1, x2, y1), their (L, 2, 2), (L, 3, 3) complex weights, (2, L)
        log residual PSDs, (2, L) the bins used for each block, (2,) 1 / sd of those logs and (2,) their
        offsets (``cross_pair.chain_offsets``). When given, the residuals include the y pair
        conditioned on the x pair; the caller leaves the y pair's own blocks it replaces out of their
        masks (``mask_s11[1]`` for the first block; ``mask_h[1]``, ``mask_c22[1]`` for the second).
    xy_white_grid, xy_white_bin: with the chain and prewhitening, (F,) and (L,) complex conj(A_x) A_y of
        the pairs' filters on the (signed) grid and at the bins: the estimator averaged the x-y spectra
        times this over its window and divided by it at the bin. Where the pairs' filters differ
        (oblique slip) its phase turns across the window; without it, a came out 1.6 % low at 20 deg,
        1.2 cm/s, a 0.9 mm (6 seeds, 50 dB). Needs the banded kernel.
    """

    omega: jax.Array
    log_s11: jax.Array
    log_h: jax.Array
    h_err: jax.Array
    mask_s11: jax.Array
    mask_h: jax.Array
    s11_weight: jax.Array
    grid_omega: jax.Array
    kernel: jax.Array
    log_k_knots: jax.Array
    depths: jax.Array
    prior_center: jax.Array
    prior_inv_sd: jax.Array
    smooth_inv_sd: jax.Array
    log_white_grid: jax.Array
    log_white_bin: jax.Array
    kernel_index: jax.Array | None = None
    kernel_log_w: jax.Array | None = None
    edge_index: jax.Array | None = None
    centroid_shift: jax.Array | None = None
    log_c22: jax.Array | None = None
    mask_c22: jax.Array | None = None
    c22_weight: jax.Array | None = None
    c22_offset: jax.Array | None = None
    log_noise_c22: jax.Array | None = None
    xy_beta1: jax.Array | None = None
    xy_beta2: jax.Array | None = None
    xy_w1: jax.Array | None = None
    xy_w2: jax.Array | None = None
    log_xy_c: jax.Array | None = None
    mask_xy: jax.Array | None = None
    xy_c_weight: jax.Array | None = None
    xy_c_offset: jax.Array | None = None
    xy_white_grid: jax.Array | None = None
    xy_white_bin: jax.Array | None = None


def banded_kernel(kernel):
    """(L, J) grid indices and log weights of the non-zero entries of each row of ``kernel`` (L, F).

    Rows with fewer than J entries are padded with index 0 and log weight -2e4
    (a weight of zero that keeps gradients finite). Numpy, for building ``ModelData``.
    """
    import numpy as np

    kernel = np.asarray(kernel, float)
    nz = kernel > 0
    j = max(int(nz.sum(axis=1).max(initial=0)), 1)
    index = np.zeros((kernel.shape[0], j), np.int32)
    log_w = np.full((kernel.shape[0], j), -2e4)
    for row in range(kernel.shape[0]):
        cols = np.flatnonzero(nz[row])
        index[row, :cols.size] = cols
        log_w[row, :cols.size] = np.log(kernel[row, cols])
    return index, log_w


def _interval_nodes(lo, hi, kink):
    """GL nodes/weights on [lo, kink] and [kink, hi] (kink clipped into [lo, hi]); (..., 2n)."""
    x, w = gauss_legendre(_N_NODES)
    x = jnp.asarray(x)
    w = jnp.asarray(w)
    hi = jnp.maximum(hi, lo)
    kink = jnp.clip(kink, lo, hi)
    def panel(a, b):
        half = 0.5 * (b - a)
        return (0.5 * (a + b))[..., None] + half[..., None] * x, half[..., None] * w
    u1, w1 = panel(lo, kink)
    u2, w2 = panel(kink, hi)
    return jnp.concatenate([u1, u2], -1), jnp.concatenate([w1, w2], -1)


def _range(omega, v_along, v_across, limit):
    """Values of u for which |(omega - u * v_across) / v_along| <= limit (all u if v_across == 0)."""
    safe = jnp.where(v_across > 0, v_across, 1.0)
    lo = jnp.where(v_across > 0, (omega - limit * v_along) / safe, -jnp.inf)
    hi = jnp.where(v_across > 0, (omega + limit * v_along) / safe, jnp.inf)
    return lo, hi


def log_phi_at(log_k, log_k_knots, log_phi):
    """log Phi at ``log_k``: the cubic spline through (log_k_knots, log_phi), constant outside.

    Piecewise-linear interpolation puts a kink at every knot; at the default
    0.3-decade spacing it misses the simulator's texture spectrum by up to 0.09
    in log Phi, which the 2-D line integrals turn into a bias of the smaller
    speed component. This spline (not-a-knot ends, scipy's default; natural
    ends for fewer than 4 knots) misses it by 0.004 inside the bands and 0.02
    near the last knots, with the same parameters. Written here (one dense
    n x n solve for the knot curvatures, n ~ 12) rather than taken from a
    library: jnp has no spline, and this is 25 lines.
    """
    x, y = log_k_knots, log_phi
    n = x.shape[0]
    h = jnp.diff(x)
    slope = jnp.diff(y) / h
    if n > 2:
        rows = jnp.arange(1, n - 1)
        a = jnp.zeros((n, n), y.dtype)
        a = a.at[rows, rows - 1].set(h[:-1]).at[rows, rows].set(2.0 * (h[:-1] + h[1:])).at[rows, rows + 1].set(h[1:])
        if n >= 4:       # not-a-knot: the third derivative is continuous at the second and the last-but-one knot
            a = a.at[0, :3].set(jnp.stack([h[1], -(h[0] + h[1]), h[0]]))
            a = a.at[-1, -3:].set(jnp.stack([h[-1], -(h[-2] + h[-1]), h[-2]]))
        else:            # natural: zero curvature at the ends
            a = a.at[0, 0].set(1.0).at[-1, -1].set(1.0)
        rhs = jnp.concatenate([jnp.zeros(1, y.dtype), 6.0 * jnp.diff(slope), jnp.zeros(1, y.dtype)])
        m = jnp.linalg.solve(a, rhs)
    else:
        m = jnp.zeros_like(y)
    t = jnp.clip(log_k, x[0], x[-1])
    i = jnp.clip(jnp.searchsorted(x, t, side="right") - 1, 0, n - 2)
    hi, x0, x1 = h[i], x[i], x[i + 1]
    m0, m1, y0, y1 = m[i], m[i + 1], y[i], y[i + 1]
    return ((m0 * (x1 - t) ** 3 + m1 * (t - x0) ** 3) / (6.0 * hi)
            + (y0 / hi - m0 * hi / 6.0) * (x1 - t) + (y1 / hi - m1 * hi / 6.0) * (t - x0))


def _log_phi(kx, ky, log_k_knots, log_phi):
    # k = 0 sits on the grid (omega = 0): the floor keeps the log and its gradient finite (``tiny``: a 1e-300
    # floor is 0 in float32 and made the chain's Jacobian NaN there, session 20)
    log_k = 0.5 * jnp.log(jnp.square(kx) + jnp.square(ky) + tiny(kx, ky))
    return log_phi_at(log_k, log_k_knots, log_phi)


def _few_inputs_jvp(f):
    """``f(p, *consts)`` with a JVP pushed through ``f`` along p's few directions only.

    p: a short vector (here (vx, vy, a)); ``consts`` are data and are not differentiated. A Jacobian over
    all P parameters (``jax.jacfwd``, P = 19 with 12 texture knots) would carry P tangents through every
    node of ``f`` (the window-depth responses ``log_g`` above all), though only the texture spline after
    it sees the other P - 3; this rule carries 3, one ``jax.jvp`` each, and maps them onto the P by a sum
    of products. (Mapping them with one ``jax.vmap`` instead made XLA's CPU code 4-10x slower.)
    Measured (session 14, 2-core CPU, oblique 1.5 mm scene, 64 bins): residual Jacobian 5.9 -> 3.6 ms
    (default model) and 49 -> 32 ms (with the chain); a warm fit 2.08 -> 0.76 s and 4.15 -> 1.23 s;
    a cold one 33 -> 32 s and 101 -> 69 s; the fitted values the same to 1e-10.
    """
    @jax.custom_jvp
    def g(p, *consts):
        return f(p, *consts)

    @g.defjvp
    def g_jvp(primals, tangents):
        p, *consts = primals
        p_dot = tangents[0]
        out, total = None, None
        for i in range(p.shape[0]):
            out, t = jax.jvp(lambda q: f(q, *consts), (p,), (jnp.zeros_like(p).at[i].set(1.0),))
            t = jax.tree.map(lambda v: v * p_dot[i], t)
            total = t if total is None else jax.tree.map(jnp.add, total, t)
        return out, total

    return g


@_few_inputs_jvp
def _pair_nodes(p, omega, d1, d2):
    """The nodes of ``_pair_log_densities`` at (vx, vy, a) = p, per branch (2, F, N): u and the solved
    component (rad/m), the log weights (quadrature, window across the probe, 1 / |v_u|; -2e4 where unused)
    and (2, 2, F, N) log G(k_s; d, a) at the two depths."""
    vx, vy, a = p[0], p[1], p[2]
    k_g = _LOG_EDGE / (2.0 * d1)                 # |k_s| where G(k_s; d1)^2 < exp(-25)
    k_l = (3.0 * _LOG_EDGE) ** 0.5 / a           # |k_p| where L^2 < exp(-25)
    by_ky = vx >= vy                             # parametrise by ky (solve kx) or by kx
    v_u = jnp.where(by_ky, vx, vy)               # speed along the solved axis: Jacobian 1 / v_u
    v_o = jnp.where(by_ky, vy, vx)
    om = omega
    # branch "s": the pair whose sensitive axis is the solved component (u is its k_p, limited by L);
    # branch "u": the pair whose sensitive axis is u itself (the solved component limited by L)
    lo_s, hi_s = _range(om, v_u, v_o, k_g)
    lo_s, hi_s = jnp.maximum(lo_s, -k_l), jnp.minimum(hi_s, k_l)
    kink_s = jnp.where(v_o > 0, om / jnp.where(v_o > 0, v_o, 1.0), jnp.inf)
    lo_u, hi_u = _range(om, v_u, v_o, k_l)
    lo_u, hi_u = jnp.maximum(lo_u, -k_g), jnp.minimum(hi_u, k_g)
    lo, hi = jnp.stack([lo_s, lo_u]), jnp.stack([hi_s, hi_u])               # (2, F)
    kink = jnp.stack([kink_s, jnp.zeros_like(om)])
    u, w = _interval_nodes(lo, hi, kink)                                     # (2, F, 2n)
    solved = (om[:, None] - u * v_o) / v_u
    sensitive_is_u = jnp.array([False, True])[:, None, None]
    k_s = jnp.where(sensitive_is_u, u, solved)
    k_p = jnp.where(sensitive_is_u, solved, u)
    lg = log_g(k_s, jnp.stack([d1, d2])[:, None, None, None], a)             # (depth, 2, F, 2n)
    log_w = -jnp.square(a * k_p) / 3.0 + jnp.log(jnp.clip(w, tiny(w), None)) - jnp.log(v_u)
    empty = (hi <= lo)[..., None]
    return u, solved, jnp.where(empty | (w <= 0), -2e4, log_w), lg         # finite: keeps gradients NaN-free


def _pair_log_densities(omega, vx, vy, a, d1, d2, log_k_knots, log_phi, deep: bool = False):
    """log E[S11], log E[S12] (and log E[S22] if ``deep``; without gains) of the x and y pairs at omega (F,): each (2, F)."""
    u, solved, log_w, (lg1, lg2) = _pair_nodes(jnp.stack([vx, vy, a]), omega, d1, d2)
    base = _log_phi(u, solved, log_k_knots, log_phi) + log_w
    s11 = jnp.maximum(logsumexp(base + 2.0 * lg1, axis=-1), -1e4)           # (2, F); an empty line: tiny
    s12 = jnp.maximum(logsumexp(base + lg1 + lg2, axis=-1), -1e4)
    # by_ky: the x pair is branch "s" (its sensitive kx is solved), the y pair branch "u"; else swapped
    order = jnp.where(vx >= vy, jnp.array([0, 1]), jnp.array([1, 0]))
    if not deep:
        return s11[order], s12[order]
    s22 = jnp.maximum(logsumexp(base + 2.0 * lg2, axis=-1), -1e4)
    return s11[order], s12[order], s22[order]


@_few_inputs_jvp
def _matrix_nodes(p, omega, d1, d2):
    """The nodes of ``_matrix_log_densities`` at (vx, vy, a) = p: kx, ky (F, N) rad/m, their log weights
    (quadrature, 1 / |v_u|; -2e4 where unused) and the four channels' log factors (4, F, N)."""
    vx, vy, a = p[0], p[1], p[2]
    k_g = _LOG_EDGE / (2.0 * d1)
    k_l = (3.0 * _LOG_EDGE) ** 0.5 / a
    by_ky = vx >= vy
    v_u = jnp.where(by_ky, vx, vy)
    v_o = jnp.where(by_ky, vy, vx)
    lo_a, hi_a = _range(omega, v_u, v_o, k_g)                 # the pair sensitive to the solved component
    lo_a, hi_a = jnp.maximum(lo_a, -k_l), jnp.minimum(hi_a, k_l)
    lo_b, hi_b = _range(omega, v_u, v_o, k_l)                 # the pair sensitive to u
    lo_b, hi_b = jnp.maximum(lo_b, -k_g), jnp.minimum(hi_b, k_g)
    lo, hi = jnp.minimum(lo_a, lo_b), jnp.maximum(hi_a, hi_b)
    hi = jnp.maximum(hi, lo)
    safe = jnp.where(v_o > 0, v_o, 1.0)
    inner = [jnp.zeros_like(omega), jnp.where(v_o > 0, omega / safe, jnp.inf), -k_l + 0.0 * omega, k_l + 0.0 * omega,
             jnp.where(v_o > 0, (omega - k_l * v_u) / safe, -jnp.inf)]
    cuts = jnp.sort(jnp.stack([lo] + [jnp.clip(c, lo, hi) for c in inner] + [hi]), axis=0)   # (7, F)
    x, w = gauss_legendre(_N_NODES)
    x, w = jnp.asarray(x), jnp.asarray(w)
    half = 0.5 * (cuts[1:] - cuts[:-1])                                      # (6, F)
    mid = 0.5 * (cuts[1:] + cuts[:-1])
    u = jnp.moveaxis(mid[..., None] + half[..., None] * x, 0, 1).reshape(omega.shape[0], -1)     # (F, 6n)
    wt = jnp.moveaxis(half[..., None] * w, 0, 1).reshape(omega.shape[0], -1)
    solved = (omega[:, None] - u * v_o) / v_u
    kx = jnp.where(by_ky, solved, u)
    ky = jnp.where(by_ky, u, solved)
    log_w = jnp.where(wt <= 0, -2e4, jnp.log(jnp.clip(wt, tiny(wt), None)) - jnp.log(v_u))
    lx, ly = -jnp.square(a * kx) / 6.0, -jnp.square(a * ky) / 6.0
    # one log_g over the four channels: written four times, it was compiled four times (1.2 s against 0.5 s)
    k_s = jnp.stack([kx, kx, ky, ky])
    depth = jnp.stack([d1, d2, d1, d2])[:, None, None]
    return kx, ky, log_w, log_g(k_s, depth, a) + jnp.stack([ly, ly, lx, lx])


def _matrix_log_densities(omega, vx, vy, a, d1, d2, log_k_knots, log_phi):
    """log of all ten entries of the 4 x 4 spectral matrix of (x1, x2, y1, y2) at omega (F,), without gains
    or level, on ONE set of nodes: (10, F) in the order x1x1, x1x2, x2x2, y1y1, y1y2, y2y2, x1y1, x1y2, x2y1,
    x2y2 (``CHAIN_ENTRIES``).

    Channel x(d) weighs the mode k by G(kx; d, a) L(ky), y(d) by G(ky; d, a) L(kx) (``spectral_matrix``).
    At slow slip x1 and y1 are coherent to 0.99 and more in the lowest bins, and the chain's residual PSDs
    (``chain_model``) are small differences of these entries: computed with ``_pair_log_densities`` for the
    autos and a separate rule for the x-y entries, a 2e-3 disagreement made log S_y1.x wrong by 0.9 at
    6 rad/s (1.5 mm, 4.2 cm/s). On shared nodes the discrete sums keep the Gram structure and the
    differences are as accurate as the rule. The line is parametrised as ``_pair_log_densities`` (by ky when
    |vx| >= |vy|) over the union of both pairs' ranges, in six Gauss-Legendre panels split at the kinks
    (kx = 0, ky = 0) and where either pair's window factor ends (``_matrix_nodes``).
    """
    kx, ky, log_w, ch = _matrix_nodes(jnp.stack([vx, vy, a]), omega, d1, d2)
    base = _log_phi(kx, ky, log_k_knots, log_phi) + log_w
    return jnp.maximum(jnp.stack([logsumexp(base + ch[i] + ch[j], axis=-1) for i, j in CHAIN_ENTRIES]), -1e4)


#: (channel, channel) of each entry of ``_matrix_log_densities``, channels (x1, x2, y1, y2)
CHAIN_ENTRIES = ((0, 0), (0, 1), (1, 1), (2, 2), (2, 3), (3, 3), (0, 2), (0, 3), (1, 2), (1, 3))


def _grid_log_densities(theta, data: ModelData, deep: bool = False):
    """Model log S11 and log S12 (with gains, level and noise floor) of both pairs on the grid: (2, F) each;
    and the deep log S22 (gains and level, no noise) as a third if ``deep``."""
    vx, vy, a = jnp.exp(theta[0]), jnp.exp(theta[1]), jnp.exp(theta[2])
    log_gains = jnp.stack([theta[3], theta[4]])[:, None]
    log_amp = jnp.stack([0.0, theta[5]])[:, None]
    log_noise = theta[6]
    log_phi = theta[N_FIXED_PARAMS:]
    d1, d2 = data.depths[0], data.depths[1]
    dens = _pair_log_densities(data.grid_omega, vx, vy, a, d1, d2, data.log_k_knots, log_phi, deep)
    s11 = jnp.logaddexp(dens[0] + log_amp, log_noise)            # shallow white noise floor
    s12 = dens[1] + log_amp + log_gains
    if not deep:
        return s11, s12
    return s11, s12, dens[2] + log_amp + 2.0 * log_gains


def _window_average(s, data: ModelData, white=None):
    """(C, L) log of each bin's spectral-window average of the grid density exp(s) (C, F), as estimated.

    white: (C, F), (C, L) log |A|^2 on the grid and at the bins; default the pairs' (C = 2)."""
    white_grid, white_bin = (data.log_white_grid, data.log_white_bin) if white is None else white
    if data.kernel_index is not None:                            # banded: J grid points per bin
        idx, log_w = data.kernel_index, data.kernel_log_w
        return logsumexp(log_w[None] + (s + white_grid)[:, idx], axis=-1) - white_bin
    log_kernel = jnp.log(jnp.clip(data.kernel, tiny(data.kernel), None))  # dense (L, F) kernel
    log_kernel = jnp.where(data.kernel > 0, log_kernel, -2e4)
    terms = log_kernel[None] + s[:, None, :] + white_grid[:, None, :]
    return logsumexp(terms, axis=-1) - white_bin


def _edge_slope(log_r_grid, log_h, data: ModelData):
    """(2, L) (R(omega + half a bin) - R(omega - half a bin)) / R-bar with R = S12 / S11 on the grid."""
    lo = log_r_grid[:, data.edge_index[0]]
    hi = log_r_grid[:, data.edge_index[1]]
    return jnp.exp(hi - log_h) - jnp.exp(lo - log_h)


def _bin_spectra(theta, data: ModelData):
    """Model log S11 (2, L) and log|S12|/S11 (2, L) at the bins, and log S22.1 (2, L) or None."""
    deep = data.log_c22 is not None
    dens = _grid_log_densities(theta, data, deep)
    s11, s12 = dens[0], dens[1]
    bin_s11 = _window_average(s11, data)
    bin_s12 = _window_average(s12, data)
    log_h = bin_s12 - bin_s11
    if data.centroid_shift is not None:                          # this recording's window term
        log_h = log_h + jnp.log1p(jnp.clip(_edge_slope(s12 - s11, log_h, data) * data.centroid_shift, -0.5, None))
    if not deep:
        return bin_s11, log_h, None
    # the estimator's S22 - |S12|^2 / S11 of bin averages, with each channel's white noise: the Jensen gap of
    # a ratio that varies across the bin is part of it, as it is of the measured one
    n1, n2 = data.log_noise_c22[:, :1], data.log_noise_c22[:, 1:]
    b11 = jnp.logaddexp(bin_s11, n1)
    b22 = jnp.logaddexp(_window_average(dens[2], data), n2)
    coherent = jnp.clip(jnp.exp(2.0 * bin_s12 - b11 - b22), 0.0, 1.0 - 8.0 * jnp.finfo(b22.dtype).eps)
    return bin_s11, log_h, b22 + jnp.log1p(-coherent) + data.c22_offset


def _bin_matrix(theta, data: ModelData):
    """(L, 4, 4) the model's Hermitian (real without ``xy_white_grid``) spectral matrix of (x1, x2, y1, y2)
    at the bins, as estimated (spectral-window averages, white noise on the diagonal), divided by exp(ref),
    and ref (L,) = log S_x1x1."""
    vx, vy, a = jnp.exp(theta[0]), jnp.exp(theta[1]), jnp.exp(theta[2])
    dens = _matrix_log_densities(data.grid_omega, vx, vy, a, data.depths[0], data.depths[1], data.log_k_knots,
                                 theta[N_FIXED_PARAMS:])
    # gains and levels: x2 has gx, y1 the level ay (power), y2 both ay and gy (amplitudes: half the power's log)
    amp = jnp.stack([0.0, theta[3], 0.5 * theta[5], 0.5 * theta[5] + theta[4]])
    level = jnp.stack([amp[i] + amp[j] for i, j in CHAIN_ENTRIES])[:, None]
    dens = dens + level
    noise = jnp.stack([theta[6], data.log_noise_c22[0, 1], theta[6], data.log_noise_c22[1, 1]])    # [x1, x2, y1, y2]
    noise = jnp.maximum(noise, jnp.ravel(data.log_noise_c22))     # the fitted shallow floor, or the measured one
    pair = dens[:6].reshape(2, 3, -1)                             # [pair][11, 12, 22] on the grid
    auto = [_window_average(pair[:, k], data) for k in range(3)]  # (2, L) each
    b11 = jnp.logaddexp(auto[0], noise[0::2, None])
    b22 = jnp.logaddexp(auto[2], noise[1::2, None])
    b12 = auto[1]
    ref = b11[0]
    xy = dens[6:]
    if data.xy_white_grid is None:
        white = (0.5 * (data.log_white_grid[0] + data.log_white_grid[1]),
                 0.5 * (data.log_white_bin[0] + data.log_white_bin[1]))
        bxy = _window_average(xy, data, (jnp.broadcast_to(white[0], xy.shape),
                                         jnp.broadcast_to(white[1], (4,) + white[1].shape)))
        cxy = jnp.exp(bxy - ref)
    else:                                                        # complex weights conj(A_x) A_y (banded kernel)
        terms = data.kernel_log_w[None] + xy[:, data.kernel_index]                # (4, L, J)
        top = jnp.max(terms, axis=-1)
        avg = jnp.sum(jnp.exp(terms - top[..., None]) * data.xy_white_grid[data.kernel_index], axis=-1)
        cxy = avg / data.xy_white_bin * jnp.exp(top - ref)
    e = lambda v: jnp.exp(v - ref)                                # noqa: E731
    c = lambda v: jnp.conj(v)                                     # noqa: E731
    rows = [[e(b11[0]), e(b12[0]), cxy[0], cxy[1]],
            [e(b12[0]), e(b22[0]), cxy[2], cxy[3]],
            [c(cxy[0]), c(cxy[2]), e(b11[1]), e(b12[1])],
            [c(cxy[1]), c(cxy[3]), e(b12[1]), e(b22[1])]]
    rows = [[jnp.asarray(v, cxy.dtype) for v in r] for r in rows]
    return jnp.moveaxis(jnp.stack([jnp.stack(r) for r in rows]), -1, 0), ref


def chain_model(theta, data: ModelData):
    """The model's chain (``cross_pair``): beta1 (L, 2), beta2 (L, 3) (complex with ``xy_white_grid``), and
    log residual PSDs (2, L)."""
    m, ref = _bin_matrix(theta, data)
    ok = data.mask_xy.any(axis=0)[:, None, None]
    m = jnp.where(ok, m, jnp.eye(4))                             # unused bins: finite, gradients NaN-free
    out = []
    for target, n in ((2, 2), (3, 3)):
        beta, c = regression(m[:, :n, :n], m[:, :n, target], m[:, target, target])
        c = jnp.maximum(c, 64.0 * jnp.finfo(c.dtype).eps * jnp.real(m[:, target, target]))
        out.append((beta, jnp.log(c) + ref))
    return out[0][0], out[1][0], jnp.stack([out[0][1], out[1][1]])


def _chain_residuals(theta, data: ModelData):
    """The chain's residuals, flat: (L, 4) and (L, 6) whitened coefficients, then (2, L) log residual PSDs."""
    beta1, beta2, log_c = chain_model(theta, data)
    blocks = []
    for b, (meas, w, model) in enumerate(((data.xy_beta1, data.xy_w1, beta1), (data.xy_beta2, data.xy_w2, beta2))):
        m = data.mask_xy[b][:, None]
        z = jnp.einsum("lij,lj->li", w, jnp.where(m, meas - model, 0.0))
        blocks.append(jnp.where(m, jnp.concatenate([z.real, z.imag], -1), 0.0).ravel())
    m = data.mask_xy
    r_c = jnp.where(m, (jnp.where(m, data.log_xy_c, 0.0) - jnp.where(m, log_c + data.xy_c_offset[:, None], 0.0))
                    * data.xy_c_weight[:, None], 0.0)
    return blocks + [r_c.ravel()]


def log_spectra(theta, data: ModelData):
    """Model log S11 (2, L) and log|S12|/S11 (2, L) at the bins, as the estimator sees them."""
    s11, log_h, _ = _bin_spectra(theta, data)
    return s11, log_h


def log_conditioned(theta, data: ModelData):
    """Model log S22.1 (2, L), the conditioned deep PSD as estimated (needs ``data.log_c22``)."""
    return _bin_spectra(theta, data)[2]


@jax.jit
def ratio_slope(theta, data: ModelData):
    """(2, L) the model's relative slope of the amplitude ratio across each bin (needs ``data.edge_index``):
    the slope ``pair_fit.noise_err_from_slope`` takes, for the joint model."""
    s11, s12 = _grid_log_densities(theta, data)[:2]
    return _edge_slope(s12 - s11, _window_average(s12, data) - _window_average(s11, data), data)


def n_prior_residuals(n_params: int) -> int:
    """How many trailing entries of ``residuals`` are priors (for ``lsq.least_squares(n_prior=...)``)."""
    return n_params + (n_params - N_FIXED_PARAMS) - 2


def residuals(theta, data: ModelData):
    """Weighted residuals, flat: shallow log PSDs and log amplitude ratios of both pairs (4 L),
    the conditioned deep log PSDs (2 L, only with ``data.log_c22``), the y pair conditioned on the x pair
    (12 L, only with ``data.xy_beta1``: ``_chain_residuals``), then the priors (P + n_knots - 2, see
    ``n_prior_residuals``)."""
    s11, h, c22 = _bin_spectra(theta, data)
    r_s = jnp.where(data.mask_s11, (jnp.where(data.mask_s11, data.log_s11, 0.0) - s11) * data.s11_weight, 0.0)
    err = jnp.where(data.mask_h, data.h_err, 1.0)
    r_h = jnp.where(data.mask_h, (jnp.where(data.mask_h, data.log_h, 0.0) - h) / err, 0.0)
    blocks = [r_s.ravel(), r_h.ravel()]
    if c22 is not None:
        m = data.mask_c22
        blocks.append(jnp.where(m, (jnp.where(m, data.log_c22, 0.0) - jnp.where(m, c22, 0.0)) * data.c22_weight,
                                0.0).ravel())
    if data.xy_beta1 is not None:
        blocks += _chain_residuals(theta, data)
    prior = (theta - data.prior_center) * data.prior_inv_sd
    log_phi = theta[N_FIXED_PARAMS:]
    smooth = (log_phi[:-2] - 2.0 * log_phi[1:-1] + log_phi[2:]) * data.smooth_inv_sd
    return jnp.concatenate(blocks + [prior, smooth])
