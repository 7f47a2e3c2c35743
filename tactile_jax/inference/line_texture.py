"""Line textures (gratings, wire nets, sums of plane waves): speeds and contact radius from coherent lines.

A surface mode of wavevector k = (kx, ky) sliding at v rings at omega = |k . v|.
Under the Gaussian contact window the x pair weighs it by G(|kx|; d, a) W(ky) and
the y pair by G(|ky|; d, a) W(kx) (``model.probe.line_response``), so at the line

    log r_x = log R(|kx|; a) + log gx,        log r_y = log R(|ky|; a) + log gy,
    log c   = log rho + log G(|ky|; d1, a) - log G(|kx|; d1, a) + a^2 (ky^2 - kx^2) / 6,

with r_x, r_y each pair's deep/shallow amplitude ratio (``spectral.peaks``), c the
shallow probes' amplitude ratio y1/x1, R the exact R curve (``model.r_curve``), gx,
gy the deep/shallow gain ratios and rho = g_y1 / g_x1 the shallow probes' gain
ratio (all known; default 1). Only |kx|, |ky| are observable, so

    omega_j = | |kx_j| |vx| + t_j |ky_j| |vy| |,   t_j = +/-1 unknown per line

(t_j is the product of the signs of kx_j ky_j and vx vy).

Under the Hertz disk the responses are the table's, log |Hn(k_s, k_p; d, a)| (``model.hertz``), not separable:
each pair's ratio of a line depends on both components. ``window=None`` fits both windows and keeps the one the
lines prefer (``_choose_window``). The disk's solves start from a scan over a (``_Fitter._hertz_scan``) and each
line's best wavevector on a grid (``_Fitter._hertz_starts``); the searches and readings outside the solves (the
level scan, harmonics, combination lines) use the Gaussian window's curves at the radius of the same second
moment. One mode per line is assumed: under the disk a wire net's crossings put several modes (k0, m k0) on one
line that the deep probe hears through the disk's edge, and such lines are not explained.

Identifiability (what the fit assumes and reports):

- One ratio has two unknowns (|k_s|, a). A mode whose two components are both
  measured (two of r_x, r_y, c) is a *2-D mode*; with all three it fixes a by
  itself. Harmonics of one family (omega in ratios 1:2:3, k_j = n_j k_0) fix a from
  the ratios of one pair. Otherwise a is profiled over ``a_range`` (0.5-10 mm) and,
  where the lines do not fix it (sd of log a above ``A_DETERMINED``), marginalised:
  the speeds' errors then hold the spread over the plausible range, and a speed
  whose relative error exceeds ``MAX_REL_ERR`` is reported undetermined, with bounds.
- With the velocity given, omega_j = |kx_j vx + t_j ky_j vy| ties each line's components
  to the speeds; along an axis (vy = 0) it fixes |kx_j| = omega_j / vx outright, so a
  line heard by the x pair alone fixes a by its ratio (the paper's Fig. 7).
- A line heard by one pair only (and no cross level) gives one component; the
  other is free, so its omega says nothing about v: it is left out of the speed fit
  (reported with its |k_s|), except as a harmonic of a family.
- All 2-D modes parallel (one family, a grating; one 2-D mode is always one): only
  v_n = omega / |k| along the wavevector is determined (the aperture problem); vx,
  vy are None, status ``undetermined``, with v_n and the normal's angle in [0, 90]
  degrees (the mirror image -angle fits equally: the sign of kx ky is unknown).
  A grating's lines are all harmonics n omega0; lines at other frequencies (heard by
  one pair) lie in other directions, so the texture is not one grating (texture
  ``multi``). Its family's v_n is reported only if the family is one of the
  texture's principal directions: if a line in another direction carries
  ``MINOR_DB`` more relief amplitude (its level over the largest response the window
  allows it, against the family's level over its own response), the family is a
  minor mode (a weak harmonic or combination of lines in other directions, or, in a
  simulation, a mode aliased by the texture's grid) and v_n is withheld.
- Two or more directions: both speeds. Sign choices t_j are searched on a grid of
  v (each line's best t at each v), the best minima refined. Two modes always
  admit several choices that fit exactly (each t, and each sign of k . v). The
  combination lines of a net (k1 +/- k2 at omega1 +/- omega2), heard outside the
  fit, tell them apart: each choice predicts their components differently (to
  ``COMBINATION_K_ERR``). Where several survive, a choice that puts two
  families at right angles (within ``PERPENDICULAR_SIN``), where no other
  does, is taken: a wire net's wires cross at right angles. When choices still
  fit equally well (chi2 within ``AMBIGUITY_CHI2``) with speeds more than 3
  sigma apart, the speeds are None, status ``undetermined``, and
  ``alternatives`` lists them.
- One family heard by both pairs and lines at other frequencies heard by one
  pair each (a net whose second family lies within about 1/a of an axis): read
  as a square net, the right angle supplies the missing component of the
  second family's fundamental, and the lines are fitted in two directions.
  That is an assumption, so the speeds are reported only where a combination
  line measures the supplied component and agrees (``_square_net``); else
  the family's v_n as above, the message giving the unchecked reading.
- Harmonics heard by one pair alone fix a only if exact (``STRICT_HARMONIC_BINS``)
  and at one radius: the ratio of two inverted wavenumbers is not monotonic in a,
  and where two radii fit, a is undetermined and both are named.

Errors: Gauss-Newton covariance of the weighted least squares (optimistix
Levenberg-Marquardt, ``inference.lsq``) scaled by max(1, reduced chi2); the
measurement errors are the Bendat-Piersol ones with floors calibrated on
simulations (``RATIO_FLOOR``, ``CROSS_FLOOR``). A fit whose chi2 has a p-value
below ``P_POOR`` (after dropping at most a quarter of the lines, one by one, beyond
4 sigma) is ``poor_fit``. Parameters: log a, vx and vy linear (cm/s; they may be
0), log |kx_j|, log |ky_j|.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..model.r_curve import log_g, log_r_exact
from .core import HERTZ_PER_GAUSS
from .lsq import least_squares

__all__ = ["LineTable", "LineFit", "fit_lines", "NMAX", "A_RANGE", "RATIO_FLOOR", "CROSS_FLOOR",
           "P_POOR", "MAX_REL_ERR", "A_DETERMINED", "AMBIGUITY_CHI2", "MINOR_DB", "invert_ratio"]

#: line slots of the compiled fit (more 2-D modes: the best measured are kept)
NMAX = 32
#: plausible contact radii (m) over which an undetermined a is marginalised
A_RANGE = (0.5e-3, 10e-3)
#: floors (natural-log units) added in quadrature to the Bendat-Piersol errors of the pairs' ratios and of
#: the cross-pair level (calibrated on simulated gratings, nets and plane-wave textures)
RATIO_FLOOR = 3e-4
CROSS_FLOOR = 3e-4
#: chi2 p-value below which a fit is ``poor_fit``
P_POOR = 1e-3
#: relative one-sigma error above which a (marginalised) speed is reported undetermined
MAX_REL_ERR = 0.25
#: sd of log a above which the lines are said not to determine a (it is then marginalised)
A_DETERMINED = 0.15
#: condition number of the fit's (equilibrated) Gauss-Newton matrix above which a combination of parameters
#: is taken as undetermined by the lines
COND_MAX = 1e10
#: chi2 margin within which two sign choices fit "equally well"
AMBIGUITY_CHI2 = 4.0
#: |cos| of the angle between two fitted modes within which a sign choice puts them at right angles (1 deg)
PERPENDICULAR_SIN = math.sin(math.radians(1.0))
#: relative error of a combination line's wavevector as predicted from the fitted modes (added in quadrature:
#: such lines are 20-40 dB weaker than the modes and blend with their neighbours' leakage)
COMBINATION_K_ERR = 0.01
#: floor (natural log) added in quadrature to the ratios' and cross levels' errors under the Hertz disk, and under both
#: windows where the lines choose between them: simulated lattices under the disk miss the table's responses by up
#: to 0.027 in log at the modes' true wavevectors (the y pair's ratios near the zeros of the disk's response along
#: the probe), against errors of 0.001-0.02
WINDOW_FLOOR = 0.01
#: Gauss-Newton decrement of chi-square below which a solve under the Hertz disk counts as converged (``_run``)
HERTZ_DECREMENT = 0.1
#: under the Hertz disk, a wavevector component the solve drives below this many radians per contact radius is held
#: at 0 (``_run``): there the disk's response is within 1 % of its value at 0 (1 - kappa^2 / 8 across the probe)
KAPPA_HELD = 0.25
#: ... where that raises chi-square by at most this
HELD_CHI2 = 1.0
#: a line z-score beyond which the worst line may be dropped
DROP_Z = 4.0
#: harmonics considered for one family
MAX_HARMONIC = 8
#: frequency tolerance floor (bins) of a line matched to a harmonic or a family (``_omega_tol``): blended lines sit
#: up to 0.18 bin off their lattice frequencies on the simulated nets
HARMONIC_BINS = 0.3
#: harmonic tolerance floor (bins) where one pair's harmonics alone fix a (or bound a family's normal speed): the
#: lines of simulated nets sit within 0.0023 bin of their lattice frequencies (95 %), while two lines of different
#: families of a sheared net 0.4 bin off a 3:5 ratio, read as harmonics, give a = 1.18 +/- 0.01 mm for 2.20
STRICT_HARMONIC_BINS = 0.02
#: relief-amplitude margin (dB) by which a line in another direction must exceed a family for the family to
#: count as a minor mode of the texture, whose normal is not reported (its lines' levels over their responses;
#: on the simulated nets and plane-wave textures, principal families reach at most +6 dB, grid-aliased modes +30-35 dB)
MINOR_DB = 20.0

_K_GRID = np.geomspace(20.0, 3e5, 4096)         # rad/m, for inverting the monotone curves
_NG = 5                                          # global parameters: log a, vx, vy, log kx0, log ky0
_K_UNIT = 1e3                                    # k in rad/mm inside the fit
_V_UNIT = 1e-2                                   # v in cm/s inside the fit
_K_NONE = 1.0                                    # rad/m: a wavevector component held at 0 (its log is the parameter)
_K_START_GRID = np.concatenate([[_K_NONE], np.geomspace(20.0, 2e5, 80)])   # rad/m: the Hertz disk's starts
_K_SCAN_GRID = np.concatenate([[_K_NONE], np.geomspace(20.0, 2e5, 30)])    # rad/m: ... its scan over a
_SCAN_FLOOR = 0.05                              # log units added to the lines' errors in that scan
_N_SCAN_MINIMA = 5                                # ... whose best minima are searched finely
_RADII_BLOCK = 64                                # radii evaluated at once in those scans


class LineTable(NamedTuple):
    """The lines and what the fit infers of each (numpy, (L,) unless noted).

    omega, omega_err: rad/s. heard: (2, L) the x and y pairs hear the line. log_ratio, log_ratio_err:
    (2, L) measured deep/shallow log amplitude ratios. cross_log, cross_err: log|y1/x1| (NaN: none).
    harmonic: the line's harmonic number in the family (0: not in it). used: in the speed fit.
    dropped: left out as an outlier. kx, kx_err, ky, ky_err: inferred |kx|, |ky| (rad/m) and
    one-sigma errors (NaN: undetermined). sign: the sign choice t (+1/-1; 0: not in the speed fit).
    """

    omega: np.ndarray
    omega_err: np.ndarray
    heard: np.ndarray
    log_ratio: np.ndarray
    log_ratio_err: np.ndarray
    cross_log: np.ndarray
    cross_err: np.ndarray
    harmonic: np.ndarray
    used: np.ndarray
    dropped: np.ndarray
    kx: np.ndarray
    kx_err: np.ndarray
    ky: np.ndarray
    ky_err: np.ndarray
    sign: np.ndarray


class LineFit(NamedTuple):
    """Result of ``fit_lines``; None where a quantity is undetermined. SI units (m/s, m, rad/s, rad/m).

    status: "ok", "undetermined" (a speed the lines cannot give: a grating's ridge component, equally good
    sign choices, or a not marginalisable a), "no_band" (no coherent line in the deep probes),
    "poor_fit" (the model does not explain the lines). message: one line.
    vx, vx_err, vy, vy_err: |vx|, |vy| and one-sigma errors. a, a_err: contact radius;
    a_source: "fit", "given", "marginalised" (a over ``a_range``: a is None) or None.
    v_n, v_n_err: speed along a grating's normal; v_n_bounds: (lo, hi) when v_n is undetermined.
    normal_angle, normal_angle_err: the normal's angle to the x axis, degrees in [0, 90] (its mirror
    image, minus that angle, fits equally). texture: "grating" (one family of parallel lines),
    "multi" (two or more directions: a fit of them, or one family among lines at other frequencies, whose
    v_n is then its own normal's) or "none". ambiguous: two sign choices fit equally well with
    different speeds; alternatives: ((|vx|, |vy|, chi2), ...) of the choices within
    ``AMBIGUITY_CHI2`` of the best. speed_bounds: ((lo, hi), (lo, hi)) of |vx|, |vy| when a
    marginalised speed is undetermined. chi2, redchi, dof; n_lines (detected), n_used (in the speed
    fit), n_dropped (outliers). lines: the ``LineTable``. window: the contact window of the fit ("gaussian" or
    "hertz"); window_margin: chi-square of the Gaussian window's fit less the Hertz disk's, in units of the better
    one's reduced chi-square (at least 1), where both were fitted (else NaN).
    """

    status: str
    message: str
    vx: float | None = None
    vx_err: float | None = None
    vy: float | None = None
    vy_err: float | None = None
    a: float | None = None
    a_err: float | None = None
    a_source: str | None = None
    v_n: float | None = None
    v_n_err: float | None = None
    v_n_bounds: tuple | None = None
    normal_angle: float | None = None
    normal_angle_err: float | None = None
    texture: str = "none"
    ambiguous: bool = False
    alternatives: tuple = ()
    speed_bounds: tuple | None = None
    chi2: float = float("nan")
    redchi: float = float("nan")
    dof: int = 0
    n_lines: int = 0
    n_used: int = 0
    n_dropped: int = 0
    lines: LineTable | None = None
    window: str = "gaussian"
    window_margin: float = float("nan")


# --------------------------------------------------------------------------------------------------------
# the compiled least squares


def _log_responses(kx, ky, d1, d2, a, coef):
    """log |response| (depth, pair, line) (2, 2, NMAX) of each line's mode (kx, ky) at both depths: the x pair
    hears it along kx, the y pair along ky. ``coef`` None: the Gaussian window, log G(|k_s|; d, a) - a^2 k_p^2 / 6;
    else the Hertz disk's table (``model.hertz``), log |Hn(k_s, k_p; d, a)|, which is not separable: the x pair's
    ratio depends on ky too."""
    n = kx.shape[0]
    if coef is None:
        # one call of log G for every (component, depth): equal to ``log_r_exact`` to 1e-12 for the ratio (one
        # special-function graph instead of four halves the compile time)
        k4 = jnp.concatenate([kx, ky, kx, ky])
        d4 = jnp.concatenate([jnp.full(2 * n, d1), jnp.full(2 * n, d2)])
        lg = log_g(k4, d4, a).reshape(2, 2, n)
        return lg - jnp.square(a) * jnp.square(jnp.stack([ky, kx])) / 6.0
    from ..model.hertz import hertz_factors, table_of

    ks = jnp.concatenate([kx, ky])
    kp = jnp.concatenate([ky, kx])
    log_env, mant = hertz_factors(jnp.stack([ks, ks]), jnp.stack([kp, kp]), jnp.stack([d1, d2]), a,
                                  table=table_of(coef))
    # |mant| is O(1) and vanishes only at the disk edge's zeros of Hn, where no line is heard
    return (log_env + jnp.log(jnp.abs(mant) + 1e-30)).reshape(2, 2, n)


@jax.jit
def _responses_over(kx, ky, d1, d2, radii, coef):
    """``_log_responses`` (R, 2, 2, N) of the Hertz disk at the modes (kx, ky) (N,) for each of ``radii`` (R,)."""
    return jax.vmap(lambda a: _log_responses(kx, ky, d1, d2, a, coef))(radii)


def _residuals(theta, args, coef=None):
    """Weighted residuals (4 NMAX,): x ratio, y ratio, cross level, frequency of every slot (0 where masked);
    ``coef``: the Hertz table's coefficients for the Hertz disk, None for the Gaussian window."""
    d1, d2 = args["d1"], args["d2"]
    a = 1e-3 * jnp.exp(theta[0])
    fam = args["family"] > 0
    n = args["harm"]
    log_n = jnp.log(jnp.maximum(n, 1.0))
    lkx = jnp.where(fam, log_n + theta[3], theta[_NG:_NG + NMAX])
    lky = jnp.where(fam, log_n + theta[4], theta[_NG + NMAX:])
    kx = _K_UNIT * jnp.exp(lkx)
    ky = _K_UNIT * jnp.exp(lky)
    mx, my, mc, mw = args["mx"], args["my"], args["mc"], args["mw"]
    lh = _log_responses(kx, ky, d1, d2, a, coef)                 # (depth, pair, line)
    log_r = lh[1] - lh[0]
    rx = jnp.where(mx > 0, (log_r[0] + args["lgx"] - args["lrx"]) / args["srx"], 0.0)
    ry = jnp.where(my > 0, (log_r[1] + args["lgy"] - args["lry"]) / args["sry"], 0.0)
    # the shallow probes' level y1 / x1
    rc = jnp.where(mc > 0, (args["lrho"] + lh[0, 1] - lh[0, 0] - args["lc"]) / args["sc"], 0.0)
    vx, vy = _V_UNIT * theta[1], _V_UNIT * theta[2]
    k0 = _K_UNIT * jnp.sqrt(jnp.exp(2 * theta[3]) + jnp.exp(2 * theta[4]))
    w_model = jnp.where(fam, n * k0 * vx, jnp.abs(kx * vx + args["t"] * ky * vy))
    rw = jnp.where(mw > 0, (w_model - args["w"]) / args["sw"], 0.0)
    return jnp.concatenate([rx, ry, rc, rw])


def _residuals_of(theta, data):
    """``_residuals`` with data = (args, coef): one module-level function for ``least_squares``."""
    return _residuals(theta, *data)


@jax.jit
def _solve_jit(theta0, args, free, coef):
    res = least_squares(_residuals_of, theta0, (args, coef), free, max_steps=200, scale_covar=False)
    return res._replace(jac=None), _residuals(res.theta, args, coef)


def _solve(theta0, args, free, coef=None):
    """(LsqResult, residuals at the fit (4 NMAX,)) as numpy: one compiled program for every record (a second
    for the Hertz disk, ``coef`` its table's coefficients)."""
    res, r = _solve_jit(jnp.asarray(theta0, float), {k: jnp.asarray(v, float) for k, v in args.items()},
                        jnp.asarray(free, bool), coef)
    return jax.tree.map(np.asarray, res), np.asarray(r)


@functools.lru_cache(maxsize=64)
def _curves(a: float, d1: float, d2: float):
    """(log R, F = log G(d1) + a^2 k^2 / 6) on ``_K_GRID`` for contact radius ``a`` (m): both increase... R
    decreases and F increases monotonically in k (checked for a from 0.3 to 10 mm)."""
    return _curves_jit(jnp.asarray(a), jnp.asarray(d1), jnp.asarray(d2))


@jax.jit
def _curves_jit(a, d1, d2):
    k = jnp.asarray(_K_GRID)
    lr = log_r_exact(k, d1, d2, a)
    f = log_g(k, d1, a) + jnp.square(a * k) / 6.0
    return jnp.stack([lr, f])


@jax.jit
def _curves_over(radii, d1, d2):
    """``_curves_jit`` at each of ``radii`` (n,) m: (n, 2, K), one call (a scan over a fills no cache)."""
    return jax.vmap(_curves_jit, in_axes=(0, None, None))(radii, d1, d2)


def _tables(a, d1, d2):
    out = np.asarray(_curves(float(a), float(d1), float(d2)))
    return out[0], out[1]


def invert_ratio(log_ratio, a: float, d1: float, d2: float):
    """|k| (rad/m) with log R(|k|; a) = ``log_ratio`` (gain removed), for contact radius ``a`` and depths
    ``d1`` < ``d2`` (m); clipped to [20, 3e5] rad/m (log R decreases monotonically in |k|)."""
    return _invert_on(_tables(a, d1, d2)[0], log_ratio)


def _invert_on(lr, log_ratio):
    """|k| (rad/m) where the log R table ``lr`` (on ``_K_GRID``) equals ``log_ratio``."""
    return np.exp(np.interp(-np.asarray(log_ratio, float), -lr, np.log(_K_GRID)))


def _invert_cross(target, a, d1, d2):
    """|k| with F(|k|) = ``target``, F = log G(k; d1, a) + a^2 k^2 / 6 (increasing)."""
    _, f = _tables(a, d1, d2)
    return np.exp(np.interp(np.asarray(target, float), f, np.log(_K_GRID)))


def _log_slope(tab, log_k_grid, k, h=0.01):
    """d tab / d log k at ``k`` (rad/m) of a table on ``log_k_grid`` (central difference)."""
    return float(np.interp(math.log(k) + h, log_k_grid, tab) - np.interp(math.log(k) - h, log_k_grid, tab)) / (2 * h)


def _cross_f(k, a, d1, d2):
    """F(|k|) = log G(|k|; d1, a) + a^2 k^2 / 6 by interpolation of the table."""
    _, f = _tables(a, d1, d2)
    return np.interp(np.log(np.asarray(k, float)), np.log(_K_GRID), f)


# --------------------------------------------------------------------------------------------------------
# measurements, starts, searches


class _Data(NamedTuple):
    """Per-line measurements with floors (numpy, (L,)) and constants."""

    w: np.ndarray
    sw: np.ndarray
    hx: np.ndarray
    hy: np.ndarray
    hc: np.ndarray
    lrx: np.ndarray
    srx: np.ndarray
    lry: np.ndarray
    sry: np.ndarray
    lc: np.ndarray
    sc: np.ndarray
    d1: float
    d2: float
    lgx: float
    lgy: float
    lrho: float
    d_omega: float


def _measurements(lines, d1, d2, gx, gy, rho, ratio_floor, cross_floor) -> _Data:
    heard = np.asarray(lines.heard, bool)
    lr = np.asarray(lines.log_ratio, float)
    er = np.asarray(lines.log_ratio_err, float)
    hx, hy = heard[0] & np.isfinite(lr[0]), heard[1] & np.isfinite(lr[1])
    lc = np.asarray(lines.cross_log, float)
    hc = np.isfinite(lc) & (rho is not None)
    return _Data(np.asarray(lines.omega, float), np.asarray(lines.omega_err, float), hx, hy, hc,
                 np.where(hx, lr[0], 0.0), np.where(hx, np.hypot(er[0], ratio_floor), 1.0),
                 np.where(hy, lr[1], 0.0), np.where(hy, np.hypot(er[1], ratio_floor), 1.0),
                 np.where(hc, lc, 0.0), np.where(hc, np.hypot(np.asarray(lines.cross_err, float), cross_floor), 1.0),
                 float(d1), float(d2), math.log(gx), math.log(gy), math.log(rho) if rho is not None else 0.0,
                 float(lines.d_omega))


def _start_k(dat: _Data, a, sel):
    """Starting |kx|, |ky| (rad/m; NaN where a component is not measured) of lines ``sel`` at radius ``a``."""
    kx = np.where(dat.hx, invert_ratio(dat.lrx - dat.lgx, a, dat.d1, dat.d2), np.nan)
    ky = np.where(dat.hy, invert_ratio(dat.lry - dat.lgy, a, dat.d1, dat.d2), np.nan)
    only_x = dat.hc & dat.hx & ~dat.hy
    only_y = dat.hc & dat.hy & ~dat.hx
    if only_x.any():
        ky = np.where(only_x, _invert_cross(dat.lc - dat.lrho + _cross_f(np.nan_to_num(kx, nan=1e3), a, dat.d1, dat.d2),
                                            a, dat.d1, dat.d2), ky)
    if only_y.any():
        fx = _cross_f(np.nan_to_num(ky, nan=1e3), a, dat.d1, dat.d2) - (dat.lc - dat.lrho)
        kx = np.where(only_y, _invert_cross(fx, a, dat.d1, dat.d2), kx)
    return np.where(sel, kx, np.nan), np.where(sel, ky, np.nan)


def _robust(z):
    """A misfit term robust to a blended or mismeasured line: log(1 + z^2 / 9), quadratic within 3 sigma."""
    return np.log1p(np.square(z) / 9.0)


def _omega_tol(sw, d_omega, floor_bins=HARMONIC_BINS):
    """How far (rad/s) a line may sit from a frequency it is matched to: 4 of its sigmas ``sw``, at least
    ``floor_bins`` bins of width ``d_omega``."""
    return np.maximum(4.0 * np.asarray(sw, float), floor_bins * d_omega)


def _harmonic_numbers(w, sw, d_omega, sel, floor_bins=HARMONIC_BINS):
    """(omega0, n (L,)) of the largest fundamental whose harmonics 1..MAX_HARMONIC explain every line in ``sel``
    (within ``_omega_tol``); (None, zeros) if none does."""
    idx = np.flatnonzero(sel)
    if idx.size == 0:
        return None, np.zeros(w.size)
    tol = _omega_tol(sw, d_omega, floor_bins)
    best = None
    for j in idx:
        for h in range(1, MAX_HARMONIC + 1):
            w0 = w[j] / h
            if w0 < 2.0 * d_omega:
                break
            n = np.rint(w[idx] / w0)
            if np.all((n >= 1) & (n <= MAX_HARMONIC) & (np.abs(w[idx] - n * w0) <= tol[idx] + n * tol[j] / h)):
                if best is None or w0 > best[0] * (1 + 1e-9):
                    best = (w0, n)
                break
    if best is None:
        return None, np.zeros(w.size)
    n = np.zeros(w.size)
    n[idx] = best[1]
    return best[0], n


def _velocity_candidates(kx, ky, w, n_cand=6, tol=0.05):
    """Starting (vx, vy) (m/s, >= 0) from a grid over speed and direction: each line's best sign at each v, a
    robust count of the lines missed by more than ``tol`` (relative); the best local minima, best first."""
    kn = np.hypot(kx, ky)
    lo = 0.8 * float(np.max(w / kn))
    s = np.geomspace(lo, min(60.0 * lo, 5.0), 220)
    phi = np.linspace(0.0, 0.5 * np.pi, 181)
    vx = (s[:, None] * np.cos(phi)[None, :])[..., None]
    vy = (s[:, None] * np.sin(phi)[None, :])[..., None]
    ep = np.abs(np.abs(kx * vx + ky * vy) - w) / w
    em = np.abs(np.abs(kx * vx - ky * vy) - w) / w
    cost = np.minimum(np.square(np.minimum(ep, em) / tol), 1.0).sum(-1)
    pad = np.pad(cost, 1, mode="edge")
    neigh = np.lib.stride_tricks.sliding_window_view(pad, (3, 3)).reshape(cost.shape + (9,))
    is_min = cost <= neigh.min(-1)
    cand = np.argwhere(is_min & (cost <= cost.min() + 1.5))
    order = np.argsort(cost[cand[:, 0], cand[:, 1]], kind="stable")
    out = []
    for i, j in cand[order]:
        v = (s[i] * math.cos(phi[j]), s[i] * math.sin(phi[j]))
        if all(math.hypot(v[0] - u[0], v[1] - u[1]) > 0.03 * math.hypot(*v) for u in out):
            out.append(v)
        if len(out) >= n_cand:
            break
    return out


def _best_signs(kx, ky, w, vx, vy):
    ep = np.abs(np.abs(kx * vx + ky * vy) - w)
    em = np.abs(np.abs(kx * vx - ky * vy) - w)
    return np.where(ep <= em, 1.0, -1.0)


# --------------------------------------------------------------------------------------------------------
# one fit


class _Fit(NamedTuple):
    theta: np.ndarray
    cov: np.ndarray
    chi2: float
    dof: int
    converged: bool
    t: np.ndarray
    z: np.ndarray          # (L,) largest |residual| of each slot's line
    n_free: int = 0
    cond: float = 1.0
    n_data: int = 0

    @property
    def determined(self) -> bool:
        """As many data as free parameters and no combination of them the data leave flat (Gauss-Newton
        condition number below ``COND_MAX``): else the pseudo-inverse covariance would understate errors."""
        return self.n_data >= self.n_free and self.cond < COND_MAX


def _args(dat: _Data, slots, family, harm, t, mw_extra=None):
    """Residual data for the lines ``slots`` (indices into the line arrays, at most NMAX)."""
    def pad(v, fill):
        out = np.full(NMAX, fill, float)
        out[:len(slots)] = v[slots]
        return out

    n = len(slots)
    m = np.zeros(NMAX)
    m[:n] = 1.0
    hx, hy, hc = (pad(h.astype(float), 0.0) for h in (dat.hx, dat.hy, dat.hc))
    mw = m.copy() if mw_extra is None else pad(mw_extra.astype(float), 0.0)
    return dict(d1=dat.d1, d2=dat.d2, lgx=dat.lgx, lgy=dat.lgy, lrho=dat.lrho, family=float(family),
                harm=pad(harm, 1.0), mx=hx, my=hy, mc=hc, mw=mw,
                lrx=pad(dat.lrx, 0.0), srx=pad(dat.srx, 1.0), lry=pad(dat.lry, 0.0), sry=pad(dat.sry, 1.0),
                lc=pad(dat.lc, 0.0), sc=pad(dat.sc, 1.0), w=pad(dat.w, 1.0), sw=pad(dat.sw, 1.0),
                t=pad(t, 1.0))


def _run(dat, slots, *, family, harm, t, a0, v0, kx0, ky0, free_a, free_v, free_kx, free_ky, mw=None, coef=None):
    """One Levenberg-Marquardt solve; kx0, ky0 (L,) rad/m starts (family: the fundamental's (2,)); coef: the
    Hertz table's coefficients (the Hertz disk) or None (the Gaussian window)."""
    n = len(slots)
    theta = np.zeros(_NG + 2 * NMAX)
    theta[0] = math.log(a0 / 1e-3)
    theta[1], theta[2] = v0[0] / _V_UNIT, v0[1] / _V_UNIT
    free = np.zeros(theta.size, bool)
    free[0] = free_a
    if family:
        theta[3], theta[4] = math.log(kx0[0] / _K_UNIT), math.log(ky0[0] / _K_UNIT)
        free[1] = free_v
        free[3], free[4] = free_kx, free_ky
    else:
        free[1] = free[2] = free_v
        theta[_NG:_NG + n] = np.log(np.nan_to_num(kx0[slots], nan=_K_UNIT) / _K_UNIT)
        theta[_NG + NMAX:_NG + NMAX + n] = np.log(np.nan_to_num(ky0[slots], nan=_K_UNIT) / _K_UNIT)
        free[_NG:_NG + n] = free_kx[slots]
        free[_NG + NMAX:_NG + NMAX + n] = free_ky[slots]
    args = _args(dat, slots, family, harm, t, mw)
    res, r = _solve(theta, args, free, coef)
    if coef is not None and not bool(res.converged):
        # the disk's response is flat in a wavevector component about 0, and a mode along an axis puts the optimum
        # there, where log |k| cannot go: the solve drifts. Components it drove below ``KAPPA_HELD`` / a are held
        # at 0 and the solve repeated; that fit is kept where it settles and fits as well
        comp = np.zeros(theta.size, bool)
        comp[3:5] = family
        comp[_NG:] = not family
        th = np.asarray(res.theta)
        flat = free & comp & (_K_UNIT * np.exp(th) * 1e-3 * math.exp(th[0]) < KAPPA_HELD)
        if flat.any():
            held = np.where(flat, math.log(_K_NONE / _K_UNIT), th)
            res2, r2 = _solve(held, args, free & ~flat, coef)
            if bool(res2.converged) and float(res2.chi2) <= float(res.chi2) + HELD_CHI2:
                res, r, free = res2, r2, free & ~flat
    r = r.reshape(4, NMAX)
    z = np.zeros(dat.w.size)
    z[slots] = np.abs(r[:, :n]).max(0)
    n_data = int(np.sum(np.asarray([args["mx"], args["my"], args["mc"], args["mw"]]) > 0))
    n_free = int(free.sum())
    dof = max(n_data - n_free, 0)
    cond = float(res.cond) if np.isfinite(res.cond) else float("inf")
    # the Hertz disk's response is flat in a component near 0 (its log drifts towards -infinity): a solve whose
    # chi-square can fall by less than ``HERTZ_DECREMENT`` more has reached its minimum for every purpose
    converged = bool(res.converged) or (coef is not None and bool(np.isfinite(res.chi2))
                                        and float(res.decrement) < HERTZ_DECREMENT)
    return _Fit(np.asarray(res.theta), np.asarray(res.cov), float(res.chi2), dof, converged,
                np.asarray(t, float), z, n_free, cond, n_data)


def _p_value(chi2, dof):
    """p-value of ``chi2``; an exactly determined fit (dof 0) should reach 0, and is judged as one dof."""
    from scipy.stats import chi2 as chi2_dist

    return float(chi2_dist.sf(chi2, max(dof, 1)))


def _scale(fit: _Fit):
    return max(1.0, fit.chi2 / fit.dof) if fit.dof > 0 else 1.0


# --------------------------------------------------------------------------------------------------------
# the public fit


def _no_band(lines, d1, d2, n_lines):
    so = np.asarray(lines.shallow_only)
    if so.sum() > 0:
        db = np.nanmax(np.asarray(lines.shallow_only_db, float))
        p = int(np.nanargmax(np.asarray(lines.shallow_only_db, float)))
        w = float(np.asarray(lines.shallow_only_omega)[p])
        snr = 10.0 ** (db / 20.0)
        k_max = math.log(snr) / (d2 - d1)
        msg = (f"the texture is too fine for the probes' depths: the shallow probes hear {int(so.sum())} line(s) "
               f"(strongest {db:.0f} dB above the noise at omega = {w:.1f} rad/s, {'xy'[p]} pair) but no deep probe "
               f"hears one coherently; at that line SNR the deep probe hears only |k| < ln(SNR) / (d2 - d1) = "
               f"{k_max:.0f} rad/m (wavelength > {2e3 * math.pi / k_max:.2f} mm)")
    else:
        msg = "no coherent line in either pair (0 usable lines): not a line texture, or lines not resolved"
    return LineFit("no_band", msg, n_lines=n_lines)


def _table(lines, dat, harm, used, dropped, kx, kx_err, ky, ky_err, sign):
    return LineTable(dat.w, dat.sw, np.asarray(lines.heard, bool), np.asarray(lines.log_ratio, float),
                     np.asarray(lines.log_ratio_err, float), np.asarray(lines.cross_log, float),
                     np.asarray(lines.cross_err, float), np.asarray(harm, int), np.asarray(used, bool),
                     np.asarray(dropped, bool), kx, kx_err, ky, ky_err, np.asarray(sign, float))


def _single_k(dat, a, a_sd, comp):
    """|k_s| and its error (propagating the ratio's error and sd(log a)) of pair ``comp`` (0 x, 1 y) lines."""
    lr, s, g, h = ((dat.lrx, dat.srx, dat.lgx, dat.hx) if comp == 0 else (dat.lry, dat.sry, dat.lgy, dat.hy))
    if a is None:
        return np.full(dat.w.size, np.nan), np.full(dat.w.size, np.nan)
    k = invert_ratio(lr - g, a, dat.d1, dat.d2)
    dk_dr = (invert_ratio(lr - g + 1e-4, a, dat.d1, dat.d2) - invert_ratio(lr - g - 1e-4, a, dat.d1, dat.d2)) / 2e-4
    da = 0.05
    dk_da = (invert_ratio(lr - g, a * math.exp(da), dat.d1, dat.d2)
             - invert_ratio(lr - g, a * math.exp(-da), dat.d1, dat.d2)) / (2 * da)
    err = np.hypot(dk_dr * s, dk_da * (a_sd or 0.0))
    return np.where(h, k, np.nan), np.where(h, err, np.nan)


def fit_lines(lines, depths, *, gain_ratio=1.0, shallow_gain_ratio=1.0, contact_radius=None, velocity=None,
              a_range=A_RANGE, ratio_floor: float = RATIO_FLOOR, cross_floor: float = CROSS_FLOOR,
              window: str | None = "gaussian") -> LineFit:
    """Speeds and contact radius of a line texture from its lines (``spectral.peaks.Lines``): see the module.

    depths: (d1, d2) probe depths, m. gain_ratio: known deep/shallow gain ratios (gx, gy) or one for both.
    shallow_gain_ratio: known y1/x1 shallow gain ratio rho (None: the cross-pair levels are not used).
    contact_radius: known a (m) or None. velocity: known (vx, vy) (m/s) or None. a_range: (lo, hi) plausible
    contact radii (m) for profiling and marginalising an undetermined a. ratio_floor, cross_floor: error
    floors (natural log). window: the contact window, "gaussian" or "hertz" (the Hertz table, ``model.hertz``),
    or None to fit both and keep the one the lines prefer (``_choose_window``). Failures come back as data
    (``LineFit.status``); bad arguments raise ValueError.
    """
    d1, d2 = (float(d) for d in depths)
    if not (0.0 < d1 < d2) or not math.isfinite(d2):
        raise ValueError(f"depths must satisfy 0 < d1 < d2, got {depths!r}")
    g = np.broadcast_to(np.asarray(gain_ratio, float), (2,))
    if not np.all(np.isfinite(g) & (g > 0)):
        raise ValueError(f"gain_ratio must be positive, got {gain_ratio!r}")
    if shallow_gain_ratio is not None and not (float(shallow_gain_ratio) > 0):
        raise ValueError(f"shallow_gain_ratio must be positive or None, got {shallow_gain_ratio!r}")
    if contact_radius is not None and not (float(contact_radius) > 0):
        raise ValueError(f"contact_radius must be positive, got {contact_radius!r}")
    if window not in (None, "gaussian", "hertz"):
        raise ValueError(f"window must be 'gaussian', 'hertz' or None, got {window!r}")
    lo_a, hi_a = (float(v) for v in a_range)
    if not 0 < lo_a < hi_a:
        raise ValueError(f"a_range must be 0 < lo < hi, got {a_range!r}")
    if velocity is not None:
        velocity = tuple(abs(float(v)) for v in velocity)
        if len(velocity) != 2 or not all(math.isfinite(v) for v in velocity) or max(velocity) == 0:
            raise ValueError(f"velocity must be two finite numbers, not both 0, got {velocity!r}")
    n_lines = int(np.asarray(lines.omega).size)
    heard = np.asarray(lines.heard, bool).reshape(2, -1)
    if n_lines == 0 or not heard.any():
        return _no_band(lines, d1, d2, n_lines)
    if n_lines > 4 * NMAX:
        raise ValueError(f"at most {4 * NMAX} lines, got {n_lines}")
    dat = _measurements(lines, d1, d2, float(g[0]), float(g[1]),
                        None if shallow_gain_ratio is None else float(shallow_gain_ratio), ratio_floor, cross_floor)
    # float64 here whatever the caller chose: the frequencies carry relative errors near 1e-5, and in float32 the
    # Levenberg-Marquardt solves stall on three of the four sign choices of two modes, so that a net's other
    # choices go missing from its alternatives (the scope ends here; nothing global is switched)
    if window != "gaussian":
        # the Hertz disk's errors (its table's, and a real contact's departure from the disk) and, where both
        # windows are compared, the same for the Gaussian window, so that their chi-squares compare
        dat = dat._replace(srx=np.hypot(dat.srx, WINDOW_FLOOR), sry=np.hypot(dat.sry, WINDOW_FLOOR),
                           sc=np.hypot(dat.sc, WINDOW_FLOOR))
    with jax.enable_x64(True):
        fits = {}
        for name in (("gaussian", "hertz") if window is None else (window,)):
            coef = None
            if name == "hertz":
                from ..model.hertz import hertz_table

                coef = jnp.asarray(hertz_table().coef)
            fits[name] = _Fitter(lines, dat, contact_radius, velocity, (lo_a, hi_a), coef).run()._replace(window=name)
    return _plain(fits[window] if window is not None else _choose_window(fits["gaussian"], fits["hertz"]))


def _choose_window(g: LineFit, h: LineFit) -> LineFit:
    """The fit of the contact window the lines prefer, by the joint analysis's rule (``analysis.WINDOW_DECISIVE``).

    A fit that explains the lines (``ok``) wins over one that does not. Between two that do, the chi-square
    margin in units of the better reduced chi-square decides where it reaches ``WINDOW_DECISIVE``; below it the
    lines cannot tell the windows apart, the Hertz disk's fit is kept (a fingertip's contact is one) and a and
    the speeds are averaged over both by their Akaike weights, their errors holding both readings."""
    from .analysis import WINDOW_DECISIVE

    def explains(f):
        return f.status == "ok"

    if explains(g) != explains(h):
        return g if explains(g) else h
    if not (math.isfinite(g.chi2) and math.isfinite(h.chi2)):
        return h if math.isfinite(h.chi2) and not math.isfinite(g.chi2) else g
    scale = max(1.0, min(g.redchi if math.isfinite(g.redchi) else 1.0, h.redchi if math.isfinite(h.redchi) else 1.0))
    margin = (g.chi2 - h.chi2) / scale
    if not explains(g):             # neither explains the lines: the closer
        return (h if margin >= 0 else g)._replace(window_margin=margin)
    if margin >= WINDOW_DECISIVE:
        return h._replace(window_margin=margin)
    if margin <= -WINDOW_DECISIVE:
        return g._replace(window_margin=margin)
    w_h = 1.0 / (1.0 + math.exp(-0.5 * margin))
    out, notes = {}, []
    for name in ("a", "vx", "vy"):
        vh, vg = getattr(h, name), getattr(g, name)
        eh, eg = getattr(h, name + "_err"), getattr(g, name + "_err")
        if None in (vh, vg, eh, eg):
            if name == "a" and (vh is None) != (vg is None):        # one window's reading, said, not averaged
                notes.append(f"a {1e3 * vg:.4g} +/- {1e3 * (eg or 0.0):.2g} mm under the Gaussian window, none under "
                             "the Hertz disk" if vh is None else
                             f"a {1e3 * vh:.4g} +/- {1e3 * (eh or 0.0):.2g} mm under the Hertz disk, none under the "
                             "Gaussian window")
            continue
        mean = w_h * vh + (1.0 - w_h) * vg
        var = w_h * (eh ** 2 + (vh - mean) ** 2) + (1.0 - w_h) * (eg ** 2 + (vg - mean) ** 2)
        out[name], out[name + "_err"] = mean, math.sqrt(var)
        if abs(vh - vg) > 1e-9 * max(abs(vh), abs(vg), 1e-300):
            unit, f = ("mm", 1e3) if name == "a" else ("cm/s", 1e2)
            notes.append(f"{name} {vh * f:.4g} (Hertz) or {vg * f:.4g} (Gaussian) {unit}, averaged "
                         f"{mean * f:.4g} +/- {math.sqrt(var) * f:.2g} {unit}")
    msg = h.message + (f"; the lines do not tell the contact windows apart (chi2 margin {margin:.2g}): "
                       f"{'; '.join(notes)} (Akaike weights, Hertz {w_h:.2f})" if notes else "")
    return h._replace(message=msg, window_margin=margin, **out)


def _plain(res: LineFit) -> LineFit:
    """numpy scalars as Python floats (tuples of them too), for printing and JSON."""
    def conv(v):
        if isinstance(v, (np.floating, np.integer)):
            return v.item()
        if isinstance(v, tuple):
            return tuple(conv(x) for x in v)
        return v

    return res._replace(**{k: conv(getattr(res, k)) for k in res._fields if k != "lines"})


class _Fitter:
    """The decision logic of ``fit_lines`` on one record's measurements."""

    def __init__(self, lines, dat: _Data, a_known, v_known, a_range, coef=None):
        self.lines, self.dat = lines, dat
        #: the Hertz table's coefficients (the Hertz disk) or None (the Gaussian window). The starts, the level
        #: scan and the readings outside the fit invert the Gaussian window's separable curves; under the Hertz
        #: disk they do so at the Gaussian radius of the same second moment (``ga`` times a): starting points
        #: and screens, which the solves then refine under the disk
        self.coef = coef
        self.ga = 1.0 if coef is None else 1.0 / HERTZ_PER_GAUSS
        self.a_known, self.v_known = a_known, v_known
        self.a_grid = np.geomspace(a_range[0], a_range[1], 9) if a_known is None else np.asarray([a_known])
        self.n = dat.w.size
        inv_x = dat.hx | dat.hc
        inv_y = dat.hy | dat.hc
        n_meas = dat.hx.astype(int) + dat.hy + dat.hc
        self.two_d = inv_x & inv_y & (n_meas >= 2) & (dat.hx | dat.hy)
        if v_known is not None:
            self.two_d = (dat.hx | dat.hy)
        self.inv_x, self.inv_y = inv_x, inv_y
        #: the pair (0 x, 1 y) whose ratio of a line the right angle of a square net supplied (``_square_net``):
        #: an ok result then needs a combination line measured in it
        self.check_pairs = None
        #: what an unchecked square-net reading gives (set by ``_multi_result``; '' where nothing)
        self.reading = ""
        #: the Hertz disk's radii (m) in distinct basins that fit the lines within ``AMBIGUITY_CHI2`` of the best
        #: (``_hertz_scan``): two or more and the lines do not determine a under the disk
        self.hertz_basins = ()

    # ---- helpers
    def _slots(self, sel):
        idx = np.flatnonzero(sel)
        if idx.size > NMAX:       # keep the best measured
            score = -(np.where(self.dat.hx, self.dat.srx, 0) + np.where(self.dat.hy, self.dat.sry, 0))[idx]
            idx = np.sort(idx[np.argsort(score)[::-1][:NMAX]])
        return idx

    def _a_sd(self, fit):
        return math.sqrt(max(fit.cov[0, 0], 0.0) * _scale(fit))

    # ---- the 2-D model
    def _fit_2d(self, slots, a0, free_a, v_start=None, n_cand=6):
        """Best 2-D fit from the velocity candidates at a0 (m); returns a list of fits (best first)."""
        dat = self.dat
        sel = np.zeros(self.n, bool)
        sel[slots] = True
        kx, ky = _start_k(dat, a0 * self.ga, sel)
        vk = self.v_known
        free_kx = sel & (self.inv_x | ((vk is not None) and vk[0] > 0))
        free_ky = sel & (self.inv_y | ((vk is not None) and vk[1] > 0))
        # a component that no level measures starts where omega puts it (known v) or at 1/mm; one that stays
        # unmeasured is held there (the Gaussian window's ratios do not depend on it) or, under the Hertz disk,
        # whose x pair's ratio depends on ky, at 0: where that pair hears the mode best
        kx = np.where(np.isnan(kx) & sel, np.where(free_kx | (self.coef is None), 1e3, _K_NONE), kx)
        ky = np.where(np.isnan(ky) & sel, np.where(free_ky | (self.coef is None), 1e3, _K_NONE), ky)
        if self.coef is not None:
            kx, ky = self._hertz_starts(a0, kx, ky, sel, free_kx, free_ky)
        # omega = |kx vx + t ky vy| constrains a line where each component is fitted or drops out: a speed known
        # to be 0 takes its component out, so the line's frequency fixes the other, and its pair's ratio then
        # fixes a (the paper's Fig. 7: a from the known v)
        zero = (False, False) if vk is None else (vk[0] == 0, vk[1] == 0)
        mw = sel & (free_kx | zero[0]) & (free_ky | zero[1])
        if self.coef is not None:
            # a component whose best start is 0 is held there: the disk's response is flat in it about 0, so a
            # free log |k| would drift towards -infinity and the solve never settle
            free_kx, free_ky = free_kx & (kx > _K_NONE), free_ky & (ky > _K_NONE)
        if vk is not None:
            starts = [vk]
        elif v_start is not None:
            starts = [v_start]
        else:
            use = sel & self.two_d
            starts = _velocity_candidates(kx[use], ky[use], dat.w[use], n_cand=n_cand)
        fits = []
        for v0 in starts:
            t = _best_signs(kx, ky, dat.w, *v0)
            fit = None
            for _ in range(3):
                fit = _run(dat, slots, family=False, harm=np.ones(self.n), t=t, a0=a0, v0=v0, kx0=kx, ky0=ky,
                           free_a=free_a, free_v=vk is None, free_kx=free_kx, free_ky=free_ky, mw=mw, coef=self.coef)
                th = fit.theta
                kx1 = np.full(self.n, np.nan)
                ky1 = np.full(self.n, np.nan)
                kx1[slots] = _K_UNIT * np.exp(th[_NG:_NG + len(slots)])
                ky1[slots] = _K_UNIT * np.exp(th[_NG + NMAX:_NG + NMAX + len(slots)])
                v1 = (abs(th[1]) * _V_UNIT, abs(th[2]) * _V_UNIT)
                # a sign flip of vx or vy in the fit is a flip of every t
                flip = np.sign(th[1]) * np.sign(th[2]) if th[1] * th[2] != 0 else 1.0
                t_new = _best_signs(kx1, ky1, dat.w, *v1)
                if np.array_equal(t_new[slots], (t * flip)[slots]):
                    break
                t, v0, kx, ky, a0 = t_new, v1, kx1, ky1, 1e-3 * math.exp(th[0])
            fits.append(fit)
        fits.sort(key=lambda f: f.chi2)
        return fits

    def _candidates(self, kx, ky, idx, free_kx, free_ky, grid):
        """Each line's candidate (|kx|, |ky|) pairs (``_hertz_starts``): the grid for a free component, its
        frequency's value for the other where the velocity is given, its start where it is held."""
        dat, vk = self.dat, self.v_known
        cands = []
        for j in idx:
            gx = grid if free_kx[j] else np.array([kx[j]])
            gy = grid if free_ky[j] else np.array([ky[j]])
            if vk is not None and free_kx[j] and vk[0] > 0:          # kx from the frequency, for each ky and sign
                gy = np.concatenate([gy, gy])
                gx = np.abs(dat.w[j] - np.repeat([1.0, -1.0], gy.size // 2) * gy * vk[1]) / vk[0]
            elif vk is not None and free_ky[j] and vk[1] > 0:
                gx = np.concatenate([gx, gx])
                gy = np.abs(dat.w[j] - np.repeat([1.0, -1.0], gx.size // 2) * gx * vk[0]) / vk[1]
            else:
                gx, gy = (g.ravel() for g in np.meshgrid(gx, gy, indexing="ij"))
            cands.append((np.maximum(gx, _K_NONE), np.maximum(gy, _K_NONE)))
        return cands

    def _line_costs(self, cands, idx, radii, floor=0.0, robust=False):
        """(R, L): each line's least misfit (its ratios and cross level: squared z, or ``_robust`` where ``robust``;
        ``floor`` added to their errors in quadrature) over its candidates, at each of ``radii`` (R,) m, and the
        index of the best candidate."""
        dat = self.dat
        term = _robust if robust else np.square
        sizes = [c[0].size for c in cands]
        # few shapes, so few compilations: modes padded to a power of 2, radii one at a time or in blocks
        n_pad = max(1024, 1 << (sum(sizes) - 1).bit_length())
        all_x, all_y = np.full(n_pad, 1e3), np.full(n_pad, 1e3)
        all_x[:sum(sizes)] = np.concatenate([c[0] for c in cands])
        all_y[:sum(sizes)] = np.concatenate([c[1] for c in cands])
        radii = np.asarray(radii, float)
        block = 1 if radii.size == 1 else _RADII_BLOCK
        padded = np.concatenate([radii, np.full(-radii.size % block, radii[-1])])
        lh = np.concatenate([np.asarray(_responses_over(jnp.asarray(all_x), jnp.asarray(all_y), dat.d1, dat.d2,
                                                        jnp.asarray(padded[i:i + block]), self.coef))
                             for i in range(0, padded.size, block)])[:radii.size]          # (R, 2, 2, N)
        costs, best = np.zeros((len(radii), len(idx))), np.zeros((len(radii), len(idx)), int)
        start = 0
        for i, (size, j) in enumerate(zip(sizes, idx)):
            h = lh[..., start:start + size]
            start += size
            cost = np.zeros((len(radii), size))
            if dat.hx[j]:
                cost += term((h[:, 1, 0] - h[:, 0, 0] + dat.lgx - dat.lrx[j]) / np.hypot(dat.srx[j], floor))
            if dat.hy[j]:
                cost += term((h[:, 1, 1] - h[:, 0, 1] + dat.lgy - dat.lry[j]) / np.hypot(dat.sry[j], floor))
            if dat.hc[j]:
                cost += term((h[:, 0, 1] - h[:, 0, 0] + dat.lrho - dat.lc[j]) / np.hypot(dat.sc[j], floor))
            best[:, i] = np.argmin(cost, 1)
            costs[:, i] = cost[np.arange(len(radii)), best[:, i]]
        return costs, best

    def _hertz_starts(self, a, kx, ky, sel, free_kx, free_ky):
        """Starting |kx|, |ky| of lines ``sel`` under the Hertz disk of radius ``a``: each line's best pair among
        its candidates (``_candidates`` on ``_K_START_GRID``) by its own ratios and cross level. The Gaussian
        window's inversions start the disk's solves in wrong basins: at a small |k_s| the disk's ratio depends
        on k_p (a mode along x rings the y pair with a deep/shallow ratio above 1), which the Gaussian
        window's cannot."""
        idx = np.flatnonzero(sel)
        cands = self._candidates(kx, ky, idx, free_kx, free_ky, _K_START_GRID)
        _, best = self._line_costs(cands, idx, [a])
        kx, ky = kx.copy(), ky.copy()
        for (cx, cy), b, j in zip(cands, best[0], idx):
            kx[j], ky[j] = cx[b], cy[b]
        return kx, ky

    def _hertz_scan(self):
        """The Hertz disk's radius (m) that best explains the lines heard in both components (with the velocity
        given, every line heard), each at its best wavevector (``_line_costs``), on a grid of ``a_range``;
        None where no line can say. Its solves are multimodal in a: from the profile's radii (1.45 apart)
        they end in wrong basins. The lines' errors (0.1-5 % in their ratios) make the misfit too sharp for a grid
        of radii: the scan adds ``_SCAN_FLOOR`` to them, and a measurement near a zero of the disk's response
        (its log swings with a) counts at most logarithmically, to find the basin the solve then refines."""
        idx = self._slots(self.two_d)
        if idx.size == 0:
            return None
        vk = self.v_known
        free_kx = self.inv_x | ((vk is not None) and vk[0] > 0)
        free_ky = self.inv_y | ((vk is not None) and vk[1] > 0)
        grid = _K_START_GRID if vk is not None else _K_SCAN_GRID
        # the responses to a mode along a probe oscillate in a (the disk's J1): a fine grid where the velocity is
        # given (each line's candidates are then its ky alone), a coarser one over the 2-D grid of wavevectors
        radii = np.geomspace(self.a_grid[0], self.a_grid[-1], 400 if vk is not None else 49)
        at_zero = np.full(self.n, _K_NONE)           # a component no level measures is held at 0
        cands = self._candidates(at_zero, at_zero, idx, free_kx, free_ky, grid)
        costs, _ = self._line_costs(cands, idx, radii, floor=_SCAN_FLOOR, robust=True)
        total = costs.sum(1)
        i = int(np.argmin(total))
        if not np.isfinite(total[i]) or total.max() - total[i] < AMBIGUITY_CHI2:
            return None
        # then the lines' own errors on a fine grid (0.1 % apart) about each of the coarse scan's best minima: a
        # line near a zero of the response pins a to 0.3 %, finer than the coarse grid, so the true basin need not
        # be the coarse scan's lowest
        pad = np.concatenate([[np.inf], total, [np.inf]])
        minima = [int(j) for j in np.argsort(total, kind="stable") if pad[j + 1] <= min(pad[j], pad[j + 2])]
        seeds = []
        for j in minima:
            if all(abs(math.log(radii[j] / radii[k])) > 0.05 for k in seeds):
                seeds.append(j)
            if len(seeds) == _N_SCAN_MINIMA:
                break
        fine = (radii[seeds][:, None] * np.geomspace(0.95, 1.0 / 0.95, 101)[None, :]).ravel()
        costs, _ = self._line_costs(cands, idx, fine)
        total = costs.sum(1)
        # the disk's responses oscillate in a: where few lines are heard (one line's ratio, at a known slip) other
        # basins fit as well, and the best one's curvature says nothing of them
        per_seed = total.reshape(len(seeds), -1)
        best = np.argmin(per_seed, axis=1)
        low = per_seed[np.arange(len(seeds)), best]
        near = np.flatnonzero(low <= total.min() + AMBIGUITY_CHI2)
        found = sorted(zip(fine.reshape(len(seeds), -1)[near, best[near]], low[near]))
        if len(found) > 1:
            # neighbours are one basin unless the misfit rises between them (by more than 1, a sigma in a)
            path = np.concatenate([np.geomspace(r0, r1, 34)[1:-1] for (r0, _), (r1, _) in zip(found, found[1:])])
            rise, _ = self._line_costs(cands, idx, path)
            rise = rise.sum(1).reshape(len(found) - 1, -1).max(1)
            keep = [found[0]]
            for (r, c), top in zip(found[1:], rise):
                if top > max(c, keep[-1][1]) + 1.0:
                    keep.append((r, c))
                elif c < keep[-1][1]:
                    keep[-1] = (r, c)
            found = keep
        self.hertz_basins = tuple(float(r) for r, _ in found)
        return float(fine[int(np.argmin(total))])

    # ---- the family model
    def _fit_family(self, slots, harm, a0, free_a):
        dat = self.dat
        sel = np.zeros(self.n, bool)
        sel[slots] = True
        kx, ky = _start_k(dat, a0 * self.ga, sel)
        has_x, has_y = bool(self.inv_x[sel].any()), bool(self.inv_y[sel].any())
        unmeasured = 1e3 if self.coef is None else _K_NONE          # as in ``_fit_2d``
        fx = np.nanmedian(kx[sel] / harm[sel]) if np.isfinite(kx[sel]).any() else unmeasured
        fy = np.nanmedian(ky[sel] / harm[sel]) if np.isfinite(ky[sel]).any() else unmeasured
        both = has_x and has_y
        k0 = math.hypot(fx, fy)
        w0 = np.median(dat.w[sel] / harm[sel])
        v0 = (w0 / k0, 0.0)
        mw = sel if both else np.zeros(self.n, bool)
        return _run(dat, slots, family=True, harm=harm, t=np.ones(self.n), a0=a0, v0=v0, kx0=np.asarray([fx]),
                    ky0=np.asarray([fy]), free_a=free_a, free_v=both, free_kx=has_x, free_ky=has_y, mw=mw,
                    coef=self.coef)

    # ---- profile over a, then free
    def _profile(self, fitfn):
        """fitfn(a0, free_a, final) -> list of fits. Returns (the fits with a free or given, best first; the
        profile [(a, best fit at a fixed a)] over ``a_grid``)."""
        if self.a_known is not None:
            fits = fitfn(float(self.a_known), False, True)
            return fits, [(float(self.a_known), fits[0])] if fits else []
        a0 = self._level_scan() if self.coef is None else self._hertz_scan()
        if a0 is not None:
            # the levels fix a: start there; the profile only where the fit then leaves a undetermined
            fits = fitfn(a0, True, True)
            if fits and self._a_ok(fits[0]):
                return fits, []
        prof = []
        for a in self.a_grid:
            fits = fitfn(float(a), False, False)
            if fits:
                prof.append((float(a), fits[0]))
        if not prof:
            return [], prof
        a_best = min(prof, key=lambda p: p[1].chi2)[0]
        return fitfn(a_best, True, True), prof

    def _level_scan(self):
        """The contact radius (m) that best explains the lines measured three times (both ratios and the cross
        level: each fixes a by itself), on a grid of 0.2-20 mm; None where no line is."""
        dat = self.dat
        full = self.two_d & dat.hx & dat.hy & dat.hc
        if not full.any():
            return None
        grid = np.geomspace(0.2e-3, 20e-3, 41)
        cost = []
        for a in grid * self.ga:
            kx = invert_ratio(dat.lrx[full] - dat.lgx, a, dat.d1, dat.d2)
            ky = invert_ratio(dat.lry[full] - dat.lgy, a, dat.d1, dat.d2)
            z = (dat.lrho + _cross_f(ky, a, dat.d1, dat.d2) - _cross_f(kx, a, dat.d1, dat.d2) - dat.lc[full]) / dat.sc[full]
            cost.append(float(np.sum(_robust(z))))
        return float(grid[int(np.argmin(cost))])

    def run(self) -> LineFit:
        res = self._fit()
        if len(self.hertz_basins) > 1:
            radii = ", ".join(f"{1e3 * r:.3g}" for r in self.hertz_basins)
            res = res._replace(message=f"{res.message}; under the Hertz disk the lines fit a = {radii} mm as well "
                                       f"(chi2 within {AMBIGUITY_CHI2:g}): they do not determine a")
        return res

    def _fit(self) -> LineFit:
        dat = self.dat
        base = dict(n_lines=self.n)
        if self.v_known is None and not self.two_d.any():
            return self._single_pair_only()
        # one family?
        w0, harm = _harmonic_numbers(dat.w, dat.sw, dat.d_omega, self.two_d)
        if self.v_known is None and w0 is not None:
            # single-pair lines that are harmonics of the family join it (they carry its a)
            extra = (dat.hx | dat.hy) & ~self.two_d
            n_extra = np.rint(dat.w / w0)
            tol = _omega_tol(dat.sw, dat.d_omega)
            join = extra & (n_extra >= 1) & (n_extra <= MAX_HARMONIC) & (np.abs(dat.w - n_extra * w0) <= tol)
            harm = np.where(join, n_extra, harm)
            fam_sel = self.two_d | join
            # lines at no harmonic of the family (any order): other directions, so not one grating
            w0_err = float(np.min(dat.sw[self.two_d] / np.maximum(harm[self.two_d], 1.0)))
            others = ~fam_sel & (np.abs(dat.w - n_extra * w0) > tol + 4.0 * n_extra * w0_err)
            slots = self._slots(fam_sel)
            fits, prof = self._profile(lambda a, fa, final: [self._fit_family(slots, harm, a, fa)])
            fit = self._drop_outliers(fits[0], lambda s: self._fit_family(s, harm, 1e-3 * math.exp(fits[0].theta[0]),
                                                                          self.a_known is None), slots)
            if _p_value(fit[0].chi2, fit[0].dof) >= P_POOR or self.two_d.sum() == 1:
                return self._grating_result(fit, prof, harm, others=others, **base)
        # two or more directions
        slots = self._slots(self.two_d)
        if self.v_known is None and len(slots) < 2:
            return LineFit("poor_fit", "the lines are not one family and fewer than two are measured in both "
                           "components", **base)
        fits, prof = self._profile(lambda a, fa, final: self._fit_2d(slots, a, fa, n_cand=6 if final else 2))
        if not fits:
            return LineFit("poor_fit", "no fit", **base)
        best = self._drop_outliers(fits[0], lambda s: self._fit_2d(s, 1e-3 * math.exp(fits[0].theta[0]),
                                                                   self.a_known is None,
                                                                   v_start=(abs(fits[0].theta[1]) * _V_UNIT,
                                                                            abs(fits[0].theta[2]) * _V_UNIT))[0],
                                   slots)
        return self._multi_result(best, fits[1:], prof, **base)

    def _drop_outliers(self, fit, refit, slots):
        """Drop the worst line (z > DROP_Z) while the fit is poor, at most a quarter of the lines, keeping dof >= 1.
        The last line a pair hears is never dropped: without it the other pair's lines, each with its own unknown
        wavenumber component, would carry the whole fit (a wire net under the Hertz disk, whose lines no model of
        one mode a line explains, then read a = 3.44 +/- 0.0002 mm for 2.45 from three lines the y pair alone
        hears, its fundamental dropped)."""
        dropped = np.zeros(self.n, bool)
        slots = np.asarray(slots)
        max_drop = len(slots) // 4
        heard = np.stack([self.dat.hx, self.dat.hy])
        while (_p_value(fit.chi2, fit.dof) < P_POOR and dropped.sum() < max_drop and fit.dof >= 2):
            kept = np.isin(np.arange(self.n), slots)
            last = np.any(heard & (heard[:, kept].sum(axis=1) == 1)[:, None], axis=0)
            z = np.where(kept & ~last, fit.z, -np.inf)
            worst = int(np.argmax(z))
            if z[worst] < DROP_Z:
                break
            dropped[worst] = True
            slots = slots[slots != worst]
            fit = refit(slots)
        return fit, slots, dropped

    # ---- results
    def _k_table(self, fit, slots, family, harm):
        n = self.n
        kx, ky, kxe, kye = (np.full(n, np.nan) for _ in range(4))
        sc = _scale(fit)
        cov = fit.cov * sc
        if family:
            lx, ly = fit.theta[3], fit.theta[4]
            for j in slots:
                kx[j] = harm[j] * _K_UNIT * math.exp(lx)
                ky[j] = harm[j] * _K_UNIT * math.exp(ly)
                kxe[j] = kx[j] * math.sqrt(max(cov[3, 3], 0.0))
                kye[j] = ky[j] * math.sqrt(max(cov[4, 4], 0.0))
        else:
            for i, j in enumerate(slots):
                kx[j] = _K_UNIT * math.exp(fit.theta[_NG + i])
                ky[j] = _K_UNIT * math.exp(fit.theta[_NG + NMAX + i])
                kxe[j] = kx[j] * math.sqrt(max(cov[_NG + i, _NG + i], 0.0))
                kye[j] = ky[j] * math.sqrt(max(cov[_NG + NMAX + i, _NG + NMAX + i], 0.0))
        # components no level measures stay undetermined
        unk_x = ~self.inv_x if self.v_known is None else np.zeros(n, bool)
        unk_y = ~self.inv_y if self.v_known is None else np.zeros(n, bool)
        kx[unk_x], kxe[unk_x], ky[unk_y], kye[unk_y] = np.nan, np.nan, np.nan, np.nan
        return kx, kxe, ky, kye

    def _fill_single(self, kx, kxe, ky, kye, a, a_sd):
        """|k_s| of lines outside the fit from their own pair's ratio at the fitted a."""
        a = None if a is None else a * self.ga
        sx, sxe = _single_k(self.dat, a, a_sd, 0)
        sy, sye = _single_k(self.dat, a, a_sd, 1)
        fill_x, fill_y = np.isnan(kx) & np.isfinite(sx), np.isnan(ky) & np.isfinite(sy)
        kx, kxe = np.where(fill_x, sx, kx), np.where(fill_x, sxe, kxe)
        ky, kye = np.where(fill_y, sy, ky), np.where(fill_y, sye, kye)
        return kx, kxe, ky, kye

    def _a_ok(self, fit) -> bool:
        """The fit with a free determines a: converged, well posed, sd(log a) <= A_DETERMINED, and (under the Hertz
        disk) no other basin of a fits the lines as well."""
        return (fit.converged and fit.determined and 0 < self._a_sd(fit) <= A_DETERMINED
                and len(self.hertz_basins) < 2)

    def _a_report(self, fit, prof):
        """(a, a_err, source, marginalise?)"""
        if self.a_known is not None:
            return float(self.a_known), 0.0, "given", False
        if self._a_ok(fit):
            a = 1e-3 * math.exp(fit.theta[0])
            return a, a * self._a_sd(fit), "fit", False
        return None, None, "marginalised", True

    @staticmethod
    def _marginal(prof, i):
        """(mean, sd, lo, hi) of |theta[i]| (m/s) over the well-posed fits of the a profile, a mixture weighted
        by exp(-chi2 / 2) (a flat prior in log a over ``a_range``); None where no fit of it is well posed."""
        good = [f for _, f in prof if f.determined and f.converged]
        if not good:
            return None
        vals = [(abs(f.theta[i]) * _V_UNIT, math.sqrt(max(f.cov[i, i] * _scale(f), 0.0)) * _V_UNIT, f.chi2)
                for f in good]
        return _Fitter._mixture(*zip(*vals))

    @staticmethod
    def _mixture(values, errs, chi2s):
        """Mean and sd of a mixture over the a profile, weighted by exp(-chi2 / 2)."""
        c = np.asarray(chi2s, float)
        wts = np.exp(-(c - c.min()) / 2.0)
        wts /= wts.sum()
        v = np.asarray(values, float)
        mean = float(np.sum(wts * v))
        var = float(np.sum(wts * (np.square(errs) + np.square(v - mean))))
        return mean, math.sqrt(var), float(np.min(v - 2 * np.asarray(errs))), float(np.max(v + 2 * np.asarray(errs)))

    def _minor_margin(self, a, slots, harm, lx, ly, others):
        """(margin dB, line, pair): how much more relief amplitude the strongest line of ``others`` carries than
        the family (``slots``, harmonics ``harm`` of the fitted log |kx0|, log |ky0| ``lx``, ``ly``), at radius ``a``.

        A mode of amplitude A rings pair x's shallow probe with power g_x1^2 A^2 H_x^2, H_x = G(|kx|; d1, a)
        W(ky) and W(k) = exp(-a^2 k^2 / 6) (``model.probe.line_response``; y likewise, g_y1 = rho g_x1). A
        family line's A follows from its level and its fitted wavevector (the pair with the higher level); a
        line outside it gives a lower bound, with W <= 1 and |k_s| from its pair's ratio at ``a`` (G <= 1
        where no pair's ratio is measured). Levels: main-lobe powers (``Lines.shallow_power``), or the dB
        above the background where the lines carry none.
        """
        dat = self.dat
        db = np.asarray(self.lines.shallow_db, float)
        power = getattr(self.lines, "shallow_power", None)
        if power is not None:
            db = 10.0 * np.log10(np.maximum(np.asarray(power, float), 1e-300))
        db = db - np.array([[0.0], [20.0 / math.log(10.0) * dat.lrho]])       # in units of g_x1^2
        to_db = 20.0 / math.log(10.0)

        def log_gain(k):                                                      # log G(|k|; d1, a)
            k = np.asarray(k, float)
            return _cross_f(k, a, dat.d1, dat.d2) - np.square(a * k) / 6.0

        fam = -np.inf
        for j in slots:
            kx, ky = harm[j] * _K_UNIT * math.exp(lx), harm[j] * _K_UNIT * math.exp(ly)
            log_h = (float(log_gain(kx)) - (a * ky) ** 2 / 6.0, float(log_gain(ky)) - (a * kx) ** 2 / 6.0)
            q = int(np.argmax(db[:, j]))
            fam = max(fam, db[q, j] - to_db * log_h[q])
        best = (-np.inf, -1, 0)
        for u in np.flatnonzero(others):
            for q, (h, lr, lgain) in enumerate(((dat.hx, dat.lrx, dat.lgx), (dat.hy, dat.lry, dat.lgy))):
                if h[u]:
                    k_s = float(invert_ratio(lr[u] - lgain, a, dat.d1, dat.d2))
                    bound = db[q, u] - to_db * float(log_gain(k_s))
                elif not (dat.hx[u] or dat.hy[u]):
                    bound = db[q, u]                                          # H <= 1
                else:
                    continue
                if bound > best[0]:
                    best = (bound, int(u), q)
        return best[0] - fam, best[1], best[2]

    def _grating_result(self, fitted, prof, harm, others=None, **base):
        fit, slots, dropped = fitted
        others = np.zeros(self.n, bool) if others is None else np.asarray(others, bool)
        n_other = int(others.sum())
        dat = self.dat
        sc = _scale(fit)
        cov = fit.cov * sc
        has_x, has_y = bool(self.inv_x[slots].any()), bool(self.inv_y[slots].any())
        a, a_err, a_src, marg = self._a_report(fit, prof)
        kx, kxe, ky, kye = self._k_table(fit, slots, True, harm)
        kx, kxe, ky, kye = self._fill_single(kx, kxe, ky, kye, a, None if a is None else a_err / a)
        used = np.isin(np.arange(self.n), slots)
        table = _table(self.lines, dat, np.where(used, harm, 0), used, dropped, kx, kxe, ky, kye,
                       np.where(used, 1.0, 0.0))
        p = _p_value(fit.chi2, fit.dof)
        stats = dict(chi2=fit.chi2, redchi=fit.chi2 / fit.dof if fit.dof else float("nan"), dof=fit.dof,
                     n_used=len(slots), n_dropped=int(dropped.sum()), lines=table,
                     texture="multi" if n_other else "grating")
        lx, ly = fit.theta[3], fit.theta[4]
        ang = math.degrees(math.atan2(math.exp(ly), math.exp(lx)))
        sc_ = math.sin(math.radians(ang)) * math.cos(math.radians(ang))
        ang_err = math.degrees(abs(sc_) * math.sqrt(max(cov[3, 3] + cov[4, 4] - 2 * cov[3, 4], 0.0)))
        w0 = float(np.median(dat.w[slots] / harm[slots]))
        if not (has_x and has_y):
            comp = "x" if has_x else "y"
            k_s = _K_UNIT * math.exp(lx if has_x else ly)
            hi = w0 / k_s if a is not None else None
            msg = (f"one family of lines heard by the {comp} pair only: |k{comp}| = {k_s:.0f} rad/m"
                   + ("" if a is not None else " (a not determined: |k| depends on it)")
                   + "; the other component is unknown, so the speed along the normal is only bounded "
                   f"(v_n <= omega0 / |k{comp}|" + (f" = {hi:.4g} m/s)" if hi else ")")
                   + "; vx, vy undetermined (aperture problem)")
            return LineFit("undetermined", msg, a=a, a_err=a_err, a_source=a_src,
                           v_n_bounds=(0.0, hi) if hi else None, **stats, **base)
        v_n, v_n_err = fit.theta[1] * _V_UNIT, math.sqrt(max(cov[1, 1], 0.0)) * _V_UNIT
        bounds = None
        status = "poor_fit" if p < P_POOR else "undetermined"
        harmonics = sorted(set(int(h) for h in harm[slots]))
        note = ""
        if n_other:
            # the family against the other lines at its radius (an undetermined a: every radius of the profile
            # that fits about as well, with that fit's wavevector; the margin shrinks as a grows)
            if marg:
                c0 = min((f.chi2 for _, f in prof if f.converged), default=math.inf)
                cands = [(r, f.theta[3], f.theta[4]) for r, f in prof if f.converged and f.chi2 <= c0 + AMBIGUITY_CHI2]
            else:
                cands = [(1e-3 * math.exp(fit.theta[0]), lx, ly)]
            margin, u, pair, a_fit = -math.inf, -1, 0, float("nan")
            for r, fx, fy in cands:
                m_ = self._minor_margin(r * self.ga, slots, harm, fx, fy, others)
                if m_[0] > margin:
                    (margin, u, pair), a_fit = m_, r
            if margin > MINOR_DB and p >= P_POOR:
                msg = (f"the lines measured in both components form one family ({len(slots)} line(s), harmonics "
                       f"{harmonics}, normal at {ang:.1f} deg), but it is a minor mode of the texture: the line at "
                       f"{dat.w[u]:.1f} rad/s ({'xy'[pair]} pair, no harmonic of it) carries at least {margin:.0f} dB "
                       f"more relief amplitude (levels over the window's responses at a = {a_fit * 1e3:.3g} mm), so "
                       "the family is a weak harmonic or combination of lines in other directions (or a mode aliased "
                       "by a simulation's grid) and its normal is not the texture's; the texture's lines "
                       f"({n_other} line(s) outside the family) are each measured in one component only, so the "
                       "speeds and the speed along the texture's normals are undetermined (the family alone would "
                       f"give omega0 / |k0| = {v_n:.3g} m/s)")
                return LineFit("undetermined", msg, a=a, a_err=a_err, a_source=a_src, **stats, **base)
            note = (f"; {n_other} other line(s), at no harmonic of the family, lie in other directions (each measured "
                    "in one component): the texture is not one grating, and the normal is its family's")
            if not marg and p >= P_POOR and self.check_pairs is None:
                net, reading = self._square_net(lx, ly, 1e-3 * math.exp(fit.theta[0]), others)
                if net is not None:
                    return net
                note += reading
        ill = marg and self._marginal(prof, 1) is None or (not marg and not fit.determined)
        if ill and p >= P_POOR:
            return LineFit(status, "one family of parallel lines (a grating) whose lines leave a combination of "
                           "its parameters undetermined (the speed along its normal among them); vx, vy undetermined "
                           "(aperture problem)" + note, a=a, a_err=a_err, a_source=a_src, **stats, **base)
        if marg and not ill:
            v_n, v_n_err, lo, hi = self._marginal(prof, 1)
            bounds = (max(lo, 0.0), hi)
        if v_n_err > MAX_REL_ERR * abs(v_n) and p >= P_POOR:
            if bounds is None:
                bounds = (max(v_n - 2 * v_n_err, 0.0), v_n + 2 * v_n_err)
            why = ("whose lines do not determine a: over a in "
                   f"[{self.a_grid[0] * 1e3:.1g}, {self.a_grid[-1] * 1e3:.1g}] mm" if marg else "loosely determined:")
            msg = (f"one family of parallel lines (a grating) {why} the speed along its normal spans "
                   f"{bounds[0]:.3g}-{bounds[1]:.3g} m/s (undetermined); vx, vy undetermined (aperture problem)" + note)
            return LineFit(status, msg, a=None, a_source=a_src, v_n_bounds=bounds, normal_angle=ang,
                           normal_angle_err=ang_err, **stats, **base)
        msg = (f"one family of parallel lines (a grating, {len(slots)} line(s), harmonics "
               f"{harmonics}): v_n = {v_n:.4g} +/- {v_n_err:.2g} m/s along the normal at "
               f"{ang:.1f} deg (or its mirror image at -{ang:.1f} deg); the component along the ridges, hence vx, vy, "
               "is undetermined (aperture problem)" + ("; a marginalised over its plausible range" if marg else "")
               + note)
        if p < P_POOR:
            return LineFit(status, f"the model does not explain the line(s) of this family: chi2 {fit.chi2:.1f} "
                           f"for {fit.dof} dof (p = {p:.1g}); its best fit would be v_n = {v_n:.4g} m/s along "
                           f"{ang:.1f} deg", **stats, **base)
        return LineFit(status, msg, a=a, a_err=a_err, a_source=a_src, v_n=v_n, v_n_err=v_n_err,
                       v_n_bounds=bounds, normal_angle=ang, normal_angle_err=ang_err, **stats, **base)

    def _multi_result(self, fitted, others, prof, _resolved="", **base):
        fit, slots, dropped = fitted
        base_resolved = _resolved
        dat = self.dat
        cov = fit.cov * _scale(fit)
        a, a_err, a_src, marg = self._a_report(fit, prof)
        kx, kxe, ky, kye = self._k_table(fit, slots, False, np.ones(self.n))
        kx, kxe, ky, kye = self._fill_single(kx, kxe, ky, kye, a, None if a is None else a_err / a)
        used = np.isin(np.arange(self.n), slots)
        flip = np.sign(fit.theta[1]) * np.sign(fit.theta[2]) if fit.theta[1] * fit.theta[2] != 0 else 1.0
        table = _table(self.lines, dat, np.zeros(self.n), used, dropped, kx, kxe, ky, kye,
                       np.where(used, fit.t * flip, 0.0))
        p = _p_value(fit.chi2, fit.dof)
        stats = dict(chi2=fit.chi2, redchi=fit.chi2 / fit.dof if fit.dof else float("nan"), dof=fit.dof,
                     n_used=len(slots), n_dropped=int(dropped.sum()), lines=table, texture="multi")
        vx, vy = abs(fit.theta[1]) * _V_UNIT, abs(fit.theta[2]) * _V_UNIT
        vxe, vye = (math.sqrt(max(cov[i, i], 0.0)) * _V_UNIT for i in (1, 2))
        known_v = self.v_known is not None
        if known_v:
            vx, vy = self.v_known
            vxe = vye = 0.0
        # equally good sign choices with different speeds
        rivals = []
        for f in others:
            if f.chi2 <= fit.chi2 + AMBIGUITY_CHI2:
                ux, uy = abs(f.theta[1]) * _V_UNIT, abs(f.theta[2]) * _V_UNIT
                if any(abs(u - v) > 3 * max(e, 1e-12) for u, v, e in ((ux, vx, vxe), (uy, vy, vye))):
                    if all(abs(ux - r[1]) > 1e-3 * (ux + 1e-9) or abs(uy - r[2]) > 1e-3 * (uy + 1e-9)
                           for r in rivals):
                        rivals.append((f, ux, uy))
        resolved = ""
        if rivals and not known_v:
            keep, resolved = self._decide([fit] + [r[0] for r in rivals], slots)
            if len(keep) == 1:
                if keep[0] > 0:
                    fit = rivals[keep[0] - 1][0]
                    return self._multi_result((fit, slots, dropped), [], prof, _resolved=resolved, **base)
                rivals = []
            else:
                rivals = [rivals[i - 1] for i in keep if i > 0]
                if 0 not in keep:            # the best fit itself ruled out: report the survivors
                    fit = rivals.pop(0)[0]
                    return self._multi_result((fit, slots, dropped), [f for f, _, _ in rivals], prof,
                                              _resolved=resolved, **base)
        resolved = resolved or base_resolved
        alts = [(vx, vy, fit.chi2)] + [(r[1], r[2], r[0].chi2) for r in rivals]
        ambiguous = bool(rivals)
        bounds = None
        common = dict(a=a, a_err=a_err, a_source=a_src, ambiguous=ambiguous,
                      alternatives=tuple(alts) if ambiguous else (), **stats, **base)
        ill = (not known_v and marg and self._marginal(prof, 1) is None) or (not marg and not fit.determined)
        if ill and p >= P_POOR:
            return LineFit("undetermined", "the lines leave a combination of the parameters undetermined "
                           f"({fit.n_data} data for {fit.n_free} free parameters, condition number {fit.cond:.1g})",
                           **common)
        if marg and not known_v:
            vx, vxe, lox, hix = self._marginal(prof, 1)
            vy, vye, loy, hiy = self._marginal(prof, 2)
            bounds = ((max(lox, 0.0), hix), (max(loy, 0.0), hiy))
        if p < P_POOR:
            return LineFit("poor_fit", f"the model does not explain the lines: chi2 {fit.chi2:.1f} for {fit.dof} dof "
                           f"(p = {p:.1g}) after dropping {int(dropped.sum())} line(s)",
                           **dict(common, a=None, a_err=None, a_source=None))
        if ambiguous:
            alt_txt = "; ".join(f"({u * 100:.3g}, {w * 100:.3g}) cm/s chi2 {c:.1f}" for u, w, c in alts)
            square = self._square_speed([fit] + [r[0] for r in rivals], slots)
            self.reading = square or f"{len(alts)} sign choices with different speeds"
            return LineFit("undetermined", f"{len(alts)} sign choices of the lines fit equally well with different "
                           f"speeds (|vx|, |vy|): {alt_txt}; more lines (or combination lines) would decide"
                           + (f"; {square}" if square else ""), **common)
        if self.check_pairs is not None:
            chi, n_m = self._combination_score(fit, slots, pairs=self.check_pairs)
            if n_m == 0 or _p_value(chi, n_m) < P_POOR:
                self.reading = (f"|vx| = {vx * 100:.4g} +/- {vxe * 100:.2g}, |vy| = {vy * 100:.4g} +/- {vye * 100:.2g} "
                                "cm/s")
                return LineFit("undetermined", "the right angle of a square net is not checked by a combination line "
                               f"(chi2 {chi:.1f} for {n_m} measurement(s)): {self.reading}", **common)
        speed = math.hypot(vx, vy)
        if not known_v and (vxe > MAX_REL_ERR * speed or vye > MAX_REL_ERR * speed):
            if bounds is None:
                bounds = ((max(vx - 2 * vxe, 0.0), vx + 2 * vxe), (max(vy - 2 * vye, 0.0), vy + 2 * vye))
            why = (f"the lines do not determine a, and over a in [{self.a_grid[0] * 1e3:.1g}, "
                   f"{self.a_grid[-1] * 1e3:.1g}] mm" if marg else "the lines determine the speeds only loosely:")
            return LineFit("undetermined", f"{why} the speeds span |vx| {bounds[0][0]:.3g}-{bounds[0][1]:.3g}, "
                           f"|vy| {bounds[1][0]:.3g}-{bounds[1][1]:.3g} m/s (2 sigma; relative errors above "
                           f"{MAX_REL_ERR:.0%})", speed_bounds=bounds, **common)
        msg = ((f"velocity given, {len(slots)} lines fitted: |vx| = {vx * 100:.4g}, |vy| = {vy * 100:.4g} cm/s"
                if known_v else f"{len(slots)} lines in two or more directions: |vx| = {vx * 100:.4g} +/- "
                f"{vxe * 100:.2g}, |vy| = {vy * 100:.4g} +/- {vye * 100:.2g} cm/s")
               + (f", a = {a * 1e3:.3g} +/- {a_err * 1e3:.2g} mm" if a is not None else ", a marginalised")
               + (f"; {int(dropped.sum())} line(s) dropped as outliers" if dropped.any() else "") + resolved)
        return LineFit("ok", msg, vx=vx, vx_err=vxe, vy=vy, vy_err=vye, speed_bounds=bounds, **common)

    def _square_net(self, lx, ly, a, others):
        """A family (fitted log |kx0|, log |ky0| = ``lx``, ``ly``; rad/mm, radius ``a``, m) and lines at other
        frequencies, each heard by one pair, read as a wire net whose second family crosses the first at
        right angles: (a LineFit, or None where that reading gives no checked speeds; what the unchecked
        readings give, for the message).

        Each other line (not a harmonic of another) in turn is taken as the second family's fundamental. It
        gives one component; the right angle gives the other (|k2y| / |k2x| = |k1x| / |k1y|, its ratio then
        known to the log-ratio error of a 1 deg tilt, ``PERPENDICULAR_SIN``), and the lines are fitted in two
        directions as any others. The right angle is an assumption: speeds are reported only where a
        combination line measures, in the pair whose ratio the right angle supplied, what the fit predicts
        (``_multi_result``), and where every reading so verified gives the same speeds.
        """
        dat = self.dat
        k1x, k1y = math.exp(lx), math.exp(ly)
        single = others & (dat.hx ^ dat.hy)
        tol = _omega_tol(dat.sw, dat.d_omega)
        lr_tab, _ = _tables(a * self.ga, dat.d1, dat.d2)
        lk = np.log(_K_GRID)
        tilt = math.asin(PERPENDICULAR_SIN) * 2.0 / max(abs(math.sin(2.0 * math.atan2(k1x, k1y))), 1e-3)
        found, unchecked = [], []
        for u in np.flatnonzero(single):
            lower = single & (dat.w < dat.w[u] - tol[u])
            ratio = dat.w[u] / np.where(lower, dat.w, np.inf)
            if np.any(lower & (np.abs(ratio - np.rint(ratio)) * dat.w <= tol + tol[u])):
                continue                     # a harmonic of a lower line: that line is the fundamental
            # the fundamental alone: its harmonics add no direction, and each mode of the fit has its own sign
            hx, hy, lrx, srx, lry, sry = (np.array(v) for v in (dat.hx, dat.hy, dat.lrx, dat.srx, dat.lry, dat.sry))
            q = 0 if dat.hx[u] else 1                # the pair that hears it; the right angle supplies the other
            lr, lg, s_meas = (dat.lrx[u], dat.lgx, dat.srx[u]) if q == 0 else (dat.lry[u], dat.lgy, dat.sry[u])
            k_meas = float(invert_ratio(lr - lg, a * self.ga, dat.d1, dat.d2))
            k_other = k_meas * (k1x / k1y if q == 0 else k1y / k1x)
            value = float(np.interp(math.log(k_other), lk, lr_tab))
            # its error: the 1 deg tilt and the measured component's own, through d log R / d log k
            slope_m, slope_o = (_log_slope(lr_tab, lk, k) for k in (k_meas, k_other))
            err = abs(slope_o) * math.hypot(tilt, s_meas / max(abs(slope_m), 1e-6))
            if q == 0:
                hy[u], lry[u], sry[u] = True, value + dat.lgy, err
            else:
                hx[u], lrx[u], srx[u] = True, value + dat.lgx, err
            sub = _Fitter(self.lines, dat._replace(hx=hx, hy=hy, lrx=lrx, srx=srx, lry=lry, sry=sry), self.a_known,
                          None, (self.a_grid[0], self.a_grid[-1]))
            sub.check_pairs = (1 - q,)
            res = sub.run()
            if res.status == "ok":
                found.append((float(dat.w[u]), res))
            elif sub.reading:
                unchecked.append((float(dat.w[u]), sub.reading))
        if not found:
            readings = "; ".join(f"second family at {w:.2f} rad/s: {text}" for w, text in unchecked)
            return None, (f"; read as a square net (its families at right angles, which no combination line checks "
                          f"here): {readings}" if unchecked else "")
        w2, best = found[0]
        for _, other in found[1:]:
            if (abs(other.vx - best.vx) > 3 * math.hypot(other.vx_err, best.vx_err)
                    or abs(other.vy - best.vy) > 3 * math.hypot(other.vy_err, best.vy_err)):
                return None, ""
        why = (f"; read as a wire net whose second family (fundamental at {w2:.2f} rad/s, heard by one pair) crosses "
               "the first at right angles, the right angle checked by combination lines")
        return best._replace(message=best.message + why), ""

    def _square_speed(self, fits, slots) -> str:
        """Where two or more equally good sign choices put two families at right angles and give one speed |v|
        (v and its reflection across a family's wires), that speed as a reading of a square net; else ''."""
        square = [f for f in fits if self._right_angle(f, slots)[0]]
        if len(square) < 2:
            return ""
        speeds, errs = [], []
        for f in square:
            vx, vy = f.theta[1] * _V_UNIT, f.theta[2] * _V_UNIT
            s = math.hypot(vx, vy)
            g = np.array([vx, vy]) / s * _V_UNIT
            speeds.append(s)
            errs.append(math.sqrt(max(float(g @ (f.cov * _scale(f))[1:3, 1:3] @ g), 0.0)))
        if max(speeds) - min(speeds) > 3.0 * max(max(errs), 1e-12):
            return ""
        return (f"the {len(square)} choices that put two families at right angles (a square net) share the speed "
                f"|v| = {speeds[0] * 100:.4g} +/- {errs[0] * 100:.2g} cm/s and differ in its direction")

    def _decide(self, cands, slots):
        """Which of the equally good sign choices ``cands`` (fits, best first) survive: (indices, message).

        First the combination lines (k_i +/- k_j of the fitted modes, at omega_i +/- omega_j) heard outside
        the fit: each choice predicts their components differently, and the choices within 9 of the best
        chi2 survive (the best must fit them: p >= ``P_POOR``). Then, where several survive, a wire net's
        geometry: its two families of wires cross at right angles, so a choice that puts two of its fitted
        modes at right angles (within ``PERPENDICULAR_SIN``, or 3 sigma) where every other puts none is taken.
        """
        scores = [self._combination_score(f, slots) for f in cands]
        chi = np.array([c for c, _ in scores])
        n_m = [n for _, n in scores]
        keep = list(range(len(cands)))
        msg = ""
        best = int(np.argmin(chi))
        if n_m[best] > 0 and _p_value(chi[best], n_m[best]) >= P_POOR:
            keep = [i for i in keep if chi[i] <= chi[best] + 9.0]
            if len(keep) < len(cands):
                worse = min(chi[i] for i in range(len(cands)) if i not in keep)
                msg = (f"; {len(cands)} sign choices fit the lines, {len(keep)} of them the {n_m[best]} "
                       f"measurement(s) of combination lines (chi2 {chi[best]:.1f} against >= {worse:.1f})")
        if len(keep) > 1:
            perp = {i: self._right_angle(cands[i], slots) for i in keep}
            square = [i for i in keep if perp[i][0]]
            if len(square) == 1:
                widest = max(math.degrees(math.acos(min(perp[i][1], 1.0))) for i in keep if i != square[0])
                msg = ((msg + ", and of those" if msg else f"; {len(keep)} sign choices fit the lines equally, and")
                       + f" the one that puts two line families at right angles is taken (a wire net's wires cross "
                       f"at right angles; the other choice(s) cross them at {widest:.0f} deg at most)")
                keep = square
        return keep, msg

    def _right_angle(self, fit, slots):
        """(whether two of the fit's modes are at right angles, the smallest |cos| between non-parallel modes)."""
        th = fit.theta
        n = len(slots)
        lx, ly = th[_NG:_NG + n], th[_NG + NMAX:_NG + NMAX + n]
        k = np.stack([np.exp(lx), fit.t[slots] * np.exp(ly)], 1)
        cov = fit.cov * _scale(fit)
        found, smallest = False, 1.0
        for i in range(n):
            for j in range(i + 1, n):
                ni, nj = np.linalg.norm(k[i]), np.linalg.norm(k[j])
                c = float(k[i] @ k[j] / (ni * nj))
                if abs(c) > 0.99:                       # parallel: one family's harmonics
                    continue
                smallest = min(smallest, abs(c))
                # d c / d log|kx|, d log|ky| of both modes
                idx = [_NG + i, _NG + NMAX + i, _NG + j, _NG + NMAX + j]
                g = np.array([k[i, 0] * k[j, 0] / (ni * nj) - c * k[i, 0] ** 2 / ni ** 2,
                              k[i, 1] * k[j, 1] / (ni * nj) - c * k[i, 1] ** 2 / ni ** 2,
                              k[i, 0] * k[j, 0] / (ni * nj) - c * k[j, 0] ** 2 / nj ** 2,
                              k[i, 1] * k[j, 1] / (ni * nj) - c * k[j, 1] ** 2 / nj ** 2])
                sd = math.sqrt(max(float(g @ cov[np.ix_(idx, idx)] @ g), 0.0))
                if abs(c) <= max(PERPENDICULAR_SIN, 3.0 * sd) and 3.0 * sd < 0.1:
                    found = True
        return found, smallest

    def _combination_score(self, fit, slots, pairs=(0, 1)):
        """(chi2, number of measurements) of the lines outside the fit that sit at |n omega_i + m omega_j|
        (|n| + |m| <= 3, within 4 sigma) of two fitted modes i, j, predicted as k = n k_i + m k_j with the
        signed wavevectors of this sign choice (k_i . v = +omega_i); per line the best such combination."""
        dat = self.dat
        th = fit.theta
        a = 1e-3 * math.exp(th[0])
        v = np.array([th[1], th[2]]) * _V_UNIT
        n = len(slots)
        kx = _K_UNIT * np.exp(th[_NG:_NG + n])
        ky = _K_UNIT * np.exp(th[_NG + NMAX:_NG + NMAX + n])
        kv = np.stack([kx, fit.t[slots] * ky], 1)                     # the model's (|kx|, t |ky|)
        kv *= np.where(kv @ v >= 0, 1.0, -1.0)[:, None]                 # k_i . v = +omega_i
        lr_tab, f_tab = _tables(a * self.ga, dat.d1, dat.d2)
        lk = np.log(_K_GRID)

        def at(tab, k):
            return np.interp(np.log(np.maximum(k, _K_GRID[0])), lk, tab)

        def slope(tab, k):          # the prediction's error from COMBINATION_K_ERR
            return _log_slope(tab, lk, max(k, _K_GRID[0])) * COMBINATION_K_ERR

        combos = [(p, q) for p in range(-3, 4) for q in range(-3, 4) if 0 < abs(p) + abs(q) <= 3 and p != 0 and q != 0]
        outside = np.flatnonzero(~np.isin(np.arange(self.n), slots) & (dat.hx | dat.hy | dat.hc))
        total, n_meas = 0.0, 0
        for u in outside:
            best = None
            for i in range(n):
                for j in range(i + 1, n):
                    for p, q in combos:
                        k = p * kv[i] + q * kv[j]
                        w = abs(k @ v)
                        tol = 4.0 * (dat.sw[u] + abs(p) * dat.sw[slots[i]] + abs(q) * dat.sw[slots[j]])
                        if abs(w - dat.w[u]) > tol:
                            continue
                        kx_u, ky_u = abs(k[0]), abs(k[1])
                        z = []
                        if dat.hx[u] and 0 in pairs:
                            z.append((at(lr_tab, kx_u) + dat.lgx - dat.lrx[u])
                                     / math.hypot(dat.srx[u], slope(lr_tab, kx_u)))
                        if dat.hy[u] and 1 in pairs:
                            z.append((at(lr_tab, ky_u) + dat.lgy - dat.lry[u])
                                     / math.hypot(dat.sry[u], slope(lr_tab, ky_u)))
                        if dat.hc[u]:
                            z.append((dat.lrho + at(f_tab, ky_u) - at(f_tab, kx_u) - dat.lc[u])
                                     / math.hypot(dat.sc[u], slope(f_tab, ky_u), slope(f_tab, kx_u)))
                        c = float(np.sum(np.square(z)))
                        if best is None or c < best[0]:
                            best = (c, len(z))
            if best is not None:
                total += best[0]
                n_meas += best[1]
        return total, n_meas

    def _harmonic_radii(self, comp, harm):
        """The contact radii (m) at which one pair's harmonics (``harm``) are consistent: the local minima, within
        ``AMBIGUITY_CHI2`` of the best, of the spread of log(|k_j| / n_j) over a fine grid of ``a_grid``'s range.
        The ratio of two inverted wavenumbers is not monotonic in a, so two radii often fit a family's harmonics
        exactly (a 1.2 mm contact and harmonics 3, 5 of 1000 rad/m also fit at 0.957 mm)."""
        dat = self.dat
        lr, s, g = (dat.lrx, dat.srx, dat.lgx) if comp == 0 else (dat.lry, dat.sry, dat.lgy)
        sel = harm > 0
        grid = np.geomspace(self.a_grid[0], self.a_grid[-1], 161)
        tables = np.asarray(_curves_over(jnp.asarray(grid * self.ga), jnp.asarray(dat.d1), jnp.asarray(dat.d2)))[:, 0]
        cost = np.empty(grid.size)
        for i, tab in enumerate(tables):
            lk = np.log(_invert_on(tab, lr[sel] - g) / harm[sel])
            slope = np.log(_invert_on(tab, lr[sel] - g + 1e-3) / harm[sel]) - lk
            z = (lk - np.average(lk, weights=1.0 / np.square(s[sel] * slope / 1e-3))) / np.abs(s[sel] * slope / 1e-3)
            cost[i] = float(np.sum(np.square(z)))
        pad = np.concatenate([[np.inf], cost, [np.inf]])
        level = cost.min() + AMBIGUITY_CHI2
        minima = [i for i in range(grid.size) if pad[i + 1] <= pad[i] and pad[i + 1] <= pad[i + 2] and cost[i] <= level]
        distinct = minima[:1]
        for i in minima[1:]:                 # separated by a rise above the level
            if cost[distinct[-1]:i].max() > level:
                distinct.append(i)
        return [float(grid[i]) for i in distinct]

    def _single_pair_only(self) -> LineFit:
        """No line measured in both components: each pair's harmonics may still give a and |k_s|."""
        dat = self.dat
        out = []
        for comp, h in ((0, dat.hx), (1, dat.hy)):
            w0, harm = _harmonic_numbers(dat.w, dat.sw, dat.d_omega, h, floor_bins=STRICT_HARMONIC_BINS)
            if w0 is not None and len(set(harm[h].astype(int))) >= 2:
                out.append((int(h.sum()), comp, harm))
        a = a_err = None
        radii = ()
        a_src = "given" if self.a_known is not None else None
        if self.a_known is not None:
            a, a_err = float(self.a_known), 0.0
        elif out:
            _, comp, harm = max(out)
            slots = self._slots(harm > 0)
            fits, _ = self._profile(lambda a0, fa, final: [self._fit_family(slots, harm, a0, fa)])
            if fits and fits[0].converged and 0 < self._a_sd(fits[0]) <= A_DETERMINED:
                a = 1e-3 * math.exp(fits[0].theta[0])
                a_err, a_src = a * self._a_sd(fits[0]), "fit"
                radii = self._harmonic_radii(comp, harm)
                if len(radii) > 1:
                    a = a_err = a_src = None
                    other = ", ".join(f"{r * 1e3:.3g}" for r in radii)
        nan = np.full(self.n, np.nan)
        kx, kxe, ky, kye = self._fill_single(nan, nan, nan.copy(), nan.copy(), a, None if a is None else a_err / a)
        table = _table(self.lines, dat, np.zeros(self.n), np.zeros(self.n, bool), np.zeros(self.n, bool),
                       kx, kxe, ky, kye, np.zeros(self.n))
        msg = (f"every line is heard by one pair only ({int(dat.hx.sum())} x, {int(dat.hy.sum())} y, no cross-pair "
               "level): each gives one wavevector component and the other is unknown, so the speeds are "
               "undetermined" + ("" if a is not None else " (and a is not determined"
                                 + (f": the harmonics' ratios fit equally at a = {other} mm)" if radii else ")")))
        # one family heard by one pair: |k| >= |k_s|, so v_n <= omega0 / |k_s| (with a over its range if unknown)
        texture, bounds = "none", None
        for comp, h in ((0, dat.hx), (1, dat.hy)):
            w0, harm = _harmonic_numbers(dat.w, dat.sw, dat.d_omega, h, floor_bins=STRICT_HARMONIC_BINS)
            if w0 is None or (dat.hx | dat.hy)[~h].any():
                continue
            lr, g = (dat.lrx, dat.lgx) if comp == 0 else (dat.lry, dat.lgy)
            j = int(np.flatnonzero(h)[0])
            radii = [a] if a is not None else list(self.a_grid)
            k_s = min(float(invert_ratio(lr[j] - g, r * self.ga, dat.d1, dat.d2)) / harm[j] for r in radii)
            texture, bounds = "grating", (0.0, w0 / k_s)
            msg += (f"; one family in the {'xy'[comp]} pair: the speed along its normal is at most omega0 / "
                    f"|k{'xy'[comp]}| = {w0 / k_s:.4g} m/s" + ("" if a is not None else " over a in the plausible range"))
        return LineFit("undetermined", msg, a=a, a_err=a_err, a_source=a_src, v_n_bounds=bounds, texture=texture,
                       n_lines=self.n, lines=table)
